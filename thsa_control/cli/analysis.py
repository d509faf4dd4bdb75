"""``thsa report`` (the main job: loop analysis of a design over speed, load and temperature) and
``thsa linearize`` (one linear model)."""

from __future__ import annotations

from functools import partial

import re
import sys

from ..errors import ThsaError
from .common import (add_command, EXIT_OK, EXIT_REQUIREMENT_FAILED, analysis_effects, effects_arg, load_params,
                     out_arg, out_options, preflight_out, progress_for, scaled_floats)

__all__ = ["add_parsers", "cmd_report", "cmd_linearize"]


def cmd_report(args) -> int:
    preflight_out(args)
    progress = progress_for(args, "thsa report")
    progress.phase("loading the model and the linear-analysis libraries")
    with progress.heartbeat():
        from ..data.units import display_unit
        from ..loops.analysis import AnalysisSettings, analyse_design
        from ..loops.design import load_design, nominal_design_path
        from ..model import resolve_effects
        from ..report.analysis_report import write_analysis_report

    params = load_params(args)
    design = load_design(args.design or nominal_design_path())
    design.check_against(params)
    grid = {name: scaled_floats(getattr(args, opt), opt, scale) for name, opt, scale in (
        ("nut_speeds", "speeds", 1 / display_unit("nut_speed").factor),
        ("load_forces", "loads", 1 / display_unit("force").factor),
        ("temperatures", "temperatures", 1 / display_unit("temperature").factor))}
    if args.temperature is not None:
        grid["temperatures"] = (args.temperature,)
    settings = AnalysisSettings.from_design(design, level=args.level and args.level.upper(),
                                            effects=None if args.effects is None else tuple(analysis_effects(args)),
                                            **grid)
    resolve_effects(settings.level, add=list(settings.effects))  # validate names before any work
    progress.phase(f"linearising level {settings.level} over the grid and analysing the loops"
                   + ("" if args.no_switching else ", then the switch-over transient"))
    with progress.heartbeat():
        result = analyse_design(design, params, settings=settings, switching=not args.no_switching)
    verdict = None
    if args.check:  # the verdict of thsa check: this grid's linear requirements + the validation runs
        from .tuning import report_verdict

        progress.phase("judging every requirement (the validation runs of thsa check)")
        with progress.heartbeat():
            verdict = report_verdict(result, params)
    progress.phase("writing the report")
    opts = out_options(args)
    with progress.heartbeat():
        out = write_analysis_report(result, args.out, force=opts["force"], inputs=opts["inputs"], verdict=verdict)
    progress.done()
    print(result.requirements.summary())
    if verdict is not None:
        print(verdict.text())
    for loop in ("current_loop", "velocity_loop", "position_loop"):
        for metric in ("phase_margin_deg", "gain_margin_db"):
            w = result.loops.worst(loop, metric)
            if w is not None:
                print(f"worst {w.text()}")
    n_bad = int((~result.loops.valid).sum())
    print(f"{n_bad} of {len(result.loops)} grid points not analysed (zero speed, backlash edge or saturated), "
          "listed with their reason in the report")
    print(f"wrote {out / 'report.html'} and {out / 'analysis.json'}")
    return EXIT_REQUIREMENT_FAILED if args.check and not (result.requirements.passed and verdict.passed) else EXIT_OK


