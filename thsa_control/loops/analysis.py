"""Loop analysis of the THSA cascade on linear models: margins, bandwidth, steps, over a grid.

This module owns the numerics of the linear loop analysis and returns frozen
result objects; it never imports matplotlib (``report/analysis_report.py``
draws them).  All loops are **discrete** (the rig's controller runs at the
design's control period ``h``, 10 kHz), built from the plant linearised by
:mod:`thsa_control.loops.linear`:

* **plant**: the continuous linear model (inputs: active voltage, load force,
  disturbance torque; outputs: active current, motor speed, nut speed),
  augmented with the nut kinematics (``d x_nut/dt = nut_speed``) and
  discretised with a zero-order hold (batched matrix exponential, as
  ``ct.c2d(..., 'zoh')``).
* **current loop**: discrete PI ``kp + ki h / (z - 1)`` (the rig's
  ``u_k = kp e_k + I_k``, ``I_{k+1} = I_k + ki h e_k``) and, with
  ``computation_delay_samples = 1``, ``z^-1``; around the ZOH-discretised
  RL plant of the linearisation (``d i/dt = (v - R i) / L``, speed held).
  The back-EMF coupling is not lost: it acts in the velocity loop's plant,
  which contains the closed current loop and the full coupled plant.
* **velocity loop**: discrete PI on motor speed around the current-reference
  -> motor-speed plant with the closed current loop inside.
* **position-monitoring loop**: ``kp_x`` (nut-speed target per position
  error), the shaper's one-sample delay ``z^-1`` (small signal: the rate
  limit is inactive and the P law is below the braking-speed cap, i.e.
  ``|e| < 2 a_max / kp_x^2``), ``1 / r`` to the motor-speed reference,
  around the closed velocity loop and the nut kinematics.

For every loop and point: gain crossover [Hz], phase margin [deg], gain
margin [dB] (signed: negative is a *lower* gain margin of a conditionally
stable loop; like python-control, the crossing closest to 0 dB is kept),
delay margin [s] (smallest extra delay that makes the loop touch -1), the
sensitivity peak ``Ms = max |1/(1+L)|``, the closed-loop -3 dB bandwidth
[Hz], closed-loop stability, step metrics (python-control ``step_info``
definitions: 10-90 % rise, 2 % settling, overshoot) and, for the velocity
and position loops, the response to a load-force step (nut speed [m/s] or
nut position [m] per newton; peak and 5 % recovery time).  Everything is
evaluated on arrays: one ``linearize_batch`` call for the grid, batched ZOH,
batched frequency responses on a log grid up to Nyquist, crossings refined
by vectorised bisection on the exact response, batched time stepping.

Requirements
------------
A design's optional ``[requirements.<loop>]`` tables (``<loop>`` one of
``current_loop``, ``velocity_loop``, ``position_loop``) hold any of
``min_phase_margin_deg``, ``min_gain_margin_db`` (compared with
``|gain_margin_db|``), ``min_delay_margin_s``, ``min_bandwidth_hz``,
``max_sensitivity_peak``, ``max_overshoot_percent``, ``max_settling_time_s``,
``max_rise_time_s``.  :func:`check_requirements` checks them at every valid
grid point; a closed-loop-unstable point fails every requirement of that
loop.  Invalid points (zero speed, backlash edge) are not checked: they are
listed with their reason.

Describing functions
--------------------
:func:`describing_functions` gives the limit cycles that python-control's
describing-function analysis predicts for the set-valued friction of the
model (tabulated from the plant's ``friction_torque`` around zero speed) in
the velocity and position loops, and for the load-path backlash in the
position loop (measured on the surface side of the play).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import control as ct
import numpy as np
from numpy.typing import NDArray

from ._loopmath import (
    MarginSet,
    _Response,
    StepMetrics,
    _SS,
    _close,
    _dcgain,
    _freq,
    _frequency_grid,
    _gain_delay,
    _load_metrics,
    _margins,
    _pi,
    _series,
    _step,
    _zoh,
    loop_margins,
    step_metrics,
)

from .design import REQUIREMENT_KEYS, REQUIREMENT_LOOPS, Design
from ..errors import DesignError
from .linear import (
    ConditionGrid,
    LinearizationSettings,
    OperatingCondition,
    PlantLinearization,
    PlantModel,
    linearize_conditions,
    plant_model,
)
from ..model.params import ParameterSet, default_parameters

__all__ = [
    "LOOPS",
    "METRICS",
    "AnalysisSettings",
    "MarginSet",
    "loop_margins",
    "StepMetrics",
    "step_metrics",
    "LoopMetrics",
    "LoopAnalysis",
    "WorstPoint",
    "analyse_loops",
    "Violation",
    "RequirementCheck",
    "check_requirements",
    "LimitCycle",
    "describing_functions",
    "predict_limit_cycles",
    "DesignAnalysis",
    "analyse_design",
    "ConfigurationAnalysis",
    "analyse_configurations",
]

#: The three loops of the cascade, inner to outer.
LOOPS: tuple[str, ...] = ("current_loop", "velocity_loop", "position_loop")

#: Metric name -> (unit, which way is worse: 'min', 'max', 'min_abs', 'max_abs').
METRICS: dict[str, tuple[str, str]] = {
    "crossover_hz": ("Hz", "min"),
    "phase_margin_deg": ("deg", "min"),
    "gain_margin_db": ("dB", "min_abs"),
    "delay_margin_s": ("s", "min"),
    "bandwidth_hz": ("Hz", "min"),
    "ms": ("-", "max"),
    "rise_time_s": ("s", "max"),
    "settling_time_s": ("s", "max"),
    "overshoot_percent": ("%", "max"),
    "load_step_peak": ("per N", "max_abs"),
    "load_step_recovery_s": ("s", "max"),
}

#: requirement key -> (metric, comparison)
_REQUIREMENTS = {
    "min_phase_margin_deg": ("phase_margin_deg", ">="),
    "min_gain_margin_db": ("gain_margin_db", "abs>="),
    "min_delay_margin_s": ("delay_margin_s", ">="),
    "min_bandwidth_hz": ("bandwidth_hz", ">="),
    "max_sensitivity_peak": ("ms", "<="),
    "max_overshoot_percent": ("overshoot_percent", "<="),
    "max_settling_time_s": ("settling_time_s", "<="),
    "max_rise_time_s": ("rise_time_s", "<="),
}
assert set(_REQUIREMENTS) == set(REQUIREMENT_KEYS)  # noqa: S101 - import-time consistency of two constants

# ----------------------------------------------------------------------------------------------------------------
# settings
# ----------------------------------------------------------------------------------------------------------------
#: Effects the analysis adds to its level by default (CLI and API alike): the
#: cold friction law and the standby motor, whose rotor the primary drags.
DEFAULT_ANALYSIS_EFFECTS: tuple[str, ...] = ("temperature_friction", "standby_motor")


@dataclass(frozen=True)
class AnalysisSettings:
    """What the loop analysis covers (SI units).

    Parameters
    ----------
    level : str
        Model level (``'A'`` .. ``'D'``).  Default ``'B'`` (no-back friction).
    effects : tuple of str
        Effects added.  Default ``DEFAULT_ANALYSIS_EFFECTS``: temperature
        friction and the standby motor, whose rotor is always dragged (the
        plant that exists: J x 1.89 against one rotor); the primary is active.
    nut_speeds : tuple of float
        Trim nut speeds [m/s] of the grid; 0 is kept to show that a trim stop
        is not linearisable.  Default 0, 0.5, 1, 2, 5, 10, 15 mm/s.
    load_forces : tuple of float
        Loads [N], compressive positive (with positive speeds: negative
        aids, positive opposes).  Default -55, -20, 0, 20, 55 kN.
    temperatures : tuple of float
        [degC].  Default -55, -30, 0, 25, 70.
    reference_speed, reference_load : float
        The point of the Bode and step overlays across temperature [m/s, N];
        default 1 mm/s against 20 kN, inside the cold-friction Stribeck region.
    n_frequencies : int
        Points of the log frequency grid (up to Nyquist).  Default 500.
    f_min : float
        Lowest frequency [Hz].  Default 0.1.
    step_horizons : tuple of float
        Step-response horizon of the current, velocity and position loops [s].
    step_decimation : tuple of int
        Samples of the control period between stored step samples, per loop.
    load_step_horizons : tuple of float
        Horizon of the load-step response of the velocity and position loops [s].
    recovery_fraction : float
        A load-step response has recovered when it stays within this fraction
        of its peak [-].  Default 0.05.
    linearization : LinearizationSettings
        Validity bands of the linearisation.
    """

    level: str = "B"
    effects: tuple[str, ...] = ("temperature_friction", "standby_motor")
    nut_speeds: tuple[float, ...] = (0.0, 0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3, 15e-3)
    load_forces: tuple[float, ...] = (-55e3, -20e3, 0.0, 20e3, 55e3)
    temperatures: tuple[float, ...] = (-55.0, -30.0, 0.0, 25.0, 70.0)
    reference_speed: float = 1e-3
    reference_load: float = 20e3
    n_frequencies: int = 500
    f_min: float = 0.1
    step_horizons: tuple[float, float, float] = (0.004, 0.3, 2.0)
    step_decimation: tuple[int, int, int] = (1, 1, 10)
    load_step_horizons: tuple[float, float] = (0.3, 2.0)
    recovery_fraction: float = 0.05
    linearization: LinearizationSettings = field(default_factory=LinearizationSettings)

    def __post_init__(self) -> None:
        for name in ("effects", "nut_speeds", "load_forces", "temperatures", "step_horizons", "step_decimation",
                     "load_step_horizons"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        self.validate()

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first invalid setting."""
        if not (self.nut_speeds and self.load_forces and self.temperatures):
            raise ValueError("AnalysisSettings: nut_speeds, load_forces and temperatures must not be empty")
        if not (isinstance(self.n_frequencies, int) and self.n_frequencies >= 20):
            raise ValueError(f"AnalysisSettings.n_frequencies = {self.n_frequencies!r} must be an integer >= 20")
        if not (self.f_min > 0 and math.isfinite(self.f_min)):
            raise ValueError(f"AnalysisSettings.f_min = {self.f_min!r} must be > 0")
        if len(self.step_horizons) != 3 or len(self.step_decimation) != 3 or len(self.load_step_horizons) != 2:
            raise ValueError("AnalysisSettings: step_horizons/step_decimation need 3 values, load_step_horizons 2")
        if any(not (h > 0) for h in self.step_horizons + self.load_step_horizons):
            raise ValueError("AnalysisSettings: step horizons must be > 0")
        if any(not (isinstance(d, int) and d >= 1) for d in self.step_decimation):
            raise ValueError("AnalysisSettings.step_decimation must be integers >= 1")
        if not 0 < self.recovery_fraction < 1:
            raise ValueError(f"AnalysisSettings.recovery_fraction = {self.recovery_fraction!r} must be in (0, 1)")

    def grid(self, active: str = "primary") -> ConditionGrid:
        """The condition grid of these settings."""
        return ConditionGrid(self.nut_speeds, self.load_forces, self.temperatures, active)


