"""A breakaway localised in nut position (issue #21, rig-sim's out-of-library worn spot): the drive's breakaway
current at starts and reversals compared between events of one class at different places.

Synthetic records and events for the event detection and the test's level; the committed rig-sim runs (the worn
spot on cold ramps with two extension starts, its null, the reversal record that cannot separate it) for the
behaviour on data the workbench did not write.  Fast (no fits).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.trace.residual import breakaway_of_runs
from thsa_control.trace.signature import (
    SignatureSettings,
    breakaway_events,
    breakaway_position_test,
    remainder_kind,
)

DATA = Path(__file__).parent / "data" / "rigsim"


def _starts_record(extra=(0.0, 0.0), loads=(30e3, 30e3), noise=0.03, seed=0, dt=2e-3):
    """Two extension ramps from rest (drive off between), each with a breakaway current peak 1.5 A above the kinetic
    2 A (+ ``extra``) just before the speed leaves the stop band; the nut travels 27.8 mm in the first ramp."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 9.0, dt)
    v = np.zeros(t.size)  # nut speed [m/s]
    w = np.zeros(t.size)
    i = np.zeros(t.size)
    f = np.full(t.size, loads[0])
    f[t > 4.5] = loads[1]
    for k, (t0, t1) in enumerate(((1.0, 4.0), (5.5, 8.5))):
        on = (t >= t0) & (t < t1)
        v[on] = np.minimum((t[on] - t0 - 0.05) * 0.03, 0.01).clip(0.0)  # 30 mm/s^2 to 10 mm/s after 50 ms stuck
        kin = 2.0 * loads[k] / 30e3
        i[on] = kin + (1.5 + extra[k]) * np.exp(-0.5 * ((t[on] - t0 - 0.05) / 0.012) ** 2)
    w = v * 2 * np.pi / 0.012 * 65.61
    x = np.cumsum(v) * dt
    i = i + noise * rng.standard_normal(t.size)
    cmd = np.where(v > 0, 0.01, 0.0)
    cmd[(t >= 1.0) & (t < 4.0)] = 0.01
    cmd[(t >= 5.5) & (t < 8.5)] = 0.01
    return t, w, f, cmd, x, i


def _events(rec, noise=0.03):
    t, w, f, cmd, x, i = rec
    return [{**e, "noise": noise, "iact": 1.0} for e in breakaway_events(t, w, f, cmd, x, i)]


def test_breakaway_events_measure_the_peak_above_the_kinetic_current():
    ev = _events(_starts_record())
    assert [e["kind"] for e in ev] == ["start", "start"]
    assert [e["direction"] for e in ev] == [1, 1]
    assert ev[0]["position"] == pytest.approx(0.0, abs=1e-4) and ev[1]["position"] == pytest.approx(0.0278, abs=1e-3)
    for e in ev:
        assert e["kinetic"] == pytest.approx(2.0, abs=0.02)
        # a mean of five samples around a Gaussian peak of 12 ms at 2 ms sampling: 97 % of its height, + noise
        assert e["excess"] == pytest.approx(1.5 * 0.97, abs=0.08)


def test_a_breakaway_larger_at_one_start_is_flagged_at_its_place_and_equal_ones_are_not():
    flat = breakaway_position_test(_events(_starts_record()))
    assert flat is not None and not flat["significant"] and flat["dof"] == 1
    spot = breakaway_position_test(_events(_starts_record(extra=(0.3, 0.0))))
    assert spot["significant"] and spot["law"] == "more breakaway at one place"
    assert spot["peak_position"] == pytest.approx(0.0, abs=1e-3)
    assert spot["peak_deviation"] == pytest.approx(0.3, abs=0.08)
    assert remainder_kind(spot, 0.0, SignatureSettings()) == "structured"


def test_starts_under_different_loads_are_not_compared():
    """The base's breakaway follows the load (a no-back's static disk): two starts at 30 and 50 kN are two classes,
    so a breakaway proportional to the load is no position feature (the test does not run)."""
    rec = _starts_record(extra=(0.0, 1.0), loads=(30e3, 50e3))
    assert breakaway_position_test(_events(rec)) is None


