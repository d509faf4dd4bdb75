"""The profile's comb check: a pawl pitch seen through one loaded stop after a long travel (issue #21).

One stop's back-drive depth is the screw travel since the pawl last engaged modulo the pitch, so every pitch
``p_k = (travel - depth) / k`` fits it: a comb of teeth.  After 30 mm of nut travel (15.7 rad of screw, about 110
pitches) the teeth are about 0.8 % of the pitch apart and each is narrower than 0.05 %: the profile's geometric grid
of 301 values (0.77 % apart) hits a few teeth near their bottom by chance and misses the others, and the teeth it hit
look like the only ones (rig-sim's bipolar tensile ramps, pawl pitch 0.1285 rad, quadrant no-back: the grid's set was
0.133..0.154 rad on the parameter file's values, 0.14239..0.1426 "determined" in the trace).  The comb check screens
the range again at a quarter of the best tooth's width (:class:`~thsa_control.fit.profile.ProfileSettings`
``comb_budget``).  The record is rig-sim's (tests/data/rigsim/make_runs.py, rig_pair_ratchet_quadrant_tensile).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.fit.identify import IdentificationSettings
from thsa_control.fit.profile import ProfileSettings, _tooth_width, profile_identify

DATA = Path(__file__).resolve().parent / "data" / "rigsim"
RECORD = "rig_pair_ratchet_quadrant_tensile"
PITCH, INITIAL = "noback.pawl_pitch", "noback.pawl_initial_clearance"
EFFECTS = ("standby_motor", "noback_backlash", "noback_quadrant_friction")


def test_tooth_width_is_the_span_between_the_values_either_side_of_the_run_within_the_threshold():
    x = np.geomspace(0.03, 0.3, 301)
    y = np.full(x.size, 100.0)
    y[150:153] = [5.0, 0.0, 8.0]  # a run of three values within 10 of the minimum
    w = _tooth_width(x, y, 10.0, geo=True)
    assert w == pytest.approx(math.log(x[153] / x[149]))
    assert _tooth_width(x, y, 1.0, geo=True) == pytest.approx(math.log(x[152] / x[150]))  # only the minimum
    lin = np.linspace(0.0, 1.0, 11)
    assert _tooth_width(lin, np.r_[0.0, np.full(10, 9.0)], 1.0, geo=False) == pytest.approx(0.1)  # at the range's end


def test_a_negative_comb_budget_is_refused_naming_the_field():
    with pytest.raises(ValueError, match="comb_budget"):
        ProfileSettings(comb_budget=-1).validate()


@pytest.mark.slow
def test_a_comb_of_narrow_teeth_is_screened_densely_and_not_determined(params):
    """On the committed rig-sim record, with the parameter file's values: the coarse screen's set excludes rig-sim's
    pitch; with the comb check the range is screened again densely, the pitch is not determined (a comb of many
    ranges) and the set's hull, the interval reported, holds rig-sim's pitch."""
    truth = json.loads((DATA / f"{RECORD}.truth.json").read_text())["effects"]["ratchet_backlash"]["params"]
    true_pitch = truth["pitch_deg"]["si"]
    run = read_run(DATA / f"{RECORD}.csv")
    st = IdentificationSettings(channels=("motor_speed",), noise={"motor_speed": 0.232}, max_nfev=10, holdout_every=3,
                                no_prior=("noback.mu_coulomb_neg",))

    def prof(budget):
        return profile_identify(run, params, ("noback.mu_coulomb_neg",), {PITCH: (0.03, 0.3), INITIAL: (0.0, 1.0)},
                                effects=EFFECTS, settings=st, psettings=ProfileSettings(comb_budget=budget),
                                fractions={INITIAL: PITCH})

    coarse = prof(0)
    lo0, hi0 = coarse.interval[PITCH]
    assert not lo0 <= true_pitch <= hi0, ("the record no longer shows a comb the coarse grid misses", lo0, hi0)
    assert "comb_check" not in coarse.determination[PITCH]
    res = prof(ProfileSettings().comb_budget)
    d = res.determination[PITCH]
    check = d["comb_check"]
    assert (check["dense"] and check["points"] > 10 * 301 and check["grid_step"] < check["coarse_tooth_width"] / 3
            and check["coarse_tooth_width"] < check["coarse_grid_step"]), check
    assert not d["determined"] and len(d["components"]) >= 3, d
    assert "comb of equal minima" in d["reason"]
    lo, hi = res.interval[PITCH]
    assert lo <= true_pitch <= hi, (lo, hi, true_pitch)


def test_a_dense_screens_teeth_a_coarse_step_apart_are_separate_ranges():
    """Teeth 1.5 coarse steps apart, resolved by a dense grid: merged at the coarse grid's resolution they read as one
    range whose inside the screen itself excludes; at the dense grid's resolution each tooth is its own range (the
    comb check's grid is the one the set is read at), and the reason lists a few of them by name."""
    from thsa_control.fit.profile import SHOWN_RANGES, profile_set

    lo, hi, coarse, dense = 0.03, 0.3, 301, 12001
    x = np.geomspace(lo, hi, dense)
    u = np.log(x)
    step = (u[-1] - u[0]) / (coarse - 1)
    centres = u[0] + step * (100 + 1.5 * np.arange(12))  # twelve teeth 1.5 coarse steps apart
    y = np.full(x.size, 1e4)
    for c in centres:
        y[np.abs(u - c) < 0.05 * step] = 0.0  # each much narrower than the coarse step
    merged = profile_set(x, y, 10.0, (lo, hi), coarse)
    assert len(merged["components"]) == 1  # what the set said before: one range holding the gaps between teeth
    got = profile_set(x, y, 10.0, (lo, hi), dense)
    assert len(got["components"]) == 12 and not got["determined"], got["components"]
    for (a, b), c in zip(got["components"], centres):
        assert a <= math.exp(c) <= b and math.log(b / a) < 0.1 * step
    assert got["share"] == pytest.approx(merged["share"])  # the hull, the interval reported, is the same
    listed = got["reason"].split(": ", 1)[1].split(", ")
    assert len(listed) == SHOWN_RANGES + 1 and listed[-2] == "... (all in `components`)", listed  # 7, "...", last