# ----------------------------------------------------------------------------------------------------------------
# the three loops of the cascade
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LoopMetrics:
    """One loop of the cascade at N operating points (arrays indexed like the conditions).

    Attributes
    ----------
    name : str
        ``'current_loop'``, ``'velocity_loop'`` or ``'position_loop'``.
    margins : MarginSet
        Open-loop response ``L`` on the frequency grid and its margins.
    closed_loop : numpy.ndarray, shape (N, W)
        ``T = L / (1 + L)`` (reference to measured output).
    stable : numpy.ndarray of bool, shape (N,)
        All closed-loop poles strictly inside the unit circle.
    spectral_radius : numpy.ndarray, shape (N,)
        Largest closed-loop pole magnitude [-].
    poles : numpy.ndarray of complex, shape (N, n)
        Closed-loop poles in the z-plane.
    step_time : numpy.ndarray, shape (K,)
        [s].
    step : numpy.ndarray, shape (N, K)
        Unit reference step response (current [A/A], motor speed [rad/s per
        rad/s], nut position [m/m]).
    step_info : StepMetrics
    load_step_time, load_step : numpy.ndarray or None
        Response to a 1 N load-force step (compressive: opposing a positive
        motion) of the nut speed [m/s per N] (velocity loop) or the nut
        position [m per N] (position loop); None for the current loop.
    load_step_peak : numpy.ndarray, shape (N,)
        Signed peak of that response (nan for the current loop).
    load_step_recovery_s : numpy.ndarray, shape (N,)
        Time after which it stays within the recovery fraction of its peak [s].
    load_step_unit : str
    """

    name: str
    margins: MarginSet
    closed_loop: NDArray[np.complex128]
    stable: NDArray[np.bool_]
    spectral_radius: NDArray[np.float64]
    poles: NDArray[np.complex128]
    step_time: NDArray[np.float64]
    step: NDArray[np.float64]
    step_info: StepMetrics
    load_step_time: NDArray[np.float64] | None
    load_step: NDArray[np.float64] | None
    load_step_peak: NDArray[np.float64]
    load_step_recovery_s: NDArray[np.float64]
    load_step_unit: str

    def metric(self, name: str) -> NDArray[np.float64]:
        """Array of metric ``name`` (a key of :data:`METRICS`)."""
        if name in ("crossover_hz", "phase_margin_deg", "gain_margin_db", "delay_margin_s", "bandwidth_hz", "ms"):
            return getattr(self.margins, name)
        if name in ("rise_time_s", "settling_time_s", "overshoot_percent"):
            return getattr(self.step_info, name)
        if name in ("load_step_peak", "load_step_recovery_s"):
            return getattr(self, name)
        raise KeyError(f"unknown metric {name!r}; metrics are {', '.join(METRICS)}")


