"""The plant of one effect set as casadi Functions with named signals.

:func:`build_plant` assembles the structure and the chosen effects once and
derives from the same expressions

* ``f(x, u, p) -> (xdot, y)``: the continuous right-hand side (friction
  resolved by the sign of the speed; exact away from zero speed);
* ``step(x, u, p, h) -> (x_next, y)``: one fixed step of the simulator's
  semi-implicit scheme: lags (currents) integrated exactly with the speed
  frozen, the main body's speed with friction resolved implicitly (it sticks
  when the friction it needs stays within the static limits, else slides with
  the kinetic torque), other velocities explicitly, positions with the new
  velocities (symplectic Euler), and effect-specific updates (pawl clearance).
  Stiction holds exactly and does not chatter; the scheme is first-order and
  converges under step halving.  ``y`` of a step is the signals at the step's
  start, with the friction it resolved over the step.

Both Functions are SX, so they can be differentiated, mapped and compiled.

The plant also exports what the model knows beyond ``f`` and ``step``, from
the same assembly, so that no tool restates it: the measurement map
(:data:`SENSORS`: what the motor-speed, current, RVDT and LVDT sensors read,
as outputs and as the state each reads), the screw-to-nut ratio
``lead / (2 pi N)``, the torque constant, and the inertias at the motor
shaft (the main body's and the one the motor current accelerates).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import ModelError, ParameterError
from ..memo import KeyedLRU
from . import effects as _effects  # noqa: F401  (registers the library's effects)
from .effect import EFFECTS, effect_order
from .levels import resolve_effects
from .params import ParameterSet, default_parameters
from .structure import (
    INPUTS, STRUCTURE_STATES, Assembly, FrictionResolution, StateInfo, apply_structure, finish_structure, sum_terms,
)

__all__ = ["Plant", "Sensor", "SENSORS", "SENSOR_OUTPUTS", "build_plant"]

_TINY = 1e-300


@dataclass(frozen=True)
class Sensor:
    """What one rig sensor reads in the model.

    ``channel``: the rig channel (``RigRun`` signal name); ``output``: the
    plant output it reads; ``state``: the state it reads directly, times
    ``scale`` (the screw speed is ``motor_speed / N``: state ``motor_speed``,
    ``scale = 1/N`` as a casadi Function of ``p``; None: unit scale).
    """

    channel: str
    output: str
    state: str
    scale: ca.Function | None = None


#: Rig channels the measurement map covers: motor speed sensor, motor current, RVDT (screw speed), LVDT.
SENSORS: tuple[str, ...] = ("motor_speed", "motor_current", "screw_speed", "nut_position")
#: The plant output each sensor reads, the same for every effect set: the LVDT (``nut_position_mm``) reads
#: the output rod, which is the surface position when the load path is compliant and the nut position
#: otherwise (the structure defines ``surface_position`` as the nut position then); the motor sensor
#: reads the rotors (output ``motor_speed``).
SENSOR_OUTPUTS: dict[str, str] = {"motor_speed": "motor_speed", "motor_current": "motor_current",
                                  "screw_speed": "screw_speed", "nut_position": "surface_position"}


@dataclass(frozen=True)
class Plant:
    """One effect set compiled to casadi Functions, with every signal named.

    Attributes
    ----------
    effects : tuple of str
        The effect set, in application order.
    states : tuple of StateInfo
        States (name, unit, integration kind, description).
    inputs : tuple of str
        Input names (``INPUTS``), the same for every effect set.
    outputs : tuple of str
        Output names; ``output_units`` gives their units.
    parameters : tuple of str
        Parameter names in ``p`` order.
    f, step, init : casadi.Function
        Continuous RHS ``f(x,u,p)->(xdot,y)``, discrete step
        ``step(x,u,p,h)->(x_next,y)`` and initial state
        ``init(nut_position, load_force, p)->x0`` (at rest, springs in static
        equilibrium with the load).
    """

    effects: tuple[str, ...]
    states: tuple[StateInfo, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    output_units: dict
    parameters: tuple[str, ...]
    f: ca.Function
    step: ca.Function
    init: ca.Function
    sensors: dict = None  # channel -> Sensor (SENSORS)
    measure: ca.Function = None  # (x, u, p) -> readings of SENSORS, in that order
    ratio_fn: ca.Function = None  # p -> lead / (2 pi N) [m/rad]
    kt_fn: ca.Function = None  # p -> torque constant [N m/A]
    inertia_fn: ca.Function = None  # (x, p) -> (main body, body the motor current accelerates) [kg m^2]
    #: states of fast internal modes a fit's segment starts at their quasi-static value (``quasi_static``)
    quasi_static_states: tuple[str, ...] = ()
    #: (x, u, p) -> x with the ``quasi_static_states`` replaced by their quasi-static values given the others
    quasi_static: ca.Function = None

    @property
    def state_names(self) -> tuple[str, ...]:
        """State names in ``x`` order."""
        return tuple(s.name for s in self.states)

    def index(self, kind: str, name: str) -> int:
        """Position of signal ``name`` in the ``"state"``, ``"input"`` or ``"output"`` vector."""
        names = {"state": self.state_names, "input": self.inputs, "output": self.outputs}[kind]
        try:
            return names.index(name)
        except ValueError:
            raise ModelError(f"unknown {kind} {name!r} of effect set {self.effects}; known: {', '.join(names)}") from None

    def p_vector(self, params: ParameterSet) -> np.ndarray:
        """Values of ``params`` in this plant's ``p`` order (by name)."""
        missing = [n for n in self.parameters if n not in params]
        if missing:
            raise ParameterError(missing[0], "missing from the parameter set")
        return np.array([params[n].value for n in self.parameters], dtype=float)

    def initial_state(self, params: ParameterSet, *, load_force: float = 0.0, nut_position: float = 0.0) -> np.ndarray:
        """State at rest with the load-path springs in equilibrium with ``load_force`` [N]."""
        return np.asarray(self.init(nut_position, load_force, self.p_vector(params))).ravel()

    def sensor_state(self, channel: str) -> str:
        """The state the sensor of rig channel ``channel`` reads (``"motor_speed"``: the rotors' speed)."""
        try:
            return self.sensors[channel].state
        except KeyError:
            raise ModelError(f"no sensor {channel!r} in the measurement map; sensors are {', '.join(SENSORS)}") from None

    def _p(self, params) -> np.ndarray:
        return params if isinstance(params, np.ndarray) else self.p_vector(params)

    def kinematic_ratio(self, params) -> float:
        """Nut travel per motor radian ``lead / (2 pi N)`` [m/rad] (``params``: ParameterSet or p vector)."""
        return float(self.ratio_fn(self._p(params)))

    def torque_constant(self, params) -> float:
        """Motor torque constant [N m/A] (``params``: ParameterSet or p vector)."""
        return float(self.kt_fn(self._p(params)))

    def inertia(self, params, x=None) -> tuple[float, float]:
        """``(J_main, J_motor)`` [kg m^2 at the motor shaft] at state ``x`` (default: at rest).

        ``J_main`` is the main body's (gear output, screw, nut and the
        translating masses; with the rotors when the drive train is rigid);
        ``J_motor`` is the inertia the motor current accelerates (the rotors
        when the drive train is compliant, else ``J_main``).
        """
        p = self._p(params)
        if x is None:
            x = np.asarray(self.init(0.0, 0.0, p)).ravel()
        j_main, j_motor = self.inertia_fn(x, p)
        return float(j_main), float(j_motor)

    def to_nlsys(self, params: ParameterSet, name: str = "thsa_plant"):
        """The continuous plant as a python-control ``NonlinearIOSystem``.

        States, inputs and outputs carry this plant's names; the parameters
        are fixed to ``params``.  Slow compared with the project's simulator:
        it calls casadi once per right-hand-side evaluation.
        """
        import control as ct

        p = self.p_vector(params)
        f = self.f

        def upd(t, x, u, _params):
            return np.asarray(f(x, u, p)[0]).ravel()

        def out(t, x, u, _params):
            return np.asarray(f(x, u, p)[1]).ravel()

        return ct.nlsys(upd, out, states=list(self.state_names), inputs=list(self.inputs),
                        outputs=list(self.outputs), name=name)


