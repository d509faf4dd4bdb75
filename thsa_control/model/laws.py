"""Pure laws of the model: the physics every effect, the structure and the tools use, written once.

Two kinds, both casadi-only and free of any effect machinery:

* **Elementary laws** of the actuator, functions of a parameter mapping ``p``
  (name -> number or casadi expression; a :class:`~thsa_control.model.params.ParameterSet`
  is accepted too) and operating variables: the screw-to-nut ratio
  :func:`kinematic_ratio`, the torque constant :func:`torque_constant`, the
  q-axis motor electrics :func:`motor_lag`, the no-back's disk normal forces
  :func:`noback_disk_normal_forces`, the friction laws (:func:`stribeck`,
  :func:`temperature_drag_terms`, :func:`drive_coulomb_terms`), the load-path
  law and its inverse, the drive-train stiffness, the limiter's slip torques,
  the screw and motor angles.  The structure (``structure.py``) and the effect
  modules (``effects/``) build the plant from them; code outside ``model/``
  that needs one of these facts for a parameter set (a controller vector, a
  report's axis) calls the same function, so no fact is restated.
* **Component laws** :data:`LAWS`: some of the laws above as named casadi
  Functions of their operating variables and parameters, for component
  identification (a friction-disk table, a load-path table, a drag table).

This module imports casadi and math only.

Examples
--------
>>> law = LAWS["noback_disk_neg"]
>>> law.inputs, law.parameters
(('screw_speed', 'normal_force'), ('noback.mu_static_neg', 'noback.mu_coulomb_neg', 'noback.viscous_neg', 'noback.stribeck_speed_neg'))
>>> round(float(law.function(-1.0, 10000.0, [0.0066, 0.0043, 0.0, 1.5865])), 3)
-58.459
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca

__all__ = ["Law", "LAWS", "values_of", "kinematic_ratio", "torque_constant", "back_emf_constant", "motor_lag",
           "stribeck", "noback_disk_normal_forces",
           "temperature_drag_terms", "loadpath_force_law", "loadpath_static_deflection",
           "drivetrain_stiffness", "drivetrain_modes", "drivetrain_damping_ratio", "stiffness_of_output_mode",
           "limiter_slip_torques", "drive_coulomb_terms", "screw_angle", "motor_angle"]


def values_of(p):
    """``name -> value`` of a parameter set; a plain mapping is returned as it is."""
    if hasattr(p, "value") and callable(p.value) and hasattr(p, "names"):
        return {n: p.value(n) for n in p.names}
    return p


# ----------------------------------------------------------------------------- elementary laws
def kinematic_ratio(p):
    """Nut travel per motor radian ``r = lead / (2 pi N)`` [m/rad]."""
    p = values_of(p)
    return p["screw.lead"] / (2 * math.pi * p["gear.ratio"])


def torque_constant(p):
    """PMSM torque constant ``Kt = 1.5 p psi`` [N m/A] (amplitude-invariant dq)."""
    p = values_of(p)
    return 1.5 * p["motor.pole_pairs"] * p["motor.flux_linkage"]


def back_emf_constant(p):
    """q-axis back-EMF per motor speed ``p psi`` [V s/rad] (``Kt / 1.5``)."""
    p = values_of(p)
    return p["motor.pole_pairs"] * p["motor.flux_linkage"]


def motor_lag(p, current, voltage, enable, speed):
    """q-axis electrics of one motor as a first-order lag ``(tau, target)``.

    ``L di/dt = clamp(v) - R i - p psi w`` while energised; with the inverter
    off the current decays with ``motor.off_current_time_constant``.  Written
    as ``di/dt = (target - i) / tau`` so that the discrete map can integrate it
    exactly over a step with the speed frozen.  The q voltage is clamped to
    what the dq voltage circle leaves it: ``vq_max = sqrt(Vmax^2 - (w_e L i_q)^2)``
    with ``Vmax = V_dc / sqrt(3)`` (i_d = 0 control; the d voltage follows).
    Returns ``(tau, target, v_q, v_d, copper_loss)``.
    """
    vmax = p["inverter.dc_bus_voltage"] / math.sqrt(3.0)
    # The inverter limits the dq voltage vector to V_dc/sqrt(3).  With i_d held
    # at zero the d-axis voltage the current controller must apply is
    # v_d = -w_e L i_q, so the q axis gets what is left of the circle.
    v_d = -p["motor.pole_pairs"] * speed * p["motor.inductance"] * current
    vq_max = ca.sqrt(ca.fmax(vmax**2 - v_d**2, 0.0))
    v = ca.fmin(ca.fmax(voltage, -vq_max), vq_max)
    back_emf = p["motor.pole_pairs"] * p["motor.flux_linkage"] * speed
    on = enable > 0.5
    tau = ca.if_else(on, p["motor.inductance"] / p["motor.resistance"], p["motor.off_current_time_constant"])
    target = ca.if_else(on, (v - back_emf) / p["motor.resistance"], 0.0)
    # copper loss when energised; when off the magnetic energy is dissipated in the diodes
    loss = ca.if_else(
        on, 1.5 * p["motor.resistance"], 1.5 * p["motor.inductance"] / p["motor.off_current_time_constant"]
    ) * current**2
    v_d = ca.if_else(on, v_d, 0.0)
    return tau, target, v, v_d, loss


def stribeck(mu_s, mu_c, speed, w_st):
    """Stribeck coefficient ``mu_c + (mu_s - mu_c) exp(-(speed/w_st)^2)`` of the disk law."""
    return mu_c + (mu_s - mu_c) * ca.exp(-((speed / w_st) ** 2))


def noback_disk_normal_forces(preload, force, share=0.5):
    """Normal forces ``(N_comp, N_tens)`` [N] of the no-back's two friction-disk sets under the axial force ``force``.

    The screw flange sits between the two disk sets, clamped by the disk-spring ``preload``; ``force`` (compressive
    positive) pushes it onto the compressive-side set.  The flange's force balance holds at every load,
    ``N_comp - N_tens = force``.  The flange moves until the two sets' force changes balance the load, so each set
    takes the load change in proportion to its stiffness: ``share = k_comp / (k_comp + k_tens)`` of a compressive
    load goes onto the compressive set and ``1 - share`` off the tensile one (a tensile load: ``1 - share`` onto the
    tensile set, ``share`` off the compressive one), until the light set unloads at ``force = preload / (1 - share)``
    (tensile: ``|force| = preload / share``); beyond it the loaded set carries ``|force|`` alone and the light one
    nothing.  So the light set's force "is limited within the spring preload and grows smaller with the increase in
    compressive load" (paper 001), and each set carries its part of the load plus what is left of the preload::

        m = max(preload - (1 - share) max(force, 0) - share max(-force, 0), 0)
        N_comp = max(force, 0) + m,   N_tens = max(-force, 0) + m

    ``share`` 0.5 (``noback.load_share``, assumed: the papers give one preload and one disk design for both sides):
    ``preload +- force / 2`` until ``|force| = 2 preload``.  Continuous through zero load; kinks where the light set
    unloads.
    """
    comp, tens = ca.fmax(force, 0.0), ca.fmax(-force, 0.0)
    rest = ca.fmax(preload - (1.0 - share) * comp - share * tens, 0.0)
    return comp + rest, tens + rest


def temperature_drag_terms(p, speed, temperature):
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


def loadpath_force_law(p, deflection, deflection_rate):
    """Papers' piecewise load-path law [N], compressive positive.

    ``deflection = x_nut - x_surface`` [m] (positive: the nut pushes the
    surface), ``deflection_rate`` its derivative [m/s].  Returns
    ``(force, conservative_part)``.  ``loadpath.backlash`` is signed (the
    papers' ``x0``): positive, a soft zone of ``+-b`` where only the disk
    springs carry the load; negative, both contacts preloaded (overlapping by
    ``|b|``), stiffness ``ku + kl + 2 kds`` near zero load until one lifts off.
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


def loadpath_static_deflection(p, force):
    """Deflection [m] at which the load path carries ``force`` [N] at rest (inverse of the law, either sign of
    the backlash: the spring law is piecewise linear and increasing, with kinks at ``-|b|`` and ``+|b|``)."""
    b = p["loadpath.backlash"]
    k_ds = 2.0 * p["loadpath.disk_spring_stiffness"]
    ku, kl = p["loadpath.contact_stiffness_upper"], p["loadpath.contact_stiffness_lower"]
    a = ca.fabs(b)

    def spring(d):
        return k_ds * d + ku * ca.fmax(d - b, 0.0) + kl * ca.fmin(d + b, 0.0)

    f_hi, f_lo = spring(a), spring(-a)
    k_mid = ca.if_else(b >= 0, k_ds, k_ds + ku + kl)  # free play: the disk springs; preload: all three
    return ca.if_else(
        force > f_hi, a + (force - f_hi) / (k_ds + ku),
        ca.if_else(force < f_lo, -a + (force - f_lo) / (k_ds + kl), -a + (force - f_lo) / ca.fmax(k_mid, 1e-300)),
    )


def drivetrain_stiffness(p):
    """Torsional stiffness of the drive train at the motor shaft [N m/rad] (``drivetrain_compliance``).

    Paper 000, Figure 6: the gearbox stiffness k_g in series with the screw's
    torsional stiffness (no inertia between them: the screw inertia sits at
    the nut end with the no-back), referred to the motor shaft by ``1/N^2``.
    ``p`` maps parameter names to values (numbers or casadi expressions).
    """
    p = values_of(p)
    k_eq = 1.0 / (1.0 / p["gear.torsional_stiffness"] + 1.0 / p["screw.torsional_stiffness"])
    return k_eq / p["gear.ratio"] ** 2


def drivetrain_modes(k, j_main, j_rotors, efficiency) -> tuple[float, float]:
    """The compliant drive train's two angular frequencies [rad/s] (``drivetrain_compliance``): the rotors against
    the gear-output side with the motor driving (the spring torque passes the gearbox at ``efficiency``),
    ``sqrt(k (1/J_rotors + eta/J_main))``, and the gear-output side's own mode with the rotor speed imposed (what a
    speed-controlled motor sees, and what the twist rate over the motor speed rings at: ``J s^2 / (J s^2 + c s +
    k)``), ``sqrt(eta k / J_main)``.  ``k`` at the motor shaft (:func:`drivetrain_stiffness`), inertias at the
    motor shaft (``Plant.inertia``)."""
    out = efficiency * k / j_main
    return math.sqrt(k / j_rotors + out), math.sqrt(out)


def drivetrain_damping_ratio(p, j_main, j_rotors) -> float:
    """Damping ratio of the compliant drive train's twist mode (``drivetrain_compliance``): the rotors against the
    gear-output side on the series stiffness (:func:`drivetrain_stiffness`) with the gearbox damping, both referred
    to the motor shaft, ``d / (2 sqrt(k J))`` with ``J = J_main J_rotors / (J_main + J_rotors)``; inertias at the
    motor shaft (``Plant.inertia``).  Above 1 the mode does not ring: the gear-output side follows the rotors as a
    first-order lag."""
    p = values_of(p)
    k = drivetrain_stiffness(p)
    d = p["gear.torsional_damping"] / p["gear.ratio"] ** 2
    j = j_main * j_rotors / (j_main + j_rotors)
    return d / (2.0 * math.sqrt(k * j))


def stiffness_of_output_mode(w, j_main, efficiency) -> float:
    """The stiffness at the motor shaft [N m/rad] whose gear-output mode (:func:`drivetrain_modes`, second) is at
    ``w`` [rad/s]: ``J_main w^2 / eta``."""
    return j_main * w**2 / efficiency


def limiter_slip_torques(p):
    """Static and kinetic slip torque of the limiter at the large gear [N m]: ``n mu F_pre R``."""
    p = values_of(p)
    base = p["limiter.faces"] * p["limiter.preload"] * p["limiter.mean_radius"]
    return base * p["limiter.mu_static"], base * p["limiter.mu_kinetic"]


def drive_coulomb_terms(p, speed):
    """``(static, kinetic)`` torque [N m, motor shaft] of ``coulomb_friction`` at ``speed`` [rad/s]."""
    tc = p["drive.coulomb_torque"]
    r_s = p["drive.static_torque_ratio"]
    kinetic = tc * (1.0 + r_s * ca.exp(-((speed / p["drive.stribeck_speed"]) ** 2)))
    return tc * (1.0 + r_s), kinetic


def screw_angle(p, nut_position):
    """Screw angle [rad] from the nut position [m] (``2 pi x / lead``)."""
    return 2.0 * math.pi * nut_position / p["screw.lead"]


def motor_angle(p, nut_position):
    """Mechanical motor angle [rad] from the nut position [m] (``x / r``, rigid drive)."""
    return nut_position / kinematic_ratio(p)


# ----------------------------------------------------------------------------- component laws


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
