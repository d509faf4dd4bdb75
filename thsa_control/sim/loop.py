"""One closed loop: plant step, controller and optional loop extensions, as casadi Functions.

One control period is the controller (``loops/controllers.py``) reading the
measurements at ``t_k``, its outputs held (zero-order hold) while the plant
advances ``substeps`` fixed steps of its discrete map (``model/plant.py``).
A *loop extension* (:class:`LoopExtension`) adds a block to that period
without another copy of the loop: before the controller it may change the
measurements and references the controller sees and add plant inputs; after
it, the commands that reach the plant.  It owns states, per-sample inputs,
parameters and output signals, appended after the plain loop's:

* ``z = [x; xc; xe_1; xe_2 ...]`` plant, controller, extension states;
* ``w = [RUN_INPUTS; inputs of extension 1; ...]`` one period's inputs;
* ``theta = [p; k; h; m_1; ...]`` plant and controller parameters, control
  period, extension parameters;
* ``y = [plant outputs; CONTROLLER_SIGNALS; signals of extension 1; ...]``.

With no extension this is exactly the plain loop.  The sensors, monitors and
reconfiguration logic of the fault cases are one extension
(``sim/monitors.py``: :class:`~thsa_control.sim.monitors.MonitorLoop`);
:func:`~thsa_control.sim.monitors.extensions_for` gives a scenario the extensions it asks for.

:class:`ClosedLoop` holds the Functions of one (plant, substeps, extensions)
and their compiled run loop (``codegen.py``); the simulator keeps one per
extension set, and the tuning objective differentiates its ``sample``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..errors import ThsaError
from ..loops.controllers import CONTROLLER_PARAMETERS, CONTROLLER_SIGNALS, CONTROLLER_STATES, REFERENCE_INPUTS, build_controller
from ..model.plant import Plant

__all__ = ["RUN_INPUTS", "OPTIONAL_INPUTS", "CONTROLLER_UNITS", "LoopStage", "LoopExtension", "ClosedLoop",
           "plant_input_vector", "measurement_vector", "output_decimation"]

#: Per-sample inputs of a run: the controller's references, then load and temperature.
RUN_INPUTS = REFERENCE_INPUTS + ("load_force", "temperature")
#: Inputs an :class:`InputSeries` may omit (zero): the current added at the velocity PI's output [A].
OPTIONAL_INPUTS = ("current_ff",)
#: Units of ``CONTROLLER_SIGNALS``.
CONTROLLER_UNITS = {"speed_cmd": "m/s", "motor_speed_ref": "rad/s", "current_ref": "A", "voltage_cmd_primary": "V",
                    "voltage_cmd_standby": "V", "energised_primary": "-", "energised_standby": "-"}
_CONTROLLER_OUTPUTS = ("voltage_primary", "voltage_standby", "enable_primary", "enable_standby")


def plant_input_vector(plant: Plant, u_ctrl, load_force, temperature, **faults):
    """The plant's input vector, by name: the controller's four outputs, load, temperature,
    fault inputs (``faults``, by name) and every other input at its healthy value 0."""
    values = dict(zip(_CONTROLLER_OUTPUTS, ca.vertsplit(u_ctrl)))
    values.update(load_force=load_force, temperature=temperature, **faults)
    unknown = set(values) - set(plant.inputs)
    if unknown:
        raise ThsaError(f"no plant input(s) {sorted(unknown)}; inputs are {', '.join(plant.inputs)}")
    return ca.vertcat(*(values.get(n, ca.SX(0.0)) for n in plant.inputs))


def measurement_vector(plant: Plant, x):
    """What the controller's sensors read from the plant state ``x`` (``MEASUREMENTS`` order): motor
    speed (the rotors where the drive train is compliant), motor current, standby current (0 without
    the standby motor), nut position."""
    names = plant.state_names
    standby = x[names.index("standby_current")] if "standby_current" in names else ca.SX(0.0)
    speed_sensor = plant.sensor_state("motor_speed")  # the plant's measurement map: the rotors where compliant
    return (x[names.index(speed_sensor)], x[names.index("motor_current")], standby, x[names.index("nut_position")])


def output_decimation(output_period: float | None, h: float) -> tuple[float, int]:
    """``(output period, control periods per output sample)``; None means every control period.

    Raises ``ValueError`` when the output period is not a whole multiple of ``h``.
    """
    out_period = output_period if output_period is not None else h
    decimation = int(round(out_period / h))
    if decimation < 1 or abs(decimation * h - out_period) > 1e-9 * out_period:
        raise ValueError(f"output_period {out_period:g} s is not a multiple of the control period {h:g} s")
    return out_period, decimation


@dataclass
class LoopStage:
    """The symbols of one control period, handed to the extensions (casadi SX).

    Read: ``plant``, ``x`` (plant states by name), ``xc`` (controller states
    by name), ``w`` (this period's inputs by name, the extensions' included),
    ``p`` (plant parameter vector), ``k`` (controller parameters by name),
    ``h`` (control period).  An extension may replace entries of
    ``reference`` (``REFERENCE_INPUTS``) and ``measurement``
    (``MEASUREMENTS`` of the controller) and add named plant inputs to
    ``plant_inputs``.
    """

    plant: Plant
    x: dict
    xc: dict
    w: dict
    p: object
    k: dict
    h: object
    reference: dict
    measurement: dict
    plant_inputs: dict = field(default_factory=dict)

    def param(self, name: str):
        """Plant parameter ``name`` (symbol)."""
        return self.p[self.plant.parameters.index(name)]


class LoopExtension:
    """A block added to the closed loop (base class; see the module docstring).

    Subclasses set the class attributes and override the hooks.  The symbolic
    structure must depend only on the class and :meth:`key` (the compiled
    loop is cached by it); run data (thresholds, schedules) go through the
    parameters and inputs.
    """

    name = "extension"
    states: tuple[str, ...] = ()
    inputs: tuple[str, ...] = ()
    parameters: tuple[str, ...] = ()
    signals: tuple[str, ...] = ()
    units: dict = {}

    def key(self) -> tuple:
        """What the compiled code depends on (default: the class)."""
        return (type(self).__module__, type(self).__qualname__)

    # ---- symbolic hooks
    def before_controller(self, stage: LoopStage, xe, m):
        """Change ``stage.reference`` / ``measurement`` / ``plant_inputs``; return ``(xe_next, signals)``."""
        return xe, ca.SX(0, 1)

    def after_controller(self, stage: LoopStage, u: dict) -> dict:
        """The controller's outputs (``voltage_primary`` ... ``enable_standby``) as they reach the plant."""
        return u

    # ---- numeric hooks of a run
    def required_effects(self, scenario) -> tuple[str, ...]:
        """Plant effects a run of ``scenario`` with this extension needs."""
        return ()

    def input_signals(self, scenario, t: np.ndarray) -> dict[str, np.ndarray]:
        """Per-sample values of :attr:`inputs` at times ``t`` [s]."""
        return {n: np.zeros_like(t) for n in self.inputs}

    def parameter_vector(self) -> np.ndarray:
        """Values of :attr:`parameters`."""
        return np.zeros(len(self.parameters))

    def initial_state(self, plant: Plant, x0: np.ndarray, k: dict) -> np.ndarray:
        """Initial extension state, given the plant's and the controller parameters by name."""
        return np.zeros(len(self.states))

    def info(self, scenario) -> dict:
        """Run metadata added to ``SimulationResult.info``."""
        return {}


