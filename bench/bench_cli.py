"""CLI speed benchmark (issue #7, item 6): prints times and ratios measured in one run.

* ``thsa --help`` and ``thsa --version`` wall and CPU time of a fresh process
  (target under 0.3 s: no casadi, python-control or scipy at import; the CPU
  time does not depend on the machine's load);
* ``thsa check-data`` wall time and peak memory (max RSS of the process) on
  synthetic runs of 1k and 10k columns (1,000 rows) and of 100k and 1M rows
  (5 FORMAT columns), with the time and memory per cell, whose ratio between
  the small and large case shows linearity (1.0 = linear).

Run: ``python bench/bench_cli.py``  (``--quick`` skips the 1M-row case).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

# Peak memory is VmHWM of the child (ru_maxrss would inherit the parent's high-water mark across exec).
_CHILD = """
import resource, sys, time
t0 = time.perf_counter()
from thsa_control.cli import main
code = main(sys.argv[1:])
wall = time.perf_counter() - t0
try:
    rss = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM:"))  # kB
except (OSError, StopIteration):
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
print(f"\\nBENCH {wall} {rss} {code}", file=sys.stderr)
"""


def _env():
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}


def run_cli(args: list[str]) -> tuple[float, float, int]:
    """(wall time of main() [s], peak RSS [MB], exit code) in a fresh process."""
    proc = subprocess.run([sys.executable, "-c", _CHILD, *args], capture_output=True, text=True, env=_env())
    line = [x for x in proc.stderr.splitlines() if x.startswith("BENCH ")][-1].split()
    return float(line[1]), float(line[2]) / 1024.0, int(line[3])


def process_time(args: list[str], repeat: int = 5) -> tuple[float, float]:
    """Best wall time and best CPU time (user + sys) [s] of a whole ``python -m thsa_control.cli ARGS`` process.

    The CPU time does not depend on how loaded the machine is; the wall time does.
    """
    best_wall = best_cpu = float("inf")
    for _ in range(repeat):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "thsa_control.cli", *args], capture_output=True, env=_env())
        best_wall = min(best_wall, time.perf_counter() - t0)
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        best_cpu = min(best_cpu, (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime))
    return best_wall, best_cpu


def write_run(stem: Path, n_rows: int, n_extra: int, seed: int = 0) -> Path:
    """A valid run: FORMAT kinematics (328.05 rpm per mm/s), 1 kHz, n_extra extra sensor columns."""
    rng = np.random.default_rng(seed)
    t = np.arange(n_rows) * 1e-3
    v = np.where((t % 4.0) < 2.0, 5.0, -5.0)
    cols = {"time_s": t, "speed_cmd_mm_s": v, "load_force_N": 1e4 + 50 * rng.standard_normal(n_rows),
            "motor_speed_rpm": 328.05 * v + 2 * rng.standard_normal(n_rows),
            "motor_current_A": 1.0 + 0.1 * np.sin(t)}
    for j in range(n_extra):
        cols[f"sensor_{j}"] = np.sin(t + j)
    with open(stem.with_suffix(".csv"), "w") as f:
        f.write(",".join(cols) + "\n")
        matrix = np.column_stack(list(cols.values()))
        for a in range(0, n_rows, 50_000):
            np.savetxt(f, matrix[a:a + 50_000], fmt="%.6g", delimiter=",")
    stem.with_suffix(".json").write_text(json.dumps({"format": "thsa-rig-run/1", "temperature_C": 20.0,
                                                    "sample_rate_hz": 1000.0}))
    return stem.with_suffix(".csv")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="skip the 1M-row case")
    opts = ap.parse_args()
    for what in ("--help", "--version"):
        wall, cpu = process_time([what])
        print(f"thsa {what:10s} {wall:.3f} s wall, {cpu:.3f} s CPU per process (target < 0.3 s)")
    cases = [("1k columns x 1000 rows", 1000, 995), ("10k columns x 1000 rows", 1000, 9995),
             ("100k rows x 5 columns", 100_000, 0)]
    if not opts.quick:
        cases.append(("1M rows x 5 columns", 1_000_000, 0))
    results = {}
    with tempfile.TemporaryDirectory() as d:
        for label, rows, extra in cases:
            path = write_run(Path(d) / f"run_{rows}_{extra}", rows, extra)
            wall, rss, code = run_cli(["check-data", str(path)])
            cells = rows * (5 + extra)
            results[label] = (wall, rss, cells)
            print(f"check-data {label:26s} {wall:7.2f} s  peak {rss:7.1f} MB  "
                  f"{wall / cells * 1e9:7.1f} ns/cell  file {path.stat().st_size / 1e6:6.1f} MB  exit {code}")
    for small, large in (("1k columns x 1000 rows", "10k columns x 1000 rows"),
                         ("100k rows x 5 columns", "1M rows x 5 columns")):
        if small in results and large in results:
            (w1, _, c1), (w2, _, c2) = results[small], results[large]
            print(f"linearity {large} vs {small}: time per cell ratio {(w2 / c2) / (w1 / c1):.2f} "
                  "(1.0 = linear; start-up cost makes the small case look slower per cell)")


if __name__ == "__main__":
    main()
