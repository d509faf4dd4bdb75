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

Batched runs
------------
:meth:`Simulator.run_batch` simulates many runs in one call: each of
``inputs`` (scenarios or input series), ``design``, ``params`` and ``x0`` is
one value for all runs or a list with one per run.  Every run is checked and
laid out first (an error names the bad run's index); runs of the same loop
and length then go to the compiled library in one call, which loops over
them in C, spreads them over the CPUs (``threads``) and writes one
(runs x signals x samples) block (``runs.blocks``) whose rows the results
view; each result is bit-identical to :meth:`Simulator.run` of the same run.
:func:`stack_signals` turns the list into one array.  For parameter studies,
the validation runs of ``thsa check`` and sweeps::

    sim = Simulator(build_plant("D"))
    runs = sim.run_batch([sc.with_temperature(T) for T in (-55, -30, 25, 70)], design, params)
    runs = sim.run_batch(scenario, design, [params.replace({"gear.viscous_friction": v}) for v in values])
    t, Y = stack_signals(runs, ["nut_speed", "motor_current"])   # Y: (runs, 2, samples)

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
import os
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType

import casadi as ca
import numpy as np

from ..loops.design import Design
from ..errors import ScenarioError, ThsaError
from ..memo import KeyedLRU
from ..model.plant import Plant
from ..model.params import ParameterSet
from .loop import OPTIONAL_INPUTS, RUN_INPUTS, ClosedLoop, LoopExtension, output_decimation, plant_input_vector
from .monitors import extensions_for
from .scenarios import TEMPERATURE_RANGE, Scenario

__all__ = ["SimulationSettings", "InputSeries", "SimulationResult", "Simulator", "simulate", "plant_input_vector",
           "available_cpus", "stack_signals", "SignalViews", "BatchResults",
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
            if not np.isfinite(arr).all():
                bad = np.flatnonzero(~np.isfinite(arr))
                raise ScenarioError(f"inputs {self.name!r}: signal {key!r} is not finite at sample {bad[0]} (t = {self.time[bad[0]]:g} s)")
        temp = np.asarray(self.signals["temperature"])
        lo, hi = TEMPERATURE_RANGE
        if temp.size and (temp.min() < lo or temp.max() > hi):
            raise ScenarioError(f"inputs {self.name!r}: temperature {temp.min():g}..{temp.max():g} degC outside {lo:g}..{hi:g} degC")

    @classmethod
    def from_scenario(cls, scenario: Scenario, control_period: float) -> "InputSeries":
        """Sample ``scenario`` at the control period [s].

        A signal constant over the run (a temperature, an enable, a zero position command)
        is a read-only zero-stride view of its one value (``np.broadcast_to``), not an
        array of n copies; the others are read-only arrays.  The values are those of
        ``scenario.inputs(time)``, bit for bit.  The scenario's own checks (finite
        breakpoints, temperature range) stand for the checks of the sampled signals.
        """
        n = int(round(scenario.duration / control_period))
        t = _time_grid(n, control_period)
        signals = scenario.sampled_inputs(t)
        signals.update({k: np.broadcast_to(0.0, (n,)) for k in OPTIONAL_INPUTS})
        for v in signals.values():
            if v.flags.writeable:
                v.setflags(write=False)
        series = object.__new__(cls)  # the fields of __init__, without re-checking what the scenario checked
        for name, value in (("name", scenario.name), ("time", t), ("signals", signals),
                            ("accel_limit", scenario.accel_limit), ("jerk_limit", scenario.jerk_limit),
                            ("motor_off_at_zero", scenario.motor_off_at_zero), ("description", scenario.description),
                            ("required_effects", scenario.required_effects)):
            object.__setattr__(series, name, value)
        return series

    def rows(self) -> tuple[np.ndarray, ...]:
        """The signals of ``RUN_INPUTS`` in order, as they are (no copies; constant ones may be zero-stride)."""
        return tuple(np.asarray(self.signals[k], dtype=float) for k in RUN_INPUTS)

    def matrix(self) -> np.ndarray:
        """Inputs as a new (len(RUN_INPUTS) x n) array."""
        return np.vstack(self.rows())


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


#: Closed loops shared by every Simulator of the process: (id(plant), substeps, extension keys, cache folder)
#: -> loop, the 32 most recently used.  A ClosedLoop is its Functions and its loaded run loop, nothing of a run; the
#: entry keeps its plant alive, so the id is not reused.  build_plant returns one Plant per effect set, so
#: a new Simulator of an effect set already simulated does not generate and load its run loop again.
_LOOPS = KeyedLRU(32)


def _shared_loop(plant: Plant, substeps: int, extensions: tuple, key: tuple) -> ClosedLoop:
    # the cache folder is part of the key: a process that points THSA_CACHE_DIR elsewhere (a sweep's worker)
    # loads its run loop from there
    k = (id(plant), int(substeps), key, os.environ.get("THSA_CACHE_DIR"), os.environ.get("XDG_CACHE_HOME"))
    return _LOOPS.get(k, lambda: ClosedLoop(plant, substeps, extensions), keep=plant)


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
            loop = self._loops[key] = _shared_loop(self.plant, self.settings.substeps, tuple(extensions), key)
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
        """casadi virtual machine fallback (no C compiler), chunked mapaccum; ``W`` the input rows."""
        W = np.vstack([np.broadcast_to(r, W[0].shape) if r.shape != W[0].shape else r for r in W]) \
            if not isinstance(W, np.ndarray) else W
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
            (:func:`~thsa_control.sim.monitors.extensions_for`: the monitors when
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
        ThsaError
            The run diverged (a non-finite signal).
        """
        prep = self._prepare(inputs, design, params, x0, extensions)
        run_loop, cinfo = self._compiled_loop(prep.loop)
        t0 = time.perf_counter()
        if run_loop is not None:
            Y, z, bad = run_loop.batch(prep.z0[None, :], [prep.rows], prep.theta, prep.decimation, n_steps=prep.n)
            Y, z, bad = Y[0], z[0], int(bad[0])
        else:
            Y, z = self._run_interpreted(prep.extensions, prep.z0, prep.rows, prep.theta, prep.decimation)
            bad = _first_non_finite(Y)
        if bad >= 0:
            raise ThsaError(f"simulation of {prep.inputs.name!r} diverged "
                            f"(non-finite signal at t = {bad * prep.decimation * prep.h:g} s)")
        return self._result(prep, Y, z, time.perf_counter() - t0, cinfo)

    def run_batch(self, inputs, design, params, *, x0=None, extensions=None, threads: int | None = None,
                  max_block: int = 256) -> "BatchResults":
        """Simulate many runs in one call, looping over them in the compiled library.

        Each of ``inputs``, ``design``, ``params`` and ``x0`` is one value for every run
        or a list with one per run (lists have the same length); so a batch varies
        parameter sets, designs, scenarios or input series (temperatures: ``Scenario.with_temperature``;
        fault timings: scenarios with other ``faults``), in any combination.

        All runs are checked and laid out first (runs sharing one input object share its
        sampled inputs: nothing is copied); then runs of the same loop (extension set), length
        and output period go to C together, ``max_block`` at a time, writing one
        preallocated (runs x signals x samples) block, while C threads (``threads``,
        default: the CPUs this process may use) take the runs one after the other.  The
        results are cheap views of that block.  Each is bit-identical to :meth:`run` of the
        same run, whatever ``threads``.

        Returns
        -------
        BatchResults
            A list of :class:`SimulationResult` in the order of the runs (``info["wall_s"]``:
            the wall time of the C call the run was part of, ``info["batch"]`` its size), with
            ``.blocks``: the output blocks and the run indices each holds.

        Raises
        ------
        ThsaError (or the subclass of the failing check)
            Naming the index of the bad run: malformed inputs, a missing effect, a design
            beyond the actuator, or a run that diverged.
        """
        runs = _broadcast(inputs=inputs, design=design, params=params, x0=x0)
        memo: dict = {}  # runs of one input object share its sampled inputs
        preps = []
        for i, r in enumerate(runs):
            try:
                preps.append(self._prepare(r["inputs"], r["design"], r["params"], r["x0"], extensions, memo))
            except ThsaError as exc:
                raise _member_error(exc, i, r["inputs"]) from exc
        if threads is None:
            threads = available_cpus()
        out = BatchResults([None] * len(preps))
        groups: dict = {}
        for i, prep in enumerate(preps):
            groups.setdefault((id(prep.loop), prep.n, prep.decimation), []).append(i)
        for idx in groups.values():
            p0 = preps[idx[0]]
            run_loop, cinfo = self._compiled_loop(p0.loop)
            n_out = -(-p0.n // p0.decimation)
            Y = np.empty((len(idx), len(p0.loop.signals), n_out))  # the group's one output block
            Z = np.empty((len(idx), p0.loop.nz))
            bad = np.full(len(idx), -1, dtype=np.int64)
            walls = np.zeros(len(idx))
            sizes = np.zeros(len(idx), dtype=int)
            for start in range(0, len(idx), max_block):
                block = slice(start, min(start + max_block, len(idx)))
                ps = [preps[i] for i in idx[block]]
                t0 = time.perf_counter()
                if run_loop is None:
                    for j, p in enumerate(ps, start):
                        Y[j], Z[j] = self._run_interpreted(p.extensions, p.z0, p.rows, p.theta, p.decimation)
                        bad[j] = _first_non_finite(Y[j])
                else:
                    theta = np.stack([p.theta for p in ps])
                    _, Z[block], bad[block] = run_loop.batch(np.stack([p.z0 for p in ps]), [p.rows for p in ps],
                                                             theta, p0.decimation, threads=threads, n_steps=p0.n,
                                                             out=Y[block])
                walls[block] = time.perf_counter() - t0
                sizes[block] = len(ps)
            for j, i in enumerate(idx):
                if bad[j] >= 0:
                    p = preps[i]
                    raise ThsaError(f"run_batch: run {i} ({p.inputs.name!r}) diverged "
                                    f"(non-finite signal at t = {bad[j] * p.decimation * p.h:g} s)")
            out.blocks.append((Y, tuple(idx)))
            for j, i in enumerate(idx):
                out[i] = self._result(preps[i], Y[j], Z[j], float(walls[j]), cinfo, batch=int(sizes[j]))
        return out

    def _prepare(self, inputs, design: Design, params: ParameterSet, x0, extensions, memo=None) -> "_Prepared":
        """Check a run and lay out its numbers (the loop, ``z0``, the input rows, ``theta``)."""
        h = design.control_period
        scenario = inputs if isinstance(inputs, Scenario) else None
        if extensions is None:
            extensions = extensions_for(scenario) if scenario is not None else ()
        extensions = tuple(extensions)
        key = (id(inputs), h, tuple(e.key() for e in extensions))
        shared = memo.get(key) if memo is not None else None
        if shared is not None and shared[0] is inputs:
            inputs, rows = shared[1], shared[2]
        else:
            rows = None
        if rows is None and scenario is not None:
            inputs = InputSeries.from_scenario(scenario, h)
        needed = tuple(inputs.required_effects) + tuple(e for x in extensions for e in x.required_effects(scenario))
        missing = [e for e in dict.fromkeys(needed) if e not in self.plant.effects]
        if missing:
            raise ScenarioError(f"run {inputs.name!r} needs effect(s) {missing}; the plant has {list(self.plant.effects)}")
        if scenario is None and len(inputs.time) > 1 and not np.allclose(np.diff(inputs.time), h, rtol=1e-6, atol=1e-12):
            raise ScenarioError(f"inputs {inputs.name!r} are not sampled at the control period {h:g} s")
        out_period, decimation = output_decimation(self.settings.output_period, h)
        k = design.controller_vector(params, accel_limit=inputs.accel_limit, jerk_limit=inputs.jerk_limit,
                                     motor_off_at_zero=inputs.motor_off_at_zero)
        loop = self.closed_loop(extensions)
        theta = loop.theta(self.plant.p_vector(params), k, h)
        if rows is None:
            rows = loop.input_rows(inputs, scenario)
            if memo is not None:
                memo[key] = (scenario if scenario is not None else inputs, inputs, rows)
        if x0 is None:
            x0 = self.plant.initial_state(params, load_force=float(rows[RUN_INPUTS.index("load_force")][0]))
        z0 = loop.initial_state(x0, k)
        return _Prepared(loop, extensions, scenario, inputs, design, params, h, decimation, z0, rows, theta,
                         len(inputs.time))

    def _result(self, prep: "_Prepared", Y: np.ndarray, z: np.ndarray, wall: float, cinfo: dict, *,
                batch: int | None = None) -> SimulationResult:
        """The result of a finite run: ``Y`` (signals x samples) becomes read-only views, no copies."""
        h, decimation, inputs = prep.h, prep.decimation, prep.inputs
        t = _time_grid(Y.shape[1], h, decimation)
        info = {"wall_s": wall, "compile": cinfo, "control_period_s": h, "output_period_s": decimation * h,
                "substeps": self.settings.substeps, "final_state": z}
        if batch is not None:
            info["batch"] = batch
        for e in prep.extensions:
            info.update(e.info(prep.scenario))
        return SimulationResult(t, SignalViews(prep.loop.signals, Y), MappingProxyType(prep.loop.units),
                                self.plant.effects, inputs.name, prep.design, prep.params, inputs, info)


@dataclass(frozen=True)
class _Prepared:
    loop: ClosedLoop
    extensions: tuple
    scenario: Scenario | None
    inputs: InputSeries
    design: Design
    params: ParameterSet
    h: float
    decimation: int
    z0: np.ndarray
    rows: tuple
    theta: np.ndarray
    n: int


class SignalViews(Mapping):
    """Signals of a run by name: read-only row views of one (signals x samples) block, made on first access."""

    __slots__ = ("_names", "_index", "_block", "_views")

    def __init__(self, names, block: np.ndarray):
        if block.flags.writeable:
            block = block.view()
            block.setflags(write=False)
        self._names = tuple(names)
        self._index = _name_index(self._names)
        self._block = block
        self._views: dict = {}

    @property
    def block(self) -> np.ndarray:
        """The (signals x samples) block, read-only (rows in the order of the names)."""
        return self._block

    def __getitem__(self, name):
        v = self._views.get(name)
        if v is None:
            v = self._views[name] = self._block[self._index[name]]
        return v

    def __iter__(self):
        return iter(self._names)

    def __len__(self):
        return len(self._names)

    def __contains__(self, name):
        return name in self._index

    def __repr__(self):
        return f"SignalViews({len(self._names)} signals x {self._block.shape[1]} samples)"

    def __getstate__(self):
        return {"names": self._names, "block": self._block}

    def __setstate__(self, state):
        self.__init__(state["names"], state["block"])


_NAME_INDEX: dict = {}


def _name_index(names: tuple) -> dict:
    d = _NAME_INDEX.get(names)
    if d is None:
        d = _NAME_INDEX[names] = {n: i for i, n in enumerate(names)}
    return d


class BatchResults(list):
    """The results of :meth:`Simulator.run_batch`, in run order; ``blocks``: ``(Y, run indices)`` per
    group of runs simulated together, ``Y`` (runs x signals x samples) the block their signals view."""

    def __init__(self, *args):
        super().__init__(*args)
        self.blocks: list = []


_TIME_GRIDS: dict = {}


def _time_grid(n: int, h: float, decimation: int = 1) -> np.ndarray:
    """``np.arange(n) * decimation * h`` (that grouping: the same bits as ever), read-only and shared by the
    runs of one length and period (a few recent grids are kept)."""
    key = (n, h, decimation)
    t = _TIME_GRIDS.get(key)
    if t is None:
        t = np.arange(n) * decimation * h if decimation != 1 else np.arange(n) * h
        t.setflags(write=False)
        if len(_TIME_GRIDS) >= 16:
            _TIME_GRIDS.pop(next(iter(_TIME_GRIDS)))
        _TIME_GRIDS[key] = t
    return t


def _first_non_finite(Y: np.ndarray) -> int:
    """First output sample (column) of ``Y`` with a non-finite value, -1 when all are finite."""
    ok = np.isfinite(Y).all(axis=0)
    return -1 if ok.all() else int(np.argmin(ok))


def _member_error(exc: Exception, i: int, inputs) -> Exception:
    """``exc`` with the index of the batch member it came from in front of its message."""
    name = getattr(inputs, "name", None)
    msg = f"run_batch: run {i}{f' ({name!r})' if name else ''}: {exc}"
    try:
        new = type(exc).__new__(type(exc))
        Exception.__init__(new, msg)
        new.__dict__.update(getattr(exc, "__dict__", {}))
        return new
    except Exception:  # noqa: BLE001 -- an exception class that cannot be rebuilt: the base class
        return ThsaError(msg)


def stack_signals(results, names=None) -> tuple[np.ndarray, np.ndarray]:
    """``(time, Y)`` of runs of one length: ``Y[r, i, :]`` is signal ``names[i]`` (default: all) of run ``r``."""
    results = list(results)
    if not results:
        raise ValueError("stack_signals: no results")
    names = list(names) if names is not None else list(results[0].names)
    n = len(results[0].time)
    if any(len(r.time) != n for r in results):
        raise ValueError("stack_signals: runs of different lengths")
    return results[0].time, np.stack([np.stack([r[k] for k in names]) for r in results])


def available_cpus() -> int:
    """CPUs this process may run on."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except (AttributeError, OSError):
        return max(os.cpu_count() or 1, 1)


def _broadcast(**fields) -> list[dict]:
    """One dict per run from values that are one for all runs or a list/tuple of one per run."""
    lengths = {k: len(v) for k, v in fields.items() if isinstance(v, list) or (isinstance(v, tuple) and k != "x0")}
    if "x0" in fields and isinstance(fields["x0"], (list, tuple)):
        lengths["x0"] = len(fields["x0"])
    if len(set(lengths.values())) > 1:
        raise ValueError(f"run_batch: lists of different lengths {lengths}")
    n = next(iter(lengths.values()), 1)
    if n == 0:
        return []
    return [{k: (v[i] if k in lengths else v) for k, v in fields.items()} for i in range(n)]


def simulate(scenario: Scenario | InputSeries, design: Design, params: ParameterSet, *, level: str | None = "A",
             effects=(), settings: SimulationSettings | None = None) -> SimulationResult:
    """One-shot convenience: build the plant of ``level`` + ``effects`` and run ``scenario``.

    Adds the scenario's required effects (e.g. ``standby_motor``) to the set.
    """
    from ..model import build_plant

    required = scenario.required_effects
    plant = build_plant(level, tuple(effects) + tuple(e for e in required if e not in effects), params=params)
    return Simulator(plant, settings).run(scenario, design, params)
