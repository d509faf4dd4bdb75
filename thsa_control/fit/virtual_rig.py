"""Virtual rig: writes ``thsa-rig-run/1`` runs from any effect set with known truth.

A :class:`VirtualRig` is the documented generator of test data with known
truth.  It runs the project's closed-loop simulator (the plant of a level
plus effects, the sampled-data cascade of a :class:`~thsa_control.loops.design.Design`)
on a scenario or an :class:`~thsa_control.sim.simulate.InputSeries`, samples the
outputs at ``sample_rate_hz`` (a divisor of the control rate), adds white
Gaussian sensor noise and quantisation per column, and writes the pair
``STEM.csv`` / ``STEM.json`` with :func:`thsa_control.data.rigdata.write_run`
(atomic, read back before it is published).

What the generator does, in order, per column (FORMAT.md units):

1. the noise-free simulated value at the sample instant (the simulator's
   outputs at the start of the control period);
2. ``+ noise[column] * N(0, 1)`` (``np.random.default_rng(seed)``; one stream,
   columns drawn in FORMAT.md order, so a seed gives the same file);
3. quantised: ``q * round(value / q)`` with ``q = quantisation[column]``.

The speed command, the enables and ``time_s`` are written exact (they are
what the rig commanded).  The JSON holds the controller as it ran, the
noise and quantisation, and a ``truth`` block: level, effects and every
parameter value of the plant, so that identification can be checked.

:func:`excitation_inputs` builds an identification excitation like the one of
``shared/rig-data/examples``: plateaus of constant speed under a constant
load with a Schroeder multi-sine and a PRBS on top.  :func:`position_inputs`
builds a position-loop run (moves between positions, optionally a current
added at the controller output); the JSON then holds the run's
``controller.position_loop`` and ``controller.current_feedforward``
(``docs/rig_format.md``), so that a replay closes the same loop.

This module does no physics and imports no matplotlib.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..loops.design import Design, load_design, nominal_design_path
from ..data.export import FEEDFORWARD_COLUMN, rig_columns, rig_metadata
from ..model import build_plant
from ..model.params import ParameterSet, default_parameters
from ..data.rigdata import COLUMNS, write_run
from ..sim.scenarios import Scenario
from ..sim.simulate import InputSeries, SimulationResult, SimulationSettings, Simulator

__all__ = ["VirtualRig", "excitation_inputs", "position_inputs", "NOISY_COLUMNS"]

#: Columns that may carry sensor noise and quantisation (the rig's sensors).
NOISY_COLUMNS = ("load_force_N", "motor_speed_rpm", "motor_current_A", "nut_position_mm", "screw_speed_rpm",
                 "temperature_C")


@dataclass(frozen=True)
class VirtualRig:
    """A simulated test rig with known truth.

    The constructor stores its configuration; :meth:`record` does the work.

    Parameters
    ----------
    level : {"A", "B", "C", "D"} or None
        Model level of the truth.
    effects : tuple of str
        Effects added to the level.
    params : ParameterSet, optional
        True parameters (default: the embedded actuator).
    design : Design, optional
        The rig's cascade (default ``designs/nominal.toml``).
    noise : mapping column -> float
        Sensor noise RMS per FORMAT.md column, in the column's unit
        (``{"motor_speed_rpm": 2.0, "nut_position_mm": 0.005}``).
    quantisation : mapping column -> float
        Quantisation step per column, in the column's unit.
    sample_rate_hz : float
        Sampling rate [Hz]; the control period times an integer.
    seed : int
        Seed of the noise generator.
    substeps : int
        Plant steps per control period.
    truth_columns : bool
        Also write every other simulated signal, noise-free, as extra columns
        (``noback_torque_Nm`` ...).

    Examples
    --------
    >>> import tempfile
    >>> from thsa_control.sim.scenarios import get_scenario
    >>> rig = VirtualRig("B", noise={"motor_speed_rpm": 2.0}, seed=1)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     csv_path, json_path = rig.record(get_scenario("cold_ramp"), f"{d}/cold")
    ...     from thsa_control.data.rigdata import read_run
    ...     run = read_run(csv_path)
    >>> run.metadata["truth"]["effects"], len(run.time)
    (['noback_quadrant_friction'], 3000)
    """

    level: str | None = "B"
    effects: tuple[str, ...] = ()
    params: ParameterSet | None = None
    design: Design | None = None
    noise: Mapping[str, float] = field(default_factory=dict)
    quantisation: Mapping[str, float] = field(default_factory=dict)
    sample_rate_hz: float = 1000.0
    seed: int = 0
    substeps: int = 1
    truth_columns: bool = False

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad option."""
        for label, table in (("noise", self.noise), ("quantisation", self.quantisation)):
            for col, value in table.items():
                if col not in NOISY_COLUMNS:
                    raise ValueError(f"VirtualRig.{label}: column {col!r} is not a sensor column; "
                                     f"choose from {', '.join(NOISY_COLUMNS)}")
                if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                    raise ValueError(f"VirtualRig.{label}[{col!r}] = {value!r} must be a finite number >= 0")
        if not (self.sample_rate_hz > 0 and math.isfinite(self.sample_rate_hz)):
            raise ValueError(f"VirtualRig.sample_rate_hz = {self.sample_rate_hz!r} must be positive")
        h = self._design().control_period
        dec = round(1.0 / (self.sample_rate_hz * h))
        if dec < 1 or abs(dec * h * self.sample_rate_hz - 1.0) > 1e-9:
            raise ValueError(f"VirtualRig.sample_rate_hz = {self.sample_rate_hz:g} Hz: the sample period must be a "
                             f"multiple of the control period {h:g} s")

    def _params(self) -> ParameterSet:
        return self.params if self.params is not None else default_parameters()

    def _design(self) -> Design:
        return self.design if self.design is not None else load_design(nominal_design_path())

    def simulate(self, inputs: Scenario | InputSeries) -> SimulationResult:
        """The noise-free closed-loop run, sampled at ``sample_rate_hz``."""
        self.validate()
        params = self._params()
        required = tuple(inputs.required_effects)
        effects = tuple(self.effects) + tuple(e for e in required if e not in self.effects)
        plant = build_plant(self.level, effects, params=params)
        sim = Simulator(plant, SimulationSettings(substeps=self.substeps, output_period=1.0 / self.sample_rate_hz))
        return sim.run(inputs, self._design(), params)

    def columns(self, result: SimulationResult) -> dict[str, np.ndarray]:
        """FORMAT.md columns of ``result`` with this rig's noise and quantisation."""
        cols = rig_columns(result)
        rng = np.random.default_rng(self.seed)
        out: dict[str, np.ndarray] = {}
        for name, values in cols.items():
            values = np.asarray(values, float)
            if name in NOISY_COLUMNS:
                sigma = float(self.noise.get(name, 0.0))
                if sigma > 0:
                    values = values + sigma * rng.standard_normal(values.shape)
                q = float(self.quantisation.get(name, 0.0))
                if q > 0:
                    values = q * np.round(values / q)
            if name in COLUMNS or name == FEEDFORWARD_COLUMN or self.truth_columns:  # the JSON names the latter
                out[name] = values
        return out

    def metadata(self, result: SimulationResult) -> dict:
        """The run's JSON: controller as it ran, noise, quantisation and the ``truth`` block."""
        params = result.params
        meta = rig_metadata(result, level=self.level)
        meta["generator"]["tool"] = "thsa-control VirtualRig"
        meta["sensors_noise_rms"] = dict(self.noise)
        meta["sensors_quantisation"] = dict(self.quantisation)
        meta["truth"] = {
            "level": self.level, "effects": list(result.effects), "seed": self.seed, "substeps": self.substeps,
            "parameters": {n: params.value(n) for n in params.names},
            "units": {n: params[n].unit for n in params.names},
        }
        return meta

    def record(self, inputs: Scenario | InputSeries, stem: str | Path, *, name: str | None = None) -> tuple[Path, Path]:
        """Simulate ``inputs`` and write ``stem.csv`` / ``stem.json`` (atomically).

        Parameters
        ----------
        inputs : Scenario or InputSeries
            What the run does.
        stem : path
            Target without suffix; its directory must exist.
        name : str, optional
            Run name in the JSON (default the stem).

        Returns
        -------
        (csv_path, json_path)

        Raises
        ------
        ValueError
            Bad noise, quantisation or sample-rate option.
        ScenarioError, DesignError
            As :meth:`Simulator.run`.
        """
        result = self.simulate(inputs)
        meta = self.metadata(result)
        meta["name"] = name or Path(stem).name
        return write_run(stem, self.columns(result), meta)


