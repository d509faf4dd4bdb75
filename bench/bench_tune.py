"""Tuning benchmark (issue #9): the cold tuning timed on one core, against scipy.optimize on finite differences.

The problem is the one that wrote ``designs/cold.toml``: the velocity PI gains
on the runs cold_ramp, low_speed, load_step, reversal at -30 degC (level B,
two-rotor plant), peak-current and overshoot constraints also on the same
runs at level D at -55 and 25 degC, margin constraints at -55, -30, 25 and
70 degC.

* **this project**: ``thsa_control.tuning.optimize.tune`` (casadi nlpsol /
  IPOPT, gradients by casadi forward sensitivities through the compiled
  simulator step), both starts, and the exact checks at the end.
* **scipy**: ``scipy.optimize.minimize(method="SLSQP")`` from the nominal
  gains on the same objective and constraints (same variables, same compiled
  value-only simulations), gradients by scipy's finite differences: the way
  most users would do it.

Printed: total times, time per objective evaluation and per objective +
gradient evaluation, evaluation counts, the optima reached, and the ratios.
Target of the issue: the cold tuning under 120 s on one core.  The ratio is printed only when both
optimisers converged and reached the same gains (5e-3 relative); otherwise, or when the target is not
met, the script exits 1.

Run: ``python bench/bench_tune.py``.
"""

from __future__ import annotations

import math
import os
import sys
import time

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")  # one core
sys.stdout.reconfigure(line_buffering=True)

import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.model import build_plant  # noqa: E402
from thsa_control.sim.simulate import Simulator  # noqa: E402
from thsa_control.tuning.objective import Objective, ObjectiveSettings, gains_of  # noqa: E402
from thsa_control.tuning.optimize import TuneSettings, tune  # noqa: E402
from thsa_control.tuning.robust import RobustConstraints  # noqa: E402
from thsa_control.tuning.validation import get_validation_scenario  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _compare import Comparisons, Side  # noqa: E402

RUNS = ("cold_ramp", "low_speed", "load_step", "reversal")


def main() -> int:
    cmp = Comparisons()
    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    scen = [get_validation_scenario(n) for n in RUNS]
    osettings = ObjectiveSettings(overshoot_limit=0.09)
    settings = TuneSettings(objective=osettings, progress=False)

    t0 = time.perf_counter()
    res = tune(design, params, scen, settings)
    t_tune = time.perf_counter() - t0
    ev = res.evaluations
    n_grad = ev["gradient"] + ev.get("constraint_runs", {}).get("gradient", 0)
    t_grad = ev["gradient_s"] + ev.get("constraint_runs", {}).get("gradient_s", 0.0)
    print(f"thsa tune (IPOPT, casadi AD), {len(res.starts)} starts + checks: {t_tune:.1f} s "
          f"(target < 120 s); starts: " + "; ".join(f"{r.start}: {r.status}, {r.iterations} it, {r.wall_s:.1f} s"
                                                     for r in res.starts))
    print(f"  optimum gains {np.round(res.best.gains, 5).tolist()}, J/J0 = {res.best.objective:.6f}, "
          f"objective {100 * res.reduction:.1f} % lower")
    print(f"  value + gradient evaluations: {ev['gradient']}, {t_grad / max(ev['gradient'], 1) * 1e3:.1f} ms each "
          f"(objective runs and constraint runs; {n_grad} run-set sweeps)")

    # ---- the same problem for scipy: value-only simulations, finite differences
    plant = build_plant(settings.level, settings.effects, params=params)
    obj = Objective(Simulator(plant), params, design, [s.with_temperature(-30.0) for s in scen], settings=osettings)
    cplant = build_plant("D", settings.effects, params=params)
    extra = Objective(Simulator(cplant), params, design, [s.with_temperature(t) for t in (-55.0, 25.0) for s in scen],
                      settings=osettings)
    robust = RobustConstraints(design, params, settings.robust_temperatures)
    g0 = gains_of(design, obj.tuned)
    w = osettings.weights
    J0 = obj.value(g0)
    cache = {}

    def evaluate(q):
        k = np.asarray(q).tobytes()
        if k not in cache:
            g = g0 * np.exp(q)
            T, Tx = obj.terms(g), extra.terms(g)
            ex = T[:, 3:].sum(axis=0) + Tx[:, 3:].sum(axis=0)
            cache[k] = (float(np.sum(T @ w)) / J0, ex)
        return cache[k]

    t_val = []

    def f(q):
        t = time.perf_counter()
        v = evaluate(q)[0]
        t_val.append(time.perf_counter() - t)
        return v

    def g_ex(q):
        return math.sqrt(2.0) - np.sqrt(1.0 + evaluate(q)[1] / settings.excess_tolerance)

    def g_rob(q):
        g = g0 * np.exp(q)
        return robust.values(g[0], g[1])

    lb = math.log(1.0 / settings.bound_factor)
    t0 = time.perf_counter()
    sp = scipy.optimize.minimize(f, np.zeros(2), method="SLSQP", bounds=[(lb, -lb)] * 2,
                                 constraints=[{"type": "ineq", "fun": g_ex}, {"type": "ineq", "fun": g_rob}],
                                 options={"maxiter": 100, "ftol": 1e-9})
    t_scipy = time.perf_counter() - t0
    g_sp = g0 * np.exp(sp.x)
    n_sim = len(cache)
    print(f"scipy SLSQP on finite differences, one start: {t_scipy:.1f} s, {sp.nit} iterations, {n_sim} simulations of "
          f"the run set, status '{sp.message}'")
    print(f"  optimum gains {np.round(g_sp, 5).tolist()}, J/J0 = {sp.fun:.6f}, constraints min "
          f"{min(np.min(g_ex(sp.x)), g_rob(sp.x).min()):.3g}")
    per_val = (ev["value_s"] + ev.get("constraint_runs", {}).get("value_s", 0.0)) / max(ev["value"], 1)
    print(f"time per objective evaluation (objective + constraint runs, value only): "
          f"{np.mean(t_val) * 1e3 if t_val else per_val * 1e3:.1f} ms; per value + AD gradient: "
          f"{t_grad / max(ev['gradient'], 1) * 1e3:.1f} ms")
    # the ratio only when both sides converged to the same optimum
    first = res.starts[0]
    ours = Side("IPOPT-AD (one start from the nominal gains)", bool(first.success), np.asarray(first.gains, float), first.wall_s,
                f"IPOPT status {first.status}")
    theirs = Side("scipy SLSQP-FD", bool(sp.success), g_sp, t_scipy, f"scipy status '{sp.message}'")

    def agree(a, b):
        d = float(np.max(np.abs(b / a - 1)))
        return f"largest relative gain difference {d:.2g}", d <= 5e-3

    cmp.compare("scipy-FD vs IPOPT-AD, same problem, one start", ours, theirs, agree=agree,
                tolerance="5e-3 relative on each gain")
    if t_tune < 120.0:
        print(f"target cold tuning < 120 s on one core: met ({t_tune:.1f} s)")
    else:
        cmp.fail(f"target cold tuning < 120 s on one core: NOT met ({t_tune:.1f} s)")
    return cmp.exit_code()


if __name__ == "__main__":
    sys.exit(main())
