"""Initial guesses of the segment states of a compliant drive train (``drivetrain_compliance``).

With ``drivetrain_compliance`` the plant has two bodies joined by the
drive-train spring: the motor rotors (state ``rotor_speed``, read by the
motor-speed sensor) and the gear output (state ``motor_speed``, read by the
screw-speed sensor through the gear ratio), and the spring's ``drivetrain_twist``.
Multiple shooting (:mod:`thsa_control.fit.identify`) frees all three per
segment; this module only gives them a starting point from the data:

* ``rotor_speed``: the measured motor speed (else ratio x screw speed);
* gear-output ``motor_speed``: ratio x the measured screw speed (else the
  motor speed: the rigid guess);
* ``drivetrain_twist``: quasi-static, from the rotors' own balance
  ``d(rotor_speed)/dt = a_i i + a_phi phi`` with ``a_i = Kt / J_r`` and
  ``a_phi = -k / J_r`` taken from the plant's own right-hand side (its
  Jacobian at rest: no second copy of the physics), ``i`` the measured
  current and ``d(rotor_speed)/dt`` the slope of a straight line through the
  measured rotor speed around the segment start.  Drag and damping are
  neglected in the guess; the fit frees the twist anyway.

Imports casadi and numpy only.
"""

from __future__ import annotations

from collections.abc import Callable

import casadi as ca
import numpy as np

from ..model.params import ParameterSet
from ..model.plant import Plant

__all__ = ["drivetrain_segment_guess"]

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


def drivetrain_segment_guess(plant: Plant, params: ParameterSet, time: np.ndarray, signals, source_columns,
                             gear_ratio: float, starts: np.ndarray, X: np.ndarray,
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
    t = np.asarray(time, float)
    if "motor_speed" in source_columns:
        w_rotor = np.asarray(signals["motor_speed"], float)
    elif "screw_speed" in source_columns:
        w_rotor = np.asarray(signals["screw_speed"], float) * gear_ratio
    else:
        w_rotor = None
    current = np.asarray(signals["motor_current"], float) if "motor_current" in source_columns else None
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
