"""The torque constant drifting in time, from the records alone (``trace.signature.current_drift_test``): one line
per run with the comparable passes, the shared relative rate of the current, its p, the drag alternative and the
verdict.  ``python bench/kt_current_drift_table.py RUN.csv [RUN.csv ...]`` (a measurement for docs/trace_notes.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

from thsa_control.cli.common import read_runs
from thsa_control.model.params import default_parameters
from thsa_control.trace.residual import current_drift_of_runs


def main(paths: list[str]) -> int:
    params = default_parameters()
    for p in paths:
        d = current_drift_of_runs(read_runs([p], None, params), params)  # as `thsa trace` reads it
        name = Path(p).stem
        if d is None:
            print(f"{name:<36} no class of comparable passes with a pass to spare")
            continue
        dr = d["drag_alternative"]
        cl = " + ".join(str(len(c["passes"])) for c in d["classes"])
        print(f"{name:<36} passes {cl:<9} rate {1e3 * d['relative_rate']:+6.3f}e-3 +- {1e3 * d['stderr']:.3f}e-3 /s "
              f"p {d['p_value']:.2g} (chi2/dof {d['overdispersion']:.2f}, dof {d['dof']}); drag {1e3 * dr['rate']:+.2f} "
              f"mA/s p {dr['p_value']:.2g}, vif {dr['vif']:.3g}"
              + (f", kt beyond drag p {dr['torque_constant_beyond_drag_p']:.2g}, drag beyond kt p "
                 f"{dr['drag_beyond_torque_constant_p']:.2g}" if "drag_beyond_torque_constant_p" in dr else "")
              + f"; housing {d['housing_temperature_span']:.2f} K: {d['verdict']}"
              + ("  <- FLAGGED" if d["significant"] else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
