"""Command line of thsa-control: a thin argparse front end over the API.

Commands::

    thsa scenarios
    thsa levels    [--scenario NAME] [--levels A,B,C,D] [--effects E ...] [--design FILE]
                   [--params FILE] [--temperature T] --out DIR
    thsa simulate  --scenario NAME --level C [--effects E ...] [--design FILE] [--params FILE]
                   [--temperature T] [--output-period S] --out DIR
    thsa check-data RUN.csv
    thsa identify  RUN.csv [RUN2.csv ...] --model B --free PARAM,... [--effects E ...] [--params FILE] --out DIR
    thsa trace     RUN.csv [RUN2.csv ...] --model A [--effects E ...] [--params FILE ...] --out DIR
    thsa residual  RUN.csv --model A [--mode closed_loop|open_loop] [--segment S|whole] [--effects E ...]
                   [--remove E ...] [--params FILE] --out DIR
    thsa report    --design designs/nominal.toml --out DIR [--level B] [--effects E ...] [--params FILE]
                   [--no-switching] [--check]
    thsa sweep     SPEC.toml --out DIR [--scheduler ADDRESS | --workers N] [--force] [--check]
    thsa linearize --level A --speed 5 --load 20000 --temperature -30 [--effects E ...] [--active standby]
                   [--params FILE] [--save FILE.npz]

Exit status: 0 success; 1 a requirement failed (``report --check``); 2 an
error of the input (unknown scenario, level or effect, bad design, parameter
or run file, bad option value, output folder that may not be replaced): one
line naming the culprit, nothing written; 3 an internal error (a bug: one
line, the traceback with ``THSA_DEBUG=1``); 128+N killed by signal N.

``--out`` replaces only a folder that thsa wrote itself (it carries a
``.thsa-output`` marker) or an empty one; ``--force`` replaces another folder
but never one that holds an input file.  Long commands print progress on
stderr (``--quiet`` silences it).  This module imports only the standard
library at import time, so that ``thsa --help`` is instant.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .errors import ThsaError, UsageError

__all__ = ["main", "EXIT_OK", "EXIT_REQUIREMENT_FAILED", "EXIT_USAGE", "EXIT_INTERNAL"]

EXIT_OK = 0
EXIT_REQUIREMENT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 3
#: Largest simulation a command accepts, in control periods (the input series alone is ~50 bytes each).
MAX_CONTROL_PERIODS = 20_000_000


def _progress(args, label: str):
    from .progress import Progress

    return Progress(label, enabled=not getattr(args, "quiet", False))


def _out_options(args, inputs=()) -> dict:
    """Keyword arguments of ``atomic_folder`` from ``--out``/``--force`` and the command's input files."""
    params = getattr(args, "params", None)  # one file, or a list (--params takes several)
    extra = [*(params if isinstance(params, (list, tuple)) else [params]), getattr(args, "design", None)]
    return {"force": bool(getattr(args, "force", False)), "inputs": [p for p in (*inputs, *extra) if p],
            "command": " ".join(["thsa", *getattr(args, "argv", [])])}


def _preflight_out(args, inputs=()) -> None:
    """Refuse an output folder before any long computation."""
    from .report.build import check_output_folder

    opts = _out_options(args, inputs)
    check_output_folder(args.out, force=opts["force"], inputs=opts["inputs"])


def _positive(value, option: str, *, integer: bool = False):
    import math

    if value is None:
        return value
    if integer and not (isinstance(value, int) and value >= 1):
        raise UsageError(f"{option} {value!r}: must be an integer >= 1")
    if not integer and not (math.isfinite(value) and value > 0):
        raise UsageError(f"{option} {value!r}: must be a positive number")
    return value


def _check_output_period(output_period: float, control_period: float) -> None:
    ratio = output_period / control_period
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6 * ratio:
        raise UsageError(f"--output-period {output_period:g}: must be a whole multiple of the design's "
                         f"control period {control_period:g} s")


def _check_run_length(duration: float, control_period: float, what: str) -> None:
    n = duration / control_period
    if n > MAX_CONTROL_PERIODS:
        raise UsageError(f"{what}: {duration:g} s at a control period of {control_period:g} s is {n:.3g} periods, "
                         f"more than {MAX_CONTROL_PERIODS:.0e}; use a longer control period or a shorter run")


