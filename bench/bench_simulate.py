"""Simulator benchmark (issues #2, #17): every comparison runs both sides in this process, on the same
scenario, checks both finished and agree, and only then prints a ratio; otherwise it says why and the
script exits 1.

* Level A and level D, 10 s of ``backdrive_bipolar_ramp`` in closed loop at 10 kHz (1 kHz output):
  real-time factor of this code against the same runs of the code *before the speed-up* (the package at
  ``--baseline``, a git commit, unpacked with ``git archive`` and imported in this process as a second
  package); agreement: the two must give the same bits.
* Batched: level-D runs (2 scenarios of 10 s x 4 parameter sets) in one ``Simulator.run_batch`` call over
  the CPUs, simulated seconds per wall second next to the single-run figure; agreement: each batched run
  has the bits of its single run.
* python-control ``input_output_response`` with RK45 (its default) and LSODA on the continuous closed
  loop of ``sim/continuous.py`` (the same plant, PI loops in continuous time, the simulator's shaped
  command as input), level A, the first 4 s of the same scenario (``--horizon``; beyond the first trim
  stop level A back-drives and the re-energised loop is stiff and discontinuous, and LSODA does not finish
  0-10 s within 600 s), each capped at ``--cap`` seconds; agreement: motor speed and nut position within
  0.5 % of their peaks, motor current within 2 % (continuous against 10 kHz sampled control).
* Compile time with an empty cache, and what a second process pays with the cache.

Run: ``python bench/bench_simulate.py`` (``--quick``: no python-control, no baseline).
Speed targets (level D >= 1000x real time on one core, judged on the run's CPU time; batched level D >=
2000 simulated seconds per wall second) are printed met or NOT met; not met exits 1 as a failed comparison.
Wall times are best of ``--repeat`` runs; the CPU time of the same runs is printed beside them, since
on a shared machine the wall time includes waiting for a core.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import os
import re
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.stdout.reconfigure(line_buffering=True)

import numpy as np  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.sim.simulate import available_cpus  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _compare import Comparisons, Side  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
#: main before the speed-up of issue #17 (the code whose level-D time the issue measured)
BASELINE = "aeddd12"
SCENARIO = "backdrive_bipolar_ramp"


def timed(fn, repeat):
    """(best wall, CPU time of that run, result)."""
    best, cpu, out = float("inf"), float("nan"), None
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.thread_time()
        out = fn()
        w = time.perf_counter() - t0
        if w < best:
            best, cpu = w, time.thread_time() - c0
    return best, cpu, out


def load_baseline(ref: str, into: Path):
    """The package at git commit ``ref`` as module ``thsa_control_before`` (imported from ``into``)."""
    data = subprocess.run(["git", "-C", str(REPO), "archive", ref, "thsa_control"], capture_output=True, check=True).stdout
    with tarfile.open(fileobj=BytesIO(data)) as tar:
        tar.extractall(into, filter="data")
    pkg = into / "thsa_control_before"
    (into / "thsa_control").rename(pkg)
    for f in pkg.rglob("*.py"):
        f.write_text(re.sub(r"\bthsa_control\b", "thsa_control_before", f.read_text(encoding="utf-8")), encoding="utf-8")
    sys.path.insert(0, str(into))
    return importlib.import_module("thsa_control_before")


def same_bits(a, b) -> tuple[str, bool]:
    names = sorted(set(a.names) & set(b.names))
    bad = [n for n in names if np.asarray(a[n]).tobytes() != np.asarray(b[n]).tobytes()]
    ok = not bad and len(names) == len(a.names) == len(b.names) and len(a.time) == len(b.time)
    return (f"{len(names)} signals bit-identical" if ok else f"{len(bad)} of {len(names)} signals differ "
            f"({', '.join(bad[:4])}), signal sets {len(a.names)}/{len(b.names)}"), ok


def rtf(label, s: Side, horizon):
    if s.ok:
        print(f"  {label}: {s.seconds * 1e3:.1f} ms wall ({horizon / s.seconds:.0f}x real time), "
              f"{s.value[1] * 1e3:.1f} ms CPU ({horizon / s.value[1]:.0f}x)")


def target(cmp, what: str, value: float, limit: float) -> None:
    """A speed target: printed met or NOT met; not met is a failure (exit 1)."""
    if value >= limit:
        print(f"  target {what}: met ({value:.0f})")
    else:
        cmp.fail(f"target {what}: NOT met ({value:.0f} < {limit:.0f}, measured under the machine's present load)")


def bench_levels(cmp, args, params, design, scenario):
    """Level A and D against the code before the speed-up."""
    base = None
    if not args.quick:
        try:
            base = load_baseline(args.baseline, Path(tempfile.mkdtemp(prefix="thsa-baseline-")))
        except Exception as exc:
            cmp.fail(f"baseline {args.baseline}: cannot load the code before the change ({exc})")
    for level in ("A", "D"):
        sim = thsa.Simulator(thsa.build_plant(level))
        sim.run(scenario, design, params)  # build / load the compiled loop

        if base is None:
            w, c, r = timed(lambda: sim.run(scenario, design, params), args.repeat)
            print(f"level {level}, 10 s {SCENARIO} closed loop at 10 kHz: {w * 1e3:.1f} ms ({10 / w:.0f}x real time), "
                  f"{c * 1e3:.1f} ms CPU ({10 / c:.0f}x)")
            if level == "D":
                target(cmp, "level D >= 1000x real time on one core (CPU time of the single-threaded run)",
                       10.0 / c, 1000.0)
            continue
        bp = base.default_parameters()
        bd = base.load_design(REPO / "designs" / "nominal.toml")
        bs = base.get_scenario(SCENARIO)
        bsim = base.Simulator(base.build_plant(level))
        try:
            bsim.run(bs, bd, bp)
        except Exception:
            pass  # reported by the timed side below
        # interleave the two sides so that a change of machine load hits both
        w_new, w_old, c_new, c_old, r_new, r_old, err = [], [], [], [], None, None, ""
        for _ in range(args.repeat):
            w, c, r_new = timed(lambda: sim.run(scenario, design, params), 1)
            w_new.append(w)
            c_new.append(c)
            try:
                w, c, r_old = timed(lambda: bsim.run(bs, bd, bp), 1)
                w_old.append(w)
                c_old.append(c)
            except Exception as exc:
                err = f"{type(exc).__name__}: {exc}"
                break
        i_new, i_old = int(np.argmin(w_new)), int(np.argmin(w_old)) if w_old else 0
        new = Side("this code", True, (r_new, c_new[i_new]), w_new[i_new])
        old = Side(f"before ({args.baseline})", not err and r_old is not None, (r_old, c_old[i_old]) if w_old else None,
                   w_old[i_old] if w_old else float("nan"), err)
        print(f"level {level}, 10 s {SCENARIO} closed loop at 10 kHz, best of {args.repeat}:")
        rtf("this code", new, 10.0)
        rtf(f"before ({args.baseline})", old, 10.0)
        cmp.compare(f"level {level} speed-up over the code before", new, old,
                    agree=lambda a, b: same_bits(a[0], b[0]), tolerance="the same bits")
        if old.ok:
            print(f"  CPU-time ratio {old.value[1] / new.value[1]:.1f}x")
        if level == "D":
            target(cmp, "level D >= 1000x real time on one core (CPU time of the single-threaded run)",
                   10.0 / new.value[1], 1000.0)


def bench_batch(cmp, args, params, design, scenario):
    """Level-D runs in one batched call, against the same runs one at a time."""
    sim = thsa.Simulator(thsa.build_plant("D"))
    scs = [scenario, thsa.get_scenario("unipolar_speed_bipolar_load")]
    name = "gear.viscous_friction"
    sets = [params.replace({name: params[name].value * f}) for f in (0.5, 1.0, 1.5, 2.0)]
    runs = [(sc, p) for sc in scs for p in sets]
    horizon = sum(sc.duration for sc, _ in runs)
    threads = available_cpus()
    sim.run(scenario, design, params)
    cpu = {"single": [], "batch": []}

    def with_cpu(key, fn):
        c0 = time.process_time()
        out = fn()
        cpu[key].append(time.process_time() - c0)  # every thread of the process
        return out

    single = cmp.side("one at a time", lambda: with_cpu("single", lambda: [sim.run(sc, design, p) for sc, p in runs]),
                      repeat=args.repeat_batch)
    batched = cmp.side(f"run_batch ({threads} thread(s))", lambda: with_cpu("batch", lambda: sim.run_batch(
        [sc for sc, _ in runs], design, [p for _, p in runs], threads=threads)), repeat=args.repeat_batch)

    def agree(a, b):
        results = [same_bits(x, y) for x, y in zip(a, b)]
        ok = len(a) == len(b) == len(runs) and all(r[1] for r in results)
        return f"{sum(r[1] for r in results)}/{len(runs)} runs bit-identical", ok

    print(f"batched level D: {len(runs)} runs ({len(scs)} scenarios of 10 s x {len(sets)} parameter sets) on "
          f"{threads} CPU(s) available")
    r = cmp.compare("batched vs one at a time", batched, single, agree=agree, tolerance="the same bits")
    if r is not None:
        print(f"  throughput: single runs {horizon / single.seconds:.0f} simulated s per wall s, "
              f"batched {horizon / batched.seconds:.0f} simulated s per wall s (target >= 2000 on 2 cores); "
              f"CPU time per simulated s: single {1e3 * min(cpu['single']) / horizon:.2f} ms, "
              f"batched {1e3 * min(cpu['batch']) / horizon:.2f} ms")
        target(cmp, f"batched level D >= 2000 simulated s per wall s ({threads} CPU(s))", horizon / batched.seconds,
               2000.0)


def bench_python_control(cmp, args, params, design, scenario):
    import control as ct

    from thsa_control.sim.continuous import continuous_closed_loop

    plant = thsa.build_plant("A")
    sim = thsa.Simulator(plant)
    sc = dataclasses.replace(scenario, duration=args.horizon)
    sim.run(sc, design, params)
    ours = cmp.side("thsa level A", lambda: sim.run(sc, design, params), repeat=args.repeat)
    res = ours.value
    if res is None:
        cmp.fail("python-control comparison: our run failed")
        return
    T = np.asarray(res.time)
    U = np.vstack([res["speed_cmd"], res["load_force"], res["temperature"]])
    X0 = np.concatenate([plant.initial_state(params), [0.0, 0.0]])
    tol = {"motor_speed": 5e-3, "nut_position": 5e-3, "motor_current": 2e-2}

    def agree_with(ref):
        def agree(a, b):
            devs = {}
            for n in tol:
                i = plant.index("state", n)
                x = np.asarray(a[n]) if ref else a.outputs[i]
                y = b.outputs[i]
                devs[n] = float(np.max(np.abs(y - x)) / np.max(np.abs(x)))
            ok = all(devs[n] <= tol[n] for n in tol)
            return ", ".join(f"{n} {100 * d:.3g} %" for n, d in devs.items()), ok
        return agree

    outs = {}
    for method in ("RK45", "LSODA"):
        def run(method=method):
            sys_cl = continuous_closed_loop(plant, params, design,
                                            deadline=None if args.cap <= 0 else time.perf_counter() + args.cap)
            r = ct.input_output_response(sys_cl, T, U, X0, solve_ivp_method=method)
            if not getattr(r, "success", True):
                raise RuntimeError(f"solve_ivp: {getattr(r, 'message', 'failed')}")
            return r

        outs[method] = theirs = cmp.side(f"python-control {method}{' (default)' if method == 'RK45' else ''}", run)
        cmp.compare(f"0-{args.horizon:g} s level A, thsa vs python-control {method}", ours, theirs,
                    agree=agree_with(True), tolerance="speed and position 0.5 %, current 2 % of the peak")
    if outs["RK45"].ok and outs["LSODA"].ok:
        m, ok = agree_with(False)(outs["RK45"].value, outs["LSODA"].value)
        print(f"  RK45 and LSODA agree: {m}")


def bench_compile(cmp, params, design, scenario):
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, THSA_CACHE_DIR=cache, PYTHONPATH=str(REPO))
        code = ("import time,sys,json,thsa_control as t;P=t.default_parameters();d=t.load_design(t.nominal_design_path());"
                "s=t.Simulator(t.build_plant('D'));t0=time.perf_counter();r=s.run(t.get_scenario(sys.argv[1]),d,P);"
                "c=r.info['compile'];print(json.dumps([time.perf_counter()-t0,c['cached'],c['codegen_s'],c['compile_s']]))")
        import json

        outs = []
        for _ in range(2):
            p = subprocess.run([sys.executable, "-c", code, SCENARIO], capture_output=True, text=True, env=env)
            if p.returncode != 0:
                cmp.fail(f"compile-time probe failed: {p.stderr.strip()[-300:]}")
                return
            outs.append(json.loads(p.stdout.strip().splitlines()[-1]))
        (t1, c1, g1, b1), (t2, c2, _, _) = outs
        print(f"compile (empty cache): codegen {g1 * 1e3:.0f} ms + C compiler {b1:.2f} s; first run incl. build {t1:.2f} s")
        print(f"second process: first run incl. load {t2:.3f} s (library from cache: {c2})")
        if c1 or not c2:
            cmp.fail("cache: the first process found a library in an empty cache, or the second did not find it")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip python-control, the baseline and the compile probe")
    ap.add_argument("--cap", type=float, default=600.0, help="time cap of each python-control run [s] (0: none)")
    ap.add_argument("--horizon", type=float, default=4.0, help="python-control comparison: simulated seconds")
    ap.add_argument("--baseline", default=BASELINE, help="git commit of the code before the speed-up")
    ap.add_argument("--repeat", type=int, default=7, help="runs per timing (best kept)")
    ap.add_argument("--repeat-batch", type=int, default=3, help="repeats of the batched timing (best kept)")
    args = ap.parse_args(argv)
    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    scenario = thsa.get_scenario(SCENARIO)
    cmp = Comparisons()
    bench_levels(cmp, args, params, design, scenario)
    bench_batch(cmp, args, params, design, scenario)
    if not args.quick:
        bench_python_control(cmp, args, params, design, scenario)
        bench_compile(cmp, params, design, scenario)
    return cmp.exit_code()


if __name__ == "__main__":
    sys.exit(main())
