"""Identifiability before plausibility (issue #21, item 1): one rule decides whether a candidate's parameter is
not determined by the run (held at its file value, reported) or collapses to zero (the effect refused)."""

from __future__ import annotations

import math
import pickle

import pytest

from thsa_control.trace import CANDIDATES
from thsa_control.trace.engine import parts_not_shown
from thsa_control.trace.scoring import _ci95, _param_entry, _plausibility, determination, zero_is_absent

Z = 2.0


@pytest.mark.parametrize("value, sd, ref, expected", [
    # one-temperature cold run: the viscous temperature coefficient, file value 0.02 1/K
    (0.00075, 0.0056, 0.02, "zero"),  # the data tell zero from 0.02 (3.6 sd apart) and say zero
    (0.00075, 0.05, 0.02, "not determined"),  # within 2 sd of zero and of 0.02: the run cannot tell
    (None, None, 0.02, "not determined"),  # a null direction of the Fisher information
    (0.05, 0.01, 0.02, "determined"),  # 5 sd from zero: present (larger than the file says)
    (0.5, 0.2, 0.02, "determined"),  # poorly known, but not zero
    (-0.03, 0.01, 0.02, "determined"),  # the sign is the data's
])
def test_one_rule_for_not_determined_and_collapses_to_zero(value, sd, ref, expected):
    assert determination(value if value is not None else 0.0, sd, ref, Z) == expected


def test_the_verdict_is_consistent_at_the_boundary():
    """Between the two verdicts nothing is left undecided: moving the estimate from zero to the reference
    magnitude goes zero -> not determined -> determined, never back."""
    ref, sd = 1.0, 0.3  # zero and ref 3.3 sd apart
    order = {"zero": 0, "not determined": 1, "determined": 2}
    seen = [order[determination(v, sd, ref, Z)] for v in [i / 100 for i in range(0, 150)]]
    assert seen == sorted(seen) and set(seen) == {0, 1, 2}
    ref, sd = 1.0, 0.6  # less than 2 x 2 sd apart: never "zero"
    assert {determination(v / 100, sd, ref, Z) for v in range(0, 150)} == {"not determined", "determined"}


def test_zero_collapses_only_what_zero_removes():
    """A friction coefficient at zero removes its effect; a compliance's stiffness, damping or a signed free play
    does not (its effect has no neutral value): there the rule is the standard error against the reference
    magnitude, and "collapses to zero" is never the verdict."""
    assert zero_is_absent("temperature_friction", "friction.viscous_temperature_coefficient")
    assert zero_is_absent("noback_quadrant_friction", "noback.mu_coulomb_neg")
    assert zero_is_absent("coulomb_friction", "drive.coulomb_torque")
    assert not zero_is_absent("drivetrain_compliance", "gear.torsional_damping")
    assert not zero_is_absent("loadpath_compliance", "loadpath.backlash")
    assert determination(0.1, 1.0, 20.0, Z, zero_is_absent=False) == "determined"
    assert determination(2.0, 25.0, 20.0, Z, zero_is_absent=False) == "not determined"


def test_drivetrain_damping_is_a_second_stage_parameter():
    """The damping of the drive-train mode is freed only once the stiffness is determined (freed from the
    start it stands in for a lag on rigid data)."""
    spec = CANDIDATES["drivetrain_compliance"]
    assert spec.free == ("gear.torsional_stiffness",)
    assert spec.second_stage == ("gear.torsional_damping",)


def test_noback_load_share_is_a_second_stage_parameter():
    """The no-back's load share is freed from the disk coefficients the run determines (freed with them, it traded
    with the light disk's coefficients where the band both sets share is thin), judged against its assumed spread."""
    spec = CANDIDATES["noback_quadrant_friction"]
    assert "noback.load_share" not in spec.free and spec.second_stage == ("noback.load_share",)
    assert 0 < spec.resolution["noback.load_share"] < 0.5


def test_interval_of_a_positive_parameter_stays_positive():
    """A stiffness (search bound above zero) poorly determined: its 95 % interval is symmetric in the logarithm, so it
    never reaches zero, holds the estimate with the Wald interval's coverage in log space (sd(log v) = sd / v), and
    comes back to the Wald interval when the relative error is small; a parameter that may take either sign keeps
    the Wald interval."""
    v, sd = 1.983e7, 1.044e7  # a contact stiffness on a reversal null (Wald: -6.4e5 .. 4.0e7 N/m)
    (lo, hi), scale = _ci95(v, sd, 1e3)
    assert scale == "log" and 0 < lo < v < hi
    assert math.log(hi / v) == pytest.approx(math.log(v / lo)) == pytest.approx(1.96 * sd / v)
    (lo, hi), _ = _ci95(v, 1e-3 * v, 1e3)
    assert (lo, hi) == pytest.approx((v - 1.96e-3 * v, v + 1.96e-3 * v), rel=1e-5)
    (lo, hi), scale = _ci95(-300.0, 200.0, -1e4)  # an axial force offset: either sign
    assert scale == "wald" and (lo, hi) == pytest.approx((-692.0, 92.0))
    e = {"value": v, "stderr": sd, "unit": "N/m", "at_bound": None, "min": 1e3}
    assert _param_entry(e)["ci95_scale"] == "log" and _param_entry(e)["ci95"][0] > 0


