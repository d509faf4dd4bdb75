"""Command line of thsa-control: a thin argparse front end over the API.

Commands::

    thsa scenarios
    thsa levels    [--scenario NAME] [--levels A,B,C,D] [--effects E ...] [--design FILE]
                   [--params FILE] [--temperature T] --out DIR
    thsa simulate  --scenario NAME --level C [--effects E ...] [--design FILE] [--params FILE]
                   [--temperature T] [--output-period S] --out DIR
    thsa check-data RUN.csv
    thsa identify  RUN.csv [RUN2.csv ...] --model B --free PARAM,... [--effects E ...] [--params FILE] --out DIR
    thsa residual  RUN.csv --model A [--mode closed_loop|open_loop] [--effects E ...] [--params FILE] --out DIR
    thsa report    --design designs/nominal.toml --out DIR [--level B] [--effects E ...] [--params FILE]
                   [--no-switching] [--check]
    thsa linearize --level A --speed 5 --load 20000 --temperature -30 [--effects E ...] [--active standby]
                   [--params FILE] [--save FILE.npz]

Errors of the input (unknown scenario, level or effect, bad design or
parameter file, malformed run) print one message naming the culprit and exit
with status 2; nothing is written then.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .errors import ThsaError

__all__ = ["main"]


def _load_common(args):
    from .loops.design import load_design, nominal_design_path
    from .model.params import default_parameters, load_parameters
    from .sim.scenarios import get_scenario

    params = default_parameters()
    if args.params:
        params = load_parameters(args.params, base=params)
    design = load_design(args.design or nominal_design_path())
    design.check_against(params)
    scenario = get_scenario(args.scenario)
    if args.temperature is not None:
        scenario = scenario.with_temperature(args.temperature)
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


def _run_levels(params, design, scenario, levels, effects, output_period):
    from .model import build_plant
    from .sim.simulate import SimulationSettings, Simulator

    settings = SimulationSettings(output_period=output_period)
    results = {}
    for level in levels:
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


def _write_results(out, results, scenario, params, design):
    from .data.export import write_simulation
    from .report import atomic_folder, write_json
    from .report.plots import close, plot_levels, plot_run

    with atomic_folder(out) as tmp:
        summary = {"scenario": scenario.name, "description": scenario.description, "temperature_C": scenario.temperature,
                   "design": design.source, "levels": {}}
        for level, res in results.items():
            stem = tmp / f"{scenario.name}_{level}"
            write_simulation(res, stem, level=level)
            fig = plot_run(res, title=f"{scenario.name}, level {level} ({', '.join(res.effects) or 'functional'})")
            fig.savefig(stem.with_suffix(".png"), dpi=110)
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
    params, design, scenario = _load_common(args)
    levels = [lv.strip().upper() for lv in args.levels.split(",") if lv.strip()]
    results = _run_levels(params, design, scenario, levels, _effects_arg(args.effects), args.output_period)
    summary = _write_results(args.out, results, scenario, params, design)
    for level, s in summary["levels"].items():
        line = f"level {level}: {s['real_time_factor']:.0f}x real time, peak |I| {s['peak_abs_current_A']:.1f} A"
        if "backdrive" in s:
            b = s["backdrive"]
            line += (f", aiding/opposing |I| {b['aiding_to_opposing']:.2f}, breakaway/opposing {b['breakaway_to_opposing']:.2f}, "
                     f"trim-stop back-drive {max(b['stop_backdrive_peak_of_command']) * 100:.0f} % of command")
        print(line)
    if not getattr(args, "no_ranges", False):
        from .sim.assumptions import assumption_ranges, format_ranges

        print("headline numbers over the plausible range of the assumed values that set them:")
        print(format_ranges(assumption_ranges(design, params, output_period=args.output_period)))
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _cmd_simulate(args) -> int:
    params, design, scenario = _load_common(args)
    from .model import resolve_effects

    effects = _effects_arg(args.effects)
    resolve_effects(args.level, add=effects)  # validate names before any work
    if args.temperature is not None and "temperature_friction" not in effects:
        print("note: --temperature changes nothing without --effects temperature_friction", file=sys.stderr)
    results = _run_levels(params, design, scenario, [args.level.upper()], effects, args.output_period)
    _write_results(args.out, results, scenario, params, design)
    res = results[args.level.upper()]
    print(f"{scenario.name} at level {args.level.upper()} ({', '.join(res.effects) or 'functional'}): "
          f"{res.time[-1]:.1f} s simulated in {res.info['wall_s'] * 1e3:.1f} ms")
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _cmd_check_data(args) -> int:
    from .data.rigdata import read_run
    from .data.rigsummary import format_summary, summarize_run

    mapping = json.loads(args.column_map) if args.column_map else None
    run = read_run(args.run, column_map=mapping)
    print(format_summary(summarize_run(run)))
    return 0


def _read_runs(paths, column_map):
    from .data.rigdata import read_run

    mapping = json.loads(column_map) if column_map else None
    return [read_run(p, column_map=mapping) for p in paths]


def _replay_mode(run, mode):
    return mode if mode != "auto" else ("closed_loop" if run.controller is not None else "open_loop")


def _cmd_identify(args) -> int:
    from .fit.identify import IdentificationSettings, Identifier
    from .model.params import default_parameters, load_parameters
    from .fit.replay import analyse_replay, replay
    from .report import atomic_folder
    from .report.identification import write_identification_folder

    params = load_parameters(args.params, base=default_parameters()) if args.params else default_parameters()
    runs = _read_runs(args.runs, args.column_map)
    effects = _effects_arg(args.effects)
    free = [n.strip() for n in (args.free or "").split(",") if n.strip()]
    settings = IdentificationSettings(segment_duration=args.segment, substeps=args.substeps,
                                      global_stage=args.global_stage)
    result = Identifier(args.model, params, free, effects=effects, settings=settings).fit(runs)
    fitted = result.to_parameter_set()
    before, after, analyses = [], [], []
    for run in runs:
        mode = _replay_mode(run, args.mode)
        before.append(replay(run, args.model, effects, params=params, mode=mode))
        after.append(replay(run, args.model, effects, params=fitted, mode=mode))
        analyses.append(analyse_replay(run, after[-1]))
    with atomic_folder(args.out) as tmp:
        write_identification_folder(tmp, result, before, after, analyses)
    print(result.fit_report())
    for b, a in zip(before, after):
        print(f"{b.run_name} ({b.mode.replace('_', ' ')} replay): " + ", ".join(
            f"{c} fit {b.fits[c].fit_percent:.1f} -> {a.fits[c].fit_percent:.1f} %" for c in a.fits))
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _cmd_residual(args) -> int:
    from .model.params import default_parameters, load_parameters
    from .fit.replay import analyse_replay, replay
    from .report import atomic_folder
    from .report.identification import write_residual_folder
    from .fit.residuals import format_residual_report

    params = load_parameters(args.params, base=default_parameters()) if args.params else default_parameters()
    run, = _read_runs([args.run], args.column_map)
    result = replay(run, args.model, _effects_arg(args.effects), params=params, mode=_replay_mode(run, args.mode))
    analysis = analyse_replay(run, result)
    with atomic_folder(args.out) as tmp:
        write_residual_folder(tmp, result, analysis)
    print(format_residual_report(analysis))
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def _analysis_effects(args) -> list[str]:
    # the plant that exists: temperature_friction and the dragged standby rotor, unless --effects says otherwise
    from .loops.analysis import DEFAULT_ANALYSIS_EFFECTS

    return list(DEFAULT_ANALYSIS_EFFECTS) if args.effects is None else _effects_arg(args.effects)


def _cmd_report(args) -> int:
    from .loops.analysis import AnalysisSettings, analyse_design
    from .loops.design import load_design, nominal_design_path
    from .model import resolve_effects
    from .model.params import default_parameters, load_parameters
    from .report.analysis_report import write_analysis_report

    params = load_parameters(args.params, base=default_parameters()) if args.params else default_parameters()
    design = load_design(args.design or nominal_design_path())
    design.check_against(params)
    effects = _analysis_effects(args)
    resolve_effects(args.level, add=effects)  # validate names before any work
    settings = AnalysisSettings(level=args.level.upper(), effects=tuple(effects))
    result = analyse_design(design, params, settings=settings, switching=not args.no_switching)
    out = write_analysis_report(result, args.out)
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
    return 1 if args.check and not result.requirements.passed else 0


def _cmd_linearize(args) -> int:
    from .loops.linear import OperatingCondition, format_linear_model, linearize_condition, plant_model
    from .model import resolve_effects
    from .model.params import default_parameters, load_parameters

    params = load_parameters(args.params, base=default_parameters()) if args.params else default_parameters()
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


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="thsa", description="THSA control workbench")
    sub = ap.add_subparsers(dest="command", required=True)
    sub.add_parser("scenarios", help="list the named scenarios").set_defaults(fn=_cmd_scenarios)

    def common(p, level_arg: bool):
        p.add_argument("--scenario", default="backdrive_bipolar_ramp" if not level_arg else None, required=level_arg)
        if level_arg:
            p.add_argument("--level", required=True, help="A, B, C or D")
        p.add_argument("--effects", nargs="*", help="effects added to the level(s), e.g. temperature_friction standby_motor")
        p.add_argument("--design", help="design TOML (default designs/nominal.toml)")
        p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
        p.add_argument("--temperature", type=float, help="temperature [degC], -55..70")
        p.add_argument("--output-period", type=float, default=1e-3, help="output sample period [s] (default 1e-3)")
        p.add_argument("--out", required=True, help="output folder (replaced atomically)")

    p = sub.add_parser("levels", help="simulate a scenario at several levels side by side (the main job)")
    common(p, False)
    p.add_argument("--levels", default="A,B,C,D")
    p.add_argument("--no-ranges", action="store_true",
                   help="skip the headline numbers over the ranges of the assumed values (thsa_control.sim.assumptions)")
    p.set_defaults(fn=_cmd_levels)
    p = sub.add_parser("simulate", help="simulate a scenario at one level, write the run (FORMAT.md) and plots")
    common(p, True)
    p.set_defaults(fn=_cmd_simulate)
    p = sub.add_parser("check-data", help="validate and summarise a rig run (FORMAT.md)")
    p.add_argument("run", help="RUN.csv (RUN.json beside it)")
    p.add_argument("--column-map", help='JSON mapping of rig column names to FORMAT names, e.g. \'{"t": "time_s"}\'')
    p.set_defaults(fn=_cmd_check_data)

    def model_args(p):
        p.add_argument("--model", required=True, help="model level A, B, C or D")
        p.add_argument("--effects", nargs="*", help="effects added to the level")
        p.add_argument("--params", help="parameter TOML overriding the embedded actuator (initial values)")
        p.add_argument("--column-map", help="JSON mapping of rig column names to FORMAT names")
        p.add_argument("--mode", default="auto", choices=["auto", "closed_loop", "open_loop"],
                       help="replay: closed loop under the run's controller (auto: when its JSON has one) or "
                            "open loop driven by the measured current")
        p.add_argument("--out", required=True, help="output folder (replaced atomically)")

    p = sub.add_parser("identify", help="fit parameters to rig runs; JSON, parameter TOML and HTML report")
    p.add_argument("runs", nargs="+", help="RUN.csv files (RUN.json beside each)")
    p.add_argument("--free", required=True, help="comma-separated parameters to fit, e.g. gear.viscous_friction")
    p.add_argument("--segment", type=float, default=0.25, help="multiple-shooting segment length [s]")
    p.add_argument("--substeps", type=int, default=4,
                   help="plant steps per sample period (default 4: at 1 kHz data, 1 step leaves a few %% bias)")
    p.add_argument("--global", dest="global_stage", action="store_true", help="differential evolution first")
    model_args(p)
    p.set_defaults(fn=_cmd_identify)
    p = sub.add_parser("residual", help="replay a run through a model; residual analysis JSON and HTML report")
    p.add_argument("run", help="RUN.csv (RUN.json beside it)")
    model_args(p)
    p.set_defaults(fn=_cmd_residual)
    p = sub.add_parser("report", help="loop analysis of a design over speed, load and temperature: HTML + JSON")
    p.add_argument("--design", help="design TOML (default designs/nominal.toml)")
    p.add_argument("--level", default="B", help="model level A, B, C or D (default B)")
    p.add_argument("--effects", nargs="*", help="effects added to the level (default: temperature_friction standby_motor)")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--no-switching", action="store_true", help="skip the nonlinear switch-over transient")
    p.add_argument("--check", action="store_true", help="exit with status 1 when a requirement is not met")
    p.add_argument("--out", required=True, help="output folder (replaced atomically)")
    p.set_defaults(fn=_cmd_report)
    p = sub.add_parser("linearize", help="print the linear model at one operating point (and save it)")
    p.add_argument("--level", required=True, help="model level A, B, C or D")
    p.add_argument("--speed", type=float, required=True, help="trim nut speed [mm/s], positive extending")
    p.add_argument("--load", type=float, required=True, help="load [N], compressive positive (opposes extension)")
    p.add_argument("--temperature", type=float, default=25.0, help="temperature [degC], -55..70 (default 25)")
    p.add_argument("--effects", nargs="*", help="effects added to the level (default: temperature_friction standby_motor)")
    p.add_argument("--active", choices=["primary", "standby"], default="primary", help="energised motor channel")
    p.add_argument("--params", help="parameter TOML overriding the embedded actuator")
    p.add_argument("--save", help="write the linear model to this .npz file")
    p.set_defaults(fn=_cmd_linearize)
    from .tuning.cli import add_parsers as _tuning_parsers  # thsa tune, thsa check
    _tuning_parsers(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``thsa`` console script; returns the exit status."""
    args = _parser().parse_args(argv)
    try:
        return args.fn(args)
    except ThsaError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
