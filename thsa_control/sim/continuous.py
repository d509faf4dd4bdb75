"""The closed loop in continuous time, as a python-control ``NonlinearIOSystem`` (for comparisons).

The project's simulator runs the sampled cascade at the control rate on the
plant's discrete step.  For a comparison against a general-purpose
integrator (python-control's ``input_output_response``, i.e. scipy's
``solve_ivp``), :func:`continuous_closed_loop` gives the same plant's
continuous right-hand side ``plant.f`` closed by the velocity and current PI
loops in continuous time, with the shaped speed command (the simulator's
``speed_cmd`` signal) as an input, the primary channel only, and motors off
(integrators decaying in 1 ms) while the command is exactly zero.

It is built from the pieces the simulator uses, so it cannot drift from the
plant: the plant's input vector is assembled by name by
:func:`~thsa_control.sim.loop.plant_input_vector` and the sensors are read
by :func:`~thsa_control.sim.loop.measurement_vector`; the gains come from
``Design.controller_vector``.  ``tests/test_simulate.py`` runs it against the
simulator, so a change of the plant's inputs that breaks it fails a test.
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from ..loops.controllers import CONTROLLER_PARAMETERS
from ..loops.design import Design
from ..model.params import ParameterSet
from ..model.plant import Plant
from .loop import measurement_vector, plant_input_vector

__all__ = ["CONTINUOUS_INPUTS", "continuous_closed_loop_function", "continuous_closed_loop"]

#: Inputs of the continuous closed loop: shaped nut speed command [m/s], load [N], temperature [degC].
CONTINUOUS_INPUTS = ("speed_cmd", "load_force", "temperature")
_OFF_RESET = 1e-3  # [s] time constant with which the integrators decay while the motors are off


def _clamp(v, lim):
    return ca.fmin(ca.fmax(v, -lim), lim)


def continuous_closed_loop_function(plant: Plant, params: ParameterSet, design: Design) -> ca.Function:
    """``rhs(x, u) -> xdot`` with ``x = [plant states; velocity integrator; current integrator]``,
    ``u = CONTINUOUS_INPUTS``, the parameters fixed."""
    k = dict(zip(CONTROLLER_PARAMETERS, design.controller_vector(params, accel_limit=1.0)))
    p = plant.p_vector(params)
    nx = len(plant.states)
    x = ca.SX.sym("x", nx + 2)
    u = ca.SX.sym("u", len(CONTINUOUS_INPUTS))
    xp, vi, ci = x[:nx], x[nx], x[nx + 1]
    cmd, load, temp = ca.vertsplit(u)
    w_meas, i_meas, _, _ = measurement_vector(plant, xp)
    on = cmd != 0
    e_w = cmd / k["nut_per_motor_rad"] - w_meas
    i_un = k["velocity_kp"] * e_w + vi
    i_ref = ca.if_else(on, _clamp(i_un, k["current_limit"]), 0.0)
    e_i = i_ref - i_meas
    v_un = k["current_kp"] * e_i + ci
    v = ca.if_else(on, _clamp(v_un, k["voltage_limit"]), 0.0)
    wind_v = ca.logic_and(ca.fabs(i_un) >= k["current_limit"], e_w * i_un > 0)
    wind_i = ca.logic_and(ca.fabs(v_un) >= k["voltage_limit"], e_i * v_un > 0)
    dvi = ca.if_else(on, ca.if_else(wind_v, 0.0, k["velocity_ki"] * e_w), -vi / _OFF_RESET)
    dci = ca.if_else(on, ca.if_else(wind_i, 0.0, k["current_ki"] * e_i), -ci / _OFF_RESET)
    u_ctrl = ca.vertcat(v, 0.0, ca.if_else(on, 1.0, 0.0), 0.0)
    up = plant_input_vector(plant, u_ctrl, load, temp)
    xdot = plant.f(xp, up, ca.DM(p))[0]
    return ca.Function("continuous_closed_loop", [x, u], [ca.vertcat(xdot, dvi, dci)], ["x", "u"], ["xdot"])


def continuous_closed_loop(plant: Plant, params: ParameterSet, design: Design, *, name: str = "thsa_closed_loop",
                           deadline: float | None = None):
    """The continuous closed loop as a python-control ``NonlinearIOSystem``.

    States: the plant's, then ``velocity_integrator``, ``current_integrator``;
    inputs :data:`CONTINUOUS_INPUTS`; outputs the plant's states.
    ``deadline`` (a ``time.perf_counter()`` value): the right-hand side raises
    ``TimeoutError`` once it has passed, so a caller can cap a slow solver
    in its own process.
    """
    import time

    import control as ct

    rhs = continuous_closed_loop_function(plant, params, design)
    nx = len(plant.states)

    def upd(t, x, u, _params):
        if deadline is not None and time.perf_counter() > deadline:
            raise TimeoutError("continuous closed loop: time cap reached")
        return np.asarray(rhs(x, u)).ravel()

    def out(t, x, u, _params):
        return x[:nx]

    return ct.nlsys(upd, out, states=list(plant.state_names) + ["velocity_integrator", "current_integrator"],
                    inputs=list(CONTINUOUS_INPUTS), outputs=list(plant.state_names), name=name)
