"""Distributions and sampling plans of a sweep (numbers only).

A :class:`Distribution` maps a uniform number ``u`` in (0, 1) to a value
through its inverse CDF (``ppf``), so that every sampling plan (plain Monte
Carlo, Latin hypercube, scrambled Sobol', Saltelli) produces unit-cube points
and one code path turns them into parameter values.  ``grid`` distributions
are not sampled: their values form a Cartesian product with the other grids.

Seeds: plain Monte Carlo draws sample ``j`` from its own stream
``SeedSequence([seed, j])`` (a sample does not depend on how many others
there are, nor on which worker runs it); Latin hypercube and Sobol' plans are
drawn as a whole from ``seed`` on the client, before any work is split.

Examples
--------
>>> d = Distribution("uniform", low=2.0, high=4.0)
>>> d.ppf(np.array([0.0, 0.25, 1.0])).tolist()
[2.0, 2.5, 4.0]
>>> unit_samples("random", 3, 2, seed=1).shape
(3, 2)
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.stats import qmc

__all__ = ["DISTRIBUTIONS", "SAMPLING_METHODS", "Distribution", "saltelli_blocks", "unit_samples"]

#: distribution -> required keys (``grid``: ``values``)
DISTRIBUTIONS = {
    "uniform": ("min", "max"),
    "loguniform": ("min", "max"),
    "normal": ("mean", "sd"),
    "truncnormal": ("mean", "sd", "min", "max"),
    "lognormal": ("median", "sigma_log"),
    "grid": ("values",),
}
#: random: independent draws per sample; lhs: Latin hypercube; sobol: scrambled Sobol' points;
#: saltelli: Saltelli's A, B, AB_i blocks for Sobol' indices (samples x (d + 2) runs); grid: grids only.
SAMPLING_METHODS = ("random", "lhs", "sobol", "saltelli", "grid")
_EPS = 1e-12  # keeps the normal's inverse CDF finite at u = 0 or 1


@dataclass(frozen=True)
class Distribution:
    """One distribution; its support is ``(lower, upper)`` (``grid``: the values).

    Parameters
    ----------
    kind : str
        One of :data:`DISTRIBUTIONS`.
    low, high : float
        ``uniform``, ``loguniform``, ``truncnormal`` bounds.
    mean, sd : float
        ``normal``, ``truncnormal`` (of the untruncated normal).
    median, sigma_log : float
        ``lognormal``: ``median * exp(sigma_log * z)``, z standard normal.
    values : tuple of float
        ``grid``.
    """

    kind: str
    low: float = math.nan
    high: float = math.nan
    mean: float = math.nan
    sd: float = math.nan
    median: float = math.nan
    sigma_log: float = math.nan
    values: tuple[float, ...] = ()

    @property
    def support(self) -> tuple[float, float]:
        """Smallest and largest value the distribution can give."""
        if self.kind in ("uniform", "loguniform", "truncnormal"):
            return self.low, self.high
        if self.kind == "normal":
            return -math.inf, math.inf
        if self.kind == "lognormal":
            return 0.0, math.inf
        return min(self.values), max(self.values)

    @property
    def is_grid(self) -> bool:
        return self.kind == "grid"

    def ppf(self, u: np.ndarray) -> np.ndarray:
        """Values at the unit-interval points ``u`` (inverse CDF)."""
        u = np.asarray(u, dtype=float)
        if self.kind == "uniform":
            return self.low + u * (self.high - self.low)
        if self.kind == "loguniform":
            return np.exp(math.log(self.low) + u * (math.log(self.high) - math.log(self.low)))
        z = stats.norm.ppf(np.clip(u, _EPS, 1 - _EPS))
        if self.kind == "normal":
            return self.mean + self.sd * z
        if self.kind == "lognormal":
            return self.median * np.exp(self.sigma_log * z)
        if self.kind == "truncnormal":
            a, b = (self.low - self.mean) / self.sd, (self.high - self.mean) / self.sd
            return np.clip(stats.truncnorm.ppf(u, a, b, loc=self.mean, scale=self.sd), self.low, self.high)
        raise ValueError(f"a {self.kind} distribution is not sampled (its values are a grid)")

    def describe(self) -> str:
        """Short text, e.g. ``uniform [2, 4]``."""
        if self.kind in ("uniform", "loguniform"):
            return f"{self.kind} [{self.low:g}, {self.high:g}]"
        if self.kind == "normal":
            return f"normal (mean {self.mean:g}, sd {self.sd:g})"
        if self.kind == "truncnormal":
            return f"normal (mean {self.mean:g}, sd {self.sd:g}) truncated to [{self.low:g}, {self.high:g}]"
        if self.kind == "lognormal":
            return f"log-normal (median {self.median:g}, sigma_log {self.sigma_log:g})"
        return "grid " + ", ".join(f"{v:g}" for v in self.values)


def unit_samples(method: str, n: int, d: int, *, seed: int) -> np.ndarray:
    """``n`` points of the unit cube ``[0, 1)^d`` for ``method`` (``saltelli``: see :func:`saltelli_blocks`)."""
    if d == 0:
        return np.zeros((n, 0))
    if method == "random":
        return np.array([np.random.default_rng(np.random.SeedSequence([seed, j])).random(d) for j in range(n)])
    if method == "lhs":
        return qmc.LatinHypercube(d, seed=np.random.default_rng(seed)).random(n)
    if method == "sobol":
        with warnings.catch_warnings():  # balance properties need a power of 2; the user chose n
            warnings.simplefilter("ignore", UserWarning)
            return qmc.Sobol(d, scramble=True, seed=np.random.default_rng(seed)).random(n)
    if method == "saltelli":
        return saltelli_blocks(n, d, seed=seed)
    raise ValueError(f"sampling method {method!r} unknown; methods are {', '.join(SAMPLING_METHODS)}")


def saltelli_blocks(n: int, d: int, *, seed: int) -> np.ndarray:
    """Saltelli's plan: ``A`` (n x d), ``B``, then ``AB_i`` (A with column i from B) for i = 0..d-1.

    Rows ``k n .. (k + 1) n - 1`` are block ``k``: 0 = A, 1 = B, 2 + i = AB_i;
    ``n (d + 2)`` rows in all, from one scrambled Sobol' sequence in 2d
    dimensions (A its first d columns, B the last d).
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        base = qmc.Sobol(2 * d, scramble=True, seed=np.random.default_rng(seed)).random(n)
    A, B = base[:, :d], base[:, d:]
    blocks = [A, B]
    for i in range(d):
        ab = A.copy()
        ab[:, i] = B[:, i]
        blocks.append(ab)
    return np.vstack(blocks)
