"""What every ``thsa`` command shares: exit codes, output-folder options and preflight, the loaders
of parameters, designs and rig runs, and the small option parsers.

Imports only the standard library at import time (``thsa --help`` stays instant); each helper imports
the numerics it needs when called.  No module outside ``thsa_control.cli`` imports this package.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..errors import ThsaError, UsageError

__all__ = ["EXIT_OK", "EXIT_REQUIREMENT_FAILED", "EXIT_USAGE", "EXIT_INTERNAL", "MAX_CONTROL_PERIODS",
           "progress_for", "out_options", "add_command", "out_arg", "preflight_out", "positive", "check_output_period",
           "check_run_length", "load_params_design", "effects_arg", "parse_column_map", "read_runs", "run_inputs",
           "load_params", "replay_mode", "bounds_arg", "scaled_floats", "analysis_effects"]

EXIT_OK = 0
EXIT_REQUIREMENT_FAILED = 1
EXIT_USAGE = 2
EXIT_INTERNAL = 3
MAX_CONTROL_PERIODS = 20_000_000


def progress_for(args, label: str):
    from ..progress import Progress

    return Progress(label, enabled=not getattr(args, "quiet", False))


def out_options(args, inputs=()) -> dict:
    """Keyword arguments of ``atomic_folder`` from ``--out``/``--force`` and the command's input files."""
    params = getattr(args, "params", None)  # one file, or a list (--params takes several)
    extra = [*(params if isinstance(params, (list, tuple)) else [params]), getattr(args, "design", None)]
    return {"force": bool(getattr(args, "force", False)), "inputs": [p for p in (*inputs, *extra) if p],
            "command": " ".join(["thsa", *getattr(args, "argv", [])])}


def add_command(sub, shared, name: str, help: str, fn):
    """Add subcommand ``name`` (with the shared options) whose handler is ``fn``; returns its parser."""
    p = sub.add_parser(name, help=help, parents=[shared])
    p.set_defaults(fn=fn)
    return p


def out_arg(p) -> None:
    """``--out`` and ``--force`` of a command that writes a folder."""
    p.add_argument("--out", required=True,
                   help="output folder: new, empty, or written by thsa before (then replaced atomically)")
    p.add_argument("--force", action="store_true",
                   help="also replace a folder not written by thsa (never one holding an input file)")


def preflight_out(args, inputs=()) -> None:
    """Refuse an output folder before any long computation."""
    from ..report.build import check_output_folder

    opts = out_options(args, inputs)
    check_output_folder(args.out, force=opts["force"], inputs=opts["inputs"])


def positive(value, option: str, *, integer: bool = False):
    import math

    if value is None:
        return value
    if integer and not (isinstance(value, int) and value >= 1):
        raise UsageError(f"{option} {value!r}: must be an integer >= 1")
    if not integer and not (math.isfinite(value) and value > 0):
        raise UsageError(f"{option} {value!r}: must be a positive number")
    return value


def check_output_period(output_period: float, control_period: float) -> None:
    ratio = output_period / control_period
    if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6 * ratio:
        raise UsageError(f"--output-period {output_period:g}: must be a whole multiple of the design's "
                         f"control period {control_period:g} s")


def check_run_length(duration: float, control_period: float, what: str) -> None:
    n = duration / control_period
    if n > MAX_CONTROL_PERIODS:
        raise UsageError(f"{what}: {duration:g} s at a control period of {control_period:g} s is {n:.3g} periods, "
                         f"more than {MAX_CONTROL_PERIODS:.0e}; use a longer control period or a shorter run")


def load_params_design(args):
    """``(params, design)`` from ``--params`` (over the embedded actuator) and ``--design`` (default nominal),
    the design checked against the actuator; shared by every subcommand that takes them."""
    from ..loops.design import load_design, nominal_design_path
    from ..model.params import default_parameters, load_parameters

    params = default_parameters()
    if getattr(args, "params", None):
        params = load_parameters(args.params, base=params)
    design = load_design(getattr(args, "design", None) or nominal_design_path())
    design.check_against(params)
    return params, design


def effects_arg(values):
    out = []
    for v in values or []:
        out += [e.strip() for e in v.split(",") if e.strip()]
    return out


def parse_column_map(text: str | None) -> dict | None:
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


def read_runs(paths, column_map, params):
    from ..data.rigdata import read_run
    from ..loops.design import check_control_period

    from ..fit.kinematics import run_kinematics

    mapping = parse_column_map(column_map)
    kin = (params.value("screw.lead") * 1e3, params.value("gear.ratio"))  # where a run states none
    runs = [run_kinematics(read_run(p, column_map=mapping, default_kinematics=kin), params) for p in paths]
    for run in runs:
        if run.controller is not None:
            # the JSON's controller against the plant: a 1 s period would "replay" a nonsense loop
            check_control_period(run.controller.control_period, params, str(run.json_path),
                                 "controller.control_period_s")
    return runs


def run_inputs(paths) -> list[str]:
    out = []
    for p in paths:
        out += [str(p), str(Path(p).with_suffix(".json"))]
    return out


def load_params(args):
    from ..model.params import default_parameters, load_parameters

    return load_parameters(args.params, base=default_parameters()) if args.params else default_parameters()


def replay_mode(run, mode):
    return mode if mode != "auto" else ("closed_loop" if run.controller is not None else "open_loop")


def bounds_arg(text: str | None) -> dict:
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


def scaled_floats(text, option: str, scale: float):
    """``--option 1,2,3`` -> SI tuple (None when not given)."""
    if text is None:
        return None
    try:
        return tuple(float(v) * scale for v in text.split(",") if v.strip())
    except ValueError:
        raise ThsaError(f"--{option} {text!r}: give comma-separated numbers") from None


def analysis_effects(args) -> list[str]:
    # the plant that exists: temperature_friction and the dragged standby rotor, unless --effects says otherwise
    from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS

    return list(DEFAULT_ANALYSIS_EFFECTS) if args.effects is None else effects_arg(args.effects)