def _evaluate(value, res):
    return value(res) if callable(value) else value


def build_plant(level: str | None = "A", effects: Iterable[str] = (), *, remove: Iterable[str] = (),
                params: ParameterSet | None = None) -> Plant:
    """Build the plant of a level plus/minus effects.

    Parameters
    ----------
    level : {"A", "B", "C", "D"} or None
        Base level.
    effects : iterable of str
        Effects added to the level (e.g. ``["temperature_friction"]``).
    remove : iterable of str
        Effects removed from the level.
    params : ParameterSet, optional
        Only its names matter (the values are the ``p`` input); defaults to
        the embedded actuator.

    Returns
    -------
    Plant

    Raises
    ------
    ModelError
        Unknown level or effect, or a missing required effect.

    Examples
    --------
    >>> plant = build_plant("C")
    >>> plant.state_names
    ('motor_current', 'motor_speed', 'nut_position', 'pawl_clearance_comp', 'pawl_clearance_tens')
    """
    chosen = resolve_effects(level, add=effects, remove=remove)
    names = (params or default_parameters()).names
    # The plant is a function of the chosen effects' definitions and the parameter names only: built once per
    # process.  The key holds the identity of each chosen Effect (kept alive by the entry, so an id is not
    # reused): an effect registered again under the same name gets a new plant.
    objs = tuple(EFFECTS[e] for e in chosen)
    return _PLANTS.get((chosen, tuple(names), tuple(map(id, objs))), lambda: _build(chosen, names), keep=objs)


