"""``thsa scenarios``, ``thsa levels`` and ``thsa simulate``: closed-loop runs of the named scenarios."""

from __future__ import annotations

from functools import partial

import sys
from pathlib import Path

from .common import (add_command, check_output_period, check_run_length, effects_arg, load_params_design, out_arg,
                     out_options, positive, preflight_out, progress_for)

__all__ = ["add_parsers", "cmd_scenarios", "cmd_levels", "cmd_simulate", "load_common", "run_levels"]


def load_common(args):
    from ..sim.scenarios import get_scenario

    params, design = load_params_design(args)
    scenario = get_scenario(args.scenario)
    if args.temperature is not None:
        scenario = scenario.with_temperature(args.temperature)
    positive(args.output_period, "--output-period")
    check_output_period(args.output_period, design.control_period)
    check_run_length(scenario.duration, design.control_period, f"scenario {scenario.name}")
    return params, design, scenario


def cmd_scenarios(args) -> int:
    from ..sim.scenarios import SCENARIOS

    for s in SCENARIOS.values():
        need = f" [needs {', '.join(s.required_effects)}]" if s.required_effects else ""
        print(f"{s.name:28s} {s.duration:5.1f} s  {s.temperature:5.1f} degC{need}\n    {s.description}")
    return 0


def run_levels(params, design, scenario, levels, effects, output_period, progress=None):
    from ..model import build_plant
    from ..sim.simulate import SimulationSettings, Simulator

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
    from ..sim.metrics import backdrive_metrics, surface_speed_deviation

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


def _write_results(args, results, scenario, params, design, progress=None):
    if progress is not None:
        progress.phase("loading the plotting library")
    from ..data.export import write_simulation
    from ..report import atomic_folder, write_json
    from ..report.plots import close, plot_levels, plot_run

    with atomic_folder(args.out, **out_options(args)) as tmp:
        summary = {"scenario": scenario.name, "description": scenario.description, "temperature_C": scenario.temperature,
                   "design": design.source, "levels": {}}
        for i, (level, res) in enumerate(results.items(), 1):
            if progress is not None:
                progress.phase(f"writing the run and plots of level {level} ({i}/{len(results)})")
            stem = tmp / f"{scenario.name}_{level}"
            write_simulation(res, stem, level=level)
            if getattr(args, "format", "csv") == "mat":  # MATLAB: load NAME.mat (SI, units beside)
                from ..data.matfile import simulation_to_mat, write_mat

                write_mat(stem.with_suffix(".mat"), simulation_to_mat(res, level=level,
                                                                     temperature_C=scenario.temperature))
            fig = plot_run(res, title=f"{scenario.name}, level {level} ({', '.join(res.effects) or 'functional'})")
            fig.savefig(stem.with_suffix(".png"), dpi=110)
            close(fig)
            if "trip_speed" in res.names:  # a run of the fault loop: torques, slip, sensor speeds, monitor flags
                from ..report.faults import plot_fault_run

                fig = plot_fault_run(res)
                fig.savefig(stem.with_name(stem.name + "_faults.png"), dpi=110)
                close(fig)
            summary["levels"][level] = _summary(res)
        if len(results) > 1:
            if progress is not None:
                progress.phase(f"plotting the {len(results)} levels side by side")
            fig = plot_levels(results)
            fig.savefig(tmp / f"{scenario.name}_levels.png", dpi=110)
            close(fig)
        params.save(tmp / "parameters.toml")
        write_json(tmp / "summary.json", summary)
    return summary


def cmd_levels(args) -> int:
    preflight_out(args)
    progress = progress_for(args, "thsa levels")
    params, design, scenario = load_common(args)
    levels = [lv.strip().upper() for lv in args.levels.split(",") if lv.strip()]
    results = run_levels(params, design, scenario, levels, effects_arg(args.effects), args.output_period, progress)
    summary = _write_results(args, results, scenario, params, design, progress)
    for level, s in summary["levels"].items():
        line = f"level {level}: {s['real_time_factor']:.0f}x real time, peak |I| {s['peak_abs_current_A']:.1f} A"
        if "backdrive" in s:
            b = s["backdrive"]
            line += (f", aiding/opposing |I| {b['aiding_to_opposing']:.2f}, breakaway/opposing {b['breakaway_to_opposing']:.2f}, "
                     f"trim-stop back-drive {max(b['stop_backdrive_peak_of_command']) * 100:.0f} % of command")
        print(line)
    if not getattr(args, "no_ranges", False):
        from ..sim.assumptions import assumption_ranges, format_ranges

        progress.phase("headline numbers over the ranges of the assumed values")
        ranges = assumption_ranges(design, params, output_period=args.output_period)
        print("headline numbers over the plausible range of the assumed values that set them:")
        print(format_ranges(ranges))
    progress.done()
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def cmd_simulate(args) -> int:
    preflight_out(args)
    params, design, scenario = load_common(args)
    from ..model import resolve_effects

    effects = effects_arg(args.effects)
    resolve_effects(args.level, add=effects)  # validate names before any work
    if args.temperature is not None and "temperature_friction" not in effects:
        print("note: --temperature changes nothing without --effects temperature_friction", file=sys.stderr)
    progress = progress_for(args, "thsa simulate")
    results = run_levels(params, design, scenario, [args.level.upper()], effects, args.output_period, progress)
    _write_results(args, results, scenario, params, design, progress)
    progress.done()
    res = results[args.level.upper()]
    print(f"{scenario.name} at level {args.level.upper()} ({', '.join(res.effects) or 'functional'}): "
          f"{res.time[-1]:.1f} s simulated in {res.info['wall_s'] * 1e3:.1f} ms")
    print(f"wrote {Path(args.out).resolve()}")
    return 0


def add_parsers(sub, shared) -> None:
    """``thsa scenarios``, ``thsa levels``, ``thsa simulate``."""
    add = partial(add_command, sub, shared)

    add("scenarios", "list the named scenarios", cmd_scenarios)

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
        p.add_argument("--format", choices=("csv", "mat"), default="csv",
                       help="csv: each run as a rig run (CSV + JSON, docs/rig_format.md); mat: also a MATLAB .mat "
                            "per run (SI, units beside; `load NAME.mat`)")
        out_arg(p)

    p = add("levels", "simulate a scenario at several levels side by side (the main job)", cmd_levels)
    common(p, False)
    p.add_argument("--levels", default="A,B,C,D")
    p.add_argument("--no-ranges", action="store_true",
                   help="skip the headline numbers over the ranges of the assumed values (thsa_control.sim.assumptions)")
    p = add("simulate", "simulate a scenario at one level, write the run (docs/rig_format.md) and plots", cmd_simulate)
    common(p, True)
