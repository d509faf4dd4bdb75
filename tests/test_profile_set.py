"""The profile-likelihood set of a profiled parameter and its determination rule (issue #21 item 1).

A parameter that acts through a switch (the no-back's pawl pitch) is profiled, not fitted; its local
curvature says nothing when the profile has a comb of equal minima (one stop's depth is the travel modulo
the pitch).  ``profile_set`` reads the set of values within the threshold off the screened profile and
says "not determined" when that set is not one range around the chosen value or covers most of the search
range.  Synthetic profiles with known answers.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from thsa_control.fit.profile import profile_set

LO, HI, N = 0.03, 0.3, 301
Q = float(chi2.ppf(0.95, 1))


def _grid():
    return np.geomspace(LO, HI, N)


def _parabola(x, x0, width, floor=5000.0):
    """chi2 = floor + (ln(x / x0) / width)^2: the profile of a log-normal estimate, width = its standard error."""
    return floor + (np.log(x / x0) / width) ** 2


def test_one_basin_is_determined_with_the_analytic_interval():
    x = _grid()
    width = 0.05  # 5 % standard error of ln(pitch)
    d = profile_set(x, _parabola(x, 0.15, width), Q, (LO, HI), N, chosen=0.15)
    assert d["determined"], d["reason"]
    assert len(d["components"]) == 1
    lo, hi = d["components"][0]
    # analytic: ln(x / x0) = +- width sqrt(Q); the screened ends lie inside by less than one grid step
    step = math.log(HI / LO) / (N - 1)
    a, b = 0.15 * math.exp(-width * math.sqrt(Q)), 0.15 * math.exp(width * math.sqrt(Q))
    assert a <= lo < a * math.exp(step) and b * math.exp(-step) < hi <= b


def test_a_comb_of_equal_minima_is_not_determined():
    x = _grid()
    y = np.minimum(_parabola(x, 0.08, 0.01), _parabola(x, 0.2, 0.01))  # two teeth, the same depth
    d = profile_set(x, y, Q, (LO, HI), N, chosen=0.08)
    assert not d["determined"]
    assert len(d["components"]) == 2
    assert d["components"][0][0] < 0.08 < d["components"][0][1] and d["components"][1][0] < 0.2 < d["components"][1][1]
    assert "comb" in d["reason"]


def test_a_second_minimum_counts_only_within_the_scaled_threshold():
    """The threshold is the chi2(1) quantile x reduced chi2 x IACT: a second tooth 10 above the minimum is
    distinct at the plain quantile (3.84) and indistinct once the residual's autocorrelation (IACT 5) is counted."""
    x = _grid()
    y = np.minimum(_parabola(x, 0.08, 0.01), _parabola(x, 0.2, 0.01) + 10.0)
    assert profile_set(x, y, Q, (LO, HI), N, chosen=0.08)["determined"]
    d = profile_set(x, y, Q * 5.0, (LO, HI), N, chosen=0.08)
    assert not d["determined"] and len(d["components"]) == 2


def test_a_staircase_step_inside_one_basin_does_not_split_it():
    """A switch acts at whole samples: one screened value inside the basin above the threshold is the profile's
    staircase, not a second mode (the screen resolves nothing finer than its grid)."""
    x = _grid()
    y = _parabola(x, 0.15, 0.05)
    i = int(np.argmin(np.abs(x - 0.152)))
    y[i] += 100.0
    d = profile_set(x, y, Q, (LO, HI), N, chosen=0.15)
    assert d["determined"] and len(d["components"]) == 1
    y[i + 1] += 100.0  # two values out in a row: a real gap of two grid steps
    assert len(profile_set(x, y, Q, (LO, HI), N, chosen=0.15)["components"]) == 2


@pytest.mark.parametrize("width, why", [(10.0, "end of the search range"), (0.5, "of the search range")])
def test_a_flat_or_wide_profile_is_not_determined(width, why):
    x = _grid()
    # width 10: flat over the range (reaches its ends); width 0.5: one basin covering most of the log range
    d = profile_set(x, _parabola(x, 0.095, width), Q, (LO, HI), N, chosen=0.095)
    assert not d["determined"] and why in d["reason"]
    assert len(d["components"]) == 1


def test_the_held_out_choice_outside_the_set_is_not_determined():
    x = _grid()
    d = profile_set(x, _parabola(x, 0.15, 0.01), Q, (LO, HI), N, chosen=0.2)
    assert not d["determined"] and "outside the screen's set" in d["reason"]
    assert profile_set(x, _parabola(x, 0.15, 0.01), Q, (LO, HI), N, chosen=0.1502)["determined"]


def test_a_linear_grid_uses_linear_shares():
    x = np.linspace(0.0, 1.0, 21)
    y = 100.0 * (x - 0.5) ** 2 / 0.01 + 7.0  # basin 0.5 +- 0.02 sqrt(Q)
    d = profile_set(x, y, Q, (0.0, 1.0), 21, chosen=0.5)
    assert d["determined"] and d["share"] == pytest.approx(0.0)
