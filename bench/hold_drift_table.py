"""The load-cell drift test of the holds (``signature.hold_drift_test``) on rig runs, from the records alone.

``python bench/hold_drift_table.py RUN.csv [RUN.csv ...]`` prints, per run, the holds found, the load reading's slope
shared by the holds with its autocorrelation-corrected standard error and p-value, the LVDT's test of a real load
change, and whether the test flags a drift.  It needs no fit: the test reads the load cell and the LVDT where the
physics holds the load (``signature.hold_samples``), so it is the same in every round of a trace.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from thsa_control.data.rigdata import read_run
from thsa_control.trace.residual import hold_drift_of_runs


def main(paths: list[str]) -> int:
    print(f"{'run':<32} {'holds':>5} {'slope N/s':>10} {'+-':>6} {'p':>9} {'IACT':>5} {'LVDT z':>7} "
          f"{'seen N/s':>9} {'flag':>5}  per-hold slopes")
    for p in paths:
        run = read_run(Path(p))
        d = hold_drift_of_runs([run])
        if d is None:
            print(f"{Path(p).stem:<32} {'-':>5}  no hold of 0.2 s outside the base's transients")
            continue
        seen = d.get("load_rate_seen_by_lvdt")
        print(f"{Path(p).stem:<32} {d['holds']:>5} {d['slope']:>10.1f} {d['stderr']:>6.1f} {d['p_value']:>9.2g} "
              f"{d['iact']:>5.1f} {d.get('lvdt_z_toward_load_change', np.nan):>7.2f} "
              f"{(seen if seen is not None else np.nan):>9.1f} {d['significant']!s:>5}  "
              + " ".join(f"{v:.0f}+-{e:.0f}" for v, e in zip(d["per_hold_slopes"], d["per_hold_stderr"])))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
