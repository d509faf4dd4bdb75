"""``thsa trace RUN.csv [RUN2.csv ...] --model A --out DIR``: parser and handler."""

from __future__ import annotations

from pathlib import Path

__all__ = ["add_parser", "run"]


def add_parser(subparsers) -> None:
    """Register the ``trace`` subcommand."""
    p = subparsers.add_parser("trace", help="trace a residual to the effect the model lacks (forward selection "
                                            "over the effect library); trace.json and HTML report")
    p.add_argument("runs", nargs="+", help="RUN.csv files (RUN.json beside each; format: docs/rig_format.md)")
    p.add_argument("--model", required=True, help="declared model level A, B, C or D")
    p.add_argument("--effects", nargs="*", help="effects the model declares beyond the level")
    p.add_argument("--remove", nargs="*", help="effects removed from the level (a plain screw drive: --model A "
                   "--remove noback_ideal)")
    p.add_argument("--params", nargs="+", help="parameter TOML file(s) over the embedded actuator, merged in order")
    p.add_argument("--free", help="comma-separated declared parameters to fit (default: the level's uncertain set)")
    p.add_argument("--candidates", help="comma-separated candidate effects (default: every library effect not declared)")
    p.add_argument("--segment", type=float, default=0.05, help="multiple-shooting segment length [s] (default 0.05)")
    p.add_argument("--max-effects", type=int, default=3,
                   help="stop after adding this many found effects (a declared component detailed in the base step, "
                        "what the base contains, is not counted)")
    p.add_argument("--max-nfev", type=int, default=40, help="evaluation limit of each fit")
    p.add_argument("--base-corrections", choices=("auto", "on", "off"), default="auto",
                   help="fit the base-correction step first (Coulomb drag, direction drag, axial force, screw "
                        "efficiencies, motor-side inertia within plausible magnitudes; reported as base corrections, not effects). "
                        "auto: on with the default candidates, off with --candidates")
    p.add_argument("--workers", type=int, default=2, help="parallel candidate fits (default 2)")
    p.add_argument("--substeps", type=int, default=1, help="plant steps per sample period of the fits (default 1; "
                   "a speed sensor's difference interval shorter than a sample needs more)")
    p.add_argument("--holdout-layout", choices=("every-kth", "dithered"), default="every-kth",
                   help="where in each block of three the held-out segment lies: the last (default) or a place drawn "
                        "from a fixed seed, for a record whose test profile repeats every multiple of three segments "
                        "(every third would hide the same phase of each repeat; trace.json's every_segment check "
                        "says where that changed an estimate)")
    p.add_argument("--final-values", choices=("every-segment", "training"), default="every-segment",
                   help="what estimates the final model's values once the held-out segments decided its effects: a "
                        "fit on every segment, the held-out ones too (default; kept only where it converged and fits "
                        "every sample at least as well), or the search's last fit on the training segments")
    p.add_argument("--speed-sensors", help="how the speed sensors read, over the run JSON's declaration: "
                   "comma-separated CHANNEL=INTERVAL, CHANNEL motor_speed or screw_speed, INTERVAL a difference "
                   "interval in seconds, 'sample' (one logged sample) or 'instantaneous' (e.g. "
                   "motor_speed=0.001,screw_speed=sample); default: each run JSON's speed_sensors, else its "
                   "sensors text (reported as a fallback), else instantaneous")
    p.add_argument("--channel-weights", choices=("sensor-noise", "base-residual"), default="sensor-noise",
                   help="what each channel is weighted by in the fits and scores: its sensor noise (default) or the "
                        "larger of that and the declared model's residual RMS on it (a channel the base leaves "
                        "far above its noise then does not pull the candidates' parameters)")
    p.add_argument("--robust-test", choices=("signed-rank", "sign"), default="signed-rank",
                   help="the one-sided test over the held-out segments that a constant-torque candidate beyond its "
                        "base correction must pass (its drop carried by the window, not by a few segments): the "
                        "Wilcoxon signed-rank test (default) or the sign test, which counts a segment the candidate "
                        "hardly changes as a full vote")
    p.add_argument("--no-rig-hardware", action="store_true",
                   help="do not complete the declared model from the runs' rig description (by default a JSON "
                        "rig.motors = 2 adds standby_motor: the second rotor carried along)")
    p.add_argument("--column-map", help="JSON mapping of rig column names to FORMAT names")
    p.add_argument("--quiet", action="store_true", help="no progress on stderr")
    p.add_argument("--out", required=True,
                   help="output folder: new, empty, or written by thsa before (then replaced atomically)")
    p.add_argument("--force", action="store_true",
                   help="also replace a folder not written by thsa (never one holding an input file)")
    p.set_defaults(fn=run)


def run(args) -> int:
    """Handler of ``thsa trace``."""
    import json

    from ..report.build import check_output_folder
    from .common import progress_for

    inputs = [q for r in args.runs for q in (Path(r), Path(r).with_suffix(".json"))] + list(args.params or ())
    out_opts = {"force": bool(args.force), "inputs": inputs}
    check_output_folder(args.out, **out_opts)  # refuse a foreign output folder before the long computation
    progress = progress_for(args, "thsa trace")
    progress.phase(f"loading the model and reading {len(args.runs)} run(s)")
    with progress.heartbeat():
        from ..data.rigdata import read_run
        from ..model.params import default_parameters, load_parameters
        from ..report import atomic_folder
        from ..report.trace import format_trace_summary, write_trace_folder
        from ..trace.engine import TraceSettings, trace
    params = load_parameters(args.params, base=default_parameters()) if args.params else default_parameters()
    mapping = json.loads(args.column_map) if args.column_map else None
    from ..fit.kinematics import run_kinematics

    kin = (params.value("screw.lead") * 1e3, params.value("gear.ratio"))  # where a run states none
    runs = [run_kinematics(read_run(p, column_map=mapping, default_kinematics=kin), params) for p in args.runs]
    split = lambda s: tuple(x.strip() for x in s.split(",") if x.strip()) if s else None  # noqa: E731
    try:
        sensors = None
        if args.speed_sensors:
            sensors = {}
            for item in split(args.speed_sensors):
                k, sep, v = item.partition("=")
                if not sep:
                    raise ValueError(f"--speed-sensors {item!r}: give CHANNEL=INTERVAL")
                sensors[k.strip()] = v.strip()
        settings = TraceSettings(segment_duration=args.segment, max_effects=args.max_effects, max_nfev=args.max_nfev,
                                 workers=args.workers, substeps=args.substeps, speed_sensors=sensors,
                                 holdout_layout=args.holdout_layout.replace("-", "_"),
                                 final_on_every_segment=args.final_values == "every-segment",
                                 channel_weights=args.channel_weights.replace("-", "_"), robust_test=args.robust_test,
                                 base_corrections={"auto": None, "on": True, "off": False}[args.base_corrections], rig_hardware=not args.no_rig_hardware, uncertain=split(args.free), candidates=split(args.candidates))
        settings.validate()
    except ValueError as exc:
        from ..errors import ThsaError

        raise ThsaError(str(exc)) from None
    with progress.heartbeat():
        result = trace(runs, args.model, args.effects or (), remove=args.remove or (), params=params,
                       settings=settings, progress=progress if progress.enabled else None)
    progress.phase("writing the trace folder")
    with atomic_folder(args.out, **out_opts, command=" ".join(["thsa", *getattr(args, "argv", [])])) as tmp:
        write_trace_folder(tmp, result)
    progress.done()
    print(format_trace_summary(result.to_dict()))
    print(f"wrote {Path(args.out).resolve()}")
    return 0
