"""Fault-loop benchmark (issue #10): prints real-time factors measured in one run, on one core.

* a normal level-D run: ``backdrive_bipolar_ramp`` on plain level D (the simulator of issue #2);
* the same normal scenario on the fault plant with the monitors in the loop (level D + compliant
  drive train, torque limiter, secondary path, jam, brakes, claw stops, standby motor);
* the ``jam`` scenario on the fault plant, with the torque limiter slipping (stick/slip switching
  of the limiter and of the no-back in the same fixed step).

Target: the jam run keeps at least half the real-time factor of the normal level-D run (not met, or a
jam run whose limiter does not slip, exits 1).
Times are the best of 5 runs of the compiled loop (compile time excluded, printed once).

Run: ``python bench/bench_faults.py``
"""

from __future__ import annotations

import os
import sys
import time
from dataclasses import replace

os.environ.setdefault("OMP_NUM_THREADS", "1")
sys.stdout.reconfigure(line_buffering=True)

import numpy as np  # noqa: E402

import thsa_control as thsa  # noqa: E402
from thsa_control.faults.analysis import FAULT_PLANT_EFFECTS  # noqa: E402
from thsa_control.sim.monitor_settings import MonitorSettings  # noqa: E402
from thsa_control.loops.design import load_design, nominal_design_path  # noqa: E402
from thsa_control.sim.simulate import Simulator  # noqa: E402


def best(sim, scenario, design, params, n=5):
    res = sim.run(scenario, design, params)  # compiles (or loads from the cache)
    walls = []
    for _ in range(n):
        t0 = time.perf_counter()
        res = sim.run(scenario, design, params)
        walls.append(time.perf_counter() - t0)
    return min(walls), res


def main() -> int:
    params = thsa.default_parameters()
    design = load_design(nominal_design_path())
    normal = thsa.get_scenario("backdrive_bipolar_ramp")
    jam = thsa.get_scenario("jam")
    plain = Simulator(thsa.build_plant("D", params=params))
    fault = Simulator(thsa.build_plant("D", FAULT_PLANT_EFFECTS, params=params))
    w_plain, _ = best(plain, normal, design, params)
    w_fault_normal, _ = best(fault, replace(normal, monitors=MonitorSettings()), design, params)
    w_jam, res = best(fault, jam, design, params)
    slipping = float(np.mean(np.asarray(res["limiter_slipping"]) > 0.5))
    # the monitors not acting: the limiter slips from the jam to the end of the run
    w_slip, res_slip = best(fault, replace(jam, monitors=MonitorSettings(reconfigure=False)), design, params)
    rtf = {"normal D": normal.duration / w_plain, "normal on the fault plant": normal.duration / w_fault_normal,
           "jam (limiter slipping)": jam.duration / w_jam, "jam, slipping to the end": jam.duration / w_slip}
    for k, v in rtf.items():
        print(f"{k:28s} real-time factor {v:8.0f}")
    print(f"jam: limiter slipping in {slipping * 100:.1f} % of the output samples, safed at "
          f"{res.time[np.flatnonzero(np.asarray(res['safed']) > 0.5)[0]]:.3f} s")
    print(f"jam with the monitors not acting: limiter slipping in "
          f"{np.mean(np.asarray(res_slip['limiter_slipping']) > 0.5) * 100:.1f} % of the output samples")
    ratio = min(rtf["jam (limiter slipping)"], rtf["jam, slipping to the end"]) / rtf["normal D"]
    print(f"ratio jam (worse of the two) / normal level D: {ratio:.2f} (target >= 0.5: {'met' if ratio >= 0.5 else 'NOT met'}); "
          f"jam / normal on the same fault plant: {rtf['jam (limiter slipping)'] / rtf['normal on the fault plant']:.2f}")
    failures = []
    if not (slipping > 0 and np.mean(np.asarray(res_slip["limiter_slipping"]) > 0.5) > 0):
        failures.append("the jam runs did not slip the limiter: the ratio measures nothing")
    if ratio < 0.5:
        failures.append(f"target jam / normal >= 0.5 NOT met ({ratio:.2f})")
    for f in failures:
        print(f"FAILED: {f}")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
