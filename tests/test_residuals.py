"""Tests of :mod:`thsa_control.fit.residuals` (residual analysis numerics).

Oracles are statistical facts with seeded data:

* white Gaussian noise is white at 95 %: over 200 seeds the Ljung-Box test
  rejects it 5.0 % of the time (the nominal false-positive rate; the band
  accepted is the binomial 3-sigma interval 0.4-9.6 %);
* an AR(1) residual with phi = 0.5 is never white (acf(1) = 0.5);
* a Coulomb-like term added only in the aiding quadrant makes that quadrant
  the one significant bin and the residual non-white;
* an input that leaks into the residual with a 3-sample delay is flagged at
  lag 3, an independent input is not;
* NRMSE and fit % are checked against values computed by hand;
* the spectrum peaks at the frequency of an injected sinusoid.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from thsa_control.fit.residuals import (
    QUADRANT_LABELS,
    ResidualSettings,
    SignalError,
    analyse_residuals,
    format_residual_report,
    quadrant,
    reversal_proximity,
    wrapped_angle,
)

N = 2000
DT = 1e-3


def _analyse(e, conditioning=None, inputs=None, **kw):
    t = np.arange(e.size) * DT
    return analyse_residuals(t, {"y": e}, {"y": np.zeros(e.size)}, conditioning or {}, inputs or {}, **kw)["y"]


def _ar1(rng, n, phi):
    w = rng.standard_normal(n + 200)
    e = np.zeros_like(w)
    for i in range(1, w.size):
        e[i] = phi * e[i - 1] + w[i]
    return e[200:]


# ------------------------------------------------------------------ fit numbers
def test_nrmse_and_fit_percent_by_hand():
    # y = 0..19, yhat = y +- 1 alternately: ||e|| = sqrt(20), ||y - 9.5|| = sqrt(665)
    y = np.arange(20.0)
    yhat = y + np.where(np.arange(20) % 2, 1.0, -1.0)
    a = analyse_residuals(np.arange(20.0), {"y": y}, {"y": yhat}, {}, {}, settings=ResidualSettings(max_lag=4))
    c = a["y"]
    assert c.nrmse == pytest.approx(math.sqrt(20.0 / 665.0), rel=1e-12)  # 0.173422
    assert c.fit_percent == pytest.approx(100.0 * (1.0 - 0.17342199), rel=1e-6)  # 82.6578 %
    assert c.rms == pytest.approx(1.0) and c.max_abs == pytest.approx(1.0) and c.mean == pytest.approx(0.0)
    np.testing.assert_allclose(c.residual, y - yhat)  # measured - simulated
    assert a.max_lag == 4


def test_perfect_and_constant_model_fit():
    t = np.arange(100.0)
    y = np.sin(t / 7.0)
    a = analyse_residuals(t, {"y": y, "z": y}, {"y": y, "z": np.full(t.size, y.mean())}, {}, {})
    assert a["y"].fit_percent == pytest.approx(100.0) and a["y"].nrmse == 0.0
    assert a["z"].fit_percent == pytest.approx(0.0, abs=1e-9)  # the mean is 0 % (MATLAB compare)


# ------------------------------------------------------------------ whiteness
@pytest.mark.parametrize("seed", range(5))
def test_white_noise_is_white(seed):
    c = _analyse(np.random.default_rng(seed).standard_normal(N))
    w = c.whiteness
    assert w.white and w.ljung_box_p >= 0.05
    assert w.band == pytest.approx(1.96 / math.sqrt(N), rel=1e-3)
    assert w.acf[0] == 1.0 and w.lags.tolist() == list(range(26))
    assert w.fraction_outside <= 0.2


def test_whiteness_false_positive_rate_is_nominal():
    """200 seeds: measured 5.0 % rejections (10/200) at the 95 % level."""
    rejected = [not _analyse(np.random.default_rng(100 + s).standard_normal(N)).whiteness.white for s in range(200)]
    assert 0.004 <= np.mean(rejected) <= 0.096


@pytest.mark.parametrize("seed", range(5))
def test_ar1_residual_is_not_white(seed):
    c = _analyse(_ar1(np.random.default_rng(seed), N, 0.5))
    assert not c.whiteness.white and c.whiteness.ljung_box_p < 1e-6
    assert c.whiteness.acf[1] == pytest.approx(0.5, abs=0.06)
    assert c.whiteness.acf[2] == pytest.approx(0.25, abs=0.08)


# ------------------------------------------------------------------ conditioning
def _bipolar_run(rng):
    """6 s at 1 kHz: +3 mm/s, stop, -3 mm/s, +3 mm/s under +5 kN then -5 kN.

    Opposing 0-1.9 s and 3-4 s, aiding 2.1-3 s and 4-6 s (FORMAT.md signs).
    The residual: 50 mA noise plus a 0.1 A Coulomb-like term against the
    motion, only while aiding (what a model missing the no-back disk gives).
    """
    t = np.arange(6000) * DT
    speed = np.where(t < 2, 3e-3, np.where(t < 4, -3e-3, 3e-3))
    speed[(t > 1.9) & (t < 2.1)] = 0.0
    load = np.where(t < 3, 5000.0, -5000.0)
    q = quadrant(speed, load, (1e-4, 100.0))
    e = 0.05 * rng.standard_normal(t.size) + np.where(q == -1, -0.1 * np.sign(speed), 0.0)
    return t, speed, load, q, e


@pytest.mark.parametrize("seed", range(3))
def test_aiding_quadrant_is_the_significant_bin(seed):
    t, speed, load, q, e = _bipolar_run(np.random.default_rng(seed))
    a = analyse_residuals(t, {"current": e}, {"current": np.zeros(t.size)},
                          {"quadrant": q, "speed": speed, "nut_position": np.cumsum(speed) * DT},
                          {"load": load}, units={"current": "A"})
    c = a["current"]
    assert not c.whiteness.white
    cq = c.conditioned["quadrant"]
    assert cq.binning == "categorical"
    assert cq.significant_bins == ("aiding",)
    aiding = cq.bin("aiding")
    assert aiding.rms == pytest.approx(math.sqrt(0.05**2 + 0.1**2), rel=0.05)
    assert cq.bin("opposing").rms == pytest.approx(0.05, rel=0.05)
    assert aiding.count == int(np.sum(q == -1))
    assert c.conditioned["nut_position"].binning == "quantile"
    assert len(c.conditioned["nut_position"].bins) == 5
    # the quadrant explains more of the residual than the direction alone
    assert cq.eta_squared > 0.0 and cq.bin("aiding").excess_ratio > 3.0


def test_white_residual_has_no_significant_bin():
    rng = np.random.default_rng(7)
    t, speed, load, q, _ = _bipolar_run(rng)
    c = _analyse(rng.standard_normal(t.size), {"quadrant": q, "speed": speed})
    assert c.conditioned["quadrant"].significant_bins == ()
    assert c.conditioned["speed"].significant_bins == ()


def test_categories_labels_and_quantile_bins():
    rng = np.random.default_rng(3)
    n = 3000
    on = np.arange(n) % 300 < 150
    temp = rng.uniform(-55, 25, n)
    e = rng.standard_normal(n) + np.where(temp < -39, 3.0, 0.0)  # cold end fails
    c = _analyse(e, {"motor_on": on.astype(int), "temperature": temp, "tag": np.where(on, "a", "b")},
                 settings=ResidualSettings(n_bins=5))
    assert [b.label for b in c.conditioned["motor_on"].bins] == ["off", "on"]
    assert [b.label for b in c.conditioned["tag"].bins] == ["a", "b"]
    ct = c.conditioned["temperature"]
    assert ct.binning == "quantile" and sum(b.count for b in ct.bins) == n
    assert ct.significant_bins == (ct.bins[0].label,)  # the coldest fifth
    assert ct.bins[0].high == pytest.approx(np.quantile(temp, 0.2))


# ------------------------------------------------------------------ cross-correlation
@pytest.mark.parametrize("seed", range(3))
def test_leaking_input_is_flagged_at_its_lag(seed):
    rng = np.random.default_rng(seed)
    u1, u2 = rng.standard_normal(N), rng.standard_normal(N)
    e = rng.standard_normal(N) + 0.3 * np.concatenate([np.zeros(3), u1[:-3]])  # u1 leads by 3 samples
    c = _analyse(e, inputs={"load_force": u1, "speed_cmd": u2})
    leak, other = c.cross["load_force"], c.cross["speed_cmd"]
    assert leak.correlated and leak.lag_at_max == 3 and leak.p_value < 1e-6
    assert leak.max_abs == pytest.approx(0.3 / math.sqrt(1.09), abs=0.05)
    assert not other.correlated
    assert leak.lags.tolist() == list(range(-25, 26))


def test_independent_smooth_input_with_coloured_residual_is_not_flagged():
    """Prewhitening keeps the false-positive rate near 5 % for an AR(1) residual and a smooth input."""
    flagged = []
    for s in range(40):
        rng = np.random.default_rng(500 + s)
        u = np.convolve(rng.standard_normal(N + 49), np.ones(50) / 50, "valid")
        flagged.append(_analyse(_ar1(rng, N, 0.5), inputs={"u": u}).cross["u"].correlated)
    assert np.mean(flagged) <= 0.15


# ------------------------------------------------------------------ spectrum
def test_spectrum_peak_at_injected_sinusoid():
    rng = np.random.default_rng(11)
    t = np.arange(4000) * DT
    e = rng.standard_normal(t.size) + 0.5 * np.sin(2 * np.pi * 37.0 * t)
    c = _analyse(e)
    sp = c.spectrum
    assert sp.peaks and abs(sp.peaks[0].frequency - 37.0) <= sp.resolution
    assert sp.peaks[0].ratio > 5.0  # 0.125 power over ~1.5 bins of 3.9 Hz vs 2e-3 /Hz noise: ~10 at a bin centre
    assert sp.frequency[-1] == pytest.approx(500.0)
    assert not c.whiteness.white


def test_white_spectrum_has_no_dominant_peak():
    assert _analyse(np.random.default_rng(12).standard_normal(4000)).spectrum.peaks == ()


def test_non_uniform_sampling_and_missing_samples():
    rng = np.random.default_rng(13)
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, N))
    y = rng.standard_normal(N)
    y[[10, 500, 501]] = np.nan
    a = analyse_residuals(t, {"y": y}, {"y": np.zeros(N)}, {}, {"u": rng.standard_normal(N)})
    c = a["y"]
    assert not a.uniform and c.n == N - 3
    assert np.isnan(c.residual[10]) and math.isfinite(c.rms)
    assert c.spectrum.peaks == () or c.spectrum.peaks[0].ratio < 20


# ------------------------------------------------------------------ helpers and errors
def test_quadrant_signs():
    speed = np.array([1.0, 1.0, -1.0, -1.0, 0.0, 1.0])
    load = np.array([5e3, -5e3, 5e3, -5e3, 5e3, 10.0])
    q = quadrant(speed, load, (0.0, 50.0))
    assert q.tolist() == [1, -1, -1, 1, 0, 0]
    assert QUADRANT_LABELS[1] == "opposing" and QUADRANT_LABELS[-1] == "aiding"
    with pytest.raises(SignalError, match="load"):
        quadrant(speed, load[:3], 0.0)


def test_reversal_proximity_and_wrapped_angle():
    t = np.arange(10.0)
    v = np.array([1, 1, 1, 0, -1, -1, -1, -1, 1, 1], dtype=float)
    d = reversal_proximity(t, v)
    assert d.tolist() == [3.0, 2.0, 1.0, 0.0, 1.0, 2.0, 1.5, 0.5, 0.5, 1.5]
    assert np.all(np.isinf(reversal_proximity(t, np.ones(10))))
    ang = wrapped_angle(np.linspace(0, 1, 1001), np.full(1001, 2 * np.pi * 3.25))
    assert ang[-1] == pytest.approx(0.25 * 2 * np.pi)
    assert np.all((ang >= 0) & (ang < 2 * np.pi))


def test_malformed_signals_name_the_culprit():
    t = np.arange(100.0)
    y = np.zeros(100)
    with pytest.raises(SignalError, match="measured"):
        analyse_residuals(t, {"a": y}, {"b": y}, {}, {})
    with pytest.raises(SignalError, match=r"inputs\['u'\]"):
        analyse_residuals(t, {"a": y}, {"a": y}, {}, {"u": y[:50]})
    with pytest.raises(SignalError, match=r"conditioning\['speed'\]"):
        analyse_residuals(t, {"a": y}, {"a": y}, {"speed": np.zeros((100, 2))}, {})
    with pytest.raises(SignalError, match="time"):
        analyse_residuals(t[::-1], {"a": y}, {"a": y}, {}, {})
    with pytest.raises(ValueError, match="confidence"):
        analyse_residuals(t, {"a": y}, {"a": y}, {}, {}, settings=ResidualSettings(confidence=1.5))


def test_report_and_summary():
    rng = np.random.default_rng(1)
    t, speed, load, q, e = _bipolar_run(rng)
    a = analyse_residuals(t, {"current": e, "extra": e}, {"current": np.zeros(t.size)}, {"quadrant": q},
                          {"load": load}, units={"current": "A"})
    text = format_residual_report(a)
    for fragment in ("[[Residual analysis]]", "[[Channel current]]", "NOT WHITE", "Ljung-Box",
                     "*+ aiding", "[[Spectrum]]", "fit ", " A", "ignored (no partner) = extra"):
        assert fragment in text, fragment
    s = a.summary()
    json.dumps(s, allow_nan=False)
    assert s["current"]["conditioned"]["quadrant"]["significant_bins"] == ["aiding"]
    with pytest.raises(dataclasses.FrozenInstanceError):
        a["current"].whiteness.white = True
    with pytest.raises(KeyError, match="extra"):
        a["extra"]
