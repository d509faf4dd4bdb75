"""Generic drive effects: what a rig engineer suspects on any screw drive.

Registered like every effect (:func:`thsa_control.model.effect.register`), in
phase ``DRIVE`` (after the bodies, before the no-back, which reads the axial
force that ``force_offset`` changes), so that simulation, linearisation,
identification and the tracer consume them like the papers' effects.  Every parameter is in
``default_actuator.toml`` (group ``drive``) with a neutral default: at value
0 the effect adds exactly nothing.

``coulomb_friction``
    Plain Coulomb and static friction of the drive (bearings, seals, screw),
    referred to the motor shaft, as a friction channel::

        T = Tc (1 + r_s exp(-(w/w_s)^2)) sgn(w),   |T| <= Tc (1 + r_s) at rest

``direction_friction``
    Coulomb friction that acts in one direction of motion only (a seal or a
    wiper that drags one way, a preloaded bearing set): ``Td = drive.
    direction_coulomb_torque`` acts against positive motion when ``Td > 0``
    and against negative motion when ``Td < 0``.  With ``coulomb_friction`` it
    gives any pair of direction-dependent Coulomb torques.
``force_offset``
    A constant axial force on the output that the load cell does not see [N,
    compressive positive]: gravity on an inclined axis, a fixture, a cable or
    a spring balancer.  It adds to the axial force (so it passes through the
    screw and gear efficiencies, and loads the no-back disks like the load
    does); with ``loadpath_compliance`` it acts on the surface beside the
    measured load, so the load path's attachments carry and deflect under it
    too (``Assembly.unmeasured_axial_force``), and it takes the power ``F v``
    with the load (``load_power``).
``screw_friction_ripple``
    Friction that varies with the screw angle, once per screw revolution
    (screw run-out, a bent shaft, a ball-return bump)::

        T_r = R + a cos(theta_s) + b sin(theta_s),   R = sqrt(a^2 + b^2)

    with ``theta_s = 2 pi x_nut / lead`` the screw angle from the nut
    position (its origin is the run's start; the phase is in ``a, b``).  It is
    >= 0, so it is friction (it opposes the motion), zero at its minimum.
``cogging_torque``
    The motor's cogging (detent) torque, conservative and periodic in the
    mechanical motor angle ``theta_m = x_nut / r``::

        T_cog = a cos(n theta_m) + b sin(n theta_m)

    with ``n = drive.cogging_periods`` periods per motor revolution (the least
    common multiple of slots and poles for a real motor).  It acts on the
    rotors (motor side of the gearbox); the angle is the rigid one (with
    ``drivetrain_compliance`` the twist is neglected in the angle).  The
    discrete form averages it over each step along the angle the step sweeps
    (:func:`~thsa_control.model.structure.step_mean_of_harmonic`): the step's
    torque impulse, where one value per step would sample a harmonic far
    faster than the step at arbitrary phases.

The friction terms act on the gear-output body (the screw side), so the
structure's gearbox efficiency applies to them like to the load: the motor
supplies ``T / eta_g`` while it drives them.

All act on the main body (motor shaft); none adds a state.
"""

from __future__ import annotations

import casadi as ca

from ..effect import EFFECTS, CandidateSpec, Effect, Phase, register
from ..laws import drive_coulomb_terms, motor_angle, screw_angle
from ..structure import Assembly, FrictionChannel, step_mean_of_harmonic

__all__ = ["DRIVE_EFFECTS"]


def _coulomb_friction(a: Assembly) -> None:
    static, kinetic = drive_coulomb_terms(a.p, a.x["motor_speed"])
    a.channels.append(FrictionChannel("drive_coulomb", static, static, kinetic, kinetic))
    a.loss("drive_coulomb", lambda res: res.channel["drive_coulomb"] * res.speed)


def _direction_friction(a: Assembly) -> None:
    td = a.p["drive.direction_coulomb_torque"]
    pos, neg = ca.fmax(td, 0.0), ca.fmax(-td, 0.0)
    a.channels.append(FrictionChannel("drive_direction", pos, neg, pos, neg))
    a.loss("drive_direction", lambda res: res.channel["drive_direction"] * res.speed)


def _force_offset(a: Assembly) -> None:
    # with a compliant load path the offset acts on the surface, beside the measured load
    # (papers._loadpath_compliance), so the attachments' force the screw carries holds it
    if not a.has("loadpath_compliance"):
        a.axial_force = a.axial_force + a.p["drive.axial_force_offset"]


def _screw_friction_ripple(a: Assembly) -> None:
    p = a.p
    th = screw_angle(p, a.x["nut_position"])
    ca_, sb = p["drive.screw_ripple_torque_cos"], p["drive.screw_ripple_torque_sin"]
    mean = ca.sqrt(ca_**2 + sb**2)
    t = ca.fmax(mean + ca_ * ca.cos(th) + sb * ca.sin(th), 0.0)
    a.channels.append(FrictionChannel("screw_ripple", t, t, t, t))
    a.loss("screw_ripple", lambda res: res.channel["screw_ripple"] * res.speed)


