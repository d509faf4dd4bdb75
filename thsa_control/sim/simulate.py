"""Closed-loop simulation: sampled-data cascade + fixed-step plant, compiled.

One control period is one casadi ``sample`` Function: the controller
(``controllers.py``) reads the measurements at ``t_k`` and its voltages are
held (zero-order hold) while the plant advances ``substeps`` fixed steps of
its discrete map (``model/plant.py``).  ``mapaccum`` strings the periods
into blocks of one output period and the blocks into chunks; the chunk
Function is compiled to C once and cached on disk (``_compile.py``).  The
same ``sample`` Function, uncompiled, is what gradient-based tuning and
identification differentiate through.

Examples
--------
>>> from thsa_control.model import build_plant
>>> from thsa_control.sim.scenarios import get_scenario
>>> from thsa_control.model.params import default_parameters
>>> from thsa_control.loops.design import derive_gains
>>> P = default_parameters()
>>> d = derive_gains(P, current_bandwidth_hz=1000, velocity_crossover_hz=30,
...                  velocity_pi_zero_ratio=5, position_bandwidth_hz=2)
>>> sim = Simulator(build_plant("B"))
>>> res = sim.run(get_scenario("cold_ramp"), d, P)
>>> round(float(res["nut_speed"][res.index_at(2.0)]) * 1e3, 1)
9.0
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from types import MappingProxyType

import casadi as ca
import numpy as np

from ._compile import compile_run_loop
from ..loops.controllers import CONTROLLER_PARAMETERS, CONTROLLER_SIGNALS, CONTROLLER_STATES, REFERENCE_INPUTS, build_controller
from ..loops.design import Design
from ..errors import ScenarioError, ThsaError
from ..model.plant import Plant
from ..model.params import ParameterSet
from .scenarios import TEMPERATURE_RANGE, Scenario

__all__ = ["SimulationSettings", "InputSeries", "SimulationResult", "Simulator", "simulate", "plant_input_vector"]

#: Per-sample inputs of a run: the controller's references, then load and temperature.
RUN_INPUTS = REFERENCE_INPUTS + ("load_force", "temperature")
#: Inputs an :class:`InputSeries` may omit (zero): the current added at the velocity PI's output [A].
OPTIONAL_INPUTS = ("current_ff",)


@dataclass(frozen=True)
class SimulationSettings:
    """How a run is integrated and sampled.

    Parameters
    ----------
    substeps : int
        Plant steps per control period (1, 2, 4 ... for convergence checks).
    output_period : float or None
        Output sample period [s], a multiple of the control period; None:
        every control period.
    chunk_blocks : int
        Output samples computed per compiled call.
    compiled : bool
        Compile to C (cached); False runs casadi's virtual machine.
    """

    substeps: int = 1
    output_period: float | None = 1e-3
    chunk_blocks: int = 1000
    compiled: bool = True

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"SimulationSettings.substeps = {self.substeps!r} must be an integer >= 1")
        if self.output_period is not None and not (self.output_period > 0 and math.isfinite(self.output_period)):
            raise ValueError(f"SimulationSettings.output_period = {self.output_period!r} must be positive")
        if not (isinstance(self.chunk_blocks, int) and self.chunk_blocks >= 1):
            raise ValueError(f"SimulationSettings.chunk_blocks = {self.chunk_blocks!r} must be an integer >= 1")


@dataclass(frozen=True)
class InputSeries:
    """Inputs of a run, one sample per control period (SI).

    ``signals`` holds every name of ``RUN_INPUTS`` as an array of the length
    of ``time`` (those of ``OPTIONAL_INPUTS`` default to zeros).  Build one with :meth:`from_scenario` or from rig data.
    """

    name: str
    time: np.ndarray
    signals: dict
    accel_limit: float
    jerk_limit: float = math.inf
    motor_off_at_zero: bool = True
    description: str = ""
    required_effects: tuple[str, ...] = ()

    def __post_init__(self):
        n = len(self.time)
        missing = {k: np.zeros(n) for k in OPTIONAL_INPUTS if k not in self.signals}
        if missing:  # optional inputs default to 0 (a copy: the caller's dict is not changed)
            object.__setattr__(self, "signals", {**self.signals, **missing})
        for key in RUN_INPUTS:
            if key not in self.signals:
                raise ScenarioError(f"inputs {self.name!r}: missing signal {key!r}")
            arr = np.asarray(self.signals[key], dtype=float)
            if arr.shape != (n,):
                raise ScenarioError(f"inputs {self.name!r}: signal {key!r} has shape {arr.shape}, expected ({n},)")
            bad = np.flatnonzero(~np.isfinite(arr))
            if bad.size:
                raise ScenarioError(f"inputs {self.name!r}: signal {key!r} is not finite at sample {bad[0]} (t = {self.time[bad[0]]:g} s)")
        temp = np.asarray(self.signals["temperature"])
        lo, hi = TEMPERATURE_RANGE
        if temp.size and (temp.min() < lo or temp.max() > hi):
            raise ScenarioError(f"inputs {self.name!r}: temperature {temp.min():g}..{temp.max():g} degC outside {lo:g}..{hi:g} degC")

    @classmethod
    def from_scenario(cls, scenario: Scenario, control_period: float) -> "InputSeries":
        """Sample ``scenario`` at the control period [s]."""
        n = int(round(scenario.duration / control_period))
        t = np.arange(n) * control_period
        return cls(scenario.name, t, scenario.inputs(t), scenario.accel_limit, scenario.jerk_limit,
                   scenario.motor_off_at_zero, scenario.description, scenario.required_effects)

    def matrix(self) -> np.ndarray:
        """Inputs as a (len(RUN_INPUTS) x n) array."""
        return np.vstack([np.asarray(self.signals[k], dtype=float) for k in RUN_INPUTS])


@dataclass(frozen=True)
class SimulationResult:
    """Signals of a run by name (SI), sampled at ``time``.

    Attributes
    ----------
    time : ndarray
        [s].
    signals : mapping name -> ndarray
        Plant outputs and controller signals (read-only arrays).
    units : mapping name -> str
    effects : tuple of str
    name : str
        Scenario or run name.
    info : dict
        Run metadata: design, settings, timings (``wall_s``, compile info).
    """

    time: np.ndarray
    signals: MappingProxyType
    units: MappingProxyType
    effects: tuple[str, ...]
    name: str
    design: Design
    params: ParameterSet
    inputs: InputSeries
    info: dict = field(default_factory=dict)

    def __getitem__(self, name: str) -> np.ndarray:
        try:
            return self.signals[name]
        except KeyError:
            raise KeyError(f"no signal {name!r}; signals are {', '.join(self.signals)}") from None

    @property
    def names(self) -> tuple[str, ...]:
        """Signal names."""
        return tuple(self.signals)

    def index_at(self, t: float) -> int:
        """Index of the sample nearest to time ``t`` [s]."""
        return int(np.argmin(np.abs(self.time - t)))

    def window(self, t0: float, t1: float) -> np.ndarray:
        """Boolean mask of samples with ``t0 <= time < t1``."""
        return (self.time >= t0) & (self.time < t1)


def plant_input_vector(plant: Plant, u_ctrl, load_force, temperature, **faults):
    """The plant's input vector, by name: the controller's four outputs, load, temperature,
    fault inputs (``faults``, by name) and every other input at its healthy value 0."""
    values = dict(zip(("voltage_primary", "voltage_standby", "enable_primary", "enable_standby"), ca.vertsplit(u_ctrl)))
    values.update(load_force=load_force, temperature=temperature, **faults)
    unknown = set(values) - set(plant.inputs)
    if unknown:
        raise ThsaError(f"no plant input(s) {sorted(unknown)}; inputs are {', '.join(plant.inputs)}")
    return ca.vertcat(*(values.get(n, ca.SX(0.0)) for n in plant.inputs))


def output_decimation(output_period: float | None, h: float) -> tuple[float, int]:
    """``(output period, control periods per output sample)``; None means every control period.

    Raises ``ValueError`` when the output period is not a whole multiple of ``h``.
    """
    out_period = output_period if output_period is not None else h
    decimation = int(round(out_period / h))
    if decimation < 1 or abs(decimation * h - out_period) > 1e-9 * out_period:
        raise ValueError(f"output_period {out_period:g} s is not a multiple of the control period {h:g} s")
    return out_period, decimation


class Simulator:
    """Closed-loop simulator of one plant (effect set).

    The constructor only stores its configuration; the casadi Functions are
    built, and compiled, on first use and kept for later runs of the same
    control/output periods.

    Parameters
    ----------
    plant : Plant
    settings : SimulationSettings
    """

    def __init__(self, plant: Plant, settings: SimulationSettings | None = None):
        self.plant = plant
        self.settings = settings or SimulationSettings()
        self.settings.validate()
        self._compiled: dict = {}
        self._sample = None

    # ---- symbolic pieces (also for tuning and identification)
    def sample_function(self) -> ca.Function:
        """``sample(z, w, theta) -> (z_next, y)`` for one control period.

        ``z = [x; xc]`` (plant then controller states), ``w`` the run inputs
        of one period (``RUN_INPUTS``), ``theta = [p; k; h]`` (plant
        parameters, controller parameters, control period).  ``y`` is the
        plant outputs followed by ``CONTROLLER_SIGNALS``.
        """
        if self._sample is not None:
            return self._sample
        plant = self.plant
        nx, nc = len(plant.states), len(CONTROLLER_STATES)
        n_p, n_k = len(plant.parameters), len(CONTROLLER_PARAMETERS)
        z = ca.SX.sym("z", nx + nc)
        w = ca.SX.sym("w", len(RUN_INPUTS))
        theta = ca.SX.sym("theta", n_p + n_k + 1)
        x, xc = z[:nx], z[nx:]
        p, k, h = theta[:n_p], theta[n_p:n_p + n_k], theta[n_p + n_k]
        names = plant.state_names
        standby = x[names.index("standby_current")] if "standby_current" in names else ca.SX(0.0)
        speed_sensor = plant.sensor_state("motor_speed")  # the motor sensor reads the rotors
        meas = ca.vertcat(x[names.index(speed_sensor)], x[names.index("motor_current")], standby,
                          x[names.index("nut_position")])
        xc_next, u_ctrl, sig = build_controller()(xc, w[:len(REFERENCE_INPUTS)], meas, k, h)
        u = plant_input_vector(plant, u_ctrl, w[RUN_INPUTS.index("load_force")], w[RUN_INPUTS.index("temperature")])
        hs = h / self.settings.substeps
        x_next, y = plant.step(x, u, p, hs)
        for _ in range(self.settings.substeps - 1):
            x_next, _ = plant.step(x_next, u, p, hs)
        self._sample = ca.Function("sample", [z, w, theta], [ca.vertcat(x_next, xc_next), ca.vertcat(y, sig)],
                                   ["z", "w", "theta"], ["z_next", "y"])
        # the same period without outputs (casadi drops what only the outputs need)
        self._sample_x = ca.Function("sample_x", [z, w, theta], [ca.vertcat(x_next, xc_next)],
                                     ["z", "w", "theta"], ["z_next"])
        return self._sample

    def chunk_function(self, decimation: int, blocks: int) -> ca.Function:
        """``chunk(z0, W, theta) -> (Z, Y)`` over ``blocks`` output periods of ``decimation`` control periods."""
        sample = self.sample_function()
        z = ca.MX.sym("z", sample.size1_in(0))
        W = ca.MX.sym("W", sample.size1_in(1), decimation)
        theta = ca.MX.sym("theta", sample.size1_in(2))
        z1, y0 = sample(z, W[:, 0], theta)
        if decimation > 1:
            zs = self._sample_x.mapaccum("periods", decimation - 1)(z1, W[:, 1:], theta)
            z1 = zs[:, -1]
        block = ca.Function("block", [z, W, theta], [z1, y0])
        return block.mapaccum(f"thsa_chunk_{decimation}_{blocks}", blocks)

    def _loop(self):
        if "loop" not in self._compiled:
            self.sample_function()
            if self.settings.compiled:
                self._compiled["loop"] = compile_run_loop(self._sample, self._sample_x)
            else:
                self._compiled["loop"] = (None, {"compiled": False, "cached": False, "codegen_s": 0.0, "compile_s": 0.0})
        return self._compiled["loop"]

    def _run_interpreted(self, z, W, theta, decimation):
        """casadi virtual machine fallback (no C compiler), chunked mapaccum."""
        nb = self.settings.chunk_blocks
        key = ("vm", decimation)
        if key not in self._compiled:
            self._compiled[key] = self.chunk_function(decimation, nb)
        f = self._compiled[key]
        n_out = -(-W.shape[1] // decimation)
        n_chunks = -(-n_out // nb)
        total = n_chunks * nb * decimation
        if total > W.shape[1]:
            W = np.hstack([W, np.repeat(W[:, -1:], total - W.shape[1], axis=1)])
        ys = []
        for c in range(n_chunks):
            Z, Y = f(z, W[:, c * nb * decimation:(c + 1) * nb * decimation], theta)
            ys.append(np.asarray(Y))
            z = np.asarray(Z)[:, -1]
        return np.hstack(ys)[:, :n_out], z

    # ---- runs
    def run(self, inputs: InputSeries | Scenario, design: Design, params: ParameterSet, *,
            x0: np.ndarray | None = None) -> SimulationResult:
        """Simulate a run in closed loop.

        Parameters
        ----------
        inputs : InputSeries or Scenario
            What the run does (a scenario is sampled at the design's period).
        design : Design
            Cascade gains and control period.
        params : ParameterSet
            Actuator parameters.
        x0 : ndarray, optional
            Initial plant state; default at rest in equilibrium with the
            initial load.

        Returns
        -------
        SimulationResult

        Raises
        ------
        ScenarioError
            The run needs an effect the plant lacks, or inputs are malformed.
        DesignError
            The design asks more than the actuator has.
        """
        h = design.control_period
        if isinstance(inputs, Scenario) and (inputs.faults or inputs.monitors is not None):
            from ..faults.loop import run_fault_loop  # faults and monitors in the loop (issue #10)
            return run_fault_loop(self, inputs, design, params, x0=x0)
        if isinstance(inputs, Scenario):
            inputs = InputSeries.from_scenario(inputs, h)
        missing = [e for e in inputs.required_effects if e not in self.plant.effects]
        if missing:
            raise ScenarioError(f"run {inputs.name!r} needs effect(s) {missing}; the plant has {list(self.plant.effects)}")
        if len(inputs.time) > 1 and not np.allclose(np.diff(inputs.time), h, rtol=1e-6, atol=1e-12):
            raise ScenarioError(f"inputs {inputs.name!r} are not sampled at the control period {h:g} s")
        out_period, decimation = output_decimation(self.settings.output_period, h)
        k = design.controller_vector(params, accel_limit=inputs.accel_limit, jerk_limit=inputs.jerk_limit,
                                     motor_off_at_zero=inputs.motor_off_at_zero)
        theta = np.concatenate([self.plant.p_vector(params), k, [h]])
        W = inputs.matrix()
        if x0 is None:
            x0 = self.plant.initial_state(params, load_force=float(W[RUN_INPUTS.index("load_force"), 0]))
        z = np.concatenate([np.asarray(x0, float), np.zeros(len(CONTROLLER_STATES))])

        loop, cinfo = self._loop()
        t0 = time.perf_counter()
        if loop is not None:
            Y, z = loop(z, W, theta, decimation)
        else:
            Y, z = self._run_interpreted(z, W, theta, decimation)
        wall = time.perf_counter() - t0
        n_out = Y.shape[1]
        if not np.all(np.isfinite(Y)):
            bad = np.argwhere(~np.isfinite(Y))[0]
            raise ThsaError(f"simulation of {inputs.name!r} diverged (non-finite signal at t = {bad[1] * decimation * h:g} s)")
        names = self.plant.outputs + CONTROLLER_SIGNALS
        units = dict(self.plant.output_units)
        units.update({"speed_cmd": "m/s", "motor_speed_ref": "rad/s", "current_ref": "A", "voltage_cmd_primary": "V",
                      "voltage_cmd_standby": "V", "energised_primary": "-", "energised_standby": "-"})
        signals = {}
        for i, name in enumerate(names):
            arr = Y[i].copy()
            arr.setflags(write=False)
            signals[name] = arr
        t = np.arange(n_out) * decimation * h
        t.setflags(write=False)
        info = {"wall_s": wall, "compile": dict(cinfo), "control_period_s": h, "output_period_s": decimation * h,
                "substeps": self.settings.substeps, "final_state": z}
        return SimulationResult(t, MappingProxyType(signals), MappingProxyType(units), self.plant.effects,
                                inputs.name, design, params, inputs, info)


def simulate(scenario: Scenario | InputSeries, design: Design, params: ParameterSet, *, level: str | None = "A",
             effects=(), settings: SimulationSettings | None = None) -> SimulationResult:
    """One-shot convenience: build the plant of ``level`` + ``effects`` and run ``scenario``.

    Adds the scenario's required effects (e.g. ``standby_motor``) to the set.
    """
    from ..model import build_plant

    required = scenario.required_effects
    plant = build_plant(level, tuple(effects) + tuple(e for e in required if e not in effects), params=params)
    return Simulator(plant, settings).run(scenario, design, params)
