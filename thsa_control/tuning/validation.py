"""The validation runs that define "good" in the cold, and their metrics (numbers only).

Named scenarios (FORMAT.md signs: load compressive positive, opposing a
positive motion), each run at any temperature with
:meth:`~thsa_control.sim.scenarios.Scenario.with_temperature`:

``cold_ramp``
    The papers' cold test (``sim/scenarios.py``): loaded start from
    standstill, 55 kN opposing applied while the motors are off (the no-back
    holds it), then the trim ramp to +9 mm/s at 30 mm/s^2: breakaway of the
    no-back and of the cold drag under full load (run at -30 and -55 degC).
``low_speed``
    Low-speed tracking at 0.5 then 1 mm/s against 20 kN (the Stribeck region,
    where the nominal loop has its worst margins).
``load_step``
    +5 mm/s, then a 20 kN opposing load step (10 ms rise) on the plateau.
``reversal``
    +5 mm/s to -5 mm/s under 20 kN compressive: opposing, then aiding.

Metrics of one run (:func:`run_metrics`), on the nut speed against the shaped
command, over every *plateau* (constant non-zero command, at least 0.2 s):

* speed error in % as the papers define it: mean ``|v_cmd - v_nut|`` over the
  plateau divided by ``|v_cmd|`` (the worst plateau of the run);
* ISE: integral of the squared speed error over the whole run [(mm/s)^2 s];
* overshoot: largest excursion of the nut speed beyond the command in the
  direction of motion on a plateau, % of the command;
* settling: time after the plateau start from which the error stays within
  ``settle_band`` (5 %) of the command [s];
* current peak [A] (active + standby) and the peak of its rate [A/s], taken
  every control period when the run is sampled so.

:func:`cost_terms` gives the integrals the tuning objective is made of, from a
run sampled every control period, with the same formula as the casadi
objective (``tuning/objective.py``): the test that the optimiser optimises the
model we simulate compares the two.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import ScenarioError
from ..sim.metrics import plateaus
from ..sim.scenarios import SCENARIOS, Scenario, get_scenario

__all__ = ["VALIDATION_SCENARIOS", "VALIDATION_SUITE", "DEFAULT_VALIDATION_REQUIREMENTS", "get_validation_scenario",
           "RunMetrics", "run_metrics", "cost_terms", "COST_TERMS", "RATE_SCALE"]

_MM = 1e-3

VALIDATION_SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario(
            "low_speed",
            "Low-speed tracking against 20 kN opposing (on from 0.05 to 0.25 s, motors off): +0.5 mm/s at "
            "30 mm/s^2 from 0.3 s, +1 mm/s from 1.3 s, stop at 2.3 s (Stribeck region).",
            2.5, ((0.0, 0.0), (0.3, 0.5 * _MM), (1.3, 1.0 * _MM), (2.3, 0.0)), 30 * _MM,
            ((0.0, 0.0), (0.05, 0.0), (0.25, 20e3)), temperature=-30.0,
        ),
        Scenario(
            "load_step",
            "+5 mm/s at 30 mm/s^2 from 0.2 s unloaded; 20 kN opposing load step (10 ms rise) at 0.8 s; "
            "stop at 1.5 s.",
            1.7, ((0.0, 0.0), (0.2, 5 * _MM), (1.5, 0.0)), 30 * _MM,
            ((0.0, 0.0), (0.8, 0.0), (0.81, 20e3)), temperature=-30.0,
        ),
        Scenario(
            "reversal",
            "Reversal under 20 kN compressive (on from 0.05 to 0.25 s, motors off): +5 mm/s (opposing) at "
            "30 mm/s^2 from 0.3 s, -5 mm/s (aiding) from 1.0 s, stop at 1.8 s.",
            2.0, ((0.0, 0.0), (0.3, 5 * _MM), (1.0, -5 * _MM), (1.8, 0.0)), 30 * _MM,
            ((0.0, 0.0), (0.05, 0.0), (0.25, 20e3)), temperature=-30.0,
        ),
    )
}

#: The validation suite of ``thsa check``, in order.
VALIDATION_SUITE: tuple[str, ...] = ("cold_ramp", "low_speed", "load_step", "reversal")

#: Limits used by ``thsa check`` for a design without a ``[validation]`` table (stated in its output);
#: the current peak defaults to the design's clamp (``velocity_loop.current_limit_A``).
DEFAULT_VALIDATION_REQUIREMENTS: dict[str, float] = {
    "max_speed_error_percent": 5.0,
    "max_overshoot_percent": 10.0,
    "max_settling_time_s": 0.5,
}

#: The integrals of the tuning objective, in this order (see :func:`cost_terms`).
COST_TERMS: tuple[str, ...] = ("ise", "current_square", "current_rate_square", "current_excess", "overshoot_excess")
#: Scale of the current rate in the objective [A/s]: the rate term is the integral of (di/dt / RATE_SCALE)^2.
RATE_SCALE = 1e3


def get_validation_scenario(name: str) -> Scenario:
    """A validation scenario, one of the papers' scenarios (``sim/scenarios.py``) of that name, or a
    scenario file (``*.toml``, read by :func:`~thsa_control.sim.scenarios.get_scenario`)."""
    if str(name).lower().endswith(".toml"):
        return get_scenario(name)
    if name in VALIDATION_SCENARIOS:
        return VALIDATION_SCENARIOS[name]
    if name in SCENARIOS:
        return SCENARIOS[name]
    raise ScenarioError(f"unknown scenario {name!r}; validation scenarios are {', '.join(VALIDATION_SCENARIOS)}; "
                        f"the papers' scenarios are {', '.join(SCENARIOS)}")


def _current(result) -> np.ndarray:
    i = np.asarray(result["motor_current"], float)
    if "standby_current" in result.names:
        i = i + np.asarray(result["standby_current"], float)
    return i


@dataclass(frozen=True)
class RunMetrics:
    """Metrics of one validation run (see the module notes).

    Attributes
    ----------
    scenario : str
    temperature : float
        [degC].
    speed_error_percent : float
        Papers' speed error, worst plateau [%].
    ise : float
        Integral of the squared speed error [(mm/s)^2 s].
    overshoot_percent : float
        [%] of the command.
    settling_time_s : float
        Worst plateau [s]; inf when a plateau never settles.
    current_peak_A : float
    current_rate_peak_A_per_s : float
    worst_plateau : str
        Which plateau has the worst speed error (command and start time).
    """

    scenario: str
    temperature: float
    speed_error_percent: float
    ise: float
    overshoot_percent: float
    settling_time_s: float
    current_peak_A: float
    current_rate_peak_A_per_s: float
    worst_plateau: str

    def as_dict(self) -> dict:
        """Plain numbers (JSON/TOML-ready; inf settling as -1)."""
        out = {k: getattr(self, k) for k in ("speed_error_percent", "ise", "overshoot_percent", "settling_time_s",
                                               "current_peak_A", "current_rate_peak_A_per_s")}
        if not math.isfinite(out["settling_time_s"]):
            out["settling_time_s"] = -1.0
        return {k: float(f"{v:.6g}") for k, v in out.items()}


def run_metrics(result, *, settle_band: float = 0.05) -> RunMetrics:
    """Metrics of one simulated (or measured) run with ``speed_cmd``, ``nut_speed``, ``load_force``, currents.

    Raises
    ------
    ScenarioError
        The run has no plateau (no constant non-zero command of 0.2 s).
    """
    t = np.asarray(result.time, float)
    cmd, v, f = (np.asarray(result[n], float) for n in ("speed_cmd", "nut_speed", "load_force"))
    e = cmd - v
    i = _current(result)
    ps = plateaus(t, cmd, f)
    if not ps:
        raise ScenarioError(f"run {result.name!r} has no speed plateau (constant non-zero command for 0.2 s)")
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    err, over, settle, worst = 0.0, 0.0, 0.0, ""
    for p in ps:
        m = (t >= p.start) & (t <= p.end)
        c = abs(p.command)
        pe = 100.0 * float(np.mean(np.abs(e[m]))) / c
        if pe >= err:
            err, worst = pe, f"{p.command * 1e3:g} mm/s from {p.start:.2f} s"
        over = max(over, 100.0 * float(np.max(np.sign(p.command) * (v[m] - p.command))) / c)
        out = np.flatnonzero(np.abs(e[m]) > settle_band * c)
        tm = t[m]
        if out.size == 0:
            s = 0.0
        elif out[-1] == tm.size - 1:
            s = math.inf
        else:
            s = float(tm[out[-1] + 1] - p.start)
        settle = max(settle, s)
    rate = np.abs(np.diff(i)) / np.diff(t) if t.size > 1 else np.zeros(1)
    return RunMetrics(result.name, float(np.median(np.asarray(result["temperature"]))) if "temperature" in result.names
                      else float("nan"), err, float(np.sum(e ** 2) * dt * 1e6), max(over, 0.0), settle,
                      float(np.max(np.abs(i))), float(np.max(rate)), worst)


def cost_terms(result, current_limit: float, state_names, overshoot_limit: float = 0.1) -> dict[str, float]:
    """The objective's integrals from a run sampled every control period.

    ``ise`` = h sum e_k^2 [(mm/s)^2 s], ``current_square`` = h sum i_k^2 [A^2 s],
    ``current_rate_square`` = h sum ((i_{k+1} - i_k) / h / RATE_SCALE)^2 [s],
    ``current_excess`` = h sum max(0, |i_k| - current_limit)^2 [A^2 s]; ``e_k`` and
    ``i_k`` are the signals at the start of period k, ``i_N`` the final state
    (``state_names``: the plant's state names, to read it);
    ``overshoot_excess`` = h sum over plateau periods (command constant and
    non-zero from k to k+1) of max(0, sgn(c_k) (v_k - c_k) - overshoot_limit |c_k|)^2
    [(mm/s)^2 s]: the speed above the allowed overshoot.
    """
    h = float(result.info["control_period_s"])
    if abs(float(result.info["output_period_s"]) - h) > 1e-12 * h:
        raise ValueError("cost_terms needs a run sampled every control period (output_period=None)")
    e = (np.asarray(result["speed_cmd"]) - np.asarray(result["nut_speed"])) * 1e3
    i = _current(result)
    plant_states = list(state_names)
    zf = np.asarray(result.info["final_state"], float)
    i_last = zf[plant_states.index("motor_current")] + (
        zf[plant_states.index("standby_current")] if "standby_current" in plant_states else 0.0)
    i_next = np.append(i[1:], i_last)
    c = np.asarray(result["speed_cmd"], float)
    v = np.asarray(result["nut_speed"], float)
    c_next = np.append(c[1:], zf[len(plant_states)])  # the shaper's state after the last period
    plateau = (c_next == c) & (c != 0)
    over = np.where(plateau, np.maximum(np.sign(c) * (v - c) - overshoot_limit * np.abs(c), 0.0), 0.0) * 1e3
    return {
        "ise": float(h * np.sum(e ** 2)),
        "current_square": float(h * np.sum(i ** 2)),
        "current_rate_square": float(h * np.sum(((i_next - i) / h / RATE_SCALE) ** 2)),
        "current_excess": float(h * np.sum(np.maximum(np.abs(i) - current_limit, 0.0) ** 2)),
        "overshoot_excess": float(h * np.sum(over ** 2)),
    }