@dataclass(frozen=True, eq=False)
class _Loops:
    """Internal: the batched systems of the cascade."""

    open: dict
    closed: dict  # name -> (_SS, reference output index)
    omega: np.ndarray
    h: float


def _plant_blocks(lin: PlantLinearization) -> tuple[_SS, np.ndarray, np.ndarray]:
    """Continuous (A, B, C) blocks: inputs [voltage, load, torque], outputs [current, speed, nut speed]."""
    b = lin.batch
    N = len(lin)
    k = np.arange(N)
    iv = np.array([b.inputs.index(lin.channel(j)[0]) for j in range(N)])
    ii = np.array([b.outputs.index(lin.channel(j)[1]) for j in range(N)])
    iF, iT = b.inputs.index("load_force"), b.inputs.index("disturbance_torque")
    iw, ivn = b.outputs.index("motor_speed"), b.outputs.index("nut_speed")
    B = np.stack([b.B[k, :, iv], b.B[:, :, iF], b.B[:, :, iT]], axis=2)
    C = np.stack([b.C[k, ii, :], b.C[:, iw, :], b.C[:, ivn, :]], axis=1)
    D = np.stack([np.stack([b.D[k, ii, iv], b.D[k, ii, iF], b.D[k, ii, iT]], 1),
                  np.stack([b.D[k, iw, iv], b.D[:, iw, iF], b.D[:, iw, iT]], 1),
                  np.stack([b.D[k, ivn, iv], b.D[:, ivn, iF], b.D[:, ivn, iT]], 1)], axis=1)
    if np.any(np.abs(D) > 0):
        raise DesignError("analysis", "the plant has feedthrough to a measured signal; the loops assume none")
    return _SS(b.A, B, C, D), k, iv


def _build(lin: PlantLinearization, design: Design, settings: AnalysisSettings) -> _Loops:
    h = design.control_period
    N = len(lin)
    cont, _, _ = _plant_blocks(lin)
    n = cont.n
    r = lin.model.kinematic_ratio
    # nut kinematics appended: d x_nut / dt = nut speed
    Aa = np.zeros((N, n + 1, n + 1))
    Aa[:, :n, :n] = cont.A
    Aa[:, n, :n] = cont.C[:, 2, :]
    Ba = np.zeros((N, n + 1, 3))
    Ba[:, :n, :] = cont.B
    Phi, Gam = _zoh(Aa, Ba, h)
    Cf = np.zeros((N, 4, n + 1))
    Cf[:, :3, :n] = cont.C
    Cf[:, 3, n] = 1.0
    full = _SS(Phi, Gam, Cf, np.zeros((N, 4, 3)))
    # without the position integrator (nothing depends on it): current and velocity loops
    motion = _SS(Phi[:, :n, :n], Gam[:, :n], Cf[:, :3, :n], np.zeros((N, 3, 3)))
    Kc = _series(_pi(N, design.current_kp, design.current_ki * h),
                 _gain_delay(N, 1.0, design.computation_delay_samples))
    Kv = _pi(N, design.velocity_kp, design.velocity_ki * h)
    Kx = _gain_delay(N, design.position_kp / r, 1)  # shaper: one-sample delay
    # the current loop proper: the RL plant of the linearisation (speed held; the back-EMF
    # coupling acts through the velocity loop's plant, which contains the closed current loop)
    ic = np.array([lin.batch.states.index(lin.channel(j)[1]) for j in range(N)])
    iv = np.array([lin.batch.inputs.index(lin.channel(j)[0]) for j in range(N)])
    k = np.arange(N)
    phi_rl, gam_rl = _zoh(lin.batch.A[k, ic, ic][:, None, None], lin.batch.B[k, ic, iv][:, None, None], h)
    rl = _SS(phi_rl, gam_rl, np.ones((N, 1, 1)), np.zeros((N, 1, 1)))
    cl_c = _close(motion, Kc, 0, 0)
    cl_v = _close(cl_c, Kv, 1, 0)
    cl_v_full = _close(_close(full, Kc, 0, 0), Kv, 1, 0)
    cl_x = _close(cl_v_full, Kx, 3, 0)
    opens = {
        "current_loop": _series(Kc, rl),
        "velocity_loop": _series(Kv, cl_c.sub([1], [0])),
        "position_loop": _series(Kx, cl_v_full.sub([3], [0])),
    }
    closed = {"current_loop": (_close(rl, Kc, 0, 0), 0), "velocity_loop": (cl_v, 1), "position_loop": (cl_x, 3)}
    omega = _frequency_grid(h, settings.f_min, settings.n_frequencies)
    return _Loops(opens, closed, omega, h)


