"""Segmented open-loop residual (issue #11): drift, noise level, missing torque and time, measured in one run.

Plain screw drive on the virtual rig (level A without its ideal no-back, no load, 1 kHz cascade, 2 rpm speed /
5 um LVDT / 0.02 A current noise, 10 s bipolar excitation): a null run (truth = declared model) and a run
with an undeclared Coulomb friction of 0.05 N m; then the shipped example run (independent reference
simulator) at levels A and B.  Prints, per run, the nut-position residual RMS in each quarter of the run for
the whole-run and the segmented (0.05 s) open-loop replays, the missing torque's mean per direction of
motion, and the wall time of both replays with their ratio.

Run: ``python bench/bench_residual_segments.py [--duration 10]``
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from thsa_control.data.rigdata import read_run
from thsa_control.fit.replay import analyse_replay, replay_open_loop
from thsa_control.fit.segmented import MISSING_TORQUE, replay_segmented
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs
from thsa_control.loops.design import derive_gains
from thsa_control.model import build_plant
from thsa_control.model.params import default_parameters

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
from handcalc import example_disk_law  # noqa: E402  (the example's disk law, one copy, shared with the tests)
NOISE = {"motor_speed_rpm": 2.0, "nut_position_mm": 0.005, "motor_current_A": 0.02, "screw_speed_rpm": 0.2}


def quarters(e):
    n = e.size
    return [float(np.sqrt(np.nanmean(e[i * n // 4:(i + 1) * n // 4] ** 2))) for i in range(4)]


def show(label, run, plant, params):
    t0 = time.perf_counter()
    whole = replay_open_loop(run, plant, params)
    t1 = time.perf_counter()
    seg = replay_segmented(run, plant, params)
    t2 = time.perf_counter()
    um = lambda xs: ", ".join(f"{1e6 * x:.4g}" for x in xs)  # noqa: E731
    print(f"{label}")
    print(f"  nut-position residual RMS per quarter [um]: whole run {um(quarters(whole.residual('nut_position')))}")
    print(f"                                              segmented {um(quarters(seg.residual('nut_position')))}")
    if MISSING_TORQUE in seg.fits:
        d = analyse_replay(run, seg)[MISSING_TORQUE].conditioned["direction"]
        means = {b.label: b.mean for b in d.bins}
        print(f"  missing torque mean [N m]: moving positive {means.get('positive', float('nan')):+.4f}, "
              f"negative {means.get('negative', float('nan')):+.4f} (eta^2 on direction {d.eta_squared:.3f}); "
              f"reflected inertia {seg.info['reflected_inertia_median']:.4g} kg m^2")
    print(f"  wall: whole run {t1 - t0:.2f} s, segmented {t2 - t1:.2f} s ({seg.info['segments']} segments), "
          f"ratio {(t2 - t1) / max(t1 - t0, 1e-9):.1f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=10.0, help="virtual run length [s]")
    args = ap.parse_args()
    params = default_parameters()
    rig = derive_gains(params, current_bandwidth_hz=150, velocity_crossover_hz=10, velocity_pi_zero_ratio=5,
                       position_bandwidth_hz=1, control_period_s=1e-3, name="rig_1kHz")
    plain = build_plant("A", remove=["noback_ideal"], params=params)
    with tempfile.TemporaryDirectory() as tmp:
        for tc in (0.0, 0.05):
            u = excitation_inputs(args.duration, bipolar=True, load=0.0, control_period=1e-3, seed=1)
            stem = Path(tmp) / f"plain_{int(1000 * tc)}"
            VirtualRig(None, effects=("coulomb_friction",) if tc else (), params=params.replace(
                {"drive.coulomb_torque": tc}), design=rig, noise=NOISE, seed=1).record(u, stem)
            show(f"plain drive, {args.duration:g} s, undeclared Coulomb {tc:g} N m (model: A - noback_ideal)",
                 read_run(stem.with_suffix(".csv")), plain, params)
    example = read_run(ROOT / "tests" / "data" / "rig-data" / "examples" / "excitation_tensile_12kN.csv")
    for level in ("A", "B"):
        show(f"shared example excitation_tensile_12kN (independent simulator), model level {level}", example,
             build_plant(level, params=params), params)
    # the example's simulator loads its slipping disk with preload + |F| (level B: |F| beyond twice the preload)
    law = example_disk_law(params, float(np.median(np.abs(example.signals["load_force"]))))
    show("shared example, model level B with the example's disk law (preload + |F| on the slipping disk)", example,
         build_plant("B", params=law), law)


if __name__ == "__main__":
    main()
