"""Command line: the main job, single runs, and clear errors that write nothing."""

import json
import shutil
import subprocess

import pytest

from thsa_control.cli import main
from thsa_control.sim.scenarios import SCENARIOS


def test_scenarios_lists_all(capsys):
    assert main(["scenarios"]) == 0
    out = capsys.readouterr().out
    for name in SCENARIOS:
        assert name in out


def test_simulate_writes_run_and_plot(tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["simulate", "--scenario", "cold_ramp", "--level", "B", "--effects", "temperature_friction",
                 "--out", str(out)]) == 0
    assert {p.name for p in out.iterdir()} >= {"cold_ramp_B.csv", "cold_ramp_B.json", "cold_ramp_B.png",
                                               "summary.json", "parameters.toml"}
    meta = json.loads((out / "cold_ramp_B.json").read_text())
    assert meta["format"] == "thsa-rig-run/1" and meta["temperature_C"] == -30.0
    assert meta["generator"]["effects"] == ["temperature_friction", "noback_quadrant_friction"]


@pytest.mark.slow
def test_main_job_levels(tmp_path):
    out = tmp_path / "levels"
    assert main(["levels", "--levels", "B,C", "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["levels"]) == {"B", "C"}
    assert (out / "backdrive_bipolar_ramp_levels.png").stat().st_size > 10_000
    c = summary["levels"]["C"]["backdrive"]
    assert 0.1 < max(c["stop_backdrive_peak_of_command"]) < 0.6


@pytest.mark.parametrize("argv, message", [
    (["simulate", "--scenario", "no_such", "--level", "A"], "unknown scenario 'no_such'"),
    (["simulate", "--scenario", "cold_ramp", "--level", "Z"], "unknown model level 'Z'"),
    (["simulate", "--scenario", "cold_ramp", "--level", "A", "--effects", "magic"], "unknown effect 'magic'"),
    (["simulate", "--scenario", "cold_ramp", "--level", "A", "--temperature", "90"], "temperature 90"),
])
def test_bad_input_is_named_and_writes_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    assert main(argv + ["--out", str(out)]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_bad_design_and_parameter_files(tmp_path, capsys):
    design = tmp_path / "d.toml"
    design.write_text("control_period_s = 1e-4\n[current_loop]\nkp_V_per_A = 14\nki_V_per_A_s = 7700\n"
                      "[velocity_loop]\nkp_A_per_rad_s = 0.1\ncurrent_limit_A = 15\n[position_loop]\nkp_per_s = 10\n")
    out = tmp_path / "out"
    assert main(["simulate", "--scenario", "cold_ramp", "--level", "A", "--design", str(design), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "d.toml" in err and "velocity_loop.ki_A_per_rad" in err
    params = tmp_path / "p.toml"
    params.write_text("[noback]\npreload = -5\n")
    assert main(["simulate", "--scenario", "cold_ramp", "--level", "A", "--params", str(params), "--out", str(out)]) == 2
    assert "noback.preload" in capsys.readouterr().err
    assert not out.exists()


def test_failure_keeps_the_previous_output(tmp_path, capsys):
    out = tmp_path / "keep"
    out.mkdir()
    (out / "old.txt").write_text("previous results")
    assert main(["simulate", "--scenario", "nope", "--level", "A", "--out", str(out)]) == 2
    assert (out / "old.txt").read_text() == "previous results"


@pytest.mark.skipif(shutil.which("thsa") is None, reason="console script not installed (pip install -e .)")
def test_console_script_is_installed():
    proc = subprocess.run(["thsa", "scenarios"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "backdrive_bipolar_ramp" in proc.stdout
