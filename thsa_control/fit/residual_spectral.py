"""Whiteness, input cross-correlation and spectrum of one residual (the time-series statistics).

Owns the result types :class:`Whiteness`, :class:`CrossCorrelation`,
:class:`SpectralPeak`, :class:`ResidualSpectrum` and the numerics that fill
them: the biased autocorrelation and the Ljung-Box test
(:func:`autocorrelation_test`), the cross-correlation with an input and the
joint leak test on the AR-prewhitened residual (:func:`cross_correlation_test`),
and the Welch spectrum with its dominant peaks (:func:`residual_spectrum`).
The definitions are in :mod:`thsa_control.fit.residuals`' docstring, whose
:func:`~thsa_control.fit.residuals.analyse_residuals` calls these per channel.

Imports numpy and scipy only; never matplotlib.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy import linalg, signal, stats

if TYPE_CHECKING:
    from .residuals import ResidualSettings

__all__ = ["Whiteness", "CrossCorrelation", "SpectralPeak", "ResidualSpectrum", "autocorrelation_test",
           "cross_correlation_test", "residual_spectrum"]


@dataclass(frozen=True, eq=False)
class Whiteness:
    """Autocorrelation of a residual and its whiteness test.

    Parameters
    ----------
    lags : ndarray of int
        ``0..max_lag`` [samples].
    acf : ndarray
        Normalised autocorrelation (``acf[0] = 1``).
    band : float
        Half width of the confidence band ``z / sqrt(N)``.
    fraction_outside : float
        Share of lags ``1..max_lag`` outside the band.
    ljung_box_q : float
        Ljung-Box statistic.
    ljung_box_dof : int
        Its degrees of freedom (``max_lag``).
    ljung_box_p : float
        Its p-value.
    white : bool
        ``ljung_box_p >= 1 - confidence``.
    """

    lags: np.ndarray
    acf: np.ndarray
    band: float
    fraction_outside: float
    ljung_box_q: float
    ljung_box_dof: int
    ljung_box_p: float
    white: bool


@dataclass(frozen=True, eq=False)
class CrossCorrelation:
    """Cross-correlation of a residual with one input and the leak test.

    Parameters
    ----------
    input : str
        Input name.
    lags : ndarray of int
        ``-max_lag..max_lag`` [samples]; ``k > 0``: the input leads.
    ccf : ndarray
        ``corr(e_t, u_{t-k})``.
    band : float
        ``z / sqrt(N)``.
    fraction_outside : float
        Share of lags outside the band.
    max_abs : float
        Largest ``|ccf|``.
    lag_at_max : int
        Its lag [samples].
    statistic : float
        ``N R^2`` of the prewhitened lag regression.
    dof : int
        Its degrees of freedom (independent lag columns).
    p_value : float
    prewhiten_order : int
        AR order of the prewhitening filter used.
    correlated : bool
        ``p_value < 1 - confidence``: the input leaks into the residual.
    """

    input: str
    lags: np.ndarray
    ccf: np.ndarray
    band: float
    fraction_outside: float
    max_abs: float
    lag_at_max: int
    statistic: float
    dof: int
    p_value: float
    prewhiten_order: int
    correlated: bool


@dataclass(frozen=True)
class SpectralPeak:
    """A dominant spectral peak: ``frequency`` [Hz], ``psd`` [unit^2/Hz], ``ratio`` to the median PSD [-]."""

    frequency: float
    psd: float
    ratio: float


@dataclass(frozen=True, eq=False)
class ResidualSpectrum:
    """Welch power spectral density of the residual.

    Parameters
    ----------
    frequency : ndarray
        [Hz].
    psd : ndarray
        One-sided PSD [unit^2/Hz].
    peaks : tuple of SpectralPeak
        Dominant peaks, largest first.
    resolution : float
        Frequency step [Hz].
    """

    frequency: np.ndarray
    psd: np.ndarray
    peaks: tuple[SpectralPeak, ...]
    resolution: float


def _xcorr0(a: np.ndarray, b: np.ndarray, k: int) -> float:
    """sum_t a_t b_{t-k} (zero outside)."""
    if k >= 0:
        return float(a[k:] @ b[:a.size - k]) if k < a.size else 0.0
    return float(a[:k] @ b[-k:]) if -k < a.size else 0.0


def _ar_prewhiten(e: np.ndarray, max_order: int) -> tuple[np.ndarray, int]:
    """AR coefficients ``a`` (``e_t - sum a_i e_{t-i}``) by Yule-Walker, order by AIC."""
    n = e.size
    if max_order == 0 or n < 4 * max_order:
        return np.zeros(0), 0
    r = np.array([_xcorr0(e, e, k) for k in range(max_order + 1)]) / n
    if r[0] <= 0:
        return np.zeros(0), 0
    best, best_aic, best_a = 0, n * math.log(r[0]), np.zeros(0)
    for p in range(1, max_order + 1):
        try:
            a = linalg.solve_toeplitz(r[:p], r[1:p + 1])
        except (linalg.LinAlgError, ValueError):
            break
        s2 = r[0] - a @ r[1:p + 1]
        if s2 <= 0:
            break
        aic = n * math.log(s2) + 2 * p
        if aic < best_aic:
            best, best_aic, best_a = p, aic, a
    return best_a, best


def autocorrelation_test(e: np.ndarray, n: int, lag: int, z: float, alpha: float) -> Whiteness:
    c0 = float(e @ e)
    acf = np.array([_xcorr0(e, e, k) for k in range(lag + 1)]) / c0 if c0 > 0 else np.zeros(lag + 1)
    if c0 > 0:
        acf[0] = 1.0
    band = z / math.sqrt(n)
    ks = np.arange(1, lag + 1)
    q = float(n * (n + 2) * np.sum(acf[1:] ** 2 / (n - ks)))
    p = float(stats.chi2.sf(q, lag))
    return Whiteness(np.arange(lag + 1), acf, band, float(np.mean(np.abs(acf[1:]) > band)), q, lag, p,
                     bool(p >= alpha))


def cross_correlation_test(name: str, e: np.ndarray, u: np.ndarray, n: int, lag: int, z: float, alpha: float,
           max_order: int) -> CrossCorrelation:
    lags = np.arange(-lag, lag + 1)
    den = math.sqrt(float(e @ e) * float(u @ u))
    ccf = np.array([_xcorr0(e, u, k) for k in lags]) / den if den > 0 else np.zeros(lags.size)
    band = z / math.sqrt(n)
    i = int(np.argmax(np.abs(ccf)))
    # joint test: prewhitened residual regressed on the lagged (same-filtered) input
    a, order = _ar_prewhiten(e, max_order)
    filt = np.concatenate([[1.0], -a])
    ew = signal.lfilter(filt, [1.0], e)[order:]
    uw = signal.lfilter(filt, [1.0], u)
    m = e.size  # samples including the zero-filled missing ones; n counts the valid ones
    X = np.zeros((m, lags.size))
    for j, k in enumerate(lags):
        if k >= 0:
            X[k:, j] = uw[:m - k]
        else:
            X[:k, j] = uw[-k:]
    X = X[order:]
    stat, dof, p = 0.0, 0, 1.0
    tss = float(ew @ ew)
    if tss > 0 and float(u @ u) > 0:
        # explained sum of squares b' G+ b from the normal equations (eigen-decomposed, rank-revealing)
        lam, vec = linalg.eigh(X.T @ X)
        keep = lam > 1e-10 * max(float(lam[-1]), 1e-300)
        proj = vec[:, keep].T @ (X.T @ ew)
        ess = float(np.sum(proj ** 2 / lam[keep]))
        stat, dof = float((n - order) * min(ess / tss, 1.0)), int(keep.sum())
        p = float(stats.chi2.sf(stat, dof)) if dof > 0 else 1.0
    return CrossCorrelation(name, lags, ccf, band, float(np.mean(np.abs(ccf) > band)), float(abs(ccf[i])),
                            int(lags[i]), stat, dof, p, order, bool(p < alpha))


def residual_spectrum(t: np.ndarray, e: np.ndarray, valid: np.ndarray, dt: float, uniform: bool,
              s: ResidualSettings) -> ResidualSpectrum:
    x = np.where(valid, e, np.mean(e[valid]))
    if not uniform:
        tu = np.arange(t[0], t[-1], dt)
        x = np.interp(tu, t, x)
    nper = min(s.nperseg, x.size)
    f, psd = signal.welch(x, fs=1.0 / dt, nperseg=nper, detrend="constant")
    med = float(np.median(psd[1:])) if psd.size > 1 else 0.0
    peaks = []
    if med > 0 and psd.size > 2:
        idx, _ = signal.find_peaks(np.concatenate([[-np.inf], psd[1:]]))  # the DC bin is never a peak
        idx = [i for i in idx if psd[i] >= s.peak_ratio * med]
        for i in sorted(idx, key=lambda i: -psd[i])[:s.n_peaks]:
            peaks.append(SpectralPeak(float(f[i]), float(psd[i]), float(psd[i] / med)))
    return ResidualSpectrum(f, psd, tuple(peaks), float(f[1] - f[0]) if f.size > 1 else math.nan)