def _cogging_torque(a: Assembly) -> None:
    p = a.p
    n = p["drive.cogging_periods"]
    th = n * motor_angle(p, a.x["nut_position"])
    # in the discrete form averaged over the step (the angle its speed sweeps: at speed the harmonic is far above the
    # step rate, and the rig's torque averages out over a step where one value per step would kick the speed)
    c, s = step_mean_of_harmonic(th, n * a.x["motor_speed"], a.step)
    # a torque on the rotors (the motor side of the gearbox), like the motor's own
    a.rotor_torques.append(("cogging", p["drive.cogging_torque_cos"] * c + p["drive.cogging_torque_sin"] * s))


register(Effect("coulomb_friction", "plain Coulomb and static friction of the drive, at the motor shaft", (),
                ("drive.coulomb_torque", "drive.static_torque_ratio", "drive.stribeck_speed"), (), _coulomb_friction,
                phase=Phase.DRIVE,
                neutral={"drive.coulomb_torque": 0.0},
                candidate=CandidateSpec("coulomb_friction", ("drive.coulomb_torque",), {"drive.coulomb_torque": 0.02},
                                        base_correction=True, plausible={"drive.coulomb_torque": "drag"})))
register(Effect("direction_friction", "Coulomb friction acting in one direction of motion only", (),
                ("drive.direction_coulomb_torque",), (), _direction_friction,
                phase=Phase.DRIVE,
                neutral={"drive.direction_coulomb_torque": 0.0},
                candidate=CandidateSpec("direction_friction", ("drive.direction_coulomb_torque",),
                                        {"drive.direction_coulomb_torque": 0.01}, base_correction=True,
                                        plausible={"drive.direction_coulomb_torque": "drag"})))
register(Effect("force_offset", "constant axial force on the output that the load cell does not see (gravity on an "
                "inclined axis, a fixture, a cable); with a compliant load path it loads the attachments too", (),
                ("drive.axial_force_offset",), (), _force_offset,
                phase=Phase.DRIVE,  # before the no-back, which reads the axial force
                neutral={"drive.axial_force_offset": 0.0},
                candidate=CandidateSpec("force_offset", ("drive.axial_force_offset",),
                                        {"drive.axial_force_offset": 200.0}, "all", base_correction=True,
                                        plausible={"drive.axial_force_offset": "axial_force"})))
register(Effect("screw_friction_ripple", "friction varying once per screw revolution (run-out, a bent screw)", (),
                ("drive.screw_ripple_torque_cos", "drive.screw_ripple_torque_sin", "screw.lead"), (),
                _screw_friction_ripple,
                phase=Phase.DRIVE,
                neutral={"drive.screw_ripple_torque_cos": 0.0, "drive.screw_ripple_torque_sin": 0.0},
                candidate=CandidateSpec("screw_friction_ripple",
                                        ("drive.screw_ripple_torque_cos", "drive.screw_ripple_torque_sin"),
                                        {"drive.screw_ripple_torque_cos": 0.005, "drive.screw_ripple_torque_sin": 0.005},
                                        plausible={"drive.screw_ripple_torque_cos": "periodic",
                                                   "drive.screw_ripple_torque_sin": "periodic"})))
register(Effect("cogging_torque", "motor cogging torque, periodic in the mechanical motor angle", (),
                ("drive.cogging_torque_cos", "drive.cogging_torque_sin", "drive.cogging_periods"), (),
                _cogging_torque,
                phase=Phase.DRIVE,
                neutral={"drive.cogging_torque_cos": 0.0, "drive.cogging_torque_sin": 0.0},
                # the cogging acts where the record resolves its period (4 samples or more): an aliased one fits
                # noise (a 0.07 N m cogging was invented on a 15 mm/s trim run logged at 500 Hz).  The period
                # count is the motor's (slots and poles), not the parameter file's placeholder: it is profiled
                # over the multiples of the pole count whose harmonic the record resolves (trace.candidates.PROFILE_GRIDS)
                candidate=CandidateSpec("cogging_torque", ("drive.cogging_torque_cos", "drive.cogging_torque_sin"),
                                        {"drive.cogging_torque_cos": 0.005, "drive.cogging_torque_sin": 0.005},
                                        "resolved_cogging",
                                        profile={"drive.cogging_periods": (2.0, 200.0)},
                                        plausible={"drive.cogging_torque_cos": "periodic",
                                                   "drive.cogging_torque_sin": "periodic"})))

#: Names of the effects this module registers.
DRIVE_EFFECTS: tuple[str, ...] = tuple(n for n, e in EFFECTS.items() if e.apply.__module__ == __name__)
