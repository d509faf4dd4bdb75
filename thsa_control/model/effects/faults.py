"""Fault effects of the effect library (the papers' model F).

Registered like every effect (:func:`thsa_control.model.effect.register`), in
the phases ``STRUCTURE_FAULTS`` (load path, surface, travel stops) and
``DRIVE_FAULTS`` (the limiter and the brakes, which read the drive-train
coupling and the rotor body), after every healthy effect.  None is a tracer
candidate by default: each acts through an event or a threshold.  The fault
*inputs* (``brake``, ``surface_jam``, ``loadpath_failure``) are plant inputs
whose healthy value is 0 (``structure.INPUTS``).

``torque_limiter``
    Paper 000: two skewed-roller friction disks pressed on the large gear by a
    preloaded disk spring; full transmission below the maximum static
    friction torque, slip with friction above it.  It sits in series with the
    drive-train spring of ``drivetrain_compliance`` (the split into an input
    shaft, motor rotors and motor sensor, and an output shaft, screw and
    RVDT), as a massless friction element::

        T_stick = k phi + d (w_r - w)          (torque if the disks stick)
        T_lim   = n (mu_k + (mu_s - mu_k) exp(-(w_slip/w_st)^2)) F_pre R / N
        |T_stick| <= T_lim: coupling = T_stick, d phi/dt = w_r - w
        else:               coupling = sgn(T_stick) T_lim,
                            d phi/dt = (coupling - k phi) / d  (the damper takes the rest)

    ``phi`` is the elastic twist (``drivetrain_twist``); the slip speed is
    ``w_r - w - dphi/dt`` and the slip loss ``coupling x slip speed >= 0``.
    In the discrete map the twist relaxes exactly (exponential over the step)
    while slipping, so a stiff spring or zero damping does not limit the step.
    The static/kinetic transition is a Stribeck law in the slip speed the
    disks had over the last ``limiter.memory_time`` (state
    ``limiter_slip_memory``, a first-order lag of the slip speed): static
    while they stick, however fast the spring winds up; continuous, so no
    stored energy jumps.  The limiter torque is
    referred to the motor shaft by the gear ratio alone (the gear losses act
    on the screw side of the coupling in this model).
``secondary_load_path``
    The actuator body (gearbox, motors, no-back, screw) hangs on the primary
    upper gimbal (stiff spring-damper ``k_a``, ``c_a``); the secondary path
    (tie rod and ACME nut) is in parallel behind an assembly clearance ``c_s``
    (dead zone, contact damping that cannot pull).  Input
    ``loadpath_failure`` breaks the primary attachment: its force fades with
    ``secondary.fracture_time`` (state ``primary_attachment_broken``, a lag)
    and the strain energy it held is counted as a fracture loss
    ``0.5 k_a s^2 dbroken/dt``.  The body moves (``actuator_axial_position``
    ``s``, the upper-gimbal LVDT) until the secondary path takes the load.
    The nut position stays the screw's (RVDT) coordinate; the surface state
    becomes relative to the actuator body and the ``surface_position`` /
    ``surface_speed`` outputs absolute.  Simplification: the nut's axial
    inertia coupling with the body acceleration is neglected.
``surface_jam``
    Input ``surface_jam`` locks the surface where it is: a stiff
    spring-damper to an anchor (state ``jam_anchor``) that follows the surface
    until the jam and then stays.  No stored energy jumps when it engages;
    the impact is dissipated in the jam's damper.
``claw_stops``
    Claws at the ends of the nut travel stop the screw's rotation: a stiff
    torsional contact beyond ``claw.travel_min/max`` with damping that cannot
    pull, on the screw side.
``motor_brakes``
    One brake per motor (two with ``standby_motor``), engaged by input
    ``brake``.  On a rigid drive train it is a friction channel of the main
    body (stiction resolved implicitly); with ``drivetrain_compliance`` it
    acts on the rotor body, with the same implicit stick/slip rule applied to
    that body's step.

This module imports casadi only.
"""

from __future__ import annotations

import casadi as ca

from ..effect import EFFECTS, Effect, NoNeutral, NotCandidate, Output, Phase, register
from ..laws import kinematic_ratio, limiter_slip_torques
from ..structure import Assembly, FrictionChannel, StateInfo

__all__ = ["FAULT_EFFECTS"]

#: Why a fault effect is not a candidate of a healthy rig's residual.
_FAULT = NotCandidate("a fault: it acts through an event or a threshold that gives a fit no gradient on data "
                      "where it does not fire")


def _evaluate(value, res):
    return value(res) if callable(value) else value


