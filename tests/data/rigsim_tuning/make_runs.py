"""Rig runs of the nominal and the README's tuned design on rig-sim (an independent plant), for issue #20.

Writes, next to this script, each design's controller block (``<design>.controller.json``, from the design
file: current and velocity PI, clamps, period, computation delay) and runs rig-sim's ``cold_ramp`` and
``reversals_under_load`` with it at -55, -30, 25 and 70 degC on its ``rig`` base with ``temp_friction``
(the cold physics), recorded at 250 Hz to keep the files small: ``<design>_<scenario>_<T>.csv/.json``
(the truth files are not kept).

Usage: ``python tests/data/rigsim_tuning/make_runs.py RIGSIM_DIR`` (the folder holding rigsim.py; default
the shared rig-sim next to the repository).  Deterministic (rig-sim's seed 1).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tomllib
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
DESIGNS = {"nominal": ROOT / "designs" / "nominal.toml", "tuned": ROOT / "designs" / "mytuned.toml"}
SCENARIOS = ("cold_ramp", "reversals_under_load")
TEMPERATURES = (-55, -30, 25, 70)
RECORD_HZ = 250


def controller_block(path: Path) -> dict:
    d = tomllib.loads(path.read_text(encoding="utf-8"))
    cl, vl = d["current_loop"], d["velocity_loop"]
    out = {"velocity_loop": {"kp_A_per_rad_s": vl["kp_A_per_rad_s"], "ki_A_per_rad": vl["ki_A_per_rad"],
                             "current_limit_A": vl["current_limit_A"]},
           "current_loop": {"kp_V_per_A": cl["kp_V_per_A"], "ki_V_per_A_s": cl["ki_V_per_A_s"]},
           "control_period_s": d["control_period_s"],
           "computation_delay_samples": d.get("computation_delay_samples", 0)}
    if "voltage_limit_V" in cl:
        out["current_loop"]["voltage_limit_V"] = cl["voltage_limit_V"]
    return out


def main(rigsim_dir: Path) -> None:
    rigsim = rigsim_dir / "rigsim.py"
    for name, path in DESIGNS.items():
        ctrl = HERE / f"{name}.controller.json"
        ctrl.write_text(json.dumps(controller_block(path), indent=2) + "\n", encoding="utf-8")
        for sc in SCENARIOS:
            for T in TEMPERATURES:
                stem = f"{name}_{sc}_{'m' if T < 0 else ''}{abs(T)}C"
                subprocess.run([sys.executable, str(rigsim), "--scenario", sc, "--base", "rig", "--effects",
                                "temp_friction", "--temperature", str(T), "--controller", str(ctrl),
                                "--record-hz", str(RECORD_HZ), "--out", str(HERE), "--name", stem], check=True)
                (HERE / f"{stem}.truth.json").unlink(missing_ok=True)
                print("wrote", stem)


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT.parent / "shared" / "rig-sim")