def _schroeder(t: np.ndarray, period: float, f_low: float, f_high: float, peak: float) -> np.ndarray:
    k = np.arange(max(1, math.ceil(f_low * period)), math.floor(f_high * period) + 1)
    if k.size == 0:
        return np.zeros_like(t)
    phase = -np.pi * k * (k - 1) / k.size
    s = np.sum(np.cos(2 * np.pi * np.outer(t, k) / period + phase), axis=1)
    grid = np.linspace(0, period, 4096, endpoint=False)
    full = np.sum(np.cos(2 * np.pi * np.outer(grid, k) / period + phase), axis=1)
    return peak * s / np.max(np.abs(full))


def excitation_inputs(duration: float = 10.0, mean_speed: float = 3e-3, load: float = -12e3, *,
                      bipolar: bool = False, multisine_peak: float = 1e-3, prbs_amplitude: float = 0.8e-3,
                      f_low: float = 0.3, f_high: float = 35.0, prbs_clock: float = 0.04,
                      ramp_accel: float = 0.03, accel_limit: float = 0.3, temperature: float = 25.0,
                      control_period: float = 1e-4, seed: int = 0, name: str | None = None) -> InputSeries:
    """An identification excitation as an :class:`InputSeries`.

    The target nut speed ramps (``ramp_accel``) to a plateau ``mean_speed``
    [m/s]; on the plateau's first half a Schroeder multi-sine
    (``f_low``..``f_high`` [Hz], peak ``multisine_peak`` [m/s]) and on its
    second half a PRBS (``+-prbs_amplitude`` [m/s], clock ``prbs_clock`` [s]) is
    added; it ramps down to zero at the end.  With ``bipolar`` the run has two
    plateaus, ``+mean_speed`` then ``-mean_speed`` (crossing zero on a ramp,
    motors staying on), so that a constant load opposes one and aids the
    other.  The load [N, compressive positive] ramps in over 0.1-0.3 s and is
    then held.  The controller's shaper limits the rate to ``accel_limit``
    [m/s^2].

    Examples
    --------
    >>> u = excitation_inputs(4.0, bipolar=True)
    >>> round(float(u.signals["load_force"][-1])), u.time.size
    (-12000, 40000)
    """
    n = int(round(duration / control_period))
    t = np.arange(n) * control_period
    rng = np.random.default_rng(seed)
    ramp_t = abs(mean_speed) / ramp_accel
    t_end_ramp = duration - ramp_t - 0.3
    t0 = 0.5
    plateaus = [(t0 + ramp_t, (duration - ramp_t) / 2 if bipolar else t_end_ramp, mean_speed)]
    if bipolar:
        mid = (duration - ramp_t) / 2
        plateaus = [(t0 + ramp_t, mid - ramp_t, mean_speed), (mid + ramp_t, t_end_ramp, -mean_speed)]
    base = np.zeros(n)
    # piecewise-linear base command through the plateau corners
    corners_t, corners_v = [0.0, t0], [0.0, 0.0]
    for a, b, v in plateaus:
        corners_t += [a, b]
        corners_v += [v, v]
    corners_t += [t_end_ramp + ramp_t, duration]
    corners_v += [0.0, 0.0]
    base = np.interp(t, corners_t, corners_v)
    extra = np.zeros(n)
    for a, b, _v in plateaus:
        mid = 0.5 * (a + b)
        m1 = (t >= a) & (t < mid)
        extra[m1] = _schroeder(t[m1] - a, mid - a, f_low, f_high, multisine_peak)
        m2 = (t >= mid) & (t < b)
        n_clock = int(math.ceil((b - mid) / prbs_clock)) + 1
        bits = rng.choice([-1.0, 1.0], size=n_clock)
        extra[m2] = prbs_amplitude * bits[((t[m2] - mid) / prbs_clock).astype(int)]
    cmd = base + extra
    cmd[np.abs(base) == 0] = 0.0  # exact zero outside the motion (motors off there)
    signals = {
        "speed_target": cmd, "position_cmd": np.zeros(n), "position_mode": np.zeros(n),
        "primary_enable": np.ones(n), "standby_enable": np.zeros(n),
        "load_force": np.interp(t, [0.0, 0.1, 0.3, duration], [0.0, 0.0, load, load]),
        "temperature": np.full(n, float(temperature)),
    }
    desc = (f"identification excitation: {'bipolar ' if bipolar else ''}plateau(s) at {mean_speed * 1e3:g} mm/s "
            f"with a {f_low:g}-{f_high:g} Hz Schroeder multi-sine (peak {multisine_peak * 1e3:g} mm/s) then a PRBS "
            f"(+-{prbs_amplitude * 1e3:g} mm/s, {prbs_clock * 1e3:g} ms clock); load {load:g} N "
            f"(compressive positive) from 0.3 s; {temperature:g} degC; seed {seed}")
    return InputSeries(name or "excitation", t, signals, accel_limit, math.inf, True, desc)


