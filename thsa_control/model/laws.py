"""Component laws of the effect library as casadi Functions (for component identification).

Each law is built from the same helper expressions the effects use
(``effects.stribeck``, ``effects.loadpath_force_law``,
``effects.temperature_drag_terms``), so that fitting a component table and
simulating the actuator use one copy of the physics.  A law's Function takes
its operating variables and its parameters, both named.

Examples
--------
>>> law = LAWS["noback_disk_neg"]
>>> law.inputs, law.parameters
(('screw_speed', 'normal_force'), ('noback.mu_static_neg', 'noback.mu_coulomb_neg', 'noback.viscous_neg', 'noback.stribeck_speed_neg'))
>>> round(float(law.function(-1.0, 10000.0, [0.0066, 0.0043, 0.0, 1.5865])), 3)
-58.459
"""

from __future__ import annotations

from dataclasses import dataclass

import casadi as ca

from .effects import loadpath_force_law, stribeck, temperature_drag_terms

__all__ = ["Law", "LAWS"]


@dataclass(frozen=True)
class Law:
    """A component law ``function(*inputs, parameters) -> output``.

    Attributes
    ----------
    name : str
    inputs : tuple of str
        Operating variables (SI: screw speed [rad/s], normal force [N],
        deflection [m], motor speed [rad/s], temperature [degC]).
    parameters : tuple of str
        Parameter names, in the order of the Function's last input.
    output : str
        What it returns, with unit.
    function : casadi.Function
    """

    name: str
    inputs: tuple[str, ...]
    parameters: tuple[str, ...]
    output: str
    function: ca.Function


def _law(name, inputs, parameters, output, build):
    syms = [ca.SX.sym(n) for n in inputs]
    psym = ca.SX.sym("p", len(parameters))
    p = {n: psym[i] for i, n in enumerate(parameters)}
    expr = build(p, *syms)
    return Law(name, tuple(inputs), tuple(parameters), output,
               ca.Function(name, [*syms, psym], [expr], [*inputs, "p"], ["out"]))


def _disk(direction):
    names = tuple(f"noback.{k}_{direction}" for k in ("mu_static", "mu_coulomb", "viscous", "stribeck_speed"))

    def build(p, ws, n):
        mu = stribeck(p[names[0]], p[names[1]], ws, p[names[3]])
        return mu * ca.fabs(n) * ca.sign(ws) + p[names[2]] * ws

    return _law(f"noback_disk_{direction}", ("screw_speed", "normal_force"), names,
                "friction torque of one disk set at the screw [N m] (sign of the speed)", build)


_LOADPATH = tuple(f"loadpath.{k}" for k in ("backlash", "disk_spring_stiffness", "contact_stiffness_upper",
                                            "contact_stiffness_lower", "contact_damping", "disk_spring_damping"))
_TEMP = ("gear.viscous_friction", "motor.bearing_viscous_friction") + tuple(f"friction.{k}" for k in (
    "reference_temperature", "viscous_temperature_coefficient", "cold_coulomb_torque",
    "coulomb_temperature_coefficient", "cold_stribeck_ratio", "cold_stribeck_speed"))


def _drag(p, w, temperature):
    db, _, kinetic = temperature_drag_terms(p, w, temperature)
    b = p["gear.viscous_friction"] + p["motor.bearing_viscous_friction"] + db
    return b * w + kinetic * ca.sign(w)


LAWS: dict[str, Law] = {
    law.name: law
    for law in (
        _disk("pos"),
        _disk("neg"),
        _law("loadpath_force", ("deflection",), _LOADPATH,
             "static load-path force [N], compressive positive", lambda p, d: loadpath_force_law(p, d, 0.0)[0]),
        _law("transmission_drag", ("motor_speed", "temperature"), _TEMP,
             "no-load drag torque of gearbox, screw and motor bearings at the motor shaft [N m]", _drag),
    )
}
