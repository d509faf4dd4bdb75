"""Generic drive effects: what a rig engineer suspects on any screw drive.

The same :class:`~thsa_control.model.effects.Effect` / :class:`~thsa_control.model.structure.Assembly`
API as :mod:`thsa_control.model.effects`; they are registered into ``EFFECTS``
and ``EFFECT_ORDER`` there, so that simulation, linearisation and
identification consume them like the papers' effects.  Every parameter is in
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
    A constant axial force on the nut [N, compressive positive]: gravity on an
    inclined axis, a cable or a spring balancer.  It adds to the axial force
    (so it passes through the screw and gear efficiencies, and loads the
    no-back disks like the load does).
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
    ``drivetrain_compliance`` the twist is neglected in the angle).

The friction terms act on the gear-output body (the screw side), so the
structure's gearbox efficiency applies to them like to the load: the motor
supplies ``T / eta_g`` while it drives them.

All act on the main body (motor shaft); none adds a state.
"""

from __future__ import annotations

import math

import casadi as ca

from .effects import Effect
from .structure import Assembly, FrictionChannel, kinematic_ratio

__all__ = ["DRIVE_EFFECTS", "DRIVE_EFFECT_ORDER", "drive_coulomb_terms", "screw_angle", "motor_angle"]


def drive_coulomb_terms(p: dict, speed):
    """``(static, kinetic)`` torque [N m, motor shaft] of ``coulomb_friction`` at ``speed`` [rad/s]."""
    tc = p["drive.coulomb_torque"]
    r_s = p["drive.static_torque_ratio"]
    kinetic = tc * (1.0 + r_s * ca.exp(-((speed / p["drive.stribeck_speed"]) ** 2)))
    return tc * (1.0 + r_s), kinetic


def screw_angle(p: dict, nut_position):
    """Screw angle [rad] from the nut position [m] (``2 pi x / lead``)."""
    return 2.0 * math.pi * nut_position / p["screw.lead"]


def motor_angle(p: dict, nut_position):
    """Mechanical motor angle [rad] from the nut position [m] (``x / r``, rigid drive)."""
    return nut_position / kinematic_ratio(p)


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
    # a torque on the rotors (the motor side of the gearbox), like the motor's own
    a.rotor_torques.append(("cogging", p["drive.cogging_torque_cos"] * ca.cos(th)
                            + p["drive.cogging_torque_sin"] * ca.sin(th)))


DRIVE_EFFECTS: dict[str, Effect] = {
    e.name: e
    for e in (
        Effect("coulomb_friction", "plain Coulomb and static friction of the drive, at the motor shaft", (),
               ("drive.coulomb_torque", "drive.static_torque_ratio", "drive.stribeck_speed"), (), _coulomb_friction),
        Effect("direction_friction", "Coulomb friction acting in one direction of motion only", (),
               ("drive.direction_coulomb_torque",), (), _direction_friction),
        Effect("force_offset", "constant axial force on the nut (gravity on an inclined axis, a cable)", (),
               ("drive.axial_force_offset",), (), _force_offset),
        Effect("screw_friction_ripple", "friction varying once per screw revolution (run-out, a bent screw)", (),
               ("drive.screw_ripple_torque_cos", "drive.screw_ripple_torque_sin", "screw.lead"), (),
               _screw_friction_ripple),
        Effect("cogging_torque", "motor cogging torque, periodic in the mechanical motor angle", (),
               ("drive.cogging_torque_cos", "drive.cogging_torque_sin", "drive.cogging_periods"), (),
               _cogging_torque),
    )
}

#: Application order: ``force_offset`` changes the axial force, so it comes
#: before the effects that read it (the no-back); it is inserted before
#: ``noback_backlash`` in ``EFFECT_ORDER``.
DRIVE_EFFECT_ORDER: tuple[str, ...] = tuple(DRIVE_EFFECTS)
