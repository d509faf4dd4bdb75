"""Loop analysis of the THSA cascade on linear models: margins, bandwidth, steps, over a grid.

Part of :mod:`thsa_control.loops.analysis` (which re-exports every public name here).

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
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from .loopmath import (
    MarginSet,
    StepMetrics,
    _SS,
    _Response,
    _close,
    _dcgain,
    frequency_grid,
    _gain_delay,
    _load_metrics,
    _margins,
    _pi,
    _series,
    _step,
    _zoh,
    step_metrics,
)
from .catalog import LOAD_STEP_UNITS, LOOPS, METRIC_LABELS, METRICS, metric_unit  # noqa: F401 (re-exported)
from .design import Design
from ..errors import DesignError, ThsaError
from .linear import (
    DEFAULT_EFFECTS,
    DEFAULT_LEVEL,
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
    "METRIC_LABELS",
    "metric_unit",
    "AnalysisSettings",
    "LoopMetrics",
    "LoopAnalysis",
    "WorstPoint",
    "analyse_loops",
]

# the loops, metrics and their units: one table in catalog.py (read by the reports too)

# ----------------------------------------------------------------------------------------------------------------
# settings
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class AnalysisSettings:
    """What the loop analysis covers (SI units).

    Parameters
    ----------
    level : str
        Model level (``'A'`` .. ``'D'``).  Default :data:`~thsa_control.loops.linear.DEFAULT_LEVEL`
        (``'B'``, no-back friction), as ``thsa report``.
    effects : tuple of str
        Effects added.  Default :data:`~thsa_control.loops.linear.DEFAULT_EFFECTS`, as ``thsa report``:
        temperature friction and the standby motor, whose rotor is always dragged (the plant that
        exists: J x 1.89 against one rotor); the primary is active.
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

    level: str = DEFAULT_LEVEL
    effects: tuple[str, ...] = DEFAULT_EFFECTS
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
        bad_t = [t for t in self.temperatures if not -55.0 <= t <= 70.0]
        if bad_t:
            raise ValueError(f"AnalysisSettings.temperatures: {bad_t[0]:g} degC is outside -55..70 degC")
        if not all(math.isfinite(v) for v in self.nut_speeds + self.load_forces):
            raise ValueError("AnalysisSettings: nut_speeds and load_forces must be finite")
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

    @classmethod
    def from_design(cls, design: Design, **overrides) -> "AnalysisSettings":
        """Settings from the design's optional ``[analysis]`` table, then ``overrides`` (None: not given).

        The table holds any of ``level``, ``effects`` (list of names), ``nut_speeds_mm_s``,
        ``loads_kN`` (compressive positive), ``temperatures_C``, ``reference_speed_mm_s`` and
        ``reference_load_kN`` (the file's units: mm/s, kN, degC); ``overrides`` are keyword
        arguments of this class in SI units (what ``thsa report --speeds/--loads/--temperatures``
        gives after conversion).  Command line over design file over defaults.

        Raises
        ------
        DesignError
            For an unknown key or a value of the wrong kind in the table, naming it.
        ThsaError
            For an override out of range (e.g. a temperature outside -55..70 degC).

        Examples
        --------
        >>> from thsa_control.loops.design import load_design, nominal_design_path
        >>> s = AnalysisSettings.from_design(load_design(nominal_design_path()), temperatures=(-30.0,))
        >>> s.temperatures, len(s.nut_speeds) * len(s.load_forces)
        ((-30.0,), 35)
        """
        table = dict(design.analysis or {})
        scale = {"nut_speeds_mm_s": ("nut_speeds", 1e-3), "loads_kN": ("load_forces", 1e3),
                 "temperatures_C": ("temperatures", 1.0)}
        single = {"reference_speed_mm_s": ("reference_speed", 1e-3), "reference_load_kN": ("reference_load", 1e3)}
        values: dict = {}
        for key, val in table.items():
            where = f"[analysis] {key} = {val!r}"
            if key == "level":
                if not isinstance(val, str):
                    raise DesignError(design.source, f"{where}: a level name is a string ('A' .. 'D')")
                values["level"] = val.upper()
            elif key == "effects":
                if not (isinstance(val, list) and all(isinstance(e, str) for e in val)):
                    raise DesignError(design.source, f"{where}: a list of effect names")
                values["effects"] = tuple(val)
            elif key in scale:
                name, k = scale[key]
                if not (isinstance(val, list) and val and all(_is_number(v) for v in val)):
                    raise DesignError(design.source, f"{where}: a non-empty list of numbers")
                values[name] = tuple(float(v) * k for v in val)
            elif key in single:
                name, k = single[key]
                if not _is_number(val):
                    raise DesignError(design.source, f"{where}: a number")
                values[name] = float(val) * k
            else:
                raise DesignError(design.source, f"unknown key {key!r} in [analysis]; allowed: "
                                                 f"{['level', 'effects', *scale, *single]}")
        try:
            settings = cls(**values)
        except ValueError as exc:
            raise DesignError(design.source, f"[analysis]: {exc}") from None
        try:
            return replace(settings, **{k: v for k, v in overrides.items() if v is not None})
        except ValueError as exc:
            raise ThsaError(f"analysis grid: {exc}") from None

    def grid(self, active: str = "primary") -> ConditionGrid:
        """The condition grid of these settings."""
        return ConditionGrid(self.nut_speeds, self.load_forces, self.temperatures, active)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


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
        if name in ("crossover_hz", "phase_margin_deg", "gain_margin_db", "gain_margin_lower_db",
                    "gain_margin_upper_db", "delay_margin_s", "bandwidth_hz", "ms"):
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


