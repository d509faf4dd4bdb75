"""Identification benchmark (issue #4): 5 parameters of level B from a 10 s, 1 kHz virtual run, one core.

The run: the virtual rig at level B (default actuator, nominal 10 kHz cascade), a bipolar identification
excitation (+-3 mm/s plateaus with multi-sine and PRBS, 12 kN compressive load: opposing, then aiding),
recorded at 1 kHz with 2 rpm speed and 5 um position noise.  The fit starts 15 % off (efficiencies 5 %).

Prints the time of one simulation (segment residuals) and one gradient (exact casadi Jacobian), the time
of the whole fit, and the recovery error of each parameter in stderr units.  Recorded at 1 kHz from a
10 kHz cascade, the current between samples is unknown to the replay, so part of the error is a bias of
the sampling, not noise: ``--rate 10000`` records at the control rate.

Run: ``python bench/bench_identify.py`` (``--substeps 4`` interpolates the current within a sample).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.fit.identify import IdentificationSettings, Identifier, RunProblem  # noqa: E402
from thsa_control.fit.replay import current_driven_map  # noqa: E402
from thsa_control.data.rigdata import read_run  # noqa: E402
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs  # noqa: E402

FREE = ("motor.rotor_inertia", "screw.efficiency_direct", "screw.efficiency_inverse", "noback.mu_coulomb_pos",
        "noback.mu_coulomb_neg")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--substeps", type=int, default=1)
    ap.add_argument("--rate", type=float, default=1000.0)
    ap.add_argument("--segment", type=float, default=0.25)
    args = ap.parse_args()
    params = thsa.default_parameters()
    with tempfile.TemporaryDirectory() as d:
        rig = VirtualRig("B", params=params, noise={"motor_speed_rpm": 2.0, "nut_position_mm": 0.005},
                         sample_rate_hz=args.rate, seed=1)
        t0 = time.perf_counter()
        rig.record(excitation_inputs(10.0, bipolar=True, load=12e3), f"{d}/bench")
        t_record = time.perf_counter() - t0
        run = read_run(f"{d}/bench.csv")
    start = params.replace({n: params.value(n) * (0.95 if "efficiency" in n else 1.15) for n in FREE})
    settings = IdentificationSettings(substeps=args.substeps, segment_duration=args.segment,
                                      channels=("motor_speed", "nut_position"))

    # one simulation and one gradient of the fit's problem (built as Identifier.fit builds it)
    plant = thsa.build_plant("B", params=start)
    pb = RunProblem(run, plant, current_driven_map(plant, args.substeps), start, FREE, settings)
    z = np.r_[np.zeros(len(FREE)), pb.initial_decision()]
    p0, scale = plant.p_vector(start), np.array([abs(start.value(n)) for n in FREE])

    def best(fn, n=5):
        out = []
        for _ in range(n):
            t = time.perf_counter()
            fn()
            out.append(time.perf_counter() - t)
        return min(out)

    t_sim = best(lambda: pb.residuals(z, p0, scale, pb.sigma0))
    t_grad = best(lambda: pb.jacobian(z, p0, scale, pb.sigma0))  # scipy CSC, as the fit uses it

    res = Identifier("B", start, FREE, settings=settings).fit(run)
    print(f"run: 10 s at {args.rate:g} Hz ({len(run.time)} samples), recorded in {t_record:.2f} s")
    print(f"problem: {pb.M} segments of {pb.L} samples, {len(FREE)} parameters + {pb.n_dec_states} segment states, "
          f"{pb.Ymeas.size} residuals, substeps {args.substeps}")
    print(f"one simulation (all segment residuals): {t_sim * 1e3:.1f} ms")
    print(f"one gradient (exact casadi Jacobian {pb.Ymeas.size} x {len(FREE) + pb.n_dec_states}, "
          f"{'compiled' if pb.compiled else 'interpreted'}): {t_grad * 1e3:.1f} ms")
    print(f"identification of {len(FREE)} parameters: {res.time_s:.1f} s ({res.nfev} evaluations, {res.njev} "
          f"Jacobians; target < 60 s) - {res.status}")
    for n, e in res.estimates.items():
        truth = params.value(n)
        print(f"  {n:28s} {e.value:.6g} +/- {e.stderr:.3g}  truth {truth:.6g}  error {100 * (e.value / truth - 1):+.2f} % "
              f"= {(e.value - truth) / e.stderr:+.1f} stderr")
    for a, b, rho in res.high_correlations:
        print(f"  flagged: C({a}, {b}) = {rho:+.3f}")


if __name__ == "__main__":
    main()
