"""The measured current at one operating point at different times (a torque constant drifting with the rotor's
temperature), from the records alone: a measurement for docs/trace_notes.md, not a tracer test.

``python bench/kt_current_drift.py RUN.csv [RUN.csv ...]`` prints per run the steady passes (moving, constant speed
command, outside the base's transients), each pass's current level and slope in time with its IACT-corrected standard
error, the F test of the slopes against a level per pass, and the torque constant's own law: one relative rate
(slope / level) shared by the passes (inverse-variance weighted, two-sided normal p).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from scipy.stats import f as f_dist
from scipy.stats import norm

from thsa_control.data.rigdata import read_run
from thsa_control.trace.signature import _effective_n_iact, base_transients


def current_drift(path) -> dict | None:
    run = read_run(Path(path))
    t = np.asarray(run.time, float)
    w = np.nan_to_num(run.measured_motor_speed())
    load = np.asarray(run.signals["load_force"], float)
    i = np.asarray(run.signals["motor_current"], float)
    cmd = np.asarray(run.signals["speed_cmd"], float)
    steady = ~base_transients(t, w, load, 0.3, sustained=True)
    sgn = np.sign(np.where(np.abs(w) > 0.05 * np.max(np.abs(w)), w, 0.0))
    ok = steady & (sgn != 0) & ~(np.r_[0.0, np.abs(np.diff(cmd))] > 0)
    idx = np.flatnonzero(ok)
    parts = [q for q in np.split(idx, np.flatnonzero((np.diff(idx) > 1) | (np.diff(sgn[idx]) != 0)) + 1)
             if q.size and t[q[-1]] - t[q[0]] > 0.5]
    if not parts:
        return None
    n, k = sum(q.size for q in parts), len(parts)
    x0, x1, y = np.zeros((n, k)), np.zeros((n, k)), np.zeros(n)
    row = 0
    for j, q in enumerate(parts):
        x0[row:row + q.size, j] = 1.0
        x1[row:row + q.size, j] = t[q] - t[q].mean()
        y[row:row + q.size] = i[q]
        row += q.size
    c0 = np.linalg.lstsq(x0, y, rcond=None)[0]
    full = np.column_stack([x0, x1])
    c1 = np.linalg.lstsq(full, y, rcond=None)[0]
    r0, r1 = y - x0 @ c0, y - full @ c1
    tau = max(n / _effective_n_iact(r1), 1.0)
    F = ((r0 @ r0 - r1 @ r1) / k) / (r1 @ r1 / (n - 2 * k)) / tau
    p = float(f_dist.sf(F, k, n / tau - 2 * k))
    se = np.array([math.sqrt(r1 @ r1 / (n - 2 * k) * tau / (x1[:, j] @ x1[:, j])) for j in range(k)])
    level, slope = c1[:k], c1[k:]
    rel, rel_se = slope / level, se / np.abs(level)
    wt = 1.0 / rel_se**2
    shared, shared_se = float(wt @ rel / wt.sum()), float(1.0 / math.sqrt(wt.sum()))
    return {"passes": [(float(t[q[0]]), float(t[q[-1]])) for q in parts], "level": level, "slope": slope, "se": se,
            "rel": rel, "rel_se": rel_se, "p": p, "iact": tau, "shared": shared, "shared_se": shared_se,
            "shared_p": float(2 * norm.sf(abs(shared / shared_se)))}


def main(paths: list[str]) -> int:
    for p in paths:
        d = current_drift(p)
        if d is None:
            print(f"{Path(p).stem:<40} no steady pass of 0.5 s")
            continue
        print(f"{Path(p).stem:<40} p {d['p']:.2g} (IACT {d['iact']:.1f}); shared relative rate "
              f"{1e3 * d['shared']:.2f}e-3 +- {1e3 * d['shared_se']:.2f}e-3 /s, p {d['shared_p']:.2g}")
        for (a, b), lv, sl, se, r, rs in zip(d["passes"], d["level"], d["slope"], d["se"], d["rel"], d["rel_se"]):
            print(f"    {a:5.2f}-{b:5.2f} s: {lv:6.2f} A, {1e3 * sl:6.1f} +- {1e3 * se:.1f} mA/s, "
                  f"relative {1e3 * r:6.2f}e-3 +- {1e3 * rs:.2f}e-3 /s")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