def test_a_declared_components_coefficient_at_zero_is_a_part_not_shown_only_beside_one_that_shows():
    """The base step's rule for a declared component's detailed model (engine.parts_not_shown): the light disk's
    static coefficient determined at zero beside a loaded-disk coefficient determined away from zero is a part the
    run does not show (reported, no refusal); every determined coefficient at zero is a component without friction
    and stays refused; other reasons always stay."""
    spec = CANDIDATES["noback_quadrant_friction"]

    def fit(**det):
        # the fields _plausibility reads: a value, its standard errors, the run's verdict, a bound
        est = {n: {"value": 1e-4, "stderr": None, "stderr_data": None, "at_bound": None,
                   "determination": det.get(n.split(".")[1], "not determined")} for n in spec.free}
        est["noback.mu_static_pos"].update(value=0.000483, stderr=0.00037, stderr_data=0.00037)
        est["noback.mu_coulomb_neg"].update(value=0.02, stderr=0.001, stderr_data=0.001, at_bound="max")
        return {"estimates": est}

    f = fit(mu_static_pos="zero", mu_coulomb_neg="determined")
    why = _plausibility(f, spec)[1]
    assert [str(w) for w in why] == ["noback.mu_coulomb_neg at its max bound",
                                     "noback.mu_static_pos = 0.000483 collapses to zero (stderr 0.00037 from the run)"]
    kept, parts = parts_not_shown(f, spec, why)
    assert parts == why[1:] and kept == why[:1]
    # the rule reads the reason's kind and parameter, not its wording: a plain text saying the same is no reason
    # it moves (an admission test's failure is a plain text)
    assert parts_not_shown(f, spec, [str(w) for w in why]) == ([str(w) for w in why], [])
    # a reason keeps its kind through a worker's pickle
    assert pickle.loads(pickle.dumps(why[1])).kind == "zero" and pickle.loads(pickle.dumps(why[1])).param == \
        "noback.mu_static_pos"
    # nothing else shows: the collapse is a verdict on the detail
    assert parts_not_shown(fit(mu_static_pos="zero", mu_coulomb_neg="zero"), spec, why) == (why, [])
    assert parts_not_shown(fit(mu_static_pos="zero"), spec, why) == (why, [])
    # a held coefficient is no evidence either way
    held = fit(mu_static_pos="zero", mu_coulomb_neg="determined")
    held["estimates"]["noback.mu_coulomb_neg"]["held"] = True
    assert parts_not_shown(held, spec, why) == (why, [])


def test_a_load_share_outside_its_assumed_range_is_said_not_refused():
    """A share the run determines beyond the assumed 0.4..0.6 (rig-sim's rig-base no-back, no disk pair, read 0.61
    on two run sets) is reported with the range it leaves, in trace.json and the report's line; inside the range and
    held, nothing is added."""
    from thsa_control.report.trace import _outside
    from thsa_control.trace.engine import _params_out

    spec = CANDIDATES["noback_quadrant_friction"]

    def fit(share, held=False):
        est = {n: {"value": 0.005, "stderr": 1e-5, "init": 0.005, "at_bound": None, "min": 0.0, "max": 1.0,
                   "unit": "N m/N"} for n in spec.free}
        est["noback.load_share"] = {"value": share, "stderr": None if held else 0.01, "init": 0.5, "at_bound": None,
                                    "min": 0.0, "max": 1.0, "unit": "-", **({"held": True} if held else {})}
        return {"estimates": est}

    out = _params_out(fit(0.61), spec)["noback.load_share"]
    assert out["assumed_range"] == pytest.approx([0.4, 0.6]) and out["outside_assumed_range"] is True
    assert "outside the assumed 0.4..0.6" in _outside(out)
    inside = _params_out(fit(0.483), spec)["noback.load_share"]
    assert inside["outside_assumed_range"] is False and _outside(inside) == ""
    held = _params_out(fit(0.5, held=True), spec)["noback.load_share"]
    assert "outside_assumed_range" not in held and _outside(held) == ""
    assert "assumed_range" not in _params_out(fit(0.61), spec)["noback.mu_coulomb_neg"]