def _metrics(loops: _Loops, settings: AnalysisSettings, steps: bool) -> dict[str, LoopMetrics]:
    h, omega = loops.h, loops.omega
    z = np.exp(1j * omega * h)
    out = {}
    for j, name in enumerate(LOOPS):
        Lsys = loops.open[name]
        cl, fb = loops.closed[name]
        resp = _Response(Lsys)
        L = resp.grid(z)
        dc = _dcgain(cl, fb, 0)
        m = _margins(lambda i, w, r=resp: r.at(i, np.exp(1j * w * h)), omega, L, dc)
        with np.errstate(divide="ignore", invalid="ignore"):
            T = L / (1.0 + L)
        poles = np.linalg.eigvals(cl.A)
        rho = np.max(np.abs(poles), axis=1)
        N = L.shape[0]
        nan = np.full(N, np.nan)
        if steps:
            t, y = _step(cl, fb, 0, h, settings.step_horizons[j], settings.step_decimation[j])
            info = step_metrics(t, y, dc)
        else:
            t, y = np.zeros(0), np.zeros((N, 0))
            info = StepMetrics(nan, nan, nan, nan, nan, nan)
        lt = ly = None
        peak, rec, unit = nan, nan, ""
        if name != "current_loop" and steps:
            out_idx, unit = (2, "m/s per N") if name == "velocity_loop" else (3, "m per N")
            lt, ly = _step(cl, out_idx, 1, h, settings.load_step_horizons[j - 1], settings.step_decimation[j])
            peak, rec = _load_metrics(lt, ly, settings.recovery_fraction)
        out[name] = LoopMetrics(name, m, T, rho < 1 - 1e-12, rho, poles, t, y, info, lt, ly, peak, rec, unit)
    return out


@dataclass(frozen=True)
class WorstPoint:
    """The worst valid grid point of one metric of one loop.

    Attributes
    ----------
    loop, metric : str
    value : float
        [unit of the metric].
    unit : str
    index : int
        Point index in the analysis.
    condition : OperatingCondition
    uniform : bool
        The metric is the same (to 1e-6 relative) at every valid point, so
        no point is worse than another.
    """

    loop: str
    metric: str
    value: float
    unit: str
    index: int
    condition: OperatingCondition
    uniform: bool = False

    def text(self) -> str:
        """One line."""
        where = "the same at every valid point" if self.uniform else f"at {self.condition.label()}"
        return f"{self.loop} {self.metric} = {self.value:.4g} {self.unit} {where}"


@dataclass(frozen=True, eq=False)
class LoopAnalysis:
    """The cascade's loops over a set of operating conditions.

    Attributes
    ----------
    design : Design
    settings : AnalysisSettings
    linearization : PlantLinearization
        Plant models, validity and reasons, friction slopes.
    loops : mapping of str to LoopMetrics
        Keyed by :data:`LOOPS`.
    grid : ConditionGrid or None
        The grid, when the conditions form one.
    saturation : tuple of tuple of str
        Per point, why the steady motion saturates the cascade (the current
        it needs exceeds the velocity loop's current limit, or the voltage
        the current loop's voltage limit): a clamped controller has no
        small-signal loop, so the point is not analysed.
    """

    design: Design
    settings: AnalysisSettings
    linearization: PlantLinearization
    loops: Mapping[str, LoopMetrics]
    grid: ConditionGrid | None = None
    saturation: tuple[tuple[str, ...], ...] = ()

    def __post_init__(self) -> None:
        if not self.saturation:
            object.__setattr__(self, "saturation", tuple(() for _ in self.conditions))

    @property
    def conditions(self) -> tuple[OperatingCondition, ...]:
        """Operating conditions, one per point."""
        return self.linearization.conditions

    @property
    def valid(self) -> NDArray[np.bool_]:
        """Points where the loops can be analysed: a valid linear model and no saturated controller."""
        return self.linearization.valid & ~self.saturated

    @property
    def saturated(self) -> NDArray[np.bool_]:
        """Points whose steady motion needs more current or voltage than the design's limits."""
        return np.array([bool(r) for r in self.saturation], dtype=bool)

    @property
    def reasons(self) -> tuple[tuple[str, ...], ...]:
        """Why each point is not analysed (linearisation reasons, then saturation)."""
        return tuple(a + b for a, b in zip(self.linearization.reasons, self.saturation))

    def invalid_points(self) -> list[tuple[OperatingCondition, tuple[str, ...]]]:
        """``(condition, reasons)`` of every point that is not analysed."""
        return [(self.conditions[k], self.reasons[k]) for k in np.flatnonzero(~self.valid)]

    def __len__(self) -> int:
        return len(self.conditions)

    def metric(self, loop: str, name: str) -> NDArray[np.float64]:
        """Metric ``name`` of ``loop`` at every point."""
        if loop not in self.loops:
            raise KeyError(f"unknown loop {loop!r}; loops are {', '.join(self.loops)}")
        return self.loops[loop].metric(name)

    def worst(self, loop: str, name: str) -> WorstPoint | None:
        """The worst valid point of metric ``name`` of ``loop`` (None if no valid point has a value).

        'Worst' is the lowest margin, crossover or bandwidth, the largest Ms,
        overshoot, rise or settling time and load-step peak; for the signed
        gain margin, the one closest to 0 dB.
        """
        unit, how = METRICS[name]
        vals = np.asarray(self.metric(loop, name), float)
        key = np.abs(vals) if how.endswith("abs") else vals
        key = np.where(self.valid & ~np.isnan(key), key, np.nan)
        if np.all(np.isnan(key)):
            return None
        k = int(np.nanargmin(key) if how.startswith("min") else np.nanargmax(key))
        finite = key[np.isfinite(key)]
        uniform = bool(finite.size == np.count_nonzero(~np.isnan(key)) and finite.size > 1
                       and np.ptp(finite) <= 1e-6 * max(np.max(np.abs(finite)), 1e-300))
        return WorstPoint(loop, name, float(vals[k]), unit, k, self.conditions[k], uniform)

    def worst_points(self) -> tuple[WorstPoint, ...]:
        """Worst point of every metric of every loop (the load-step ones for the outer loops)."""
        out = []
        for loop in self.loops:
            for name in METRICS:
                if name.startswith("load_step") and loop == "current_loop":
                    continue
                w = self.worst(loop, name)
                if w is not None:
                    out.append(w)
        return tuple(out)

    def reference_indices(self) -> dict[float, int]:
        """Temperature -> index of the point nearest the reference speed and load."""
        out = {}
        sp, ld = self.settings.reference_speed, self.settings.reference_load
        for k, c in enumerate(self.conditions):
            if not self.valid[k]:
                continue
            cur = out.get(c.temperature)
            dist = (abs(c.nut_speed - sp) / 1e-3, abs(c.load_force - ld) / 1e3)
            if cur is None or dist < cur[0]:
                out[c.temperature] = (dist, k)
        return {t: v[1] for t, v in sorted(out.items())}


