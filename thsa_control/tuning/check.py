"""`thsa check`: every requirement of a design judged by :mod:`thsa_control.verdict`, and writing tuned designs.

:func:`check_design` is :func:`thsa_control.verdict.evaluate_design`: the linear
``[requirements.<loop>]`` over the design's analysis grid and the ``[validation]``
limits on the nonlinear validation runs at every level and temperature, one
row per requirement (worst point, value, limit, pass/fail).  ``thsa tune``
gates what it writes with the same function, and ``thsa report --check`` gives
the same verdict.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import tomli_w

from ..errors import DesignError
from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS
from ..loops.design import Design, parse_design
from ..model.params import ParameterSet
from ..verdict import DEFAULT_LEVELS, DEFAULT_TEMPERATURES, Verdict, evaluate_design, validation_limits
from .validation import VALIDATION_SUITE, get_validation_scenario, run_metrics

__all__ = ["check_design", "validation_limits", "PROVENANCE_MARKER", "write_design", "suite_metrics"]

#: Written as ``[tuning].written_by`` into every design ``thsa tune`` writes; ``--out`` may only replace such files.
PROVENANCE_MARKER = "thsa tune (thsa_control.tuning)"


def check_design(design: Design, params: ParameterSet, *, levels=DEFAULT_LEVELS, temperatures=DEFAULT_TEMPERATURES,
                 scenarios=VALIDATION_SUITE, effects=DEFAULT_ANALYSIS_EFFECTS, progress=None, analysis=None,
                 linear: bool = True) -> Verdict:
    """The verdict on every requirement of ``design`` (see :func:`thsa_control.verdict.evaluate_design`)."""
    return evaluate_design(design, params, analysis=analysis, levels=tuple(levels), temperatures=tuple(temperatures),
                           scenarios=tuple(scenarios), effects=tuple(effects), progress=progress, linear=linear)


def suite_metrics(design: Design, params: ParameterSet, level: str, temperature: float, *,
                  scenarios=VALIDATION_SUITE, effects=DEFAULT_ANALYSIS_EFFECTS) -> dict:
    """Metrics of every run of the suite at one level and temperature (compiled simulator)."""
    from ..model import build_plant
    from ..sim.simulate import SimulationSettings, Simulator

    sim = Simulator(build_plant(level, effects, params=params), SimulationSettings(output_period=None))
    scenarios = tuple(scenarios)
    runs = sim.run_batch([get_validation_scenario(n).with_temperature(temperature) for n in scenarios], design, params)
    return {name: run_metrics(r) for name, r in zip(scenarios, runs)}


def write_design(design: Design, path: str | Path, *, force_marker: str = PROVENANCE_MARKER) -> Path:
    """Write ``design`` as TOML to ``path`` (atomically).

    Refuses (DesignError) to replace an existing file that ``thsa tune`` did
    not write: one whose ``[tuning].written_by`` is not the marker.
    """
    path = Path(path)
    if path.exists():
        try:
            doc = tomllib.loads(path.read_text(encoding="utf-8"))
        except (OSError, tomllib.TOMLDecodeError):
            doc = {}
        if doc.get("tuning", {}).get("written_by") != force_marker:
            raise DesignError(str(path), "exists and was not written by 'thsa tune' (no [tuning] provenance "
                                         "marker): refusing to overwrite it; choose another --out")
    doc = design.to_toml_dict()
    text = tomli_w.dumps(doc)
    parse_design(tomllib.loads(text), source=str(path))  # what we write must load back
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(path)
    return path
