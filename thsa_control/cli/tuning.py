"""Command line of the tuning package: ``thsa tune`` and ``thsa check``.

::

    thsa tune  --design designs/nominal.toml --scenario cold_ramp [--scenario low_speed ...]
               --temperature -30 [--robust-temperatures -55,-30,25,70] [--level B] [--effects E ...]
               [--require min_phase_margin_deg=50 ...] --out designs/NAME.toml
    thsa check --design FILE [--levels A,B,C,D] [--temperatures -55,-30,25,70] [--scenarios a,b]
               [--runs RUN.csv ...] [--out DIR]

``tune`` prints its progress on stderr, the before/after numbers on stdout,
and exits 1 (one message, no traceback) when IPOPT does not converge or a
requirement cannot be met (naming it, writing nothing); ``check`` prints one row per requirement
(:mod:`thsa_control.verdict`: worst point, value, limit, pass/fail) and exits 1 when one is not met
or could not be judged.
"""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import DesignError, SolverError

__all__ = ["add_parsers", "tune_command", "check_command", "provenance", "report_verdict"]


def _floats(text: str, what: str) -> tuple[float, ...]:
    try:
        return tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise DesignError(what, f"{text!r} is not a comma-separated list of numbers") from None


def _common(args):
    from .common import load_params_design

    return load_params_design(args)


def provenance(result, scenarios, design_path: str, metrics_before: dict | None = None,
               metrics_after: dict | None = None) -> dict:
    """The ``[tuning]`` table of a tuned design: objective, runs, solver statistics, before/after numbers.

    ``metrics_before``/``metrics_after``: run name -> :class:`~.validation.RunMetrics` of the source
    and tuned designs at the tuning temperature and level.
    """
    from ..tuning.check import PROVENANCE_MARKER
    from ..tuning.optimize import linear_temperatures
    from ..tuning.validation import COST_TERMS

    s = result.settings
    best = result.best

    def margins(ms):
        return [{"temperature_C": m.temperature, "phase_margin_deg": round(m.phase_margin_deg, 3),
                 "gain_margin_db": round(m.gain_margin_db, 3), "sensitivity_peak": round(m.ms, 4),
                 "worst_point": m.phase_margin_at} for m in ms]

    return {
        "written_by": PROVENANCE_MARKER,
        "source_design": design_path,
        "objective": ("sum over runs of ISE [(mm/s)^2 s] + current_weight * int i^2 dt + rate_weight * "
                      "int (di/dt / 1 kA/s)^2 dt; closed-loop nonlinear runs, gradient by casadi forward "
                      "sensitivities through the simulator's step"),
        "current_weight": s.objective.current_weight,
        "rate_weight": s.objective.rate_weight,
        "scenarios": [sc for sc in scenarios],
        "temperature_C": s.temperature,
        "robust_temperatures_C": list(s.robust_temperatures),
        "level": s.level,
        "effects": list(s.effects),
        "tuned": list(result.tuned),
        "bound_factor": s.bound_factor,
        "constraints": ("int (|i| - %g x clamp)+^2 dt <= %g A^2 s and int (overshoot above %g %%)+^2 dt <= %g "
                        "(mm/s)^2 s on the objective's runs and on the constraint runs (the validation suite at "
                        "level %s at the coldest check temperature, plus every run the verdict failed "
                        "on); every [requirements.velocity_loop] key the grid analysis judges (phase, |gain|, "
                        "delay margins, Ms, bandwidth; step overshoot and settling) at every valid point of the "
                        "design's analysis grid at %s degC (two-rotor plant, computation delay), smooth; then "
                        "the verdict of thsa check on every requirement, failing runs added and failing linear "
                        "constraints tightened until it passes"
                        % (s.objective.current_fraction, s.excess_tolerance, 100 * s.objective.overshoot_limit,
                           s.excess_tolerance, s.constraint_level,
                           ", ".join(f"{t:g}" for t in linear_temperatures(result.source, s)))),
        "verdict": "PASS" if result.verdict is not None and result.verdict.passed else "FAIL",
        "rounds": [{"round": r["round"], "gains": r["gains"],
                    "constraint_runs": [f"{lv} {T:g} degC {n}" for lv, T, n in r["constraint_runs"]],
                    "failing": r["failing"], "excess_tolerance": r["excess_tolerance"]} for r in result.rounds],
        "solver": "ipopt via casadi nlpsol, limited-memory Hessian",
        "status": best.status,
        "iterations": best.iterations,
        "best_start": best.start,
        "wall_s": round(result.wall_s, 2),
        "objective_before": result.objective_before,
        "objective_after": result.objective_after,
        "reduction_percent": round(100 * result.reduction, 2),
        "starts": [{"start": r.start, "status": r.status, "iterations": r.iterations, "wall_s": round(r.wall_s, 2),
                    "relative_objective": r.objective, "initial_gains": list(r.initial_gains),
                    "gains": list(r.gains), "worst_constraint": r.worst_constraint,
                    "worst_constraint_value": r.constraint_min} for r in result.starts],
        "gains_before": [float(getattr(result.source, n)) for n in result.tuned],
        "gains_after": [float(getattr(result.design, n)) for n in result.tuned],
        "terms": list(COST_TERMS),
        "runs": list(result.run_names),
        "terms_before": [list(map(float, row)) for row in result.terms_before],
        "terms_after": [list(map(float, row)) for row in result.terms_after],
        "margins_before": margins(result.margins_before),
        "margins_after": margins(result.margins_after),
        "metrics_before": {k: m.as_dict() for k, m in (metrics_before or {}).items()},
        "metrics_after": {k: m.as_dict() for k, m in (metrics_after or {}).items()},
    }


