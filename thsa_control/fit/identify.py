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

This module owns the settings (:class:`IdentificationSettings`) and the fit
driver (:class:`Identifier`); the result type and its statistics live in
:mod:`thsa_control.fit.identify_result`, the per-run multiple-shooting problem
in :mod:`thsa_control.fit.shooting` (all re-exported here).

Imports casadi, numpy, scipy; no matplotlib, no file parsing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace as dc_replace
from types import MappingProxyType

import casadi as ca
import numpy as np

from ..errors import ParameterError, RigDataError, SolverError
from ..model import build_plant
from ..model.plant import Plant
from ..model.params import ParameterSet, default_parameters
from .replay import channel_fit, current_driven_map
from ..data.rigdata import RigRun
from .kinematics import run_kinematics

from .identify_result import (
    COLLINEAR_CORRELATION, NOT_DETERMINED_REL_STDERR, IdentificationResult, ParameterEstimate,
    collinearity_safe_inverse,
)
from .shooting import FREE_STATE_KINDS, HOLDOUT_LAYOUTS, MECH_CHANNELS, RunProblem, estimate_noise, held_out_segments

__all__ = ["IdentificationSettings", "ParameterEstimate", "IdentificationResult", "Identifier", "estimate_noise",
           "RunProblem", "MECH_CHANNELS", "NOT_DETERMINED_REL_STDERR", "COLLINEAR_CORRELATION"]


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
    quasi_static_starts : bool
        Start each segment with the plant's fast internal modes (``Plant.quasi_static_states``: the surface on a
        compliant load path) at their quasi-static values (the static deflection of the measured load, moving
        with the nut) instead of freeing them: free, they let the fit ring the mode to absorb another channel's
        mismatch, and the channel the mode shows in (the LVDT) gets worse.
    speed_sensors : mapping channel -> interval, optional
        How the speed sensors read, over each run's own declaration
        (:func:`~thsa_control.data.rigformat.speed_sensor_intervals`: the run JSON's ``speed_sensors``, else its
        ``sensors`` text as a reported fallback, else instantaneous): a difference interval [s], ``"sample"``
        or ``"instantaneous"``.  A difference-quotient sensor is compared with the model's angle travelled over
        that interval divided by it (resolved to the plant steps: ``substeps`` per sample).
    holdout_every : int
        0: every segment is fitted.  k >= 2: every k-th segment is held out of
        the parameter fit; its initial state is fitted afterwards at the
        identified parameters and its error reported separately (validation on
        data the parameter fit did not see).
    holdout_layout : {"every_kth", "dithered"}
        Where in each block of ``holdout_every`` the held-out segment lies:
        the last (every k-th), or a place drawn from a fixed seed, so that a
        test profile repeating every multiple of k segments does not hide the
        same phase of each repeat (:func:`~thsa_control.fit.shooting.held_out_segments`).
    compiled : bool
        Evaluate the residuals and their Jacobian with the segment Functions compiled to C (through the
        simulator's verified build cache, one library per model structure, the data as inputs); False, or no
        working C compiler: casadi's interpreter.  The same operations either way (agreement to rounding).
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
    holdout_layout: str = "every_kth"
    quasi_static_starts: bool = False
    speed_sensors: Mapping[str, object] | None = None
    priors: Mapping[str, tuple[float, float]] | None = None
    compiled: bool = True

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
        if self.holdout_layout not in HOLDOUT_LAYOUTS:
            raise ValueError(f"IdentificationSettings.holdout_layout = {self.holdout_layout!r} must be one of "
                             + ", ".join(HOLDOUT_LAYOUTS))
        if not self.global_span > 1:
            raise ValueError(f"IdentificationSettings.global_span = {self.global_span!r} must be > 1")


def segment_information(J, layout, nf: int, offsets, r=None) -> tuple[dict, dict]:
    """Where a fit's parameter values come from, segment by segment: ``(shares, influence)``, each run name ->
    ``(segments, nf)``.

    ``J`` the weighted Jacobian of a multiple-shooting fit at its optimum and ``r`` its weighted residuals (rows:
    each run's channel-major residuals, ``nc x L x M``, then any prior rows; columns: the ``nf`` free parameters,
    then each run's segment start states, ``nfs`` per segment from ``offsets[i]``); ``layout``: per run ``(name,
    nc, L, M, nfs)``.  A segment's start states act on its own rows only, so the information on the parameters
    with every segment's states profiled out is the sum over segments of ``I_m = Jp' Jp`` with ``Jp`` the
    segment's parameter columns projected off its state columns, plus the priors'.

    ``shares[m, k]``: segment ``m``'s part of the information on parameter ``k`` (its diagonal entry of ``I_m`` over
    the total's).  ``influence[m, k]``: how far the estimate of ``k`` moves, in its standard errors (of the
    information), when segment ``m`` is left out, to first order (``C Jp' r_m``, ``C`` the inverse of the total
    information): an estimate that one segment moves by several of its standard errors rests on one event of the
    record, whatever its standard error says (a damping pulled by one stop).  Held-out segments carry neither;
    ``influence`` is empty without ``r``."""
    import scipy.sparse as sps

    if nf == 0:
        return {}, {}
    J = sps.csr_matrix(J) if not sps.issparse(J) else J.tocsr()
    diag, grads = {}, {}
    total = np.zeros((nf, nf))
    row0 = 0
    for i, (name, nc, L, M, nfs) in enumerate(layout):
        N, n = L * M, nc * L
        # the run's rows in segment-major order (segment, channel, sample): a segment's rows are one block
        perm = row0 + ((np.arange(nc)[None, :, None] * N + np.arange(M)[:, None, None] * L
                        + np.arange(L)[None, None, :]).ravel())
        block = J[perm]
        Jp = block[:, :nf].toarray().reshape(M, n, nf)
        Js = np.zeros((M, n, nfs))
        if nfs:  # each segment's start-state columns act on its own rows only: gather them block by block
            st = block[:, int(offsets[i]):int(offsets[i]) + M * nfs].tocoo()
            m, j = np.divmod(st.col, nfs)
            ok = m == st.row // n
            Js[m[ok], st.row[ok] % n, j[ok]] = st.data[ok]
            Jp = Jp - Js @ (np.linalg.pinv(Js) @ Jp)  # the parameter columns projected off the segment's states
        Im = np.einsum("mik,mil->mkl", Jp, Jp)
        total += Im.sum(axis=0)
        diag[name] = np.einsum("mkk->mk", Im).copy()
        if r is not None:
            grads[name] = np.einsum("mik,mi->mk", Jp, np.asarray(r, float)[perm].reshape(M, n))
        row0 += nc * N
    prior = J[row0:, :nf].toarray() if row0 < J.shape[0] else np.zeros((0, nf))
    total += prior.T @ prior
    tot = np.diag(total)
    with np.errstate(invalid="ignore", divide="ignore"):
        shares = {n: np.where(tot > 0, x / tot, 0.0) for n, x in diag.items()}
    if r is None:
        return shares, {}
    C = np.linalg.pinv(total)
    sd = np.sqrt(np.clip(np.diag(C), 1e-300, None))
    return shares, {n: (g @ C.T) / sd for n, g in grads.items()}


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
    states_only : bool
        Fit the segment states only, with ``free`` empty (the model's own
        segment predictions at ``params``); without it an empty ``free`` is a
        :class:`ParameterError`.

    Examples
    --------
    >>> ident = Identifier("B", free=["gear.viscous_friction", "noback.mu_coulomb_pos"])
    >>> ident.free
    ('gear.viscous_friction', 'noback.mu_coulomb_pos')
    """

    def __init__(self, level: str | None = "A", params: ParameterSet | None = None, free: Sequence[str] = (), *,
                 effects: Iterable[str] = (), settings: IdentificationSettings | None = None,
                 bounds: Mapping[str, tuple[float, float]] | None = None, states_only: bool = False):
        self.level = level
        #: no parameter free on purpose: only the segment states are fitted (the model's own segment predictions
        #: at ``params``; the tracer's declared model when the runs determine none of its uncertain parameters)
        self.states_only = bool(states_only)
        self.params = params if params is not None else default_parameters()
        self.bounds = dict(bounds or {})
        self.free = tuple(free)
        self.effects = tuple(effects)
        self.settings = settings or IdentificationSettings()

    def _check(self, plant: Plant) -> None:
        self.settings.validate()
        if not self.free and not self.states_only:
            raise ParameterError("<free>", "no free parameters: name at least one parameter to identify")
        if self.free and self.states_only:
            raise ParameterError("<free>", f"states_only with free parameters {', '.join(self.free)}")
        seen = set()
        xs, us, ps, hs = (ca.SX.sym(k, plant.step.size1_in(i)) for i, k in enumerate(("x", "u", "p", "h")))
        used = ca.which_depends(ca.vertcat(*plant.step(xs, us, ps, hs)), ps, 1, False)
        # initial values of the states the segments do not free (pawl clearances) act through init
        custom = [i for i, s in enumerate(plant.states) if s.kind not in FREE_STATE_KINDS and s.kind != "lag"]
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

    def fit(self, runs: RigRun | Sequence[RigRun], *, progress=None,
            initial_states: Mapping[str, np.ndarray] | None = None,
            custom_states: Mapping[str, np.ndarray] | None = None) -> IdentificationResult:
        """Fit the free parameters to ``runs`` together.

        Parameters
        ----------
        runs : RigRun or sequence of RigRun
            Each needs ``motor_current`` and at least one of ``motor_speed``,
            ``nut_position``, ``screw_speed``.
        progress : callable, optional
            ``progress(nfev, cost, elapsed_s)`` after each residual evaluation
            of the optimiser (the command line prints it).
        initial_states : mapping run name -> ndarray, optional
            Segment start states to start from instead of the measured
            values: an earlier fit's ``segment_states`` of the same runs and
            segment layout (a refit from its optimum: on every segment, or
            going on after the evaluation limit).  A run it does not name
            starts from its measurements; a length that does not match the
            run's layout is an error.
        custom_states : mapping run name -> ndarray, optional
            The custom states (pawl clearances) at the segment starts, which
            are not decision variables but follow the model's map at the
            initial parameters: an earlier fit's ``custom_states``, so that a
            refit from its optimum starts with its predictions exactly.

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
        for pb in problems:
            if custom_states is not None and pb.run.name in custom_states:
                pb.use_custom_starts(custom_states[pb.run.name])
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
            parts = [pb.residuals(d, p0, scale, sg) * w for pb, d, sg, w in zip(problems, split(z), sigmas, weights)]
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

        import scipy.sparse as sps

        def jacobian(z, weights=None):
            counters["njev"] += 1
            weights = fit_w if weights is None else weights
            blocks = []
            for i, (pb, d, sg) in enumerate(zip(problems, split(z), sigmas)):
                Ji = sps.diags(weights[i]) @ pb.jacobian(d, p0, scale, sg)
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

        def jacobian_states(z, weights, prior_rows=True):
            """The Jacobian's segment-state columns (``jacobian(z, weights)[:, nf:]``) without differentiating
            by the parameters: each run's states act on its own rows only (block-diagonal)."""
            blocks = [sps.diags(weights[i]) @ pb.jacobian(d, p0, scale, sg, states_only=True)
                      for i, (pb, d, sg) in enumerate(zip(problems, split(z), sigmas))]
            J = sps.block_diag(blocks, format="csr")
            if prior_rows and prior_w is not None:
                J = sps.vstack([J, sps.csr_matrix((nf, J.shape[1]))], format="csr")
            J.data = np.nan_to_num(J.data)
            return J if sparse_jac else J.toarray()

        starts = []
        for pb in problems:
            x = pb.initial_decision()
            if initial_states is not None and pb.run.name in initial_states:
                given = np.asarray(initial_states[pb.run.name], float).ravel()
                if given.shape != x.shape or not np.all(np.isfinite(given)):
                    raise ValueError(f"initial_states[{pb.run.name!r}]: {given.size} values"
                                     f"{'' if np.all(np.isfinite(given)) else ' (not all finite)'}, the run's "
                                     f"segment layout has {x.size}")
                x = given
            starts.append(x)
        z0 = np.concatenate([np.zeros(nf)] + starts)
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
            counters["njev"] += 1
            return jacobian_states(np.r_[dtheta, zs], ones_w)

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
                held_out_segments(pb.M, st.holdout_every, st.holdout_layout), len(pb.free_states)))
                for i, pb in enumerate(problems)]) if st.holdout_every else np.array([], int)

            def _zh(zh):
                zz = z.copy()
                zz[cols] = zh
                return zz

            # start each held-out state fit from the better of where the parameter fit left those states (they
            # have no weight there, so they can drift along its null directions: a held-out segment of a drive-off
            # phase was found starting at -295 rad/s) and the states fitted at the initial parameters
            def _cost_h(zz):
                r = residuals(zz, hold_w)[:n_rows]
                return float(r @ r)

            if z0.size == z.size and _cost_h(_zh(z0[cols])) < _cost_h(z):
                z = _zh(z0[cols])

            def _jac_hold(zz):
                counters["njev"] += 1
                return jacobian_states(zz, hold_w, prior_rows=False)[:, cols - nf]

            sol_h = least_squares(lambda zh: residuals(_zh(zh), hold_w)[:n_rows], z[cols],
                                  jac=lambda zh: _jac_hold(_zh(zh)),
                                  method="trf", x_scale="jac", max_nfev=30, ftol=1e-10, xtol=1e-10, gtol=1e-10, **tr)
            z = _zh(sol_h.x)

        # -- statistics
        parts_z = split(z)
        r_runs = [pb.residuals(d, p0, scale, np.ones(len(pb.channels)))
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
        nfev, on = counters["nfev"], tracking["on"]
        tracking["on"] = False
        r_cov = residuals(z)  # weighted as the Jacobian (the residual RMS of each channel); not a solver evaluation
        counters["nfev"], tracking["on"] = nfev, on
        seg_info, seg_infl = segment_information(J, [(pb.run.name, pb._nc, pb.L, pb._M, pb._nfs) for pb in problems],
                                                 nf, offsets, r_cov)
        # the segments as clusters: the sandwich over the information's standard error is the root sum of squares
        # of the segments' first-order influences (each in those standard errors)
        seg_ratio = np.sqrt(sum((x ** 2).sum(axis=0) for x in seg_infl.values())) if seg_infl else np.full(nf, np.nan)
        JTJ = J.T @ J
        cov_all, unresolved = collinearity_safe_inverse(JTJ.toarray() if hasattr(JTJ, "toarray") else JTJ)
        cov_d = cov_all[:nf, :nf] * (n_data / dof)
        cov = cov_d * np.outer(scale, scale)
        sd = np.sqrt(np.clip(np.diag(cov), 0, None))
        sd_seg = sd * seg_ratio
        regularising = [k for k, n in enumerate(self.free) if n in priors and n not in (st.priors or {})]
        if regularising:
            # what the runs say (with the explicit priors, external knowledge such as a catalogue spread): the
            # Fisher information without the regularising priors' rows (prior_relative_sd around the initial
            # values, which on a refit are this run's own estimates); a parameter determined only through
            # such a prior on another (a product of two at one operating point) has no information here
            keep = np.ones(J.shape[0], bool)
            keep[J.shape[0] - nf + np.asarray(regularising)] = False
            Jd = J[np.flatnonzero(keep)]
            JTJd = Jd.T @ Jd
            cov_dd, unresolved_d = collinearity_safe_inverse(JTJd.toarray() if hasattr(JTJd, "toarray") else JTJd)
            sd_data = np.sqrt(np.clip(np.diag(cov_dd[:nf, :nf]) * (n_data / dof), 0, None)) * scale
            sd_data = np.where(unresolved_d[:nf], math.inf, sd_data)
        else:
            sd_data = np.where(unresolved[:nf], math.inf, sd)
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
                                             at_bound, at_init, float(sd_data[k]),
                                             float(sd_seg[k]) if at_bound is None and not unresolved[k] else math.nan)
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
            holdout_fits=MappingProxyType(hold), warnings=run_warnings,
            segment_information=MappingProxyType(seg_info), segment_influence=MappingProxyType(seg_infl),
            segment_states=MappingProxyType({pb.run.name: np.array(d[nf:]) for pb, d in zip(problems, parts_z)}),
            custom_states=MappingProxyType({pb.run.name: c for pb in problems
                                            if (c := pb.custom_starts()) is not None}))