def load_params_design(args):
    """``(params, design)`` from ``--params`` (over the embedded actuator) and ``--design`` (default nominal),
    the design checked against the actuator; shared by every subcommand that takes them."""
    from .loops.design import load_design, nominal_design_path
    from .model.params import default_parameters, load_parameters

    params = default_parameters()
    if getattr(args, "params", None):
        params = load_parameters(args.params, base=params)
    design = load_design(getattr(args, "design", None) or nominal_design_path())
    design.check_against(params)
    return params, design


def _load_common(args):
    from .sim.scenarios import get_scenario

    params, design = load_params_design(args)
    scenario = get_scenario(args.scenario)
    if args.temperature is not None:
        scenario = scenario.with_temperature(args.temperature)
    _positive(args.output_period, "--output-period")
    _check_output_period(args.output_period, design.control_period)
    _check_run_length(scenario.duration, design.control_period, f"scenario {scenario.name}")
    return params, design, scenario


def _effects_arg(values):
    out = []
    for v in values or []:
        out += [e.strip() for e in v.split(",") if e.strip()]
    return out


def _cmd_scenarios(args) -> int:
    from .sim.scenarios import SCENARIOS

    for s in SCENARIOS.values():
        need = f" [needs {', '.join(s.required_effects)}]" if s.required_effects else ""
        print(f"{s.name:28s} {s.duration:5.1f} s  {s.temperature:5.1f} degC{need}\n    {s.description}")
    return 0


def _run_levels(params, design, scenario, levels, effects, output_period, progress=None):
    from .model import build_plant
    from .sim.simulate import SimulationSettings, Simulator

    settings = SimulationSettings(output_period=output_period)
    results = {}
    for i, level in enumerate(levels, 1):
        if progress is not None:
            progress.phase(f"simulating {scenario.name} at level {level} ({i}/{len(levels)})")
        eff = list(effects) + [e for e in scenario.required_effects if e not in effects]
        plant = build_plant(level, eff, params=params)
        results[level] = Simulator(plant, settings).run(scenario, design, params)
    return results


def _summary(result) -> dict:
    from .sim.metrics import backdrive_metrics, surface_speed_deviation

    out = {"effects": list(result.effects), "wall_s": result.info["wall_s"],
           "real_time_factor": float(result.time[-1] / max(result.info["wall_s"], 1e-12)),
           "peak_abs_current_A": float(max(abs(result["motor_current"].min()), abs(result["motor_current"].max()))),
           "final_nut_position_mm": float(result["nut_position"][-1] * 1e3)}
    try:
        m = backdrive_metrics(result)
    except ValueError:
        m = None
    if m is not None:
        out["backdrive"] = {
            "opposing_mean_current_A": m.opposing_mean_current, "aiding_mean_current_A": m.aiding_mean_current,
            "aiding_to_opposing": m.aiding_to_opposing, "aiding_drive_fraction": m.aiding_drive_fraction,
            "breakaway_peak_A": m.breakaway_peak, "breakaway_to_opposing": m.breakaway_to_opposing,
            "stop_backdrive_peak_mm_s": [v * 1e3 for v in m.stop_backdrive_peak],
            "stop_backdrive_peak_of_command": [v / m.command_amplitude for v in m.stop_backdrive_peak],
        }
    out["surface_speed_deviation_of_command"] = surface_speed_deviation(result)
    return out


def _write_results(args, results, scenario, params, design):
    from .data.export import write_simulation
    from .report import atomic_folder, write_json
    from .report.plots import close, plot_levels, plot_run

    with atomic_folder(args.out, **_out_options(args)) as tmp:
        summary = {"scenario": scenario.name, "description": scenario.description, "temperature_C": scenario.temperature,
                   "design": design.source, "levels": {}}
        for level, res in results.items():
            stem = tmp / f"{scenario.name}_{level}"
            write_simulation(res, stem, level=level)
            fig = plot_run(res, title=f"{scenario.name}, level {level} ({', '.join(res.effects) or 'functional'})")
            fig.savefig(stem.with_suffix(".png"), dpi=110)
            close(fig)
            if "trip_speed" in res.names:  # a run of the fault loop: torques, slip, sensor speeds, monitor flags
                from .report.faults import plot_fault_run

                fig = plot_fault_run(res)
                fig.savefig(stem.with_name(stem.name + "_faults.png"), dpi=110)
                close(fig)
            summary["levels"][level] = _summary(res)
        if len(results) > 1:
            fig = plot_levels(results)
            fig.savefig(tmp / f"{scenario.name}_levels.png", dpi=110)
            close(fig)
        params.save(tmp / "parameters.toml")
        write_json(tmp / "summary.json", summary)
    return summary


