"""Tuning benchmark (issues #9, #20): the README's tune, and the same optimisation with scipy on finite differences.

The problem is the README's: ``thsa tune --design designs/nominal.toml --scenario cold_ramp --temperature -30``:
the velocity PI gains on cold_ramp at -30 degC (level B, two-rotor plant), every velocity-loop requirement
as a smooth constraint over the design's analysis grid (phase, |gain| and delay margins, Ms, bandwidth,
step overshoot and settling), the current-clamp and overshoot constraints on the validation suite at level D
at -55 degC, then the verdict of ``thsa check`` on every requirement.

* **this project**: ``thsa_control.tuning.optimize.tune`` (casadi nlpsol / IPOPT, gradients by casadi
  forward sensitivities through the compiled simulator step), both starts, the rounds and the verdict.
* **scipy**: ``scipy.optimize.minimize(method="SLSQP")`` from the nominal gains on the same objective and
  constraints of round 1 (same variables, same compiled value-only simulations, same constraint functions),
  gradients by scipy's finite differences: the way most users would do it.

Printed: total times, time per objective evaluation and per objective + gradient evaluation, evaluation
counts, the optima reached, and the ratio of one start each.  Target: the tune under 60 s on 2 cores.
The ratio is printed only when both optimisers converged to the same gains (5e-3 relative, ``_compare``);
exit status 1 when a side fails (tune raises, scipy ends infeasible or unconverged), when the casadi gradient
is not faster than scipy's finite differences, or when the target is not met.

Run: ``python bench/bench_tune.py``.
"""

from __future__ import annotations

import math
import os
import sys
import time

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")  # the process uses one core; the machine has two
sys.stdout.reconfigure(line_buffering=True)

import numpy as np  # noqa: E402
import scipy.optimize  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.model import build_plant  # noqa: E402
from thsa_control.sim.simulate import Simulator  # noqa: E402
from thsa_control.tuning.objective import Objective, gains_of  # noqa: E402
from thsa_control.tuning.optimize import TuneSettings, linear_temperatures, objective_settings_for, tune  # noqa: E402
from thsa_control.tuning.robust import RobustConstraints  # noqa: E402
from thsa_control.tuning.validation import VALIDATION_SUITE, get_validation_scenario  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _compare import Comparisons, Side  # noqa: E402

RUNS = ("cold_ramp",)
TARGET_S = 60.0


def main() -> int:
    cmp = Comparisons()
    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    scen = [get_validation_scenario(n) for n in RUNS]
    suite = [get_validation_scenario(n) for n in VALIDATION_SUITE]
    osettings = objective_settings_for(design)
    settings = TuneSettings(objective=osettings, progress=False)

    t0 = time.perf_counter()
    try:
        res = tune(design, params, scen, settings)
    except Exception as exc:  # noqa: BLE001 - a failed side is reported and fails the benchmark
        cmp.fail(f"thsa tune raised {type(exc).__name__}: {exc}")
        return cmp.exit_code()
    t_tune = time.perf_counter() - t0
    ev = res.evaluations
    n_grad = ev["gradient"] + ev.get("constraint_runs", {}).get("gradient", 0)
    t_grad = ev["gradient_s"] + ev.get("constraint_runs", {}).get("gradient_s", 0.0)
    print(f"thsa tune (IPOPT, casadi AD), {len(res.starts)} solves in {len(res.rounds)} round(s) + the verdict "
          f"({'PASS' if res.verdict.passed else 'FAIL'}): {t_tune:.1f} s (target < 60 s on 2 cores); starts: " + "; ".join(f"{r.start}: {r.status}, {r.iterations} it, {r.wall_s:.1f} s"
                                                     for r in res.starts))
    print(f"  optimum gains {np.round(res.best.gains, 5).tolist()}, J/J0 = {res.best.objective:.6f}, "
          f"objective {100 * res.reduction:.1f} % lower")
    print(f"  value + gradient evaluations: {ev['gradient']}, {t_grad / max(ev['gradient'], 1) * 1e3:.1f} ms each "
          f"(objective runs and constraint runs; {n_grad} run-set sweeps)")

    # ---- the same problem for scipy: value-only simulations, finite differences
    plant = build_plant(settings.level, settings.effects, params=params)
    obj = Objective(Simulator(plant), params, design, [s.with_temperature(-30.0) for s in scen], settings=osettings)
    cplant = build_plant("D", settings.effects, params=params)
    extra = Objective(Simulator(cplant), params, design, [s.with_temperature(t) for t in (-55.0,) for s in suite],
                      settings=osettings)
    robust = RobustConstraints(design, params, linear_temperatures(design, settings))
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
    # the ratio only when both sides converged to the same feasible optimum
    feasible = min(np.min(g_ex(sp.x)), g_rob(sp.x).min()) >= -1e-6
    first = res.starts[0]
    ours = Side("IPOPT-AD (one start from the nominal gains)", bool(first.success), np.asarray(first.gains, float),
                first.wall_s, f"IPOPT status {first.status}")
    theirs = Side("scipy SLSQP-FD", bool(sp.success and feasible), g_sp, t_scipy,
                  f"scipy status '{sp.message}'" + ("" if feasible else ", constraints violated"))

    def agree(a, b):
        d = float(np.max(np.abs(b / a - 1)))
        return f"largest relative gain difference {d:.2g}", d <= 5e-3

    ratio = cmp.compare("scipy-FD vs IPOPT-AD, same problem, one start", ours, theirs, agree=agree,
                        tolerance="5e-3 relative on each gain")
    if ratio is not None and not ratio > 1.0:
        cmp.fail(f"the casadi-gradient start was not faster than scipy on finite differences (ratio {ratio:.2f})")
    if t_tune < TARGET_S:
        print(f"target tune < {TARGET_S:g} s on 2 cores: met ({t_tune:.1f} s)")
    else:
        cmp.fail(f"target tune < {TARGET_S:g} s on 2 cores: NOT met ({t_tune:.1f} s; load average "
                 f"{os.getloadavg()[0]:.1f} on this machine)")
    return cmp.exit_code()


if __name__ == "__main__":
    sys.exit(main())
