"""Replay a rig run through a declared model, in closed loop or driven by the measured current.

Two replays of one :class:`~thsa_control.data.rigdata.RigRun`:

* **closed loop** (:func:`replay_closed_loop`): the plant of the declared
  effect set, under the rig's cascade as the run's JSON gives it
  (:func:`run_design`), driven by the run's inputs (:func:`run_inputs`): the
  speed command, which the rig records already shaped, the load force, the
  temperature and the channel enables.  The command is rebuilt at the
  controller period from the samples (linear interpolation, or hold) and
  passed through the simulator's shaper with a rate limit so large that it
  changes nothing.  The simulator's shaper applies a target one control
  period later, so the rebuilt command is read one control period ahead:
  a run recorded at the control rate is reproduced exactly.
* **open loop** (:func:`replay_open_loop`): the mechanics alone, driven by
  the measured motor current.  Each sample period the plant's current state
  is overwritten with the measured current (interpolated linearly within the
  period) before each fixed step of the plant's own discrete map
  (:func:`current_driven_map`), so the motor torque is ``Kt i_measured`` and
  neither the controller nor the electrics take part.  The same map, mapped
  over segments, is what :mod:`thsa_control.fit.identify` differentiates.
  On a drive whose position integrates, this whole-run replay drifts:
  :mod:`thsa_control.fit.segmented` restarts it from the measured state
  every segment (what ``thsa residual --mode open_loop`` uses by default).

Both return a :class:`ReplayResult` with simulated and measured signals at the
run's sample times (SI, FORMAT.md signs) and the fit statistics of
:func:`channel_fit` (RMS, NRMSE and MATLAB ``compare``'s fit percent).

No physics is written here: everything goes through the plant's casadi
Functions and the simulator.  No file I/O (rigdata does it), no matplotlib.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType

import casadi as ca
import numpy as np

from linearization.buffered import call_dense

from ..loops.design import Design
from ..errors import RigDataError, ThsaError
from ..model.plant import SENSOR_OUTPUTS, Plant
from ..model.params import ParameterSet
from ..data.rigdata import RigRun, drive_on, motor_speed_from
from .kinematics import run_kinematics
from ..sim.simulate import InputSeries, SimulationSettings, Simulator

__all__ = [
    "FIT_CHANNELS",
    "MECH_INPUTS",
    "ChannelFit",
    "ReplaySettings",
    "ReplayResult",
    "channel_fit",
    "COMPARED_OUTPUT",
    "standby_active",
    "check_run_model",
    "rig_declared_effects",
    "compared_signals",
    "run_design",
    "run_inputs",
    "current_driven_map",
    "mech_inputs",
    "sample_periods",
    "replay_closed_loop",
    "replay_open_loop",
    "replay",
    "residual_signals",
    "analyse_replay",
]

#: Measured signals a replay is compared on (RigRun signal names, SI).
FIT_CHANNELS = ("motor_speed", "motor_current", "nut_position", "screw_speed")
#: Per-sample inputs of the current-driven map: measured current at the start
#: and end of the sample period [A], which motor carries it (1: standby), load
#: force at start and end [N, compressive positive], temperature [degC].
MECH_INPUTS = ("current_start", "current_end", "standby_active", "load_start", "load_end", "temperature")
#: Plant output each measured channel is compared with: what its sensor reads in the model's measurement
#: map (:data:`thsa_control.model.plant.SENSOR_OUTPUTS`; the LVDT reads the surface position).
COMPARED_OUTPUT = SENSOR_OUTPUTS
#: A plant-step count within this of a whole number is that whole number: a speed sensor's difference-quotient interval
#: over the plant step is a ratio of two sample periods in floating point (shooting.py snaps it, the
#: current-driven map splits it into whole steps and a fraction with it).
STEP_COUNT_TOL = 1e-6
#: Shaper rate limit that passes a recorded (already shaped) command through [m/s^2].
PASS_THROUGH_ACCEL = 1e9
#: Speed cap [m/s] of a run's position loop that states none (the Design needs a finite one).
UNLIMITED_SPEED = 1e3


@dataclass(frozen=True)
class ChannelFit:
    """Fit of one channel, as MATLAB's ``compare`` and ``goodnessOfFit`` define it.

    Attributes
    ----------
    channel : str
    unit : str
        SI unit of ``rms`` and ``max_abs``.
    n : int
        Samples used (finite in both signals).
    rms : float
        Root mean square of ``measured - simulated``.
    max_abs : float
        Largest absolute residual.
    nrmse : float
        ``||y - yhat|| / ||y - mean(y)||`` [-] (inf for a constant measurement).
    fit_percent : float
        ``100 (1 - nrmse)`` [%]; 100 is a perfect fit, it may be negative.
    """

    channel: str
    unit: str
    n: int
    rms: float
    max_abs: float
    nrmse: float
    fit_percent: float

    def to_dict(self) -> dict:
        """JSON-ready dict (non-finite numbers as None)."""
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
                for k, v in self.__dict__.items()}


_UNITS = {"motor_speed": "rad/s", "motor_current": "A", "nut_position": "m", "screw_speed": "rad/s",
          "missing_torque": "N m"}


def channel_fit(channel: str, measured, simulated, unit: str | None = None) -> ChannelFit:
    """Fit statistics of one channel (NaN samples of either signal are skipped).

    Parameters
    ----------
    channel : str
        Name for the record.
    measured, simulated : array_like
        Same length, same unit.
    unit : str, optional
        Unit of the signals (default from the channel name).

    Returns
    -------
    ChannelFit

    Examples
    --------
    >>> f = channel_fit("x", [0.0, 1.0, 2.0, 3.0], [0.0, 1.0, 2.0, 2.0])
    >>> round(f.nrmse, 4), round(f.fit_percent, 2), f.max_abs
    (0.4472, 55.28, 1.0)
    """
    y = np.asarray(measured, dtype=float)
    yhat = np.asarray(simulated, dtype=float)
    if y.shape != yhat.shape:
        raise ValueError(f"channel {channel!r}: measured {y.shape} and simulated {yhat.shape} differ in shape")
    ok = np.isfinite(y) & np.isfinite(yhat)
    y, yhat = y[ok], yhat[ok]
    if y.size == 0:
        return ChannelFit(channel, unit or _UNITS.get(channel, "?"), 0, math.nan, math.nan, math.nan, math.nan)
    e = y - yhat
    spread = float(np.linalg.norm(y - y.mean()))
    nrmse = float(np.linalg.norm(e)) / spread if spread > 0 else math.inf
    return ChannelFit(channel, unit or _UNITS.get(channel, "?"), int(y.size), float(np.sqrt(np.mean(e**2))),
                      float(np.max(np.abs(e))), nrmse, 100.0 * (1.0 - nrmse))


@dataclass(frozen=True)
class ReplaySettings:
    """How a run is replayed.

    Parameters
    ----------
    command_interpolation : {"linear", "hold"}
        How the recorded speed command, load and enables are rebuilt at the
        controller period between samples (enables are always held).
    substeps : int
        Plant steps per control period (closed loop) or per sample period
        (open loop).
    compiled : bool
        Closed loop: use the simulator's compiled C loop.
    """

    command_interpolation: str = "linear"
    substeps: int = 1
    compiled: bool = True

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        if self.command_interpolation not in ("linear", "hold"):
            raise ValueError(f"ReplaySettings.command_interpolation = {self.command_interpolation!r}: "
                             "expected 'linear' or 'hold'")
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"ReplaySettings.substeps = {self.substeps!r} must be an integer >= 1")


@dataclass(frozen=True)
class ReplayResult:
    """Simulated and measured signals of one run at the run's sample times.

    Attributes
    ----------
    run_name : str
    mode : {"closed_loop", "open_loop"}
    time : ndarray
        The run's sample times [s].
    simulated : mapping name -> ndarray
        Every plant output (and, closed loop, the controller signals), SI.
    measured : mapping name -> ndarray
        The run's measured channels among :data:`FIT_CHANNELS`, SI.
    effects : tuple of str
    params : ParameterSet
    fits : mapping channel -> ChannelFit
        Fit of each measured channel (open loop: not ``motor_current``, which
        drives it).
    info : dict
        ``wall_s``, substeps, the design (closed loop).
    compared : mapping channel -> ndarray
        The simulated signal each measured channel is compared with
        (:func:`compared_signals`: the LVDT with the surface position, the
        current with the active channel's).
    """

    run_name: str
    mode: str
    time: np.ndarray
    simulated: MappingProxyType
    measured: MappingProxyType
    effects: tuple[str, ...]
    params: ParameterSet
    fits: MappingProxyType
    info: dict = field(default_factory=dict)
    compared: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))

    @property
    def channels(self) -> tuple[str, ...]:
        """Channels compared (measured and simulated)."""
        return tuple(self.fits)

    def residual(self, channel: str) -> np.ndarray:
        """``measured - simulated`` of ``channel`` (SI)."""
        sim = self.compared[channel] if channel in self.compared else self.simulated[channel]
        return np.asarray(self.measured[channel]) - np.asarray(sim)

    def report(self) -> str:
        """Fit of every compared channel, in display units."""
        from ..report.results import format_replay

        return format_replay(self)

    def to_dict(self) -> dict:
        """Run, mode, effects and the fit of each channel (SI), JSON-able."""
        from ..report.results import replay_to_dict

        return replay_to_dict(self)

    def plot(self, ax=None):
        """Measured and simulated channels, one panel each; ``ax``: one Axes per channel."""
        from ..report.results import plot_replay

        return plot_replay(self, ax)


# ----------------------------------------------------------------- inputs
def run_design(run: RigRun, *, name: str | None = None) -> Design:
    """The rig's cascade of ``run`` (its JSON ``controller`` block) as a :class:`Design`.

    Without the block's ``position_loop`` (an extension, ``docs/rig_format.md``)
    the position loop is open (``position_kp = 0``): a replay feeds the
    recorded speed command.  With it, its P gain and speed cap
    (:data:`UNLIMITED_SPEED` when the run gives none) close the loop on the
    CSV's ``position_cmd_mm`` (:func:`run_inputs`).  The controller block's
    free key ``computation_delay_samples`` (0 or 1, written by the workbench)
    is honoured; absent, no delay.

    Raises
    ------
    RigDataError
        The run's JSON has no ``controller`` block.
    """
    c = run.controller
    if c is None:
        raise RigDataError(str(run.json_path), [(f"{run.json_path.name}:controller", None,
                                                 "missing: a closed-loop replay needs the rig's controller")])
    pl = c.position_loop
    return Design(name=name or f"{run.name} (rig controller)", current_kp=c.current_loop.kp,
                  current_ki=c.current_loop.ki, voltage_limit=c.current_loop.voltage_limit,
                  velocity_kp=c.velocity_loop.kp, velocity_ki=c.velocity_loop.ki,
                  current_limit=c.velocity_loop.current_limit, position_kp=pl.kp if pl else 0.0,
                  max_speed=min(pl.max_speed, UNLIMITED_SPEED) if pl else Design.max_speed,
                  control_period=c.control_period, source=str(run.json_path),
                  computation_delay_samples=_delay_samples(c.extra.get("computation_delay_samples", 0), run))


def _delay_samples(value, run: RigRun) -> int:
    """``controller.computation_delay_samples`` of the run's JSON (free metadata; 0 when absent)."""
    if isinstance(value, bool) or value not in (0, 1):
        raise RigDataError(str(run.json_path), [(f"{run.json_path.name}:controller.computation_delay_samples", None,
                                                 f"must be 0 or 1, got {value!r}")])
    return int(value)


def _fill_single_gaps(t: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Inputs only: an isolated NaN (the reader allows one) is interpolated between its neighbours."""
    bad = ~np.isfinite(y)
    if not bad.any():
        return y
    return np.interp(t, t[~bad], y[~bad])


def _resample(t_run, y, t, how: str):
    if how == "hold":
        idx = np.clip(np.searchsorted(t_run, t + 1e-12 * max(1.0, abs(t_run[-1])), side="right") - 1, 0, len(t_run) - 1)
        return np.asarray(y, float)[idx]
    return np.interp(t, t_run, y)


def run_inputs(run: RigRun, control_period: float, *, interpolation: str = "linear") -> InputSeries:
    """The run's inputs at the controller period, ready for :class:`~thsa_control.sim.simulate.Simulator`.

    Parameters
    ----------
    run : RigRun
    control_period : float
        [s].
    interpolation : {"linear", "hold"}
        Rebuilding of the speed command and the load between samples.

    Returns
    -------
    InputSeries
        Starting at ``run.time[0]``, covering the last sample.  ``speed_target``
        is the recorded command read one control period ahead (the shaper's
        one-period delay), ``accel_limit`` is :data:`PASS_THROUGH_ACCEL`;
        position loop open; motors off at zero command as the JSON says.
        When the JSON's controller has a ``position_loop``, the loop is closed
        on ``position_cmd_mm`` (rebuilt like the command) and the shaper
        limits are the loop's ``accel_limit`` / ``jerk_limit``; the recorded
        speed command is then an output of the rig, not an input.  A
        ``current_feedforward`` gives ``current_ff`` (offset plus its column,
        rebuilt like the command).
    """
    t_run = np.asarray(run.time, float)
    n = int(math.floor((t_run[-1] - t_run[0]) / control_period + 1e-6)) + 1
    t = t_run[0] + np.arange(n) * control_period
    sig = run.signals
    cmd = _resample(t_run, _fill_single_gaps(t_run, sig["speed_cmd"]), t + control_period, interpolation)
    load = _resample(t_run, _fill_single_gaps(t_run, sig["load_force"]), t, interpolation)
    temp = _resample(t_run, _fill_single_gaps(t_run, sig["temperature"]), t, "linear")
    c = run.controller
    pl = c.position_loop if c is not None else None
    ff = c.current_feedforward if c is not None else None
    current_ff = np.zeros(n)
    if ff is not None:
        current_ff += ff.offset
        if ff.column is not None:
            current_ff += _resample(t_run, np.asarray(run.extra[ff.column], float), t, interpolation)
    signals = {
        "speed_target": cmd,
        "position_cmd": _resample(t_run, sig["position_cmd"], t, interpolation) if pl else np.zeros(n),
        "position_mode": np.full(n, 1.0 if pl else 0.0),
        "primary_enable": _resample(t_run, sig["primary_enable"], t, "hold"),
        "standby_enable": _resample(t_run, sig["standby_enable"], t, "hold"),
        "load_force": load, "temperature": temp, "current_ff": current_ff,
    }
    accel, jerk = (min(pl.accel_limit, PASS_THROUGH_ACCEL), pl.jerk_limit) if pl else (PASS_THROUGH_ACCEL, math.inf)
    return InputSeries(run.name, t, signals, accel, jerk, bool(run.motor_disabled_when_cmd_zero),
                       str(run.metadata.get("description", "")))


def standby_active(run: RigRun) -> np.ndarray:
    """1 where the standby channel carries the torque (standby enabled, primary off), else 0."""
    return ((np.asarray(run.signals["standby_enable"]) > 0.5)
            & (np.asarray(run.signals["primary_enable"]) < 0.5)).astype(float)


def _rig_motors(run: RigRun):
    """The motor count the run JSON's ``rig`` block gives (None when it gives none)."""
    rig = run.metadata.get("rig") if isinstance(run.metadata, dict) else None
    return rig.get("motors") if isinstance(rig, dict) else None


def _standby_enabled(run: RigRun) -> bool:
    """Whether the run enables the standby channel at any sample."""
    return bool(np.any(np.asarray(run.signals["standby_enable"]) > 0.5))


def rig_declared_effects(runs: Sequence[RigRun]) -> dict[str, str]:
    """Effects the runs' own rig description declares: ``{effect: why}``.

    The run JSON's ``rig`` block describes the hardware, not physics to be
    found: ``rig.motors = 2`` means a second rotor is carried along (torque
    summed at the gearbox input), which is the ``standby_motor`` effect.  A
    run that enables the standby channel needs it too.  Runs that disagree
    (one says two motors, another one) give nothing: the caller keeps the
    declared model and :func:`check_run_model` warns per run.
    """
    why = []
    for run in runs:
        if _rig_motors(run) == 2:
            why.append(f"run {run.name!r}: rig.motors = 2")
        elif _standby_enabled(run):
            why.append(f"run {run.name!r}: standby_enable set")
        else:
            return {}
    return {"standby_motor": "; ".join(why)} if why else {}


def check_run_model(run: RigRun, plant: Plant, *, mode: str = "closed_loop") -> list[str]:
    """Refuse a run that the declared model cannot reproduce; return warnings for what it only approximates.

    A run that enables the standby channel needs the ``standby_motor`` effect
    in closed loop (without it the model has no torque after a switch-over).
    Driven by the measured current (open loop, identification), the current
    of the active channel drives the one motor of the model: a warning says
    that the standby rotor's inertia and drag are missing.

    Raises
    ------
    ModelError
        Closed loop, standby enabled in the run, no ``standby_motor`` in the model.
    """
    from ..errors import ModelError

    uses_standby = _standby_enabled(run)
    if not uses_standby and _rig_motors(run) == 2 and "standby_motor" not in plant.effects:
        # the run JSON's rig block (as this project writes it) says a second rotor is carried along: without it
        # the model has half the rotor inertia (rig-sim's speed-chirp run: motor-speed error 11.5 -> 1.8 rad/s
        # rms with it)
        return [f"run {run.name!r}: its JSON says rig.motors = 2 (a standby rotor carried along) but the model "
                f"({', '.join(plant.effects) or 'level A'}) has one motor: the standby rotor's inertia and drag are "
                "missing; add the effect standby_motor (--effects standby_motor)"]
    if not uses_standby or "standby_motor" in plant.effects:
        return []
    msg = (f"run {run.name!r} enables the standby channel (standby_enable) but the model "
           f"({', '.join(plant.effects) or 'level A'}) has no standby motor; add the effect standby_motor "
           "(--effects standby_motor)")
    if mode == "closed_loop":
        raise ModelError(msg)
    return [msg + "; driven by the measured current, the active channel's current drives the model's one motor "
            "(the standby rotor's inertia and drag are missing)"]


def compared_signals(run: RigRun, simulated: dict, channels) -> dict[str, np.ndarray]:
    """The simulated signal each measured channel is compared with (:data:`COMPARED_OUTPUT`).

    ``motor_current`` is the active channel's current: the standby motor's
    after a switch-over (standby enabled, primary off), the primary's
    otherwise (FORMAT.md: the column is the active motor's current).
    """
    out = {}
    for c in channels:
        y = np.asarray(simulated[COMPARED_OUTPUT.get(c, c)], float)
        if c == "motor_current" and "standby_current" in simulated:
            y = np.where(standby_active(run) > 0.5, np.asarray(simulated["standby_current"], float), y)
        out[c] = y
    return out


def measured_signals(run: RigRun) -> dict[str, np.ndarray]:
    """The run's measured fit channels (FIT_CHANNELS it has a column for) as float arrays."""
    return {c: np.asarray(run.signals[c], float) for c in FIT_CHANNELS if c in run.source_columns}


def _initial_nut_position(run: RigRun) -> float:
    if "nut_position" in run.source_columns:
        x = np.asarray(run.signals["nut_position"][:5], float)
        x = x[np.isfinite(x)]
        return float(np.median(x)) if x.size else 0.0
    return 0.0


def _uniform_decimation(t_run: np.ndarray, h: float) -> int | None:
    dt = np.diff(t_run)
    if dt.size == 0:
        return 1
    d = int(round(float(np.median(dt)) / h))
    if d >= 1 and np.allclose(dt, d * h, rtol=1e-6, atol=1e-9):
        return d
    return None


# ----------------------------------------------------------------- closed loop
def replay_closed_loop(run: RigRun, plant: Plant, params: ParameterSet, *, design: Design | None = None,
                       settings: ReplaySettings | None = None) -> ReplayResult:
    """Simulate ``plant`` under the run's controller with the run's inputs.

    Parameters
    ----------
    run : RigRun
    plant : Plant
        Declared effect set.
    params : ParameterSet
        Declared parameters.
    design : Design, optional
        Controller; default :func:`run_design` (the run's JSON).
    settings : ReplaySettings, optional

    Returns
    -------
    ReplayResult
        Outputs at the run's sample times (decimated when the run is sampled
        uniformly at a multiple of the control period, else linearly
        interpolated from every control period).

    Raises
    ------
    RigDataError
        No controller in the run's JSON and none given.
    ThsaError
        The simulation diverged.
    """
    settings = settings or ReplaySettings()
    settings.validate()
    run = run_kinematics(run, params)  # one source of truth: a run stating other kinematics is refused
    check_run_model(run, plant, mode="closed_loop")
    design = design or run_design(run)
    h = design.control_period
    inputs = run_inputs(run, h, interpolation=settings.command_interpolation)
    t_run = np.asarray(run.time, float)
    dec = _uniform_decimation(t_run, h)
    sim = Simulator(plant, SimulationSettings(substeps=settings.substeps, output_period=(dec or 1) * h,
                                              compiled=settings.compiled))
    x0 = plant.initial_state(params, load_force=float(inputs.signals["load_force"][0]),
                             nut_position=_initial_nut_position(run))
    res = sim.run(inputs, design, params, x0=x0)
    t_sim = t_run[0] + np.asarray(res.time)
    simulated = {}
    for name in res.names:
        y = np.asarray(res[name])
        if dec is not None and len(y) >= len(t_run):
            y = y[:len(t_run)]
        else:
            y = np.interp(t_run, t_sim, y)
        simulated[name] = y
    measured = measured_signals(run)
    compared = compared_signals(run, simulated, measured)
    fits = {c: channel_fit(c, measured[c], compared[c]) for c in measured}
    info = {"wall_s": res.info["wall_s"], "substeps": settings.substeps, "design": design.name,
            "control_period_s": h, "command_interpolation": settings.command_interpolation}
    return ReplayResult(run.name, "closed_loop", t_run, MappingProxyType(simulated), MappingProxyType(measured),
                        plant.effects, params, MappingProxyType(fits), info, MappingProxyType(compared))


# ----------------------------------------------------------------- open loop
def current_driven_map(plant: Plant, substeps: int = 1, quotients: Mapping[str, int] | None = None) -> ca.Function:
    """One sample period of the mechanics driven by a measured current.

    ``mech(x, v, p, h) -> (x_next, y)`` with ``v`` = :data:`MECH_INPUTS`,
    ``h`` the sample period [s].  With ``quotients`` (speed-sensor channel of the plant's measurement map ->
    number of plant steps ``m``, 0 < m <= substeps) a third output ``q`` holds, per channel in that order, the
    sensor's reading at the period's *end* as a difference quotient: the angle travelled over the last ``m``
    plant steps divided by their duration (the mean of the speeds the positions were integrated with: the
    resolver's or RVDT's speed estimate, not the instantaneous speed).  A fractional ``m`` (a difference
    interval that is not a whole number of plant steps: a resolver differenced over 1 ms, logged at 500 Hz, fitted
    at one step per sample) takes the whole steps and, of the step before them, the mean speed over its last
    fraction: each step's speed is the mean over that step (the semi-implicit Euler integrates the angle with
    it), so it stands at the step's middle, and between the middles of that step and the one before it the speed
    is interpolated linearly (exact for a constant acceleration).  Before each of the ``substeps`` plant
    steps the motor current state (the standby current when
    ``standby_active``) is overwritten with the current interpolated linearly
    between ``current_start`` and ``current_end``; the load force likewise.
    Voltages are zero and the inverters on: the electrics do not act, since
    the current state is overwritten again before it is used.  ``y`` is the
    plant's outputs at the period's start.

    Examples
    --------
    >>> from thsa_control.model import build_plant
    >>> current_driven_map(build_plant("A")).name_in()
    ['x', 'v', 'p', 'h']
    """
    if not (isinstance(substeps, int) and substeps >= 1):
        raise ValueError(f"substeps = {substeps!r} must be an integer >= 1")
    nx = len(plant.states)
    x = ca.SX.sym("x", nx)
    v = ca.SX.sym("v", len(MECH_INPUTS))
    p = ca.SX.sym("p", len(plant.parameters))
    h = ca.SX.sym("h")
    V = dict(zip(MECH_INPUTS, ca.vertsplit(v)))
    names = plant.state_names
    i_main = names.index("motor_current")
    i_stby = names.index("standby_current") if "standby_current" in names else None
    inp = {n: i for i, n in enumerate(plant.inputs)}
    hs = h / substeps
    y0 = None
    xk = x
    quotients = dict(quotients or {})
    for c, m in quotients.items():
        if not (isinstance(m, (int, float)) and 0 < m <= substeps):
            raise ValueError(f"quotient steps of {c!r} = {m!r} must be a number in (0, {substeps}]")
    speeds = {c: [] for c in quotients}
    i_speed = {c: names.index(plant.sensor_state(c)) for c in quotients}
    scale = {c: (plant.sensors[c].scale(p) if plant.sensors[c].scale is not None else 1.0) for c in quotients}
    for j in range(substeps):
        frac = j / substeps
        cur = V["current_start"] + frac * (V["current_end"] - V["current_start"])
        load = V["load_start"] + frac * (V["load_end"] - V["load_start"])
        parts = ca.vertsplit(xk)
        if i_stby is None:
            parts[i_main] = cur
        else:
            parts[i_main] = (1 - V["standby_active"]) * cur
            parts[i_stby] = V["standby_active"] * cur
        xk = ca.vertcat(*parts)
        u = [ca.SX(0.0)] * len(plant.inputs)
        u[inp["enable_primary"]] = ca.SX(1.0)
        u[inp["enable_standby"]] = ca.SX(1.0) if i_stby is not None else ca.SX(0.0)
        u[inp["load_force"]] = load
        u[inp["temperature"]] = V["temperature"]
        xk, y = plant.step(xk, ca.vertcat(*u), p, hs)
        if j == 0:
            y0 = y
        for c in quotients:
            speeds[c].append(xk[i_speed[c]])
    if quotients:
        q = []
        for c, m in quotients.items():
            whole = math.floor(m + STEP_COUNT_TOL)
            frac = m - whole if m - whole > STEP_COUNT_TOL else 0.0
            total = sum(speeds[c][substeps - whole:]) if whole else ca.SX(0.0)
            if frac:
                # the step before the whole ones (index j; its predecessor the period's start speed when j = 0)
                j = substeps - whole - 1
                s_j = speeds[c][j]
                s_prev = speeds[c][j - 1] if j >= 1 else x[i_speed[c]]
                total = total + frac * (s_j + 0.5 * (1.0 - frac) * (s_j - s_prev))
            q.append(scale[c] * total / m)
        return ca.Function("mech_q", [x, v, p, h], [xk, y0, ca.vertcat(*q)], ["x", "v", "p", "h"],
                           ["x_next", "y", "q"])
    return ca.Function("mech", [x, v, p, h], [xk, y0], ["x", "v", "p", "h"], ["x_next", "y"])


def mech_inputs(run: RigRun) -> np.ndarray:
    """The run's :data:`MECH_INPUTS`, one column per sample period (the last sample repeated).

    Raises
    ------
    RigDataError
        The run has no ``motor_current`` column.
    """
    if "motor_current" not in run.source_columns:
        raise RigDataError(str(run.csv_path), [("motor_current_A", None,
                                                "missing: the open-loop replay is driven by the measured current")])
    t = np.asarray(run.time, float)
    i = _fill_single_gaps(t, np.asarray(run.signals["motor_current"], float))
    f = _fill_single_gaps(t, np.asarray(run.signals["load_force"], float))
    temp = _fill_single_gaps(t, np.asarray(run.signals["temperature"], float))
    stby = standby_active(run)
    nxt = np.r_[np.arange(1, len(t)), len(t) - 1]
    return np.vstack([i, i[nxt], stby, f, f[nxt], temp])


def sample_periods(run: RigRun) -> np.ndarray:
    """Length of each sample period [s] (the last repeats the one before)."""
    dt = np.diff(np.asarray(run.time, float))
    return np.r_[dt, dt[-1:]] if dt.size else np.array([1e-3])


#: Periods per casadi ``mapaccum`` of :func:`run_map`.  casadi builds a mapaccum as a tower of unrolled calls
#: (``base`` 10); from 10^4 periods on one more level makes building it about 10 times slower (measured, casadi
#: 3.8: 0.1 s for 9999 periods, 0.8-1.2 s for 10^4 to 4 x 10^4), while evaluating costs the same per period.
_MAP_CHUNK = 5000


def run_map(step: ca.Function, x0, V: np.ndarray, p: np.ndarray, hs: np.ndarray) -> np.ndarray:
    """The outputs (one column per period) of ``step(x, v, p, h) -> (x_next, y)`` strung over the columns of ``V``
    from ``x0``, ``p`` fixed, ``hs`` the periods: ``step.mapaccum`` over every column, in chunks of
    :data:`_MAP_CHUNK` periods, each starting from the state the one before ended in (the same steps in the same
    order: the same numbers as one mapaccum over the whole run, bit for bit)."""
    n = V.shape[1]
    x = np.asarray(x0, float)
    p = np.asarray(p, float).reshape(-1, 1)
    hs = np.asarray(hs, float)
    maps: dict[int, ca.Function] = {}
    out = []
    for a in range(0, n, _MAP_CHUNK):
        m = min(_MAP_CHUNK, n - a)
        F = maps.get(m)
        if F is None:
            F = maps[m] = step.mapaccum("mech_run", m)
        X, Y = call_dense(F, x, V[:, a:a + m], np.repeat(p, m, axis=1), hs[None, a:a + m])
        x = X[:, -1]
        out.append(Y)
    return np.concatenate(out, axis=1) if out else np.zeros((step.size1_out(1), 0))


def replay_open_loop(run: RigRun, plant: Plant, params: ParameterSet, *, settings: ReplaySettings | None = None,
                     x0: np.ndarray | None = None) -> ReplayResult:
    """Replay the mechanics of ``plant`` driven by the run's measured current.

    Parameters
    ----------
    run : RigRun
        Needs ``motor_current``.
    plant : Plant
    params : ParameterSet
    settings : ReplaySettings, optional
        ``substeps`` plant steps per sample period.
    x0 : array_like, optional
        Initial plant state; default at rest in equilibrium with the first
        load sample, nut at its first measured position.

    Returns
    -------
    ReplayResult
        ``fits`` leaves out ``motor_current`` (it is the input).
    """
    import time as _time

    import warnings as _warnings

    settings = settings or ReplaySettings()
    settings.validate()
    run = run_kinematics(run, params)
    for msg in check_run_model(run, plant, mode="open_loop"):
        _warnings.warn(msg, stacklevel=2)
    V = mech_inputs(run)
    hs = sample_periods(run)
    p = plant.p_vector(params)
    if x0 is None:
        x0 = plant.initial_state(params, load_force=float(V[3, 0]), nut_position=_initial_nut_position(run))
    mech = current_driven_map(plant, settings.substeps)
    t0 = _time.perf_counter()
    Y = run_map(mech, x0, V, p, hs)
    wall = _time.perf_counter() - t0
    if not np.all(np.isfinite(Y)):
        raise ThsaError(f"open-loop replay of {run.name!r} diverged")
    simulated = {name: Y[i] for i, name in enumerate(plant.outputs)}
    measured = measured_signals(run)
    compared = compared_signals(run, simulated, [c for c in measured if c != "motor_current"])
    fits = {c: channel_fit(c, measured[c], compared[c]) for c in compared}
    info = {"wall_s": wall, "substeps": settings.substeps, "open_loop_replay": "whole_run", "segment_s": None,
            "segments": 1}
    return ReplayResult(run.name, "open_loop", np.asarray(run.time, float), MappingProxyType(simulated),
                        MappingProxyType(measured), plant.effects, params, MappingProxyType(fits), info,
                        MappingProxyType(compared))


def replay(run: RigRun, level: str | None = "A", effects=(), *, params: ParameterSet | None = None,
           mode: str = "closed_loop", design: Design | None = None,
           settings: ReplaySettings | None = None) -> ReplayResult:
    """Build the plant of ``level`` + ``effects`` and replay ``run`` (``mode``: closed_loop / open_loop).

    Raises
    ------
    ValueError
        Unknown mode.
    """
    from ..model import build_plant
    from ..model.params import default_parameters

    params = params or default_parameters()
    plant = build_plant(level, effects, params=params)
    if mode == "closed_loop":
        return replay_closed_loop(run, plant, params, design=design, settings=settings)
    if mode == "open_loop":
        return replay_open_loop(run, plant, params, settings=settings)
    raise ValueError(f"replay mode {mode!r}: expected 'closed_loop' or 'open_loop'")


def residual_signals(run: RigRun, result: ReplayResult) -> tuple[dict, dict]:
    """Operating variables to condition the residual on, and inputs to cross-correlate with.

    Conditioning (FORMAT.md signs): nut speed command [m/s], load [N],
    quadrant (opposing / aiding / unloaded, from the command and the load),
    direction of motion (sign of the measured motor speed, else of ratio x
    screw speed, else of the command; stopped within 5 % of its peak: a
    friction shows as residual means of opposite signs),
    temperature [degC], nut position [m] and motor electrical angle [rad]
    (as simulated: they are not noisy), time to the nearest direction
    reversal [s], motors on/off [0/1].  Inputs: load force, speed command,
    and (open loop) the measured current that drives the replay.
    """
    from .residuals import quadrant, reversal_proximity, wrapped_angle

    s = run.signals
    t = np.asarray(run.time, float)
    cmd = np.asarray(s["speed_cmd"], float)
    load = np.asarray(s["load_force"], float)
    on = drive_on(run)
    sim = result.simulated
    deadband = 0.05 * float(np.max(np.abs(cmd))) if cmd.size and np.any(cmd) else 0.0
    pole_pairs = result.params.value("motor.pole_pairs")
    meas = result.measured
    speed = motor_speed_from(lambda c: np.asarray(meas[c], float) if c in meas else None, run.gear_ratio)
    speed = cmd if speed is None else speed
    speed = np.nan_to_num(speed)
    moving = 0.05 * float(np.max(np.abs(speed))) if speed.size else 0.0
    conditioning = {
        "speed_cmd": cmd, "load_force": load,
        "direction": np.where(np.abs(speed) > moving, np.sign(speed), 0.0),
        "quadrant": quadrant(cmd, load, (deadband, 0.02 * float(np.max(np.abs(load))) if np.any(load) else 0.0)),
        "temperature": np.asarray(s["temperature"], float), "nut_position": np.asarray(sim["nut_position"], float),
        "motor_angle": wrapped_angle(t, sim["motor_speed"], periods_per_revolution=pole_pairs),
        "reversal_proximity": np.minimum(reversal_proximity(t, cmd, deadband=deadband), 1e3),
        "motor_on": on.astype(float),
    }
    inputs = {"load_force": load, "speed_cmd": cmd}
    if result.mode == "open_loop" and "motor_current" in result.measured:
        inputs["motor_current"] = np.nan_to_num(np.asarray(result.measured["motor_current"], float))
    return conditioning, inputs


def analyse_replay(run: RigRun, result: ReplayResult, settings=None):
    """Residual analysis (:func:`thsa_control.fit.residuals.analyse_residuals`) of a replay's fitted channels."""
    from .residuals import analyse_residuals

    conditioning, inputs = residual_signals(run, result)
    channels = list(result.fits)
    return analyse_residuals(result.time, {c: result.measured[c] for c in channels},
                             {c: result.compared[c] if c in result.compared else result.simulated[c] for c in channels},
                             conditioning, inputs, settings=settings,
                             units={c: _UNITS.get(c, "") for c in channels})