def _cmd_levels(args) -> int:
    _preflight_out(args)
    progress = _progress(args, "thsa levels")
    params, design, scenario = _load_common(args)
    levels = [lv.strip().upper() for lv in args.levels.split(",") if lv.strip()]
    results = _run_levels(params, design, scenario, levels, _effects_arg(args.effects), args.output_period, progress)
    progress.phase("writing runs and plots")
    summary = _write_results(args, results, scenario, params, design)
    for level, s in summary["levels"].items():
        line = f"level {level}: {s['real_time_factor']:.0f}x real time, peak |I| {s['peak_abs_current_A']:.1f} A"
        if "backdrive" in s:
            b = s["backdrive"]
            line += (f", aiding/opposing |I| {b['aiding_to_opposing']:.2f}, breakaway/opposing {b['breakaway_to_opposing']:.2f}, "
                     f"trim-stop back-drive {max(b['stop_backdrive_peak_of_command']) * 100:.0f} % of command")
        print(line)
    if not getattr(args, "no_ranges", False):
        from .sim.assumptions import assumption_ranges, format_ranges

        progress.phase("headline numbers over the ranges of the assumed values")
        ranges = assumption_ranges(design, params, output_period=args.output_period)
        print("headline numbers over the plausible range of the assumed values that set them:")
        print(format_ranges(ranges))
    progress.done()
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _cmd_simulate(args) -> int:
    _preflight_out(args)
    params, design, scenario = _load_common(args)
    from .model import resolve_effects

    effects = _effects_arg(args.effects)
    resolve_effects(args.level, add=effects)  # validate names before any work
    if args.temperature is not None and "temperature_friction" not in effects:
        print("note: --temperature changes nothing without --effects temperature_friction", file=sys.stderr)
    results = _run_levels(params, design, scenario, [args.level.upper()], effects, args.output_period)
    _write_results(args, results, scenario, params, design)
    res = results[args.level.upper()]
    print(f"{scenario.name} at level {args.level.upper()} ({', '.join(res.effects) or 'functional'}): "
          f"{res.time[-1]:.1f} s simulated in {res.info['wall_s'] * 1e3:.1f} ms")
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _column_map(text: str | None) -> dict | None:
    """``--column-map`` JSON -> {rig column: FORMAT column}; UsageError otherwise."""
    if not text:
        return None
    try:
        mapping = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise UsageError(f"--column-map is not valid JSON ({exc if isinstance(exc, json.JSONDecodeError) else 'nested too deeply'}); "
                         """expected an object like '{"t": "time_s"}'""") from None
    if not isinstance(mapping, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in mapping.items()):
        raise UsageError("""--column-map must be a JSON object of column names to column names, e.g. '{"t": "time_s"}'""")
    return mapping


def _cmd_check_data(args) -> int:
    from .data.rigdata import read_run
    from .data.rigsummary import format_summary, summarize_run

    run = read_run(args.run, column_map=_column_map(args.column_map))
    print(format_summary(summarize_run(run)))
    return 0


def _read_runs(paths, column_map, params):
    from .data.rigdata import read_run
    from .loops.design import check_control_period

    from .fit.kinematics import run_kinematics

    mapping = _column_map(column_map)
    kin = (params.value("screw.lead") * 1e3, params.value("gear.ratio"))  # where a run states none
    runs = [run_kinematics(read_run(p, column_map=mapping, default_kinematics=kin), params) for p in paths]
    for run in runs:
        if run.controller is not None:
            # the JSON's controller against the plant: a 1 s period would "replay" a nonsense loop
            check_control_period(run.controller.control_period, params, str(run.json_path),
                                 "controller.control_period_s")
    return runs


