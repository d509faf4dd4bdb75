"""The repetition test of angle-periodic candidates (thsa_control.trace.periodicity; issue #21, rig-sim's
friction bump).

A ripple once per screw revolution is the same torque in every revolution: its held-out gain is spread over the
nut travel.  A fit of it to a friction bump at one nut position gains in the one lead that holds the bump and
loses elsewhere.  The statistic is exercised here on held-out segments built from a model of each (a
per-segment chi2 drop proportional to the torque the candidate explains there, plus the scatter of a chi2
difference); the traces of rig-sim's runs are judged in test_trace_foreign.py and below (slow).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from thsa_control.trace import periodicity

LEAD = 0.012
DATA = Path(__file__).resolve().parent / "data" / "rigsim"


def _segments(gain_of_x, seed=0, travel=0.045, seg=0.00075, scatter=3.0):
    """Held-out segments of one extension and one retraction over ``travel`` (every third 0.75 mm segment),
    each with the drop ``gain_of_x(mid) + scatter * N(0, 1)``."""
    rng = np.random.default_rng(seed)
    out = []
    for run in ("out", "back"):
        starts = np.arange(0.0, travel - seg, 3 * seg) + (seg if run == "back" else 0.0)
        for a in starts:
            mid = a + seg / 2
            out.append({"run": run, "drop": float(gain_of_x(mid) + scatter * rng.standard_normal()),
                        "x_min": float(a), "x_max": float(a + seg)})
    return out


def _ripple_gain(x):
    """A ripple explained everywhere: the gain follows the ripple's square, the same in every revolution."""
    return 40.0 * (1 + math.sin(2 * math.pi * x / LEAD + 0.7)) ** 2


def _bump_gain(centre, width=0.0015):
    """A ripple fitted to a bump: a gain where the bump is, the fitted ripple's cost everywhere else."""
    def g(x):
        return 400.0 * math.exp(-0.5 * ((x - centre) / width) ** 2) - 8.0 * (1 + math.sin(2 * math.pi * x / LEAD)) ** 2
    return g


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_ripple_gains_in_every_revolution(seed):
    segs = _segments(_ripple_gain, seed)
    t = periodicity.repetition_test(segs, LEAD, threshold=14.0)
    assert t["repeats"], t
    assert t["periods_gaining"] == t["periods_covered"] == 4
    assert t["left_out_share"] < 0.5  # one revolution of four carries about a quarter
    assert t["total_drop"] == pytest.approx(sum(s["drop"] for s in segs))


@pytest.mark.parametrize("centre", [0.005, 0.012, 0.0245, 0.040])
def test_a_gain_at_one_place_is_not_periodic(centre):
    """Wherever the bump is, also across the boundary of two leads counted from the start (12 mm, 24.5 mm): the
    period left out is placed where the gain is, not on a fixed grid."""
    segs = _segments(_bump_gain(centre), 4)
    t = periodicity.repetition_test(segs, LEAD, threshold=14.0)
    assert not t["repeats"], t
    assert t["left_out"][0] <= centre <= t["left_out"][1]
    assert t["rest_drop"] < 0 < t["total_drop"]
    assert periodicity.describe(t).startswith("not periodic over the travel")


def test_the_rest_must_pass_the_threshold_not_only_be_positive():
    """A bump with a small chance gain elsewhere: positive rest, below the held-out test's threshold."""
    def g(x):
        return 400.0 * math.exp(-0.5 * ((x - 0.02) / 0.0015) ** 2) + 0.5
    segs = _segments(g, 5, scatter=0.1)
    t = periodicity.repetition_test(segs, LEAD, threshold=60.0)
    assert 0 < t["rest_drop"] < 60.0 and not t["repeats"], t
    assert "does not pass the held-out test" in periodicity.describe(t)


def test_a_gain_at_two_places_is_not_periodic():
    """Two local structures a lead or more apart (a load path's two zero crossings on a load sweep): leaving out the
    period of the larger still leaves the other's gain above the threshold, but the typical period of travel loses,
    and a ripple gains in every period."""
    def g(x):
        bumps = sum(400.0 * math.exp(-0.5 * ((x - c) / 0.0015) ** 2) for c in (0.006, 0.032))
        return bumps - 2.0 * (1 + math.sin(2 * math.pi * x / LEAD)) ** 2

    segs = _segments(g, 7, travel=0.09)
    t = periodicity.repetition_test(segs, LEAD, threshold=14.0)
    assert t["rest_drop"] > t["threshold"], t  # the leave-one-out part alone would pass it
    assert t["median_period_drop"] < 0 and not t["repeats"], t
    assert "the typical period does not gain" in periodicity.describe(t)
    r = periodicity.repetition_test(_segments(_ripple_gain, 7, travel=0.09), LEAD, threshold=14.0)
    assert r["repeats"] and r["median_period_drop"] > 0, r


