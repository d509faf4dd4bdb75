"""Closed-loop simulation: sampled-data cascade + fixed-step plant, compiled.

One control period is one casadi ``sample`` Function of the closed loop
(``loop.py``: the controller of ``loops/controllers.py`` reads the
measurements at ``t_k``, its voltages are held while the plant advances
``substeps`` fixed steps of its discrete map, plus the loop extensions a
scenario asks for, e.g. the monitors of the fault cases).  A C driver loops
over the periods; it is compiled once and cached on disk (``codegen.py``).
Without a C compiler, ``mapaccum`` strings the periods into chunks run by
casadi's virtual machine.  The same ``sample`` Function, uncompiled, is what
gradient-based tuning and identification differentiate through.

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

from ..loops.design import Design
from ..errors import ScenarioError, ThsaError
from ..model.plant import Plant
from ..model.params import ParameterSet
from .loop import (OPTIONAL_INPUTS, RUN_INPUTS, ClosedLoop, LoopExtension, extensions_for, output_decimation,
                   plant_input_vector)
from .scenarios import TEMPERATURE_RANGE, Scenario

__all__ = ["SimulationSettings", "InputSeries", "SimulationResult", "Simulator", "simulate", "plant_input_vector",
           "RUN_INPUTS", "OPTIONAL_INPUTS", "output_decimation"]


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

    def report(self) -> str:
        """Range and final value of every signal, in display units."""
        from ..report.results import format_simulation

        return format_simulation(self)

    def to_dict(self) -> dict:
        """Name, effects, units and every signal (SI), JSON-able."""
        from ..report.results import simulation_to_dict

        return simulation_to_dict(self)

    def plot(self, ax=None):
        """Speeds, currents, forces and no-back (``thsa_control.report.plots.plot_run``); ``ax``: four Axes."""
        from ..report.plots import plot_run

        return plot_run(self, axes=ax)


class Simulator:
    """Closed-loop simulator of one plant (effect set).

    The constructor only stores its configuration; the closed loop of each
    set of loop extensions (none, or the monitors of a fault scenario) is
    built, and compiled, on first use and kept for later runs.

    Parameters
    ----------
    plant : Plant
    settings : SimulationSettings
    """

    def __init__(self, plant: Plant, settings: SimulationSettings | None = None):
        self.plant = plant
        self.settings = settings or SimulationSettings()
        self.settings.validate()
        self._loops: dict = {}
        self._chunks: dict = {}

    # ---- the closed loop (also for tuning and identification)
    def closed_loop(self, extensions: tuple[LoopExtension, ...] = ()) -> ClosedLoop:
        """The :class:`~thsa_control.sim.loop.ClosedLoop` of this plant with ``extensions`` (kept)."""
        key = tuple(e.key() for e in extensions)
        loop = self._loops.get(key)
        if loop is None:
            loop = self._loops[key] = ClosedLoop(self.plant, self.settings.substeps, tuple(extensions))
        return loop

    def sample_function(self, extensions: tuple[LoopExtension, ...] = ()) -> ca.Function:
        """``sample(z, w, theta) -> (z_next, y)`` for one control period.

        ``z = [x; xc]`` (plant then controller states), ``w`` the run inputs
        of one period (``RUN_INPUTS``), ``theta = [p; k; h]`` (plant
        parameters, controller parameters, control period).  ``y`` is the
        plant outputs followed by ``CONTROLLER_SIGNALS``.  With
        ``extensions``, their states, inputs, parameters and signals follow
        (``loop.py``).
        """
        return self.closed_loop(extensions).functions()[0]

    def chunk_function(self, decimation: int, blocks: int, extensions: tuple[LoopExtension, ...] = ()) -> ca.Function:
        """``chunk(z0, W, theta) -> (Z, Y)`` over ``blocks`` output periods of ``decimation`` control periods."""
        sample, sample_x = self.closed_loop(extensions).functions()
        z = ca.MX.sym("z", sample.size1_in(0))
        W = ca.MX.sym("W", sample.size1_in(1), decimation)
        theta = ca.MX.sym("theta", sample.size1_in(2))
        z1, y0 = sample(z, W[:, 0], theta)
        if decimation > 1:
            zs = sample_x.mapaccum("periods", decimation - 1)(z1, W[:, 1:], theta)
            z1 = zs[:, -1]
        block = ca.Function("block", [z, W, theta], [z1, y0])
        return block.mapaccum(f"thsa_chunk_{decimation}_{blocks}", blocks)

    def _compiled_loop(self, loop: ClosedLoop):
        if self.settings.compiled:
            return loop.compiled()
        return None, {"compiled": False, "cached": False, "codegen_s": 0.0, "compile_s": 0.0}

    def _run_interpreted(self, extensions, z, W, theta, decimation):
        """casadi virtual machine fallback (no C compiler), chunked mapaccum."""
        nb = self.settings.chunk_blocks
        key = (tuple(e.key() for e in extensions), decimation)
        if key not in self._chunks:
            self._chunks[key] = self.chunk_function(decimation, nb, extensions)
        f = self._chunks[key]
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
            x0: np.ndarray | None = None, extensions: tuple[LoopExtension, ...] | None = None) -> SimulationResult:
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
        extensions : tuple of LoopExtension, optional
            Blocks added to the loop; default: those the scenario asks for
            (:func:`~thsa_control.sim.loop.extensions_for`: the monitors when
            it has faults or monitor settings), none for an ``InputSeries``.

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
        scenario = inputs if isinstance(inputs, Scenario) else None
        if extensions is None:
            extensions = extensions_for(scenario) if scenario is not None else ()
        extensions = tuple(extensions)
        if scenario is not None:
            inputs = InputSeries.from_scenario(scenario, h)
        needed = tuple(inputs.required_effects) + tuple(e for x in extensions for e in x.required_effects(scenario))
        missing = [e for e in dict.fromkeys(needed) if e not in self.plant.effects]
        if missing:
            raise ScenarioError(f"run {inputs.name!r} needs effect(s) {missing}; the plant has {list(self.plant.effects)}")
        if len(inputs.time) > 1 and not np.allclose(np.diff(inputs.time), h, rtol=1e-6, atol=1e-12):
            raise ScenarioError(f"inputs {inputs.name!r} are not sampled at the control period {h:g} s")
        out_period, decimation = output_decimation(self.settings.output_period, h)
        k = design.controller_vector(params, accel_limit=inputs.accel_limit, jerk_limit=inputs.jerk_limit,
                                     motor_off_at_zero=inputs.motor_off_at_zero)
        loop = self.closed_loop(extensions)
        theta = loop.theta(self.plant.p_vector(params), k, h)
        W = loop.input_matrix(inputs, scenario)
        if x0 is None:
            x0 = self.plant.initial_state(params, load_force=float(W[RUN_INPUTS.index("load_force"), 0]))
        z = loop.initial_state(x0, k)

        run_loop, cinfo = self._compiled_loop(loop)
        t0 = time.perf_counter()
        if run_loop is not None:
            Y, z = run_loop(z, W, theta, decimation)
        else:
            Y, z = self._run_interpreted(extensions, z, W, theta, decimation)
        wall = time.perf_counter() - t0
        n_out = Y.shape[1]
        if not np.all(np.isfinite(Y)):
            bad = np.argwhere(~np.isfinite(Y))[0]
            raise ThsaError(f"simulation of {inputs.name!r} diverged (non-finite signal at t = {bad[1] * decimation * h:g} s)")
        signals = {}
        for i, name in enumerate(loop.signals):
            arr = Y[i].copy()
            arr.setflags(write=False)
            signals[name] = arr
        t = np.arange(n_out) * decimation * h
        t.setflags(write=False)
        info = {"wall_s": wall, "compile": dict(cinfo), "control_period_s": h, "output_period_s": decimation * h,
                "substeps": self.settings.substeps, "final_state": z}
        for e in extensions:
            info.update(e.info(scenario))
        return SimulationResult(t, MappingProxyType(signals), MappingProxyType(dict(loop.units)), self.plant.effects,
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
