"""Segmented open-loop residual (issue #11): restarted from the measured state every segment, it does not drift.

A plain screw drive (level A without its ideal no-back: the position integrates) recorded on the virtual rig
at 1 kHz with sensor noise; the faulty truth has a Coulomb friction of 0.05 N m at the motor shaft that the
model does not declare.  The whole-run open-loop replay driven by the measured current drifts away; the
segmented one stays at the noise level on the null run and shows the friction as a residual of opposite
signs in the two directions of motion; the inverse-model channel ``missing_torque`` measures it.  The same
is checked on the shipped example run, written by an independent reference simulator of the rig.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from handcalc import RIG_NOISE, example_disk_law

from thsa_control.cli import main
from thsa_control.data.rigdata import read_run
from thsa_control.errors import UsageError
from thsa_control.fit.replay import analyse_replay, replay_open_loop
from thsa_control.fit.segmented import MISSING_TORQUE, parse_segment, replay_segmented
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs
from thsa_control.model import build_plant

ROOT = Path(__file__).resolve().parents[1]
NOISE = RIG_NOISE
LVDT_NOISE = 5e-6  # [m]
COULOMB = 0.05  # [N m], at the motor shaft


@pytest.fixture(scope="module")
def runs(tmp_path_factory, params, rig_1khz):
    """``runs[(coulomb_torque, seed)]`` -> RigRun of a plain drive, 2.5 s bipolar excitation, no load."""
    rig = rig_1khz
    d = tmp_path_factory.mktemp("segments")
    out = {}
    for tc, seed in ((0.0, 1), (0.0, 2), (COULOMB, 1)):
        u = excitation_inputs(2.5, bipolar=True, load=0.0, control_period=1e-3, seed=seed)
        stem = d / f"plain_{int(tc * 1000)}_{seed}"
        effects = ("coulomb_friction",) if tc else ()
        VirtualRig(None, effects=effects, params=params.replace({"drive.coulomb_torque": tc}), design=rig,
                   noise=NOISE, seed=seed).record(u, stem)
        out[(tc, seed)] = read_run(stem.with_suffix(".csv"))
    return out


@pytest.fixture(scope="module")
def plain(params):
    return build_plant("A", remove=["noback_ideal"], params=params)


def _quarters(e: np.ndarray) -> np.ndarray:
    n = e.size
    return np.array([np.sqrt(np.nanmean(e[i * n // 4:(i + 1) * n // 4] ** 2)) for i in range(4)])


def test_whole_run_drifts_segmented_stays_bounded(runs, plain, params):
    """Faulty run: the whole-run nut-position residual grows with time far above the noise; the segmented one
    stays within twice the LVDT noise in every quarter of the run, without growing."""
    run = runs[(COULOMB, 1)]
    whole = replay_open_loop(run, plain, params)
    seg = replay_segmented(run, plain, params)
    assert whole.info["open_loop_replay"] == "whole_run" and seg.info["open_loop_replay"] == "segmented"
    assert seg.info["segment_s"] == pytest.approx(0.05) and seg.info["segments"] == 50
    qw = _quarters(whole.residual("nut_position"))
    qs = _quarters(seg.residual("nut_position"))
    assert qw[1:].max() > 20 * qw[0] and qw[1:].max() > 50 * LVDT_NOISE, qw  # drifts
    assert np.all(qs < 2 * LVDT_NOISE), qs  # one-segment errors: at the noise level
    assert qs.max() < 1.5 * qs.min(), qs  # and not growing


@pytest.mark.parametrize("seed", [1, 2])
def test_null_run_segmented_residual_is_noise(runs, plain, params, seed):
    """Null run (the truth is the declared model): the segmented nut-position residual is the LVDT noise
    (RMS within 25 % of it), the motor-speed residual does not depend on the direction of motion, and the
    missing torque is below a tenth of the friction the faulty run has, in each direction."""
    run = runs[(0.0, seed)]
    seg = replay_segmented(run, plain, params)
    rms = seg.fits["nut_position"].rms
    assert 0.75 * LVDT_NOISE < rms < 1.25 * LVDT_NOISE, rms
    a = analyse_replay(run, seg)
    assert a["motor_speed"].conditioned["direction"].eta_squared < 0.05
    d = a[MISSING_TORQUE].conditioned["direction"]
    for label in ("positive", "negative"):
        assert abs(d.bin(label).mean) < 0.1 * COULOMB, (label, d.bin(label).mean)


def test_faulty_run_residual_is_correlated_with_the_direction(runs, plain, params):
    """Faulty run: conditioned on the direction of motion, the segmented motor-speed residual has means of
    opposite signs (slower than predicted in either direction: a friction), each significant, and the
    direction explains most of its variance."""
    run = runs[(COULOMB, 1)]
    a = analyse_replay(run, replay_segmented(run, plain, params))
    d = a["motor_speed"].conditioned["direction"]
    pos, neg = d.bin("positive"), d.bin("negative")
    assert pos.mean < 0 < neg.mean, (pos.mean, neg.mean)
    assert pos.mean_significant and neg.mean_significant
    assert d.eta_squared > 0.5, d.eta_squared


def test_missing_torque_measures_the_coulomb_friction(runs, plain, params):
    """The inverse-model channel: its mean per direction of motion is the undeclared Coulomb torque within
    10 %, opposing the motion (-Tc moving positively, +Tc moving negatively), in N m."""
    run = runs[(COULOMB, 1)]
    seg = replay_segmented(run, plain, params)
    assert seg.fits[MISSING_TORQUE].unit == "N m"
    a = analyse_replay(run, seg)
    assert a[MISSING_TORQUE].unit == "N m"
    d = a[MISSING_TORQUE].conditioned["direction"]
    assert d.bin("positive").mean == pytest.approx(-COULOMB, rel=0.1), d.bin("positive").mean
    assert d.bin("negative").mean == pytest.approx(COULOMB, rel=0.1), d.bin("negative").mean


def _shared_example() -> Path:
    shared = os.environ.get("THSA_SHARED_DIR")
    base = Path(shared) if shared else ROOT / "tests" / "data"
    return base / "rig-data" / "examples" / "excitation_tensile_12kN.csv"


def test_independent_simulator_run_segmented_residual_is_bounded(params):
    """The shipped example (an independent reference simulator, 10 s, no-back friction under a 12 kN aiding
    load): the whole-run open-loop replay runs away (metres) at level A and at level B; the segmented one stays
    bounded over the run.  With the example's own no-back law (below) level B's segmented nut-position residual is
    several times smaller than level A's, near the sensor noise; with level B's file law it is still half A's.

    The example's simulator loads the slipping disk with preload + |F| (15 kN at its 12 kN), the reading of
    issue #8; level B's flange balance gives |F| alone beyond twice the preload.  At the example's one load the
    two differ by a factor (3 + 12) / 12 on the disk coefficients (handcalc.example_disk_law)."""
    run = read_run(_shared_example())
    load = float(np.median(np.abs(run.signals["load_force"])))
    assert load == pytest.approx(12e3, rel=0.02)
    example_law = example_disk_law(params, load)
    rms = {}
    for key, level, p in (("A", "A", params), ("B", "B", params), ("B, the example's disk law", "B", example_law)):
        plant = build_plant(level, params=p)
        whole = _quarters(replay_open_loop(run, plant, p).residual("nut_position"))
        seg = _quarters(replay_segmented(run, plant, p).residual("nut_position"))
        assert whole[-1] > 10 * whole[0] and whole[-1] > 0.1, whole
        assert seg.max() < 1.5 * seg.min(), seg
        rms[key] = float(np.sqrt(np.mean(seg ** 2)))
    assert rms["B, the example's disk law"] < 0.25 * rms["A"] and rms["B, the example's disk law"] < 3e-5, rms
    assert rms["B"] < 0.5 * rms["A"], rms


def test_cli_segmented_and_whole_run(runs, tmp_path, capsys):
    """`thsa residual --mode open_loop` is segmented by default (0.05 s) with the missing-torque channel, and
    says so in residuals.json and the HTML report; `--segment whole` is the whole-run replay."""
    csv = str(runs[(COULOMB, 1)].csv_path)
    base = ["residual", csv, "--model", "A", "--remove", "noback_ideal", "--mode", "open_loop", "--quiet"]
    assert main(base + ["--out", str(tmp_path / "seg")]) == 0
    doc = json.loads((tmp_path / "seg" / "residuals.json").read_text())
    assert doc["open_loop_replay"] == "segmented" and doc["segment_s"] == pytest.approx(0.05)
    assert doc["residuals"][MISSING_TORQUE]["unit"] == "N m"
    assert "every 0.05 s" in (tmp_path / "seg" / "report.html").read_text()
    assert main(base + ["--segment", "whole", "--out", str(tmp_path / "whole")]) == 0
    whole = json.loads((tmp_path / "whole" / "residuals.json").read_text())
    assert whole["open_loop_replay"] == "whole_run" and whole["segment_s"] is None
    assert MISSING_TORQUE not in whole["residuals"]
    assert whole["residuals"]["nut_position"]["rms"] > 20 * doc["residuals"]["nut_position"]["rms"]
    capsys.readouterr()


@pytest.mark.parametrize("value, message", [
    ("-0.05", "positive"), ("nan", "positive"), ("abc", "segment length"), ("10", "longer than run"),
    ("0.0005", "shorter than two samples"),
])
def test_cli_bad_segment_exit_2_nothing_written(runs, tmp_path, capsys, value, message):
    csv = str(runs[(0.0, 1)].csv_path)
    out = tmp_path / "out"
    assert main(["residual", csv, "--model", "A", "--remove", "noback_ideal", "--mode", "open_loop",
                 f"--segment={value}", "--quiet", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "segment" in err and message in err, err
    assert not out.exists()


def test_cli_segment_refused_in_closed_loop(runs, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["residual", str(runs[(0.0, 1)].csv_path), "--model", "A", "--remove", "noback_ideal",
                 "--mode", "closed_loop", "--segment", "0.05", "--quiet", "--out", str(out)]) == 2
    assert "open-loop" in capsys.readouterr().err
    assert not out.exists()


def test_parse_segment():
    assert parse_segment(None) == 0.05 and parse_segment("0.1") == 0.1
    assert parse_segment("whole") is None and parse_segment("0") is None
    for bad in ("-1", "inf", "x"):
        with pytest.raises(UsageError, match="segment"):
            parse_segment(bad)
