"""Segment states the measurements do not give: the model's own custom states along a run.

Multiple shooting (:mod:`thsa_control.fit.identify`) frees each segment's
speeds and positions, but an effect's *custom* states (the no-back's pawl
clearances, a jam anchor) have no sensor and no gradient: where the ratchets
stopped decides whether a pawl is engaged, a switch.  Each segment must start
with the clearance the model itself would have there, for the parameters being
tried (a clearance from a replay at other parameters, e.g. another pawl
pitch, is inconsistent with the model being fitted).

:func:`custom_state_track` runs the plant's own current-driven map
(:func:`~thsa_control.fit.replay.current_driven_map`) one sample period at a
time from the *measured* state: before each step the speed and position states
are reset to their measured values, so only the custom states are carried from
step to step (the series-parallel, one-step-ahead form of a replay).  It
cannot drift like an open-loop replay, and it uses the effect's own discrete
update, so no law is written twice.  The result depends on the parameters:
call it again for each pitch of a profile.

:func:`drivetrain_segment_guess` starts the compliant drive train's segment
states (``drivetrain_compliance``: rotors and gear output as two bodies, read
by the motor-speed and the screw-speed sensor, joined by the drive-train
spring) from the data:

* ``rotor_speed``: the measured motor speed (else ratio x screw speed);
* gear-output ``motor_speed``: ratio x the measured screw speed (else the
  motor speed: the rigid guess);
* ``drivetrain_twist``: quasi-static, from the rotors' own balance
  ``d(rotor_speed)/dt = a_i i + a_phi phi`` with ``a_i = Kt / J_r`` and
  ``a_phi = -k / J_r`` taken from the plant's own right-hand side (its
  Jacobian at rest: no second copy of the physics), ``i`` the measured
  current and ``d(rotor_speed)/dt`` the slope of a straight line through the
  measured rotor speed around the segment start.  Drag and damping are
  neglected in the guess; the fit frees these states per segment anyway.

Imports casadi and numpy; no file parsing, no plotting.
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np

from ..data.rigdata import RigRun, measured_motor_speed
from ..model.params import ParameterSet
from ..model.plant import Plant

__all__ = ["custom_state_indices", "custom_state_track", "measured_speed", "measured_state_matrix", "one_step_map",
           "drivetrain_segment_guess"]


def custom_state_indices(plant: Plant) -> list[int]:
    """Positions of the plant's ``custom`` states (effect-specific discrete updates) in ``x``."""
    return [i for i, s in enumerate(plant.states) if s.kind == "custom"]


def measured_speed(run: RigRun) -> np.ndarray | None:
    """Motor speed [rad/s] per sample: the motor speed sensor, else ratio x screw speed, else None.

    Single missing samples are bridged by linear interpolation; a run with no
    finite speed sample gives None.
    """
    w = measured_motor_speed(run)
    if w is None:
        return None
    ok = np.isfinite(w)
    if not ok.any():
        return None
    if not ok.all():
        k = np.arange(w.size)
        w = np.interp(k, k[ok], w[ok])
    return w


def measured_state_matrix(run: RigRun, plant: Plant, params: ParameterSet) -> np.ndarray | None:
    """Full state per sample: at rest with the load-path springs in equilibrium with the measured load,
    the speeds and positions set to the measured values.

    The motor speed (and the rotors' speed with a compliant drive train) is
    the measured motor speed (:func:`measured_speed`), the surface speed the
    matching nut speed; the LVDT gives the surface position where the load
    path is compliant (the nut sits the spring deflection ahead), the nut
    position otherwise.  The custom states are their initial values
    (``plant.init``).  None when the run measures no speed.
    """
    w = measured_speed(run)
    if w is None:
        return None
    n = w.size
    p = plant.p_vector(params)
    load = np.nan_to_num(np.asarray(run.signals["load_force"], float))
    nut = np.asarray(run.signals["nut_position"], float) if "nut_position" in run.source_columns else None
    if nut is not None and not np.isfinite(nut).all():
        nut = None
    X = np.array(plant.init.map(n)((nut if nut is not None else np.zeros(n))[None, :], load[None, :], p))
    names = plant.state_names
    lvdt = plant.sensor_state("nut_position")
    if nut is not None and lvdt != "nut_position":  # the LVDT reads the surface
        i_nut, i_srf = plant.index("state", "nut_position"), plant.index("state", lvdt)
        X[i_nut] = nut + (X[i_nut] - X[i_srf])
        X[i_srf] = nut
    for name in ("motor_speed", "rotor_speed"):
        if name in names:
            X[plant.index("state", name)] = w
    if "surface_speed" in names:
        X[plant.index("state", "surface_speed")] = w * plant.kinematic_ratio(p)
    return X


