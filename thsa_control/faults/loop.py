"""The closed loop with sensors, monitors, reconfiguration and scheduled faults, compiled.

:meth:`thsa_control.sim.simulate.Simulator.run` hands a scenario with faults
or monitors to :func:`run_fault_loop`.  One control period of the fault loop
is the simulator's period with two things added, all in one casadi Function
compiled to C with the same driver and cache as a normal run:

* before the controller, ``monitors.build_monitor()``: sensors with their
  faults, the three monitors and the reconfiguration logic, which set the
  enables the controller sees and the brake input of the plant, and give the
  controller its (possibly faulty) speed and position measurements;
* after the controller, the channel failures: a failed channel's inverter
  delivers nothing (its enable and voltage reaching the plant are 0),
  whatever the controller commands.

So the monitors act at the control rate (10 kHz), in the period a trip is
confirmed: the time resolution of every detection is one control period.
"""

from __future__ import annotations

import time
from types import MappingProxyType

import casadi as ca
import numpy as np

from ..errors import ScenarioError, ThsaError
from ..loops.controllers import CONTROLLER_PARAMETERS, CONTROLLER_SIGNALS, CONTROLLER_STATES, REFERENCE_INPUTS, build_controller
from ..sim._compile import compile_run_loop
from ..sim.simulate import RUN_INPUTS, InputSeries, SimulationResult, output_decimation, plant_input_vector
from .events import FAULT_INPUTS, effects_for_faults, fault_signals
from .monitors import MONITOR_CONTEXT, MONITOR_SENSORS, MONITOR_SIGNALS, MONITOR_STATES, MONITOR_UNITS, build_monitor
from .settings import MONITOR_PARAMETERS, MonitorSettings

__all__ = ["fault_sample_functions", "run_fault_loop", "FAULT_RUN_INPUTS"]

FAULT_RUN_INPUTS = RUN_INPUTS + FAULT_INPUTS
_CONTROLLER_UNITS = {"speed_cmd": "m/s", "motor_speed_ref": "rad/s", "current_ref": "A", "voltage_cmd_primary": "V",
                     "voltage_cmd_standby": "V", "energised_primary": "-", "energised_standby": "-"}


def fault_sample_functions(sim):
    """``(sample, sample_x)`` of the fault loop for ``sim``'s plant and substeps.

    ``sample(z, w, theta) -> (z_next, y)`` with ``z = [x; xc; xm]`` (plant,
    controller, monitor states), ``w`` = ``FAULT_RUN_INPUTS`` of one period,
    ``theta = [p; k; h; m]`` (``m``: ``MONITOR_PARAMETERS``); ``y`` = plant
    outputs, ``CONTROLLER_SIGNALS``, ``MONITOR_SIGNALS``.
    """
    plant = sim.plant
    nx, nc, nm = len(plant.states), len(CONTROLLER_STATES), len(MONITOR_STATES)
    n_p, n_k, n_m = len(plant.parameters), len(CONTROLLER_PARAMETERS), len(MONITOR_PARAMETERS)
    z = ca.SX.sym("z", nx + nc + nm)
    w = ca.SX.sym("w", len(FAULT_RUN_INPUTS))
    theta = ca.SX.sym("theta", n_p + n_k + 1 + n_m)
    x, xc, xm = z[:nx], z[nx:nx + nc], z[nx + nc:]
    p, k, h, m = theta[:n_p], theta[n_p:n_p + n_k], theta[n_p + n_k], theta[n_p + n_k + 1:]
    W = dict(zip(FAULT_RUN_INPUTS, ca.vertsplit(w)))
    K = dict(zip(CONTROLLER_PARAMETERS, ca.vertsplit(k)))
    XC = dict(zip(CONTROLLER_STATES, ca.vertsplit(xc)))
    X = dict(zip(plant.state_names, ca.vertsplit(x)))
    N = p[plant.parameters.index("gear.ratio")]
    r = K["nut_per_motor_rad"]

    rotor = X[plant.sensor_state("motor_speed")]  # the motor sensor reads the rotors
    gimbal = X.get("actuator_axial_position", ca.SX(0.0))
    sens = ca.vertcat(rotor, X["nut_position"] / (r * N), gimbal)
    energised = ca.fmax(XC["energised_prev_primary"], XC["energised_prev_standby"])
    ctx = ca.vertcat(XC["shaped_speed"] / r, energised, N)
    sensor_faults = ca.vertcat(*(W[n] for n in FAULT_INPUTS if n.startswith(("motor_speed_", "rvdt_", "lvdt_"))))
    xm_next, cmd, msig = build_monitor()(xm, sens, ctx, sensor_faults, m, h)
    allow_p, allow_s, force_s, brake, w_meas, ang_meas = ca.vertsplit(cmd)

    ref = [W[n] for n in REFERENCE_INPUTS]
    ref[REFERENCE_INPUTS.index("primary_enable")] = W["primary_enable"] * allow_p
    ref[REFERENCE_INPUTS.index("standby_enable")] = ca.fmax(W["standby_enable"] * allow_s, force_s)
    standby = X.get("standby_current", ca.SX(0.0))
    meas = ca.vertcat(w_meas, X["motor_current"], standby, ang_meas * r * N)
    xc_next, u_ctrl, sig = build_controller()(xc, ca.vertcat(*ref), meas, k, h)
    v_p, v_s, en_p, en_s = ca.vertsplit(u_ctrl)
    ok_p, ok_s = 1.0 - W["primary_channel_failure"], 1.0 - W["standby_channel_failure"]
    u_ctrl = ca.vertcat(v_p * ok_p, v_s * ok_s, en_p * ok_p, en_s * ok_s)
    u = plant_input_vector(plant, u_ctrl, W["load_force"], W["temperature"], brake=brake,
                           surface_jam=W["surface_jam"], loadpath_failure=W["loadpath_failure"])
    hs = h / sim.settings.substeps
    x_next, y = plant.step(x, u, p, hs)
    for _ in range(sim.settings.substeps - 1):
        x_next, _ = plant.step(x_next, u, p, hs)
    z_next = ca.vertcat(x_next, xc_next, xm_next)
    sample = ca.Function("sample", [z, w, theta], [z_next, ca.vertcat(y, sig, msig)], ["z", "w", "theta"], ["z_next", "y"])
    sample_x = ca.Function("sample_x", [z, w, theta], [z_next], ["z", "w", "theta"], ["z_next"])
    return sample, sample_x