def tune_command(args) -> int:
    """``thsa tune``: optimise, check, write the design with its provenance."""
    from dataclasses import replace

    from ..tuning.validation import DEFAULT_VALIDATION_REQUIREMENTS, get_validation_scenario

    names = args.scenario or ["cold_ramp"]
    scenarios = [get_validation_scenario(n) for n in names]  # a bad name fails before the heavy imports
    from .common import progress_for

    progress = progress_for(args, "thsa tune")
    progress.phase("loading the model and the optimiser")
    with progress.heartbeat():
        from ..tuning.check import PROVENANCE_MARKER, write_design
        from ..tuning.optimize import TuneSettings, objective_settings_for, tune

        params, design = _common(args)
    out = Path(args.out)
    if out.exists():  # refuse early, before any work
        import tomllib

        try:
            doc = tomllib.loads(out.read_text(encoding="utf-8"))
        except (OSError, tomllib.TOMLDecodeError):
            doc = {}
        if doc.get("tuning", {}).get("written_by") != PROVENANCE_MARKER:
            raise DesignError(str(out), "exists and was not written by 'thsa tune' (no [tuning] provenance "
                                        "marker): refusing to overwrite it; choose another --out")
    req = dict(design.requirements.get("velocity_loop", {}))
    for item in args.require or []:
        key, _, value = item.partition("=")
        try:
            req[key.strip()] = float(value)
        except ValueError:
            raise DesignError("--require", f"{item!r} is not KEY=VALUE with a number") from None
    requirements = dict(design.requirements)
    requirements["velocity_loop"] = req
    from ..verdict import validate_requirements

    validate_requirements(requirements, "--require")
    source = replace(design, requirements=requirements)
    from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS

    effects = tuple(e for v in (args.effects or DEFAULT_ANALYSIS_EFFECTS) for e in v.split(",") if e)
    settings = TuneSettings(
        temperature=args.temperature, robust_temperatures=_floats(args.robust_temperatures, "--robust-temperatures"),
        level=args.level, effects=effects, bound_factor=args.bound_factor, max_iter=args.max_iter,
        objective=objective_settings_for(design, current_weight=args.current_weight, rate_weight=args.rate_weight),
        progress=progress if progress.enabled else False)
    try:
        with progress.heartbeat():
            result = tune(source, params, scenarios, settings)
    except SolverError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    validation = dict(DEFAULT_VALIDATION_REQUIREMENTS)
    validation["max_current_peak_A"] = design.current_limit
    validation.update(design.validation)
    from ..tuning.check import suite_metrics

    progress.phase("validation runs before and after")
    before = suite_metrics(source, params, settings.level, settings.temperature, scenarios=names, effects=effects)
    after = suite_metrics(result.design, params, settings.level, settings.temperature, scenarios=names,
                          effects=effects)
    prov = provenance(result, names, str(args.design or "designs/nominal.toml"), before, after)
    robust_report = None
    if not args.no_robustness:
        from ..tuning.robust import robustness_spread

        progress.phase("robustness beyond the grid (friction, inertia, stiffness, delay spread)")
        with progress.heartbeat():
            robust_report = robustness_spread(source, result.design, params, temperature=settings.temperature,
                                              scenario=names[0], level=settings.level, effects=effects)
        prov["robustness"] = robust_report.as_dict()
    progress.done()
    tuned = replace(result.design, name=out.stem, source=str(out),
                    description=(f"velocity loop tuned by thsa tune for {', '.join(names)} at {args.temperature:g} degC, "
                                 f"margins kept at {args.robust_temperatures} degC (from {design.name})"),
                    validation=validation, tuning=prov, derivation={})  # the source's bandwidths no longer hold
    write_design(tuned, out)
    print(f"tuned {', '.join(result.tuned)}: "
          + ", ".join(f"{n} {getattr(design, n):.5g} -> {getattr(tuned, n):.5g}" for n in result.tuned))
    print(f"objective {result.objective_before:.6g} -> {result.objective_after:.6g} "
          f"({100 * result.reduction:.1f} % lower); {result.best.status}, {result.best.iterations} iterations, "
          f"{result.wall_s:.1f} s")
    for r in result.starts:
        print(f"  start {r.start}: {r.status}, {r.iterations} it, J/J0 = {r.objective:.6g}, gains "
              + ", ".join(f"{v:.5g}" for v in r.gains))
    for name, b, a in zip(result.run_names, result.terms_before, result.terms_after):
        print(f"  {name}: ISE {b[0]:.4g} -> {a[0]:.4g} (mm/s)^2 s, int (di/dt)^2 {b[2]:.4g} -> {a[2]:.4g}")
    for name in names:
        b, a = before[name], after[name]
        print(f"  {name}: speed error {b.speed_error_percent:.3g} -> {a.speed_error_percent:.3g} %, overshoot "
              f"{b.overshoot_percent:.3g} -> {a.overshoot_percent:.3g} %, settling {b.settling_time_s:.3g} -> "
              f"{a.settling_time_s:.3g} s, current peak {b.current_peak_A:.3g} -> {a.current_peak_A:.3g} A")
    for mb, ma in zip(result.margins_before, result.margins_after):
        print(f"  {ma.temperature:6.1f} degC: PM {mb.phase_margin_deg:.1f} -> {ma.phase_margin_deg:.1f} deg, "
              f"GM {mb.gain_margin_db:.1f} -> {ma.gain_margin_db:.1f} dB, Ms {mb.ms:.3f} -> {ma.ms:.3f}")
    print(f"every requirement met (the verdict of thsa check, {len(result.verdict.rows)} requirements, "
          f"{len(result.rounds)} round(s)):")
    print("\n".join("  " + r.text() for r in result.verdict.rows))
    if robust_report is not None:
        print(robust_report.text())
    print(f"wrote {out}")
    return 0


