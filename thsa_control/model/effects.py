"""Effect library: the physical effects that model levels add to the structure.

Each effect is a pure function of an :class:`~thsa_control.model.structure.Assembly`
that declares its states and parameters and adds terms (torques, friction
channels, states with their derivatives, losses, outputs).  It is written once
as casadi expressions; linearisation, simulation, optimisation and
identification all consume the same terms through ``plant.py``.

Effects (the papers' incremental modelling):

``standby_motor``
    A second, identical PMSM torque-summed at the gearbox input, with its own
    enable; its rotor is always dragged (inertia and bearing drag).
``loadpath_compliance``
    The nut (with the load-path mass) and the surface become two bodies joined
    by the papers' piecewise law: disk springs ``2 kds x`` everywhere, contact
    springs ``kp,u`` beyond ``+b`` and ``kp,l`` beyond ``-b`` with contact
    damping that cannot pull (Modelica ``ElastoBacklash`` rule).
``temperature_friction``
    Gearbox and nut-screw drag as a function of speed and temperature::

        b(T)  = b_25 exp(a_v (T_ref - T))
        Tc(T) = T_cold (exp(a_c max(T_ref - T, 0)) - 1)
        T_f   = Tc(T) (1 + r_st exp(-(w/w_st)^2)) sgn(w) + b(T) w

    It rises at low temperature and at low speed, and at ``T_ref`` (25 degC) it
    is exactly the base (level-A) viscous drag.  Valid -55..70 degC.
``noback_quadrant_friction``
    Two friction-disk sets, each between the screw flange and a ratchet wheel.
    The compressive-side wheel is locked by its pawl against retraction, the
    tensile-side wheel against extension; the other direction is free, so the
    wheel turns with the screw and its disks do not slip.  Normal forces:
    the loaded disk ``preload + |F|``, the light one ``max(preload - |F|, 0)``,
    i.e. ``N_comp = max(preload + F, 0)``, ``N_tens = max(preload - F, 0)``
    (``F`` the force through the no-back: the load-path force at level D).  So when
    the load aids the motion the loaded disk slips (large friction) and when it
    opposes, the preload-only disk slips (small friction); with the motors off
    the loaded disk holds the load by stiction.  Disk law per rotation
    direction: ``T = (mu_c + (mu_s - mu_c) exp(-(ws/ws_t)^2)) N sgn(ws) + fs ws``.
``noback_ideal``
    Level A's no-back (paper 001, basic model (a); paper 000's "ideal"
    no-back): a Coulomb torque ``Tb = F_L / TF`` (the load torque at the
    screw, ``F r`` at the motor shaft) against motion in the direction the
    load pushes.  Irreversible: the de-energised actuator holds, the motor
    drives an aiding load with ``(1 - eta_i) F r``.  Removed (``remove=
    ["noback_ideal"]``) it leaves the reversible functional model; the
    detailed ``noback_quadrant_friction`` supersedes it.
``drivetrain_compliance``
    The motor rotors become a body of their own, joined to the gear output by
    the gearbox stiffness and damping (paper 000, Figure 6) in series with the
    screw's torsional stiffness.  The motor speed sensor reads the rotors;
    ``screw_speed`` the gear output.  Removing it gives the rigid model
    exactly; a stiff spring approaches it.
``noback_backlash``
    The ratchet/pawl clearance: a wheel turned in its free direction lets its
    pawl drop behind each tooth, so the clearance to the locking face grows
    from 0 to one pitch (8.57 deg) and wraps; turned the other way, the wheel
    (and the screw, its disks sticking) travels the clearance freely before
    the pawl engages.  Needs ``noback_quadrant_friction``.

Simplifications stated here once: the ratchet wheels' inertia is counted with
the screw at all times (0.7 % of the reflected inertia; the impact of a wheel
stopped by its pawl is not modelled); the gearbox efficiency acts on the
torque entering the gearbox by the direction of power flow there (see
``structure.finish_structure``); i_d is held at zero (the d voltage only
takes its share of the voltage circle).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca

from .structure import Assembly, FrictionChannel, StateInfo, kinematic_ratio, motor_lag, torque_constant

__all__ = ["Effect", "EFFECTS", "EFFECT_ORDER", "stribeck", "temperature_drag_terms", "loadpath_force_law",
           "drivetrain_stiffness",
           "loadpath_static_deflection"]


@dataclass(frozen=True)
class Effect:
    """A physical effect: what it adds, and the function that adds it.

    Parameters
    ----------
    name : str
        Effect name used in effect sets.
    summary : str
        One line for listings.
    states : tuple of StateInfo
        States it adds.
    parameters : tuple of str
        Parameters it reads (beyond the structure's).
    requires : tuple of str
        Effects that must be in the same set.
    apply : callable
        ``apply(assembly)`` adds the terms.
    supersedes : tuple of str
        Effects it replaces when both are asked for (the detailed no-back
        replaces level A's ideal one).
    """

    name: str
    summary: str
    states: tuple[StateInfo, ...]
    parameters: tuple[str, ...]
    requires: tuple[str, ...]
    apply: Callable[[Assembly], None]
    supersedes: tuple[str, ...] = ()


def _standby_motor(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    w = a.rotor_speed
    i = x["standby_current"]
    tau, target, v_applied, v_d, copper = motor_lag(a, i, u["voltage_standby"], u["enable_standby"], w)
    a.lags["standby_current"] = (tau, target)
    a.rotor_torques.append(("motor_standby", torque_constant(p) * i))
    a.rotor_inertia.append(p["motor.rotor_inertia"])  # the standby rotor is always dragged
    b = p["motor.bearing_viscous_friction"]
    a.rotor_torques.append(("viscous_standby", -b * w))
    a.loss("viscous_standby", b * w**2)
    a.output("standby_voltage_d", "V", v_d)
    a.loss("copper_standby", copper)
    a.stored_energy["magnetic_standby"] = 0.75 * p["motor.inductance"] * i**2
    a.output("standby_current", "A", i)
    a.output("standby_voltage", "V", v_applied)
    a.output("standby_energised", "-", ca.if_else(u["enable_standby"] > 0.5, 1.0, 0.0))


def loadpath_force_law(p: dict, deflection, deflection_rate):
    """Papers' piecewise load-path law [N], compressive positive.

    ``deflection = x_nut - x_surface`` [m] (positive: the nut pushes the
    surface), ``deflection_rate`` its derivative [m/s].  Returns
    ``(force, conservative_part)``.
    """
    d, dd = deflection, deflection_rate
    b = p["loadpath.backlash"]
    k_ds = 2.0 * p["loadpath.disk_spring_stiffness"]
    c = p["loadpath.contact_damping"]
    upper = ca.if_else(d > b, ca.fmax(p["loadpath.contact_stiffness_upper"] * (d - b) + c * dd, 0.0), 0.0)
    lower = ca.if_else(d < -b, ca.fmin(p["loadpath.contact_stiffness_lower"] * (d + b) + c * dd, 0.0), 0.0)
    spring = (
        k_ds * d
        + p["loadpath.contact_stiffness_upper"] * ca.fmax(d - b, 0.0)
        + p["loadpath.contact_stiffness_lower"] * ca.fmin(d + b, 0.0)
    )
    force = k_ds * d + p["loadpath.disk_spring_damping"] * dd + upper + lower
    return force, spring


def loadpath_static_deflection(p: dict, force):
    """Deflection [m] at which the load path carries ``force`` [N] at rest (inverse of the law)."""
    b = p["loadpath.backlash"]
    k_ds = 2.0 * p["loadpath.disk_spring_stiffness"]
    ku, kl = p["loadpath.contact_stiffness_upper"], p["loadpath.contact_stiffness_lower"]
    f_edge = k_ds * b
    return ca.if_else(
        force > f_edge,
        (force + ku * b) / (k_ds + ku),
        ca.if_else(force < -f_edge, (force - kl * b) / (k_ds + kl), force / ca.fmax(k_ds, 1e-300)),
    )


def _loadpath_compliance(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    r = kinematic_ratio(p)
    v_nut = r * x["motor_speed"]
    d = x["nut_position"] - x["surface_position"]
    dd = v_nut - x["surface_speed"]
    force, spring = loadpath_force_law(p, d, dd)
    a.translating_mass = p["loadpath.mass"]  # the surface is now a body of its own
    a.axial_force = force
    a.rates["surface_position"] = x["surface_speed"]
    a.rates["surface_speed"] = (force - u["load_force"]) / p["surface.mass"]
    a.loss("loadpath_damping", (force - spring) * dd)
    b = p["loadpath.backlash"]
    a.stored_energy["loadpath_springs"] = (
        p["loadpath.disk_spring_stiffness"] * d**2
        + 0.5 * p["loadpath.contact_stiffness_upper"] * ca.fmax(d - b, 0.0) ** 2
        + 0.5 * p["loadpath.contact_stiffness_lower"] * ca.fmin(d + b, 0.0) ** 2
    )
    a.stored_energy["kinetic_surface"] = 0.5 * p["surface.mass"] * x["surface_speed"] ** 2
    a.initial["surface_position"] = lambda x0, f0: x0["nut_position"] - loadpath_static_deflection(p, f0)
    a.output("surface_position", "m", x["surface_position"])
    a.output("surface_speed", "m/s", x["surface_speed"])
    a.output("loadpath_force", "N", force)
    a.output("loadpath_deflection", "m", d)


def temperature_drag_terms(p: dict, speed, temperature):
    """Terms of the temperature law at motor speed ``speed`` [rad/s] and ``temperature`` [degC].

    Returns ``(delta_viscous, coulomb_static, coulomb_kinetic)``: the change of
    the gearbox/screw viscous coefficient from its 25 degC value [N m s/rad]
    and the extra Coulomb drag at standstill and at ``speed`` [N m], all
    referred to the motor shaft.
    """
    dT = p["friction.reference_temperature"] - temperature
    db = p["gear.viscous_friction"] * (ca.exp(p["friction.viscous_temperature_coefficient"] * dT) - 1.0)
    tc = p["friction.cold_coulomb_torque"] * (ca.exp(p["friction.coulomb_temperature_coefficient"] * ca.fmax(dT, 0.0)) - 1.0)
    r_st = p["friction.cold_stribeck_ratio"]
    kinetic = tc * (1.0 + r_st * ca.exp(-((speed / p["friction.cold_stribeck_speed"]) ** 2)))
    return db, tc * (1.0 + r_st), kinetic


def _temperature_friction(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    w = x["motor_speed"]
    db, static, kinetic = temperature_drag_terms(p, w, u["temperature"])
    a.torques.append(("viscous_temperature", -db * w))
    a.loss("viscous_temperature", db * w**2)  # sums with "viscous" to b(T) w^2 >= 0
    a.channels.append(FrictionChannel("temperature", static, static, kinetic, kinetic))
    a.loss("temperature_coulomb", lambda res: res.channel["temperature"] * res.speed)
    a.output("temperature_drag_torque", "N m", lambda res: res.channel["temperature"])
    a.output("viscous_coefficient", "N m s/rad", p["motor.bearing_viscous_friction"] + p["gear.viscous_friction"] + db)


def stribeck(mu_s, mu_c, speed, w_st):
    """Stribeck coefficient ``mu_c + (mu_s - mu_c) exp(-(speed/w_st)^2)`` of the disk law."""
    return mu_c + (mu_s - mu_c) * ca.exp(-((speed / w_st) ** 2))


def _noback_quadrant_friction(a: Assembly) -> None:
    x, p = a.x, a.p
    w = x["motor_speed"]
    N = p["gear.ratio"]
    ws = w / N
    F = a.axial_force
    pre = noback_preload(a)
    # the loaded disk sees preload + |F|; the light one what the load leaves of
    # the preload, max(preload - |F|, 0) (paper 001: "limited within the spring
    # preload and grows smaller with the increase in compressive load")
    n_comp = ca.fmax(pre + F, 0.0)
    n_tens = ca.fmax(pre - F, 0.0)
    g_comp = a.pawl_engaged.get("comp", 1.0)
    g_tens = a.pawl_engaged.get("tens", 1.0)
    a.inertia.append(2.0 * p["noback.ratchet_inertia"] / N**2)
    # compressive-side disks slip only in retraction (their wheel is locked then)
    s_comp = g_comp * p["noback.mu_static_neg"] * n_comp / N
    k_comp = g_comp * stribeck(p["noback.mu_static_neg"], p["noback.mu_coulomb_neg"], ws, p["noback.stribeck_speed_neg"]) * n_comp / N
    a.channels.append(FrictionChannel("noback_comp", 0.0, s_comp, 0.0, k_comp))
    s_tens = g_tens * p["noback.mu_static_pos"] * n_tens / N
    k_tens = g_tens * stribeck(p["noback.mu_static_pos"], p["noback.mu_coulomb_pos"], ws, p["noback.stribeck_speed_pos"]) * n_tens / N
    a.channels.append(FrictionChannel("noback_tens", s_tens, 0.0, k_tens, 0.0))
    visc = ca.if_else(w < 0, g_comp * p["noback.viscous_neg"], ca.if_else(w > 0, g_tens * p["noback.viscous_pos"], 0.0)) / N**2
    a.torques.append(("noback_viscous", -visc * w))
    a.loss("noback_viscous", visc * w**2)
    a.loss("noback_disks", lambda res: (res.channel["noback_comp"] + res.channel["noback_tens"]) * res.speed)
    a.output("noback_torque", "N m", lambda res: (res.channel["noback_comp"] + res.channel["noback_tens"]) * N - visc * w * N)
    a.output("noback_normal_force_comp", "N", n_comp)
    a.output("noback_normal_force_tens", "N", n_tens)
    a.output("noback_disk_comp_slipping", "-", lambda res: g_comp * ca.if_else(res.speed < 0, 1.0, 0.0))
    a.output("noback_disk_tens_slipping", "-", lambda res: g_tens * ca.if_else(res.speed > 0, 1.0, 0.0))
    a.output("pawl_comp_engaged", "-", g_comp)
    a.output("pawl_tens_engaged", "-", g_tens)
    a.output("pawl_engaged", "-", ca.if_else(F >= 0, g_comp, g_tens))


def noback_preload(a: Assembly):
    """No-back disk-spring preload [N]; with ``temperature_friction`` it dilates with temperature.

    Paper 000 (temperature section) names the preload change by thermal
    dilation but gives no value: ``preload (1 + k_T (T_ref - T))`` with an
    assumed ``friction.preload_temperature_coefficient`` (see the parameter
    file for its reason and range).
    """
    pre = a.p["noback.preload"]
    if a.has("temperature_friction"):
        dT = a.p["friction.reference_temperature"] - a.u["temperature"]
        pre = pre * ca.fmax(1.0 + a.p["friction.preload_temperature_coefficient"] * dT, 0.0)
    return pre


def _noback_ideal(a: Assembly) -> None:
    # Paper 001 basic model (a): the no-back as a Coulomb torque Tb = F_L / TF
    # (the load torque at the screw, no efficiency) against motion in the
    # direction the load pushes; nothing against the other direction.  Since
    # Tb exceeds what the load can back-drive through the screw (F r eta_i),
    # the de-energised actuator holds by stiction and the motor needs only
    # (1 - eta_i) F r (plus drag) to move with an aiding load.
    r = kinematic_ratio(a.p)
    F = a.axial_force
    against_neg = ca.fmax(F, 0.0) * r  # compressive load pushes towards retraction
    against_pos = ca.fmax(-F, 0.0) * r
    a.channels.append(FrictionChannel("noback_ideal", against_pos, against_neg, against_pos, against_neg))
    a.loss("noback_ideal", lambda res: res.channel["noback_ideal"] * res.speed)
    a.output("noback_torque", "N m", lambda res: res.channel["noback_ideal"] * a.p["gear.ratio"])


def drivetrain_stiffness(p) -> object:
    """Torsional stiffness of the drive train at the motor shaft [N m/rad] (``drivetrain_compliance``).

    Paper 000, Figure 6: the gearbox stiffness k_g in series with the screw's
    torsional stiffness (no inertia between them: the screw inertia sits at
    the nut end with the no-back), referred to the motor shaft by ``1/N^2``.
    ``p`` maps parameter names to values (numbers or casadi expressions).
    """
    k_eq = 1.0 / (1.0 / p["gear.torsional_stiffness"] + 1.0 / p["screw.torsional_stiffness"])
    return k_eq / p["gear.ratio"] ** 2


def _drivetrain_compliance(a: Assembly) -> None:
    # Paper 000, Figure 6: the spring of drivetrain_stiffness and the gearbox
    # damping d_g between the motor rotors and the gear output, at the motor shaft.
    x, p = a.x, a.p
    k, d = drivetrain_stiffness(p), p["gear.torsional_damping"] / p["gear.ratio"] ** 2
    twist = x["drivetrain_twist"]

    def coupling(wr, w):
        return k * twist + d * (wr - w)

    a.coupling = coupling
    wr, w = x["rotor_speed"], x["motor_speed"]
    a.rates["drivetrain_twist"] = wr - w
    a.stored_energy["drivetrain_spring"] = 0.5 * k * twist**2
    a.loss("drivetrain_damping", d * (wr - w) ** 2)
    a.output("drivetrain_twist", "rad", twist)
    a.output("drivetrain_torque", "N m", coupling(wr, w))


def _noback_backlash(a: Assembly) -> None:
    x, p = a.x, a.p
    N = p["gear.ratio"]
    pitch = p["noback.pawl_pitch"]
    c_comp, c_tens = x["pawl_clearance_comp"], x["pawl_clearance_tens"]
    a.pawl_engaged["comp"] = ca.if_else(c_comp <= 0.0, 1.0, 0.0)
    a.pawl_engaged["tens"] = ca.if_else(c_tens <= 0.0, 1.0, 0.0)
    a.rates["pawl_clearance_comp"] = x["motor_speed"] / N
    a.rates["pawl_clearance_tens"] = -x["motor_speed"] / N

    def advance(c, travel):
        # travel > 0: free direction (pawl drops behind each tooth, clearance wraps);
        # travel < 0: towards the locking face, stopped there.
        moved = c + travel
        wrapped = ca.if_else(pitch > 0, ca.fmod(moved, ca.fmax(pitch, 1e-300)), 0.0)
        return ca.if_else(travel >= 0, wrapped, ca.fmax(moved, 0.0))

    a.discrete["pawl_clearance_comp"] = lambda new, h: advance(c_comp, h * new["motor_speed"] / N)
    a.discrete["pawl_clearance_tens"] = lambda new, h: advance(c_tens, -h * new["motor_speed"] / N)
    a.initial["pawl_clearance_comp"] = lambda x0, f0: p["noback.pawl_initial_clearance"] * pitch
    a.initial["pawl_clearance_tens"] = lambda x0, f0: p["noback.pawl_initial_clearance"] * pitch
    a.output("pawl_clearance_comp", "rad", c_comp)
    a.output("pawl_clearance_tens", "rad", c_tens)


_NOBACK = tuple(f"noback.{n}" for n in (
    "preload", "ratchet_inertia", "mu_static_pos", "mu_coulomb_pos", "viscous_pos", "stribeck_speed_pos",
    "mu_static_neg", "mu_coulomb_neg", "viscous_neg", "stribeck_speed_neg",
))

EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect(
            "standby_motor", "second PMSM torque-summed at the gearbox input, rotor always dragged",
            (StateInfo("standby_current", "A", "lag", "q-axis current of the standby motor"),),
            ("motor.rotor_inertia", "motor.bearing_viscous_friction"), (), _standby_motor,
        ),
        Effect(
            "loadpath_compliance", "load-path backlash and preload compliance; surface as a separate body",
            (
                StateInfo("surface_position", "m", "position", "surface position referred to the nut axis"),
                StateInfo("surface_speed", "m/s", "velocity", "surface speed referred to the nut axis"),
            ),
            tuple(f"loadpath.{n}" for n in (
                "contact_stiffness_lower", "contact_stiffness_upper", "disk_spring_stiffness", "backlash",
                "contact_damping", "disk_spring_damping")) + ("surface.mass",),
            (), _loadpath_compliance,
        ),
        Effect(
            "temperature_friction", "gearbox and nut-screw drag rising at low temperature and low speed",
            (),
            tuple(f"friction.{n}" for n in (
                "reference_temperature", "viscous_temperature_coefficient", "cold_coulomb_torque",
                "coulomb_temperature_coefficient", "cold_stribeck_ratio", "cold_stribeck_speed")),
            (), _temperature_friction,
        ),
        Effect(
            "noback_backlash", "ratchet/pawl clearance crossed before the pawl engages",
            (
                StateInfo("pawl_clearance_comp", "rad", "custom", "screw travel left before the compressive-side pawl locks retraction"),
                StateInfo("pawl_clearance_tens", "rad", "custom", "screw travel left before the tensile-side pawl locks extension"),
            ),
            ("noback.pawl_pitch", "noback.pawl_initial_clearance"), ("noback_quadrant_friction",), _noback_backlash,
        ),
        Effect(
            "noback_quadrant_friction", "no-back friction disks with load- and quadrant-dependent normal force",
            (), _NOBACK, (), _noback_quadrant_friction, supersedes=("noback_ideal",),
        ),
        Effect(
            "noback_ideal", "ideal irreversible no-back (level A): Coulomb torque F r against load-aided motion",
            (), (), (), _noback_ideal,
        ),
        Effect(
            "drivetrain_compliance", "gearbox and screw torsional compliance between the motor rotors and the gear output",
            (
                StateInfo("rotor_speed", "rad/s", "velocity", "speed of the motor rotors (gearbox input), the motor sensor"),
                StateInfo("drivetrain_twist", "rad", "position", "rotor angle minus gear-output angle, at the motor shaft"),
            ),
            ("gear.torsional_stiffness", "screw.torsional_stiffness", "gear.torsional_damping"), (),
            _drivetrain_compliance,
        ),
    )
}

#: Order in which effects are applied: those that change the axial force or
#: gate the pawls come before those that read them.
EFFECT_ORDER: tuple[str, ...] = (
    "standby_motor", "drivetrain_compliance", "loadpath_compliance", "temperature_friction", "noback_backlash",
    "noback_quadrant_friction", "noback_ideal",
)

# Generic drive effects (drive_effects.py), applied after the load path and
# before the no-back, which reads the axial force that force_offset changes.
from .drive_effects import DRIVE_EFFECT_ORDER, DRIVE_EFFECTS  # noqa: E402

EFFECTS.update(DRIVE_EFFECTS)
EFFECT_ORDER = (tuple(e for e in EFFECT_ORDER if not e.startswith("noback")) + DRIVE_EFFECT_ORDER
                + tuple(e for e in EFFECT_ORDER if e.startswith("noback")))

# Fault effects (model F, issue #10): same API, in their own module, applied after the effects above.
from .fault_effects import FAULT_EFFECT_ORDER, FAULT_EFFECTS  # noqa: E402

EFFECTS.update(FAULT_EFFECTS)
EFFECT_ORDER = EFFECT_ORDER + FAULT_EFFECT_ORDER