def test_less_than_two_periods_of_travel_is_not_testable():
    segs = _segments(_bump_gain(0.005), 6, travel=0.02)
    t = periodicity.repetition_test(segs, LEAD, threshold=14.0)
    assert t["repeats"] and "not testable" in t["reason"], t


def test_segment_drops_split_the_held_out_chi2_drop_by_nut_position():
    """Per held-out segment the noise-weighted drop of the masked held-out samples, with the segment's span of
    nut position; training segments and masked samples do not count."""
    n, seg = 300, 50
    t = np.arange(n) * 0.002
    starts = np.arange(0, n, seg)
    hold = np.zeros(n, bool)
    for s in starts[::3]:
        hold[s:s + seg] = True
    rng = np.random.default_rng(0)
    y = rng.standard_normal(n)
    before = {"predictions": {"r": {"time": t, "holdout": hold, "segment_starts": starts,
                                    "measured": {"motor_speed": y}, "simulated": {"motor_speed": y + 1.0}}}}
    after = {"predictions": {"r": {"time": t, "holdout": hold, "segment_starts": starts,
                                   "measured": {"motor_speed": y}, "simulated": {"motor_speed": y + 0.5}}}}
    x = np.linspace(0.0, 0.03, n)
    mask = {"r": np.ones(n, bool)}
    mask["r"][:10] = False
    segs = periodicity.segment_drops(before, after, {"motor_speed": 0.5}, {"r": x}, mask)
    assert len(segs) == 2  # held-out segments 0 and 3
    assert segs[0]["drop"] == pytest.approx((seg - 10) * (4.0 - 1.0))
    assert segs[1]["drop"] == pytest.approx(seg * 3.0)
    assert segs[0]["x_min"] == pytest.approx(x[10]) and segs[1]["x_max"] == pytest.approx(x[3 * seg + seg - 1])


# ----------------------------------------------------------------------------- on rig-sim's runs (slow)
def _traced(name, params):
    from thsa_control.data.rigdata import read_run
    from thsa_control.fit.kinematics import run_kinematics
    from thsa_control.trace import TraceSettings, trace

    run = run_kinematics(read_run(DATA / f"{name}.csv"), params)
    st = TraceSettings(workers=2, candidates=("noback_quadrant_friction", "screw_friction_ripple"),
                       base_corrections=True, max_effects=2)
    return trace(run, "A", params=params, settings=st).to_dict()


def _ripple(doc):
    return [c for r in doc["rounds"] for c in r["candidates"] if c["name"] == "screw_friction_ripple"]


@pytest.mark.slow
def test_ripple_fitted_to_a_friction_bump_is_refused_as_not_periodic(params):
    """rig-sim's friction bump (8 N m at the screw, Gaussian at 5 mm, 1.5 mm wide) on the 45 mm trim: the ripple
    fitted to it gains in the lead of travel that holds the bump and loses over the others: not added, the
    reason in trace.json, and the bump still flagged by the nut-position test."""
    doc = _traced("rig_friction_bump", params)
    assert "screw_friction_ripple" not in [e["name"] for e in doc["effects_added"]], doc["rounds"]
    fits = _ripple(doc)
    assert fits and all(not c["significant"] and c["not_periodic"].startswith("not periodic over the travel")
                        for c in fits), fits
    t = fits[0]["periodicity"]
    assert t["left_out"][0] <= 0.005 <= t["left_out"][1] and t["rest_drop"] < t["threshold"], t
    # the refusal names the local residual the ripple was fitted to: the nut-position test's peak, near 5 mm
    lo, hi = t["local_structure"]["peak_bin"]
    assert lo - 0.002 <= 0.005 <= hi + 0.002, t
    assert doc["unexplained"] and any("nut_position" in s for s in doc["residual_signature"]["structured"])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["rig_screw_ripple", "rig_pair_coulomb_ripple"])