class ClosedLoop:
    """The Functions of one control period of ``plant`` with ``extensions``.

    Parameters
    ----------
    plant : Plant
    substeps : int
        Plant steps per control period.
    extensions : tuple of LoopExtension
    """

    def __init__(self, plant: Plant, substeps: int = 1, extensions: tuple[LoopExtension, ...] = ()):
        self.plant = plant
        self.substeps = int(substeps)
        self.extensions = tuple(extensions)
        self.inputs = RUN_INPUTS + tuple(n for e in self.extensions for n in e.inputs)
        self.signals = tuple(plant.outputs) + CONTROLLER_SIGNALS + tuple(n for e in self.extensions for n in e.signals)
        units = dict(plant.output_units)
        units.update(CONTROLLER_UNITS)
        for e in self.extensions:
            units.update(e.units)
        self.units = units
        self._functions = None
        self._compiled = None

    @property
    def nz(self) -> int:
        return len(self.plant.states) + len(CONTROLLER_STATES) + sum(len(e.states) for e in self.extensions)

    def functions(self) -> tuple[ca.Function, ca.Function]:
        """``(sample, sample_x)``: ``sample(z, w, theta) -> (z_next, y)``, ``sample_x`` without ``y``."""
        if self._functions is not None:
            return self._functions
        plant, exts = self.plant, self.extensions
        nx, nc = len(plant.states), len(CONTROLLER_STATES)
        n_p, n_k = len(plant.parameters), len(CONTROLLER_PARAMETERS)
        z = ca.SX.sym("z", self.nz)
        w = ca.SX.sym("w", len(self.inputs))
        theta = ca.SX.sym("theta", n_p + n_k + 1 + sum(len(e.parameters) for e in exts))
        x, xc = z[:nx], z[nx:nx + nc]
        p, k, h = theta[:n_p], theta[n_p:n_p + n_k], theta[n_p + n_k]
        names = plant.state_names
        sensed = measurement_vector(plant, x)
        nref = len(REFERENCE_INPUTS)
        if exts:
            stage = LoopStage(plant, dict(zip(names, ca.vertsplit(x))), dict(zip(CONTROLLER_STATES, ca.vertsplit(xc))),
                              dict(zip(self.inputs, ca.vertsplit(w))), p, dict(zip(CONTROLLER_PARAMETERS, ca.vertsplit(k))),
                              h, dict(zip(REFERENCE_INPUTS, ca.vertsplit(w[:nref]))),
                              dict(zip(("motor_speed", "motor_current", "standby_current", "nut_position"), sensed)))
            xe_next, ext_signals = [], []
            iz, im = nx + nc, n_p + n_k + 1
            for e in exts:
                xe, m = z[iz:iz + len(e.states)], theta[im:im + len(e.parameters)]
                iz, im = iz + len(e.states), im + len(e.parameters)
                xn, sig_e = e.before_controller(stage, xe, m)
                xe_next.append(xn)
                ext_signals.append(sig_e)
            ref = ca.vertcat(*(stage.reference[n] for n in REFERENCE_INPUTS))
            meas = ca.vertcat(*(stage.measurement[n] for n in ("motor_speed", "motor_current", "standby_current",
                                                                 "nut_position")))
        else:
            ref = w[:nref]
            meas = ca.vertcat(*sensed)
        xc_next, u_ctrl, sig = build_controller()(xc, ref, meas, k, h)
        extra = {}
        if exts:
            u = dict(zip(_CONTROLLER_OUTPUTS, ca.vertsplit(u_ctrl)))
            for e in exts:
                u = e.after_controller(stage, u)
            u_ctrl = ca.vertcat(*(u[n] for n in _CONTROLLER_OUTPUTS))
            extra = stage.plant_inputs
        u = plant_input_vector(plant, u_ctrl, w[RUN_INPUTS.index("load_force")], w[RUN_INPUTS.index("temperature")],
                               **extra)
        hs = h / self.substeps
        x_next, y = plant.step(x, u, p, hs)
        for _ in range(self.substeps - 1):
            x_next, _ = plant.step(x_next, u, p, hs)
        if exts:
            z_next = ca.vertcat(x_next, xc_next, *xe_next)
            y_all = ca.vertcat(y, sig, *ext_signals)
        else:
            z_next, y_all = ca.vertcat(x_next, xc_next), ca.vertcat(y, sig)
        sample = ca.Function("sample", [z, w, theta], [z_next, y_all], ["z", "w", "theta"], ["z_next", "y"])
        # the same period without outputs (casadi drops what only the outputs need)
        sample_x = ca.Function("sample_x", [z, w, theta], [z_next], ["z", "w", "theta"], ["z_next"])
        self._functions = (sample, sample_x)
        return self._functions

    def compiled(self):
        """``(RunLoop or None, info)``: the run loop compiled to C (cached on disk, verified)."""
        if self._compiled is None:
            from .codegen import compile_run_loop

            self._compiled = compile_run_loop(*self.functions())
        return self._compiled

    # ---- numeric layout of a run
    def input_rows(self, inputs, scenario=None) -> tuple[np.ndarray, ...]:
        """The rows of ``W``: the run inputs of ``inputs`` (an ``InputSeries``), then each extension's
        (as they are: no copies; a constant may be a zero-stride view)."""
        rows = inputs.rows()
        for e in self.extensions:
            sig = e.input_signals(scenario, inputs.time)
            rows += tuple(np.asarray(sig[n], dtype=float) for n in e.inputs)
        return rows

    def input_matrix(self, inputs, scenario=None) -> np.ndarray:
        """``W`` (len(inputs) x n): :meth:`input_rows` as one new array."""
        return np.vstack(self.input_rows(inputs, scenario))

    def theta(self, p: np.ndarray, k: np.ndarray, h: float) -> np.ndarray:
        """``[p; k; h; m_1; ...]``."""
        return np.concatenate([p, k, [h]] + [e.parameter_vector() for e in self.extensions])

    def initial_state(self, x0: np.ndarray, k: np.ndarray) -> np.ndarray:
        """``z0 = [x0; 0; xe0_1; ...]``."""
        x0 = np.asarray(x0, float)
        kd = dict(zip(CONTROLLER_PARAMETERS, k))
        return np.concatenate([x0, np.zeros(len(CONTROLLER_STATES))]
                              + [e.initial_state(self.plant, x0, kd) for e in self.extensions])
