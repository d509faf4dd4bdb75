"""Which constant torques a run set separates: the tracer's separability diagnostic on CSVs, before tracing.

For each group of runs (one rig, traced together) it prints the variance inflation of the Coulomb drag, the axial
force and the direction drag against what a set trace on the ``rig`` base carries (the four base corrections, the
motor-side inertia, the detailed no-back's four disk coefficients, the declared viscous drag), at the parameter
file's values (:func:`thsa_control.trace.separability.separability`; above 10 the record's torques alone cannot tell
the explainer from the others).  Use it to choose the scenarios of a run set before tracing them
(docs/trace_notes.md, "Two load magnitudes of one sign").

Run: ``python bench/set_separability.py A.csv B.csv [-- C.csv D.csv ...]`` (groups separated by ``--``).
"""

from __future__ import annotations

import sys

from thsa_control.cli.common import read_runs
from thsa_control.model.params import default_parameters
from thsa_control.trace.separability import explainer_steps, separability

BASE = {"drive.coulomb_torque": "coulomb_friction", "drive.axial_force_offset": "force_offset",
        "screw.efficiency_direct": "efficiency", "screw.efficiency_inverse": "efficiency",
        "motor.rotor_inertia": "standby_motor",
        **{f"noback.{k}": "noback_quadrant_friction" for k in ("mu_coulomb_pos", "mu_coulomb_neg", "mu_static_pos",
                                                               "mu_static_neg")},
        "gear.viscous_friction": "declared"}
TARGETS = {"drive.coulomb_torque": "coulomb_friction", "drive.axial_force_offset": "force_offset",
           "drive.direction_coulomb_torque": "direction_friction"}
#: step magnitudes: the plausible bounds of the base corrections (trace/scoring.py), a direction drag of the size a
#: rig-sim run plants (4 N m at the screw = 0.06 N m at the motor)
MAGNITUDES = {"drive.coulomb_torque": 0.057, "drive.axial_force_offset": 400.0, "screw.efficiency_direct": 0.07,
              "screw.efficiency_inverse": 0.07, "drive.direction_coulomb_torque": 0.06}


def vifs(csvs: list[str], params=None) -> dict[str, tuple[float, list[str]]]:
    """effect -> (variance inflation, the explainers named beside it) on the runs ``csvs`` traced together."""
    params = params or default_parameters()
    runs = read_runs(csvs, None, params)  # as `thsa trace` reads them
    doc = separability(runs, ("standby_motor", "noback_quadrant_friction"), params, BASE, TARGETS,
                       explainer_steps(params, list(BASE) + list(TARGETS), {}, MAGNITUDES))
    return {e["effect"]: (e["vif"], e["same_part_as"]) for e in doc["explainers"].values()}


def main(argv: list[str]) -> int:
    groups, cur = [], []
    for a in argv:
        if a == "--":
            groups.append(cur)
            cur = []
        else:
            cur.append(a)
    groups.append(cur)
    groups = [g for g in groups if g]
    if not groups:
        print(__doc__)
        return 2
    print("| runs | Coulomb drag | axial force | direction drag |\n| --- | --- | --- | --- |")
    for g in groups:
        v = vifs(g)
        cells = [f"{v[e][0]:.3g}" if e in v else "-" for e in ("coulomb_friction", "force_offset", "direction_friction")]
        print(f"| {' + '.join(c.rsplit('/', 1)[-1].removesuffix('.csv') for c in g)} | {' | '.join(cells)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