def _torque_limiter(a: Assembly) -> None:
    x, p = a.x, a.p
    N = p["gear.ratio"]
    wr, w = x["rotor_speed"], x["motor_speed"]
    phi = x["drivetrain_twist"]
    spring = a.coupling(wr, w)  # drivetrain_compliance's law, linear in twist and relative speed
    k = ca.jacobian(spring, phi)
    d = ca.jacobian(spring, wr)
    dw = wr - w
    t_s, t_k = limiter_slip_torques(p)
    w_st = p["limiter.stribeck_speed"] * N  # at the motor shaft
    # Stribeck law in the slip speed the disks had over the last memory time (state limiter_slip_memory):
    # static while they stick, whatever the elastic twist rate
    lim = (t_k + (t_s - t_k) * ca.exp(-((x["limiter_slip_memory"] / w_st) ** 2))) / N  # at the motor shaft
    slipping = ca.fabs(spring) > lim
    coupling = ca.if_else(slipping, ca.sign(spring) * lim, spring)
    twist_rate = ca.if_else(slipping, (coupling - k * phi) / ca.fmax(d, 1e-300), dw)
    slip = dw - twist_rate
    a.coupling = lambda _wr, _w: coupling
    a.lags["limiter_slip_memory"] = (p["limiter.memory_time"], ca.if_else(slipping, slip, 0.0))
    a.rates["drivetrain_twist"] = twist_rate

    target = coupling / k  # twist the spring relaxes to while the disks slip (time constant d/k)

    def relaxation(h):
        """Twist change over a slipping step of ``h`` (exact exponential)."""
        return (target - phi) * (1.0 - ca.exp(-h * k / ca.fmax(d, 1e-300)))

    def twist_update(new, h):
        stuck = phi + h * (new["rotor_speed"] - new["motor_speed"])
        return ca.if_else(slipping, phi + relaxation(h), stuck)

    def damping_loss(res):
        if res.step is None:  # continuous form: the damper moves with the elastic twist only
            return d * twist_rate**2
        # discrete: exactly what the relaxing spring-damper dissipates over the step
        dphi = relaxation(res.step)
        relaxed = coupling * dphi - 0.5 * k * ((phi + dphi) ** 2 - phi**2)
        return ca.if_else(slipping, relaxed / res.step, d * dw**2)

    def slip_loss(res):
        if res.step is None:
            return ca.if_else(slipping, coupling * slip, 0.0)
        return ca.if_else(slipping, coupling * (dw - relaxation(res.step) / res.step), 0.0)

    a.discrete["drivetrain_twist"] = twist_update
    a.losses["drivetrain_damping"] = damping_loss
    a.loss("limiter_slip", slip_loss)
    a.output("drivetrain_torque", "N m", coupling)
    a.output("limiter_torque", "N m", coupling * N)
    a.output("limiter_slip_torque", "N m", lim * N)
    a.output("limiter_slipping", "-", ca.if_else(slipping, 1.0, 0.0))
    a.output("limiter_slip_speed", "rad/s", ca.if_else(slipping, slip / N, 0.0))