def _interpreted(sample, sample_x, z, W, theta, decimation):
    """casadi virtual machine fallback (no C compiler): one output period at a time."""
    ys = []
    for j in range(0, W.shape[1], decimation):
        z, y = sample(z, W[:, j], theta)
        ys.append(np.asarray(y).ravel())
        for i in range(j + 1, min(j + decimation, W.shape[1])):
            z = sample_x(z, W[:, i], theta)
        z = np.asarray(z).ravel()
    return np.array(ys).T, z


def run_fault_loop(sim, scenario, design, params, *, x0=None, monitors: MonitorSettings | None = None) -> SimulationResult:
    """Run ``scenario`` (with its faults and monitors) in closed loop on ``sim``'s plant.

    Parameters
    ----------
    sim : Simulator
        Its plant and settings; the compiled fault loop is kept in it.
    scenario : Scenario
    design : Design
    params : ParameterSet
    x0 : ndarray, optional
        Initial plant state (default: at rest, in equilibrium with the initial load).
    monitors : MonitorSettings, optional
        Overrides ``scenario.monitors``; with neither, the monitors run with
        ``reconfigure=False`` (flags only).

    Returns
    -------
    SimulationResult
        Plant outputs, controller signals and ``MONITOR_SIGNALS``.

    Raises
    ------
    ScenarioError
        The plant lacks an effect the scenario or its faults need.
    """
    plant = sim.plant
    settings = monitors or scenario.monitors or MonitorSettings(reconfigure=False)
    needed = tuple(scenario.required_effects) + effects_for_faults(scenario.faults)
    missing = [e for e in needed if e not in plant.effects]
    if missing:
        raise ScenarioError(f"run {scenario.name!r} needs effect(s) {missing}; the plant has {list(plant.effects)}")
    h = design.control_period
    inputs = InputSeries.from_scenario(scenario, h)
    faults = fault_signals(scenario.faults, inputs.time)
    W = np.vstack([inputs.matrix()] + [faults[n] for n in FAULT_INPUTS])
    out_period, decimation = output_decimation(sim.settings.output_period, h)
    k = design.controller_vector(params, accel_limit=inputs.accel_limit, jerk_limit=inputs.jerk_limit,
                                 motor_off_at_zero=inputs.motor_off_at_zero)
    p = plant.p_vector(params)
    theta = np.concatenate([p, k, [h], settings.vector()])
    if x0 is None:
        x0 = plant.initial_state(params, load_force=float(W[RUN_INPUTS.index("load_force"), 0]))
    x0 = np.asarray(x0, float)
    xm0 = np.zeros(len(MONITOR_STATES))
    r = dict(zip(CONTROLLER_PARAMETERS, k))["nut_per_motor_rad"]
    xm0[MONITOR_STATES.index("motor_angle")] = x0[plant.index("state", "nut_position")] / r  # no discrepancy at start
    xm0[MONITOR_STATES.index("since_takeover")] = 1e9
    z = np.concatenate([x0, np.zeros(len(CONTROLLER_STATES)), xm0])

    key = "fault_loop"
    if key not in sim._compiled:
        sample, sample_x = fault_sample_functions(sim)
        loop, cinfo = (compile_run_loop(sample, sample_x) if sim.settings.compiled
                       else (None, {"compiled": False, "cached": False, "codegen_s": 0.0, "compile_s": 0.0}))
        sim._compiled[key] = (loop, cinfo, sample, sample_x)
    loop, cinfo, sample, sample_x = sim._compiled[key]
    t0 = time.perf_counter()
    if loop is not None:
        Y, z = loop(z, W, theta, decimation)
    else:
        Y, z = _interpreted(sample, sample_x, z, W, theta, decimation)
    wall = time.perf_counter() - t0
    if not np.all(np.isfinite(Y)):
        bad = np.argwhere(~np.isfinite(Y))[0]
        raise ThsaError(f"simulation of {scenario.name!r} diverged (non-finite signal at t = {bad[1] * decimation * h:g} s)")
    names = plant.outputs + CONTROLLER_SIGNALS + MONITOR_SIGNALS
    units = dict(plant.output_units)
    units.update(_CONTROLLER_UNITS)
    units.update(MONITOR_UNITS)
    signals = {}
    for i, name in enumerate(names):
        arr = Y[i].copy()
        arr.setflags(write=False)
        signals[name] = arr
    t = np.arange(Y.shape[1]) * decimation * h
    t.setflags(write=False)
    info = {"wall_s": wall, "compile": dict(cinfo), "control_period_s": h, "output_period_s": decimation * h,
            "substeps": sim.settings.substeps, "final_state": z, "monitors": settings.as_dict(),
            "faults": [f.label + f" at {f.time:g} s" for f in scenario.faults]}
    return SimulationResult(t, MappingProxyType(signals), MappingProxyType(units), plant.effects, scenario.name,
                            design, params, inputs, info)
