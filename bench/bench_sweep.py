"""Sweep throughput at level D: in-process vs the local Dask default vs a Dask cluster, 1 -> 2 workers.

    python bench/bench_sweep.py [--runs 160] [--chunk 16] [--scenario cold_ramp]

Measures, in one run of this script (ratios, not absolute targets):

* ``serial``: ``engine.simulate_chunk`` over the same chunks in this process
  (one core, no Dask): simulations per second per core;
* ``local 1``: ``thsa sweep``'s default, a ``LocalCluster`` of one worker
  process (Parquet appends included), and its overhead ratio to serial;
* ``cluster 1``: a scheduler and one worker started here as separate
  processes (``dask scheduler`` / ``dask worker``, Dask's default
  configuration, so its nanny sets ``MALLOC_TRIM_THRESHOLD_=65536``, which
  the local default leaves out), reached by address as a remote cluster
  would be;
* ``local 2``: two workers: the scaling 1 -> 2;
* CPU seconds of the workers' tasks and of this process: on a shared machine
  wall-clock rates measure the contention, CPU seconds what a dedicated core
  spends, so the overhead of Dask shows in them;
* the projection of a 10^5-run campaign on N dedicated cores from the
  workers' CPU seconds per run (cluster start-up not included; it is printed
  apart), and with this machine's measured 1 -> 2 efficiency.

The compile happens once before the timings (the cache is warm).  The
machine may be shared: every figure is from this one run.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from thsa_control.sweep.engine import SweepError, read_results, run_sweep, scheduler_address, simulate_chunk
from thsa_control.sweep.spec import parse_spec


def _spec(runs: int, chunk: int, scenario: str):
    doc = {"name": "bench", "seed": 1, "level": "D", "effects": ["temperature_friction"], "designs": ["nominal"],
           "scenarios": [scenario],
           "sampling": {"method": "random", "samples": runs, "chunk_runs": chunk},
           "parameters": {"gear.viscous_friction": {"distribution": "uniform", "min": 4e-5, "max": 2e-4},
                          "screw.efficiency_direct": {"distribution": "uniform", "min": 0.85, "max": 0.94}},
           "metrics": {"keep": ["current_peak_A", "speed_error_percent"]}}
    return parse_spec(doc, source=str(ROOT / "bench" / "bench_sweep.py"), base_dir=ROOT)


def _cluster(tmp: Path, workers: int):
    env = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
    sfile = tmp / "scheduler.json"
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                               "--port", "0", "--no-dashboard", "--scheduler-file", str(sfile)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    try:  # the scheduler creates the file before it writes it: read once it parses
        address = scheduler_address(sfile, timeout=60.0, exited=procs[0].poll)
    except SweepError as exc:
        _stop(procs)
        raise SystemExit(f"bench_sweep: {exc}") from None
    for _ in range(workers):
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker", address, "--nthreads",
                                       "1", "--no-dashboard"], env=env, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL, start_new_session=True))
    from distributed import Client

    with Client(address, timeout=30) as c:
        c.wait_for_workers(workers, timeout=120)
    return address, procs


def _stop(procs):
    for p in reversed(procs):
        os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        p.wait(timeout=30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=160)
    ap.add_argument("--chunk", type=int, default=16)
    ap.add_argument("--scenario", default="cold_ramp")
    args = ap.parse_args()
    spec = _spec(args.runs, args.chunk, args.scenario)
    runs = spec.run_specs(range(spec.total_runs))
    simulate_chunk(spec, runs[:1])  # compile (or load the cache) before timing
    chunks = [runs[i:i + spec.chunk_runs] for i in range(0, len(runs), spec.chunk_runs)]
    t0, c0 = time.perf_counter(), time.process_time()
    rows = [r for ch in chunks for r in simulate_chunk(spec, ch)]  # the same chunks as the workers
    serial, serial_cpu = time.perf_counter() - t0, time.process_time() - c0
    rate1 = len(rows) / serial
    print(f"level D, {args.scenario}, {spec.total_runs} runs in chunks of {spec.chunk_runs}; "
          f"{os.cpu_count()} cores on this machine, load average {os.getloadavg()[0]:.1f} at the start")
    print(f"serial in-process:  {serial:6.2f} s  {rate1:7.1f} sims/s per core (wall); CPU {serial_cpu:.2f} s: "
          f"{len(rows) / serial_cpu:.1f} sims per CPU second")
    out, cpu = {}, {}
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
        tmp = Path(tmp)
        for label, kw in (("local 1", {"workers": 1}), ("local 2", {"workers": 2})):
            t0 = time.perf_counter()
            st = run_sweep(spec, tmp / label.replace(" ", "_"), **kw)
            out[label] = (st.compute_s, time.perf_counter() - t0 - st.compute_s, st.steady_rate())
            cpu[label] = (st.task_cpu_s, st.worker_cpu_s, st.client_cpu_s, st.steady_cpu_per_run())
        t0 = time.perf_counter()
        address, procs = _cluster(tmp, 1)
        start = time.perf_counter() - t0
        try:
            st = run_sweep(spec, tmp / "cluster_1", scheduler=address)
            out["cluster 1"] = (st.compute_s, start, st.steady_rate())
            cpu["cluster 1"] = (st.task_cpu_s, st.worker_cpu_s, st.client_cpu_s, st.steady_cpu_per_run())
        finally:
            _stop(procs)
        same = read_results(tmp / "local_1").equals(read_results(tmp / "cluster_1")) and \
            read_results(tmp / "local_1").equals(read_results(tmp / "local_2"))
    # the serial run again, after the Dask runs: on a shared machine the load drifts, and CPU seconds with it
    c0 = time.process_time()
    for ch in chunks:
        simulate_chunk(spec, ch)
    serial_cpu_end = time.process_time() - c0
    print(f"serial in-process again: CPU {serial_cpu_end:.2f} s ({len(rows) / serial_cpu_end:.1f} sims per CPU second); "
          f"the CPU ratios below use the mean {0.5 * (serial_cpu + serial_cpu_end):.2f} s")
    serial_cpu = 0.5 * (serial_cpu + serial_cpu_end)
    for label in ("local 1", "cluster 1", "local 2"):
        c, s, steady = out[label]
        w = int(label[-1])
        rate = spec.total_runs / c
        print(f"{label + ':':19s} {c:6.2f} s  {rate:7.1f} sims/s ({rate / w:.1f} per core, overhead ratio "
              f"{c * w / serial:.2f} x serial); after each worker's first chunk {steady:.1f} sims/s "
              f"({steady / w:.1f} per core, overhead ratio {rate1 / (steady / w):.2f}); cluster start, compile "
              f"check and report outside the loop {s:.1f} s")
    for label in ("local 1", "cluster 1", "local 2"):
        task, proc, client, steady = cpu[label]
        print(f"{label + ':':19s} CPU: tasks {task:.2f} s ({task / serial_cpu:.2f} x serial; after each worker's "
              f"first chunk, which builds its plant: {steady * len(rows) / serial_cpu:.2f} x serial), worker "
              f"processes {proc:.2f} s ({proc / serial_cpu:.2f} x serial: Dask's threads), "
              f"this process {client:.2f} s (scheduler of a local cluster, Parquet)")
    speedup = out["local 2"][2] / out["local 1"][2]
    eff = speedup / 2.0
    print(f"scaling 1 -> 2 workers (after the first chunks): speed-up {speedup:.2f} (efficiency {eff:.2f})")
    print(f"tables bit-identical (local 1, local 2, cluster 1): {same}")
    print(f"load average at the end {os.getloadavg()[0]:.1f} (above {os.cpu_count()}: the cores were shared, "
          "the rates and the scaling are lower bounds)")
    # a dedicated core does what a worker process's CPU seconds say (the task's and Dask's threads)
    rates = {}
    for label in ("local 1", "cluster 1"):
        task, proc, _, steady = cpu[label]
        rates[label] = 1.0 / (steady * proc / task)
    print(f"CPU cost of a second worker: {cpu['local 2'][1] / cpu['local 1'][1]:.2f} x the worker CPU per run "
          "(what the wall-clock scaling measures on a loaded machine is the load)")
    # the client writes each chunk's Parquet file and (local cluster) runs the scheduler: a cost per chunk
    n_chunks = -(-spec.total_runs // spec.chunk_runs)
    per_chunk = {label: cpu[label][2] / n_chunks for label in ("local 1", "cluster 1")}
    print(f"client CPU per chunk: {per_chunk['local 1'] * 1e3:.1f} ms with the local cluster's scheduler in it, "
          f"{per_chunk['cluster 1'] * 1e3:.1f} ms with a separate scheduler")
    for n in (2, 16, 64):
        for chunk in (spec.chunk_runs, 256):
            compute = 1e5 / (rates["cluster 1"] * n)
            client = -(-100000 // chunk) * per_chunk["cluster 1"]
            print(f"projection: 1e5 runs of {args.scenario} on {n:3d} dedicated cores, chunks of {chunk:3d}: "
                  f"{max(compute, client) / 60:5.2f} min (workers {compute:.0f} s at {rates['cluster 1']:.0f} sims per "
                  f"CPU second of a default Dask worker, {rates['local 1']:.0f} for thsa's local ones; client "
                  f"{client:.0f} s{', the bottleneck' if client > compute else ''})")


if __name__ == "__main__":
    main()
