"""Sensors, monitors and reconfiguration logic, as one casadi Function per control period.

It runs in the closed loop at the controller's rate: :class:`MonitorLoop` is
the loop extension (``loop.py``) that puts it in the compiled sample
function, before the controller, so that a trip acts in the period it is
confirmed (the time resolution of every detection is one control period).
In one period:

1. **Sensors** (with the scheduled sensor faults of ``events.py``): the
   primary motor's speed sensor (rotor speed [rad/s]), the RVDT (screw angle
   [rad]; the nut position the position loop uses is ``angle x lead / 2 pi``)
   and the upper-gimbal LVDT (actuator body displacement [m]).  A stuck sensor
   holds its last reading, a lost one reads 0, offset and noise add.
2. **Monitors**, each with a threshold and a confirmation time (the time the
   monitored quantity must stay beyond the threshold; below it the timer
   restarts):

   * ``discrepancy``: motor position (the motor sensor integrated, divided by
     the gear ratio) minus the RVDT angle [rad at the screw]: torque-limiter
     slip and jams that slip it;
   * ``lvdt``: the upper-gimbal displacement [m]: primary load-path failure;
   * ``speed``: motor speed reference minus measured motor speed [rad/s],
     only while a channel is energised and not within ``speed_rearm`` of a
     take-over: channel failure (and stalls).

3. **Reconfiguration** (``reconfigure``): a confirmed speed trip with the
   primary active disables the primary at once and enables the standby after
   ``takeover_delay``; a speed trip with the standby active, a discrepancy or
   an LVDT trip *safe* the actuator: both channels off and, with
   ``brakes_on_safe``, the motor brakes on.  Trips are latched.

4. **Channel failures** (after the controller): a failed channel's inverter
   delivers nothing (its enable and voltage reaching the plant are 0),
   whatever the controller commands; the jam, the load-path failure and the
   brake command are plant inputs.

Everything is casadi SX, so the logic compiles with the plant and controller.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from .events import FAULT_INPUTS, effects_for_faults, fault_signals
from .loop import LoopExtension, LoopStage
from .monitor_settings import MONITOR_PARAMETERS, MonitorSettings

__all__ = ["MONITOR_STATES", "MONITOR_SENSORS", "MONITOR_CONTEXT", "MONITOR_SIGNALS", "MONITOR_UNITS", "build_monitor",
           "MonitorLoop", "extensions_for"]

MONITOR_STATES = (
    "motor_angle", "held_motor_speed", "held_rvdt", "held_lvdt",
    "timer_discrepancy", "timer_lvdt", "timer_speed",
    "trip_discrepancy", "trip_lvdt", "speed_trips",
    "primary_failed", "takeover_timer", "standby_active", "since_takeover", "safed",
)
#: true sensed quantities: rotor speed [rad/s], screw angle [rad], gimbal displacement [m]
MONITOR_SENSORS = ("rotor_speed", "screw_angle", "gimbal_displacement")
#: from the controller and the plant: speed reference [rad/s], a channel energised (0/1), gear ratio
MONITOR_CONTEXT = ("motor_speed_ref", "energised", "gear_ratio")
MONITOR_SIGNALS = (
    "measured_motor_speed", "measured_screw_angle", "measured_gimbal_displacement",
    "monitor_discrepancy", "monitor_lvdt", "monitor_speed_error",
    "trip_discrepancy", "trip_lvdt", "trip_speed", "speed_trips", "primary_failed", "standby_active", "safed",
    "brake_cmd",
)
MONITOR_UNITS = {
    "measured_motor_speed": "rad/s", "measured_screw_angle": "rad", "measured_gimbal_displacement": "m",
    "monitor_discrepancy": "rad", "monitor_lvdt": "m", "monitor_speed_error": "rad/s",
    "trip_discrepancy": "-", "trip_lvdt": "-", "trip_speed": "-", "speed_trips": "-", "primary_failed": "-",
    "standby_active": "-", "safed": "-", "brake_cmd": "-",
}
_SENSOR_FAULTS = tuple(n for n in FAULT_INPUTS if n.startswith(("motor_speed_", "rvdt_", "lvdt_")))


def _read(true, held, stuck, lost, error):
    return ca.if_else(lost > 0.5, 0.0, ca.if_else(stuck > 0.5, held, true + error))


def _confirm(timer, beyond, active, h):
    """Timer of a monitor: counts while ``beyond`` and ``active``, restarts otherwise."""
    return ca.if_else(ca.logic_and(beyond, active), timer + h, 0.0)


def build_monitor() -> ca.Function:
    """``monitor(xm, sens, ctx, faults, m, h) -> (xm_next, cmd, signals)``.

    ``faults`` are the sensor fault inputs (``*_stuck``, ``*_lost``,
    ``*_error`` of ``FAULT_INPUTS``); ``m`` the ``MONITOR_PARAMETERS``.
    ``cmd = [allow_primary, allow_standby, force_standby, brake, speed_meas, screw_angle_meas]``:
    the scheduled enables are multiplied by the allows, the standby is forced on
    after a take-over, and the measurements go to the controller.

    Examples
    --------
    >>> build_monitor().name_out()
    ['xm_next', 'cmd', 'signals']
    """
    xm = ca.SX.sym("xm", len(MONITOR_STATES))
    sens = ca.SX.sym("sens", len(MONITOR_SENSORS))
    ctx = ca.SX.sym("ctx", len(MONITOR_CONTEXT))
    flt = ca.SX.sym("faults", len(_SENSOR_FAULTS))
    m = ca.SX.sym("m", len(MONITOR_PARAMETERS))
    h = ca.SX.sym("h")
    X = dict(zip(MONITOR_STATES, ca.vertsplit(xm)))
    S = dict(zip(MONITOR_SENSORS, ca.vertsplit(sens)))
    C = dict(zip(MONITOR_CONTEXT, ca.vertsplit(ctx)))
    F = dict(zip(_SENSOR_FAULTS, ca.vertsplit(flt)))
    M = dict(zip(MONITOR_PARAMETERS, ca.vertsplit(m)))

    # 1. sensors
    w_meas = _read(S["rotor_speed"], X["held_motor_speed"], F["motor_speed_stuck"], F["motor_speed_lost"],
                   F["motor_speed_error"])
    ang_meas = _read(S["screw_angle"], X["held_rvdt"], F["rvdt_stuck"], F["rvdt_lost"], F["rvdt_error"])
    lvdt_meas = _read(S["gimbal_displacement"], X["held_lvdt"], F["lvdt_stuck"], F["lvdt_lost"], F["lvdt_error"])

    # 2. monitors
    safed = X["safed"] > 0.5
    discrepancy = X["motor_angle"] / C["gear_ratio"] - ang_meas
    t_disc = _confirm(X["timer_discrepancy"], ca.fabs(discrepancy) > M["discrepancy_threshold"], 1, h)
    t_lvdt = _confirm(X["timer_lvdt"], ca.fabs(lvdt_meas) > M["lvdt_threshold"], 1, h)
    armed = ca.logic_or(X["standby_active"] < 0.5, X["since_takeover"] >= M["speed_rearm"])
    gate = ca.logic_and(ca.logic_and(C["energised"] > 0.5, armed), ca.logic_not(safed))
    speed_err = ca.if_else(gate, C["motor_speed_ref"] - w_meas, 0.0)
    t_speed = _confirm(X["timer_speed"], ca.fabs(speed_err) > M["speed_threshold"], gate, h)
    disc_trip = ca.logic_or(X["trip_discrepancy"] > 0.5, t_disc >= M["discrepancy_confirmation"])
    lvdt_trip = ca.logic_or(X["trip_lvdt"] > 0.5, t_lvdt >= M["lvdt_confirmation"])
    new_speed_trip = t_speed >= M["speed_confirmation"]
    t_speed = ca.if_else(new_speed_trip, 0.0, t_speed)  # restart: a second trip needs its own confirmation

    # 3. reconfiguration
    on_standby = X["standby_active"] > 0.5
    primary_failed = ca.logic_or(X["primary_failed"] > 0.5, ca.logic_and(new_speed_trip, ca.logic_not(on_standby)))
    takeover_timer = ca.if_else(ca.logic_and(primary_failed, ca.logic_not(on_standby)), X["takeover_timer"] + h, 0.0)
    takes_over = ca.logic_and(ca.logic_not(on_standby), takeover_timer >= M["takeover_delay"])
    takes_over = ca.logic_and(takes_over, primary_failed)
    standby_active = ca.logic_or(on_standby, takes_over)
    since = ca.if_else(takes_over, 0.0, X["since_takeover"] + h)
    safe = ca.logic_or(ca.logic_or(safed, ca.logic_or(disc_trip, lvdt_trip)),
                       ca.logic_and(new_speed_trip, on_standby))
    R = M["reconfigure"] > 0.5
    b = lambda c: ca.if_else(c, 1.0, 0.0)  # noqa: E731
    allow_primary = ca.if_else(R, b(ca.logic_not(ca.logic_or(primary_failed, safe))), 1.0)
    allow_standby = ca.if_else(R, b(ca.logic_not(safe)), 1.0)
    force_standby = ca.if_else(R, b(ca.logic_and(standby_active, ca.logic_not(safe))), 0.0)
    brake = ca.if_else(ca.logic_and(R, M["brakes_on_safe"] > 0.5), b(safe), 0.0)
    speed_trips = X["speed_trips"] + b(new_speed_trip)

    xm_next = ca.vertcat(
        X["motor_angle"] + h * w_meas, w_meas, ang_meas, lvdt_meas, t_disc, t_lvdt, t_speed,
        b(disc_trip), b(lvdt_trip), speed_trips, b(primary_failed), takeover_timer, b(standby_active), since, b(safe),
    )
    cmd = ca.vertcat(allow_primary, allow_standby, force_standby, brake, w_meas, ang_meas)
    signals = ca.vertcat(
        w_meas, ang_meas, lvdt_meas, discrepancy, lvdt_meas, speed_err,
        b(disc_trip), b(lvdt_trip), b(speed_trips > 0.5), speed_trips, b(primary_failed), b(standby_active), b(safe),
        brake,
    )
    return ca.Function("monitor", [xm, sens, ctx, flt, m, h], [xm_next, cmd, signals],
                       ["xm", "sens", "ctx", "faults", "m", "h"], ["xm_next", "cmd", "signals"])


class MonitorLoop(LoopExtension):
    """The loop extension of the fault cases: sensors with their faults, monitors, reconfiguration,
    channel failures and the plant's fault inputs (jam, load-path failure, brake).

    Parameters
    ----------
    settings : MonitorSettings or None
        None: the monitors run with ``reconfigure=False`` (flags only).

    Its inputs are ``FAULT_INPUTS`` (from the scenario's ``faults``), its
    parameters ``MONITOR_PARAMETERS``, its states ``MONITOR_STATES`` and its
    signals ``MONITOR_SIGNALS``.
    """

    name = "monitors"
    states = MONITOR_STATES
    inputs = FAULT_INPUTS
    parameters = MONITOR_PARAMETERS
    signals = MONITOR_SIGNALS
    units = MONITOR_UNITS

    def __init__(self, settings: MonitorSettings | None = None):
        self.settings = settings if settings is not None else MonitorSettings(reconfigure=False)

    def before_controller(self, stage: LoopStage, xe, m):
        X, XC, W, K, h = stage.x, stage.xc, stage.w, stage.k, stage.h
        N = stage.param("gear.ratio")
        r = K["nut_per_motor_rad"]
        rotor = X[stage.plant.sensor_state("motor_speed")]  # the motor sensor reads the rotors
        gimbal = X.get("actuator_axial_position", ca.SX(0.0))
        sens = ca.vertcat(rotor, X["nut_position"] / (r * N), gimbal)
        energised = ca.fmax(XC["energised_prev_primary"], XC["energised_prev_standby"])
        ctx = ca.vertcat(XC["shaped_speed"] / r, energised, N)
        sensor_faults = ca.vertcat(*(W[n] for n in _SENSOR_FAULTS))
        xm_next, cmd, msig = build_monitor()(xe, sens, ctx, sensor_faults, m, h)
        allow_p, allow_s, force_s, brake, w_meas, ang_meas = ca.vertsplit(cmd)
        stage.reference["primary_enable"] = W["primary_enable"] * allow_p
        stage.reference["standby_enable"] = ca.fmax(W["standby_enable"] * allow_s, force_s)
        stage.measurement["motor_speed"] = w_meas
        stage.measurement["nut_position"] = ang_meas * r * N
        stage.plant_inputs.update(brake=brake, surface_jam=W["surface_jam"], loadpath_failure=W["loadpath_failure"])
        return xm_next, msig

    def after_controller(self, stage: LoopStage, u: dict) -> dict:
        ok_p, ok_s = 1.0 - stage.w["primary_channel_failure"], 1.0 - stage.w["standby_channel_failure"]
        return {"voltage_primary": u["voltage_primary"] * ok_p, "voltage_standby": u["voltage_standby"] * ok_s,
                "enable_primary": u["enable_primary"] * ok_p, "enable_standby": u["enable_standby"] * ok_s}

    def required_effects(self, scenario) -> tuple[str, ...]:
        return effects_for_faults(getattr(scenario, "faults", ()))

    def input_signals(self, scenario, t):
        faults = getattr(scenario, "faults", ())
        return fault_signals(faults, t)

    def parameter_vector(self) -> np.ndarray:
        return self.settings.vector()

    def initial_state(self, plant, x0, k):
        xm0 = np.zeros(len(MONITOR_STATES))
        xm0[MONITOR_STATES.index("motor_angle")] = x0[plant.index("state", "nut_position")] / k["nut_per_motor_rad"]
        xm0[MONITOR_STATES.index("since_takeover")] = 1e9  # no take-over yet; no discrepancy at start
        return xm0

    def info(self, scenario) -> dict:
        return {"monitors": self.settings.as_dict(),
                "faults": [f.label + f" at {f.time:g} s" for f in getattr(scenario, "faults", ())]}


def extensions_for(scenario) -> tuple[LoopExtension, ...]:
    """The loop extensions a scenario asks for: the monitors when it has faults or monitor settings."""
    if getattr(scenario, "faults", ()) or getattr(scenario, "monitors", None) is not None:
        return (MonitorLoop(scenario.monitors),)
    return ()
