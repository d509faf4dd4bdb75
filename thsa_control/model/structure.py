"""Functional structure of the THSA: states, inputs, balances and sign conventions.

The structure owns the balances; effects (``effects/``) only add terms to
them, and declare the neutral values of their outputs, which the structure
writes for every effect set (``Effect.outputs``).  Everything is written once as casadi ``SX`` expressions and used twice,
by two numerical forms assembled in ``plant.py``:

* the continuous right-hand side ``f(x, u, p) -> (xdot, y)`` (linearisation,
  python-control), where set-valued friction is resolved by the sign of the
  speed (valid away from zero speed);
* the fixed-step discrete map used by the simulator, where the same friction
  limits are resolved implicitly (stick or slip decided per step, so that
  stiction holds exactly and does not chatter at any step size).

Sign conventions (``shared/rig-data/FORMAT.md``): nut position and speed,
motor and screw speed and motor current are positive when the actuator
extends; the load force on the nut is positive when compressive (it pushes the
nut back, opposing extension).  All rotational quantities of the main body are
referred to the motor shaft: ``motor_speed`` [rad/s]; the screw turns at
``motor_speed / N`` and the nut moves at ``r * motor_speed`` with
``r = lead / (2 pi N)``.

Main mechanical balance (motor shaft)::

    J dw/dt = sum_k Kt i_k  - b w  - F_ax r c0  + (effect torques)  - T_f
    T_f in friction set:  w > 0: sum K+_c(w);  w < 0: -sum K-_c(w);
                          w = 0: [-sum S-_c, +sum S+_c]

``F_ax r c0`` and the load-dependent channel ``|F_ax| r c1`` are the
power-flow-dependent efficiency written as a mean load torque plus a Coulomb
friction: with ``c0 = (1/eta_d + eta_i)/2`` and ``c1 = (1/eta_d - eta_i)/2``
the motor sees ``F r / eta_d`` when it drives the load and ``F r eta_i`` when
the load drives it.

This module imports casadi only (no numpy I/O, no matplotlib).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import casadi as ca

from .effect import EFFECTS
from .laws import kinematic_ratio, limiter_slip_torques, motor_lag, torque_constant

__all__ = [
    "INPUTS",
    "StateInfo",
    "FrictionChannel",
    "FrictionResolution",
    "Assembly",
    "apply_structure",
    "STRUCTURE_STATES",
]


@dataclass(frozen=True)
class StateInfo:
    """A state of the plant.

    ``kind`` says how the discrete map integrates it: ``"lag"`` (first-order
    linear, integrated exactly), ``"speed"`` (the main body's speed, with
    implicit friction), ``"velocity"`` (another body's velocity, explicit),
    ``"position"`` (integrated with the updated velocities, symplectic Euler),
    ``"custom"`` (an effect gives its own discrete update).
    """

    name: str
    unit: str
    kind: str
    description: str


#: Plant inputs, the same for every effect set (unused ones are ignored).
INPUTS: tuple[tuple[str, str, str], ...] = (
    ("voltage_primary", "V", "q-axis voltage command of the primary motor (clamped to V_dc/sqrt(3))"),
    ("voltage_standby", "V", "q-axis voltage command of the standby motor (needs standby_motor)"),
    ("enable_primary", "-", "1: primary inverter energised, 0: off (current decays)"),
    ("enable_standby", "-", "1: standby inverter energised (needs standby_motor)"),
    ("load_force", "N", "axial load on the surface/nut, positive compressive (opposes extension)"),
    ("temperature", "degC", "actuator temperature (needs temperature_friction)"),
    # fault inputs (model/effects/faults.py); 0 is the healthy value, so runs that ignore them are unchanged
    ("brake", "-", "1: motor brakes engaged (needs motor_brakes)"),
    ("surface_jam", "-", "1: surface locked where it is (needs surface_jam)"),
    ("loadpath_failure", "-", "1: primary load path broken at the upper gimbal (needs secondary_load_path)"),
)

STRUCTURE_STATES: tuple[StateInfo, ...] = (
    StateInfo("motor_current", "A", "lag", "q-axis current of the primary motor"),
    StateInfo("motor_speed", "rad/s", "speed", "speed of the motor shaft (rotors, gearbox, screw, nut)"),
    StateInfo("nut_position", "m", "position", "nut position, positive extending"),
)


@dataclass(frozen=True)
class FrictionChannel:
    """Set-valued friction acting on the main body, referred to the motor shaft.

    ``static_pos`` / ``static_neg`` (>= 0) bound the torque the channel can
    hold against positive / negative motion at standstill;
    ``kinetic_pos`` / ``kinetic_neg`` (>= 0, <= static) is its torque while the
    body slides in that direction (may depend on speed).  The effect that adds
    it also names it so that its torque is a signal.
    """

    name: str
    static_pos: ca.SX
    static_neg: ca.SX
    kinetic_pos: ca.SX
    kinetic_neg: ca.SX


@dataclass(frozen=True)
class FrictionResolution:
    """Friction torques as resolved by one of the numerical forms.

    ``channel`` maps channel name to its torque [N m at the motor shaft,
    positive opposing positive motion]; ``total`` is their sum; ``stuck`` is 1
    while the main body is held by stiction (discrete form only); ``speed`` is
    the motor speed the friction acts at [rad/s] (the end-of-step speed in the
    discrete form); ``step`` is the step size of the discrete form (None in the
    continuous one), for losses an effect integrates exactly over a step.
    """

    channel: dict
    total: ca.SX
    stuck: ca.SX
    speed: ca.SX
    step: ca.SX | None = None  # the discrete step size h [s]; None in the continuous form


@dataclass
class Assembly:
    """Mutable collector used while one effect set is assembled.

    Effects receive it, read symbols (``x``, ``u``, ``p``) and add terms.  It
    never leaves ``model/``: ``plant.py`` turns it into casadi Functions.
    """

    states: tuple[StateInfo, ...]
    x: dict
    u: dict
    p: dict
    effects: tuple[str, ...]
    inertia: list = field(default_factory=list)  # [N m s^2/rad] of the main body, at the motor shaft
    torques: list = field(default_factory=list)  # (label, expr) smooth torques on the main body, at the motor shaft
    rotor_inertia: list = field(default_factory=list)  # motor rotors (the gearbox input)
    rotor_torques: list = field(default_factory=list)  # (label, expr) motor and bearing torques on the rotors
    coupling: object = None  # fn(rotor_speed, main_speed) -> torque from rotors to main body; None: rigid
    channels: list = field(default_factory=list)  # FrictionChannel
    lags: dict = field(default_factory=dict)  # state -> (tau, target)
    rates: dict = field(default_factory=dict)  # state -> continuous derivative
    discrete: dict = field(default_factory=dict)  # state -> fn(x_new: dict, h) -> expr (custom; may override velocity/position)
    outputs: dict = field(default_factory=dict)  # name -> (unit, expr | fn(FrictionResolution) -> expr)
    losses: dict = field(default_factory=dict)  # label -> expr | fn(FrictionResolution) -> expr [W]
    stored_energy: dict = field(default_factory=dict)  # label -> expr [J]
    axial_force: ca.SX | None = None  # [N], compressive positive, on the nut
    translating_mass: ca.SX | None = None  # [kg] moving rigidly with the nut
    pawl_engaged: dict = field(default_factory=dict)  # "comp"/"tens" -> expr (1 engaged)
    initial: dict = field(default_factory=dict)  # state -> fn(load_force) -> expr (static equilibrium)
    # state -> expr in x, u, p: a fast internal mode's state at a shooting segment's start, tied to the slow
    # states (the surface at the static load-path deflection of the load, moving with the nut); a fit does not
    # free it (a free start rings the mode to absorb another channel's mismatch)
    quasi_static: dict = field(default_factory=dict)
    # facts the plant exports (set by the structure): the screw-to-nut ratio [m/rad], the torque
    # constant [N m/A], the main body's inertia at the motor shaft and the rotors' [kg m^2]
    kinematic_ratio: object = None
    torque_constant: object = None
    main_inertia: object = None
    rotor_body_inertia: object = None
    #: the step size of the discrete form [s] as a symbol: ``plant.py`` puts 0 in its place in the continuous form
    #: and the step ``h`` in the discrete one, for a torque an effect averages over a step (a cogging whose angle
    #: sweeps several of its periods in one step: :func:`step_mean_of_harmonic`)
    step: object = None

    @property
    def rotor_speed(self):
        """Speed of the motor rotors [rad/s]: the main body's unless the drive train is compliant."""
        return self.x["rotor_speed"] if "rotor_speed" in self.x else self.x["motor_speed"]

    def output(self, name: str, unit: str, expr) -> None:
        """Define (or redefine) an output signal."""
        self.outputs[name] = (unit, expr)

    def loss(self, label: str, expr) -> None:
        """Add a dissipated power [W] (must be >= 0 for every state)."""
        self.losses[label] = expr

    def has(self, effect: str) -> bool:
        """True if ``effect`` is part of the set being assembled."""
        return effect in self.effects

    def unmeasured_axial_force(self):
        """The axial force on the output that the load cell does not see (``force_offset``'s
        ``drive.axial_force_offset``; 0 without it): beside the measured load it loads the load path's attachments
        (``loadpath_compliance``) and takes the power ``F v`` out with it (``load_power``)."""
        return self.p["drive.axial_force_offset"] if self.has("force_offset") else 0.0


def apply_structure(a: Assembly) -> None:
    """The functional structure (level A): one motor, rigid transmission, efficiencies, viscous drag."""
    x, u, p = a.x, a.u, a.p
    w = x["motor_speed"]
    wr = a.rotor_speed
    N = p["gear.ratio"]
    r = a.kinematic_ratio = kinematic_ratio(p)
    kt = a.torque_constant = torque_constant(p)

    tau, target, v_applied, v_d, copper = motor_lag(p, x["motor_current"], u["voltage_primary"], u["enable_primary"], wr)
    a.lags["motor_current"] = (tau, target)
    a.rotor_torques.append(("motor_primary", kt * x["motor_current"]))
    a.loss("copper_primary", copper)
    a.stored_energy["magnetic_primary"] = 0.75 * p["motor.inductance"] * x["motor_current"] ** 2

    a.rotor_inertia.append(p["motor.rotor_inertia"])
    a.inertia.append(p["screw.inertia"] / N**2)
    a.translating_mass = p["loadpath.mass"] + p["surface.mass"]
    a.axial_force = u["load_force"]

    b_m = p["motor.bearing_viscous_friction"]
    a.rotor_torques.append(("viscous_bearing", -b_m * wr))
    a.loss("viscous_bearing", b_m * wr**2)
    b = p["gear.viscous_friction"]
    a.torques.append(("viscous", -b * w))
    a.loss("viscous", b * w**2)

    a.rates["nut_position"] = r * w

    a.output("motor_voltage", "V", v_applied)
    a.output("motor_voltage_d", "V", v_d)
    a.output("motor_current", "A", x["motor_current"])
    a.output("motor_speed", "rad/s", wr)
    a.output("screw_speed", "rad/s", w / N)
    a.output("nut_position", "m", x["nut_position"])
    a.output("nut_speed", "m/s", r * w)
    a.output("load_force", "N", u["load_force"])
    a.output("temperature", "degC", u["temperature"])
    a.output("primary_energised", "-", ca.if_else(u["enable_primary"] > 0.5, 1.0, 0.0))
    # Signals of effects, at their neutral value when the effect is absent, so
    # that every effect set has the same outputs (effects redefine them).
    # Each effect declares them (Effect.outputs); the first declaration of a name wins.
    for eff in EFFECTS.values():
        for out in eff.outputs:
            if out.name not in a.outputs:
                a.output(out.name, out.unit, out.neutral(a) if callable(out.neutral) else out.neutral)


def finish_structure(a: Assembly) -> None:
    """Terms that depend on what the effects decided (axial force, masses)."""
    x, p = a.x, a.p
    w = x["motor_speed"]
    r = kinematic_ratio(p)
    a.inertia.append(a.translating_mass * r**2)
    eta_d = p["screw.efficiency_direct"]
    eta_i = p["screw.efficiency_inverse"]
    c0 = 0.5 * (1.0 / eta_d + eta_i)
    c1 = 0.5 * (1.0 / eta_d - eta_i)
    F = a.axial_force
    a.torques.append(("load", -F * r * c0))
    limit = ca.fabs(F) * r * c1
    a.channels.append(FrictionChannel("efficiency", limit, limit, limit, limit))

    def efficiency_loss(res: FrictionResolution):
        # power into the load path is F r w; what the screw takes beyond it is lost
        return F * r * res.speed * (c0 - 1.0) + res.channel["efficiency"] * res.speed

    a.loss("efficiency", efficiency_loss)

    motor_torque = sum_terms(expr for label, expr in a.rotor_torques if label.startswith("motor_"))
    rotor_drag = sum_terms(expr for label, expr in a.rotor_torques if not label.startswith("motor_"))
    eta_g = p["gear.efficiency"]
    c_drive, c_back = 1.0 - eta_g, (1.0 - eta_g) / eta_g

    # Gearbox efficiency by the power flow at the gearbox.  T_g, the torque
    # the motor side puts into the gearbox, drives it when T_g w > 0 and then
    # (1 - eta) |T_g| is lost; when the screw side drives the motors
    # (T_g w < 0) the loss is (1 - eta)/eta |T_g|.  Written as a friction
    # channel on the gear-output body, it applies to everything the screw
    # side demands (load, no-back disks, drag, its inertia) and always acts
    # against the motion.
    if a.coupling is None:
        # Rigid input: the rotors are part of the main body, and T_g is the
        # motor torque less what accelerates the rotors, T_g = T_m + D_r - J_r dw/dt.
        # With dw/dt = (T_smooth - F_other - G) / J and G = c |T_g| against the
        # motion, T_g solves in closed form per direction of motion s:
        #   a_s = T_m + D_r - rho (T_smooth - s F_other,s),  rho = J_r / J,
        #   |T_g| = |a_s| / (1 - rho c s sgn(a_s)),  c by the sign of s a_s.
        # At standstill (stick) dw/dt = 0 and T_g = T_m + D_r.
        a.inertia += a.rotor_inertia
        a.torques += a.rotor_torques
        j_total = sum_terms(a.inertia)
        rho = sum_terms(a.rotor_inertia) / j_total
        t_smooth = sum_terms(expr for _, expr in a.torques)
        f_pos = sum_terms(c.kinetic_pos for c in a.channels)
        f_neg = sum_terms(c.kinetic_neg for c in a.channels)

        def loss_moving(s, a_s):
            drive = s * a_s > 0
            c = ca.if_else(drive, c_drive, c_back)
            return c * ca.fabs(a_s) / (1.0 - rho * c * ca.if_else(drive, 1.0, -1.0))

        a_pos = motor_torque + rotor_drag - rho * (t_smooth - f_pos)
        a_neg = motor_torque + rotor_drag - rho * (t_smooth + f_neg)
        t_g0 = motor_torque + rotor_drag
        g_static_pos = ca.if_else(t_g0 > 0, c_drive, c_back) * ca.fabs(t_g0)
        g_static_neg = ca.if_else(t_g0 < 0, c_drive, c_back) * ca.fabs(t_g0)
        a.channels.append(FrictionChannel("gear_efficiency", g_static_pos, g_static_neg,
                                          loss_moving(1.0, a_pos), loss_moving(-1.0, a_neg)))
        a.stored_energy["kinetic_main"] = 0.5 * j_total * w**2
        a.main_inertia = a.rotor_body_inertia = j_total  # the rotors are part of the main body
        gear_torque = t_g0  # quasi-static (the output signal)
    else:
        wr = a.rotor_speed
        coupling = a.coupling(wr, w)
        j_rotor = sum_terms(a.rotor_inertia)
        a.rates["rotor_speed"] = (motor_torque + rotor_drag - coupling) / j_rotor
        a.torques.append(("drivetrain", coupling))
        gear_torque = coupling
        mag = ca.fabs(gear_torque)
        g_pos = ca.if_else(gear_torque > 0, c_drive, c_back) * mag
        g_neg = ca.if_else(gear_torque < 0, c_drive, c_back) * mag
        a.channels.append(FrictionChannel("gear_efficiency", g_pos, g_neg, g_pos, g_neg))
        a.stored_energy["kinetic_main"] = 0.5 * sum_terms(a.inertia) * w**2
        a.stored_energy["kinetic_rotors"] = 0.5 * j_rotor * wr**2
        a.main_inertia, a.rotor_body_inertia = sum_terms(a.inertia), j_rotor
    a.loss("gear_efficiency", lambda res: res.channel["gear_efficiency"] * res.speed)

    a.output("axial_force", "N", F)
    # 1 while the torque into the gearbox exceeds the limiter's static slip torque (limiter.* parameters);
    # the limiter slips only when the torque_limiter effect is in the set.
    a.output("motor_torque", "N m", motor_torque)
    a.output("gearbox_input_torque", "N m", gear_torque)
    a.output(
        "torque_limiter_exceeded", "-",
        ca.if_else(ca.fabs(gear_torque) * p["gear.ratio"] > _limiter_static_torque(p), 1.0, 0.0)
        if "limiter.faces" in p else 0.0,  # a rig described without a limiter
    )


def _limiter_static_torque(p: dict):
    """The torque limiter's static slip torque [N m at the large gear], from the limiter's own law."""
    return limiter_slip_torques(p)[0]  # one law for the monitor and the torque_limiter effect


def step_mean_of_harmonic(phase, rate, step):
    """``(cos, sin)`` of a harmonic's phase averaged over a step of the plant, and exact in the continuous form.

    Over a step ``h`` at the phase rate ``rate`` the phase sweeps ``d = rate h``; the mean of ``cos`` over
    ``[phase, phase + d]`` is ``cos(phase + d/2) sinc(d/2)`` (and the same for ``sin``): the torque impulse of the
    step divided by ``h``, which is what the discrete form integrates.  Evaluated once per step at its start instead,
    a torque periodic faster than the step samples its harmonic at arbitrary phases (at 15 mm/s an 18th harmonic of
    the motor speed sweeps 18 rad in a 2 ms step: the model kicked the speed by random torques of the full amplitude
    where the rig's torque averages out).  ``step`` is :attr:`Assembly.step` (0 in the continuous form: the exact
    ``cos(phase), sin(phase)``).
    """
    half = 0.5 * rate * step
    small = ca.fabs(half) < 1e-4
    safe = ca.if_else(small, 1.0, half)
    sinc = ca.if_else(small, 1.0 - half**2 / 6.0, ca.sin(safe) / safe)
    mid = phase + half
    return sinc * ca.cos(mid), sinc * ca.sin(mid)


def sum_terms(terms):
    """Sum of casadi terms, SX zero when there are none (used here and by ``plant.py``)."""
    total = ca.SX(0.0)
    for t in terms:
        total = total + t
    return total
