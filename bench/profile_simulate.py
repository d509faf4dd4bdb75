"""Where the time of one level-D run goes (issue #17): the split of ``Simulator.run`` and of a batch.

Prints, best of ``--repeat`` on the CPU time of this thread (``time.thread_time``: waiting for a core
on a shared machine is not counted):

* the whole ``Simulator.run`` of 10 s ``backdrive_bipolar_ramp`` at 10 kHz (1 kHz output);
* its parts: checking and laying out the run (``_prepare``: sampling the scenario, parameter and
  controller vectors, initial state), of which sampling the scenario alone; the compiled C loop called
  alone on the prepared run (incl. the numpy output block); building the result from the block;
* for the batch of the benchmark (2 scenarios x 4 parameter sets): the Python work before and after
  the C call and the C call itself on 1 and on all CPUs (wall and process CPU time).

Run: ``python bench/profile_simulate.py`` (``--perf``: also a ``perf record`` of the C loop, when
``perf`` is installed).  Numbers only; the speed targets are judged by ``bench/bench_simulate.py``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.sim.simulate import InputSeries, available_cpus  # noqa: E402

SCENARIO = "backdrive_bipolar_ramp"


def best_cpu(fn, repeat: int) -> float:
    best = float("inf")
    for _ in range(repeat):
        c0 = time.thread_time()
        fn()
        best = min(best, time.thread_time() - c0)
    return best


def best_wall_and_process(fn, repeat: int) -> tuple[float, float]:
    best, cpu = float("inf"), float("nan")
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        w = time.perf_counter() - t0
        if w < best:
            best, cpu = w, time.process_time() - c0
    return best, cpu


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=15)
    ap.add_argument("--perf", action="store_true", help="perf record the C loop for 5 s and print the top symbols")
    ap.add_argument("--loop-seconds", type=float, default=0.0, help=argparse.SUPPRESS)  # the --perf child
    args = ap.parse_args(argv)
    params = thsa.default_parameters()
    design = thsa.load_design(thsa.nominal_design_path())
    scenario = thsa.get_scenario(SCENARIO)
    sim = thsa.Simulator(thsa.build_plant("D"))
    sim.run(scenario, design, params)
    prep = sim._prepare(scenario, design, params, None, None)
    loop, _ = sim._compiled_loop(prep.loop)

    def c_loop():
        return loop.batch(prep.z0[None, :], [prep.rows], prep.theta, prep.decimation, n_steps=prep.n)

    if args.loop_seconds:
        t_end = time.perf_counter() + args.loop_seconds
        while time.perf_counter() < t_end:
            c_loop()
        return 0
    Y, z, _ = c_loop()
    r = args.repeat
    whole = best_cpu(lambda: sim.run(scenario, design, params), r)
    prepare = best_cpu(lambda: sim._prepare(scenario, design, params, None, None), r)
    sampling = best_cpu(lambda: InputSeries.from_scenario(scenario, design.control_period), r)
    c = best_cpu(c_loop, r)
    result = best_cpu(lambda: sim._result(prep, Y[0], z[0], 0.0, {}), r)
    print(f"level D, 10 s {SCENARIO} at 10 kHz (1 kHz output), CPU time of this thread, best of {r}:")
    print(f"  whole Simulator.run                 {whole * 1e3:6.2f} ms  ({10 / whole:.0f}x real time)")
    print(f"  check and lay out the run (_prepare) {prepare * 1e3:6.2f} ms, of which sampling the scenario "
          f"{sampling * 1e3:.2f} ms")
    print(f"  compiled C loop alone               {c * 1e3:6.2f} ms  ({10 / c:.0f}x real time)")
    print(f"  result from the output block        {result * 1e3:6.2f} ms")
    print(f"  rest (the difference)               {(whole - prepare - c - result) * 1e3:6.2f} ms")

    scs = [scenario, thsa.get_scenario("unipolar_speed_bipolar_load")]
    name = "gear.viscous_friction"
    sets = [params.replace({name: params[name].value * f}) for f in (0.5, 1.0, 1.5, 2.0)]
    runs = [(sc, p) for sc in scs for p in sets]
    horizon = sum(sc.duration for sc, _ in runs)
    memo: dict = {}
    preps = [sim._prepare(sc, design, p, None, None, memo) for sc, p in runs]
    py_before = best_cpu(lambda: [sim._prepare(sc, design, p, None, None, m) for m in [{}] for sc, p in runs],
                         max(r // 3, 3))  # one memo per batch, as run_batch
    Z0 = np.stack([p.z0 for p in preps])
    TH = np.stack([p.theta for p in preps])
    print(f"batch of {len(runs)} level-D runs ({horizon:.0f} simulated s), best of {max(r // 3, 3)}:")
    print(f"  Python before the C call (all runs checked and laid out) {py_before * 1e3:.2f} ms CPU")
    for threads in sorted({1, available_cpus()}):
        w, cpu = best_wall_and_process(lambda: loop.batch(Z0, [p.rows for p in preps], TH, preps[0].decimation,
                                                          threads=threads, n_steps=preps[0].n), max(r // 3, 3))
        print(f"  C call on {threads} thread(s): {w * 1e3:.1f} ms wall ({horizon / w:.0f} simulated s per wall s), "
              f"{cpu * 1e3:.1f} ms CPU of the process")
    w, cpu = best_wall_and_process(lambda: sim.run_batch([sc for sc, _ in runs], design, [p for _, p in runs]),
                                   max(r // 3, 3))
    print(f"  whole run_batch: {w * 1e3:.1f} ms wall ({horizon / w:.0f} simulated s per wall s), {cpu * 1e3:.1f} ms CPU")

    if args.perf:
        if shutil.which("perf") is None:
            print("perf: not installed")
            return 0
        data = os.path.join(os.environ.get("TMPDIR", "/tmp"), f"thsa-perf-{os.getpid()}.data")
        subprocess.run(["perf", "record", "-q", "-o", data, "-F", "2000", sys.executable, __file__,
                        "--loop-seconds", "5"], capture_output=True)
        rep = subprocess.run(["perf", "report", "-i", data, "--stdio", "--percent-limit", "1"],
                             capture_output=True, text=True).stdout
        os.unlink(data)
        print("perf record of the C loop (symbols >= 1 %):")
        for line in rep.splitlines():
            if line.strip() and not line.startswith("#"):
                print("  " + " ".join(line.split()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