def _run_inputs(paths) -> list[str]:
    out = []
    for p in paths:
        out += [str(p), str(Path(p).with_suffix(".json"))]
    return out


def _load_params(args):
    from .model.params import default_parameters, load_parameters

    return load_parameters(args.params, base=default_parameters()) if args.params else default_parameters()


def _replay_mode(run, mode):
    return mode if mode != "auto" else ("closed_loop" if run.controller is not None else "open_loop")


def _bounds_arg(text: str | None) -> dict:
    """``--bounds NAME=LO:HI,...`` (SI) -> {name: (lo, hi)}."""
    out = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        name, _, rng = item.partition("=")
        lo, _, hi = rng.partition(":")
        try:
            out[name.strip()] = (float(lo), float(hi))
        except ValueError:
            raise UsageError(f"--bounds: {item.strip()!r} is not NAME=LO:HI (SI numbers)") from None
    return out


def _cmd_identify(args) -> int:
    from .fit.identify import IdentificationSettings, Identifier
    from .fit.replay import analyse_replay, replay
    from .report import atomic_folder
    from .report.identification import write_identification_folder

    _positive(args.segment, "--segment")
    _positive(args.substeps, "--substeps", integer=True)
    _preflight_out(args, _run_inputs(args.runs))
    progress = _progress(args, "thsa identify")
    params = _load_params(args)
    progress.phase(f"reading {len(args.runs)} run(s)")
    runs = _read_runs(args.runs, args.column_map, params)
    effects = _effects_arg(args.effects)
    free = [n.strip() for n in (args.free or "").split(",") if n.strip()]
    from .fit.progress import stderr_progress
    from .trace._threads import limit_blas_threads

    limit_blas_threads(1)  # a many-threaded BLAS on a small shared machine is 40x slower per SVD
    try:
        settings = IdentificationSettings(segment_duration=args.segment, substeps=args.substeps,
                                          global_stage=args.global_stage, max_nfev=args.max_nfev,
                                          time_budget=args.time_budget, prior_relative_sd=args.prior_sd)
        settings.validate()
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    progress.phase(f"fitting {', '.join(free) or 'nothing'} at level {args.model}")
    result = Identifier(args.model, params, free, effects=effects, settings=settings,
                        bounds=_bounds_arg(args.bounds)).fit(
        runs, progress=stderr_progress("identify", quiet=getattr(args, "quiet", False)))
    fitted = result.to_parameter_set()
    before, after, analyses = [], [], []
    for i, run in enumerate(runs, 1):
        progress.phase(f"replaying {run.name} before and after ({i}/{len(runs)})")
        mode = _replay_mode(run, args.mode)
        before.append(replay(run, args.model, effects, params=params, mode=mode))
        after.append(replay(run, args.model, effects, params=fitted, mode=mode))
        analyses.append(analyse_replay(run, after[-1]))
    progress.phase("writing the report")
    with atomic_folder(args.out, **_out_options(args, _run_inputs(args.runs))) as tmp:
        write_identification_folder(tmp, result, before, after, analyses)
    progress.done()
    print(result.fit_report())
    if not result.converged:
        print(f"warning: {result.status}; the best result so far is written, flagged converged = false",
              file=sys.stderr)
    for b, a in zip(before, after):
        print(f"{b.run_name} ({b.mode.replace('_', ' ')} replay): " + ", ".join(
            f"{c} fit {b.fits[c].fit_percent:.1f} -> {a.fits[c].fit_percent:.1f} %" for c in a.fits))
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _cmd_residual(args) -> int:
    from .fit.replay import analyse_replay
    from .fit.residuals import format_residual_report
    from .fit.segmented import parse_segment, replay_for_residual
    from .model import build_plant
    from .report import atomic_folder
    from .report.identification import write_residual_folder

    segment = parse_segment(args.segment)
    _preflight_out(args, _run_inputs([args.run]))
    progress = _progress(args, "thsa residual")
    params = _load_params(args)
    progress.phase("reading the run")
    run, = _read_runs([args.run], args.column_map, params)
    mode = _replay_mode(run, args.mode)
    if args.segment is not None and mode != "open_loop":
        raise UsageError(f"--segment {args.segment}: segments apply to the open-loop replay (--mode open_loop); "
                         f"run {run.name!r} replays in closed loop under its controller")
    plant = build_plant(args.model, _effects_arg(args.effects), remove=_effects_arg(args.remove), params=params)
    progress.phase(f"replaying {run.name} through level {args.model}")
    result = replay_for_residual(run, plant, params, mode, segment_duration=segment)
    progress.phase("residual analysis")
    analysis = analyse_replay(run, result)
    progress.phase("writing the report")
    with atomic_folder(args.out, **_out_options(args, _run_inputs([args.run]))) as tmp:
        write_residual_folder(tmp, result, analysis)
    progress.done()
    print(format_residual_report(analysis))
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _floats(text, option: str, scale: float):
    """``--option 1,2,3`` -> SI tuple (None when not given)."""
    if text is None:
        return None
    try:
        return tuple(float(v) * scale for v in text.split(",") if v.strip())
    except ValueError:
        raise ThsaError(f"--{option} {text!r}: give comma-separated numbers") from None


