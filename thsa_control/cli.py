"""Command line of thsa-control: a thin argparse front end over the API.

Commands::

    thsa scenarios
    thsa levels    [--scenario NAME] [--levels A,B,C,D] [--effects E ...] [--design FILE]
                   [--params FILE] [--temperature T] --out DIR
    thsa simulate  --scenario NAME --level C [--effects E ...] [--design FILE] [--params FILE]
                   [--temperature T] [--output-period S] --out DIR
    thsa check-data RUN.csv

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
    from .design import load_design, nominal_design_path
    from .params import default_parameters, load_parameters
    from .scenarios import get_scenario

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
    from .scenarios import SCENARIOS

    for s in SCENARIOS.values():
        need = f" [needs {', '.join(s.required_effects)}]" if s.required_effects else ""
        print(f"{s.name:28s} {s.duration:5.1f} s  {s.temperature:5.1f} degC{need}\n    {s.description}")
    return 0


def _run_levels(params, design, scenario, levels, effects, output_period):
    from .model import build_plant
    from .simulate import SimulationSettings, Simulator

    settings = SimulationSettings(output_period=output_period)
    results = {}
    for level in levels:
        eff = list(effects) + [e for e in scenario.required_effects if e not in effects]
        plant = build_plant(level, eff, params=params)
        results[level] = Simulator(plant, settings).run(scenario, design, params)
    return results


def _summary(result) -> dict:
    from .metrics import backdrive_metrics, surface_speed_deviation

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
    from .export import write_simulation
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
    from .rigdata import format_summary, read_run, summarize_run

    mapping = json.loads(args.column_map) if args.column_map else None
    run = read_run(args.run, column_map=mapping)
    print(format_summary(summarize_run(run)))
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
    p.set_defaults(fn=_cmd_levels)
    p = sub.add_parser("simulate", help="simulate a scenario at one level, write the run (FORMAT.md) and plots")
    common(p, True)
    p.set_defaults(fn=_cmd_simulate)
    p = sub.add_parser("check-data", help="validate and summarise a rig run (FORMAT.md)")
    p.add_argument("run", help="RUN.csv (RUN.json beside it)")
    p.add_argument("--column-map", help='JSON mapping of rig column names to FORMAT names, e.g. \'{"t": "time_s"}\'')
    p.set_defaults(fn=_cmd_check_data)
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
