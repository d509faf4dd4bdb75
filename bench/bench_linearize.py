"""Linear-analysis benchmark (issue #3): prints times and ratios measured in one run, on one core.

Grid: 8 temperatures x 8 trim speeds x 5 loads = 320 operating points of
level B + ``temperature_friction``.  For every point and each of the three
loops (current, velocity, position): operating point, linearisation (with
the finite-difference cross-check and kink detection), zero-order-hold
discretisation, 500-frequency Bode data and the margins (gain, phase, delay,
Ms, bandwidth).

* **this project**: ``thsa_control.loops.analysis.analyse_loops(..., steps=False)``:
  one mapped Newton solve, one ``linearize_batch`` call, batched ZOH,
  frequency responses and margins on arrays.
* **python-control, looped**: per point, ``ct.linearize`` of the plant as a
  ``NonlinearIOSystem`` (``Plant.to_nlsys``) at the same operating point,
  the same three discrete loops built with ``ct.c2d``/``ct.series``/
  ``ct.feedback`` on ``StateSpace`` objects and ``ct.frequency_response`` at
  the same 500 frequencies (the issue's reference); then, separately,
  ``ct.stability_margins`` on that frequency data.

The ratio is printed only when python-control finished and its loop responses agree with ours at every
point, loop and frequency measured (``LOOP_TOLERANCE``); a failed side, a disagreement or an unmet
target exits 1.

Run: ``python bench/bench_linearize.py`` (``--quick``: python-control on 40 points, scaled to 320).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(var, "1")  # one core
sys.stdout.reconfigure(line_buffering=True)

import control as ct  # noqa: E402
import numpy as np  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.loops.analysis import AnalysisSettings, analyse_loops  # noqa: E402
from thsa_control.loops.linear import ConditionGrid, operating_points, plant_model  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _compare import Comparisons, Side  # noqa: E402

TEMPERATURES = tuple(np.linspace(-55.0, 70.0, 8))
SPEEDS = tuple(v * 1e-3 for v in (0.5, 1.0, 2.0, 3.0, 5.0, 8.0, 11.0, 15.0))
LOADS = (-55e3, -20e3, 0.0, 20e3, 55e3)
#: agreement of python-control's loop responses with ours (relative, every frequency, loop and point)
LOOP_TOLERANCE = 1e-3


def python_control_loop(nlsys, points, design, r, omega):
    """Per point: ct.linearize + the three loops + ct.frequency_response; returns (seconds, margins seconds)."""
    h = design.control_period
    z1 = ct.ss([[1.0]], [[1.0]], [[1.0]], [[0.0]], h)  # 1 / (z - 1)

    def pi(kp, ki):
        return ct.parallel(ct.ss([], [], [], [[kp]], h), ki * h * z1)

    Kc, Kv = pi(design.current_kp, design.current_ki), pi(design.velocity_kp, design.velocity_ki)
    Kx = ct.ss([[0.0]], [[1.0]], [[design.position_kp / r]], [[0.0]], h)
    outs = list(nlsys.output_labels)
    sel = [outs.index("motor_current"), outs.index("motor_speed"), outs.index("nut_position")]
    iv = list(nlsys.input_labels).index("voltage_primary")
    t_margins = 0.0
    responses = []
    t0 = time.perf_counter()
    for x0, u0 in points:
        lin = ct.linearize(nlsys, x0, u0)
        P = ct.c2d(ct.ss(lin.A, lin.B[:, iv:iv + 1], lin.C[sel], np.zeros((3, 1))), h, "zoh")
        RL = ct.c2d(ct.ss(lin.A[:1, :1], lin.B[:1, iv:iv + 1], [[1.0]], [[0.0]]), h, "zoh")
        Pc = ct.feedback(ct.series(Kc, P), ct.ss([], [], [], [[1.0, 0.0, 0.0]], h))
        Pv = ct.feedback(ct.series(Kv, Pc), ct.ss([], [], [], [[0.0, 1.0, 0.0]], h))
        loops = (ct.series(Kc, RL), ct.series(Kv, Pc[1, 0]), ct.series(Kx, Pv[2, 0]))
        resp = [ct.frequency_response(L, omega) for L in loops]
        responses.append(resp)
        tm = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for rsp in resp:
                ct.stability_margins((rsp.magnitude.ravel(), np.degrees(np.unwrap(rsp.phase.ravel())), omega))
        t_margins += time.perf_counter() - tm
    total = time.perf_counter() - t0
    return total - t_margins, t_margins, responses


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="python-control on 40 points only, scaled to 320")
    args = ap.parse_args(argv)
    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    settings = AnalysisSettings(level="B", effects=("temperature_friction",), nut_speeds=SPEEDS, load_forces=LOADS,
                                temperatures=TEMPERATURES, n_frequencies=500)
    grid = ConditionGrid(SPEEDS, LOADS, TEMPERATURES)
    n = len(grid)
    print(f"grid: {len(TEMPERATURES)} temperatures x {len(SPEEDS)} speeds x {len(LOADS)} loads = {n} points, "
          f"level B + temperature_friction, 500 frequencies, 3 loops")

    # --- this project: cold (first call builds and maps the casadi Functions), then warm
    t0 = time.perf_counter()
    model = plant_model("B", ("temperature_friction",), params)
    a = analyse_loops(design, params, grid, settings=settings, model=model, steps=False)
    cold = time.perf_counter() - t0
    warm = []
    for _ in range(3):
        t0 = time.perf_counter()
        a = analyse_loops(design, params, grid, settings=settings, model=model, steps=False)
        warm.append(time.perf_counter() - t0)
    t0 = time.perf_counter()
    analyse_loops(design, params, grid, settings=settings, model=model, steps=True)
    with_steps = time.perf_counter() - t0
    ours = min(warm)
    print(f"thsa analyse_loops: {ours:.3f} s warm (best of 3), {cold:.3f} s cold incl. building the model; "
          f"{with_steps:.3f} s with step and load-step responses")
    print(f"  valid points {int(a.valid.sum())}/{n}; L arrays {a.loops['velocity_loop'].margins.L.shape}")

    # --- python-control, looped over the same points (same operating points: ours)
    ops = operating_points(model, grid)
    plant = thsa.build_plant("B", ("temperature_friction",), params=params)
    nlsys = plant.to_nlsys(params)
    points = []
    for k, c in enumerate(grid.conditions()):
        x = ops.X[:, k]
        u = np.zeros(len(plant.inputs))  # plant inputs by name; fault inputs healthy (0)
        for name, value in (("voltage_primary", ops.U[0, k]), ("enable_primary", 1.0), ("load_force", c.load_force),
                            ("temperature", c.temperature)):
            u[plant.index("input", name)] = value
        points.append((x, u))
    m = 40 if args.quick else n
    omega = a.loops["velocity_loop"].margins.omega
    cmp = Comparisons()
    theirs = cmp.side("python-control looped",
                      lambda: python_control_loop(nlsys, points[:m], design, model.kinematic_ratio, omega))
    scale = n / m
    note = f" (measured on {m} points, scaled x{scale:g})" if m < n else ""
    if theirs.ok:
        t_lin_fr, t_marg, responses = theirs.value
        theirs = Side(theirs.name, True, responses, t_lin_fr * scale)
        base_all = (t_lin_fr + t_marg) * scale
        print(f"python-control looped: linearize + 3 loops + frequency_response {theirs.seconds:.2f} s, "
              f"+ stability_margins {base_all:.2f} s{note}")
    ours_side = Side("thsa analyse_loops", True, a, ours)

    def agree(res, responses):
        # the same Bode data: every loop at every point measured (python-control linearises by one-sided
        # finite differences, so a small relative difference remains)
        worst = 0.0
        for k, resp in enumerate(responses):
            if not res.valid[k]:
                continue
            for j, loop in enumerate(("current_loop", "velocity_loop", "position_loop")):
                L = resp[j].complex.ravel()
                worst = max(worst, float(np.max(np.abs(L - res.loops[loop].margins.L[k]) / np.abs(L))))
        return f"largest relative difference of the 3 loop responses over {len(responses)} points {worst:.1e}", \
            worst <= LOOP_TOLERANCE

    ratio = cmp.compare("python-control (linearize + frequency_response) vs thsa", ours_side, theirs, agree=agree,
                        tolerance=f"{LOOP_TOLERANCE:g} relative")
    if ratio is not None:
        print(f"  ratio {ratio:.0f}x (target >= 20x); including margins: {base_all / ours:.0f}x")
        if ratio < 20:
            cmp.fail(f"target ratio >= 20x: NOT met ({ratio:.1f}x)")
    if ours < 2.0:
        print(f"target < 2 s on one core: met ({ours:.3f} s)")
    else:
        cmp.fail(f"target < 2 s on one core: NOT met ({ours:.3f} s)")
    return cmp.exit_code()


if __name__ == "__main__":
    sys.exit(main())