def one_step_map(plant: Plant, mech: ca.Function, n: int) -> ca.Function:
    """``F(c0, U, p) -> (C, W)``: ``n`` steps of the map from measured states, custom states carried.

    ``U`` stacks per sample the measured full state, the map's inputs and the
    sample period (``nx + nv + 1`` rows, ``n`` columns); ``C`` holds the custom
    states after each step, ``W`` the motor speed the map predicts one sample
    ahead.  Build it once per plant and run length: the parameters are an input.
    """
    return one_step_function(plant, mech).mapaccum("one_step", n)


def one_step_function(plant: Plant, mech: ca.Function) -> ca.Function:
    """``f(c, u, p) -> (c_next, w_next)``: one step of :func:`one_step_map` (``u``: one column of its ``U``).

    ``w_next`` is the state the motor-speed sensor reads (``plant.sensor_state("motor_speed")``: the rotors' speed
    with a compliant drive train, the motor speed otherwise), so that the one-step error compares the model's
    prediction with what the sensor measured.  It was the gear output's speed on a compliant drive train, which a
    torque on the rotors (a cogging) does not move within one step: the cogging period's screen was flat there and
    held the period at the grid's first value (measured on a rig-sim position loop with a cogging beside a
    drive-train compliance: 6 per revolution against rig-sim's 18, and the cogging refused)."""
    idx = custom_state_indices(plant)
    nx = len(plant.states)
    nv = mech.size1_in(1)
    c = ca.SX.sym("c", len(idx))
    xm = ca.SX.sym("xm", nx)
    v = ca.SX.sym("v", nv)
    ps = ca.SX.sym("p", mech.size1_in(2))
    h = ca.SX.sym("h")
    parts = ca.vertsplit(xm)
    for k, i in enumerate(idx):
        parts[i] = c[k]
    xn, _ = mech(ca.vertcat(*parts), v, ps, h)
    w_next = xn[plant.index("state", plant.sensor_state("motor_speed"))]
    return ca.Function("custom_step", [c, ca.vertcat(xm, v, h), ps], [xn[idx] if idx else ca.SX(0, 1), w_next])


def one_step_loop(plant: Plant, mech: ca.Function):
    """:func:`one_step_map`'s loop over the samples compiled to C, or None (no working C compiler: use
    :func:`one_step_map` in casadi's interpreter).

    A :class:`~thsa_control.sim.codegen.RunLoop` (the simulator's verified build cache; the same operations in
    the same order as the interpreter, so the same bits): the carried state is the custom states, the inputs a
    column of ``U``, the parameters ``p``; each step outputs the custom states after it (none for a plant without
    any: the cogging period's screen) and the predicted motor speed (last row).  ``loop.batch`` runs many
    parameter vectors (a profile's grid) in one call.
    """
    from ..sim.codegen import compile_run_loop

    f = one_step_function(plant, mech)
    c, u, p = f.sx_in()
    c_next, w_next = f(c, u, p)
    sample = ca.Function("onestep_sample", [c, u, p], [c_next, ca.vertcat(c_next, w_next)])
    sample_x = ca.Function("onestep_sample_x", [c, u, p], [c_next])
    loop, _ = compile_run_loop(sample, sample_x)
    return loop