def build_loops(lin: PlantLinearization, design: Design, settings: AnalysisSettings) -> _Loops:
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
    omega = frequency_grid(h, settings.f_min, settings.n_frequencies)
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
            out_idx, unit = (2 if name == "velocity_loop" else 3), LOAD_STEP_UNITS[name]
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
    note: str = ""

    def text(self) -> str:
        """One line (a negative gain margin reads "conditionally stable", with both margins)."""
        where = "the same at every valid point" if self.uniform else f"at {self.condition.label()}"
        if self.note:
            return f"{self.loop} {self.metric}: {self.note} {where}"
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
        unit, how = metric_unit(loop, name), METRICS[name][1]
        vals = np.asarray(self.metric(loop, name), float)
        key = np.abs(vals) if how.endswith("abs") else vals
        key = np.where(self.valid & ~np.isnan(key), key, np.nan)
        if np.all(np.isnan(key)):
            return None
        if name in ("gain_margin_lower_db", "gain_margin_upper_db") and not np.any(np.isfinite(key)):
            return None  # no such crossing anywhere
        k = int(np.nanargmin(key) if how.startswith("min") else np.nanargmax(key))
        finite = key[np.isfinite(key)]
        uniform = bool(finite.size == np.count_nonzero(~np.isnan(key)) and finite.size > 1
                       and np.ptp(finite) <= 1e-6 * max(np.max(np.abs(finite)), 1e-300))
        note = ""
        if name.startswith("gain_margin") and vals[k] < 0:
            m = self.loops[loop].margins
            note = (f"conditionally stable (lower gain margin {m.gain_margin_lower_db[k]:.1f} dB, "
                    f"upper {m.gain_margin_upper_db[k]:+.1f} dB)")
        return WorstPoint(loop, name, float(vals[k]), unit, k, self.conditions[k], uniform, note)

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

    def report(self) -> str:
        """Worst point of each metric (display units) and the points not analysed."""
        from ..report.results import format_loop_analysis

        return format_loop_analysis(self)

    def to_dict(self) -> dict:
        """Every metric of every loop at every point (SI, unit in the key), JSON-able."""
        from ..report.results import loop_analysis_to_dict

        return loop_analysis_to_dict(self)

    def plot(self, ax=None, loop: str = "velocity_loop"):
        """Open-loop Bode plot of ``loop`` across the grid; ``ax``: (magnitude, phase) Axes."""
        from ..report.analysis_plots import plot_loop_bode

        return plot_loop_bode(self, loop, axes=ax)


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
    >>> round(float(a.metric("velocity_loop", "crossover_hz")[0]), 1)  # [Hz], designed for 30 Hz
    29.0
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
    loops = _metrics(build_loops(lin, design, settings), settings, steps)
    return LoopAnalysis(design, settings, lin, loops, grid, saturation_flags(lin, design, params))


def saturation_flags(lin: PlantLinearization, design: Design, params: ParameterSet) -> tuple[tuple[str, ...], ...]:
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


def margins_with_extra_delay(design: Design, params: ParameterSet, settings: AnalysisSettings, *,
                             loop: str = "velocity_loop", extra_delay: int = 0):
    """Margins of one loop over the grid with ``extra_delay`` more samples of delay in series with it.

    For robustness studies beyond the design's computation delay (the controllers take 0 or 1 sample).

    Returns
    -------
    margins : MarginSet
        Of every grid point (refined like :func:`analyse_loops`' margins).
    valid : ndarray of bool
        Points with a linear loop (linearisable and not saturated).
    unstable : ndarray of bool
        Points whose loop, closed with the extra delay, is unstable.
    """
    model = plant_model(settings.level, settings.effects, params, settings=settings.linearization)
    lin = linearize_conditions(model, settings.grid())
    loops = build_loops(lin, design, settings)
    sysL = loops.open[loop]
    if extra_delay:
        sysL = _series(_gain_delay(len(lin), 1.0, int(extra_delay)), sysL)
    h = design.control_period
    resp = _Response(sysL)
    L = resp.grid(np.exp(1j * loops.omega * h))
    cl, fb = loops.closed[loop]
    m = _margins(lambda i, w: resp.at(i, np.exp(1j * w * h)), loops.omega, L, _dcgain(cl, fb, 0))
    valid = lin.valid & ~np.array([bool(r) for r in saturation_flags(lin, design, params)])
    A = _close(sysL, _gain_delay(len(lin), 1.0, 0), 0, 0).A if extra_delay else cl.A
    unstable = valid & (np.max(np.abs(np.linalg.eigvals(A)), axis=1) >= 1 - 1e-12)
    return m, valid, unstable