def analyse_loops(design: Design, params: ParameterSet | None = None, conditions=None, *,
                  settings: AnalysisSettings | None = None, model: PlantModel | None = None,
                  steps: bool = True) -> LoopAnalysis:
    """Linearise the plant at every condition and analyse the three loops, vectorised.

    Parameters
    ----------
    design : Design
        Gains, control period and computation delay.
    params : ParameterSet, optional
        Actuator; default the embedded one.
    conditions : ConditionGrid, OperatingCondition or sequence of them, optional
        Default ``settings.grid()``.
    settings : AnalysisSettings, optional
    model : PlantModel, optional
        Reuse a wrapped plant (must match ``settings.level`` / effects).
    steps : bool
        Compute the step and load-step responses (the time stepping is the
        costliest part); margins and Bode data are always computed.

    Returns
    -------
    LoopAnalysis

    Raises
    ------
    SolverError
        When a condition has no steady motion.
    DesignError
        When the design asks more than the actuator has.

    Examples
    --------
    >>> from thsa_control.loops.design import load_design, nominal_design_path
    >>> a = analyse_loops(load_design(nominal_design_path()),
    ...                   conditions=[OperatingCondition(10e-3, 20e3, 25.0)])
    >>> round(float(a.metric("velocity_loop", "crossover_hz")[0]), 1)  # designed for 30 Hz
    29.2
    >>> bool(a.loops["velocity_loop"].stable[0]), a.valid.tolist()
    (True, [True])
    """
    settings = settings or AnalysisSettings()
    params = params or default_parameters()
    design.check_against(params)
    model = model or plant_model(settings.level, settings.effects, params, settings=settings.linearization)
    if conditions is None:
        conditions = settings.grid()
    grid = conditions if isinstance(conditions, ConditionGrid) else None
    lin = linearize_conditions(model, conditions)
    loops = _metrics(_build(lin, design, settings), settings, steps)
    return LoopAnalysis(design, settings, lin, loops, grid, _saturation(lin, design, params))


def _saturation(lin: PlantLinearization, design: Design, params: ParameterSet) -> tuple[tuple[str, ...], ...]:
    b = lin.batch
    v_max = design.voltage_limit if design.voltage_limit is not None else (
        params.value("inverter.dc_bus_voltage") / math.sqrt(3.0))
    out = []
    for k in range(len(lin)):
        v_name, i_name = lin.channel(k)
        i = float(b.Y[b.model_outputs.index(i_name), k])
        v = float(b.U[b.model_inputs.index(v_name), k])
        why = []
        if abs(i) > design.current_limit:
            why.append(f"saturated: the steady motion needs {i:.3g} A, beyond the current limit "
                       f"{design.current_limit:g} A (the velocity PI output is clamped: no small-signal loop)")
        if abs(v) > v_max:
            why.append(f"saturated: the steady motion needs {v:.4g} V, beyond the voltage limit {v_max:.4g} V")
        out.append(tuple(why))
    return tuple(out)


# ----------------------------------------------------------------------------------------------------------------
# requirements
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Violation:
    """A requirement not met at a grid point.

    Attributes
    ----------
    loop, requirement, metric : str
    limit : float
    value : float
        The metric's value there (``|value|`` is compared for gain margins).
    index : int
    condition : OperatingCondition
    """

    loop: str
    requirement: str
    metric: str
    limit: float
    value: float
    index: int
    condition: OperatingCondition

    def text(self) -> str:
        """One line naming the requirement, the point and the value."""
        unit = METRICS[self.metric][0]
        return (f"{self.loop}.{self.requirement} = {self.limit:g} not met at {self.condition.label()}: "
                f"{self.metric} = {self.value:.4g} {unit}")


@dataclass(frozen=True)
class RequirementRow:
    """Summary of one requirement over the grid: worst value, where, how many points fail.

    ``uniform`` is True when the metric is the same at every valid point
    (the current loop's, for instance): then no point is worse than another.
    """

    loop: str
    requirement: str
    metric: str
    limit: float
    worst_value: float
    worst_index: int
    worst_condition: OperatingCondition | None
    n_failed: int
    passed: bool
    uniform: bool = False


