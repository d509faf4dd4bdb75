"""The papers' effects: what the model levels add to the structure.

Each effect's ``apply`` is a function of an :class:`~thsa_control.model.structure.Assembly`
that adds terms (torques, friction channels, states with their derivatives,
losses, outputs), written once as casadi expressions from the laws of
``model/laws.py``; linearisation, simulation, optimisation and identification
all consume the same terms through ``plant.py``.  Each is registered at the
end of this module with everything else the workbench knows about it
(:class:`~thsa_control.model.effect.Effect`: outputs and their neutral values,
phase, tracer candidate spec, linearisation hints, neutral parameters).

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
    wheel turns with the screw and its disks do not slip.  Normal forces
    (``laws.noback_disk_normal_forces``): the flange between the two sets
    balances ``N_comp - N_tens = F`` at every load, the sets sharing the
    load change by their stiffness (``noback.load_share``; equal sets, the
    assumed 0.5: ``preload +- F/2``) until the light one unloads (at
    ``|F| = 2 preload`` for equal sets), beyond which the loaded one carries ``|F|`` alone
    (``F`` the force through the no-back: the load-path force at level D).  So when
    the load aids the motion the loaded disk slips (large friction) and when it
    opposes, the light disk slips (small friction, none above twice the preload); with the motors off
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

import casadi as ca

from ..effect import CandidateSpec, Effect, Guard, LinearHints, NoNeutral, NotCandidate, Output, Phase, register
from ..laws import (
    drivetrain_stiffness, kinematic_ratio, loadpath_force_law, loadpath_static_deflection, motor_lag,
    noback_disk_normal_forces, stribeck, temperature_drag_terms, torque_constant,
)
from ..structure import Assembly, FrictionChannel, StateInfo

__all__ = ["noback_preload"]


def _standby_motor(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    w = a.rotor_speed
    i = x["standby_current"]
    tau, target, v_applied, v_d, copper = motor_lag(p, i, u["voltage_standby"], u["enable_standby"], w)
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


def _loadpath_compliance(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    r = kinematic_ratio(p)
    v_nut = r * x["motor_speed"]
    d = x["nut_position"] - x["surface_position"]
    dd = v_nut - x["surface_speed"]
    force, spring = loadpath_force_law(p, d, dd)
    a.translating_mass = p["loadpath.mass"]  # the surface is now a body of its own
    a.axial_force = force
    # every axial force on the output passes through the load path's attachments: the measured load and an
    # unmeasured one (force_offset: a fixture's weight, a cable), so both deflect it
    outside = u["load_force"] + a.unmeasured_axial_force()
    a.rates["surface_position"] = x["surface_speed"]
    a.rates["surface_speed"] = (force - outside) / p["surface.mass"]
    a.loss("loadpath_damping", (force - spring) * dd)
    b = p["loadpath.backlash"]
    a.stored_energy["loadpath_springs"] = (
        p["loadpath.disk_spring_stiffness"] * d**2
        + 0.5 * p["loadpath.contact_stiffness_upper"] * ca.fmax(d - b, 0.0) ** 2
        + 0.5 * p["loadpath.contact_stiffness_lower"] * ca.fmin(d + b, 0.0) ** 2
    )
    a.stored_energy["kinetic_surface"] = 0.5 * p["surface.mass"] * x["surface_speed"] ** 2
    a.initial["surface_position"] = lambda x0, f0: x0["nut_position"] - loadpath_static_deflection(
        p, f0 + a.unmeasured_axial_force())
    # a segment of a fit starts with the surface at the static deflection of the load, moving with the nut: the
    # surface mode (about 60 Hz) is not a free state there (fit/shooting.py)
    a.quasi_static["surface_position"] = x["nut_position"] - loadpath_static_deflection(p, outside)
    a.quasi_static["surface_speed"] = v_nut
    a.output("surface_position", "m", x["surface_position"])
    a.output("surface_speed", "m/s", x["surface_speed"])
    a.output("loadpath_force", "N", force)
    a.output("loadpath_deflection", "m", d)


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


def _noback_quadrant_friction(a: Assembly) -> None:
    x, p = a.x, a.p
    w = x["motor_speed"]
    N = p["gear.ratio"]
    ws = w / N
    F = a.axial_force
    # the flange between the two disk sets: each takes its stiffness' share of the load change (0.5 +- F/2) until the
    # light set unloads (at |F| = 2 preload for equal sets)
    n_comp, n_tens = noback_disk_normal_forces(noback_preload(a), F, p["noback.load_share"])
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



def _loadpath_operating_point(c):
    rest = c.rest_state()
    return {}, {"loadpath_deflection": float(rest["nut_position"] - rest["surface_position"]),
                "surface_speed": c.nut_speed}


def _backlash_operating_point(c):
    # extension (w > 0) is locked by the tensile-side pawl, retraction by the compressive-side one; the
    # free one ratchets inside its pitch, the engaged one sits inside its set (or at its edge)
    pitch = c.values["noback.pawl_pitch"]
    engaged = 0.0 if c.pawl == "edge" else -0.5 * pitch
    comp, tens = (0.5 * pitch, engaged) if c.nut_speed >= 0 else (engaged, 0.5 * pitch)
    return {"pawl_clearance_comp": comp, "pawl_clearance_tens": tens}, {}


def _drivetrain_operating_point(c):
    return {}, {"rotor_speed": c.speed, "drivetrain_twist": c.torque_constant * c.current / drivetrain_stiffness(c.values)}


#: half the plausible range of ``noback.load_share`` around its assumed 0.5 (0.4..0.6: the housing and cover that react
#: the two disk sets differ; the parameter file's source); sim.assumptions spans it, the tracer's candidate needs a
#: standard error below it to call the share determined by a record
NOBACK_LOAD_SHARE_SPREAD = 0.1

_NOBACK = tuple(f"noback.{n}" for n in (
    "preload", "load_share", "ratchet_inertia", "mu_static_pos", "mu_coulomb_pos", "viscous_pos", "stribeck_speed_pos",
    "mu_static_neg", "mu_coulomb_neg", "viscous_neg", "stribeck_speed_neg",
))
_PAWLS = ("pawl_clearance_comp", "pawl_clearance_tens")

# Registration order is the order of the output signals (and, within a phase, of application).
register(Effect(
    "standby_motor", "second PMSM torque-summed at the gearbox input, rotor always dragged",
    (StateInfo("standby_current", "A", "lag", "q-axis current of the standby motor"),),
    ("motor.rotor_inertia", "motor.bearing_viscous_friction"), (), _standby_motor,
    phase=Phase.BODIES,
    neutral=NoNeutral("the standby rotor is always dragged: its inertia and bearing drag stay, whatever the "
                      "parameters"),
    outputs=(Output("standby_current", "A"), Output("standby_voltage", "V"), Output("standby_voltage_d", "V"),
             Output("standby_energised", "-")),
    candidate=NotCandidate("a configuration of the actuator (the standby motor is fitted or not), "
                           "not a missing physics of a healthy rig's residual"),
))
register(Effect(
    "drivetrain_compliance", "gearbox and screw torsional compliance between the motor rotors and the gear output",
    (
        StateInfo("rotor_speed", "rad/s", "velocity", "speed of the motor rotors (gearbox input), the motor sensor"),
        StateInfo("drivetrain_twist", "rad", "position", "rotor angle minus gear-output angle, at the motor shaft"),
    ),
    ("gear.torsional_stiffness", "screw.torsional_stiffness", "gear.torsional_damping"), (),
    _drivetrain_compliance,
    phase=Phase.BODIES,
    neutral=NoNeutral("the rotors are a body of their own: no parameter value makes the drive train rigid exactly"),
    outputs=(Output("drivetrain_twist", "rad"), Output("drivetrain_torque", "N m")),
    # only the series stiffness is identifiable: the gearbox's is freed, the screw's held.  The damping is freed in
    # a second fit once the first (damping at the file's 20 N m s/rad) determines the stiffness: freed from the
    # start it stands in for a lag on rigid data; held, a lightly damped mode (rig-sim's 2 N m s/rad, 47 Hz)
    # cannot ring and the screw-speed error grows (docs/trace_notes.md)
    # The stiffness starts at the mode the record rings at, where it shows one (``fit.resonance_screen``: a peak of
    # the twist rate over the motor speed): the cost has a minimum at each stiffness whose ringing matches the
    # record's in some phase, and from the file's (a mode near 87 Hz) the fit stopped at the wrong one on a rig-sim
    # speed excitation ringing at 47 Hz (gearbox 3.2e4 N m/rad where rig-sim's 8000 in series asks 1.0e4)
    candidate=CandidateSpec("drivetrain_compliance", ("gear.torsional_stiffness",), {}, "all", "screw_speed",
                            start="drivetrain_resonance", second_stage=("gear.torsional_damping",)),
    linear=LinearHints(
        # the spring torque k * twist enters the gear-output body with unit gain
        inertia_probe=("drivetrain_twist", drivetrain_stiffness),
        operating_point=_drivetrain_operating_point,
    ),
))
register(Effect(
    "loadpath_compliance", "load-path backlash and preload compliance; surface as a separate body",
    (
        StateInfo("surface_position", "m", "position", "surface position referred to the nut axis"),
        StateInfo("surface_speed", "m/s", "velocity", "surface speed referred to the nut axis"),
    ),
    tuple(f"loadpath.{n}" for n in (
        "contact_stiffness_lower", "contact_stiffness_upper", "disk_spring_stiffness", "backlash",
        "contact_damping", "disk_spring_damping")) + ("surface.mass",),
    (), _loadpath_compliance,
    phase=Phase.LOAD_PATH,
    neutral=NoNeutral("the surface is a body of its own: no parameter value makes the load path rigid exactly "
                      "(a stiff spring approaches it)"),
    outputs=(Output("surface_position", "m", lambda a: a.x["nut_position"]),
             Output("surface_speed", "m/s", lambda a: kinematic_ratio(a.p) * a.x["motor_speed"]),
             Output("loadpath_force", "N", lambda a: a.u["load_force"]), Output("loadpath_deflection", "m")),
    # the contact stiffnesses and the signed soft zone (free play, or a preload when negative): the LVDT reads the
    # surface, so a load change shows the deflection whether the drive moves or not (window "load_change")
    candidate=CandidateSpec("loadpath_compliance",
                            ("loadpath.contact_stiffness_upper", "loadpath.contact_stiffness_lower",
                             "loadpath.backlash"),
                            {}, "load_change", "nut_position", start="loadpath_static",
                            # a linear load path (the load never reaches a clearance or lifts a preloaded contact):
                            # the clearance only bounds the deflection, and a load of one sign does not split the
                            # contacts' stiffness; held at the static screen's values, the stiffness is read
                            singular_hold=("loadpath.backlash", "loadpath.contact_stiffness_lower")),
    linear=LinearHints(
        # a steady motion ramps both positions: the deflection nut - surface is its equilibrium state
        relative={"surface_position": ("loadpath_deflection", "nut_position")},
        guards=(Guard("loadpath_contact_edge", lambda x, p: ca.fabs(ca.fabs(x["loadpath_deflection"])
                                                                     - ca.fabs(p["loadpath.backlash"])),
                      "loadpath_edge_band"),),
        operating_point=_loadpath_operating_point,
    ),
))
register(Effect(
    "temperature_friction", "gearbox and nut-screw drag rising at low temperature and low speed",
    (),
    tuple(f"friction.{n}" for n in (
        "reference_temperature", "viscous_temperature_coefficient", "cold_coulomb_torque",
        "coulomb_temperature_coefficient", "cold_stribeck_ratio", "cold_stribeck_speed")),
    (), _temperature_friction,
    phase=Phase.DRIVE,
    neutral={"friction.cold_coulomb_torque": 0.0, "friction.viscous_temperature_coefficient": 0.0,
             "friction.preload_temperature_coefficient": 0.0},
    outputs=(Output("temperature_drag_torque", "N m"),
             Output("viscous_coefficient", "N m s/rad",
                    lambda a: a.p["motor.bearing_viscous_friction"] + a.p["gear.viscous_friction"])),
    candidate=CandidateSpec("temperature_friction",
                            ("friction.cold_coulomb_torque", "friction.viscous_temperature_coefficient"), {}, "cold",
                            reference=("gear.viscous_friction",)),
))
register(Effect(
    "noback_quadrant_friction", "no-back friction disks with load- and quadrant-dependent normal force",
    (), _NOBACK, (), _noback_quadrant_friction, supersedes=("noback_ideal",),
    phase=Phase.NOBACK,
    # the load share is no size of the effect: with the coefficients at zero any share leaves no torque
    neutral={n: 0.0 for n in _NOBACK if "stribeck_speed" not in n and n != "noback.load_share"},
    outputs=(Output("noback_torque", "N m"), Output("noback_normal_force_comp", "N"),
             Output("noback_normal_force_tens", "N"), Output("noback_disk_comp_slipping", "-"),
             Output("noback_disk_tens_slipping", "-"), Output("pawl_comp_engaged", "-"),
             Output("pawl_tens_engaged", "-"), Output("pawl_engaged", "-")),
    # the static coefficients (the Stribeck hump's height) are free with the Coulomb ones: Table 2's are one
    # specimen's, and a no-back without the hump (a plain Coulomb disk, sticking only at rest) left a hump of
    # (mu_s - mu_c) N at every start under an aiding load that the base corrections then stood in for
    # (docs/trace_notes.md, "Base drags"); what a run does not determine is held at the file's value
    # then the load share, from the coefficients the run determines: a record whose load crosses the band where both
    # disk sets carry load (|F| below about twice the preload) determines it from where and how the slipping set's
    # drag changes with the load; any other record leaves it at the file's assumed value, held and reported (its
    # spread, NOBACK_LOAD_SHARE_SPREAD, is what a determining record must narrow).  Freed with the coefficients it
    # traded with them where the band is thin (trace.scoring._second_stage).  The disk-spring preload is freed with
    # it: the same band shows it (the slipping set carries the preload plus its share of the load there, the load
    # alone beyond), nothing else does, so it is held at the file's 3 kN on every other record.  rig-sim's bases have
    # none (the papers' level-B Coulomb disk on the loaded brake); held at 3 kN on its load sweep the base step left a
    # mismatch "beyond the plausible set" on the null (docs/trace_notes.md, thirty-first session).  0 N is a value (a
    # no-back without preload springs), kept; moved far from the file's, the fit is started again with the
    # coefficients at the file's values, which the first stage had fitted around 3 kN
    candidate=CandidateSpec("noback_quadrant_friction", ("noback.mu_coulomb_pos", "noback.mu_coulomb_neg",
                                                         "noback.mu_static_pos", "noback.mu_static_neg"), {},
                            "loaded", second_stage=("noback.preload", "noback.load_share"),
                            second_stage_range_ends=("noback.preload",), second_stage_reseed=("noback.preload",),
                            resolution={"noback.load_share": NOBACK_LOAD_SHARE_SPREAD}),
    linear=LinearHints(kinks={"noback_normal_force": "the no-back's light disk set unloading (load-path force at "
                                                     "preload / (1 - load share), compressive, preload / load "
                                                     "share, tensile: twice the preload for equal sets)"}),
))
register(Effect(
    "noback_ideal", "ideal irreversible no-back (level A): Coulomb torque F r against load-aided motion",
    (), (), (), _noback_ideal,
    phase=Phase.NOBACK,
    neutral=NoNeutral("it has no parameter: the ideal no-back always holds the load (remove it for the "
                      "reversible model)"),
    outputs=(Output("noback_torque", "N m"),),
    candidate=NotCandidate("level A's ideal no-back; the detailed no-back (noback_quadrant_friction) is the "
                           "candidate that supersedes it"),
))
register(Effect(
    "noback_backlash", "ratchet/pawl clearance crossed before the pawl engages",
    (
        StateInfo("pawl_clearance_comp", "rad", "custom", "screw travel left before the compressive-side pawl locks retraction"),
        StateInfo("pawl_clearance_tens", "rad", "custom", "screw travel left before the tensile-side pawl locks extension"),
    ),
    ("noback.pawl_pitch", "noback.pawl_initial_clearance"), ("noback_quadrant_friction",), _noback_backlash,
    phase=Phase.PAWLS,
    neutral={"noback.pawl_pitch": 0.0},  # no clearance: the pawls are always engaged
    outputs=(Output("pawl_clearance_comp", "rad"), Output("pawl_clearance_tens", "rad")),
    # the pawl switch gives no gradient: the pitch (papers: 8.57 deg max; searched 1.7..17 deg) is profiled,
    # each value with segment clearances of its own; the initial clearance only where it matters.  It acts
    # within one pitch of screw travel after each change of direction (a reversal; a back-drive by the load at a
    # stop; the first motion): the "clearance" window
    candidate=CandidateSpec("noback_backlash", (), {}, "clearance",
                            profile={"noback.pawl_pitch": (0.03, 0.3), "noback.pawl_initial_clearance": (0.0, 1.0)},
                            # the first back-drive sees the initial clearance angle, fraction x pitch
                            profile_fractions={"noback.pawl_initial_clearance": "noback.pawl_pitch"}),
    linear=LinearHints(
        # in a steady motion the clearances ramp (+-w/N) and nothing depends on them away from an edge
        drifting=_PAWLS,
        guards=tuple(Guard(f"{s}_edge", lambda x, p, s=s: ca.fabs(x[s]), "pawl_edge_band") for s in _PAWLS),
        operating_point=_backlash_operating_point,
        # both pawls engaged: each direction meets its loaded disk, as at a reversal
        at_reversal=lambda v: {s: -0.5 * v["noback.pawl_pitch"] for s in _PAWLS},
    ),
))
