"""Headline numbers of the papers' scenarios over the plausible range of the assumed values that set them.

Two headline numbers of the model are set less by the papers' tables than by
values the papers do not give:

* the surface-speed overshoot of level D while the load crosses the load-path
  backlash (``triangular_load``) is set by the damping of the preload disk
  springs (``loadpath.disk_spring_damping``), swept here as the damping ratio
  ``zeta = c / (2 sqrt(2 k_ds m_surface))`` of the surface on the disk springs;
* the back-drive of level C at the first trim stop (``backdrive_bipolar_ramp``)
  is set by where the ratchets stopped before the run
  (``noback.pawl_initial_clearance``, a fraction of the pawl pitch; a full
  pitch is the next tooth, i.e. zero clearance again).  The clearance left
  at the stop is the initial one plus the travel before it, modulo the pitch,
  so the back-drive is not monotonic in the initial clearance;
* the motor current of level B while a tensile load of 5..7 kN opposes the
  retraction of ``triangular_load`` is set by how the no-back's two disk sets
  share a load change (``noback.load_share``, their stiffness ratio: one disk
  design on both sides, assumed 0.5): the light compressive set slips there,
  with what is left of its preload as normal force.

:func:`assumption_ranges` runs each scenario over the range and returns the
metric at every value, so that a reader sees what the model predicts and what
it assumes.  Numerics only (no printing, no plotting).

Examples
--------
>>> from thsa_control.sim.assumptions import ASSUMED_RANGES
>>> [a.parameter for a in ASSUMED_RANGES]
['loadpath.disk_spring_damping', 'noback.pawl_initial_clearance', 'noback.load_share']
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..loops.design import Design
from ..model import build_plant
from ..model.effects.papers import NOBACK_LOAD_SHARE_SPREAD
from ..model.params import ParameterSet
from .metrics import backdrive_metrics, current_in_load_band, surface_speed_deviation
from .scenarios import get_scenario
from .simulate import SimulationSettings, Simulator

__all__ = ["AssumedRange", "RangeResult", "ASSUMED_RANGES", "assumption_ranges", "format_ranges"]


@dataclass(frozen=True)
class AssumedRange:
    """An assumed value, the range swept and the headline metric it sets.

    ``values`` are in the sweep's own unit (``label``); ``to_parameter`` turns
    one into the parameter's SI value.
    """

    parameter: str
    label: str
    values: tuple[float, ...]
    scenario: str
    level: str
    metric: str

    def to_parameter(self, params: ParameterSet, value: float) -> float:
        if self.parameter == "loadpath.disk_spring_damping":
            k = 2.0 * params.value("loadpath.disk_spring_stiffness")
            return value * 2.0 * math.sqrt(k * params.value("surface.mass"))
        return value

    def from_parameter(self, params: ParameterSet) -> float:
        v = params.value(self.parameter)
        if self.parameter == "loadpath.disk_spring_damping":
            k = 2.0 * params.value("loadpath.disk_spring_stiffness")
            return v / (2.0 * math.sqrt(k * params.value("surface.mass")))
        return v


ASSUMED_RANGES: tuple[AssumedRange, ...] = (
    AssumedRange("loadpath.disk_spring_damping", "disk-spring damping ratio", (0.0, 0.05, 0.1, 0.2, 0.35),
                 "triangular_load", "D", "surface speed deviation [% of command]"),
    AssumedRange("noback.pawl_initial_clearance", "initial pawl clearance [fraction of pitch]",
                 (0.0, 0.25, 0.5, 0.75, 0.95), "backdrive_bipolar_ramp", "C",
                 "back-drive at the first trim stop [% of command]"),
    AssumedRange("noback.load_share", "no-back load share of the compressive disk set",
                 tuple(0.5 + k * NOBACK_LOAD_SHARE_SPREAD for k in (-1.0, -0.5, 0.0, 0.5, 1.0)),
                 "triangular_load", "B", "|motor current| with 5..7 kN tensile opposing [A]"),
)


@dataclass(frozen=True)
class RangeResult:
    """The metric of one assumed value over its range; ``nominal`` is the embedded value's metric."""

    assumed: AssumedRange
    values: tuple[float, ...]
    metric_values: tuple[float, ...]
    nominal_value: float
    nominal_metric: float

    @property
    def span(self) -> tuple[float, float]:
        return (min(self.metric_values), max(self.metric_values))


def _metric(assumed: AssumedRange, result) -> float:
    if assumed.parameter == "noback.load_share":
        return current_in_load_band(result, -7e3, -5e3)
    if assumed.scenario == "triangular_load":
        return 100.0 * surface_speed_deviation(result)
    m = backdrive_metrics(result)
    return 100.0 * m.stop_backdrive_peak[1] / m.command_amplitude


def assumption_ranges(design: Design, params: ParameterSet, *, ranges=ASSUMED_RANGES,
                      output_period: float = 1e-3) -> tuple[RangeResult, ...]:
    """Run each range's scenario at its level for every value; see the module docstring.

    Parameters
    ----------
    design : Design
    params : ParameterSet
        Actuator; only the swept parameter is changed.
    ranges : sequence of AssumedRange
    output_period : float
        [s].

    Returns
    -------
    tuple of RangeResult
    """
    out = []
    settings = SimulationSettings(output_period=output_period)
    for a in ranges:
        scenario = get_scenario(a.scenario)
        plant = build_plant(a.level, scenario.required_effects, params=params)
        sim = Simulator(plant, settings)
        sets = [params.replace({a.parameter: a.to_parameter(params, v)}) for v in a.values] + [params]
        runs = sim.run_batch(scenario, design, sets)  # the swept values and the nominal one in one batch
        metrics = [_metric(a, r) for r in runs[:-1]]
        nominal = _metric(a, runs[-1])
        out.append(RangeResult(a, tuple(a.values), tuple(float(m) for m in metrics),
                               float(a.from_parameter(params)), float(nominal)))
    return tuple(out)


def format_ranges(results) -> str:
    """Plain-text table of :func:`assumption_ranges` (for the console and the notebook)."""
    lines = []
    for r in results:
        a = r.assumed
        lines.append(f"{a.metric}, {a.scenario} at level {a.level}, over {a.label} ({a.parameter}, assumed):")
        lines.append("    " + "  ".join(f"{v:g}: {m:.3g}" for v, m in zip(r.values, r.metric_values)))
        lines.append(f"    embedded value {r.nominal_value:.3g} gives {r.nominal_metric:.3g}; "
                     f"the range spans {r.span[0]:.3g} .. {r.span[1]:.3g}")
    return "\n".join(lines)