def _analysis_effects(args) -> list[str]:
    # the plant that exists: temperature_friction and the dragged standby rotor, unless --effects says otherwise
    from .loops.analysis import DEFAULT_ANALYSIS_EFFECTS

    return list(DEFAULT_ANALYSIS_EFFECTS) if args.effects is None else _effects_arg(args.effects)


def _cmd_report(args) -> int:
    from .loops.analysis import AnalysisSettings, analyse_design
    from .loops.design import load_design, nominal_design_path
    from .model import resolve_effects
    from .report.analysis_report import write_analysis_report

    _preflight_out(args)
    progress = _progress(args, "thsa report")
    params = _load_params(args)
    design = load_design(args.design or nominal_design_path())
    design.check_against(params)
    grid = {name: _floats(getattr(args, opt), opt, scale) for name, opt, scale in (
        ("nut_speeds", "speeds", 1e-3), ("load_forces", "loads", 1e3), ("temperatures", "temperatures", 1.0))}
    if args.temperature is not None:
        grid["temperatures"] = (args.temperature,)
    settings = AnalysisSettings.from_design(design, level=args.level and args.level.upper(),
                                            effects=None if args.effects is None else tuple(_analysis_effects(args)),
                                            **grid)
    resolve_effects(settings.level, add=list(settings.effects))  # validate names before any work
    progress.phase(f"linearising level {settings.level} over the grid and analysing the loops"
                   + ("" if args.no_switching else ", then the switch-over transient"))
    result = analyse_design(design, params, settings=settings, switching=not args.no_switching)
    progress.phase("writing the report")
    opts = _out_options(args)
    out = write_analysis_report(result, args.out, force=opts["force"], inputs=opts["inputs"])
    progress.done()
    print(result.requirements.summary())
    for loop in ("current_loop", "velocity_loop", "position_loop"):
        for metric in ("phase_margin_deg", "gain_margin_db"):
            w = result.loops.worst(loop, metric)
            if w is not None:
                print(f"worst {w.text()}")
    n_bad = int((~result.loops.valid).sum())
    print(f"{n_bad} of {len(result.loops)} grid points not analysed (zero speed, backlash edge or saturated), "
          "listed with their reason in the report")
    print(f"wrote {out / 'report.html'} and {out / 'analysis.json'}")
    return EXIT_REQUIREMENT_FAILED if args.check and not result.requirements.passed else EXIT_OK


def _cmd_linearize(args) -> int:
    from .loops.linear import OperatingCondition, format_linear_model, linearize_condition, plant_model
    from .model import resolve_effects

    params = _load_params(args)
    effects = _analysis_effects(args)
    if args.active == "standby" and "standby_motor" not in effects:
        effects.append("standby_motor")
    resolve_effects(args.level, add=effects)
    try:
        cond = OperatingCondition(args.speed * 1e-3, args.load, args.temperature, args.active)
    except ValueError as exc:
        raise ThsaError(str(exc)) from None
    lin = linearize_condition(plant_model(args.level, effects, params), cond)
    print(format_linear_model(lin))
    if args.save:
        print(f"saved {lin[0].save(args.save)}")
    return 0


