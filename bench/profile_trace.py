"""Where a short trace's processor time goes (issue #17 item 4, issue #21 item 6): fits against overhead.

One trace of the fast test subset's size (tests/test_trace.py, force_offset case: a 2.5 s, 1 kHz virtual run
of a plain screw drive with a 1500 N axial force offset in the truth, candidates force_offset and
cogging_torque, 30 evaluations per fit), with every fit in this process (``workers=1``) under cProfile's
processor-time clock, so that the fits and what surrounds them are counted on one clock.  Prints:

* the processor time of the imports, of recording the virtual run, and of the trace;
* the trace split into the least-squares solver (scipy ``least_squares``; of it the dense SVDs of its
  ``trf`` steps and the compiled residual/Jacobian evaluations), the rest of the fits (problem set-up,
  predictions, covariances), and the tracer's own work outside the fits (scoring, signatures, plants);
* with ``--workers 2`` it runs the same trace again with two fit processes and prints this process's and
  the children's processor time (the fork start-up and the results' pickling are the difference).

Run: ``python bench/profile_trace.py [--workers 2] [--top 25]``.  Numbers, not a pass/fail target.
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import resource
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))


def _cpu() -> tuple[float, float]:
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime


def _cum(stats: pstats.Stats, name: str, file_part: str = "") -> float:
    """Cumulative time of the functions called ``name`` (in a file containing ``file_part``), outermost only."""
    return sum(v[3] for (f, _, fn), v in stats.stats.items() if fn == name and file_part in f)


def _tot(stats: pstats.Stats, name: str, file_part: str = "") -> float:
    return sum(v[2] for (f, _, fn), v in stats.stats.items() if fn == name and file_part in f)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=1, help="also run the trace with this many fit processes")
    ap.add_argument("--top", type=int, default=0, help="print the N functions with the largest cumulative time")
    args = ap.parse_args()

    c0 = time.process_time()
    from handcalc import RIG_NOISE

    from thsa_control.data.rigdata import read_run
    from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs
    from thsa_control.loops.design import derive_gains
    from thsa_control.model.params import default_parameters
    from thsa_control.trace import TraceSettings, trace

    print(f"imports: {time.process_time() - c0:.2f} s CPU")
    params = default_parameters()
    rig = derive_gains(params, current_bandwidth_hz=150, velocity_crossover_hz=10, velocity_pi_zero_ratio=5,
                       position_bandwidth_hz=1, control_period_s=1e-3, name="rig_1kHz")
    with tempfile.TemporaryDirectory() as d:
        c1 = time.process_time()
        u = excitation_inputs(2.5, bipolar=True, load=0.0, control_period=1e-3, seed=1, temperature=25.0)
        VirtualRig(None, effects=("force_offset",), params=params.replace({"drive.axial_force_offset": 1500.0}),
                   design=rig, noise=RIG_NOISE, seed=1).record(u, Path(d) / "r")
        run = read_run(Path(d) / "r.csv")
        print(f"recording the virtual run (2.5 s, 1 kHz): {time.process_time() - c1:.2f} s CPU")

        def settings(workers):
            return TraceSettings(candidates=("force_offset", "cogging_torque"), max_nfev=30, max_effects=1,
                                 workers=workers)

        prof = cProfile.Profile(time.process_time)
        prof.enable()
        doc = trace(run, "A", remove=["noback_ideal"], params=params, settings=settings(1)).to_dict()
        prof.disable()
        st = pstats.Stats(prof)
        total = _cum(st, "trace", "trace/engine.py")
        fits = _cum(st, "_fit_job", "trace/scoring.py")
        lsq = _cum(st, "least_squares", "least_squares.py")
        svd = _tot(st, "svd", "_decomp_svd.py")
        ev = _tot(st, "__call__", "fit/shooting.py")
        rows = [("trace, all fits in this process", total),
                ("  fits (_fit_job)", fits),
                ("    scipy least_squares", lsq),
                ("      of it: dense SVDs of the trf steps", svd),
                ("      of it: compiled residual/Jacobian calls", ev),
                ("    fit set-up, predictions, covariances", fits - lsq),
                ("  tracer outside the fits", total - fits)]
        print(f"\nfound {[e['name'] for e in doc['effects_added']]} (under cProfile: times inflated by its hooks)")
        for label, v in rows:
            print(f"{label:<52s} {v:7.2f} s CPU  {100 * v / total:5.1f} %")
        if args.top:
            st.sort_stats("cumulative").print_stats(args.top)
        if args.workers > 1:
            a = _cpu()
            trace(run, "A", remove=["noback_ideal"], params=params, settings=settings(args.workers))
            b = _cpu()
            print(f"\nsame trace, {args.workers} fit processes, no profiler: this process {b[0] - a[0]:.2f} s CPU, "
                  f"fit processes {b[1] - a[1]:.2f} s CPU, sum {b[0] + b[1] - a[0] - a[1]:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
