"""The rig's control cascade as a sampled-data controller written in casadi.

One control period ``h`` (10 kHz by default) does, in this order:

1. position P loop (optional): ``v_target = sgn(e) min(kp_x |e|, sqrt(2 a_max |e|), v_max)``
   with ``e = x_cmd - x_nut``: the P law, capped by the speed from which the
   shaper can brake to rest within the error;
2. speed-command shaping: the target nut speed is rate limited to
   ``accel_limit`` and, if finite, acceleration limited to ``jerk_limit`` with
   braking so that it lands on the target without overshoot;
3. motors de-energised while the shaped command is exactly zero (as on the
   rig; optional), integrators reset then;
4. velocity PI on motor speed [rad/s] (reference = shaped nut speed / r),
   plus the per-sample ``current_ff`` [A] added at its output (a feed-forward
   or a disturbance at the controller output; 0 by default),
   current reference clamped to ``+-current_limit``, conditional integration
   (no integration while the clamp is active and the error drives further into
   it, nor while no motor is energised);
5. one current PI per energised motor, voltage clamped to ``+-voltage_limit``,
   same anti-windup; optional one-sample computation delay;
6. optional bumpless hand-over: in the period a channel is energised, its
   current integrator is preset to the steady voltage ``R i_ref + p psi w``
   (back-EMF feed-forward) instead of zero; the proportional action adds to it.  The
   velocity integrator is held while a fault leaves no channel energised, so
   the channel taking over inherits the load torque; without hand-over it is
   reset (a standby channel starting its own controller from zero).

The controller is a casadi ``Function`` so that simulation, tuning and
identification differentiate through it.  No numpy arrays are made here.
"""

from __future__ import annotations

import casadi as ca

__all__ = ["CONTROLLER_STATES", "REFERENCE_INPUTS", "MEASUREMENTS", "CONTROLLER_PARAMETERS", "CONTROLLER_SIGNALS", "build_controller"]

CONTROLLER_STATES = (
    "shaped_speed", "shaped_accel", "velocity_integrator", "current_integrator_primary",
    "current_integrator_standby", "delayed_voltage_primary", "delayed_voltage_standby",
    "energised_prev_primary", "energised_prev_standby",
)
#: Per-sample reference inputs: target nut speed [m/s], position command [m],
#: position mode (1: P loop closed), channel enables (0/1), current added at the velocity PI's output [A].
REFERENCE_INPUTS = ("speed_target", "position_cmd", "position_mode", "primary_enable", "standby_enable", "current_ff")
#: Measurements: motor speed [rad/s], currents [A], nut position [m].
MEASUREMENTS = ("motor_speed", "motor_current", "standby_current", "nut_position")
CONTROLLER_PARAMETERS = (
    "current_kp", "current_ki", "voltage_limit", "velocity_kp", "velocity_ki", "current_limit",
    "position_kp", "delay_samples", "accel_limit", "jerk_limit", "max_speed", "motor_off_at_zero",
    "nut_per_motor_rad", "handover", "motor_resistance", "back_emf_constant",
)
CONTROLLER_SIGNALS = ("speed_cmd", "motor_speed_ref", "current_ref", "voltage_cmd_primary", "voltage_cmd_standby",
                      "energised_primary", "energised_standby")


def _clamp(v, lim):
    return ca.fmin(ca.fmax(v, -lim), lim)


def _pi(error, integrator, kp, ki, limit, h, active, offset=0.0):
    """PI (plus ``offset`` at its output) with output clamp and conditional integration; returns (output, integrator_next)."""
    unsat = kp * error + integrator + offset
    out = _clamp(unsat, limit)
    saturated = ca.fabs(unsat) >= limit
    winding = saturated * (error * unsat > 0)
    integ = ca.if_else(ca.logic_and(active, ca.logic_not(winding)), integrator + ki * h * error, integrator)
    return out, ca.if_else(active, integ, 0.0)