def position_inputs(times, positions, *, current_ff=None, load: float = 0.0, accel_limit: float = 2.0,
                    jerk_limit: float = math.inf, temperature: float = 25.0, control_period: float = 1e-4,
                    motor_off_at_zero: bool = False, name: str = "position_moves") -> InputSeries:
    """A position-loop run as an :class:`InputSeries` (the cascade's position P loop closed throughout).

    Parameters
    ----------
    times, positions : sequence of float
        Corners of the piecewise-linear position command [s], [m]; the run
        lasts until the last time.
    current_ff : callable or float, optional
        Current added at the velocity loop's output [A]: a constant, or
        ``f(t) -> A`` on the time grid (a disturbance or a feed-forward).
    load : float
        Constant axial load [N, compressive positive].
    accel_limit, jerk_limit : float
        Shaper limits of the speed target [m/s^2], [m/s^3].

    Examples
    --------
    >>> u = position_inputs([0.0, 0.1, 0.5], [0.0, 0.0, 0.01], current_ff=0.2)
    >>> u.time.size, float(u.signals["position_cmd"][-1]) < 0.01, float(u.signals["current_ff"][0])
    (5000, True, 0.2)
    """
    times, positions = np.asarray(times, float), np.asarray(positions, float)
    n = int(round(times[-1] / control_period))
    t = np.arange(n) * control_period
    ff = np.zeros(n) if current_ff is None else (
        np.asarray(current_ff(t), float) * np.ones(n) if callable(current_ff) else np.full(n, float(current_ff)))
    signals = {"speed_target": np.zeros(n), "position_cmd": np.interp(t, times, positions),
               "position_mode": np.ones(n), "primary_enable": np.ones(n), "standby_enable": np.zeros(n),
               "load_force": np.full(n, float(load)), "temperature": np.full(n, float(temperature)),
               "current_ff": ff}
    desc = (f"position moves through {len(times)} corners ({positions.min() * 1e3:g}..{positions.max() * 1e3:g} mm), "
            f"load {load:g} N" + ("" if current_ff is None else ", current added at the controller output"))
    return InputSeries(name, t, signals, accel_limit, jerk_limit, motor_off_at_zero, desc)
