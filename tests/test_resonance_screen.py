"""The drive train's torsional mode read off a record (thsa_control.fit.resonance_screen): the start of the tracer's
drive-train compliance candidate.

Analytic cases: a motor speed of broadband content driving a gear-output side through a second-order spring of
known frequency and damping (the screen finds the frequency and a gain of about 1 / (2 zeta)); the same rigid drive
with a lag or a gain error on one speed sensor (no mode: the twist rate is then a rising or a flat |H|).  Round
trip through the plant's inertias: a record ringing at the mode of a gearbox stiffness gives that stiffness back.
rig-sim: its drive-train compliance records start near rig-sim's 8000 N m/rad in series; no other committed record
moves the start.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from scipy import signal

from thsa_control.data.rigdata import read_run
from thsa_control.fit.resonance_screen import MIN_PEAK_GAIN, drivetrain_resonance_start, twist_resonance
from thsa_control.model import build_plant
from thsa_control.model.laws import drivetrain_modes, drivetrain_stiffness

DATA = Path(__file__).resolve().parent / "data" / "rigsim"
FS = 500.0
N = 65.61


def _record(f_mode=None, zeta=0.05, lag_s=0.0, gain_error=0.0, seconds=10.0, seed=0, noise=0.05):
    """A run-like record: motor speed = 20 rad/s + band-limited noise (broadband up to 150 Hz); the gear-output
    speed its response through ``(2 zeta w s + w^2) / (s^2 + 2 zeta w s + w^2)`` (None: rigid); the screw-speed
    sensor that speed / N, lagged by ``lag_s`` (first order) and scaled by ``1 + gain_error``; white sensor noise."""
    rng = np.random.default_rng(seed)
    n = int(seconds * FS)
    t = np.arange(n) / FS
    b, a = signal.butter(4, 150.0 / (FS / 2))
    w = 20.0 + 5.0 * signal.lfilter(b, a, rng.standard_normal(n))
    if f_mode is None:
        wo = w.copy()
    else:
        wn = 2 * FS * math.tan(math.pi * f_mode / FS)  # prewarped: the bilinear map puts the digital mode at f_mode
        sys = signal.cont2discrete(([2 * zeta * wn, wn**2], [1.0, 2 * zeta * wn, wn**2]), 1.0 / FS, method="bilinear")
        wo = 20.0 + signal.lfilter(np.ravel(sys[0]), sys[1], w - 20.0)
    screw = wo / N
    if lag_s:
        sys = signal.cont2discrete(([1.0], [lag_s, 1.0]), 1.0 / FS, method="bilinear")
        screw = screw[0] + signal.lfilter(np.ravel(sys[0]), sys[1], screw - screw[0])
    screw = screw * (1.0 + gain_error)
    signals = {"motor_speed": w + noise * rng.standard_normal(n),
               "screw_speed": screw + noise / N * rng.standard_normal(n)}
    return SimpleNamespace(name="synthetic", time=t, signals=signals, source_columns=("motor_speed", "screw_speed"),
                           gear_ratio=N)


@pytest.mark.parametrize("f_mode, zeta", [(30.0, 0.05), (47.0, 0.03), (80.0, 0.08)])
def test_a_lightly_damped_mode_is_found_at_its_frequency(f_mode, zeta):
    """The peak of the twist rate over the motor speed is the gear-output mode (2 Hz resolution), its gain about
    1 / (2 zeta) (the spectral estimate smooths the peak over a bin: within 40 %)."""
    got = twist_resonance([_record(f_mode, zeta)])
    assert got is not None
    assert got["frequency_hz"] == pytest.approx(f_mode, abs=2.1), got
    assert got["gain"] == pytest.approx(1.0 / (2 * zeta), rel=0.4), got
    assert got["coherence"] > 0.6, got


@pytest.mark.parametrize("kw", [{}, {"lag_s": 0.02}, {"lag_s": 0.003}, {"gain_error": 0.02}, {"gain_error": -0.1},
                                {"f_mode": 47.0, "zeta": 0.5}])
def test_no_mode_where_the_sensors_disagree_otherwise(kw):
    """A rigid drive, one with a lag or a gain error on the screw-speed sensor (the twist rate's |H| rises with
    frequency, or is flat at the error), and a heavily damped mode (zeta 0.5: no ringing, gain 1): no mode, so the
    candidate keeps the file's start."""
    assert twist_resonance([_record(**kw)]) is None