def check_command(args) -> int:
    """``thsa check``: every requirement of the design (linear grid + validation runs [+ measured runs]);
    exit 1 when one is not met or could not be judged."""
    from dataclasses import replace

    from ..tuning.validation import VALIDATION_SUITE, get_validation_scenario

    temps = _floats(args.temperatures, "--temperatures")
    scen = tuple(v.strip() for v in args.scenarios.split(",")) if args.scenarios else VALIDATION_SUITE
    for name in scen:
        get_validation_scenario(name)  # a bad name fails before the heavy imports
    from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS
    from ..report.build import check_output_folder
    from ..tuning.check import check_design

    params, design = _common(args)
    inputs = [design.source] + [str(p) for p in (args.runs or [])] + [
        str(Path(p).with_suffix(".json")) for p in (args.runs or [])]
    if args.out:
        check_output_folder(args.out, force=args.force, inputs=inputs)  # refuse early, before any work
    levels = tuple(v.strip().upper() for v in args.levels.split(",") if v.strip())
    effects = tuple(e for v in (args.effects or DEFAULT_ANALYSIS_EFFECTS) for e in v.split(",") if e)
    from .common import progress_for

    progress = progress_for(args, "thsa check")
    say = progress.phase
    measured, mrows = (), []
    if args.runs:  # first: an unreadable run is bad input (exit 2) before any simulation
        from ..tuning.measured import judge_runs

        say(f"{len(args.runs)} measured run(s) against the validation limits, beside the model's prediction")
        with progress.heartbeat():
            mrows, measured = judge_runs(design, params, args.runs, level=args.run_level, effects=effects)
    with progress.heartbeat():
        verdict = check_design(design, params, levels=levels, temperatures=temps, scenarios=scen, effects=effects,
                               progress=lambda m: say(m.removeprefix("check: ").removesuffix(" ...")))
    progress.done()
    if args.runs:
        verdict = replace(verdict, rows=verdict.rows + tuple(mrows),
                          scope=verdict.scope | {"measured": [str(p) for p in args.runs]})
    print(f"design {design.source} ({design.name})")
    print(verdict.text())
    for m in measured:
        p = m.predicted
        print(f"  run {m.name} ({m.temperature:.3g} degC): speed error {m.measured.speed_error_percent:.3g} % "
              f"(model {p.speed_error_percent:.3g} %), ISE {m.measured.ise:.4g} (model {p.ise:.4g}) (mm/s)^2 s, "
              f"current peak {m.measured.current_peak_A:.3g} A (model {p.current_peak_A:.3g} A), oscillation "
              f"{m.oscillation_percent:.3g} % (model {m.predicted_oscillation_percent:.3g} %)" if p is not None else
              f"  run {m.name}: model prediction failed: {m.prediction_error}")
    if args.out:
        from ..report.check_report import write_check_report

        out = write_check_report(verdict, args.out, measured=measured, force=args.force, inputs=inputs)
        print(f"wrote {out / 'check.json'} and {out / 'check.html'}")
    return 0 if verdict.passed else 1