def test_a_flat_screen_is_not_determined_and_its_first_value_not_reported_as_chosen(params):
    """A ratchet that slips through its initial free travel once (rig-sim's cold check, tests/data/rigsim
    rig_pair_cogging_ratchet_cold): the one-step screen of the pitch is flat over the whole range, so one profile
    fit was made, at the screen's first value (0.03 rad, the range's end), and the trace reported it as the pitch.
    Now the pitch is not determined by the profile (no interval), the free travel (the initial clearance's product
    with the pitch) is kept, and the parameter file's pitch is held where its fit's score is within the gap the data
    resolve; where it is not, the fitted value is held and both scores are kept."""
    run = read_run(DATA / "rig_pair_cogging_ratchet_cold.csv")
    st = IdentificationSettings(channels=("motor_speed",), noise={"motor_speed": 0.232}, max_nfev=10, holdout_every=3,
                                no_prior=("noback.mu_coulomb_neg",))

    def prof(gap):
        return profile_identify(run, params, ("noback.mu_coulomb_neg",), {PITCH: (0.03, 0.3), INITIAL: (0.0, 1.0)},
                                effects=EFFECTS, settings=st, fractions={INITIAL: PITCH}, gap=gap)

    res = prof(None)  # no gap: every score difference within it, the file value held
    d = res.determination[PITCH]
    assert not res.mattered[PITCH] and res.mattered[INITIAL]
    assert d["flat"] and not d["determined"] and d["components"] == [] and res.interval[PITCH] is None
    assert d["value_if_free"] == pytest.approx(0.03) and d["held_at"] == res.values[PITCH] == params.value(PITCH)
    first = res.fits[0]["values"]
    assert first[PITCH] == pytest.approx(0.03)
    travel = first[PITCH] * first[INITIAL]  # the free travel the screen of the initial clearance chose
    assert res.values[PITCH] * res.values[INITIAL] == pytest.approx(travel, rel=1e-9)
    assert any("not determined" in n and "one-step screen" in n for n in res.notes), res.notes
    strict = prof(lambda r: 10.0)  # the file value's fit is far worse than the gap: the fitted value, said so
    ds = strict.determination[PITCH]
    assert not ds["determined"] and ds["file_score_above_best"] > 10.0
    assert ds["held_at"] == strict.values[PITCH] == pytest.approx(0.03)
