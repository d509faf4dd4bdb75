"""Active/standby switch-over: the transient of the nonlinear closed loop.

The ``motor_fault_switch`` scenario disables the primary channel and enables
the standby one after a detection delay.  :func:`analyse_switchover` runs it
for several delays, with and without the bumpless hand-over of the current
integrator, and compares each run with the same run without fault, so that the
errors are those of the switch alone (the load ramp is common to both):

* peak speed error [m/s] and peak position error [m] of the nut;
* recovery time [s]: from the fault until the speed error stays within
  ``tolerance`` of the command (papers: about 0.15 s with a 15 ms delay).

Numbers only; the report draws them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .design import Design
from ..errors import ScenarioError
from ..model import build_plant
from ..model.params import ParameterSet
from ..sim.scenarios import Scenario, get_scenario
from ..sim.simulate import SimulationSettings, Simulator

__all__ = ["SwitchoverCase", "SwitchoverAnalysis", "analyse_switchover"]


@dataclass(frozen=True)
class SwitchoverCase:
    """One switch-over run.

    Attributes
    ----------
    delay_s : float
        Detection delay between primary off and standby on [s].
    handover : bool
        Bumpless hand-over of the current integrator.
    peak_speed_error_m_s, peak_position_error_m : float
        Largest deviation from the run without fault.
    recovery_time_s : float
        From the fault until |speed error| stays below the tolerance (inf: never).
    time, nut_speed, speed_cmd, nut_speed_no_fault, standby_current : ndarray
        The transient, from 0.1 s before the fault [s, m/s, A].
    """

    delay_s: float
    handover: bool
    peak_speed_error_m_s: float
    peak_position_error_m: float
    recovery_time_s: float
    time: np.ndarray
    nut_speed: np.ndarray
    speed_cmd: np.ndarray
    nut_speed_no_fault: np.ndarray
    standby_current: np.ndarray


@dataclass(frozen=True)
class SwitchoverAnalysis:
    """Switch-over cases of one design, level and scenario."""

    level: str
    scenario: str
    fault_time_s: float
    tolerance: float
    cases: tuple[SwitchoverCase, ...]

    def case(self, delay_s: float, handover: bool) -> SwitchoverCase:
        """The case of ``delay_s`` [s] and ``handover``."""
        for c in self.cases:
            if abs(c.delay_s - delay_s) < 1e-9 and c.handover == handover:
                return c
        raise KeyError(f"no case with delay {delay_s} s and handover {handover}")

    def report(self) -> str:
        """Recovery and peaks of each case (ms, mm/s, mm)."""
        from ..report.results import format_switchover

        return format_switchover(self)

    def to_dict(self) -> dict:
        """The cases' numbers (SI), JSON-able."""
        from ..report.results import switchover_to_dict

        return switchover_to_dict(self)

    def plot(self, ax=None):
        """Transients per delay and recovery vs delay; ``ax`` is not supported (a figure of its own)."""
        from ..report.analysis_plots import plot_switching

        if ax is not None:
            raise ValueError("SwitchoverAnalysis.plot draws three panels in a figure of its own")
        return plot_switching(self)


def _fault_time(s: Scenario) -> float:
    offs = [t for t, v in s.primary_enable if v < 0.5]
    if not offs:
        raise ScenarioError(f"scenario {s.name!r} never disables the primary channel")
    return float(offs[0])


def analyse_switchover(design: Design, params: ParameterSet, *, level: str = "B",
                       delays_s=(0.005, 0.01, 0.015, 0.02, 0.03, 0.05), handover=(False, True),
                       scenario: Scenario | str = "motor_fault_switch", tolerance: float = 0.05,
                       effects=()) -> SwitchoverAnalysis:
    """Run the switch-over for each delay and hand-over setting.

    Parameters
    ----------
    design : Design
        Its ``bumpless_handover`` is overridden by ``handover``.
    params : ParameterSet
    level : str
        Model level; ``standby_motor`` is always added.
    delays_s : sequence of float
        Detection delays [s].
    handover : sequence of bool
    scenario : Scenario or name
        Must disable the primary; its standby enable is replaced.
    tolerance : float
        Recovery band, fraction of the speed command [-].

    Returns
    -------
    SwitchoverAnalysis
    """
    sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
    t_fault = _fault_time(sc)
    plant = build_plant(level, tuple(effects) + ("standby_motor",), params=params)
    sim = Simulator(plant, SimulationSettings(output_period=1e-3))
    ref = sim.run(replace(sc, primary_enable=((0.0, 1.0),), standby_enable=((0.0, 0.0),), name=f"{sc.name}_no_fault"),
                  design, params)
    t = np.asarray(ref.time)
    window = t >= t_fault - 0.1
    cases = []
    for hand in handover:
        d = replace(design, bumpless_handover=bool(hand))
        for delay in delays_s:
            run = sim.run(replace(sc, standby_enable=((0.0, 0.0), (t_fault + float(delay), 1.0))), d, params)
            err_v = np.asarray(run["nut_speed"]) - np.asarray(ref["nut_speed"])
            err_x = np.asarray(run["nut_position"]) - np.asarray(ref["nut_position"])
            after = t >= t_fault
            band = tolerance * np.maximum(np.abs(np.asarray(ref["speed_cmd"])), 1e-12)
            outside = np.flatnonzero(after & (np.abs(err_v) > band))
            if outside.size == 0:
                rec = 0.0
            elif outside[-1] >= len(t) - 1:
                rec = float("inf")
            else:
                rec = float(t[outside[-1] + 1] - t_fault)
            cases.append(SwitchoverCase(
                float(delay), bool(hand), float(np.max(np.abs(err_v[after]))), float(np.max(np.abs(err_x[after]))), rec,
                t[window], np.asarray(run["nut_speed"])[window], np.asarray(run["speed_cmd"])[window],
                np.asarray(ref["nut_speed"])[window], np.asarray(run["standby_current"])[window]))
    return SwitchoverAnalysis(level, sc.name, t_fault, tolerance, tuple(cases))
