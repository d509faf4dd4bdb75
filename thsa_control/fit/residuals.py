"""Residual analysis numerics (issue 4, item 6): where and how a model misses the data.

Generic over arrays: it knows nothing of files, models or plots.  Given the
measured and simulated signals of a run, the operating variables to condition
on and the inputs, :func:`analyse_residuals` returns frozen results per
channel, and :func:`format_residual_report` prints them lmfit-style.  It
imports numpy, scipy and :mod:`thsa_control.errors` only; never matplotlib
(``thsa_control.report`` draws these results).

What is computed, per channel (keys common to ``measured`` and ``simulated``)
-----------------------------------------------------------------------------
* the residual ``e = measured - simulated`` (MATLAB ``resid`` sign), RMS,
  mean, maximum ``|e|`` and when, NRMSE ``= ||y - yhat|| / ||y - mean(y)||`` and
  fit ``= 100 (1 - NRMSE)`` % (MATLAB ``compare``);
* whiteness (MATLAB ``resid``): the biased autocorrelation ``r_k``,
  ``k = 0..max_lag``, the band ``+-z/sqrt(N)`` (``z = 1.96`` at 95 %), the
  fraction of lags ``1..max_lag`` outside it, and the Ljung-Box portmanteau
  ``Q = N (N + 2) sum r_k^2 / (N - k)`` against chi-square(``max_lag``).  The
  residual is *white* when the Ljung-Box p-value is at least ``1 - confidence``:
  a white residual is declared non-white with probability ``1 - confidence``
  (5 %; the tests measure it);
* cross-correlation with each input, ``r_eu(k) = corr(e_t, u_{t-k})``,
  ``k = -max_lag..max_lag`` (``k > 0``: the input leads the residual, which is
  where a causal leak shows), with the same band.  The band is exact for a
  white residual only, and with 2 max_lag + 1 lags some fall outside by chance,
  so the *flag* is a joint test: the residual (prewhitened by an AR model of
  order <= ``prewhiten_max_order`` chosen by AIC, the same filter applied to the
  input) is regressed on the lagged input, and ``N R^2`` is tested against
  chi-square(number of lags).  This holds for an autocorrelated input and, after
  prewhitening, approximately for an autocorrelated residual;
* the residual conditioned on each operating variable: categories for discrete
  signals (booleans, strings, or at most ``max_categories`` distinct values,
  e.g. speed plateaus), quantile bins otherwise.  Per bin: count, mean, RMS, a t-test of the bin mean
  against the overall mean, and a one-sided F-test of the bin's mean square
  about the overall mean against that of the other samples.  A bin is
  *significant* (the model fails there) when the F-test rejects at
  ``1 - confidence`` with a Bonferroni correction over the bins of that signal:
  the bin's residual is larger than elsewhere.  (The t-test alone would also
  flag the complementary bins, whose mean moves the other way when one regime
  shifts the overall mean.)  Both tests use an effective sample size
  ``n (1 - rho) / (1 + rho)`` with ``rho`` the lag-1 autocorrelation of the
  residual about its bin means, because a model error makes neighbouring
  samples dependent.  ``eta_squared`` is the share of the residual variance
  explained by the bins (rank the signals by it);
* the residual spectrum (Welch, :func:`scipy.signal.welch`) and its dominant
  peaks (local maxima at least ``peak_ratio`` times the median PSD).

Samples where the measured or simulated value is NaN are left out of every
statistic (correlations treat them as zero after removing the mean and
normalise by the count of valid samples); the spectrum uses the residual with
NaN samples set to its mean and, for non-uniform sampling, interpolated on a
uniform grid at the median step.

Examples
--------
>>> import numpy as np
>>> rng = np.random.default_rng(0)
>>> t = np.arange(2000) * 1e-3
>>> y = np.sin(2 * np.pi * t)
>>> a = analyse_residuals(t, {"x": y + 0.01 * rng.standard_normal(t.size)}, {"x": y}, {}, {})
>>> a["x"].whiteness.white, round(a["x"].fit_percent)
(True, 99)
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy import linalg, signal, stats

from thsa_control.errors import SignalError  # noqa: F401 (re-exported)

__all__ = [
    "SignalError",
    "ResidualSettings",
    "Whiteness",
    "CrossCorrelation",
    "ResidualBin",
    "ConditionedResidual",
    "SpectralPeak",
    "ResidualSpectrum",
    "ChannelResiduals",
    "ResidualAnalysis",
    "QUADRANT_LABELS",
    "quadrant",
    "reversal_proximity",
    "wrapped_angle",
    "analyse_residuals",
    "format_residual_report",
]

Float1D = NDArray[np.float64]

#: Labels of :func:`quadrant` categories (FORMAT.md signs).
QUADRANT_LABELS: dict[int, str] = {1: "opposing", -1: "aiding", 0: "unloaded/stopped"}


# ------------------------------------------------------------------ settings
def _default_labels() -> dict[str, dict[float, str]]:
    return {"quadrant": {float(k): v for k, v in QUADRANT_LABELS.items()},
            "motor_on": {0.0: "off", 1.0: "on"},
            "direction": {1.0: "positive", -1.0: "negative", 0.0: "stopped"}}


@dataclass(frozen=True)
class ResidualSettings:
    """Options of :func:`analyse_residuals` (defaults as MATLAB ``resid``).

    Parameters
    ----------
    max_lag : int
        Largest correlation lag [samples]; reduced to ``N // 4`` for short records.
    confidence : float
        Confidence level of the band and of every test [-], e.g. 0.95.
    n_bins : int
        Quantile bins of a continuous conditioning signal.
    max_categories : int
        A signal with at most this many distinct values is categorical.
    min_bin_count : int
        Bins with fewer samples are reported but not tested.
    prewhiten_max_order : int
        Largest AR order of the prewhitening filter of the cross-correlation
        test (0 disables prewhitening).
    nperseg : int
        Welch segment length [samples] (at most N).
    n_peaks : int
        Most spectral peaks reported.
    peak_ratio : float
        A peak must exceed this multiple of the median PSD [-].
    category_labels : dict of str to dict of float to str
        Labels of categorical conditioning values by signal name (``quadrant``,
        ``motor_on`` and ``direction`` by default).
    """

    max_lag: int = 25
    confidence: float = 0.95
    n_bins: int = 5
    max_categories: int = 10
    min_bin_count: int = 10
    prewhiten_max_order: int = 10
    nperseg: int = 256
    n_peaks: int = 5
    peak_ratio: float = 5.0
    category_labels: dict[str, dict[float, str]] = field(default_factory=_default_labels)

    def validate(self) -> "ResidualSettings":
        """Raise ``ValueError`` naming the bad option; return self."""
        checks = [
            ("max_lag", self.max_lag >= 1), ("confidence", 0.5 <= self.confidence < 1.0),
            ("n_bins", self.n_bins >= 2), ("max_categories", self.max_categories >= 2),
            ("min_bin_count", self.min_bin_count >= 2), ("prewhiten_max_order", self.prewhiten_max_order >= 0),
            ("nperseg", self.nperseg >= 8), ("n_peaks", self.n_peaks >= 0), ("peak_ratio", self.peak_ratio > 1.0),
        ]
        for name, ok in checks:
            if not ok:
                raise ValueError(f"ResidualSettings.{name} = {getattr(self, name)!r} is out of range")
        return self

    @property
    def z(self) -> float:
        """Two-sided normal quantile of :attr:`confidence` (1.96 at 95 %)."""
        return float(stats.norm.ppf(0.5 + self.confidence / 2.0))


# ------------------------------------------------------------------ results
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
class ResidualBin:
    """The residual in one bin of a conditioning signal.

    Parameters
    ----------
    label : str
        Category label or ``[lo, hi]`` interval.
    low, high : float
        Interval of a quantile bin; the category value twice for a category
        (NaN for string categories).
    count : int
        Valid samples in the bin.
    mean, rms : float
        Residual mean and RMS in the bin [channel unit].
    mean_p : float
        p-value of the t-test of the bin mean against the overall mean.
    mean_significant : bool
        ``mean_p`` below the Bonferroni-corrected level.
    excess_ratio : float
        Bin mean square about the overall mean / that of the other samples [-].
    excess_p : float
        One-sided F-test p-value of that ratio being > 1.
    significant : bool
        ``excess_p`` below the Bonferroni-corrected level: the model fails here.
    """

    label: str
    low: float
    high: float
    count: int
    mean: float
    rms: float
    mean_p: float
    mean_significant: bool
    excess_ratio: float
    excess_p: float
    significant: bool


@dataclass(frozen=True)
class ConditionedResidual:
    """The residual binned on one operating variable.

    Parameters
    ----------
    signal : str
        Conditioning signal name.
    binning : str
        ``"categorical"`` or ``"quantile"``.
    bins : tuple of ResidualBin
    eta_squared : float
        Share of the residual variance explained by the bin means [-].
    lag1_correlation : float
        ``rho`` used for the effective sample size.
    """

    signal: str
    binning: str
    bins: tuple[ResidualBin, ...]
    eta_squared: float
    lag1_correlation: float

    @property
    def significant_bins(self) -> tuple[str, ...]:
        """Labels of the bins where the residual is significantly larger."""
        return tuple(b.label for b in self.bins if b.significant)

    def bin(self, label: str) -> ResidualBin:
        """The bin with this label (KeyError otherwise)."""
        for b in self.bins:
            if b.label == label:
                return b
        raise KeyError(f"no bin {label!r} for '{self.signal}'; bins: {[b.label for b in self.bins]}")


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


@dataclass(frozen=True, eq=False)
class ChannelResiduals:
    """Everything about the residual of one channel.

    Parameters
    ----------
    name : str
    unit : str
    residual : ndarray
        ``measured - simulated`` at every sample (NaN where either is NaN).
    n : int
        Valid samples.
    rms, mean, std, max_abs : float
        [unit].
    time_of_max : float
        Time of ``max_abs`` [s].
    nrmse : float
        ``||y - yhat|| / ||y - mean(y)||`` [-] (inf when ``y`` is constant).
    fit_percent : float
        ``100 (1 - nrmse)`` [%].
    whiteness : Whiteness
    cross : dict of str to CrossCorrelation
    conditioned : dict of str to ConditionedResidual
    spectrum : ResidualSpectrum
    """

    name: str
    unit: str
    residual: np.ndarray
    n: int
    rms: float
    mean: float
    std: float
    max_abs: float
    time_of_max: float
    nrmse: float
    fit_percent: float
    whiteness: Whiteness
    cross: dict[str, CrossCorrelation]
    conditioned: dict[str, ConditionedResidual]
    spectrum: ResidualSpectrum


@dataclass(frozen=True, eq=False)
class ResidualAnalysis:
    """Result of :func:`analyse_residuals`.

    Parameters
    ----------
    channels : dict of str to ChannelResiduals
    time : ndarray
        [s].
    sample_time : float
        Median step [s].
    uniform : bool
        Steps within 1 % of the median.
    max_lag : int
        Lag actually used [samples].
    settings : ResidualSettings
    ignored : tuple of str
        Measured or simulated keys without a partner.
    """

    channels: dict[str, ChannelResiduals]
    time: np.ndarray
    sample_time: float
    uniform: bool
    max_lag: int
    settings: ResidualSettings
    ignored: tuple[str, ...] = ()

    def __getitem__(self, name: str) -> ChannelResiduals:
        try:
            return self.channels[name]
        except KeyError:
            raise KeyError(f"no channel {name!r}; channels: {list(self.channels)}") from None

    def summary(self) -> dict:
        """Scalars (no series) by channel, ready for strict JSON (NaN and inf become None)."""
        out = {}
        for name, c in self.channels.items():
            w = c.whiteness
            out[name] = {
                "unit": c.unit, "n": c.n, "rms": c.rms, "mean": c.mean, "max_abs": c.max_abs,
                "time_of_max": c.time_of_max, "nrmse": c.nrmse, "fit_percent": c.fit_percent,
                "whiteness": {"white": w.white, "ljung_box_q": w.ljung_box_q, "ljung_box_dof": w.ljung_box_dof,
                              "ljung_box_p": w.ljung_box_p, "fraction_outside": w.fraction_outside,
                              "band": w.band},
                "cross": {k: {"correlated": x.correlated, "p_value": x.p_value, "max_abs": x.max_abs,
                              "lag_at_max": x.lag_at_max, "fraction_outside": x.fraction_outside}
                          for k, x in c.cross.items()},
                "conditioned": {k: {"binning": v.binning, "eta_squared": v.eta_squared,
                                    "significant_bins": list(v.significant_bins),
                                    "bins": [{"label": b.label, "count": b.count, "mean": b.mean, "rms": b.rms,
                                              "mean_p": b.mean_p, "excess_ratio": b.excess_ratio,
                                              "excess_p": b.excess_p, "significant": b.significant}
                                             for b in v.bins]}
                                for k, v in c.conditioned.items()},
                "spectrum_peaks": [{"frequency": p.frequency, "psd": p.psd, "ratio": p.ratio}
                                   for p in c.spectrum.peaks],
            }
        return _finite_or_none(out)

    def report(self) -> str:
        """lmfit-style text report (:func:`format_residual_report`)."""
        return format_residual_report(self)

    def to_dict(self) -> dict:
        """Scalars by channel, strict JSON (the same as :meth:`summary`)."""
        return self.summary()

    def plot(self, ax=None, channel: str | None = None):
        """Residual of ``channel`` (default the first): time series, autocorrelation, spectrum; ``ax``: three Axes."""
        from ..report.identification import plot_residual_channel

        c = self.channels[channel] if channel is not None else next(iter(self.channels.values()))
        return plot_residual_channel(self.time, c, title=c.name, axes=ax)


def _finite_or_none(x):
    if isinstance(x, dict):
        return {k: _finite_or_none(v) for k, v in x.items()}
    if isinstance(x, list):
        return [_finite_or_none(v) for v in x]
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


# ------------------------------------------------------------------ helpers
def quadrant(speed, load, deadband: float | tuple[float, float] = 0.0) -> np.ndarray:
    """Load quadrant of each sample with the FORMAT.md signs.

    Parameters
    ----------
    speed : array_like
        Speed, positive when the actuator extends [any speed unit].
    load : array_like
        Load force, positive compressive [N].
    deadband : float or (float, float)
        ``(speed_deadband, load_deadband)`` in the units of each signal; a
        single number applies to both.  ``|speed| <= speed_deadband`` or
        ``|load| <= load_deadband`` is category 0.

    Returns
    -------
    ndarray of int
        +1 where the load opposes the motion (``load * speed > 0``), -1 where
        it aids it, 0 unloaded or stopped (labels in :data:`QUADRANT_LABELS`).

    Examples
    --------
    >>> quadrant([1.0, 1.0, -1.0, 0.0], [5e3, -5e3, 5e3, 5e3], (0.1, 100.0))
    array([ 1, -1, -1,  0])
    """
    v, f = np.asarray(speed, dtype=float), np.asarray(load, dtype=float)
    if v.shape != f.shape:
        raise SignalError("load", f"shape {f.shape} differs from the speed's {v.shape}")
    dv, df = (deadband, deadband) if np.isscalar(deadband) else tuple(deadband)
    if dv < 0 or df < 0:
        raise ValueError(f"deadband must be >= 0, got {deadband!r}")
    q = np.sign(v) * np.sign(f)
    q[(np.abs(v) <= dv) | (np.abs(f) <= df)] = 0
    return q.astype(int)


def reversal_proximity(time, speed, *, deadband: float = 0.0) -> Float1D:
    """Time to the nearest direction reversal of ``speed`` [s] (inf if none).

    A reversal is where the sign of ``speed`` (values within ``deadband`` are
    ignored) changes between two moving samples; its time is midway.

    Examples
    --------
    >>> reversal_proximity([0.0, 1.0, 2.0, 3.0], [1.0, 1.0, -1.0, -1.0]).tolist()
    [1.5, 0.5, 0.5, 1.5]
    """
    t, v = np.asarray(time, dtype=float), np.asarray(speed, dtype=float)
    moving = np.flatnonzero(np.abs(v) > deadband)
    s = np.sign(v[moving])
    flips = np.flatnonzero(s[1:] != s[:-1])
    if flips.size == 0:
        return np.full(t.shape, np.inf)
    tr = 0.5 * (t[moving[flips]] + t[moving[flips + 1]])
    j = np.searchsorted(tr, t)
    before = np.abs(t - tr[np.clip(j - 1, 0, tr.size - 1)])
    after = np.abs(tr[np.clip(j, 0, tr.size - 1)] - t)
    return np.minimum(before, after)


def wrapped_angle(time, speed, *, periods_per_revolution: float = 1.0) -> Float1D:
    """Angle wrapped to [0, 2 pi) from the trapezoidal integral of ``speed`` [rad/s].

    With ``periods_per_revolution`` = pole pairs it is the electrical angle
    (torque ripple, cogging show as a dependence on it).
    """
    t, w = np.asarray(time, dtype=float), np.asarray(speed, dtype=float)
    ang = np.concatenate([[0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))])
    return np.mod(periods_per_revolution * ang, 2.0 * np.pi)


def _array(name: str, x, n: int | None, numeric: bool = True) -> np.ndarray:
    a = np.asarray(x)
    if a.ndim != 1:
        raise SignalError(name, f"must be one-dimensional, has shape {a.shape}")
    if n is not None and a.size != n:
        raise SignalError(name, f"has {a.size} samples, time has {n}")
    if numeric:
        if a.dtype.kind not in "biuf":
            raise SignalError(name, f"must be numeric, has dtype {a.dtype}")
        a = a.astype(float)
    return a


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


def _whiteness(e: np.ndarray, n: int, lag: int, z: float, alpha: float) -> Whiteness:
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


def _cross(name: str, e: np.ndarray, u: np.ndarray, n: int, lag: int, z: float, alpha: float,
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


def _lag1(x: np.ndarray) -> float:
    c0 = float(x @ x)
    return float(x[1:] @ x[:-1]) / c0 if c0 > 0 and x.size > 2 else 0.0


def _condition(name: str, values: np.ndarray, e: np.ndarray, valid: np.ndarray, s: ResidualSettings,
               alpha: float) -> ConditionedResidual:
    labels_map = s.category_labels.get(name, {})
    if values.dtype.kind in "biuf":
        x = values.astype(float)
        finite = np.isfinite(x)
        uniq = np.unique(x[finite & valid])
        categorical = values.dtype.kind == "b" or uniq.size <= s.max_categories
    else:
        x = values.astype(str)
        finite = np.ones(x.size, dtype=bool)
        uniq = np.unique(x[valid])
        categorical = True
    use = valid & finite
    groups: list[tuple[str, float, float, np.ndarray]] = []
    if not np.any(use):
        return ConditionedResidual(name, "categorical" if categorical else "quantile", (), 0.0, 0.0)
    if categorical:
        for u in uniq:
            m = use & (x == u)
            if values.dtype.kind in "biuf":
                lab = labels_map.get(float(u), f"{float(u):g}")
                groups.append((lab, float(u), float(u), m))
            else:
                groups.append((str(u), math.nan, math.nan, m))
        binning = "categorical"
    else:
        edges = np.unique(np.quantile(x[use], np.linspace(0.0, 1.0, s.n_bins + 1)))
        idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, max(edges.size - 2, 0))
        for b in range(max(edges.size - 1, 1)):
            lo, hi = float(edges[b]), float(edges[min(b + 1, edges.size - 1)])
            groups.append((f"[{lo:.4g}, {hi:.4g}]", lo, hi, use & (idx == b)))
        binning = "quantile"
    ev = e[use]
    mu = float(np.mean(ev)) if ev.size else math.nan
    # residual about its bin means, in time order, for the effective sample size
    about = np.zeros(e.size)
    between = 0.0
    for _, _, _, m in groups:
        if np.any(m):
            mb = float(np.mean(e[m]))
            about[m] = e[m] - mb
            between += m.sum() * (mb - mu) ** 2
    total = float(np.sum((ev - mu) ** 2))
    rho = max(0.0, min(_lag1(about[use]), 0.99))
    shrink = (1.0 - rho) / (1.0 + rho)
    tested = [g for g in groups if g[3].sum() >= s.min_bin_count]
    level = alpha / max(len(tested), 1)
    bins = []
    dev_all = (e - mu) ** 2
    for lab, lo, hi, m in groups:
        cnt = int(m.sum())
        eb = e[m]
        mean = float(np.mean(eb)) if cnt else math.nan
        rms = float(np.sqrt(np.mean(eb ** 2))) if cnt else math.nan
        mean_p = excess_p = 1.0
        ratio = math.nan
        rest = use & ~m
        if cnt >= s.min_bin_count and rest.sum() >= s.min_bin_count:
            n_eff = max(2.0, cnt * shrink)
            sd = float(np.std(eb, ddof=1))
            if sd > 0:
                t = (mean - mu) / (sd / math.sqrt(n_eff))
                mean_p = float(2.0 * stats.t.sf(abs(t), n_eff - 1.0))
            ms_b, ms_r = float(np.mean(dev_all[m])), float(np.mean(dev_all[rest]))
            if ms_r > 0:
                ratio = ms_b / ms_r
                excess_p = float(stats.f.sf(ratio, n_eff, max(2.0, rest.sum() * shrink)))
        bins.append(ResidualBin(lab, lo, hi, cnt, mean, rms, mean_p, bool(mean_p < level), ratio, excess_p,
                                bool(excess_p < level)))
    return ConditionedResidual(name, binning, tuple(bins), between / total if total > 0 else 0.0, rho)


def _spectrum(t: np.ndarray, e: np.ndarray, valid: np.ndarray, dt: float, uniform: bool,
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


# ------------------------------------------------------------------ main
def analyse_residuals(time, measured: Mapping[str, np.ndarray], simulated: Mapping[str, np.ndarray],
                      conditioning: Mapping[str, np.ndarray], inputs: Mapping[str, np.ndarray], *,
                      settings: ResidualSettings | None = None,
                      units: Mapping[str, str] | None = None) -> ResidualAnalysis:
    """Residual statistics, whiteness, cross-correlation, conditioning and spectrum per channel.

    Parameters
    ----------
    time : array_like
        Sample times [s], strictly increasing.
    measured, simulated : mapping of str to array_like
        Channels [any unit, the same for both]; the keys present in both are
        analysed, in ``measured`` order.  NaN samples are left out.
    conditioning : mapping of str to array_like
        Operating variables to bin the residual on (speed [m/s], load [N],
        ``quadrant(...)``, temperature [degC], nut position [m], motor angle
        [rad], reversal proximity [s], motor on/off [0/1], ...).  Numeric,
        boolean or string arrays.
    inputs : mapping of str to array_like
        Inputs to cross-correlate with (load force, speed command, ...).
    settings : ResidualSettings, optional
    units : mapping of str to str, optional
        Unit of each channel, for the report.

    Returns
    -------
    ResidualAnalysis

    Raises
    ------
    SignalError
        A signal is not one-dimensional, has the wrong length or a bad dtype,
        time is not finite and strictly increasing, no channel is common to
        ``measured`` and ``simulated``, or a channel has fewer than 16 valid
        samples.
    ValueError
        Invalid settings.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(1000) * 1e-3
    >>> e = np.random.default_rng(1).standard_normal(t.size)
    >>> a = analyse_residuals(t, {"f": e + 3.0}, {"f": np.full(t.size, 3.0)}, {}, {})
    >>> round(a["f"].rms, 2), a["f"].whiteness.white
    (0.99, True)
    """
    s = (settings or ResidualSettings()).validate()
    t = _array("time", time, None)
    n_all = t.size
    if n_all < 16 or not np.all(np.isfinite(t)):
        raise SignalError("time", "needs at least 16 finite samples")
    dts = np.diff(t)
    if np.any(dts <= 0):
        i = int(np.flatnonzero(dts <= 0)[0])
        raise SignalError("time", f"not strictly increasing at sample {i + 1} ({t[i]!r} -> {t[i + 1]!r})")
    dt = float(np.median(dts))
    uniform = bool(np.all(np.abs(dts - dt) <= 0.01 * dt))
    names = [k for k in measured if k in simulated]
    ignored = tuple([k for k in measured if k not in simulated] + [k for k in simulated if k not in measured])
    if not names:
        raise SignalError("measured", f"no channel in common with simulated (measured: {list(measured)}, "
                                      f"simulated: {list(simulated)})")
    cond = {k: _array(f"conditioning['{k}']", v, n_all, numeric=False) for k, v in conditioning.items()}
    for k, v in cond.items():
        if v.dtype.kind not in "biufUSO":
            raise SignalError(f"conditioning['{k}']", f"unsupported dtype {v.dtype}")
    ins = {k: _array(f"inputs['{k}']", v, n_all) for k, v in inputs.items()}
    alpha = 1.0 - s.confidence
    units = dict(units or {})
    channels = {}
    lag_used = s.max_lag
    for name in names:
        y = _array(f"measured['{name}']", measured[name], n_all)
        yh = _array(f"simulated['{name}']", simulated[name], n_all)
        valid = np.isfinite(y) & np.isfinite(yh)
        n = int(valid.sum())
        if n < 16:
            raise SignalError(f"measured['{name}']", f"only {n} valid samples (measured and simulated finite)")
        e = np.where(valid, y - yh, np.nan)
        ev = e[valid]
        lag = max(1, min(s.max_lag, n // 4))
        lag_used = min(lag_used, lag)
        num = float(np.linalg.norm(ev))
        den = float(np.linalg.norm(y[valid] - np.mean(y[valid])))
        nrmse = num / den if den > 0 else (math.inf if num > 0 else 0.0)
        ec = np.where(valid, e - np.mean(ev), 0.0)  # centred, zero where missing
        imax = int(np.nanargmax(np.abs(e)))
        cross = {}
        for k, u in ins.items():
            uv = np.isfinite(u)
            uc = np.where(uv & valid, u - (np.mean(u[uv & valid]) if np.any(uv & valid) else 0.0), 0.0)
            cross[k] = _cross(k, ec, uc, n, lag, s.z, alpha, s.prewhiten_max_order)
        channels[name] = ChannelResiduals(
            name=name, unit=units.get(name, ""), residual=e, n=n, rms=float(np.sqrt(np.mean(ev ** 2))),
            mean=float(np.mean(ev)), std=float(np.std(ev, ddof=1)), max_abs=float(abs(e[imax])),
            time_of_max=float(t[imax]), nrmse=nrmse, fit_percent=100.0 * (1.0 - nrmse),
            whiteness=_whiteness(ec, n, lag, s.z, alpha),
            cross=cross,
            conditioned={k: _condition(k, v, e, valid, s, alpha) for k, v in cond.items()},
            spectrum=_spectrum(t, e, valid, dt, uniform, s),
        )
    return ResidualAnalysis(channels, t, dt, uniform, lag_used, s, ignored)


def _p(p: float) -> str:
    return f"{p:.3g}" if p >= 1e-4 else f"{p:.1e}"


def _display(name: str, unit: str) -> tuple[float, str]:
    """(factor, unit) to show a channel: its display unit when it is a known signal in SI, else as it is."""
    from ..data.units import SIGNAL_QUANTITY, signal_display

    du = signal_display(name)
    if name in SIGNAL_QUANTITY and unit == du.si:
        return du.factor, du.unit
    return 1.0, unit


def _bin_label(v: ConditionedResidual, b: ResidualBin) -> str:
    """A bin's label in the display unit of its conditioning signal (SI inside: m/s -> mm/s, N -> kN)."""
    from ..data.units import SIGNAL_QUANTITY, signal_display

    if v.signal not in SIGNAL_QUANTITY or not np.isfinite(b.low):
        return b.label
    du = signal_display(v.signal)
    if v.binning == "categorical":
        return f"{du.to_display(b.low):.4g} {du.unit}" if b.label == f"{b.low:g}" else b.label
    return f"[{du.to_display(b.low):.4g}, {du.to_display(b.high):.4g}] {du.unit}"


