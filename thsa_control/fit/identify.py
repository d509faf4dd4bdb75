"""Parameter identification from rig runs: casadi least squares with honest error bars.

:class:`Identifier` fits a chosen subset of a :class:`~thsa_control.model.params.ParameterSet`
to one or several rig runs at once (multi-experiment) and returns an
lmfit-style :class:`IdentificationResult`.

Method (``IdentificationSettings.method = "multiple_shooting"``, the only one
so far): the model is the plant's own discrete map driven by the measured
motor current (:func:`thsa_control.fit.replay.current_driven_map`), so the
controller and the electrics do not take part and only the mechanics are
fitted.  The mechanics are not stable in open loop (the no-back's Stribeck
friction is a negative damping; aiding loads accelerate), so each run is cut
into segments of ``segment_duration`` and each segment starts from its own
free initial speed and position (and surface states at level D): multiple
shooting without continuity constraints, each segment an experiment of its
own.  The residuals are the measured speed and position channels minus the
segment predictions, each channel weighted by its noise level; the segment
map is a casadi ``mapaccum`` mapped over the segments, and the exact Jacobian
is casadi's.  The optimiser is scipy's bounded trust-region least squares
(``least_squares(method="trf")``) on parameters scaled by their initial
value, inside the ParameterSet's bounds.  An optional global stage runs
``scipy.optimize.differential_evolution`` first, with the segments' initial
states held at their measured values.

Statistics (lmfit's definitions): the covariance of all decision variables is
``(J^T W J)^-1`` with ``W`` the inverse residual variance of each channel
after the fit (so it also scales with the reduced chi-square); the parameter
block is marginal over the segment states.  ``stderr`` is its diagonal's
square root; pairs with ``|correlation| > correlation_threshold`` are flagged
as not identifiable together (an exactly collinear pair gives +-1 through the
pseudo-inverse, and infinite stderr).  ``aic = n ln(chi2/n) + 2 k``,
``bic = n ln(chi2/n) + ln(n) k`` with ``k`` every decision variable.  Per
channel: RMS, NRMSE = ``||y - yhat|| / ||y - mean(y)||`` and fit % = ``100 (1 -
NRMSE)`` (MATLAB ``compare``).

Imports casadi, numpy, scipy; no matplotlib, no file parsing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace as dc_replace
from pathlib import Path
from types import MappingProxyType

import casadi as ca
import numpy as np

from ..errors import ParameterError, RigDataError, SolverError, ThsaError
from ..model import build_plant
from ..model.plant import Plant
from ..model.params import ParameterSet, default_parameters
from .replay import (
    COMPARED_OUTPUT, channel_fit, check_run_model, current_driven_map, mech_inputs, replay_closed_loop, run_design,
    sample_periods,
)
from ..data.rigdata import RigRun, motor_speed_from
from .kinematics import run_kinematics
from .segment_states import drivetrain_segment_guess

__all__ = ["IdentificationSettings", "ParameterEstimate", "IdentificationResult", "Identifier", "estimate_noise"]

#: Channels the mechanics are fitted on (RigRun signals, compared with the plant
#: outputs of :data:`~thsa_control.fit.replay.COMPARED_OUTPUT`: the LVDT with the surface position).
MECH_CHANNELS = ("motor_speed", "nut_position", "screw_speed")
#: A parameter whose standard error exceeds this fraction of its value is not determined by the data.
NOT_DETERMINED_REL_STDERR = 0.5
#: Above this |correlation| two parameters are collinear in the data: only their combination is determined.
COLLINEAR_CORRELATION = 0.999
_FREE_STATE_KINDS = ("speed", "velocity", "position")


@dataclass(frozen=True)
class IdentificationSettings:
    """How :class:`Identifier` fits.

    Parameters
    ----------
    method : {"multiple_shooting"}
        Current-driven mechanics, segments with free initial states.
    segment_duration : float
        Segment length [s]; short enough that the open-loop mechanics do not
        run away from the data (0.25 s: the no-back's Stribeck instability
        grows about 3x per second).
    substeps : int
        Plant steps per sample period (current interpolated linearly).
    channels : tuple of str or None
        Fitted channels among ``motor_speed``, ``nut_position``,
        ``screw_speed``; None: every one the runs measure.
    noise : mapping channel -> float, optional
        Noise RMS per channel [SI] used as the weights; default estimated from
        each run's second differences (:func:`estimate_noise`).
    max_nfev : int
        Limit of residual evaluations; 0: no optimisation, only the
        statistics at the initial values (a local identifiability analysis).
    tolerance : float
        ``ftol``, ``xtol`` and ``gtol`` of the optimiser.
    global_stage : bool
        Run differential evolution before the local fit.
    global_maxiter, global_popsize : int
        Differential evolution budget.
    global_span : float
        Search range of the global stage where a bound is infinite:
        ``init / span .. init * span``.
    seed : int
        Seed of the global stage.
    correlation_threshold : float
        ``|rho|`` above which a pair is flagged.
    time_budget : float or None
        Wall-time limit of the optimisation [s]; when it (or ``max_nfev``)
        is reached the best point so far is returned, flagged not converged.
    prior_relative_sd : float or None
        Regularisation: each free parameter gets a Gaussian prior centred on
        its value in the parameter file with standard deviation
        ``prior_relative_sd * |value|`` (or a hundredth of its bound range
        for a value at 0), added to the residuals as ``(theta - theta0) / sd``.
        None: no prior.  It keeps weakly identified parameters at their
        documented values instead of letting them stand in for a missing
        effect (a self-locking screw for a missing no-back).
    no_prior : tuple of str
        Free parameters without a prior (an effect being tried, whose file
        value is only a seed).
    priors : mapping name -> (mean, sd), optional
        Explicit Gaussian priors of these free parameters (SI), replacing the
        ``prior_relative_sd`` rule for them (the tracer's base corrections:
        centred at 0 with a standard deviation of half their plausible size).
    holdout_every : int
        0: every segment is fitted.  k >= 2: every k-th segment is held out of
        the parameter fit; its initial state is fitted afterwards at the
        identified parameters and its error reported separately (validation on
        data the parameter fit did not see).
    """

    method: str = "multiple_shooting"
    segment_duration: float = 0.25
    substeps: int = 1
    channels: tuple[str, ...] | None = None
    noise: Mapping[str, float] | None = None
    max_nfev: int = 100
    tolerance: float = 1e-10
    global_stage: bool = False
    global_maxiter: int = 20
    global_popsize: int = 8
    global_span: float = 10.0
    seed: int = 0
    correlation_threshold: float = 0.95
    time_budget: float | None = None
    prior_relative_sd: float | None = None
    no_prior: tuple[str, ...] = ()
    holdout_every: int = 0
    priors: Mapping[str, tuple[float, float]] | None = None

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        if self.method != "multiple_shooting":
            raise ValueError(f"IdentificationSettings.method = {self.method!r}: only 'multiple_shooting' is implemented")
        if not (self.segment_duration > 0 and math.isfinite(self.segment_duration)):
            raise ValueError(f"IdentificationSettings.segment_duration = {self.segment_duration!r} must be positive")
        if not (isinstance(self.substeps, int) and self.substeps >= 1):
            raise ValueError(f"IdentificationSettings.substeps = {self.substeps!r} must be an integer >= 1")
        if self.channels is not None:
            bad = [c for c in self.channels if c not in MECH_CHANNELS]
            if bad or not self.channels:
                raise ValueError(f"IdentificationSettings.channels: {bad or 'empty'}; choose from {MECH_CHANNELS}")
        if not (isinstance(self.max_nfev, int) and self.max_nfev >= 0):
            raise ValueError(f"IdentificationSettings.max_nfev = {self.max_nfev!r} must be an integer >= 0")
        if not (0 < self.correlation_threshold < 1):
            raise ValueError(f"IdentificationSettings.correlation_threshold = {self.correlation_threshold!r} "
                             "must lie in (0, 1)")
        if self.time_budget is not None and not (self.time_budget > 0 and math.isfinite(self.time_budget)):
            raise ValueError(f"IdentificationSettings.time_budget = {self.time_budget!r} must be a positive number [s]")
        if self.prior_relative_sd is not None and not (self.prior_relative_sd > 0
                                                       and math.isfinite(self.prior_relative_sd)):
            raise ValueError(f"IdentificationSettings.prior_relative_sd = {self.prior_relative_sd!r} must be positive")
        if not (isinstance(self.holdout_every, int) and (self.holdout_every == 0 or self.holdout_every >= 2)):
            raise ValueError(f"IdentificationSettings.holdout_every = {self.holdout_every!r} must be 0 or >= 2")
        if not self.global_span > 1:
            raise ValueError(f"IdentificationSettings.global_span = {self.global_span!r} must be > 1")


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
                 *([f"    # priors           = " + ", ".join(f"{n} ~ N({m:.4g}, {sd:.3g})"
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


def estimate_noise(y: np.ndarray) -> float:
    """Noise RMS of a sampled signal from its second differences (robust, MAD based).

    For white noise of RMS ``s`` on a smooth signal, ``diff(y, 2)`` has RMS
    ``s sqrt(6)``.  Returns a floor of ``1e-9 * max|y|`` (and 1e-12) for
    noise-free data.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.linspace(0, 1, 5001)
    >>> round(estimate_noise(np.sin(2 * np.pi * t) + 0.01 * rng.standard_normal(t.size)), 3)
    0.01
    """
    y = np.asarray(y, float)
    d = np.diff(y[np.isfinite(y)], 2)
    if d.size < 3:
        return 1.0
    mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    floor = max(1e-9 * float(np.max(np.abs(y[np.isfinite(y)]))), 1e-12)
    return max(mad / math.sqrt(6.0), floor)


# ----------------------------------------------------------------------------- problem per run
class RunProblem:
    """Residuals and Jacobian of one run: casadi map over segments of the current-driven map."""

    def __init__(self, run: RigRun, plant: Plant, mech: ca.Function, params: ParameterSet, free: Sequence[str],
                 settings: IdentificationSettings):
        self.run = run
        self.plant = plant
        t = np.asarray(run.time, float)
        self.time = t
        n = t.size
        channels = settings.channels or MECH_CHANNELS
        self.channels = tuple(c for c in channels if c in run.source_columns)
        if not self.channels:
            raise RigDataError(str(run.csv_path), [(None, None, f"no fitted channel measured; need one of {channels}")])
        dt = float(np.median(np.diff(t)))
        L = max(2, int(round(settings.segment_duration / dt)))
        M = int(math.ceil(n / L))
        self.L, self.M = L, M
        npad = L * M - n
        V = mech_inputs(run)
        H = sample_periods(run)
        V = np.hstack([V, np.repeat(V[:, -1:], npad, axis=1)])
        H = np.r_[H, np.repeat(H[-1], npad)]
        # measured data and noise weights
        Ymeas = np.vstack([np.asarray(run.signals[c], float) for c in self.channels])
        Ymeas = np.hstack([Ymeas, np.full((len(self.channels), npad), np.nan)])
        self.Ymeas = Ymeas
        noise = dict(settings.noise or {})
        self.sigma0 = np.array([float(noise[c]) if c in noise else estimate_noise(run.signals[c])
                                for c in self.channels])
        self.mask = np.isfinite(Ymeas)
        k_hold = settings.holdout_every
        seg_of = np.arange(L * M) // L
        self.holdout_samples = (seg_of % k_hold == k_hold - 1) if k_hold and M >= k_hold else np.zeros(L * M, bool)
        # channel-major residual rows: weight 0 on held-out samples in the parameter fit
        self.train_weight = np.tile((~self.holdout_samples).astype(float), len(self.channels))
        # states: which are free per segment, initial guesses
        states = plant.states
        self.free_states = [i for i, s in enumerate(states) if s.kind in _FREE_STATE_KINDS
                            and not (s.name == "nut_position" and "nut_position" not in run.source_columns)]
        self.x_guess = self._initial_states(params, L, M)
        self._track_custom_states(mech, params, V, H, L, M)
        # casadi: one segment = mapaccum of the map; all segments = map
        n_p = len(plant.parameters)
        y_idx = [plant.index("output", COMPARED_OUTPUT[c]) for c in self.channels]
        x = ca.SX.sym("x", len(states))
        v = ca.SX.sym("v", V.shape[0])
        p = ca.SX.sym("p", n_p)
        h = ca.SX.sym("h")
        xn, y = mech(x, v, p, h)
        step = ca.Function("step_sel", [x, v, p, h], [xn, y[y_idx]])
        seg = step.mapaccum("segment", L)
        xs0 = ca.MX.sym("x0", len(states))
        Vs = ca.MX.sym("V", V.shape[0], L)
        ps = ca.MX.sym("p", n_p)
        Hs = ca.MX.sym("H", 1, L)
        _, Yseg = seg(xs0, Vs, ps, Hs)
        segY = ca.Function("segY", [xs0, Vs, ps, Hs], [Yseg])
        allY = segY.map("segments", "serial", M, [2], [])
        self.V, self.H = V, H
        self.n_p = n_p
        # decision variables: free parameters (scaled deltas) and free segment states
        self.free_idx = [plant.parameters.index(nm) for nm in free]
        d_theta = ca.MX.sym("dtheta", len(free))
        S = ca.MX.sym("S", len(self.free_states), M)
        self.p0 = plant.p_vector(params)
        self.scale = None  # set by the Identifier
        P = ca.MX.sym("pbase", n_p)
        scale = ca.MX.sym("scale", len(free))
        pv = P
        for k, j in enumerate(self.free_idx):
            pv = pv + ca.DM.eye(n_p)[:, j] * (d_theta[k] * scale[k])
        X0 = ca.MX(ca.DM(self.x_guess))
        rows = []
        k_free = 0
        pawl = {"pawl_clearance_comp", "pawl_clearance_tens"}
        for i in range(len(states)):
            if i in self.free_states:
                rows.append(S[k_free, :])
                k_free += 1
            elif states[i].name in pawl and M > 0:
                # the run starts with the ratchets where they stopped: the clearance of the first segment is a
                # parameter (noback.pawl_initial_clearance, a fraction of the pitch); later segments take it
                # from the model's map driven by the measured speed at the initial parameters (no gradient:
                # a pitch is profiled, thsa_control.fit.profile, each value with its own segment clearances)
                ip, ic = plant.parameters.index("noback.pawl_pitch"), plant.parameters.index("noback.pawl_initial_clearance")
                first = pv[ic] * pv[ip]
                rows.append(ca.horzcat(first, X0[i, 1:]) if M > 1 else first)
            else:
                rows.append(X0[i, :])
        X0full = ca.vertcat(*rows)
        Y = allY(X0full, ca.DM(V), pv, ca.DM(H).T)  # (ny, L*M)
        W = ca.DM(np.where(self.mask, 1.0, 0.0))
        Ymeas0 = ca.DM(np.nan_to_num(Ymeas))
        sig = ca.MX.sym("sigma", len(self.channels))
        r = (Ymeas0 - Y) * W / ca.repmat(sig, 1, L * M)
        r = ca.vec(r.T)  # channel-major: all samples of channel 0, then 1 ...
        dec = ca.vertcat(d_theta, ca.vec(S))
        self.n_dec_states = len(self.free_states) * M
        self.f_res = ca.Function("res", [dec, P, scale, sig], [r])
        self.f_jac = ca.Function("res_jac", [dec, P, scale, sig], [r, ca.jacobian(r, dec)])
        self.f_pred = ca.Function("pred", [dec, P, scale], [Y])
        # every state (at each sample's start) and every output of the same segment predictions, for the
        # segmented open-loop residual (thsa_control.fit.segmented); not differentiated
        step_all = ca.Function("step_all", [x, v, p, h], [xn, y])
        Xs, Ys = step_all.mapaccum("segment_all", L)(xs0, Vs, ps, Hs)
        seg_all = ca.Function("seg_all", [xs0, Vs, ps, Hs], [ca.horzcat(xs0, Xs[:, :L - 1]), Ys])
        Xall, Yall = seg_all.map("segments_all", "serial", M, [2], [])(X0full, ca.DM(V), pv, ca.DM(H).T)
        self.f_pred_all = ca.Function("pred_all", [dec, P, scale], [Xall, Yall])

    def _initial_states(self, params: ParameterSet, L: int, M: int) -> np.ndarray:
        """Segment initial states: measured where measured, else from a closed-loop replay or rest."""
        run, plant = self.run, self.plant
        starts = np.arange(M) * L
        n = self.time.size
        cl = None
        if run.controller is not None:
            try:
                cl = replay_closed_loop(run, plant, params, design=run_design(run))
            except ThsaError:
                cl = None
        X = np.zeros((len(plant.states), M))
        for m, k in enumerate(starts):
            k = min(k, n - 1)
            f0 = float(run.signals["load_force"][k])
            nut = self._measured_at("nut_position", k)
            x_rest = plant.initial_state(params, load_force=f0, nut_position=nut if nut is not None else 0.0)
            for i, s in enumerate(plant.states):
                if cl is not None and s.name in cl.simulated:
                    X[i, m] = cl.simulated[s.name][k]
                else:
                    X[i, m] = x_rest[i]
            w = motor_speed_from(lambda c: self._measured_at(c, k), run.gear_ratio)
            if w is not None:
                X[plant.index("state", "motor_speed"), m] = w
            if nut is not None:  # the LVDT reads the surface; the nut sits the load-path deflection ahead
                i_nut = plant.index("state", "nut_position")
                if "surface_position" in plant.state_names:
                    i_srf = plant.index("state", "surface_position")
                    deflection = X[i_nut, m] - X[i_srf, m]
                    X[i_srf, m] = nut
                    X[i_nut, m] = nut + deflection
                else:
                    X[i_nut, m] = nut
        # a compliant drive train: rotors from the motor sensor, gear output from the screw sensor, twist quasi-static
        drivetrain_segment_guess(plant, params, run, starts, X, self._measured_at)
        return X

    def _track_custom_states(self, mech: ca.Function, params: ParameterSet, V: np.ndarray, H: np.ndarray, L: int,
                             M: int) -> None:
        """Custom states (pawl clearances) at the segment starts from the model's own map driven by the
        measured speeds at ``params`` (:func:`~thsa_control.fit.segment_states.custom_state_track`), so that
        they are consistent with the parameters being fitted; unchanged when the run measures no speed."""
        from .segment_states import custom_state_indices, custom_state_track, measured_state_matrix

        run, plant = self.run, self.plant
        idx = custom_state_indices(plant)
        Xm = measured_state_matrix(run, plant, params) if idx else None
        if Xm is None:
            return
        n = self.time.size
        Xm[idx, 0] = self.x_guess[idx, 0]
        track = custom_state_track(plant, mech, Xm, V[:, :n], H[:n], plant.p_vector(params))
        starts = np.minimum(np.arange(M) * L, n - 1)
        self.x_guess[idx, :] = track[:, starts]

    def _measured_at(self, name: str, k: int) -> float | None:
        if name not in self.run.source_columns:
            return None
        y = np.asarray(self.run.signals[name], float)
        window = y[max(0, k - 2):k + 3]
        window = window[np.isfinite(window)]
        return float(np.median(window)) if window.size else None

    def initial_decision(self) -> np.ndarray:
        return self.x_guess[self.free_states, :].ravel(order="F")


def _collinearity_safe_inverse(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
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


class Identifier:
    """Fit free parameters of a model to rig runs (multi-experiment).

    The constructor only stores its configuration (scikit-learn style); the
    work is in :meth:`fit`.

    Parameters
    ----------
    level : {"A", "B", "C", "D"} or None
        Model level.
    params : ParameterSet, optional
        Initial values and bounds (default: the embedded actuator).
    free : sequence of str
        Parameters to fit (others are held).
    effects : iterable of str
        Effects added to the level.
    settings : IdentificationSettings, optional
    bounds : mapping name -> (lo, hi), optional
        Search bounds of this fit, replacing the parameter file's ``min`` /
        ``max`` (SI).  They must contain the initial value and lie inside the
        parameter's physical ``valid`` interval (else :class:`ParameterError`
        naming the parameter).

    Examples
    --------
    >>> ident = Identifier("B", free=["gear.viscous_friction", "noback.mu_coulomb_pos"])
    >>> ident.free
    ('gear.viscous_friction', 'noback.mu_coulomb_pos')
    """

    def __init__(self, level: str | None = "A", params: ParameterSet | None = None, free: Sequence[str] = (), *,
                 effects: Iterable[str] = (), settings: IdentificationSettings | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None):
        self.level = level
        self.params = params if params is not None else default_parameters()
        self.bounds = dict(bounds or {})
        self.free = tuple(free)
        self.effects = tuple(effects)
        self.settings = settings or IdentificationSettings()

    def _check(self, plant: Plant) -> None:
        self.settings.validate()
        if not self.free:
            raise ParameterError("<free>", "no free parameters: name at least one parameter to identify")
        seen = set()
        xs, us, ps, hs = (ca.SX.sym(k, plant.step.size1_in(i)) for i, k in enumerate(("x", "u", "p", "h")))
        used = ca.which_depends(ca.vertcat(*plant.step(xs, us, ps, hs)), ps, 1, False)
        # initial values of the states the segments do not free (pawl clearances) act through init
        custom = [i for i, s in enumerate(plant.states) if s.kind not in _FREE_STATE_KINDS and s.kind != "lag"]
        if custom:
            x0 = plant.init(ca.SX.sym("n"), ca.SX.sym("f"), ps)
            used_init = ca.which_depends(ca.vertcat(*[x0[i] for i in custom]), ps, 1, False)
            used = [a or b for a, b in zip(used, used_init)]
        for n in self.free:
            if n not in self.params:
                raise ParameterError(n, "unknown; it cannot be identified (see default_actuator.toml for names)")
            if n not in plant.parameters or not used[plant.parameters.index(n)]:
                raise ParameterError(n, f"not used by the model (effects: {', '.join(plant.effects) or 'level A'})")
            if n in seen:
                raise ParameterError(n, "listed twice in the free parameters")
            seen.add(n)

    def _with_search_bounds(self) -> ParameterSet:
        """``self.params`` with this fit's search bounds (``bounds``), checked against the physical ones."""
        new = {}
        for n, b in self.bounds.items():
            if n not in self.params:
                raise ParameterError(n, "unknown; cannot set its search bounds")
            if not (isinstance(b, (tuple, list)) and len(b) == 2):
                raise ParameterError(n, f"search bounds {b!r} must be a pair (lo, hi)")
            par = self.params[n]
            lo, hi = float(b[0]), float(b[1])
            if not lo <= par.value <= hi:
                raise ParameterError(n, f"search bounds [{lo:g}, {hi:g}] {par.unit} do not contain the initial "
                                        f"value {par.value:g}")
            new[n] = dc_replace(par, min=lo, max=hi)  # the Parameter checks them against its physical bounds
        return self.params.replace_parameters(new) if new else self.params

    def _scales(self) -> np.ndarray:
        out = []
        for n in self.free:
            par = self.params[n]
            if par.value != 0:
                out.append(abs(par.value))
            elif math.isfinite(par.max - par.min):
                out.append(0.01 * (par.max - par.min))
            else:
                out.append(1.0)
        return np.array(out)

    def _priors(self, scale: np.ndarray) -> dict[str, tuple[float, float]]:
        r = self.settings.prior_relative_sd
        explicit = {n: (float(m), float(sd)) for n, (m, sd) in (self.settings.priors or {}).items()
                    if n in self.free and sd > 0}
        if r is None:
            return explicit
        return {**{n: (self.params[n].value, float(r * s)) for n, s in zip(self.free, scale)
                   if n not in self.settings.no_prior}, **explicit}

    def fit(self, runs: RigRun | Sequence[RigRun], *, progress=None) -> IdentificationResult:
        """Fit the free parameters to ``runs`` together.

        Parameters
        ----------
        runs : RigRun or sequence of RigRun
            Each needs ``motor_current`` and at least one of ``motor_speed``,
            ``nut_position``, ``screw_speed``.
        progress : callable, optional
            ``progress(nfev, cost, elapsed_s)`` after each residual evaluation
            of the optimiser (the command line prints it).

        Returns
        -------
        IdentificationResult

        Raises
        ------
        ParameterError
            No free parameter, or an unknown one (named).
        RigDataError
            A run lacks the current or every fitted channel.
        SolverError
            The optimiser failed (improper input, its status named) or the
            model diverged at the initial values.  Hitting ``max_nfev`` or
            ``time_budget`` is not an error: the best point is returned with
            ``converged = False``.
        """
        from scipy.optimize import least_squares

        t_start = time.perf_counter()
        runs = [runs] if isinstance(runs, RigRun) else list(runs)
        if not runs:
            raise RigDataError("<runs>", [(None, None, "no run given")])
        self.params = self._with_search_bounds()
        runs = [run_kinematics(r, self.params) for r in runs]  # a run stating other kinematics is refused
        plant = build_plant(self.level, self.effects, params=self.params)
        self._check(plant)
        st = self.settings
        mech = current_driven_map(plant, st.substeps)
        from .replay import check_run_model

        run_warnings = tuple(w for r in runs for w in check_run_model(r, plant, mode="open_loop"))
        problems = [RunProblem(r, plant, mech, self.params, self.free, st) for r in runs]
        nf = len(self.free)
        scale = self._scales()
        priors = self._priors(scale)
        # prior rows (scaled decision units); a parameter without a prior gets a zero row
        prior_w = np.array([scale[k] / priors[n][1] if n in priors else 0.0 for k, n in enumerate(self.free)]) \
            if priors else None
        # prior centres in decision units (the initial value unless an explicit prior names another)
        prior_z0 = np.array([(priors[n][0] - self.params[n].value) / scale[k] if n in priors else 0.0
                             for k, n in enumerate(self.free)]) if priors else None
        p0 = plant.p_vector(self.params)
        box = [self.params[n].search_interval() for n in self.free]
        lo = np.array([(b[0] - self.params[n].value) / s for (n, s), b in zip(zip(self.free, scale), box)])
        hi = np.array([(b[1] - self.params[n].value) / s for (n, s), b in zip(zip(self.free, scale), box)])
        sizes = [pb.n_dec_states for pb in problems]
        offsets = np.cumsum([nf] + sizes)
        sigmas = [pb.sigma0 for pb in problems]
        counters = {"nfev": 0, "njev": 0}
        # fit weights: held-out segments do not inform the parameters
        fit_w = [pb.train_weight for pb in problems]
        best = {"cost": math.inf, "z": None}
        tracking = {"on": False}

        class _Budget(Exception):
            pass

        def split(z):
            return [np.r_[z[:nf], z[offsets[i]:offsets[i] + sizes[i]]] for i in range(len(problems))]

        def residuals(z, weights=None):
            counters["nfev"] += 1
            weights = fit_w if weights is None else weights
            parts = [np.asarray(pb.f_res(d, p0, scale, sg)).ravel() * w
                     for pb, d, sg, w in zip(problems, split(z), sigmas, weights)]
            if prior_w is not None:
                parts.append((z[:nf] - prior_z0) * prior_w)
            r = np.concatenate(parts)
            r = np.where(np.isfinite(r), r, 1e10)
            if tracking["on"]:
                cost = 0.5 * float(r @ r)
                if cost < best["cost"]:
                    best["cost"], best["z"] = cost, np.array(z, float)
                elapsed = time.perf_counter() - t_start
                if progress is not None:
                    progress(counters["nfev"], best["cost"], elapsed)
                if st.time_budget is not None and elapsed > st.time_budget:
                    raise _Budget()
            return r

        def jacobian(z, weights=None):
            counters["njev"] += 1
            weights = fit_w if weights is None else weights
            import scipy.sparse as sps

            blocks = []
            for i, (pb, d, sg) in enumerate(zip(problems, split(z), sigmas)):
                _, Ji = pb.f_jac(d, p0, scale, sg)
                Ji = sps.diags(weights[i]) @ sps.csc_matrix(Ji.sparse())
                m = Ji.shape[0]
                left = offsets[i] - nf
                right = z.size - offsets[i] - sizes[i]
                parts = [Ji[:, :nf]] + ([sps.csc_matrix((m, left))] if left else []) + [Ji[:, nf:]] \
                    + ([sps.csc_matrix((m, right))] if right else [])
                blocks.append(sps.hstack(parts, format="csr"))
            if prior_w is not None:
                blocks.append(sps.hstack([sps.diags(prior_w), sps.csc_matrix((nf, z.size - nf))], format="csr")
                              if z.size > nf else sps.csr_matrix(np.diag(prior_w)))
            J = sps.vstack(blocks, format="csr")
            J.data = np.nan_to_num(J.data)
            if tracking["on"] and st.time_budget is not None and time.perf_counter() - t_start > st.time_budget:
                raise _Budget()
            return J if sparse_jac else J.toarray()

        z0 = np.concatenate([np.zeros(nf)] + [pb.initial_decision() for pb in problems])
        # many segment states: the Jacobian is block-sparse; an iterative trust-region solver (lsmr) on the
        # sparse matrix instead of a dense SVD (a 10 s, 1 kHz run in 50 ms segments has 600 states)
        sparse_jac = z0.size > 150
        tr = {"tr_solver": "lsmr"} if sparse_jac else {}
        r_init = residuals(z0)
        if not np.all(np.isfinite(r_init)):
            raise SolverError("identification", "the model diverges at the initial parameter values (non-finite "
                              "residuals); shorten segment_duration or check the runs")

        # -- optional global stage: parameters only, segment states at their measured values
        global_info: dict = {}
        if st.global_stage and st.max_nfev > 0:
            from scipy.optimize import differential_evolution

            glo, ghi = [], []
            for k, n in enumerate(self.free):
                par = self.params[n]
                a = par.min if math.isfinite(par.min) else par.value / st.global_span if par.value > 0 else par.value - st.global_span * scale[k]
                b = par.max if math.isfinite(par.max) else par.value * st.global_span if par.value > 0 else par.value + st.global_span * scale[k]
                if par.value > 0:
                    a, b = max(a, par.value / st.global_span), min(b, par.value * st.global_span)
                glo.append((a - par.value) / scale[k])
                ghi.append((b - par.value) / scale[k])
            zs = z0[nf:]

            def cost(dtheta):
                r = residuals(np.r_[dtheta, zs])
                return float(r @ r)

            de = differential_evolution(cost, list(zip(glo, ghi)), maxiter=st.global_maxiter, popsize=st.global_popsize,
                                        seed=st.seed, polish=False, tol=1e-8, updating="deferred")
            global_info = {"nfev": int(de.nfev), "fun": float(de.fun), "message": str(de.message),
                           "x": {n: float(self.params[n].value + scale[k] * de.x[k]) for k, n in enumerate(self.free)}}
            z0 = np.r_[de.x, zs]

        # -- fit the segment states alone at the initial parameters (for "before" statistics)
        ones_w = [np.ones_like(w) for w in fit_w]

        def res_states(zs, dtheta):
            return residuals(np.r_[dtheta, zs], ones_w)

        def jac_states(zs, dtheta):
            return jacobian(np.r_[dtheta, zs], ones_w)[:, nf:]

        z_before = z0.copy()
        if st.max_nfev > 0:
            pre = least_squares(res_states, z0[nf:], jac=jac_states, args=(np.zeros(nf),), method="trf",
                                x_scale="jac", max_nfev=6, ftol=1e-8, xtol=1e-8, gtol=1e-8, **tr)
            z_before = np.r_[np.zeros(nf), pre.x]
            if global_info:
                z0 = np.r_[z0[:nf], pre.x]
            else:
                z0 = z_before.copy()

        status, success, converged = "not optimised (max_nfev = 0): statistics at the initial values", True, True
        z = z0
        if st.max_nfev > 0:
            lb = np.r_[lo, np.full(z0.size - nf, -np.inf)]
            ub = np.r_[hi, np.full(z0.size - nf, np.inf)]
            z0c = np.clip(z0, lb, ub)
            tracking["on"] = True
            try:
                sol = least_squares(residuals, z0c, jac=jacobian, bounds=(lb, ub), method="trf", x_scale="jac",
                                    max_nfev=st.max_nfev, ftol=st.tolerance, xtol=st.tolerance, gtol=st.tolerance, **tr)
            except _Budget:
                sol = None
            tracking["on"] = False
            if sol is None:
                status = f"not converged: time budget {st.time_budget:g} s reached; best point of {counters['nfev']} evaluations"
                success, converged, z = False, False, best["z"]
            elif sol.status == 0:
                status = (f"not converged: status 0: maximum number of function evaluations ({st.max_nfev}) exceeded; "
                          "best point so far")
                success, converged = False, False
                z = best["z"] if best["z"] is not None and best["cost"] < float(sol.cost) else sol.x
            elif sol.status < 0:
                raise SolverError("scipy least_squares (trf)", f"status {sol.status}: improper input parameters",
                                  {"nfev": sol.nfev, "cost": float(sol.cost)})
            else:
                status = f"status {sol.status}: {sol.message}"
                success = bool(sol.success)
                z = sol.x

        # -- held-out segments: their initial states fitted at the identified parameters (a few steps)
        if any(pb.holdout_samples.any() for pb in problems):
            hold_w = [1.0 - w for w in fit_w]
            n_rows = sum(w.size for w in hold_w)
            # decision columns of the held-out segments' states
            cols = np.concatenate([offsets[i] + np.flatnonzero(np.repeat(
                (np.arange(pb.M) % st.holdout_every == st.holdout_every - 1), len(pb.free_states)))
                for i, pb in enumerate(problems)]) if st.holdout_every else np.array([], int)

            def _zh(zh):
                zz = z.copy()
                zz[cols] = zh
                return zz

            sol_h = least_squares(lambda zh: residuals(_zh(zh), hold_w)[:n_rows], z[cols],
                                  jac=lambda zh: jacobian(_zh(zh), hold_w)[:n_rows][:, cols],
                                  method="trf", x_scale="jac", max_nfev=30, ftol=1e-10, xtol=1e-10, gtol=1e-10, **tr)
            z = _zh(sol_h.x)

        # -- statistics
        parts_z = split(z)
        r_runs = [np.asarray(pb.f_res(d, p0, scale, np.ones(len(pb.channels)))).ravel()
                  for pb, d in zip(problems, parts_z)]  # unweighted residuals, channel-major
        noise_after, new_sig = {}, []
        for pb, r in zip(problems, r_runs):
            R = r.reshape(len(pb.channels), -1)
            s = []
            for c, row, msk in zip(pb.channels, R, pb.mask):
                rms = float(np.sqrt(np.mean(row[msk] ** 2))) if msk.any() else 1.0
                s.append(max(rms, 1e-300))
            new_sig.append(np.array(s))
            noise_after[pb.run.name] = {c: v for c, v in zip(pb.channels, s)}
        rw = residuals(z)  # weighted with the noise levels the fit used (and the prior)
        chisqr = float(rw @ rw)
        n_data = int(sum(int((pb.mask & ~pb.holdout_samples[None, :]).sum()) for pb in problems))
        n_varys = int(z.size)
        dof = max(n_data - n_varys, 1)
        sigmas = new_sig  # the covariance uses the residual RMS of each channel (lmfit: scale_covar)
        J = jacobian(z)
        JTJ = J.T @ J
        cov_all, unresolved = _collinearity_safe_inverse(JTJ.toarray() if hasattr(JTJ, "toarray") else JTJ)
        cov_d = cov_all[:nf, :nf] * (n_data / dof)
        cov = cov_d * np.outer(scale, scale)
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        with np.errstate(invalid="ignore", divide="ignore"):
            corr = cov / np.outer(sd, sd)
        corr[~np.isfinite(corr)] = np.nan
        np.fill_diagonal(corr, 1.0)
        values = p0[[plant.parameters.index(n) for n in self.free]] + scale * z[:nf]
        estimates = {}
        for k, n in enumerate(self.free):
            par = self.params[n]
            tol_b = 1e-6 * max(scale[k], abs(par.max - par.min) if math.isfinite(par.max - par.min) else 0.0)
            at_bound = "min" if values[k] - par.min <= tol_b else ("max" if par.max - values[k] <= tol_b else None)
            stderr = float(sd[k]) if not unresolved[k] else math.inf
            at_init = bool(st.max_nfev > 0 and abs(values[k] - par.value) <= 1e-6 * scale[k])
            estimates[n] = ParameterEstimate(n, par.unit, float(values[k]), stderr, par.value, par.min, par.max,
                                             at_bound, at_init)
        high = []
        for i in range(nf):
            for j in range(i + 1, nf):
                rho = corr[i, j]
                if np.isfinite(rho) and abs(rho) > st.correlation_threshold:
                    high.append((self.free[i], self.free[j], float(rho)))
        high.sort(key=lambda p: -abs(p[2]))

        fits, fits0, preds, hold = {}, {}, {}, {}
        zb_parts = split(z_before)
        for pb, d, db in zip(problems, parts_z, zb_parts):
            Y = np.asarray(pb.f_pred(d, p0, scale))
            Y0 = np.asarray(pb.f_pred(db, p0, scale))
            n = pb.time.size
            name = pb.run.name
            tr = ~pb.holdout_samples[:n]
            fits[name] = MappingProxyType({c: channel_fit(c, pb.Ymeas[i, :n][tr], Y[i, :n][tr])
                                           for i, c in enumerate(pb.channels)})
            if pb.holdout_samples.any():
                ho = pb.holdout_samples[:n]
                hold[name] = MappingProxyType({c: channel_fit(c, pb.Ymeas[i, :n][ho], Y[i, :n][ho])
                                               for i, c in enumerate(pb.channels)})
            fits0[name] = MappingProxyType({c: channel_fit(c, pb.Ymeas[i, :n], Y0[i, :n]) for i, c in enumerate(pb.channels)})
            preds[name] = {"time": pb.time, "measured": {c: pb.Ymeas[i, :n] for i, c in enumerate(pb.channels)},
                           "simulated": {c: Y[i, :n] for i, c in enumerate(pb.channels)},
                           "initial": {c: Y0[i, :n] for i, c in enumerate(pb.channels)},
                           "segment_starts": pb.time[np.arange(pb.M) * pb.L],
                           "holdout": pb.holdout_samples[:n].copy()}
        n_log = max(n_data, 1)
        chi_n = max(chisqr, 1e-300) / n_log
        return IdentificationResult(
            method=st.method, effects=plant.effects, runs=tuple(r.name for r in runs), params=self.params,
            estimates=MappingProxyType(estimates), correlation=corr, high_correlations=tuple(high),
            n_data=n_data, n_free=nf, n_varys=n_varys, chisqr=chisqr, redchi=chisqr / dof,
            aic=n_log * math.log(chi_n) + 2 * n_varys, bic=n_log * math.log(chi_n) + math.log(n_log) * n_varys,
            channel_fits=MappingProxyType(fits), initial_channel_fits=MappingProxyType(fits0),
            noise=MappingProxyType(noise_after), success=success, status=status, nfev=counters["nfev"],
            njev=counters["njev"], time_s=time.perf_counter() - t_start, predictions=MappingProxyType(preds),
            settings=st, global_stage=global_info, converged=converged, priors=MappingProxyType(priors),
            holdout_fits=MappingProxyType(hold), warnings=run_warnings)
