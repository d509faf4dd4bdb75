"""``thsa check-data``, ``thsa identify`` and ``thsa residual``: measured rig runs against the model."""

from __future__ import annotations

from functools import partial

import sys
from pathlib import Path

from ..errors import UsageError
from .common import (add_command, bounds_arg, effects_arg, load_params, out_arg, out_options, parse_column_map,
                     positive, preflight_out, progress_for, read_runs, replay_mode, run_inputs)

__all__ = ["add_parsers", "cmd_check_data", "cmd_identify", "cmd_residual"]


def cmd_check_data(args) -> int:
    from ..data.rigdata import read_run
    from ..data.rigsummary import format_summary, summarize_run

    run = read_run(args.run, column_map=parse_column_map(args.column_map))
    print(format_summary(summarize_run(run)))
    return 0


def cmd_identify(args) -> int:
    from ..fit.identify import IdentificationSettings, Identifier
    from ..fit.replay import analyse_replay, replay
    from ..report import atomic_folder
    from ..report.identification import write_identification_folder

    positive(args.segment, "--segment")
    positive(args.substeps, "--substeps", integer=True)
    preflight_out(args, run_inputs(args.runs))
    progress = progress_for(args, "thsa identify")
    params = load_params(args)
    progress.phase(f"reading {len(args.runs)} run(s)")
    runs = read_runs(args.runs, args.column_map, params)
    effects = effects_arg(args.effects)
    free = [n.strip() for n in (args.free or "").split(",") if n.strip()]
    from ..trace.threads import limit_blas_threads

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
                        bounds=bounds_arg(args.bounds)).fit(
        runs, progress=progress.fit_callback())
    fitted = result.to_parameter_set()
    before, after, analyses = [], [], []
    for i, run in enumerate(runs, 1):
        progress.phase(f"replaying {run.name} before and after ({i}/{len(runs)})")
        mode = replay_mode(run, args.mode)
        before.append(replay(run, args.model, effects, params=params, mode=mode))
        after.append(replay(run, args.model, effects, params=fitted, mode=mode))
        analyses.append(analyse_replay(run, after[-1]))
    progress.phase("writing the report")
    with atomic_folder(args.out, **out_options(args, run_inputs(args.runs))) as tmp:
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


def cmd_residual(args) -> int:
    from ..fit.replay import analyse_replay
    from ..fit.residuals import format_residual_report
    from ..fit.segmented import parse_segment, replay_for_residual
    from ..model import build_plant
    from ..report import atomic_folder
    from ..report.identification import write_residual_folder

    segment = parse_segment(args.segment)
    preflight_out(args, run_inputs([args.run]))
    progress = progress_for(args, "thsa residual")
    params = load_params(args)
    progress.phase("reading the run")
    run, = read_runs([args.run], args.column_map, params)
    mode = replay_mode(run, args.mode)
    if args.segment is not None and mode != "open_loop":
        raise UsageError(f"--segment {args.segment}: segments apply to the open-loop replay (--mode open_loop); "
                         f"run {run.name!r} replays in closed loop under its controller")
    plant = build_plant(args.model, effects_arg(args.effects), remove=effects_arg(args.remove), params=params)
    progress.phase(f"replaying {run.name} through level {args.model}")
    result = replay_for_residual(run, plant, params, mode, segment_duration=segment)
    progress.phase("residual analysis")
    analysis = analyse_replay(run, result)
    progress.phase("writing the report")
    with atomic_folder(args.out, **out_options(args, run_inputs([args.run]))) as tmp:
        write_residual_folder(tmp, result, analysis)
    progress.done()
    print(format_residual_report(analysis))
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def add_parsers(sub, shared) -> None:
    """``thsa check-data``, ``thsa identify``, ``thsa residual``."""
    add = partial(add_command, sub, shared)

    p = add("check-data", "validate and summarise a rig run (format: docs/rig_format.md)", cmd_check_data)
    p.add_argument("run", help="RUN.csv (RUN.json beside it; format: docs/rig_format.md)")
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

    p = add("identify", "fit parameters to rig runs; JSON, parameter TOML and HTML report", cmd_identify)
    p.add_argument("runs", nargs="+", help="RUN.csv files (RUN.json beside each; format: docs/rig_format.md)")
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
    p = add("residual", "replay a run through a model; residual analysis JSON and HTML report", cmd_residual)
    p.add_argument("run", help="RUN.csv (RUN.json beside it; format: docs/rig_format.md)")
    p.add_argument("--segment", help="open loop: restart the mechanics from the measured state every SEGMENT "
                   "seconds (default 0.05), so each residual is a one-segment prediction error and does not "
                   "drift; 'whole' (or 0): one replay over the whole run")
    p.add_argument("--remove", nargs="*", help="effects removed from the level (a plain screw drive: --model A "
                   "--remove noback_ideal)")
    model_args(p)