@dataclass(frozen=True)
class RequirementCheck:
    """Requirements of a design checked at every valid grid point.

    Attributes
    ----------
    passed : bool
        Every requirement met at every valid point, every loop stable there.
    violations : tuple of Violation
    rows : tuple of RequirementRow
    unstable : tuple of (loop, index, condition)
        Valid points where a loop's closed loop is unstable.
    checked_points, skipped_points : int
        Valid points checked; invalid ones skipped (listed in the analysis).
    """

    passed: bool
    violations: tuple[Violation, ...]
    rows: tuple[RequirementRow, ...]
    unstable: tuple[tuple[str, int, OperatingCondition], ...]
    checked_points: int
    skipped_points: int

    def summary(self) -> str:
        """A few lines: PASS/FAIL, then the worst violation of each requirement."""
        head = "requirements: PASS" if self.passed else (
            f"requirements: FAIL ({len(self.violations)} violation(s) at {self.checked_points} valid points)")
        lines = [head]
        for row in self.rows:
            if not row.passed and row.worst_condition is not None:
                lines.append(f"  {row.loop}.{row.requirement} = {row.limit:g}: worst {row.metric} = "
                             f"{row.worst_value:.4g} at {row.worst_condition.label()} ({row.n_failed} point(s) fail)")
        for loop, _, cond in self.unstable:
            lines.append(f"  {loop}: closed loop unstable at {cond.label()}")
        return "\n".join(lines)


def check_requirements(analysis: LoopAnalysis, requirements: Mapping | None = None) -> RequirementCheck:
    """Check ``[requirements.<loop>]`` at every valid point of ``analysis``.

    Parameters
    ----------
    analysis : LoopAnalysis
    requirements : mapping, optional
        ``{loop: {key: limit}}``; default ``analysis.design.requirements``.
        Keys: see the module notes (``thsa_control.loops.design.REQUIREMENT_KEYS``).

    Returns
    -------
    RequirementCheck

    Raises
    ------
    DesignError
        For an unknown loop or key.
    """
    req = analysis.design.requirements if requirements is None else requirements
    valid = analysis.valid
    violations, rows, unstable = [], [], []
    for loop, table in req.items():
        if loop not in REQUIREMENT_LOOPS:
            raise DesignError(analysis.design.source, f"unknown table [requirements.{loop}]")
        lm = analysis.loops[loop]
        for k in np.flatnonzero(valid & ~lm.stable):
            unstable.append((loop, int(k), analysis.conditions[k]))
        for key, limit in table.items():
            if key not in _REQUIREMENTS:
                raise DesignError(analysis.design.source, f"unknown key {key!r} in [requirements.{loop}]")
            metric, op = _REQUIREMENTS[key]
            vals = np.asarray(lm.metric(metric), float)
            cmp = np.abs(vals) if op == "abs>=" else vals
            with np.errstate(invalid="ignore"):
                ok = cmp >= limit if op.endswith(">=") else cmp <= limit
            ok = ok & lm.stable & ~np.isnan(cmp)
            fail = np.flatnonzero(valid & ~ok)
            for k in fail:
                violations.append(Violation(loop, key, metric, float(limit), float(vals[k]), int(k),
                                            analysis.conditions[k]))
            score = np.where(valid, cmp, np.nan)
            if np.all(np.isnan(score)):
                wk, wv, wc = -1, float("nan"), None
            else:
                wk = int(np.nanargmin(score) if op.endswith(">=") else np.nanargmax(score))
                wv, wc = float(vals[wk]), analysis.conditions[wk]
            fin = score[np.isfinite(score)]
            uniform = bool(fin.size > 1 and fin.size == np.count_nonzero(~np.isnan(score))
                           and np.ptp(fin) <= 1e-6 * max(np.max(np.abs(fin)), 1e-300))
            rows.append(RequirementRow(loop, key, metric, float(limit), wv, wk, wc, int(fail.size), fail.size == 0,
                                       uniform))
    return RequirementCheck(passed=not violations and not unstable, violations=tuple(violations), rows=tuple(rows),
                            unstable=tuple(unstable), checked_points=int(valid.sum()),
                            skipped_points=int((~valid).sum()))


# ----------------------------------------------------------------------------------------------------------------
# describing functions
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LimitCycle:
    """A limit cycle predicted (or not) by describing-function analysis.

    Attributes
    ----------
    loop : str
        ``'velocity_loop'`` or ``'position_loop'`` (closed around the linear part).
    nonlinearity : str
        ``'friction'`` (the model's set-valued friction around zero speed:
        no-back disks, cold Coulomb drag, efficiency channel) or
        ``'backlash'`` (load-path play ``2 b`` in the position feedback).
    condition : OperatingCondition
        Load and temperature (trim speed 0: reversal / trim stop).
    predicted : bool
        True when ``H(jw) N(a) = -1`` has a solution.
    signal : str
        What oscillates at the nonlinearity's input.
    amplitude : float
        Its amplitude [``amplitude_unit``] (nan if none predicted).
    amplitude_unit : str
    frequency_hz : float
        [Hz] (nan if none).
    note : str
    """

    loop: str
    nonlinearity: str
    condition: OperatingCondition
    predicted: bool
    signal: str
    amplitude: float
    amplitude_unit: str
    frequency_hz: float
    note: str = ""