def test_a_record_without_both_speed_sensors_or_too_short_shows_no_mode():
    rec = _record(47.0, 0.03)
    one = SimpleNamespace(**{**vars(rec), "source_columns": ("motor_speed",)})
    short = SimpleNamespace(**{**vars(rec), "time": rec.time[:400],
                               "signals": {k: v[:400] for k, v in rec.signals.items()}})
    assert twist_resonance([one]) is None and twist_resonance([short]) is None
    gap = SimpleNamespace(**{**vars(rec), "signals": {k: v.copy() for k, v in rec.signals.items()}})
    gap.signals["screw_speed"][100] = np.nan  # a dropout: the longest finite stretch is read
    assert twist_resonance([gap])["frequency_hz"] == pytest.approx(47.0, abs=2.1)


@pytest.mark.parametrize("k_gear", [6.0e3, 1.2e4, 3.0e4])
def test_the_start_is_the_stiffness_whose_mode_the_record_rings_at(params, k_gear):
    """Round trip through the plant's own inertias: a record ringing at the gear-output mode of a gearbox stiffness
    (the screw's held in series) starts the candidate at that stiffness, within what the 2 Hz resolution allows
    (the mode's frequency to a bin, the series stiffness to twice that, the gearbox's beyond it by k_gear / series)."""
    plant = build_plant("A", ["drivetrain_compliance"], params=params)
    j_main, j_rotors = plant.inertia(params)
    p = {n: params.value(n) for n in ("screw.torsional_stiffness", "gear.ratio")}
    k = drivetrain_stiffness({**p, "gear.torsional_stiffness": k_gear})
    f = drivetrain_modes(k, j_main, j_rotors, params.value("gear.efficiency"))[1] / (2 * math.pi)
    got = drivetrain_resonance_start(params, [_record(f, 0.04)])
    series = k * p["gear.ratio"] ** 2
    tol = 2 * (1.0 / f) * (k_gear / series)  # one 2 Hz bin, relative, through k ~ f^2 and the series split
    assert got["gear.torsional_stiffness"] == pytest.approx(k_gear, rel=tol * 2.0 + 0.02), (f, got)


def test_a_mode_stiffer_than_the_screw_alone_moves_no_start(params):
    """Above the mode of the screw's own stiffness (the gearbox infinitely stiff) no gearbox stiffness rings: the
    search stops below it, and the file's start stands."""
    assert drivetrain_resonance_start(params, [_record(140.0, 0.03)]) == {}


def test_rigsim_compliance_records_start_near_its_stiffness_and_no_other_record_moves(params):
    """rig-sim's drive-train compliance (8000 N m/rad in series, 2 N m s/rad: a mode near 47 Hz) on its speed chirp
    and its position steps: the start, in series with the file's screw, within 35 % of 8000 (the bin and rig-sim's
    gear-output inertia, which is not the file's).  On every other committed rig-sim record (nulls, the other library
    and out-of-library effects, run sets) the start stays the file's."""
    k_screw = params.value("screw.torsional_stiffness")
    moved = {}
    for path in sorted(DATA.glob("*.csv")) + sorted((DATA / "sets").glob("*.csv")):
        got = drivetrain_resonance_start(params, [read_run(path)])
        if got:
            moved[path.stem] = 1.0 / (1.0 / got["gear.torsional_stiffness"] + 1.0 / k_screw)
    planted = {p.stem for p in DATA.glob("*.truth.json")
               if "drivetrain_compliance" in json.loads(p.read_text())["effects"]}
    assert set(moved) == {n.removesuffix(".truth") for n in planted}, moved
    for n, series in moved.items():
        truth = json.loads((DATA / f"{n}.truth.json").read_text())["effects"]["drivetrain_compliance"]["params"]
        assert series == pytest.approx(truth["k_Nm_rad"]["si"], rel=0.35), (n, series)


def test_the_gain_threshold_is_a_lightly_damped_mode():
    """The threshold's meaning: a mode damped at 0.07 of critical rings at 1 / (2 x 0.07) = 7, above the threshold,
    found; at 0.2 (2.5, below it) not."""
    assert 1.0 / (2 * 0.07) > MIN_PEAK_GAIN > 1.0 / (2 * 0.2)
    assert twist_resonance([_record(47.0, 0.07)]) is not None
    assert twist_resonance([_record(47.0, 0.2)]) is None
