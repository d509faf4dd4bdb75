"""Starting values of the load-path law read off the runs: the static deflection against the measured load.

The LVDT reads the output rod (the surface when the load path is compliant), the screw's own angle sensor
(RVDT) or the motor sensor the kinematic nut position.  Their difference is the load-path deflection
(relative to the start of the run), and against the measured load it traces the static law of
:func:`~thsa_control.model.laws.loadpath_static_deflection` (the same expression, evaluated here in numpy
through casadi): a soft zone of ``+-b`` where only the disk springs carry the load, or, with ``b < 0``, a
preloaded stiff zone.  Whether the soft zone is ``+0.67 mm`` or a preload of ``-0.03 mm`` is a switch a
least-squares fit started at the file's value cannot cross (no gradient through a contact that never
closes); this screen fits the static curve on a grid of signed soft zones (stiffnesses and an offset by
least squares at each) and gives the best as the candidate fit's start.

The kinematic position is the cumulative sum of the RVDT speed times the sample period (exact when the
RVDT reads the angle difference over one sample, as the rig's does; a first-order rule otherwise),
else of the motor speed through the gear ratio.  Only the parameters the run informs are returned: the
soft zone when the load passes through it (within 500 N of zero and spanning 5 kN), a contact stiffness
when the load presses that contact by more than 2 kN.

Imports numpy, scipy and casadi; no plotting, no file parsing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import casadi as ca
import numpy as np

from ..model.laws import loadpath_static_deflection
from ..model.params import ParameterSet

__all__ = ["deflection_from_runs", "loadpath_static_screen"]

_NAMES = ("loadpath.backlash", "loadpath.contact_stiffness_upper", "loadpath.contact_stiffness_lower",
          "loadpath.disk_spring_stiffness")


def _delta_fn() -> ca.Function:
    f = ca.SX.sym("f")
    ps = ca.SX.sym("p", len(_NAMES))
    p = dict(zip(_NAMES, ca.vertsplit(ps)))
    return ca.Function("delta", [f, ps], [loadpath_static_deflection(p, f)])


def deflection_from_runs(run, params: ParameterSet) -> tuple[np.ndarray, np.ndarray] | None:
    """``(load [N], deflection [m] relative to the first sample)`` of one run, or None when the run lacks the
    LVDT or a speed sensor.  Deflection: kinematic nut position minus the LVDT (positive compressive)."""
    s = run.signals
    if "nut_position" not in run.source_columns:
        return None
    t = np.asarray(run.time, float)
    lead = params.value("screw.lead") if "screw.lead" in params else run.screw_lead
    if "screw_speed" in run.source_columns:
        w = np.asarray(s["screw_speed"], float)
        ratio = lead / (2 * math.pi)
    elif "motor_speed" in run.source_columns:
        w = np.asarray(s["motor_speed"], float)
        ratio = lead / (2 * math.pi * run.gear_ratio)
    else:
        return None
    lvdt = np.asarray(s["nut_position"], float)
    load = np.asarray(s["load_force"], float)
    if not (np.isfinite(w).all() and np.isfinite(lvdt).all() and np.isfinite(load).all()) or t.size < 10:
        return None
    h = np.diff(t)
    kin = np.r_[0.0, np.cumsum(w[1:] * h)] * ratio  # the sample's speed reading covers the period before it
    return load, (kin - lvdt) - (kin[0] - lvdt[0])


def loadpath_static_screen(runs: Sequence, params: ParameterSet, *, soft_zone_points: int = 23,
                           max_samples: int = 2000) -> dict[str, float]:
    """Starting values of the load-path parameters the runs inform (see the module doc); {} when none."""
    from scipy.optimize import least_squares

    data = [d for d in (deflection_from_runs(r, params) for r in runs) if d is not None]
    total = sum(d[0].size for d in data)
    if total > max_samples:  # a static curve: every k-th sample is as good and the screen stays cheap
        k = int(math.ceil(total / max_samples))
        data = [(d[0][::k], d[1][::k]) for d in data]
    if not data:
        return {}
    loads = np.concatenate([d[0] for d in data])
    fmin, fmax = float(np.min(loads)), float(np.max(loads))
    informs = {"loadpath.contact_stiffness_upper": fmax > 2000.0, "loadpath.contact_stiffness_lower": fmin < -2000.0,
               "loadpath.backlash": float(np.min(np.abs(loads))) < 500.0 and fmax - fmin > 5000.0}
    if not any(informs.values()):
        return {}
    delta = _delta_fn()
    kds = params.value("loadpath.disk_spring_stiffness")
    ku0, kl0 = params.value("loadpath.contact_stiffness_upper"), params.value("loadpath.contact_stiffness_lower")
    dmap = delta.map(sum(d[0].size for d in data))
    offsets = np.concatenate([np.full(d[0].size, i) for i, d in enumerate(data)])
    y = np.concatenate([d[1] for d in data])
    n_runs = len(data)

    def resid(z, b):
        ku, kl = math.exp(z[0]) * ku0, math.exp(z[1]) * kl0
        pred = np.asarray(dmap(loads[None, :], np.array([b, ku, kl, kds]))).ravel()
        return (pred + z[2:][offsets] - y) * 1e6  # micrometres

    best = (math.inf, None, None)
    b_lo, b_hi = max(params["loadpath.backlash"].min, -0.5e-3), min(params["loadpath.backlash"].max, 2.0e-3)
    for b in np.linspace(b_lo, b_hi, soft_zone_points):
        z0 = np.r_[0.0, 0.0, np.zeros(n_runs)]
        r = least_squares(resid, z0, args=(b,), bounds=(np.r_[-3.0, -3.0, np.full(n_runs, -np.inf)],
                                                        np.r_[3.0, 3.0, np.full(n_runs, np.inf)]), max_nfev=50)
        if r.cost < best[0]:
            best = (r.cost, b, r.x)
    _, b, z = best
    if z is None:
        return {}
    # refine the soft zone around the best grid value
    step = (b_hi - b_lo) / (soft_zone_points - 1)
    for bb in np.linspace(max(b_lo, b - step), min(b_hi, b + step), 9):
        r = least_squares(resid, z, args=(bb,), bounds=(np.r_[-3.0, -3.0, np.full(n_runs, -np.inf)],
                                                        np.r_[3.0, 3.0, np.full(n_runs, np.inf)]), max_nfev=50)
        if r.cost < best[0]:
            best = (r.cost, bb, r.x)
    _, b, z = best
    out = {"loadpath.backlash": float(b), "loadpath.contact_stiffness_upper": float(math.exp(z[0]) * ku0),
           "loadpath.contact_stiffness_lower": float(math.exp(z[1]) * kl0)}
    return {n: v for n, v in out.items() if informs[n]}