def cmd_linearize(args) -> int:
    from ..data.units import from_display
    from ..model import resolve_effects
    from ..loops.conditions import OperatingCondition

    # bad names and values fail before the heavy imports (python-control, scipy: seconds)
    resolve_effects(args.level, add=[] if args.effects is None else effects_arg(args.effects))
    load_n = load_newtons(args.load)
    try:
        cond = OperatingCondition(from_display("nut_speed", args.speed), load_n, args.temperature, args.active)
    except ValueError as exc:
        raise ThsaError(str(exc)) from None
    progress = progress_for(args, "thsa linearize")
    progress.phase("loading the linear-analysis libraries")
    params = load_params(args)
    effects = analysis_effects(args)
    if args.active == "standby" and "standby_motor" not in effects:
        effects.append("standby_motor")
    resolve_effects(args.level, add=effects)
    from ..loops.linear import format_linear_model, linearize_condition, plant_model

    progress.phase(f"building level {args.level.upper()} and linearising at {args.speed:g} mm/s, "
                   f"{load_n * 1e-3:g} kN, {args.temperature:g} degC")
    model = plant_model(args.level, effects, params)
    lin = linearize_condition(model, cond)
    progress.done()
    print(format_linear_model(lin))
    if args.save:
        fmt = args.format or ("mat" if str(args.save).endswith(".mat") else "npz")
        if fmt == "mat":  # MATLAB: load model.mat; ss(A, B, C, D, 'StateName', states, ...)
            from ..data.matfile import linear_model_to_mat, plant_units, write_mat

            path = write_mat(args.save, linear_model_to_mat(lin[0], units=plant_units(model.plant), condition=cond))
        else:
            path = lin[0].save(args.save)
        print(f"saved {path}")
    return 0


def load_newtons(text: str) -> float:
    """``--load`` [kN, like ``thsa report --loads``] -> N; ``20kN`` / ``20000N`` name their unit.

    The old form, a bare number in N, is still read when it cannot be kN (|value| > 100: beyond any load of the
    actuator), with a deprecation note on stderr.
    """
    raw = str(text).strip().replace(" ", "")
    m = re.fullmatch(r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)(kN|N)?", raw)
    if m is None:
        raise ThsaError(f"--load {text!r}: expected a number in kN (e.g. 20, -55, 20kN or 20000N)")
    from ..data.units import from_display

    value, unit = float(m.group(1)), m.group(2)
    if unit == "N":
        return value
    if unit is None and abs(value) > 100.0:
        print(f"note: --load {text} read as N (the old unit); --load takes kN now, like report --loads: "
              f"write --load {value * 1e-3:g}", file=sys.stderr)
        return value
    return float(from_display("force", value))


def add_parsers(sub, shared) -> None:
    """``thsa report``, ``thsa linearize``."""
    add = partial(add_command, sub, shared)

    p = add("report", "loop analysis of a design over speed, load and temperature: HTML + JSON", cmd_report)
    p.add_argument("--design", help="design TOML (default designs/nominal.toml)")
    p.add_argument("--level", help="model level A, B, C or D (default: the design's [analysis], else B)")
    p.add_argument("--effects", nargs="*", help="effects added to the level (default: the design's [analysis], "
                                                "else temperature_friction standby_motor)")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--speeds", help="grid trim speeds [mm/s], comma-separated (default 0,0.5,1,2,5,10,15)")
    p.add_argument("--loads", help="grid loads [kN], compressive positive (default -55,-20,0,20,55)")
    p.add_argument("--temperatures", help="grid temperatures [degC] (default -55,-30,0,25,70)")
    p.add_argument("--temperature", type=float, help="analyse at this one temperature [degC] only")
    p.add_argument("--no-switching", action="store_true", help="skip the nonlinear switch-over transient")
    p.add_argument("--check", action="store_true", help="judge every requirement as thsa check does (linear "
                   "requirements on this grid + the nonlinear validation runs); exit with status 1 when one is not met")
    out_arg(p)
    p = add("linearize", "print the linear model at one operating point (and save it)", cmd_linearize)
    p.add_argument("--level", required=True, help="model level A, B, C or D")
    p.add_argument("--speed", type=float, required=True, help="trim nut speed [mm/s], positive extending")
    p.add_argument("--load", required=True,
                   help="load [kN], compressive positive (opposes extension); 20kN or 20000N name the unit "
                        "(a bare number above 100 is read as N, the old unit, with a note)")
    p.add_argument("--temperature", type=float, default=25.0, help="temperature [degC], -55..70 (default 25)")
    p.add_argument("--effects", nargs="*", help="effects added to the level (default: temperature_friction standby_motor)")
    p.add_argument("--active", choices=["primary", "standby"], default="primary", help="energised motor channel")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--save", help="write the linear model to this file: .npz (numpy), or .mat for MATLAB (A, B, C, D, "
                                  "signal names and units, the operating point; `load model.mat`)")
    p.add_argument("--format", choices=("npz", "mat"), help="format of --save (default: from its suffix, else npz)")