def test_a_planted_ripple_repeats_over_the_travel(params, name):
    """rig-sim's ripple (3 N m (1 + sin(theta_s + 40 deg)) at the screw): the gain repeats in every lead of
    travel, the ripple is added."""
    doc = _traced(name, params)
    assert "screw_friction_ripple" in [e["name"] for e in doc["effects_added"]], doc["rounds"]
    t = _ripple(doc)[0]["periodicity"]
    assert t["repeats"] and t["periods_gaining"] == t["periods_covered"] >= 3, t


def test_a_period_shorter_than_two_position_bins_is_not_tested(params):
    """The cogging's period in nut travel (lead / (ratio x count): 0.03 mm at the file's 6 per revolution) is far
    shorter than two bins of the nut-position test: a drag local at the scale the tracer resolves has no
    component there, and one period left out would be one held-out segment.  The screw ripple's lead is tested."""
    from thsa_control.trace.candidates import CANDIDATES, PERIODS
    from thsa_control.trace.engine import _repetition
    from thsa_control.trace.signature import SignatureSettings

    fit = {"params_toml": params.to_toml(), "predictions": {}}
    two_bins = 2 * SignatureSettings().position_bin
    assert PERIODS["cogging_torque"](params) < two_bins <= PERIODS["screw_friction_ripple"](params)
    cog = _repetition(fit, fit, CANDIDATES["cogging_torque"], 3, [], {}, None, 1e-3, two_bins)
    assert cog["repeats"] and "not tested" in cog["reason"], cog
    rip = _repetition(fit, fit, CANDIDATES["screw_friction_ripple"], 2, [], {}, None, 1e-3, two_bins)
    assert "not tested" not in rip.get("reason", ""), rip


def _creep_segments(gains, span=0.3e-3):
    """Held-out segments of a creep over ``span`` of nut travel in time order, one per ``gains`` entry."""
    x = np.linspace(0.0, span, len(gains) + 1)
    return [{"run": "r", "drop": float(g), "x_min": float(a), "x_max": float(b)} for g, a, b in zip(gains, x[:-1], x[1:])]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_cogging_must_gain_in_both_halves_of_its_travel(seed):
    """A period too short to leave one out (the cogging): a gain spread over the travel passes in both halves; the
    same total made in one half (a structured remainder at one place, as the check_slow null of seed 622: 18.0 and
    4.5 against 20.5) does not; the halves are split at the median nut position, whatever the time order."""
    rng = np.random.default_rng(seed)
    spread = 40.0 + 3.0 * rng.standard_normal(6)
    t = periodicity.halves_test(_creep_segments(spread), threshold=20.0)
    assert t["repeats"] and t["total_drop"] == pytest.approx(spread.sum()), t
    assert t["half_segments"] == [3, 3] and min(t["half_drops"]) > 100.0
    one_place = np.r_[spread[:3] * 2.0, 3.0 * rng.standard_normal(3)]
    t = periodicity.halves_test(_creep_segments(one_place)[::-1], threshold=20.0)  # a retraction: reversed order
    assert not t["repeats"] and t["half_drops"][0] > 200.0 and t["half_drops"][1] < 20.0, t
    assert t["total_drop"] > 20.0  # the whole drop alone would have passed
    why = periodicity.describe(t)
    assert why.startswith("not periodic over the travel") and "weaker half" in why, why
    assert periodicity.halves_test(_creep_segments([50.0]), 20.0)["repeats"]  # one segment: not testable


def test_report_draws_the_drop_per_period_and_says_why():
    """The report's figure: one panel per tested candidate, a bar per period of travel, the verdict in the title;
    the summary line carries the refusal reason."""
    from thsa_control.report.trace import _periodic_tests, plot_periodicity

    t = periodicity.repetition_test(_segments(_bump_gain(0.005), 4), LEAD, threshold=14.0)
    cand = {"name": "screw_friction_ripple", "periodicity": t, "not_periodic": periodicity.describe(t)}
    doc = {"rounds": [{"round": 1, "candidates": [cand, {"name": "coulomb_friction"}]}]}
    assert [c["name"] for _, c in _periodic_tests(doc)] == ["screw_friction_ripple"]
    fig = plot_periodicity(doc)
    ax = fig.axes[0]
    assert len(ax.patches) == t["periods_covered"] == 4 and "NOT periodic" in ax.get_title()
    assert ax.get_xticklabels()[0].get_text() == "0..12 mm"
