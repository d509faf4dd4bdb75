"""Profiled backlash candidate benchmark (issue #11): what the pawl-pitch profile costs.

The run: the trim-stop record of tests/test_trace_backlash.py (five extensions against 20 kN with motor-off
stops, 1 kHz, level C with a pawl pitch of 0.10 rad).  Measured in one process, one after the other: one
plain identification of the level-C model at the file's pitch (the declared parameters free), the one-step
screen of one pitch value, and the whole profiled identification (screen + refined screen + profile fits).
Prints the times, their ratios, and the pitch found.

Run: ``python bench/bench_backlash_profile.py``
"""

from __future__ import annotations

import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import thsa_control as thsa
from thsa_control.data.rigdata import read_run
from thsa_control.fit.identify import IdentificationSettings, Identifier, estimate_noise
from thsa_control.fit.profile import OneStepScreen, profile_identify
from thsa_control.fit.virtual_rig import VirtualRig
from thsa_control.loops.design import derive_gains
from thsa_control.model import build_plant

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from test_trace_backlash import NOISE, PITCH, TRUE_PITCH, _stops_scenario

FREE = ("gear.viscous_friction", "noback.mu_coulomb_pos", "noback.mu_coulomb_neg")


def main() -> None:
    params = thsa.default_parameters()
    rig = derive_gains(params, current_bandwidth_hz=150, velocity_crossover_hz=10, velocity_pi_zero_ratio=5,
                       position_bandwidth_hz=1, control_period_s=1e-3, name="rig_1kHz")
    with tempfile.TemporaryDirectory() as d:
        stem = Path(d) / "stops"
        VirtualRig("C", params=params.replace({PITCH: TRUE_PITCH}), design=rig, noise=NOISE, seed=1).record(
            _stops_scenario(), stem)
        run = dataclasses.replace(read_run(stem.with_suffix(".csv")), controller=None)
    chans = ("motor_speed", "nut_position", "screw_speed")
    st = IdentificationSettings(segment_duration=0.05, channels=chans, max_nfev=30, tolerance=1e-7,
                                noise={c: estimate_noise(run.signals[c]) for c in chans}, prior_relative_sd=0.1,
                                holdout_every=3)
    t0 = time.perf_counter()
    Identifier("C", params, FREE, settings=st).fit(run)
    t_fit = time.perf_counter() - t0
    screen = OneStepScreen([run], build_plant("C", params=params), params)
    t0 = time.perf_counter()
    for v in (0.08, 0.09, 0.1, 0.11, 0.12):
        screen.chi2(params.replace({PITCH: v}))
    t_screen = (time.perf_counter() - t0) / 5
    t0 = time.perf_counter()
    prof = profile_identify(run, params, FREE, {PITCH: (0.03, 0.3), "noback.pawl_initial_clearance": (0.0, 1.0)},
                            level="C", settings=st)
    t_prof = time.perf_counter() - t0
    n_screen = sum(len(v) for v in prof.screen.values())
    print(f"run: {run.time.size} samples; one plain level-C fit {t_fit:.2f} s; one screened pitch {1e3 * t_screen:.1f} ms")
    print(f"profiled fit {t_prof:.1f} s = {t_prof / t_fit:.1f} plain fits ({n_screen} screened values in "
          f"{prof.screen_time_s:.1f} s, {len(prof.fits)} profile fits)")
    lo, hi = prof.interval[PITCH] or (float("nan"), float("nan"))
    print(f"pitch {prof.values[PITCH]:.5f} rad (truth {TRUE_PITCH}), interval {lo:.5f}..{hi:.5f}")


if __name__ == "__main__":
    main()