def _secondary_load_path(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    s, vs, broken = x["actuator_axial_position"], x["actuator_axial_speed"], x["primary_attachment_broken"]
    k_a, c_a = p["secondary.attachment_stiffness"], p["secondary.attachment_damping"]
    tau_f = p["secondary.fracture_time"]
    a.lags["primary_attachment_broken"] = (tau_f, u["loadpath_failure"])
    intact = 1.0 - broken
    f_att = intact * (k_a * s + c_a * vs)  # force of the attachment on the body, towards -s
    gap, k_s, c_s = p["secondary.clearance"], p["secondary.stiffness"], p["secondary.contact_damping"]
    upper = ca.if_else(s > gap, ca.fmax(k_s * (s - gap) + c_s * vs, 0.0), 0.0)
    lower = ca.if_else(s < -gap, ca.fmin(k_s * (s + gap) + c_s * vs, 0.0), 0.0)
    f_sec = upper + lower
    sec_spring = k_s * (ca.fmax(s - gap, 0.0) + ca.fmin(s + gap, 0.0))
    f_lp = a.axial_force  # the load path pushes the nut, and through the thread the body, towards -x
    accel = (-f_lp - f_att - f_sec) / p["secondary.axial_mass"]
    a.rates["actuator_axial_position"] = vs
    a.rates["actuator_axial_speed"] = accel
    # the surface state is now measured from the moving body: subtract the body's acceleration
    a.rates["surface_speed"] = a.rates["surface_speed"] - accel
    m_s = p["surface.mass"]
    v_abs = x["surface_speed"] + vs
    a.stored_energy["kinetic_surface"] = 0.5 * m_s * v_abs**2
    a.stored_energy["kinetic_actuator_body"] = 0.5 * p["secondary.axial_mass"] * vs**2
    a.stored_energy["primary_attachment"] = 0.5 * intact * k_a * s**2
    a.stored_energy["secondary_path"] = 0.5 * k_s * (ca.fmax(s - gap, 0.0) ** 2 + ca.fmin(s + gap, 0.0) ** 2)
    a.loss("primary_attachment_damping", intact * c_a * vs**2)
    a.loss("primary_attachment_fracture", 0.5 * k_a * s**2 * (u["loadpath_failure"] - broken) / tau_f)
    a.loss("secondary_path_damping", (f_sec - sec_spring) * vs)
    a.initial["actuator_axial_position"] = lambda x0, f0: -f0 / k_a
    a.output("surface_position", "m", x["surface_position"] + s)
    a.output("surface_speed", "m/s", v_abs)
    a.output("gimbal_displacement", "m", s)
    # forces the two attachments carry, compressive positive like the load path (the body pushed towards -s)
    a.output("primary_attachment_force", "N", -f_att)
    a.output("secondary_path_force", "N", -f_sec)
    a.output("primary_attachment_broken", "-", broken)


def _surface_jam(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    pos, vel = a.outputs["surface_position"][1], a.outputs["surface_speed"][1]  # absolute (see secondary_load_path)
    anchor = x["jam_anchor"]
    jammed = u["surface_jam"] > 0.5
    stretch = pos - anchor
    f_jam = ca.if_else(jammed, p["jam.stiffness"] * stretch + p["jam.damping"] * vel, 0.0)
    a.rates["surface_speed"] = a.rates["surface_speed"] - f_jam / p["surface.mass"]
    a.rates["jam_anchor"] = ca.if_else(jammed, 0.0, vel)
    vel_names = [s.name for s in a.states if s.kind in ("speed", "velocity")]

    def anchor_update(new, h):
        old = ca.vertcat(*(x[n] for n in vel_names))
        vel_new = ca.substitute(vel, old, ca.vertcat(*(new[n] for n in vel_names)))
        return ca.if_else(jammed, anchor, pos + h * vel_new)  # follows the surface until the jam

    a.discrete["jam_anchor"] = anchor_update
    a.initial["jam_anchor"] = lambda x0, f0: ca.substitute(pos, ca.vertcat(*(x[s.name] for s in a.states)),
                                                           ca.vertcat(*(x0[s.name] for s in a.states)))
    a.stored_energy["jam_spring"] = ca.if_else(jammed, 0.5 * p["jam.stiffness"] * stretch**2, 0.0)
    a.loss("jam_damping", ca.if_else(jammed, p["jam.damping"] * vel**2, 0.0))
    a.output("jam_force", "N", f_jam)
    a.output("surface_jammed", "-", ca.if_else(jammed, 1.0, 0.0))


def _claw_stops(a: Assembly) -> None:
    x, p = a.x, a.p
    N = p["gear.ratio"]
    r = kinematic_ratio(p)
    w = x["motor_speed"]
    k, c = p["claw.stiffness"] / N**2, p["claw.damping"] / N**2  # at the motor shaft
    over = (x["nut_position"] - p["claw.travel_max"]) / r  # motor-shaft rad beyond the end
    under = (x["nut_position"] - p["claw.travel_min"]) / r
    t_hi = ca.if_else(over > 0, ca.fmax(k * over + c * w, 0.0), 0.0)
    t_lo = ca.if_else(under < 0, ca.fmin(k * under + c * w, 0.0), 0.0)
    spring = k * (ca.fmax(over, 0.0) + ca.fmin(under, 0.0))
    a.torques.append(("claw_stops", -(t_hi + t_lo)))
    a.stored_energy["claw_stops"] = 0.5 * k * (ca.fmax(over, 0.0) ** 2 + ca.fmin(under, 0.0) ** 2)
    a.loss("claw_damping", (t_hi + t_lo - spring) * w)
    a.output("claw_torque", "N m", -(t_hi + t_lo) * N)


def _motor_brakes(a: Assembly) -> None:
    x, u, p = a.x, a.u, a.p
    n = 2.0 if a.has("standby_motor") else 1.0
    on = ca.if_else(u["brake"] > 0.5, 1.0, 0.0)
    hold = n * p["brake.holding_torque"] * on
    slide = p["brake.kinetic_ratio"] * hold
    a.output("brakes_engaged", "-", on)
    if "rotor_speed" not in a.x:  # rigid drive train: a friction channel of the main body
        a.channels.append(FrictionChannel("brakes", hold, hold, slide, slide))
        a.loss("brakes", lambda res: res.channel["brakes"] * res.speed)
        a.output("brake_torque", "N m", lambda res: res.channel["brakes"])
        return
    # compliant drive train: the brakes hold the rotor body (implicit stick/slip of its step)
    wr = x["rotor_speed"]
    smooth = -slide * ca.sign(wr)
    a.rotor_torques.append(("brakes", smooth))  # the continuous form (and the explicit step) see the sliding torque
    a.loss("brakes", slide * ca.fabs(wr))

    def rotor_update(new, h):
        j = sum(a.rotor_inertia)
        free = new["rotor_speed"] - h * smooth / j  # the explicit step without the brake
        t_stick = j * free / h
        return ca.if_else(ca.fabs(t_stick) <= hold, 0.0, free - h * ca.sign(free) * slide / j)

    a.discrete["rotor_speed"] = rotor_update
    a.output("brake_torque", "N m", smooth)


def _limiter_torque_neutral(a: Assembly):
    # without the limiter the large gear carries the gearbox input torque times the ratio
    return lambda res: a.p["gear.ratio"] * _evaluate(a.outputs["gearbox_input_torque"][1], res)


register(Effect(
    "torque_limiter", "friction torque limiter on the large gear: the drive train slips above its static torque",
    (StateInfo("limiter_slip_memory", "rad/s", "lag",
               "slip speed of the limiter disks over the last memory time, at the motor shaft"),),
    tuple(f"limiter.{n}" for n in ("faces", "preload", "mu_static", "mu_kinetic", "mean_radius",
                                   "stribeck_speed", "memory_time")),
    ("drivetrain_compliance",), _torque_limiter,
    phase=Phase.DRIVE_FAULTS,
    neutral={"limiter.preload": 1e12},  # a limiter that never slips
    outputs=(Output("limiter_torque", "N m", _limiter_torque_neutral), Output("limiter_slip_torque", "N m"),
             Output("limiter_slipping", "-"), Output("limiter_slip_speed", "rad/s")),
    candidate=_FAULT,
))
register(Effect(
    "secondary_load_path", "actuator body on the primary upper gimbal; tie rod and ACME nut behind a clearance",
    (
        StateInfo("actuator_axial_position", "m", "position", "actuator body axial displacement at the upper gimbal (LVDT)"),
        StateInfo("actuator_axial_speed", "m/s", "velocity", "actuator body axial speed"),
        StateInfo("primary_attachment_broken", "-", "lag", "0 intact .. 1 broken primary upper attachment"),
    ),
    tuple(f"secondary.{n}" for n in ("axial_mass", "attachment_stiffness", "attachment_damping",
                                     "fracture_time", "clearance", "stiffness", "contact_damping")),
    ("loadpath_compliance",), _secondary_load_path,
    phase=Phase.STRUCTURE_FAULTS,
    neutral=NoNeutral("the actuator body is a body of its own on its attachments: no parameter value removes it "
                      "exactly"),
    outputs=(Output("gimbal_displacement", "m"),
             Output("primary_attachment_force", "N",
                    lambda a: (lambda res: _evaluate(a.outputs["loadpath_force"][1], res))),
             Output("secondary_path_force", "N"), Output("primary_attachment_broken", "-")),
    candidate=_FAULT,
))
register(Effect(
    "surface_jam", "the surface locks where it is when input surface_jam is 1",
    (StateInfo("jam_anchor", "m", "custom", "where the surface jams (follows it until the jam)"),),
    ("jam.stiffness", "jam.damping", "surface.mass"), ("loadpath_compliance",), _surface_jam,
    phase=Phase.STRUCTURE_FAULTS,  # after secondary_load_path: reads the absolute surface outputs
    neutral={},  # with its input healthy (surface_jam = 0)
    outputs=(Output("jam_force", "N"), Output("surface_jammed", "-")),
    candidate=_FAULT,
))
register(Effect(
    "claw_stops", "claw stops at the ends of the nut travel (screw rotation stopped)",
    (), ("claw.travel_min", "claw.travel_max", "claw.stiffness", "claw.damping"), (), _claw_stops,
    phase=Phase.STRUCTURE_FAULTS,
    neutral={"claw.travel_min": -1e3, "claw.travel_max": 1e3},  # stops beyond any travel
    outputs=(Output("claw_torque", "N m"),),
    candidate=_FAULT,
))
register(Effect(
    "motor_brakes", "one brake per motor, engaged by input brake",
    (), ("brake.holding_torque", "brake.kinetic_ratio"), (), _motor_brakes,
    phase=Phase.DRIVE_FAULTS,
    neutral={},  # with its input healthy (brake = 0)
    outputs=(Output("brake_torque", "N m"), Output("brakes_engaged", "-")),
    candidate=_FAULT,
))

#: Names of the effects this module registers.
FAULT_EFFECTS: tuple[str, ...] = tuple(n for n, e in EFFECTS.items() if e.apply.__module__ == __name__)
