"""Simulator benchmark (issue #2): prints ratios measured in one run, on one core.

* real-time factor of 10 s of ``backdrive_bipolar_ramp`` at level D, closed loop;
* level A: the project's simulator against python-control's
  ``input_output_response`` (default solver RK45, and LSODA) on an equivalent
  ``NonlinearIOSystem`` (the same casadi plant right-hand side, the same PI
  cascade in continuous time, the shaped command as input), both producing
  1 kHz output;
* compile time, and what a second process pays with the cache.

Run: ``python bench/bench_simulate.py``  (``--quick`` skips python-control).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.stdout.reconfigure(line_buffering=True)

import numpy as np  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.loops.controllers import CONTROLLER_PARAMETERS  # noqa: E402


def best_of(fn, n=5):
    times = []
    for _ in range(n):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def equivalent_nlsys(plant, params, design):
    """Closed loop in continuous time as one python-control NonlinearIOSystem."""
    import control as ct

    p = plant.p_vector(params)
    k = dict(zip(CONTROLLER_PARAMETERS, design.controller_vector(params, accel_limit=1.0)))
    f = plant.f
    nx = len(plant.states)
    iw, ii = plant.index("state", "motor_speed"), plant.index("state", "motor_current")
    r = k["nut_per_motor_rad"]

    def clamp(v, lim):
        return min(max(v, -lim), lim)

    def upd(t, x, u, params_):
        xp, vi, ci = x[:nx], x[nx], x[nx + 1]
        cmd, load, temp = u
        on = cmd != 0.0
        e_w = cmd / r - xp[iw]
        i_un = k["velocity_kp"] * e_w + vi
        i_ref = clamp(i_un, k["current_limit"]) if on else 0.0
        e_i = i_ref - xp[ii]
        v_un = k["current_kp"] * e_i + ci
        v = clamp(v_un, k["voltage_limit"]) if on else 0.0
        dvi = k["velocity_ki"] * e_w if on and not (abs(i_un) >= k["current_limit"] and e_w * i_un > 0) else 0.0
        dci = k["current_ki"] * e_i if on and not (abs(v_un) >= k["voltage_limit"] and e_i * v_un > 0) else 0.0
        if not on:
            dvi, dci = -vi / 1e-3, -ci / 1e-3  # reset quickly while off
        uu = np.array([v, 0.0, 1.0 if on else 0.0, 0.0, load, temp])
        xdot = np.asarray(f(xp, uu, p)[0]).ravel()
        return np.concatenate([xdot, [dvi, dci]])

    def out(t, x, u, params_):
        return x[:nx]

    return ct.nlsys(upd, out, states=nx + 2, inputs=["speed_cmd", "load_force", "temperature"],
                    outputs=list(plant.state_names), name="thsa_closed_loop")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true", help="skip python-control")
    ap.add_argument("--cap", type=float, default=600.0, help="time cap for each python-control run [s] (0: none)")
    ap.add_argument("--python-control", dest="pc_method", help=argparse.SUPPRESS)
    ap.add_argument("--horizon", type=float, default=10.0, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.pc_method:
        python_control_run(args.pc_method, args.horizon)
        return
    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    scenario = thsa.get_scenario("backdrive_bipolar_ramp")

    # compile time with an empty cache, then a second process with the cache
    with tempfile.TemporaryDirectory() as cache:
        os.environ["THSA_CACHE_DIR"] = cache
        sim_d = thsa.Simulator(thsa.build_plant("D"))
        t0 = time.perf_counter()
        sim_d.run(scenario, design, params)
        first = time.perf_counter() - t0
        info = sim_d._loop()[1]
        code = ("import time,thsa_control as t;P=t.default_parameters();d=t.load_design(t.nominal_design_path());"
                "s=t.Simulator(t.build_plant('D'));t0=time.perf_counter();s.run(t.get_scenario('backdrive_bipolar_ramp'),d,P);"
                "print(time.perf_counter()-t0, s._loop()[1]['cached'])")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=dict(os.environ)).stdout.split()
        print(f"compile (empty cache): codegen {info['codegen_s']*1e3:.0f} ms + C compiler {info['compile_s']:.2f} s; "
              f"first run incl. build {first:.2f} s")
        print(f"second process: first run incl. build {float(out[0]):.3f} s (library from cache: {out[1]})")
    del os.environ["THSA_CACHE_DIR"]

    sim_d = thsa.Simulator(thsa.build_plant("D"))
    sim_d.run(scenario, design, params)
    t_d = best_of(lambda: sim_d.run(scenario, design, params))
    print(f"level D, 10 s backdrive_bipolar_ramp closed loop at 10 kHz: {t_d*1e3:.1f} ms -> {10.0/t_d:.0f}x faster than real time (target >= 300x)")

    plant_a = thsa.build_plant("A")
    sim_a = thsa.Simulator(plant_a)
    sim_a.run(scenario, design, params)  # warm-up (build and load the compiled loop)
    t_a = best_of(lambda: sim_a.run(scenario, design, params))
    print(f"level A, same scenario: {t_a*1e3:.1f} ms ({10.0/t_a:.0f}x real time)")
    if args.quick:
        return
    # the whole scenario, and its first 4 s (before the first trim stop, where level A, having
    # no no-back, back-drives and re-energising makes the problem stiff and discontinuous)
    first_4s = dataclasses.replace(scenario, duration=4.0)
    t_a4 = best_of(lambda: sim_a.run(first_4s, design, params))
    for method, horizon, t_ours in (("RK45", 10.0, t_a), ("LSODA", 10.0, t_a), ("RK45", 4.0, t_a4), ("LSODA", 4.0, t_a4)):
        try:
            proc = subprocess.run([sys.executable, __file__, "--python-control", method, "--horizon", str(horizon)],
                                  capture_output=True, text=True, timeout=None if args.cap <= 0 else args.cap)
            line = proc.stdout.strip().splitlines()[-1] if proc.stdout.strip() else ""
            err = proc.stderr.strip()[-200:]
        except subprocess.TimeoutExpired:
            line, err = "", "(killed at the cap; it includes about 1 s of start-up)"
        if line.startswith("RESULT"):
            _, t_ct, dev = line.split()
            t_ct, dev = float(t_ct), float(dev)
            print(f"0-{horizon:g} s, python-control input_output_response ({method}{', default' if method == 'RK45' else ''}): "
                  f"{t_ct:.3g} s vs {t_ours * 1e3:.1f} ms -> project simulator {t_ct / t_ours:.0f}x faster "
                  f"(targets: >= 50x vs default, > 1x vs LSODA); motor speed agrees to {100 * dev:.3g} % of its peak "
                  f"over 0-4 s (continuous vs 10 kHz sampled control)", flush=True)
        else:
            print(f"0-{horizon:g} s, python-control input_output_response ({method}): not finished within the "
                  f"{args.cap:.0f} s cap -> project simulator more than {args.cap / t_ours:.0f}x faster {err}", flush=True)


def python_control_run(method: str, horizon: float) -> None:
    """Child process: time python-control on the equivalent system, print RESULT <seconds> <deviation>."""
    import control as ct

    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    plant_a = thsa.build_plant("A")
    sc = thsa.get_scenario("backdrive_bipolar_ramp")
    res_a = thsa.Simulator(plant_a).run(dataclasses.replace(sc, duration=horizon), design, params)
    sys_cl = equivalent_nlsys(plant_a, params, design)
    T = np.asarray(res_a.time)
    U = np.vstack([res_a["speed_cmd"], res_a["load_force"], res_a["temperature"]])
    X0 = np.concatenate([plant_a.initial_state(params), [0.0, 0.0]])
    iw = plant_a.index("state", "motor_speed")
    t0 = time.perf_counter()
    resp = ct.input_output_response(sys_cl, T, U, X0, solve_ivp_method=method)
    t_ct = time.perf_counter() - t0
    m = T < 4.0
    dev = np.max(np.abs(resp.outputs[iw][m] - res_a["motor_speed"][m])) / np.max(np.abs(res_a["motor_speed"][m]))
    print(f"RESULT {t_ct} {dev}", flush=True)

if __name__ == "__main__":
    main()