def custom_state_track(plant: Plant, mech: ca.Function, x_measured: np.ndarray, inputs: np.ndarray,
                       periods: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Custom states at every sample, carried by the plant's map from the measured states.

    Parameters
    ----------
    plant : Plant
    mech : casadi.Function
        ``mech(x, v, p, h) -> (x_next, y)``, the current-driven map of ``plant``.
    x_measured : ndarray (nx, n)
        Full state per sample (:func:`measured_state_matrix`); the custom rows
        of column 0 are the initial custom states.
    inputs : ndarray (nv, n)
        The map's inputs per sample (:func:`~thsa_control.fit.replay.mech_inputs`).
    periods : ndarray (n,)
        Sample periods [s].
    p : ndarray
        Parameter vector in ``plant.parameters`` order.

    Returns
    -------
    ndarray (n_custom, n)
        Custom states at the start of each sample period (column 0 is the
        given initial value).
    """
    idx = custom_state_indices(plant)
    X = np.asarray(x_measured, float)
    n = X.shape[1]
    if not idx or n == 0:
        return np.zeros((len(idx), n))
    out = np.empty((len(idx), n))
    out[:, 0] = X[idx, 0]
    if n > 1:
        U = np.vstack([X[:, :-1], inputs[:, :n - 1], np.asarray(periods, float)[None, :n - 1]])
        from ..sim.codegen import NonFiniteOutput

        loop = one_step_loop(plant, mech)
        try:
            if loop is None:
                raise NonFiniteOutput(0, -1)
            out[:, 1:] = loop(X[idx, 0], U, np.asarray(p, float), 1)[0][:-1]
        except NonFiniteOutput:  # no compiler, or a non-finite prediction that stops a compiled run
            out[:, 1:] = np.asarray(one_step_map(plant, mech, n - 1)(X[idx, 0], U, p)[0])
    return out


#: Half-width of the window of the rotor-speed slope [samples].
SLOPE_HALF_WIDTH = 2


def _rotor_rate_sensitivities(plant: Plant, params: ParameterSet) -> tuple[float, float]:
    """``(a_i, a_phi)``: d(rotor acceleration)/d(current), d(rotor acceleration)/d(twist) at rest."""
    x0 = plant.initial_state(params)
    u = np.zeros(len(plant.inputs))
    u[plant.index("input", "enable_primary")] = 1.0
    u[plant.index("input", "temperature")] = 25.0
    xs = ca.SX.sym("x", len(x0))
    i_r = plant.index("state", "rotor_speed")
    jac = ca.Function("rotor_jac", [xs], [ca.jacobian(plant.f(xs, u, plant.p_vector(params))[0][i_r], xs)])
    row = np.asarray(jac(x0)).ravel()
    return float(row[plant.index("state", "motor_current")]), float(row[plant.index("state", "drivetrain_twist")])


def _slope(t: np.ndarray, y: np.ndarray, k: int) -> float | None:
    lo, hi = max(0, k - SLOPE_HALF_WIDTH), min(len(t), k + SLOPE_HALF_WIDTH + 1)
    tt, yy = t[lo:hi], y[lo:hi]
    ok = np.isfinite(yy)
    if ok.sum() < 3:
        return None
    return float(np.polyfit(tt[ok] - tt[ok][0], yy[ok], 1)[0])


def drivetrain_segment_guess(plant: Plant, params: ParameterSet, run: RigRun, starts: np.ndarray, X: np.ndarray,
                             measured_at: Callable[[str, int], float | None]) -> None:
    """Overwrite the compliant drive train's states in ``X`` (states x segments) at the segment ``starts``.

    Does nothing for a plant without ``drivetrain_compliance``.  ``measured_at(name, k)``
    is the measured value of a channel near sample ``k`` (None where not measured).
    """
    names = plant.state_names
    if "rotor_speed" not in names or "drivetrain_twist" not in names:
        return
    i_r, i_w, i_phi = (plant.index("state", n) for n in ("rotor_speed", "motor_speed", "drivetrain_twist"))
    a_i, a_phi = _rotor_rate_sensitivities(plant, params)
    t = np.asarray(run.time, float)
    gear_ratio = run.gear_ratio
    w_rotor = measured_speed(run)
    current = np.asarray(run.signals["motor_current"], float) if "motor_current" in run.source_columns else None
    for m, k in enumerate(starts):
        k = int(min(k, t.size - 1))
        wm = measured_at("motor_speed", k)
        ws = measured_at("screw_speed", k)
        ws = ws * gear_ratio if ws is not None else None
        if wm is not None or ws is not None:
            X[i_r, m] = wm if wm is not None else ws
            X[i_w, m] = ws if ws is not None else wm
        if w_rotor is None or current is None or not np.isfinite(current[k]) or a_phi == 0.0:
            continue
        slope = _slope(t, w_rotor, k)
        if slope is not None:
            X[i_phi, m] = (slope - a_i * float(current[k])) / a_phi