def build_controller() -> ca.Function:
    """The cascade as ``ctrl(xc, ref, meas, k, h) -> (xc_next, u_plant, signals)``.

    ``u_plant`` is ``[voltage_primary, voltage_standby, enable_primary,
    enable_standby]`` for the plant inputs of the same names.

    Examples
    --------
    >>> c = build_controller()
    >>> c.name_out()
    ['xc_next', 'u_plant', 'signals']
    """
    xc = ca.SX.sym("xc", len(CONTROLLER_STATES))
    ref = ca.SX.sym("ref", len(REFERENCE_INPUTS))
    meas = ca.SX.sym("meas", len(MEASUREMENTS))
    k = ca.SX.sym("k", len(CONTROLLER_PARAMETERS))
    h = ca.SX.sym("h")
    X = dict(zip(CONTROLLER_STATES, ca.vertsplit(xc)))
    R = dict(zip(REFERENCE_INPUTS, ca.vertsplit(ref)))
    M = dict(zip(MEASUREMENTS, ca.vertsplit(meas)))
    K = dict(zip(CONTROLLER_PARAMETERS, ca.vertsplit(k)))

    # 1. position loop
    # P law, capped by the speed from which the shaper can still brake to rest within the error
    # (square-root law), so the acceleration limit does not make the position overshoot
    e_x = R["position_cmd"] - M["nut_position"]
    v_brake = ca.sqrt(2.0 * K["accel_limit"] * ca.fabs(e_x) + 1e-24)  # offset: finite derivative at e = 0
    p_loop = ca.sign(e_x) * ca.fmin(ca.fmin(K["position_kp"] * ca.fabs(e_x), v_brake), K["max_speed"])
    target = ca.if_else(R["position_mode"] > 0.5, p_loop, R["speed_target"])
    # 2. shaping (rate limit; acceleration limit with braking when finite)
    s, acc = X["shaped_speed"], X["shaped_accel"]
    amax, jmax = K["accel_limit"], K["jerk_limit"]
    braking = acc * ca.fabs(acc) / (2.0 * jmax)  # speed still gained while the acceleration returns to zero
    a_des = _clamp((target - s - braking) / h, amax)
    a_new = ca.fmin(ca.fmax(a_des, acc - jmax * h), acc + jmax * h)
    land = ca.logic_and(ca.fabs(target - s) <= amax * h, ca.fabs(acc) <= jmax * h)
    s_new = ca.if_else(land, target, s + h * a_new)
    a_new = ca.if_else(land, 0.0, a_new)
    speed_cmd = s  # the command applied in this period (the shaper's output so far)
    # 3. de-energise at exactly zero command
    run = ca.logic_or(K["motor_off_at_zero"] < 0.5, speed_cmd != 0)
    en_p = ca.logic_and(run, R["primary_enable"] > 0.5)
    en_s = ca.logic_and(run, R["standby_enable"] > 0.5)
    any_on = ca.logic_or(en_p, en_s)
    # 4. velocity PI (reset at zero command; in a fault gap held with hand-over, else reset)
    w_ref = speed_cmd / K["nut_per_motor_rad"]
    i_ref, vi = _pi(w_ref - M["motor_speed"], X["velocity_integrator"], K["velocity_kp"], K["velocity_ki"],
                    K["current_limit"], h, any_on, R["current_ff"])
    held = ca.if_else(K["handover"] > 0.5, X["velocity_integrator"], 0.0)
    vi = ca.if_else(run, ca.if_else(any_on, vi, held), 0.0)
    i_ref = ca.if_else(any_on, i_ref, 0.0)
    # 5. current PIs
    steady_v = K["motor_resistance"] * i_ref + K["back_emf_constant"] * M["motor_speed"]

    def preset(integrator, en, prev):
        starting = ca.logic_and(ca.logic_and(en, prev < 0.5), K["handover"] > 0.5)
        return ca.if_else(starting, steady_v, integrator)

    v_p, ci_p = _pi(i_ref - M["motor_current"],
                    preset(X["current_integrator_primary"], en_p, X["energised_prev_primary"]),
                    K["current_kp"], K["current_ki"], K["voltage_limit"], h, en_p)
    v_s, ci_s = _pi(i_ref - M["standby_current"],
                    preset(X["current_integrator_standby"], en_s, X["energised_prev_standby"]),
                    K["current_kp"], K["current_ki"], K["voltage_limit"], h, en_s)
    v_p, v_s = ca.if_else(en_p, v_p, 0.0), ca.if_else(en_s, v_s, 0.0)
    f_en_p, f_en_s = ca.if_else(en_p, 1.0, 0.0), ca.if_else(en_s, 1.0, 0.0)
    delayed = K["delay_samples"] > 0.5
    u_p = ca.if_else(delayed, X["delayed_voltage_primary"], v_p)
    u_s = ca.if_else(delayed, X["delayed_voltage_standby"], v_s)
    xc_next = ca.vertcat(s_new, a_new, vi, ci_p, ci_s, v_p, v_s, f_en_p, f_en_s)
    u_plant = ca.vertcat(u_p, u_s, f_en_p, f_en_s)
    signals = ca.vertcat(speed_cmd, w_ref, i_ref, v_p, v_s, f_en_p, f_en_s)
    return ca.Function("ctrl", [xc, ref, meas, k, h], [xc_next, u_plant, signals],
                       ["xc", "ref", "meas", "k", "h"], ["xc_next", "u_plant", "signals"])
