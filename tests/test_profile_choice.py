"""Which error chooses among the profile fits, and the gap the data resolve (issue #21, a known limit).

The profile fits of a switched parameter (the pawl pitch) are chosen by their training error (the fit's own
objective on the samples it was fitted to); the held-out samples stay for the tracer's judgement.  The file value
is held where its fit's training error is within the gap the data resolve: the ``chi2(1)`` quantile at ``alpha`` x
the reduced chi-square x the integrated autocorrelation time, all computed on the training residual.  Synthetic
residuals with known statistics.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.stats import chi2

from thsa_control.fit.profile import why_held
from thsa_control.trace.scoring import _profile_gap

ALPHA = 1e-3
Q = float(chi2.ppf(1 - ALPHA, 1))
N = 60_000
SEG = 50  # samples per segment; every third segment held out


def _result(train_err: np.ndarray, hold_err: np.ndarray) -> SimpleNamespace:
    """A fit whose residual (measured - simulated, in noise units) is ``train_err`` on the training samples and
    ``hold_err`` on the held-out ones."""
    hold = (np.arange(N) // SEG) % 3 == 2
    e = np.empty(N)
    e[~hold] = train_err[:int((~hold).sum())]
    e[hold] = hold_err[:int(hold.sum())]
    pred = {"time": np.arange(N) * 1e-3, "measured": {"motor_speed": e}, "simulated": {"motor_speed": np.zeros(N)},
            "holdout": hold, "segment_starts": np.arange(0, N, SEG) * 1e-3}
    return SimpleNamespace(predictions={"run": pred})


def _ar1(phi: float, n: int, rng) -> np.ndarray:
    """Unit-variance AR(1) noise: its integrated autocorrelation time is (1 + phi) / (1 - phi)."""
    w = rng.standard_normal(n) * np.sqrt(1 - phi ** 2)
    x = np.empty(n)
    x[0] = rng.standard_normal()
    for k in range(1, n):
        x[k] = phi * x[k - 1] + w[k]
    return x


def test_white_training_residual_at_the_noise_gives_the_bare_quantile():
    rng = np.random.default_rng(1)
    gap = _profile_gap({"motor_speed": 1.0}, ALPHA, "training")(_result(rng.standard_normal(N), rng.standard_normal(N)))
    # reduced chi2 ~ 1 (clipped at 1 from below), IACT ~ 1: the chi2(1) quantile itself, within sampling spread
    assert gap == pytest.approx(Q, rel=0.1)


def test_the_gap_scales_with_the_training_residual_size_and_correlation_not_the_held_out_one():
    rng = np.random.default_rng(2)
    phi = 0.8
    train = 3.0 * _ar1(phi, N, rng)  # reduced chi2 9, IACT (1 + 0.8) / (1 - 0.8) = 9
    held = 100.0 * rng.standard_normal(N)  # a held-out residual that would give a gap 1e4 x the quantile
    res = _result(train, held)
    g_train = _profile_gap({"motor_speed": 1.0}, ALPHA, "training")(res)
    assert g_train == pytest.approx(Q * 9.0 * 9.0, rel=0.25)
    g_hold = _profile_gap({"motor_speed": 1.0}, ALPHA, "holdout")(res)
    assert g_hold == pytest.approx(Q * 1e4, rel=0.1)
    # the noise level the tracer measured scales the residual: at 3 x the noise the training residual is white
    # noise of unit reduced chi2 in size, the gap keeps only the correlation
    assert _profile_gap({"motor_speed": 3.0}, ALPHA, "training")(res) == pytest.approx(Q * 9.0, rel=0.25)


def test_without_a_noise_level_nothing_is_resolved():
    rng = np.random.default_rng(3)
    res = _result(rng.standard_normal(N), rng.standard_normal(N))
    assert _profile_gap({}, ALPHA)(res) == float("inf")
    with pytest.raises(ValueError, match="samples"):
        _profile_gap({"motor_speed": 1.0}, ALPHA, "all")


def test_why_held_names_the_error_that_chose():
    d = {"file_in_set": True, "file_value": 0.1496, "held_at": 0.0771, "chosen_by": "training_chi2",
         "file_score_above_best": 5000.0, "score_gap": 400.0}
    assert "training error" in why_held(d) and "5000" in why_held(d) and "400" in why_held(d)
    d_held = {**d, "held_at": 0.1496, "file_score_above_best": 100.0}
    assert why_held(d_held).startswith("the parameter file's value") and "training error" in why_held(d_held)
    assert "held-out error" in why_held({**d, "chosen_by": "holdout_chi2"})