def format_residual_report(analysis: ResidualAnalysis, *, channels: Sequence[str] | None = None) -> str:
    """lmfit-style text report of a :class:`ResidualAnalysis`.

    Parameters
    ----------
    analysis : ResidualAnalysis
    channels : sequence of str, optional
        Channels to include (default all).

    Returns
    -------
    str
    """
    s = analysis.settings
    pct = f"{100 * s.confidence:g} %"
    out = ["[[Residual analysis]]",
           f"    # samples          = {analysis.time.size}",
           f"    # sample time      = {analysis.sample_time:.6g} s "
           f"({'uniform' if analysis.uniform else 'non-uniform'})",
           f"    # max lag          = {analysis.max_lag}",
           f"    # confidence       = {pct}",
           "    residual           = measured - simulated"]
    if analysis.ignored:
        out.append(f"    # ignored (no partner) = {', '.join(analysis.ignored)}")
    for name in channels or list(analysis.channels):
        c = analysis[name]
        kd, unit = _display(name, c.unit)  # a known signal in its display unit (rad/s -> rpm, m -> mm)
        u = f" {unit}" if unit else ""
        w = c.whiteness
        out += [f"[[Channel {name}]]",
                f"    valid samples      = {c.n}",
                f"    RMS                = {c.rms * kd:.6g}{u}",
                f"    mean (bias)        = {c.mean * kd:.6g}{u}",
                f"    max |residual|     = {c.max_abs * kd:.6g}{u} at t = {c.time_of_max:.6g} s",
                f"    NRMSE              = {c.nrmse:.4g}",
                f"    fit                = {c.fit_percent:.2f} %",
                "  [[Whiteness]]",
                f"    Ljung-Box Q({w.ljung_box_dof}) = {w.ljung_box_q:.4g}, p = {_p(w.ljung_box_p)}"
                f" -> {'white' if w.white else 'NOT WHITE'} at {pct}",
                f"    lags outside +-{w.band:.4g}: {100 * w.fraction_outside:.0f} %"
                f" (largest |r| = {np.max(np.abs(w.acf[1:])):.3f} at lag {int(np.argmax(np.abs(w.acf[1:]))) + 1})"]
        if c.cross:
            out.append("  [[Cross-correlation with inputs]]")
            for k, x in c.cross.items():
                out.append(f"    {k}: max |r| = {x.max_abs:.3f} at lag {x.lag_at_max}, "
                           f"outside band {100 * x.fraction_outside:.0f} %,"
                           f" N R^2 = {x.statistic:.4g} ({x.dof} dof, AR({x.prewhiten_order}) prewhitened),"
                           f" p = {_p(x.p_value)} -> {'CORRELATED' if x.correlated else 'independent'}")
        if c.conditioned:
            out.append("  [[Conditioned on]] (* = residual significantly larger than elsewhere, "
                       "+ = mean differs from the overall mean)")
            ranked = sorted(c.conditioned.values(), key=lambda v: -v.eta_squared)
            for v in ranked:
                sig = f"; significant: {', '.join(v.significant_bins)}" if v.significant_bins else ""
                out.append(f"    {v.signal} ({v.binning}, eta^2 = {v.eta_squared:.3f}, lag-1 rho = "
                           f"{v.lag1_correlation:.2f}){sig}")
                labels = [_bin_label(v, b) for b in v.bins]
                width = max(len(lab) for lab in labels) if labels else 0
                for b, lab in zip(v.bins, labels):
                    mark = ("*" if b.significant else " ") + ("+" if b.mean_significant else " ")
                    out.append(f"      {mark} {lab:<{width}}  n = {b.count:>7d}  mean = {b.mean * kd:+.4g}  rms = "
                               f"{b.rms * kd:.4g}  ms ratio = {b.excess_ratio:.3g} (p = {_p(b.excess_p)})"
                               f"  mean p = {_p(b.mean_p)}")
        sp = c.spectrum
        peaks = ", ".join(f"{p.frequency:.4g} Hz (x{p.ratio:.1f} median)" for p in sp.peaks) or "none"
        out += ["  [[Spectrum]]", f"    Welch, resolution {sp.resolution:.4g} Hz; dominant peaks: {peaks}"]
    return "\n".join(out)
