"""What the tracer's backward check costs (thsa_control.trace.backward): each run traced as ``thsa trace RUN.csv
--model A`` does, with the backward check off and on, in one process; prints the processor time of each trace (this
process and its fit workers, which does not depend on what else the machine runs), the ratio, the backward fits
and their processor time, and whether the found effects and their order changed.

Run: ``python bench/bench_backward.py RUN.csv [RUN.csv ...] [--workers 2]``
"""

from __future__ import annotations

import argparse
import os
import resource
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from thsa_control.data.rigdata import read_run
from thsa_control.fit.kinematics import run_kinematics
from thsa_control.model.params import default_parameters
from thsa_control.trace import TraceSettings, trace


def _cpu() -> float:
    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv", nargs="+")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    params = default_parameters()
    for path in a.csv:
        run = run_kinematics(read_run(path), params)
        out = {}
        for on in (False, True):
            c0, t0 = _cpu(), time.perf_counter()
            doc = trace(run, "A", params=params, settings=TraceSettings(workers=a.workers, backward=on)).to_dict()
            out[on] = (_cpu() - c0, time.perf_counter() - t0, doc)
        (c_off, w_off, d_off), (c_on, w_on, d_on) = out[False], out[True]
        names = lambda d: [e["name"] for e in d["effects_added"]]
        print(f"{run.name}: CPU {c_off:.1f} s -> {c_on:.1f} s (x{c_on / c_off:.2f}; wall {w_off:.1f} -> {w_on:.1f} s), "
              f"backward fits {d_on['timing']['backward_fits']} ({d_on['timing']['backward_cpu_s']:.1f} s CPU); "
              f"added {names(d_off)} -> {names(d_on)}; removed {[r['name'] for r in d_on['effects_removed']]}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