def report_verdict(result, params):
    """The verdict of ``thsa check`` for ``thsa report --check``: the report's grid analysis (its linear
    requirements) and the validation runs at the check's default levels and temperatures."""
    from ..tuning.check import check_design

    return check_design(result.design, params, analysis=result.loops, effects=result.settings.effects)


def add_parsers(sub) -> None:
    """Add ``tune`` and ``check`` to the ``thsa`` subcommands."""
    p = sub.add_parser("tune", help="optimise the velocity-loop gains on nonlinear validation runs (IPOPT)")
    p.add_argument("--design", help="source design TOML (default designs/nominal.toml)")
    p.add_argument("--scenario", action="append", help="run of the objective (repeatable; default cold_ramp)")
    p.add_argument("--temperature", type=float, default=-30.0, help="temperature of the runs [degC] (default -30)")
    p.add_argument("--robust-temperatures", default="-55,-30,25,70", help="margin constraints at these [degC]")
    p.add_argument("--level", default="B", help="model level (default B)")
    p.add_argument("--effects", nargs="*", help="effects added (default temperature_friction standby_motor)")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--require", action="append",
                   help="override a velocity-loop requirement, e.g. min_phase_margin_deg=50 (repeatable)")
    p.add_argument("--current-weight", type=float, default=1e-6, help="weight of int i^2 dt")
    p.add_argument("--rate-weight", type=float, default=0.05, help="weight of int (di/dt / 1 kA/s)^2 dt")
    p.add_argument("--bound-factor", type=float, default=10.0, help="gains stay within this factor of the source")
    p.add_argument("--max-iter", type=int, default=60, help="IPOPT iteration limit (no wall-clock limit)")
    p.add_argument("--no-robustness", action="store_true",
                   help="skip the side-by-side under friction/inertia/stiffness/delay spread")
    p.add_argument("--out", required=True, help="design TOML to write (only replaces a file thsa tune wrote)")
    p.set_defaults(fn=tune_command)
    p = sub.add_parser("check", help="validation suite in nonlinear simulation at every level and temperature")
    p.add_argument("--design", help="design TOML (default designs/nominal.toml)")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--levels", default="A,B,C,D")
    p.add_argument("--temperatures", default="-55,-30,25,70", help="[degC], e.g. --temperatures=-55,25 (with =)")
    p.add_argument("--scenarios", help="comma-separated runs (default: the validation suite)")
    p.add_argument("--effects", nargs="*", help="effects added (default temperature_friction standby_motor)")
    p.add_argument("--runs", nargs="+", help="measured runs RUN.csv (RUN.json beside) recorded with this design: "
                                             "judged against the validation limits, beside the model's prediction")
    p.add_argument("--run-level", default="B", help="model level of the prediction beside measured runs (default B)")
    p.add_argument("--out", help="folder for check.json and check.html")
    p.add_argument("--force", action="store_true", help="replace a non-empty --out folder not written by thsa")
    p.set_defaults(fn=check_command)
