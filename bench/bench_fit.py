"""Fit benchmark (issue #17 item 4, #21 item 6): compiled against interpreted residuals, Jacobians and one fit.

The multiple-shooting problem of one run (:class:`thsa_control.fit.shooting.RunProblem`, as the tracer builds
it: 50 ms segments, every third held out, quasi-static starts) is evaluated with its segment Functions compiled
to C (the default) and in casadi's interpreter (``IdentificationSettings(compiled=False)``), in this process, on
the same decision vector.  Both sides must give the same residuals and Jacobians (to 1e-12 relative) before a
ratio is printed.  Then one identification runs both ways; the estimates must agree (1e-9 relative) and the
processor time of each is printed with the ratio.  The cost of building the library in an empty cache (the C
compiler's processor time) is printed apart: it is paid once per model structure and machine.

Processor time (this process and the compiler it waits for), not wall time: it does not depend on what else
the machine runs.  Exits 1 when a side fails or the two disagree.

Run: ``python bench/bench_fit.py [--csv RUN.csv] [--level A] [--effects standby_motor] [--free a,b]``
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import resource
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.data.rigdata import read_run  # noqa: E402
from thsa_control.fit.identify import IdentificationSettings, Identifier  # noqa: E402
from thsa_control.fit.kinematics import run_kinematics  # noqa: E402
from thsa_control.fit.replay import current_driven_map  # noqa: E402
from thsa_control.fit.shooting import RunProblem  # noqa: E402

DEFAULT_RUN = Path(__file__).resolve().parents[1] / "tests" / "data" / "rigsim" / "null_rig_trim_s1.csv"


def _cpu() -> float:
    """Processor time [s] of this process and of the children it waited for (the C compiler)."""
    a, b = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime + b.ru_utime + b.ru_stime


def _best(fn, n: int = 7) -> float:
    out = []
    for _ in range(n):
        c = _cpu()
        fn()
        out.append(_cpu() - c)
    return min(out)


def _rel(a, b) -> float:
    a = a.toarray() if hasattr(a, "toarray") else np.asarray(a)
    b = b.toarray() if hasattr(b, "toarray") else np.asarray(b)
    if a.shape != b.shape:
        return float("inf")
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--csv", default=str(DEFAULT_RUN))
    ap.add_argument("--level", default="A")
    ap.add_argument("--effects", default="standby_motor")
    ap.add_argument("--free", default="gear.viscous_friction,screw.efficiency_direct,screw.efficiency_inverse")
    args = ap.parse_args()
    params = thsa.default_parameters()
    run = run_kinematics(read_run(args.csv), params)
    effects = tuple(e for e in args.effects.split(",") if e)
    free = tuple(args.free.split(","))
    plant = thsa.build_plant(args.level, effects, params=params)
    mech = current_driven_map(plant, 1)
    st = IdentificationSettings(segment_duration=0.05, holdout_every=3, quasi_static_starts=True)
    failed = False

    # -- the library built in an empty cache: the compiler's processor time, paid once per model structure
    with tempfile.TemporaryDirectory() as tmp:
        old = os.environ.get("THSA_CACHE_DIR")
        os.environ["THSA_CACHE_DIR"] = tmp
        try:
            import thsa_control.fit.shooting as shooting

            saved = dict(shooting._COMPILED)
            shooting._COMPILED.clear()
            cold = RunProblem(run, plant, mech, params, free, st)
            c = _cpu()
            ok = cold.compiled
            build = _cpu() - c
            shooting._COMPILED.clear()
            shooting._COMPILED.update(saved)
        finally:
            if old is None:
                os.environ.pop("THSA_CACHE_DIR")
            else:
                os.environ["THSA_CACHE_DIR"] = old
    if not ok:
        print("the segment Functions were not compiled (no working C compiler?): nothing to compare")
        return 1

    comp = RunProblem(run, plant, mech, params, free, st)
    itp = RunProblem(run, plant, mech, params, free, dataclasses.replace(st, compiled=False))
    nf = len(free)
    p0, sig = plant.p_vector(params), comp.sigma0
    scale = np.array([abs(params.value(n)) or 1.0 for n in free])
    z = np.r_[np.full(nf, 0.05), comp.initial_decision()]
    print(f"run: {args.csv} ({run.time.size} samples); level {args.level} + {', '.join(effects) or 'nothing'}; "
          f"{comp.M} segments of {comp.L} samples, {nf} parameters + {comp.n_dec_states} segment states")
    print(f"library build in an empty cache (codegen + C compiler, once per model structure): {build:.2f} s CPU")
    cases = [("residuals", lambda pb: pb.residuals(z, p0, scale, sig)),
             ("Jacobian", lambda pb: pb.jacobian(z, p0, scale, sig)),
             ("Jacobian by the segment states", lambda pb: pb.jacobian(z, p0, scale, sig, states_only=True))]
    for name, fn in cases:
        try:
            a, b = fn(comp), fn(itp)
        except Exception as exc:  # a side that fails is reported, never a ratio
            print(f"{name}: failed ({type(exc).__name__}: {exc}); no ratio")
            failed = True
            continue
        rel = _rel(a, b)
        if not rel <= 1e-12:
            print(f"{name}: compiled and interpreted differ by {rel:.3g} relative (limit 1e-12); no ratio")
            failed = True
            continue
        tc, ti = _best(lambda: fn(comp)), _best(lambda: fn(itp))
        print(f"{name}: compiled {tc * 1e3:.1f} ms, interpreted {ti * 1e3:.1f} ms CPU -> {ti / tc:.1f}x "
              f"(agree to {rel:.1g} relative)")

    fits, cpu = {}, {}
    for compiled in (True, False):
        c = _cpu()
        try:
            fits[compiled] = Identifier(args.level, params, free, effects=effects,
                                        settings=dataclasses.replace(st, compiled=compiled)).fit(run)
        except Exception as exc:
            print(f"fit ({'compiled' if compiled else 'interpreted'}) failed: {type(exc).__name__}: {exc}")
            return 1
        cpu[compiled] = _cpu() - c
    worst = max(abs(fits[True].estimates[n].value - fits[False].estimates[n].value)
                / max(abs(fits[False].estimates[n].value), 1e-300) for n in free)
    if not worst <= 1e-9 or fits[True].nfev != fits[False].nfev:
        print(f"fit: the estimates differ by {worst:.3g} relative (limit 1e-9) or the evaluations "
              f"({fits[True].nfev} against {fits[False].nfev}); no ratio")
        return 1
    print(f"one fit ({fits[True].nfev} evaluations, {fits[True].njev} Jacobians): compiled {cpu[True]:.2f} s, "
          f"interpreted {cpu[False]:.2f} s CPU -> {cpu[False] / cpu[True]:.1f}x (estimates agree to {worst:.1g})")
    for n, e in fits[True].estimates.items():
        print(f"  {n} = {e.value:.6g} +/- {e.stderr:.2g} {e.unit}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
