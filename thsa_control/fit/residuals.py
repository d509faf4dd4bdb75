"""Residual analysis numerics (issue 4, item 6): where and how a model misses the data.

Generic over arrays: it knows nothing of files, models or plots.  Given the
measured and simulated signals of a run, the operating variables to condition
on and the inputs, :func:`analyse_residuals` returns frozen results per
channel, and :func:`format_residual_report` prints them lmfit-style.  It
imports numpy, scipy and :mod:`thsa_control.errors` only; never matplotlib
(``thsa_control.report`` draws these results).

This module owns the settings, the per-channel and whole-run result types,
:func:`analyse_residuals` and the text report; the time-series statistics
(whiteness, input cross-correlation, spectrum) live in
:mod:`thsa_control.fit.residual_spectral`, the conditioning on operating
regimes (quadrant, reversal proximity, binned residual) in
:mod:`thsa_control.fit.residual_regimes` (all re-exported here).

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
from scipy import stats

from thsa_control.errors import SignalError  # noqa: F401 (re-exported)

from .residual_regimes import (
    QUADRANT_LABELS, ConditionedResidual, ResidualBin, condition_residual, quadrant, reversal_proximity, wrapped_angle,
)
from .residual_spectral import (
    CrossCorrelation, ResidualSpectrum, SpectralPeak, Whiteness, autocorrelation_test, cross_correlation_test,
    residual_spectrum,
)

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
            cross[k] = cross_correlation_test(k, ec, uc, n, lag, s.z, alpha, s.prewhiten_max_order)
        channels[name] = ChannelResiduals(
            name=name, unit=units.get(name, ""), residual=e, n=n, rms=float(np.sqrt(np.mean(ev ** 2))),
            mean=float(np.mean(ev)), std=float(np.std(ev, ddof=1)), max_abs=float(abs(e[imax])),
            time_of_max=float(t[imax]), nrmse=nrmse, fit_percent=100.0 * (1.0 - nrmse),
            whiteness=autocorrelation_test(ec, n, lag, s.z, alpha),
            cross=cross,
            conditioned={k: condition_residual(k, v, e, valid, s, alpha) for k, v in cond.items()},
            spectrum=residual_spectrum(t, e, valid, dt, uniform, s),
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