def _synthetic_events(rng, scatter=0.0):
    """Two classes: one with two places of three replicate events each, one with three places of one event; each
    excess the current noise's mean (0.03 A over 5 and 150 samples) plus a base scatter ``scatter`` [A]."""
    out = []
    for kind, places, reps in (("start", (0.0, 0.01), 3), ("reversal", (0.0, 0.01, 0.02), 1)):
        for x in places:
            for _ in range(reps):
                sd = 0.03 * np.sqrt(1 / 5 + 1 / 150)
                out.append({"kind": kind, "direction": 1, "position": x + 1e-4 * rng.standard_normal(), "load": 25e3,
                            "speed_cmd": 0.006, "excess": 2.0 + sd * rng.standard_normal() + scatter * rng.standard_normal(),
                            "peak_samples": 5, "kinetic_samples": 150, "noise": 0.03, "iact": 1.0})
    return out


@pytest.mark.parametrize("scatter", [0.0, 0.02, 0.05])
def test_false_alarm_rate_is_the_level(scatter):
    """Events without a position feature: rejected at 0.05 in about 5 % of 400 seeds (binomial sd 1.1 %), with the
    current noise alone and with a base scatter 1.5 and 3.7 x the noise that the replicates' Birge ratio takes up
    (on 1000 seeds: 4.4, 6.1, 4.8 % at 0.05; 1.2, 1.7, 1.0 % at 0.01)."""
    rng = np.random.default_rng(7)
    p = np.array([breakaway_position_test(_synthetic_events(rng, scatter))["p_value"] for _ in range(400)])
    assert 0.025 <= np.mean(p < 0.05) <= 0.08, np.mean(p < 0.05)


def test_worn_spot_on_cold_ramps_is_flagged_where_the_first_start_is():
    """rig-sim's default worn spot (15 N m at the screw, x_c 0, 1 mm) on cold ramps: the extension start at -0.6 mm
    breaks away with more current than the same start at 30.8 mm; the same scenario's null does not."""
    name = "rig_worn_spot_stiction_cold"
    truth = json.loads((DATA / f"{name}.truth.json").read_text())["effects"]["worn_spot_stiction"]["params"]
    b = breakaway_of_runs([read_run(DATA / f"{name}.csv")])
    assert b["significant"] and b["p_value"] < 1e-4, b
    assert b["law"] == "more breakaway at one place"
    assert abs(b["peak_position"] - truth["x_c_mm"]["si"]) < truth["width_mm"]["si"], b["places"]
    null = breakaway_of_runs([read_run(DATA / "null_rig_cold2_s262.csv")])
    assert null is not None and not null["significant"], null


@pytest.mark.parametrize("name", ["rig_worn_spot_stiction", "null_rig_reversals_s303", "rig_friction_bump",
                                  "rig_noback_quadrant", "rig_ratchet_backlash"])
def test_records_with_each_kind_of_event_at_one_place_are_not_tested(name):
    """Reversals under load (each kind of event at one place, replicated), trim and bipolar ramps (one start each way):
    no class is seen at two places, so a breakaway at one place is not told from the base's breakaway of that kind
    of event; the test does not run (the committed worn spot on reversals stays not flagged: KNOWN_FAILING)."""
    assert breakaway_of_runs([read_run(DATA / f"{name}.csv")]) is None


def test_an_event_without_a_position_reading_is_left_out():
    """A missing LVDT sample where the nut breaks away gives the event no place: it is left out, not placed at NaN."""
    t, w, f, cmd, x, i = _starts_record(extra=(0.3, 0.0))
    k = int(np.argmax(w > 0.05 * np.max(w)))  # the first event's sample
    x = x.copy()
    x[k] = np.nan
    ev = breakaway_events(t, w, f, cmd, x, i)
    assert len(ev) == 1 and ev[0]["position"] == pytest.approx(0.0278, abs=1e-3)


