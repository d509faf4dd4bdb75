"""The residual per operating regime: the conditioning variables and the binned residual.

Owns the operating variables a residual is conditioned on (:func:`quadrant`
with :data:`QUADRANT_LABELS`, :func:`reversal_proximity`,
:func:`wrapped_angle`), the result types :class:`ResidualBin` and
:class:`ConditionedResidual`, and :func:`condition_residual`: categories or
quantile bins, per bin a t-test of the mean and a one-sided F-test of the mean
square, Bonferroni-corrected, with an effective sample size from the lag-1
autocorrelation.  The definitions are in :mod:`thsa_control.fit.residuals`'
docstring, whose :func:`~thsa_control.fit.residuals.analyse_residuals` calls
:func:`condition_residual` per channel and conditioning signal.

Imports numpy, scipy and :mod:`thsa_control.errors` only; never matplotlib.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy import stats

from thsa_control.data.rigformat import speed_integral
from thsa_control.errors import SignalError

if TYPE_CHECKING:
    from .residuals import ResidualSettings

__all__ = ["QUADRANT_LABELS", "quadrant", "reversal_proximity", "wrapped_angle", "ResidualBin",
           "ConditionedResidual", "condition_residual"]

Float1D = NDArray[np.float64]

#: Labels of :func:`quadrant` categories (FORMAT.md signs).
QUADRANT_LABELS: dict[int, str] = {1: "opposing", -1: "aiding", 0: "unloaded/stopped"}


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
    return np.mod(periods_per_revolution * speed_integral(time, speed), 2.0 * np.pi)


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


def _lag1(x: np.ndarray) -> float:
    c0 = float(x @ x)
    return float(x[1:] @ x[:-1]) / c0 if c0 > 0 and x.size > 2 else 0.0


def condition_residual(name: str, values: np.ndarray, e: np.ndarray, valid: np.ndarray, s: ResidualSettings,
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