def predict_limit_cycles(response, omega, nonlinearity, amplitudes) -> list[tuple[float, float]]:
    """Describing-function limit cycles of a loop ``H`` with a nonlinearity ``F`` in its feedback.

    Solves ``H(jw) N(a) = -1`` with ``ct.describing_function_response``
    (negative feedback ``u = -F(y)``), ``H`` given by its samples on
    ``omega`` (turned into a smoothed FRD, so that discrete loops are
    evaluated on the unit circle, not at ``z = jw``).  Intersections at the
    last frequency (Nyquist, where every sampled response is real) are
    dropped: they are an artefact of holding a continuous nonlinearity.

    Parameters
    ----------
    response : array_like of complex, shape (W,)
        ``H(e^{jwh})`` or ``H(jw)`` [output unit / input unit].
    omega : array_like, shape (W,)
        [rad/s], increasing.
    nonlinearity : callable or python-control DescribingFunctionNonlinearity
        ``F``.
    amplitudes : array_like
        Input amplitudes of ``F`` to scan [unit of ``y``].

    Returns
    -------
    list of (amplitude, frequency [rad/s])

    Examples
    --------
    python-control's textbook case, ``8 / (s^3 + 2 s^2 + 2 s + 1)`` with a
    unit saturation, oscillates at ``w = sqrt(2)``:

    >>> import numpy as np, control as ct
    >>> w = np.geomspace(0.01, 100, 300)
    >>> H = ct.tf([8], [1, 2, 2, 1])
    >>> [(round(a, 2), round(f, 3)) for a, f in predict_limit_cycles(
    ...     H(1j * w), w, ct.saturation_nonlinearity(1), np.linspace(1, 4, 10))]
    [(3.34, 1.414)]
    """
    omega = np.asarray(omega, float)
    frd = ct.frd(np.asarray(response, complex), omega, smooth=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # python-control's Nyquist and refinement warnings
        res = ct.describing_function_response(frd, nonlinearity, np.asarray(amplitudes, float), omega=omega,
                                              warn_nyquist=False)
    return [(float(a), float(w)) for a, w in (res.intersections or [])
            if a > 0 and 0 < w < omega[-1] * (1 - 1e-6)]


def _friction_map(model: PlantModel, lin: PlantLinearization, k: int, w_max: float):
    """Static friction torque [N m] vs motor speed [rad/s] at point k, from the plant (one mapped call)."""
    b = lin.batch
    pos = np.geomspace(1e-9, w_max, 400)
    w = np.concatenate([-pos[::-1], [0.0], pos])
    X = np.repeat(b.X[:, k:k + 1], w.size, axis=1)
    names = model.named.states
    X[names.index("motor_speed")] = w
    for s in ("pawl_clearance_comp", "pawl_clearance_tens"):
        if s in names:  # both pawls engaged: each direction meets its loaded disk, as at a reversal
            X[names.index(s)] = -0.5 * model.params.value("noback.pawl_pitch")
    _, Y = model.named.evaluate_many(X, b.U[:, k:k + 1], b.P[:, k:k + 1])
    tf = Y[model.named.outputs.index("friction_torque")]
    return w, tf


def describing_functions(design: Design, params: ParameterSet | None = None, *,
                         settings: AnalysisSettings | None = None, temperatures: Sequence[float] | None = None,
                         loads: Sequence[float] | None = None, model: PlantModel | None = None,
                         n_frequencies: int = 300) -> tuple[LimitCycle, ...]:
    """Limit cycles predicted by describing functions (python-control) at trim stop / reversal.

    The linear part is the plant linearised at zero speed, where the
    continuous model's set-valued friction contributes nothing, so the
    linear model is exactly the smooth part (inertia, viscous drag,
    electrics) and the whole friction goes into the nonlinearity.  Three
    loops per condition:

    * velocity loop with friction: ``H`` = disturbance torque -> motor speed
      with the velocity loop closed, ``F`` = the friction torque of the plant
      vs motor speed (tabulated from ``friction_torque``; describing function
      by ``ct.describing_function``);
    * position loop with friction: the same with the position loop closed;
    * position loop with backlash: ``H`` = the open position loop, ``F`` =
      ``ct.friction_backlash_nonlinearity(2 * loadpath.backlash)`` on the
      fed-back position (as if it were measured on the surface side).

    ``H`` is the discrete loop's response on a grid up to Nyquist, handed to
    ``ct.describing_function_response`` as an FRD.

    Parameters
    ----------
    design : Design
    params : ParameterSet, optional
    settings : AnalysisSettings, optional
        Level and effects; default temperatures.
    temperatures : sequence of float, optional
        [degC]; default ``settings.temperatures``.
    loads : sequence of float, optional
        [N]; default 0 and the largest grid load.
    model : PlantModel, optional
    n_frequencies : int
        Frequency points of ``H``.

    Returns
    -------
    tuple of LimitCycle
    """
    settings = settings or AnalysisSettings()
    params = params or default_parameters()
    model = model or plant_model(settings.level, settings.effects, params, settings=settings.linearization)
    temps = tuple(settings.temperatures if temperatures is None else temperatures)
    if loads is None:
        loads = (0.0, float(max(abs(f) for f in settings.load_forces)))
    conds = [OperatingCondition(0.0, float(f), float(t)) for t in temps for f in loads]
    lin = linearize_conditions(model, conds)  # invalid (zero speed) by design: see the docstring
    dsettings = replace(settings, n_frequencies=int(n_frequencies))
    loops = _build(lin, design, dsettings)
    omega, h = loops.omega, loops.h
    z = np.exp(1j * omega * h)
    cl_v, _ = loops.closed["velocity_loop"]
    cl_x, _ = loops.closed["position_loop"]
    H = {
        ("velocity_loop", "friction"): _freq(cl_v.sub([1], [2]), z),
        ("position_loop", "friction"): _freq(cl_x.sub([1], [2]), z),
        ("position_loop", "backlash"): _freq(loops.open["position_loop"], z),
    }
    backlash = params.value("loadpath.backlash")
    r = model.kinematic_ratio
    out = []
    for k, c in enumerate(conds):
        w_tab, t_tab = _friction_map(model, lin, k, 2e3)

        def friction(v, w_tab=w_tab, t_tab=t_tab):
            return float(np.interp(v, w_tab, t_tab))

        for (loop, kind), resp in H.items():
            if kind == "friction":
                amps = np.geomspace(1e-3, 1e3, 60)
                nl, signal, unit = friction, "motor speed", "rad/s"
            else:
                amps = 0.5 * (2 * backlash) * (1 + np.geomspace(1e-3, 1e2, 60))
                nl, signal, unit = ct.friction_backlash_nonlinearity(2 * backlash), "nut position", "m"
            hits = predict_limit_cycles(resp[k], omega, nl, amps)
            if hits:
                a, wf = max(hits, key=lambda p: p[0])
                extra = f"; {len(hits)} intersections, largest amplitude kept" if len(hits) > 1 else ""
                if unit == "rad/s":
                    note = f"nut speed amplitude {a * r * 1e3:.3g} mm/s{extra}"
                else:
                    note = f"position amplitude {a * 1e3:.3g} mm vs half play {backlash * 1e3:.3g} mm{extra}"
                out.append(LimitCycle(loop, kind, c, True, signal, a, unit, wf / (2 * np.pi), note))
            else:
                note = "no intersection of H(jw) with -1/N(a): no limit cycle predicted"
                ph0 = float(np.degrees(np.angle(resp[k][0])))
                if kind == "friction" and abs(ph0) > 170.0:
                    note += (f"; H approaches the negative real axis at the lowest frequency (phase {ph0:.0f} deg at "
                             f"{omega[0] / (2 * np.pi):.2g} Hz, integral action against friction): a slow stick-slip "
                             "hunting is not excluded, describing functions cannot resolve it")
                out.append(LimitCycle(loop, kind, c, False, signal, float("nan"), unit, float("nan"), note))
    return tuple(out)


# ----------------------------------------------------------------------------------------------------------------
# active / standby configurations
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ConfigurationAnalysis:
    """Loops of the two channel configurations (``standby_motor`` added).

    Attributes
    ----------
    primary : LoopAnalysis
        Primary active, standby off with its rotor dragged.
    standby : LoopAnalysis
        Standby active, primary off (its rotor dragged).
    """

    primary: LoopAnalysis
    standby: LoopAnalysis

    def rows(self) -> list[dict]:
        """One row per configuration, loop and point: the margins (nan where the point is not analysed)."""
        out = []
        for name, a in (("primary active", self.primary), ("standby active", self.standby)):
            for loop, lm in a.loops.items():
                for k, c in enumerate(a.conditions):
                    m = lm.margins
                    ok = bool(a.valid[k])  # no numbers where there is no linear loop
                    out.append({"configuration": name, "loop": loop, "condition": c.label(), "valid": ok,
                                "crossover_hz": float(m.crossover_hz[k]) if ok else float("nan"),
                                "phase_margin_deg": float(m.phase_margin_deg[k]) if ok else float("nan"),
                                "gain_margin_db": float(m.gain_margin_db[k]) if ok else float("nan"),
                                "bandwidth_hz": float(m.bandwidth_hz[k]) if ok else float("nan"),
                                "ms": float(m.ms[k]) if ok else float("nan"), "stable": bool(lm.stable[k])})
        return out


def analyse_configurations(design: Design, params: ParameterSet | None = None, *,
                           settings: AnalysisSettings | None = None, temperatures: Sequence[float] | None = None,
                           loads: Sequence[float] | None = None,
                           nut_speed: float | None = None) -> ConfigurationAnalysis:
    """Linear models and margins of the primary-active and standby-active configurations.

    Both plants have the two rotors (``standby_motor`` effect): the active
    one driven by its current loop, the other off and dragged (its current
    decays through the inverter's diodes).  Evaluated at the reference
    speed, for each temperature and load.

    Returns
    -------
    ConfigurationAnalysis
    """
    settings = settings or AnalysisSettings()
    params = params or default_parameters()
    effects = tuple(settings.effects) + (() if "standby_motor" in settings.effects else ("standby_motor",))
    model = plant_model(settings.level, effects, params, settings=settings.linearization)
    temps = tuple(settings.temperatures if temperatures is None else temperatures)
    loads = tuple(settings.load_forces if loads is None else loads)
    v = settings.reference_speed if nut_speed is None else nut_speed
    out = {}
    for active in ("primary", "standby"):
        grid = ConditionGrid((v,), loads, temps, active)
        out[active] = analyse_loops(design, params, grid, settings=replace(settings, effects=effects), model=model)
    return ConfigurationAnalysis(out["primary"], out["standby"])


# ----------------------------------------------------------------------------------------------------------------
# everything for one design (what the report draws)
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class DesignAnalysis:
    """Everything the analysis report shows for one design.

    Attributes
    ----------
    design : Design
    params : ParameterSet
    settings : AnalysisSettings
    loops : LoopAnalysis
        The grid.
    requirements : RequirementCheck
    limit_cycles : tuple of LimitCycle
    configurations : ConfigurationAnalysis or None
    switching : thsa_control.loops.switching.SwitchoverAnalysis or None
        The nonlinear switch-over transient (None when not run).
    timings : dict
        Wall time of each part [s].
    """

    design: Design
    params: ParameterSet
    settings: AnalysisSettings
    loops: LoopAnalysis
    requirements: RequirementCheck
    limit_cycles: tuple[LimitCycle, ...]
    configurations: ConfigurationAnalysis | None
    switching: object | None
    timings: dict


def analyse_design(design: Design, params: ParameterSet | None = None, *, settings: AnalysisSettings | None = None,
                   switching=True, configurations: bool = True, limit_cycles: bool = True) -> DesignAnalysis:
    """Grid analysis, requirement check, describing functions, configurations and switch-over of a design.

    Parameters
    ----------
    design : Design
    params : ParameterSet, optional
    settings : AnalysisSettings, optional
    switching : bool or SwitchoverAnalysis
        True: run :func:`thsa_control.loops.switching.analyse_switchover` (the
        nonlinear ``motor_fault_switch`` transient over detection delays) at
        the analysis level; False: skip; or a result computed beforehand.
    configurations, limit_cycles : bool
        Run :func:`analyse_configurations` / :func:`describing_functions`.

    Returns
    -------
    DesignAnalysis
    """
    settings = settings or AnalysisSettings()
    params = params or default_parameters()
    timings = {}
    t0 = time.perf_counter()
    model = plant_model(settings.level, settings.effects, params, settings=settings.linearization)
    loops = analyse_loops(design, params, settings=settings, model=model)
    timings["grid_s"] = time.perf_counter() - t0
    check = check_requirements(loops)
    t0 = time.perf_counter()
    cycles = describing_functions(design, params, settings=settings, model=model) if limit_cycles else ()
    timings["describing_functions_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    configs = analyse_configurations(design, params, settings=settings) if configurations else None
    timings["configurations_s"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if switching is True:
        from .switching import analyse_switchover

        sw = analyse_switchover(design, params, level=settings.level)
    else:
        sw = switching or None
    timings["switching_s"] = time.perf_counter() - t0
    return DesignAnalysis(design, params, settings, loops, check, tuple(cycles), configs, sw, timings)