def _cmd_sweep(args) -> int:
    from .sweep.command import sweep_command

    return sweep_command(args.spec, args.out, scheduler=args.scheduler, workers=args.workers, force=args.force,
                         check=args.check, quiet=getattr(args, "quiet", False),
                         command=" ".join(["thsa", *getattr(args, "argv", [])]))


def _parser() -> argparse.ArgumentParser:
    from . import __version__

    shared = argparse.ArgumentParser(add_help=False)
    shared.add_argument("-q", "--quiet", action="store_true", default=argparse.SUPPRESS,
                        help="no progress lines on stderr")
    ap = argparse.ArgumentParser(prog="thsa", description="THSA control workbench", parents=[shared])
    ap.add_argument("--version", action="version", version=f"thsa-control {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)

    def add(name: str, help: str, fn):
        p = sub.add_parser(name, help=help, parents=[shared])
        p.set_defaults(fn=fn)
        return p

    def out_arg(p):
        p.add_argument("--out", required=True,
                       help="output folder: new, empty, or written by thsa before (then replaced atomically)")
        p.add_argument("--force", action="store_true",
                       help="also replace a folder not written by thsa (never one holding an input file)")

    add("scenarios", "list the named scenarios", _cmd_scenarios)

    def common(p, level_arg: bool):
        p.add_argument("--scenario", default="backdrive_bipolar_ramp" if not level_arg else None, required=level_arg)
        if level_arg:
            p.add_argument("--level", required=True, help="A, B, C or D")
        p.add_argument("--effects", nargs="*", help="effects added to the level(s), e.g. temperature_friction standby_motor")
        p.add_argument("--design", help="design TOML (default designs/nominal.toml)")
        p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
        p.add_argument("--temperature", type=float, help="temperature [degC], -55..70")
        p.add_argument("--output-period", type=float, default=1e-3,
                       help="output sample period [s], a multiple of the control period (default 1e-3)")
        out_arg(p)

    p = add("levels", "simulate a scenario at several levels side by side (the main job)", _cmd_levels)
    common(p, False)
    p.add_argument("--levels", default="A,B,C,D")
    p.add_argument("--no-ranges", action="store_true",
                   help="skip the headline numbers over the ranges of the assumed values (thsa_control.sim.assumptions)")
    p = add("simulate", "simulate a scenario at one level, write the run (FORMAT.md) and plots", _cmd_simulate)
    common(p, True)
    p = add("check-data", "validate and summarise a rig run (FORMAT.md)", _cmd_check_data)
    p.add_argument("run", help="RUN.csv (RUN.json beside it)")
    p.add_argument("--column-map", help='JSON mapping of rig column names to FORMAT names, e.g. \'{"t": "time_s"}\'')

    def model_args(p):
        p.add_argument("--model", required=True, help="model level A, B, C or D")
        p.add_argument("--effects", nargs="*", help="effects added to the level")
        p.add_argument("--params", nargs="+", help="parameter TOML file(s) overriding the embedded actuator, "
                       "merged in order (initial values)")
        p.add_argument("--column-map", help="JSON mapping of rig column names to FORMAT names")
        p.add_argument("--mode", default="auto", choices=["auto", "closed_loop", "open_loop"],
                       help="replay: closed loop under the run's controller (auto: when its JSON has one) or "
                            "open loop driven by the measured current")
        out_arg(p)

    p = add("identify", "fit parameters to rig runs; JSON, parameter TOML and HTML report", _cmd_identify)
    p.add_argument("runs", nargs="+", help="RUN.csv files (RUN.json beside each)")
    p.add_argument("--free", required=True, help="comma-separated parameters to fit, e.g. gear.viscous_friction")
    p.add_argument("--segment", type=float, default=0.05,
                   help="multiple-shooting segment length [s] (default 0.05: longer segments of a low-inertia drive "
                        "driven by the measured current drift off the data before the fit can pull them back)")
    p.add_argument("--substeps", type=int, default=4,
                   help="plant steps per sample period (default 4: at 1 kHz data, 1 step leaves a few %% bias)")
    p.add_argument("--global", dest="global_stage", action="store_true", help="differential evolution first")
    p.add_argument("--max-nfev", type=int, default=100, help="limit of residual evaluations (default 100); when "
                   "reached, the best result so far is written, flagged not converged")
    p.add_argument("--time-budget", type=float, default=180.0,
                   help="wall-time limit of the fit [s] (default 180); the best result is written when reached")
    p.add_argument("--prior-sd", type=float, help="regularise: Gaussian prior on each free parameter at its "
                   "parameter-file value, relative standard deviation (e.g. 0.3)")
    p.add_argument("--bounds", help="search bounds of this fit, SI, inside the physical ones: "
                   "NAME=LO:HI,... (default: the parameter file's min/max)")
    model_args(p)
    p = add("residual", "replay a run through a model; residual analysis JSON and HTML report", _cmd_residual)
    p.add_argument("run", help="RUN.csv (RUN.json beside it)")
    p.add_argument("--segment", help="open loop: restart the mechanics from the measured state every SEGMENT "
                   "seconds (default 0.05), so each residual is a one-segment prediction error and does not "
                   "drift; 'whole' (or 0): one replay over the whole run")
    p.add_argument("--remove", nargs="*", help="effects removed from the level (a plain screw drive: --model A "
                   "--remove noback_ideal)")
    model_args(p)
    p = add("report", "loop analysis of a design over speed, load and temperature: HTML + JSON", _cmd_report)
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
    p.add_argument("--check", action="store_true", help="exit with status 1 when a requirement is not met")
    out_arg(p)
    p = add("linearize", "print the linear model at one operating point (and save it)", _cmd_linearize)
    p.add_argument("--level", required=True, help="model level A, B, C or D")
    p.add_argument("--speed", type=float, required=True, help="trim nut speed [mm/s], positive extending")
    p.add_argument("--load", type=float, required=True, help="load [N], compressive positive (opposes extension)")
    p.add_argument("--temperature", type=float, default=25.0, help="temperature [degC], -55..70 (default 25)")
    p.add_argument("--effects", nargs="*", help="effects added to the level (default: temperature_friction standby_motor)")
    p.add_argument("--active", choices=["primary", "standby"], default="primary", help="energised motor channel")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--save", help="write the linear model to this .npz file")

    from .sweep.command import add_arguments as _sweep_arguments  # thsa sweep (issue #19)

    _sweep_arguments(add("sweep", "campaigns (Monte Carlo, grids, fault timings) on the local cores or a Dask "
                                  "cluster: Parquet table, HTML + JSON report", _cmd_sweep))

    # Subcommands of other packages register here: each module offers
    # add_parser(subparsers) and sets ``fn`` (e.g. ``from .tuning.cli import add_parser; add_parser(sub)``).
    from .faults.cli import add_parser as _add_faults  # thsa faults (issue #10)
    from .trace.cli import add_parser as _add_trace  # thsa trace (issue #11)

    _add_faults(sub)
    _add_trace(sub)
    from .tuning.cli import add_parsers as _tuning_parsers  # thsa tune, thsa check (issue #9)

    _tuning_parsers(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``thsa`` console script; returns the exit status.

    0 success, 1 requirement failed (``report --check``), 2 input or
    environment error (one line on stderr: bad input, disk full, permissions),
    3 internal error (one line; ``THSA_DEBUG=1`` shows the traceback).
    """
    import os

    argv = list(sys.argv[1:] if argv is None else argv)
    args = _parser().parse_args(argv)
    args.argv = argv
    try:
        return args.fn(args)
    except ThsaError as exc:
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    except OSError as exc:  # the environment, not a bug: disk full, permissions, a vanished file
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"error: {exc.strerror or exc}{where}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print("error: out of memory (a grid, run or period too large for this machine)", file=sys.stderr)
        return EXIT_USAGE
    except Exception as exc:  # a bug: never a traceback for the user, but say how to get it
        if os.environ.get("THSA_DEBUG"):
            raise
        print(f"internal error ({type(exc).__name__}): {_one_line(exc)}; this is a bug in thsa-control, "
              "rerun with THSA_DEBUG=1 for the traceback and report it", file=sys.stderr)
        return EXIT_INTERNAL


def _one_line(exc: BaseException) -> str:
    return str(exc).strip() or type(exc).__name__


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