def test_a_class_spans_no_more_than_its_load_gap():
    """Starts at loads 0 .. 9.9 kN in 900 N steps (each step under the 1 kN class gap): the classes are cut against
    their first event, so no class spans more than the gap (chained against the previous event, all twelve were one
    class and a start at 0 N was compared with one at 9.9 kN)."""
    from thsa_control.trace.signature import BREAKAWAY_LOAD_GAP, _classes

    ev = [{"kind": "start", "direction": 1, "load": 900.0 * k, "speed_cmd": 0.006, "position": 0.0} for k in range(12)]
    classes = _classes(ev, BREAKAWAY_LOAD_GAP, 1.1)
    assert len(classes) >= 2
    for c in classes:
        loads = [e["load"] for e in c]
        assert max(loads) - min(loads) <= BREAKAWAY_LOAD_GAP, loads
    assert sorted(e["load"] for c in classes for e in c) == [900.0 * k for k in range(12)]


def test_a_cold_run_and_a_warm_run_are_not_compared():
    """A set of two runs of one rig: a cold run (-30 degC) whose extension start at 0 mm breaks away 0.3 A harder (cold
    grease) than the warm run's (25 degC) at 30 mm.  Same kind, direction, load and speed, but 55 K apart: two classes
    of one place each, so no worn spot is made of the temperature (pooled, it was flagged at 0 mm)."""
    cold = _events(_starts_record(seed=1))[:1]
    warm = _events(_starts_record(seed=2))[1:]
    cold[0]["excess"] += 0.3
    ev = [{**cold[0], "run": "cold", "temperature": -30.0}, {**warm[0], "run": "warm", "temperature": 25.0}]
    assert breakaway_position_test(ev) is None
    # at one temperature the same pair is compared (and the 0.3 A is a place's)
    same = [{**e, "temperature": 25.0} for e in ev]
    b = breakaway_position_test(same)
    assert b is not None and b["significant"] and b["peak_position"] == pytest.approx(0.0, abs=1e-3)


def test_without_replicates_the_sample_based_level_judges():
    """No class has two events at one place: the error is the IACT-corrected sample noise alone, judged at the
    sample-based level (1e-6), not the replicate-based one (1e-4).  A 0.1 A harder start (p 4e-5 on this seed) is
    significant at 1e-4 and not at 1e-6."""
    ev = _events(_starts_record(extra=(0.1, 0.0), seed=4))
    b = breakaway_position_test(ev, alpha=1e-4, sample_alpha=1e-6)
    assert b["replicate_dof"] == 0 and b["level"] == 1e-6
    assert 1e-6 < b["p_value"] < 1e-4 and not b["significant"], b["p_value"]


def test_an_empty_current_cell_at_the_peak_leaves_the_event_out():
    """A missing current sample among those averaged at the peak (just outside the window checked for finite
    currents) gives no excess: the event is left out, not given a NaN excess."""
    from thsa_control.trace.signature import BREAKAWAY_PEAK_SAMPLES, BREAKAWAY_WINDOW

    t, w, f, cmd, x, i = _starts_record(extra=(0.3, 0.0))
    k = int(np.argmax(w > 0.05 * np.max(w)))
    win = np.flatnonzero(np.abs(t - t[k]) <= BREAKAWAY_WINDOW)
    j = win[int(np.argmax(i[win]))]
    i = i.copy()
    # the peak at the window's edge, and the averaged sample beyond it empty
    i[win[-1]] = 10.0
    i[win[-1] + 1] = np.nan
    assert BREAKAWAY_PEAK_SAMPLES // 2 >= 1 and j in win
    ev = breakaway_events(t, w, f, cmd, x, i)
    assert all(np.isfinite(e["excess"]) for e in ev)
    assert len(ev) == 1 and ev[0]["position"] == pytest.approx(0.0278, abs=1e-3)


def test_stretches_of_an_empty_mask_are_none():
    from thsa_control.trace.signature import stretches

    assert stretches(np.zeros(10, bool)) == []
    assert [q.tolist() for q in stretches(np.array([1, 1, 0, 1, 1, 1], bool), np.array([1, 1, 1, 1, -1, -1]))] == \
        [[0, 1], [3], [4, 5]]