#: build_plant's memo: key -> Plant, the chosen Effect objects kept with it; the 64 most recently used.
_PLANTS = KeyedLRU(64)


def _build(chosen: tuple[str, ...], names) -> Plant:
    psym = ca.SX.sym("p", len(names))
    p = {n: psym[i] for i, n in enumerate(names)}
    for eff in chosen:
        for n in EFFECTS[eff].parameters:
            if n not in p:
                raise ParameterError(n, f"needed by effect {eff!r} but not in the parameter set")

    order = effect_order()
    states = STRUCTURE_STATES + tuple(s for e in order if e in chosen for s in EFFECTS[e].states)
    xsym = ca.SX.sym("x", len(states))
    x = {s.name: xsym[i] for i, s in enumerate(states)}
    usym = ca.SX.sym("u", len(INPUTS))
    u = {name: usym[i] for i, (name, _, _) in enumerate(INPUTS)}

    h = ca.SX.sym("h")  # the discrete form's step; Assembly.step, 0 in the continuous forms (:func:`continuous`)
    a = Assembly(states=states, x=x, u=u, p=p, effects=chosen, step=h)

    def continuous(e):
        """``e`` with the step at 0, where an effect used it (a torque averaged over a step)."""
        return ca.substitute(e, h, ca.SX(0.0)) if ca.depends_on(e, h) else e
    apply_structure(a)
    for e in order:
        if e in chosen:
            EFFECTS[e].apply(a)
    finish_structure(a)

    w = x["motor_speed"]
    J = sum_terms(a.inertia)
    t_smooth = sum_terms(expr for _, expr in a.torques)
    channels = a.channels

    def outputs(res: FrictionResolution):
        names_, units, exprs = [], {}, []
        for name, (unit, value) in a.outputs.items():
            names_.append(name)
            units[name] = unit
            exprs.append(_evaluate(value, res))
        extra = {
            "friction_torque": ("N m", res.total),
            "stuck": ("-", res.stuck),
            "loss_power": ("W", sum_terms(_evaluate(v, res) for v in a.losses.values())),
            "stored_energy": ("J", sum_terms(a.stored_energy.values())),
            "electrical_power": ("W", 1.5 * sum_terms(
                _evaluate(a.outputs[v][1], res) * x[c]
                for v, c in (("motor_voltage", "motor_current"), ("standby_voltage", "standby_current")) if c in x)),
            "load_power": ("W", (u["load_force"] + a.unmeasured_axial_force())
                           * _evaluate(a.outputs["surface_speed"][1], res)),
        }
        for name, (unit, expr) in extra.items():
            names_.append(name)
            units[name] = unit
            exprs.append(expr)
        return names_, units, ca.vertcat(*exprs)

    # ---- continuous form
    cont = {c.name: ca.if_else(w > 0, c.kinetic_pos, ca.if_else(w < 0, -c.kinetic_neg, 0.0)) for c in channels}
    res_c = FrictionResolution(cont, sum_terms(cont.values()), ca.SX(0.0), w)
    xdot = []
    for s in states:
        if s.kind == "lag":
            tau, target = a.lags[s.name]
            xdot.append((target - x[s.name]) / tau)
        elif s.kind == "speed":
            xdot.append((t_smooth - res_c.total) / J)
        else:
            xdot.append(a.rates[s.name])
    out_names, out_units, y_c = outputs(res_c)
    y_c = continuous(y_c)
    f = ca.Function("f", [xsym, usym, psym], [continuous(ca.vertcat(*xdot)), y_c],
                    ["x", "u", "p"], ["xdot", "y"])

    # ---- discrete form (in the step ``h``)
    s_pos = sum_terms(c.static_pos for c in channels)
    s_neg = sum_terms(c.static_neg for c in channels)
    k_pos = sum_terms(ca.fmin(c.kinetic_pos, c.static_pos) for c in channels)
    k_neg = sum_terms(ca.fmin(c.kinetic_neg, c.static_neg) for c in channels)
    momentum = J * w + h * t_smooth
    t_stick = momentum / h
    slip_pos = t_stick > s_pos
    slip_neg = t_stick < -s_neg
    stuck = ca.logic_not(ca.logic_or(slip_pos, slip_neg))
    t_fric = ca.if_else(slip_pos, k_pos, ca.if_else(slip_neg, -k_neg, t_stick))
    w_new = ca.if_else(stuck, 0.0, (momentum - h * t_fric) / J)
    disc = {}
    for c in channels:
        share = ca.if_else(t_stick >= 0, c.static_pos / ca.fmax(s_pos, _TINY), c.static_neg / ca.fmax(s_neg, _TINY))
        disc[c.name] = ca.if_else(
            slip_pos, ca.fmin(c.kinetic_pos, c.static_pos),
            ca.if_else(slip_neg, -ca.fmin(c.kinetic_neg, c.static_neg), t_stick * share),
        )
    res_d = FrictionResolution(disc, t_fric, ca.if_else(stuck, 1.0, 0.0), w_new, h)

    new_vel = {"motor_speed": w_new}
    for s in states:
        if s.kind == "velocity":
            new_vel[s.name] = x[s.name] + h * a.rates[s.name]
            if s.name in a.discrete:  # an effect's own update (e.g. a brake holding a body), given the explicit one
                new_vel[s.name] = a.discrete[s.name](dict(new_vel), h)
    old_syms = ca.vertcat(*(x[n] for n in new_vel))
    new_vals = ca.vertcat(*new_vel.values())
    x_next = []
    for s in states:
        if s.kind == "lag":
            tau, target = a.lags[s.name]
            x_next.append(target + (x[s.name] - target) * ca.exp(-h / tau))
        elif s.kind in ("speed", "velocity"):
            x_next.append(new_vel[s.name])
        elif s.kind == "position" and s.name in a.discrete:  # e.g. a twist limited by a slipping clutch
            x_next.append(a.discrete[s.name](new_vel, h))
        elif s.kind == "position":
            x_next.append(x[s.name] + h * ca.substitute(a.rates[s.name], old_syms, new_vals))
        elif s.kind == "custom":
            x_next.append(a.discrete[s.name](new_vel, h))
        else:  # pragma: no cover - StateInfo kinds are fixed above
            raise ModelError(f"state {s.name!r} has unknown kind {s.kind!r}")
    _, _, y_d = outputs(res_d)
    step = ca.Function("step", [xsym, usym, psym, h], [ca.vertcat(*x_next), y_d], ["x", "u", "p", "h"], ["x_next", "y"])

    # ---- initial state
    x_nut0, f0 = ca.SX.sym("nut_position"), ca.SX.sym("load_force")
    x0 = {s.name: ca.SX(0.0) for s in states}
    x0["nut_position"] = x_nut0
    for name, fn in a.initial.items():
        x0[name] = fn(x0, f0)
    init = ca.Function("init", [x_nut0, f0, psym], [continuous(ca.vertcat(*(x0[s.name] for s in states)))],
                       ["nut_position", "load_force", "p"], ["x0"])

    # ---- what the model knows beyond f and step, from the same assembly
    speed_state = "rotor_speed" if "rotor_speed" in x else "motor_speed"  # the motor sensor reads the rotors
    inv_n = ca.Function("inverse_gear_ratio", [psym], [1.0 / p["gear.ratio"]], ["p"], ["scale"])
    O = SENSOR_OUTPUTS
    sensors = {
        "motor_speed": Sensor("motor_speed", O["motor_speed"], speed_state),
        "motor_current": Sensor("motor_current", O["motor_current"], "motor_current"),
        "screw_speed": Sensor("screw_speed", O["screw_speed"], "motor_speed", inv_n),
        # the LVDT reads the output rod: the surface when the load path is compliant, else the nut
        "nut_position": Sensor("nut_position", O["nut_position"],
                               "surface_position" if "surface_position" in x else "nut_position"),
    }
    measure = ca.Function("measure", [xsym, usym, psym], [ca.vertcat(*(y_c[out_names.index(sensors[c].output)]
                                                                        for c in SENSORS))],
                          ["x", "u", "p"], ["y"])
    ratio_fn = ca.Function("kinematic_ratio", [psym], [a.kinematic_ratio], ["p"], ["r"])
    kt_fn = ca.Function("torque_constant", [psym], [a.torque_constant], ["p"], ["kt"])
    inertia_fn = ca.Function("inertia", [xsym, psym], [a.main_inertia, a.rotor_body_inertia], ["x", "p"],
                             ["j_main", "j_motor"])

    qs_states = tuple(st.name for st in states if st.name in a.quasi_static)
    qs_x = [a.quasi_static[st.name] if st.name in a.quasi_static else x[st.name] for st in states]
    quasi_static = ca.Function("quasi_static", [xsym, usym, psym], [continuous(ca.vertcat(*qs_x))],
                               ["x", "u", "p"], ["x_qs"])

    return Plant(
        quasi_static_states=qs_states, quasi_static=quasi_static,
        effects=chosen, states=states, inputs=tuple(n for n, _, _ in INPUTS), outputs=tuple(out_names),
        output_units=out_units, parameters=names, f=f, step=step, init=init, sensors=sensors, measure=measure,
        ratio_fn=ratio_fn, kt_fn=kt_fn, inertia_fn=inertia_fn,
    )
