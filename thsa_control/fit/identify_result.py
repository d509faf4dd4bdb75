"""The result of an identification and its report-ready statistics.

Owns :class:`ParameterEstimate` (one identified parameter: value, standard
error, bounds, flags), :class:`IdentificationResult` (lmfit ``ModelResult``
style: estimates, correlation, chi-square / AIC / BIC, per-channel fits, the
identifiability flags, the lmfit-style text report and the TOML export), the
thresholds of those flags (:data:`NOT_DETERMINED_REL_STDERR`,
:data:`COLLINEAR_CORRELATION`) and :func:`collinearity_safe_inverse`, the
pseudo-inverse the covariance is computed with.  The fit itself is
:class:`thsa_control.fit.identify.Identifier`; the statistics' definitions are
in that module's docstring.

Imports numpy and scipy; no matplotlib (``plot`` is a lazy pass-through to
:mod:`thsa_control.report`), no file parsing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path
from types import MappingProxyType
from typing import TYPE_CHECKING

import numpy as np

from ..model.params import ParameterSet

if TYPE_CHECKING:
    from .identify import IdentificationSettings

__all__ = ["NOT_DETERMINED_REL_STDERR", "COLLINEAR_CORRELATION", "ParameterEstimate", "IdentificationResult",
           "collinearity_safe_inverse"]

#: A parameter whose standard error exceeds this fraction of its value is not determined by the data.
NOT_DETERMINED_REL_STDERR = 0.5
#: Above this |correlation| two parameters are collinear in the data: only their combination is determined.
COLLINEAR_CORRELATION = 0.999


@dataclass(frozen=True)
class ParameterEstimate:
    """One identified parameter (lmfit's ``Parameter`` after a fit).

    Attributes
    ----------
    name, unit : str
    value : float
        Estimate [SI].
    stderr : float
        Standard error [SI] (inf: not determined by the data).
    init : float
        Initial value [SI].
    min, max : float
        Bounds used.
    at_bound : str or None
        ``"min"`` / ``"max"`` when the estimate sits on a bound.
    at_initial : bool
        The estimate did not move from its initial value.
    stderr_data : float
        Standard error [SI] from the runs' information and the explicit priors (external knowledge,
        ``IdentificationSettings.priors``), the regularising priors (``prior_relative_sd`` around the
        initial values) left out of the Fisher information: inf where only such a prior determines the
        parameter, or only together with another parameter.  ``stderr`` is the posterior one (with
        every prior); nan where not computed.
    stderr_segments : float
        Standard error [SI] with the segments as independent clusters (the sandwich ``C (sum_m g_m g_m') C``,
        ``g_m`` a segment's gradient with its start states profiled out, :func:`thsa_control.fit.identify.
        segment_information`): the spread the estimate would have if the record's segments were drawn again,
        whatever the residual's structure within a segment.  About ``stderr`` where the residual is the sensor
        noise; several times it where a model mismatch makes the residual structured (a value pulled by a few
        events).  nan where not computed (at a bound, where the gradient is not zero).
    """

    name: str
    unit: str
    value: float
    stderr: float
    init: float
    min: float
    max: float
    at_bound: str | None
    at_initial: bool
    stderr_data: float = math.nan
    stderr_segments: float = math.nan

    @property
    def relative_stderr(self) -> float:
        """``stderr / |value|`` [-]."""
        return self.stderr / abs(self.value) if self.value != 0 else math.inf

    def interval(self, level: float = 0.95) -> tuple[float, float]:
        """Two-sided normal confidence interval ``value -+ z stderr`` at ``level``."""
        from scipy.stats import norm

        z = float(norm.ppf(0.5 + level / 2))
        return self.value - z * self.stderr, self.value + z * self.stderr

    def to_dict(self) -> dict:
        """JSON-ready dict."""
        d = dict(self.__dict__)
        d["stderr"] = self.stderr if math.isfinite(self.stderr) else None
        d["stderr_data"] = self.stderr_data if math.isfinite(self.stderr_data) else None
        d["stderr_segments"] = self.stderr_segments if math.isfinite(self.stderr_segments) else None
        d["min"] = self.min if math.isfinite(self.min) else None
        d["max"] = self.max if math.isfinite(self.max) else None
        return d


@dataclass(frozen=True)
class IdentificationResult:
    """What a fit found and how far to trust it (lmfit ``ModelResult`` style).

    Attributes
    ----------
    method : str
    effects : tuple of str
        Effect set of the model.
    runs : tuple of str
        Names of the runs fitted together.
    params : ParameterSet
        The initial set (values, bounds, sources), untouched.
    estimates : mapping name -> ParameterEstimate
        The free parameters.
    correlation : ndarray
        Correlation matrix of the free parameters (``estimates`` order).
    high_correlations : tuple of (str, str, float)
        Pairs with ``|rho|`` above the threshold, largest first.
    n_data, n_free, n_varys : int
        Weighted residuals, free parameters, all decision variables
        (parameters and segment initial states).
    chisqr, redchi, aic, bic : float
        Weighted statistics (weights = 1 / channel noise RMS).
    channel_fits : mapping run -> mapping channel -> ChannelFit
        Segment predictions against the data, after the fit.
    initial_channel_fits : mapping run -> mapping channel -> ChannelFit
        Same at the initial values (segments' states fitted for those).
    noise : mapping run -> mapping channel -> float
        Residual RMS per channel after the fit (the weights of the covariance).
    success : bool
    status : str
        Solver status text.
    nfev, njev : int
    time_s : float
        Wall time of the whole fit [s].
    predictions : mapping run -> dict
        ``time``, ``measured`` and ``simulated`` (dicts by channel) and
        ``segment_starts`` [s], for plots.
    settings : IdentificationSettings
    global_stage : dict
        Differential evolution summary (empty when not run).
    converged : bool
        False when the evaluation limit or the time budget stopped the fit:
        the estimates are the best point found, not a converged optimum.
    priors : mapping name -> (mean, sd)
        Regularisation priors used (empty without).
    holdout_fits : mapping run -> mapping channel -> ChannelFit
        Error on the held-out segments (empty when none held out).
    warnings : tuple of str
        What the model only approximates in these runs.
    segment_information : mapping run -> ndarray (segments x free parameters)
        Each segment's share of the data's information on each free parameter, its own start states profiled
        out (:func:`thsa_control.fit.identify.segment_information`): where a value comes from.  Held-out segments
        carry none.
    segment_influence : mapping run -> ndarray (segments x free parameters)
        How far each estimate moves, in its standard errors, with each segment left out (first order; same
        function).
    segment_states : mapping run -> ndarray
        Each run's fitted segment start states (held-out segments' included), the decision vector a later fit of
        the same layout starts from (:meth:`Identifier.fit`'s ``initial_states``).
    custom_states : mapping run -> ndarray
        Each run's custom states (pawl clearances) at the segment starts (states x segments), where the model has
        any: with ``segment_states`` what a refit needs to start at this fit's predictions (``custom_states``).
    """

    method: str
    effects: tuple[str, ...]
    runs: tuple[str, ...]
    params: ParameterSet
    estimates: MappingProxyType
    correlation: np.ndarray
    high_correlations: tuple[tuple[str, str, float], ...]
    n_data: int
    n_free: int
    n_varys: int
    chisqr: float
    redchi: float
    aic: float
    bic: float
    channel_fits: MappingProxyType
    initial_channel_fits: MappingProxyType
    noise: MappingProxyType
    success: bool
    status: str
    nfev: int
    njev: int
    time_s: float
    predictions: MappingProxyType
    settings: IdentificationSettings
    global_stage: dict = field(default_factory=dict)
    converged: bool = True
    priors: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    holdout_fits: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    warnings: tuple[str, ...] = ()
    segment_information: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    segment_influence: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    segment_states: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))
    custom_states: MappingProxyType = field(default_factory=lambda: MappingProxyType({}))

    @property
    def names(self) -> tuple[str, ...]:
        """Free parameter names."""
        return tuple(self.estimates)

    @property
    def values(self) -> dict[str, float]:
        """Estimates by name [SI]."""
        return {n: e.value for n, e in self.estimates.items()}

    @property
    def not_identifiable(self) -> tuple[str, ...]:
        """Parameters the data do not determine: undetermined stderr, or stderr above half the value.

        A high correlation (:attr:`high_correlations`) alone does not make a
        parameter unidentifiable: its standard error comes from the
        covariance, which already counts the correlation, so a correlated
        parameter with a small standard error is determined (reported as
        "correlated with ...").  A flagged pair (|rho| above the threshold)
        one of whose members is undetermined, or whose correlation exceeds
        :data:`COLLINEAR_CORRELATION`, is seen only as a combination: both
        are flagged.
        """
        out = {n for n, e in self.estimates.items()
               if not math.isfinite(e.stderr) or e.relative_stderr > NOT_DETERMINED_REL_STDERR}
        for a, b, rho in self.high_correlations:  # only a combination of the pair is seen: both go
            if a in out or b in out or abs(rho) > COLLINEAR_CORRELATION:
                out |= {a, b}
        return tuple(n for n in self.estimates if n in out)

    def to_parameter_set(self, source: str | None = None) -> ParameterSet:
        """The initial set with the estimates as values; their ``source`` says where they come from."""
        new = {}
        for n, e in self.estimates.items():
            old = self.params[n]
            src = source or (f"identified: {self.method} on {', '.join(self.runs)}; "
                             f"stderr {e.stderr:.3g} {old.unit}" if math.isfinite(e.stderr) else
                             f"identified: {self.method} on {', '.join(self.runs)}; stderr undetermined")
            new[n] = dc_replace(old, value=e.value, source=src)  # keeps the search and physical bounds
        return self.params.replace_parameters(new)

    def parameters_toml(self) -> str:
        """TOML of the identified entries only, for ``load_parameters(path, base=...)``."""
        return self._identified_set().to_toml()

    def full_parameters_toml(self) -> str:
        """TOML of the whole set (identified entries replaced): replayable with ``--params`` alone."""
        return self.to_parameter_set().to_toml()

    def _identified_set(self) -> ParameterSet:
        full = self.to_parameter_set()
        return ParameterSet(tuple(full[n] for n in self.estimates))

    def save_parameters(self, path: str | Path) -> Path:
        """Write the whole set with the estimates (:meth:`full_parameters_toml`) to ``path`` (atomically).

        It replays the identified model with ``--params`` alone; the
        identified entries carry an ``identified:`` source.
        """
        return self.to_parameter_set().save(path)

    def to_dict(self) -> dict:
        """JSON-ready summary (no time series)."""
        def fits(table):
            return {r: {c: f.to_dict() for c, f in ch.items()} for r, ch in table.items()}

        return {
            "method": self.method, "effects": list(self.effects), "runs": list(self.runs),
            "success": self.success, "status": self.status, "nfev": self.nfev, "njev": self.njev,
            "time_s": self.time_s, "n_data": self.n_data, "n_free": self.n_free, "n_varys": self.n_varys,
            "chisqr": self.chisqr, "redchi": self.redchi, "aic": self.aic, "bic": self.bic,
            "parameters": {n: e.to_dict() for n, e in self.estimates.items()},
            "correlation": {"names": list(self.names), "matrix": np.nan_to_num(self.correlation).tolist()},
            "high_correlations": [list(p) for p in self.high_correlations],
            "not_identifiable": list(self.not_identifiable),
            "channel_fits": fits(self.channel_fits), "initial_channel_fits": fits(self.initial_channel_fits),
            "noise_rms": {r: dict(v) for r, v in self.noise.items()},
            "settings": {k: (dict(v) if isinstance(v, Mapping) else (list(v) if isinstance(v, tuple) else v))
                         for k, v in self.settings.__dict__.items()},
            "global_stage": dict(self.global_stage),
            "converged": self.converged,
            "priors": {n: {"mean": m, "sd": sd} for n, (m, sd) in self.priors.items()},
            "holdout_fits": fits(self.holdout_fits),
            "warnings": list(self.warnings),
        }

    def fit_report(self) -> str:
        """lmfit-style text report."""
        lines = ["[[Fit Statistics]]",
                 f"    # method           = {self.method} (effects: {', '.join(self.effects) or 'functional'})",
                 f"    # runs             = {', '.join(self.runs)}",
                 f"    # solver           = scipy least_squares trf: {self.status}",
                 *(["    # NOT CONVERGED: the estimates are the best point found before the limit"]
                   if not self.converged else []),
                 *(["    # priors           = " + ", ".join(f"{n} ~ N({m:.4g}, {sd:.3g})"
                                                               for n, (m, sd) in self.priors.items())]
                   if self.priors else []),
                 f"    # function evals   = {self.nfev} (jacobians {self.njev}), {self.time_s:.1f} s",
                 f"    # data points      = {self.n_data}",
                 f"    # variables        = {self.n_free} parameters + {self.n_varys - self.n_free} segment states",
                 f"    chi-square         = {self.chisqr:.6g}",
                 f"    reduced chi-square = {self.redchi:.6g}",
                 f"    Akaike info crit   = {self.aic:.6g}",
                 f"    Bayesian info crit = {self.bic:.6g}"]
        if self.global_stage:
            lines.append(f"    global stage       = differential evolution, {self.global_stage.get('nfev')} evals, "
                         f"cost {self.global_stage.get('fun', float('nan')):.4g}")
        lines.append("[[Variables]]")
        for n, e in self.estimates.items():
            # a relative error means nothing for a value at (or next to) zero
            pct = f"({100 * e.relative_stderr:.2f}%)" if math.isfinite(e.relative_stderr) and e.relative_stderr < 1e3 else ""
            err = f"+/- {e.stderr:.4g} {pct}" if math.isfinite(e.stderr) else "+/- undetermined"
            flags = []
            if e.at_bound:
                flags.append(f"AT {e.at_bound.upper()} BOUND")
            if e.at_initial:
                flags.append("AT INITIAL VALUE")
            if n in self.not_identifiable:
                flags.append("NOT IDENTIFIABLE")
            if math.isfinite(e.stderr_segments) and math.isfinite(e.stderr) and e.stderr_segments > 2.0 * e.stderr:
                # the residual is structured: a few segments pull the value (stderr_segments)
                flags.append(f"+/- {e.stderr_segments:.4g} OVER THE SEGMENTS ({e.stderr_segments / e.stderr:.3g} x)")
            partners = [b if a == n else a for a, b, _ in self.high_correlations if n in (a, b)]
            if partners:
                flags.append(f"CORRELATED WITH {', '.join(partners)}")
            lines.append(f"    {n}: {e.value:.6g} {err} [{e.unit}] (init = {e.init:.6g})"
                         + (f"  <- {', '.join(flags)}" if flags else ""))
        lines.append(f"[[Correlations]] (|rho| > {self.settings.correlation_threshold:g}: flagged, the pair moves together; "
                     "the standard errors count it)")
        names = self.names
        pairs = [(names[i], names[j], self.correlation[i, j]) for i in range(len(names)) for j in range(i + 1, len(names))]
        pairs = sorted((p for p in pairs if np.isfinite(p[2]) and abs(p[2]) > 0.1), key=lambda p: -abs(p[2]))
        for a, b, r in pairs:
            mark = "  <- FLAGGED" if abs(r) > self.settings.correlation_threshold else ""
            lines.append(f"    C({a}, {b}) = {r:+.4f}{mark}")
        if not pairs:
            lines.append("    (none above 0.1)")
        lines.append("[[Channels]] (segment predictions: before -> after; display units)")
        from ..data.units import SIGNAL_QUANTITY, signal_display

        for run, chans in self.channel_fits.items():
            for c, f in chans.items():
                f0 = self.initial_channel_fits[run][c]
                du = signal_display(c)
                k, unit = (du.factor, du.unit) if c in SIGNAL_QUANTITY and f.unit == du.si else (1.0, f.unit)
                lines.append(f"    {run} {c}: RMS {f0.rms * k:.4g} -> {f.rms * k:.4g} [{unit}], NRMSE {f0.nrmse:.4g} -> "
                             f"{f.nrmse:.4g}, fit {f0.fit_percent:.2f} -> {f.fit_percent:.2f} %")
        return "\n".join(lines)

    def report(self) -> str:
        """lmfit-style text report (:meth:`fit_report`)."""
        return self.fit_report()

    def plot(self, ax=None, run: str | None = None):
        """Segment predictions of ``run`` (default the first), initial and identified; ``ax``: one Axes per channel."""
        from ..report.identification import plot_segments

        name = run if run is not None else next(iter(self.predictions))
        return plot_segments(self.predictions[name], title=f"{name}: segment predictions", axes=ax)


def collinearity_safe_inverse(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverse of a symmetric PSD matrix and a mask of columns it cannot resolve."""
    d = np.sqrt(np.clip(np.diag(A), 1e-300, None))
    As = A / np.outer(d, d)
    w, V = np.linalg.eigh(As)
    tol = max(w.max(), 1e-300) * A.shape[0] * 1e-12
    inv_w = np.where(w > tol, 1.0 / np.where(w > tol, w, 1.0), 0.0)
    cov_s = (V * inv_w) @ V.T
    unresolved = np.zeros(A.shape[0], bool)
    for k in np.flatnonzero(w <= tol):
        unresolved |= np.abs(V[:, k]) > 1e-3
    return cov_s / np.outer(d, d), unresolved
