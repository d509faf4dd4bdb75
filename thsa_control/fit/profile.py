"""Profiled parameters: a parameter that acts through a switch is searched, not differentiated.

The no-back's pawl pitch decides *when* a pawl engages (a switch): the
least-squares fit gets no gradient from it, and the chi-square as a function
of the pitch is rugged (the screw travel between stops, modulo the pitch,
decides how far each stop back-drives, so pitches a few per cent apart
predict different depths).  :func:`profile_identify` therefore profiles it:

1. **screen**: on a geometric grid over the parameter's search range, the
   one-step-ahead prediction error of the measured motor speed
   (:func:`~thsa_control.fit.segment_states.one_step_map`: the model's own map
   from the measured state, its custom states carried) is evaluated (on
   every sample, or on the training samples only:
   ``ProfileSettings.screen_samples``); it costs one pass over the run per
   value, no fit;
2. **refine the screen**: a finer grid around its ``local_minima`` best
   local minima;
3. **profile fits**: at each refined minimum the parameter is fixed, the
   segments' custom states are recomputed at that value (the
   :class:`~thsa_control.fit.identify.Identifier` does it from the
   parameter set it is given), the remaining free parameters are identified,
   and the best fit is chosen by its training error (the fit's own objective
   on the samples it was fitted to, :func:`training_chi2`; ``score`` names
   another rule): the held-out samples stay out of the choice, so that a
   caller who judges the result on them (the tracer) judges it out of sample;
   ``refine_fits`` more fits half a fine step either side of the best keep
   the best;
4. further profiled parameters (e.g. the initial clearance fraction) are
   screened one at a time at the best value of the ones before, on a coarse
   grid, and kept only where they matter (their screened chi-square spans
   more than the interval threshold); the profile fits then use the best
   combination.

The interval of each profiled parameter is read off its screened profile:
the contiguous range around the chosen value where the one-step chi-square
stays below its local minimum plus ``chi2(1)`` quantile x the reduced
chi-square of that minimum (the residual variance scaled as lmfit's
``scale_covar``: model error, not only sensor noise, sets the width),
widened to the next screened value each side: a pawl engages at a whole
sample, so the chi-square is a staircase at fine scale and the profile
resolves nothing finer than its grid (0.08 % of the pitch by default).

Imports casadi, numpy, scipy; no plotting, no file parsing.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..data.rigdata import RigRun
from ..errors import ParameterError, SolverError, ThsaError
from ..model import build_plant
from ..model.params import ParameterSet
from .identify import (
    IdentificationResult,
    IdentificationSettings,
    Identifier,
    estimate_noise,
)
from .replay import current_driven_map, mech_inputs, sample_periods
from .segment_states import (
    custom_state_indices,
    measured_speed,
    measured_state_matrix,
    one_step_loop,
    one_step_map,
)
from .shooting import segment_layout

__all__ = ["OneStepScreen", "ProfileResult", "ProfileSettings", "chi2_by_channel", "holdout_chi2", "profile_identify",
           "profile_set", "training_chi2"]


@dataclass(frozen=True)
class ProfileSettings:
    """How :func:`profile_identify` searches.

    Parameters
    ----------
    screen_points : int
        Geometric grid of the first profiled parameter's range (a linear grid
        when the range includes 0).
    other_points : int
        Linear grid of each further profiled parameter.
    local_minima : int
        Local minima of the screen refined and fitted.
    fine_points : int
        Finer grid over one coarse step either side of each local minimum.
    refine_fits : int
        Extra profile fits half a fine step either side of the best (0 or 2).
    level : float
        Confidence level of the profile interval.
    determined_span : float
        Largest share of the first parameter's search range (in its grid's
        coordinate: logarithmic for a geometric grid) its profile set may
        cover and still count as determined (:func:`profile_set`).  The
        search range is the parameter's plausible range (for the pawl pitch
        0.2..2 x the papers' maximum); a set covering more than half of it
        has not halved what was known before the run (less than one bit of
        information): the run does not determine the parameter.
    screen_samples : str
        ``"all"`` (default): the one-step screen sums every sample.
        ``"training"``: only the samples outside the identification settings'
        held-out segments (its minima are the profile fits' candidates and its
        set decides "determined", so with ``"all"`` the held-out samples take
        part in proposing the values the fits then choose among).  Not the
        default, measured: a pawl pitch and its initial clearance are seen
        only through a few back-drives of 0.1-0.2 s, and every third 50 ms
        segment held out puts parts of them out of the training samples by
        chance; on rig-sim's committed ratchet run the first back-drive's end
        lies in held-out segments, the training screen then cannot place the
        initial clearance (0.049 rad found against 0.074 on every sample and
        0.0766 planted; the profile fits' training errors equal to 0.1) and
        the held-out judgement refuses the right candidate (motor-speed window
        error +42 %); on a generated trim run (10 deg, seed 341) the profile
        fits' and the file value's training errors agreed to 0.3, the file
        value was held and refused (+44 %), and a load path and an axial
        force were added in its place.
    comb_budget : int
        Samples x values the comb check may screen (0: no check).  When the
        best screened minimum is a tooth narrower than the grid's step
        (:func:`_tooth_width`: the span between the screened values either
        side of its run within the threshold), the grid samples a comb of
        such teeth at random and one tooth hit by luck looks unique: the
        range is screened again at a quarter of that width, at most
        ``comb_budget / samples`` values (6000 on a 10 s record at 500 Hz,
        about 5 s).  Measured on rig-sim (bipolar tensile trim, pawl pitch
        0.1285 rad + quadrant no-back, seed 106868): 301 values found one
        tooth at 0.1425 rad and called the pitch determined within
        0.14239..0.1426; 3001 values found eleven teeth of equal minimum,
        one of them 0.12847.  A set that is still one tooth narrower than
        :data:`COMB_HIT` of the final step does not determine the parameter
        (an equal tooth as narrow between two screened values is more likely
        missed than hit).
    """

    screen_points: int = 301
    other_points: int = 5
    local_minima: int = 2
    fine_points: int = 21
    refine_fits: int = 0
    level: float = 0.95
    determined_span: float = 0.5
    screen_samples: str = "all"
    comb_budget: int = 30_000_000

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        for name in ("screen_points", "other_points", "fine_points"):
            v = getattr(self, name)
            if not (isinstance(v, int) and v >= 3):
                raise ValueError(f"ProfileSettings.{name} = {v!r} must be an integer >= 3")
        if not (isinstance(self.local_minima, int) and self.local_minima >= 1):
            raise ValueError(f"ProfileSettings.local_minima = {self.local_minima!r} must be an integer >= 1")
        if self.refine_fits not in (0, 2):
            raise ValueError(f"ProfileSettings.refine_fits = {self.refine_fits!r} must be 0 or 2")
        if not (0 < self.level < 1):
            raise ValueError(f"ProfileSettings.level = {self.level!r} must lie in (0, 1)")
        if not (0 < self.determined_span <= 1):
            raise ValueError(f"ProfileSettings.determined_span = {self.determined_span!r} must lie in (0, 1]")
        if not (isinstance(self.comb_budget, int) and self.comb_budget >= 0):
            raise ValueError(f"ProfileSettings.comb_budget = {self.comb_budget!r} must be an integer >= 0")
        if self.screen_samples not in ("training", "all"):
            raise ValueError(f"ProfileSettings.screen_samples = {self.screen_samples!r} must be 'training' or 'all'")


@dataclass(frozen=True)
class ProfileResult:
    """What a profiled identification found.

    Attributes
    ----------
    result : IdentificationResult
        The best profile fit (its parameter set holds the profiled values).
    values : dict name -> float
        The profiled parameters' chosen values.
    interval : dict name -> (lo, hi) or None
        Range where the screened chi-square rises by less than the threshold
        (None: it does not close inside the search range).
    at_bound : dict name -> str or None
        ``"min"``/``"max"`` when the chosen value is the search range's edge.
    mattered : dict name -> bool
        Whether each parameter changed the screen by more than the threshold.
    screen : dict name -> list of (value, chi2)
        The screened profiles (one-step chi-square).
    fits : list of dict
        The profile fits: ``values``, ``score`` (what chose among them, see
        ``chosen_by``), ``training_chi2`` (the fit's objective on the samples
        it was fitted to), ``holdout_chi2`` (noise-weighted squared error on
        the held-out samples, when the settings carry a noise and a hold-out),
        ``chisqr``.
    time_s : float
    determination : dict name -> dict
        The first parameter's profile set (:func:`profile_set`) and what was
        done with it: ``determined``, ``reason``, ``components``, ``threshold``,
        ``iact``, ``reduced_chi2``, ``value_if_free`` (the best profile fit's
        value), ``held_at`` (the value used when not determined: the parameter
        file's when the profile set holds it and its fit's score is within
        the score's gap of the best fit's, else the best fit's), ``file_value``,
        ``file_in_set`` (in the screen's set), ``file_chi2_above_min``,
        ``chosen_by`` and, where the file value was fitted,
        ``file_score_above_best`` and ``score_gap`` (in the units of the score
        that chose); :func:`why_held` says it in words.  ``comb_check`` (a
        continuous grid with ``ProfileSettings.comb_budget``): the best
        tooth's width and the grid's step in the grid's coordinate, of the
        first screen (``coarse_*``) and of the one used (``tooth_width``,
        ``grid_step``, ``points``); ``dense`` when the range was screened again
        because the tooth was narrower than the step (``skipped`` says why
        not where the first screen's set already covers more than
        ``determined_span``); ``resolved`` when the
        tooth used is at least one step wide (otherwise teeth of its width can
        still lie between the screened values: the set holds those found, and
        a lone tooth narrower than :data:`COMB_HIT` of the step is not
        determined).
    chosen_by : str
        Which error chose among the profile fits: ``"training_chi2"`` (the
        default: the fits' own objective on the non-held-out samples),
        ``"holdout_chi2"`` or the name of a caller's ``score``.
    """

    result: IdentificationResult
    values: dict
    interval: dict
    at_bound: dict
    mattered: dict
    screen: dict
    fits: list
    time_s: float
    threshold: float = math.nan
    notes: list = field(default_factory=list)
    screen_time_s: float = math.nan
    determination: dict = field(default_factory=dict)
    chosen_by: str = "training_chi2"

    def to_dict(self) -> dict:
        """JSON-ready summary (no time series)."""
        return {"values": dict(self.values), "interval": {n: (list(v) if v else None) for n, v in self.interval.items()},
                "at_bound": dict(self.at_bound), "mattered": dict(self.mattered),
                "screen": {n: [[float(a), float(b)] for a, b in v] for n, v in self.screen.items()},
                "fits": [dict(f) for f in self.fits], "time_s": self.time_s, "screen_time_s": self.screen_time_s,
                "threshold": self.threshold, "determination": {n: dict(d) for n, d in self.determination.items()},
                "chosen_by": self.chosen_by, "notes": list(self.notes)}


def chi2_by_channel(predictions: Mapping[str, Mapping], noise: Mapping[str, float], select: str = "holdout",
                    windows: Mapping[str, np.ndarray] | None = None, counts: dict[str, int] | None = None
                    ) -> dict[str, float]:
    """Noise-weighted squared error per channel of segment predictions (``IdentificationResult.predictions``)
    over the held-out (``select="holdout"``) or all samples, optionally only inside ``windows[run]``;
    ``counts``, when given, receives the number of samples summed per channel."""
    out: dict[str, float] = {}
    for r, p in predictions.items():
        hold = np.asarray(p["holdout"], bool)
        for c, y in p["measured"].items():
            if noise[c] == 0:  # no weight: neither chi2 nor samples (its errors x/0 were not finite either)
                out[c] = out.get(c, 0.0)
                if counts is not None:
                    counts[c] = counts.get(c, 0)
                continue
            e = (np.asarray(y, float) - np.asarray(p["simulated"][c], float)) / noise[c]
            m = np.isfinite(e) & (hold if select == "holdout" else np.ones_like(hold))
            if windows is not None:
                m &= windows[r][:m.size]
            out[c] = out.get(c, 0.0) + float(np.sum(e[m] ** 2))
            if counts is not None:
                counts[c] = counts.get(c, 0) + int(m.sum())
    return out


def training_chi2(res: IdentificationResult) -> float:
    """The fit's own objective at its estimate: the noise-weighted squared error on the samples it was fitted to
    (the held-out segments excluded) plus its prior rows (``IdentificationResult.chisqr``).  At a fixed value of a
    profiled parameter this is the profile of the objective, so choosing among profile fits by it is the profile
    likelihood's choice, and it leaves the held-out samples to judge the choice."""
    return float(res.chisqr)


def holdout_chi2(res: IdentificationResult, noise: Mapping[str, float]) -> float:
    """Noise-weighted squared error of ``res``'s segment predictions on its held-out samples
    (every sample when none is held out)."""
    held = any(np.asarray(p["holdout"], bool).any() for p in res.predictions.values())
    return sum(chi2_by_channel(res.predictions, noise, "holdout" if held else "all").values())


#: the most samples x parameter sets one compiled call of :meth:`OneStepScreen.chi2_many` evaluates (about 32 MB of
#: errors, more with the custom states the loop returns)
CHI2_CHUNK_SAMPLES = 4_000_000


class OneStepScreen:
    """One-step-ahead chi-square of the measured motor speed, the model's custom states carried.

    Built once per model and runs; :meth:`chi2` takes a parameter set (the
    plant's parameters are an input), so a profile costs one pass per value.
    ``holdout``: the identification settings whose held-out segments
    (:func:`~thsa_control.fit.shooting.segment_layout`) the screen leaves out
    of its sum (the one-step predictions *of* held-out samples; the custom
    states are carried through them from the measured speeds, as the fits'
    segment states are), so that a profile chosen on the screen is chosen on
    the training samples.  None: every sample.
    """

    def __init__(self, runs: Sequence[RigRun], plant, params: ParameterSet, substeps: int = 1,
                 holdout: IdentificationSettings | None = None):
        self.plant = plant
        mech = current_driven_map(plant, substeps)
        self._mech = mech
        self.loop = one_step_loop(plant, mech)
        self.parts = []
        for run in runs:
            w = measured_speed(run)
            X = measured_state_matrix(run, plant, params)
            if w is None or X is None or w.size < 3:
                continue
            n = w.size
            sigma = estimate_noise(w) * math.sqrt(2.0)  # the start speed and the compared one both carry noise
            U = np.vstack([X[:, :-1], mech_inputs(run)[:, :n - 1], sample_periods(run)[None, :n - 1]])
            # the compared samples 1..n-1: all, or those outside the fit's held-out segments
            keep = (~segment_layout(run.time, holdout)[2][1:n] if holdout is not None and holdout.holdout_every
                    else np.ones(n - 1, bool))
            self.parts.append((None if self.loop is not None else one_step_map(plant, mech, n - 1),
                               np.ascontiguousarray(U), w[1:], sigma, keep))
        if not self.parts:
            raise ParameterError("<profile>", "no run measures a motor or screw speed: nothing to screen a profile on")
        self.n = sum(int(p[4].sum()) for p in self.parts)

    def chi2(self, params: ParameterSet, solve: Sequence[str] = ()) -> float:
        """Sum of squared one-step speed errors over the runs, each weighted by its noise.

        ``solve``: parameters whose one-step effect is taken as linear and solved for at this point (one
        Gauss-Newton step from their values in ``params``, sensitivities by finite differences): the screen
        of a count (periods per revolution) whose terms' sizes are free, where the count changes which
        terms act, not how large they are.
        """
        if not solve:
            return float(self.chi2_many([params])[0])
        steps = []
        for n in solve:
            par = params[n]
            steps.append(1e-3 * max(abs(par.value), 1e-3 * (par.max - par.min) if math.isfinite(par.max - par.min)
                                    else 1e-6, 1e-12))
        errs = self._errors_many([params] + [params.replace({n: params.value(n) + d}) for n, d in zip(solve, steps)])
        e0 = errs[0]
        A = np.column_stack([(e - e0) / d for e, d in zip(errs[1:], steps)])
        ok = np.isfinite(e0) & np.isfinite(A).all(axis=1)
        if ok.sum() > len(solve):
            coef = np.linalg.lstsq(A[ok], -e0[ok], rcond=None)[0]
            e0 = np.where(ok, e0 + A @ coef, e0)
        e0 = e0[np.isfinite(e0)]
        return float(e0 @ e0)

    def _errors_many(self, psets: Sequence[ParameterSet]) -> list[np.ndarray]:
        """Noise-weighted one-step speed errors of several parameter sets (the runs concatenated)."""
        P = np.array([self.plant.p_vector(ps) for ps in psets], float)
        # the first custom states follow the parameters (initial clearance fraction x pitch)
        idx = custom_state_indices(self.plant)
        C0 = np.array([self.plant.initial_state(ps)[idx] for ps in psets], float).reshape(len(psets), len(idx))
        out = [[] for _ in psets]
        for F, U, w_next, sigma, keep in self.parts:
            if F is None:
                Y, _, bad = self.loop.batch(C0, [U] * len(psets), P, 1)
                Ws = list(Y[:, -1, :])  # the predicted speed (the rows before: the custom states)
                bad = np.flatnonzero(bad[:len(psets)] >= 0)
                if bad.size:  # a non-finite prediction stops a compiled run: the interpreter carries on past it
                    G = one_step_map(self.plant, self._mech, U.shape[1])
                    for k in bad:
                        Ws[k] = np.asarray(G(C0[k], U, P[k])[1]).ravel()
            else:
                Ws = [np.asarray(F(c0, U, p)[1]).ravel() for c0, p in zip(C0, P)]
            for k, W in enumerate(Ws):
                out[k].append(((np.asarray(W, float) - w_next) / sigma)[keep])
        return [np.concatenate(e) for e in out]

    def chi2_many(self, psets: Sequence[ParameterSet]) -> np.ndarray:
        """:meth:`chi2` of several parameter sets (a profile's grid), in one compiled call per run where a C
        compiler works (each set computed exactly as alone)."""
        tot = np.zeros(len(psets))
        # in chunks of at most CHI2_CHUNK_SAMPLES samples x sets: a comb check's thousands of sets on a 10 s, 1 kHz
        # record held every set's errors (and its custom states) at once, 1.26 GB at the peak
        step = max(1, CHI2_CHUNK_SAMPLES // max(self.n, 1))
        for k0 in range(0, len(psets), step):
            for k, e in enumerate(self._errors_many(psets[k0:k0 + step]), start=k0):
                e = e[np.isfinite(e)]
                tot[k] = float(e @ e)
        return tot


def _grid(lo: float, hi: float, n: int, integer: bool = False) -> np.ndarray:
    if integer:  # a count: every whole value of the range
        return np.arange(math.ceil(lo), math.floor(hi) + 1, dtype=float)
    if lo > 0:
        return np.geomspace(lo, hi, n)
    return np.linspace(lo, hi, n)


#: the least width of a lone tooth, as a share of the screen's step, for the profile set to determine the parameter: a
#: tooth as narrow lying between two screened values is hit with odds of its width over the step, so below one half a
#: comb of equal teeth is more likely missed than seen.  Measured on the catalogue (71 pawl-pitch profiles, 6000-11997
#: values after the comb check): every lone tooth left on a record without a pawl clearance was 0.10-0.20 of the step
#: (two nulls, a ripple pair), the virtual rig's five stops (truth 0.10 rad, found 0.1000) 0.60.
COMB_HIT = 0.5


def _tooth_width(x: np.ndarray, y: np.ndarray, thr: float, geo: bool) -> float:
    """Width of the screened minimum's tooth, in the grid's coordinate (the logarithm for a geometric grid): the
    span between the nearest screened values either side of the contiguous run within ``thr`` of the minimum
    (an upper bound of the width inside the threshold; the range's end where the run reaches it)."""
    u = np.log(x) if geo else np.asarray(x, float)
    ok = np.isfinite(y)
    if not ok.any():
        return math.inf
    i, j = _run_within(y, int(np.nanargmin(np.where(ok, y, np.nan))), thr)
    return float(u[min(j + 1, len(u) - 1)] - u[max(i - 1, 0)])


def _run_within(y: np.ndarray, i0: int, thr: float) -> tuple[int, int]:
    """The first and last index of the contiguous run around ``i0`` where ``y <= y[i0] + thr``."""
    top = y[i0] + thr
    i = i0
    while i > 0 and y[i - 1] <= top:
        i -= 1
    j = i0
    while j < len(y) - 1 and y[j + 1] <= top:
        j += 1
    return i, j


def _local_minima(x: np.ndarray, y: np.ndarray, k: int) -> list[int]:
    idx = [i for i in range(len(y)) if (i == 0 or y[i] <= y[i - 1]) and (i == len(y) - 1 or y[i] <= y[i + 1])]
    return sorted(idx, key=lambda i: y[i])[:k]


def _interval(x: np.ndarray, y: np.ndarray, i0: int, thr: float) -> tuple[float, float] | None:
    """Contiguous range around ``x[i0]`` where ``y <= y[i0] + thr``, widened by one grid step each side (the
    profile resolves nothing finer: the switch times are whole samples); None if it reaches an edge."""
    i, j = _run_within(y, i0, thr)
    if i == 0 or j == len(y) - 1:
        return None
    return float(x[i - 1]), float(x[j + 1])


#: ranges of a profile set listed by name in its reason (a dense comb has a hundred; all are in ``components``)
SHOWN_RANGES = 8


def profile_set(x: Sequence[float], y: Sequence[float], threshold: float, search: tuple[float, float],
                steps: int, chosen: float | None = None, span: float = 0.5, chosen_by: str = "profile fits") -> dict:
    """The profile-likelihood set of a screened parameter and whether it determines the parameter.

    The set is every screened value whose chi-square lies within ``threshold`` of the profile's minimum (the
    ``chi2(1)`` quantile scaled as the fit's held-out differences are: reduced chi-square x the residual's
    integrated autocorrelation time).  Its connected components are runs of consecutive screened values;
    two runs separated by less than two steps of the grid screened (``steps`` values over ``search``: at most
    one screened value between them; the dense grid's after a comb check) are one component, since the screen
    resolves nothing finer than its grid
    (a switch acts at whole samples: the profile is a staircase at fine scale).

    Determined when the set is one component, does not reach an end of the search range, covers at most
    ``span`` of the range (in the grid's coordinate: the logarithm for a geometric grid, i.e. a range that
    starts above 0) and holds ``chosen`` (the value the profile fits chose, by ``chosen_by``) within one coarse
    step.
    A pawl pitch seen through one stop's depth (the travel modulo the pitch) has a comb of equal minima:
    several components, and the screen samples the comb at random.

    Returns a dict: ``components`` (list of [lo, hi]), ``threshold``, ``determined``, ``reason`` (None when
    determined), ``share`` (of the search range the set's hull covers).
    """
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    order = np.argsort(x)
    x, y = x[order], y[order]
    lo, hi = search
    geo = lo > 0
    u = np.log(x) if geo else x
    ulo, uhi = (math.log(lo), math.log(hi)) if geo else (lo, hi)
    step = (uhi - ulo) / max(steps - 1, 1)
    ok = np.isfinite(y)
    if not ok.any():
        return {"components": [], "threshold": float(threshold), "determined": False, "share": math.nan,
                "reason": "no screened value gives a finite chi-square"}
    top = float(np.min(y[ok])) + threshold
    inside = np.flatnonzero(ok & (y <= top))
    comps: list[list[int]] = []
    for i in inside:
        if comps and u[i] - u[comps[-1][1]] < 2 * step * (1 + 1e-9):
            comps[-1][1] = int(i)
        else:
            comps.append([int(i), int(i)])
    components = [[float(x[a]), float(x[b])] for a, b in comps]
    share = float((u[inside[-1]] - u[inside[0]]) / (uhi - ulo)) if uhi > ulo else math.nan
    why = []
    if len(comps) > 1:
        shown = [f"{a:.4g}" if a == b else f"{a:.4g}..{b:.4g}" for a, b in components]
        why.append(f"{len(comps)} separate ranges within the threshold (a comb of equal minima): "
                   + ", ".join(shown if len(shown) <= SHOWN_RANGES else
                               shown[:SHOWN_RANGES - 1] + ["... (all in `components`)", shown[-1]]))
    if comps[0][0] == 0 or comps[-1][1] == x.size - 1:
        why.append(f"the set reaches an end of the search range {lo:g}..{hi:g}")
    if share > span:
        why.append(f"the set covers {share:.0%} of the search range (more than {span:.0%})")
    if chosen is not None and not why:
        uc = math.log(chosen) if geo else chosen
        if not (u[comps[0][0]] - step * (1 + 1e-9) <= uc <= u[comps[0][1]] + step * (1 + 1e-9)):
            why.append(f"the profile fits ({chosen_by}) chose {chosen:.4g}, outside the screen's set "
                       f"{components[0][0]:.4g}..{components[0][1]:.4g}")
    return {"components": components, "threshold": float(threshold), "determined": not why, "share": share,
            "reason": "; ".join(why) if why else None}


def why_held(d: Mapping) -> str:
    """Where a not-determined profiled parameter was held (a ``ProfileResult.determination`` entry), in words."""
    by = {"training_chi2": "training error", "holdout_chi2": "held-out error"}.get(d.get("chosen_by"),
                                                                                   d.get("chosen_by") or "score")
    if d.get("file_in_set") and d.get("held_at") == d.get("file_value"):
        return "the parameter file's value, inside the profile set" + (
            f" (its fit's {by} within {d['score_gap']:.4g} of the best: {d['file_score_above_best']:+.4g})"
            if "file_score_above_best" in d and math.isfinite(d.get("score_gap", math.inf)) else "")
    if d.get("file_in_set") and "file_score_above_best" in d:
        return (f"the best profile fit's (by {by}), one of the set; the parameter file's value is inside the screen's "
                f"set but its fit's {by} is worse by {d['file_score_above_best']:.4g}, more than the gap the data "
                f"resolve {d['score_gap']:.4g}")
    if d.get("file_in_set"):
        return f"the best profile fit's (by {by}), one of the set; the profile fit at the parameter file's value failed"
    return f"the best profile fit's (by {by}), one of the set; the parameter file's value is outside the profile set" + (
        f" (+{d['file_chi2_above_min']:.4g} above its minimum)" if "file_chi2_above_min" in d else "")


def _at_min(x: np.ndarray, y: np.ndarray) -> float:
    """The screened value ``x`` at which the screen ``y`` is least."""
    return float(x[int(np.argmin(y))])


def profile_identify(runs: RigRun | Sequence[RigRun], params: ParameterSet, free: Sequence[str],
                     profile: Mapping[str, tuple[float, float]], *, level: str | None = None, effects=(),
                     settings: IdentificationSettings | None = None, psettings: ProfileSettings | None = None,
                     score: Callable[[IdentificationResult], float] | str | None = None,
                     progress: Callable[[str], None] | None = None,
                     fractions: Mapping[str, str] | None = None,
                     iact: Callable[[np.ndarray], float] | None = None,
                     gap: Callable[[IdentificationResult], float] | None = None,
                     grids: Mapping[str, Sequence[float]] | None = None) -> ProfileResult:
    """Identify ``free`` with the ``profile`` parameters searched over their ranges (see the module doc).

    Parameters
    ----------
    runs : RigRun or sequence of RigRun
    params : ParameterSet
        Initial values, bounds, priors.
    free : sequence of str
        Parameters fitted by least squares at each profiled value.
    profile : mapping name -> (lo, hi)
        Search range of each profiled parameter (inside its bounds), the
        first one screened finely.
    level, effects : the model (as :class:`Identifier`).
    settings : IdentificationSettings
        Of each profile fit.
    psettings : ProfileSettings
    score : callable or str, optional
        What chooses among the profile fits (smallest wins).  Default
        ``"training"``: :func:`training_chi2`, the fit's own objective on the
        samples it was fitted to.  The held-out samples stay out of the
        choice: a choice among several local minima (a comb of pitches) made
        on them biases any judgement made on them afterwards (measured: a
        pitch chosen on the held-out segments bought a ratchet backlash whose
        training error was higher than without it).  ``"holdout"``:
        :func:`holdout_chi2` with the settings' noise (needs a noise and a
        hold-out); a callable ``score(result) -> float``: a caller's own rule.
        ``ProfileResult.chosen_by`` says which one chose.
    progress : callable, optional
    fractions : mapping name -> name, optional
        Further profiled parameters the model uses as a fraction of the first
        one (the initial pawl clearance, a fraction of the pitch).  What a run
        sees of them is the product (the first back-drive crosses the
        clearance angle, fraction x pitch), so after the first screen each is
        screened finely (a grid over its range, then a finer one around the
        best) at the first parameter's best value, and the first parameter is
        screened again with the product held (the fraction clipped to its
        range), the fraction once more at the new best: one step of descent
        in the coordinates the data see.  Screened only after the first, at
        the first's value found with the fraction at its file value, on five
        points, the fraction never moved: on rig-sim's trim runs (pawl phases
        drawn from the seed) it stayed at the file's 0.5 on every seed and
        the pitch came out as twice the first back-drive's clearance.
    iact : callable, optional
        ``iact(errors) -> float``: the integrated autocorrelation time of the
        one-step errors at the best screened value (1 when not given).  The
        profile set's threshold (:func:`profile_set`) is the ``chi2(1)``
        quantile x the screen's reduced chi-square x this time: a difference
        of chi-squares is a sum over an autocorrelated residual, whose
        variance grows by that factor (the tracer's ambiguity gap, scaled the
        same way).  When the set does not determine the first parameter, it
        is held at the parameter file's value where the set holds that value
        (one more profile fit, the fractions' products as screened), else at
        the best fit's value; either way ``determination`` says so.
    gap : callable, optional
        ``gap(result) -> float``: the difference of ``score`` the data resolve
        at the best profile fit (the tracer passes the ``chi2(1)`` quantile at
        its ``alpha`` x the reduced chi-square x the integrated
        autocorrelation time, computed on the residual of the samples the
        score sums: the training residual for the default score).  The
        parameter file's value is held only when its profile fit's score is
        within that gap of the best fit's too (the one-step screen scores
        every sample with the measured states; the fits integrate segments,
        and a value both do not reject is the one to hold).  Without it the
        file value is held whenever the screen's set holds it.

    grids : mapping name -> values, optional
        The values the first profiled parameter is screened at, instead of the grid over its range (the cogging's
        period counts the record resolves, multiples of the pole count); they must lie in its range, which may then
        be a single value (``lo == hi``: the one value is fitted).

    Raises
    ------
    ParameterError
        A profiled parameter that is unknown, also free, or a range outside its bounds.
    SolverError
        Every profile fit failed (a single failing value is recorded in ``fits`` and skipped).
    """
    t0 = time.perf_counter()
    runs = [runs] if isinstance(runs, RigRun) else list(runs)
    st = settings or IdentificationSettings()
    ps = psettings or ProfileSettings()
    ps.validate()
    say = progress or (lambda m: None)
    plant = build_plant(level, effects, params=params)
    for name, (lo, hi) in profile.items():
        if name not in params or name not in plant.parameters:
            raise ParameterError(name, f"cannot be profiled: not a parameter of the model ({', '.join(plant.effects)})")
        if name in free:
            raise ParameterError(name, "cannot be both free and profiled")
        par = params[name]
        single = grids is not None and name in grids and lo == hi
        if not (par.min <= lo and (lo < hi or single) and hi <= par.max):
            raise ParameterError(name, f"profile range {lo:g}..{hi:g} {par.unit} must lie inside its bounds "
                                       f"{par.min:g}..{par.max:g} and be increasing")
    if score is None or score == "training":
        score, chosen_by = training_chi2, "training_chi2"
    elif score == "holdout":
        if st.noise is None or not st.holdout_every:
            raise ParameterError("<profile>", "score='holdout' needs IdentificationSettings.noise and holdout_every")
        noise_ = st.noise

        def score(res):
            return holdout_chi2(res, noise_)
        chosen_by = "holdout_chi2"
    elif callable(score):
        chosen_by = getattr(score, "__name__", None) or "caller's score"
        chosen_by = "caller's score" if chosen_by == "<lambda>" else chosen_by
    else:
        raise ParameterError("<profile>", f"score = {score!r} must be 'training', 'holdout' or a callable")
    from scipy.stats import chi2 as chi2_dist

    q = float(chi2_dist.ppf(ps.level, 1))
    screen = OneStepScreen(runs, plant, params, st.substeps, holdout=st if ps.screen_samples == "training" else None)
    names = list(profile)
    main = names[0]
    fractions = dict(fractions or {})
    for name, of in fractions.items():
        if name not in names[1:] or of != main:
            raise ParameterError(name, f"a profiled fraction must be a further profiled parameter and a fraction of the "
                                       f"first one ({main}), got a fraction of {of!r}")
    lo, hi = profile[main]
    products: dict[str, float] = {}  # fraction -> the product held while the first parameter is screened
    screens: dict[str, list] = {}
    mattered: dict[str, bool] = {}

    def held(v: float) -> dict:
        """The fractions at a value of the first parameter: their products held, clipped to their ranges."""
        return {n: float(min(max(g / v, profile[n][0]), profile[n][1])) for n, g in products.items()}

    # 1-2: screen the first parameter, then refine around its best local minima; an integer parameter (a
    # count) is screened at every whole value, with the free parameters solved linearly at each (the count
    # decides which terms act; their sizes are what the fit is for)
    integer = bool(params[main].integer)
    # solved in the screen: the effect being tried (the free parameters without a prior), else every free one
    solve = (tuple(n for n in free if n in st.no_prior) or tuple(free)) if integer else ()
    if grids is not None and main in grids:
        x = np.array(sorted(float(v) for v in grids[main] if lo <= v <= hi))
    else:
        x = _grid(lo, hi, ps.screen_points, integer)
    if x.size == 0:
        raise ParameterError(main, f"profile range {lo:g}..{hi:g} holds no whole value")

    def screen_main(x=x):
        if solve:
            y = np.array([screen.chi2(params.replace({main: float(v), **held(v)}), solve) for v in x])
        else:
            y = screen.chi2_many([params.replace({main: float(v), **held(v)}) for v in x])
        say(f"profile {main}: screened {x.size} values")
        cands, fine_pts = [], {}
        for i in _local_minima(x, y, ps.local_minima):
            if integer:
                cands.append(float(x[i]))
                continue
            a, b = x[max(i - 1, 0)], x[min(i + 1, x.size - 1)]
            xf = np.linspace(a, b, ps.fine_points)
            yf = screen.chi2_many([params.replace({main: float(v), **held(v)}) for v in xf])
            fine_pts.update(zip(xf.tolist(), yf.tolist()))
            cands.append(_at_min(xf, yf))
        allx = np.array(sorted(set(x.tolist()) | set(fine_pts)))
        ally = np.array([fine_pts[v] if v in fine_pts else float(y[np.searchsorted(x, v)]) for v in allx])
        return cands, allx, ally

    def screen_fraction(name: str, v: float) -> None:
        """A fraction at the first parameter's value ``v``: a grid over its range, then a finer one around the best;
        it matters when it moves the screen by more than the interval threshold of its own screen's minimum."""
        a, b = profile[name]
        xo = np.linspace(a, b, ps.fine_points)
        yo = screen.chi2_many([params.replace({main: v, name: float(u)}) for u in xo])
        i = int(np.argmin(yo))
        xf = np.linspace(xo[max(i - 1, 0)], xo[min(i + 1, xo.size - 1)], ps.fine_points)
        yf = screen.chi2_many([params.replace({main: v, name: float(u)}) for u in xf])
        pts = dict(zip(xo.tolist(), yo.tolist()))
        pts.update(zip(xf.tolist(), yf.tolist()))
        screens[name] = sorted((u * v, c) for u, c in pts.items())  # in units of the product
        c = np.array(list(pts.values()))
        mattered[name] = bool(np.ptp(c) > q * max(float(np.min(c)) / max(screen.n - 1, 1), 1.0))
        if mattered[name]:
            products[name] = float(min(pts, key=pts.get)) * v
        else:
            products.pop(name, None)

    cands, allx, ally = screen_main()
    x_best = _at_min(allx, ally)  # the first parameter's best screened value
    if fractions:
        # one step of descent in the coordinates the runs see (the first parameter, each fraction's product): the
        # fractions at the first parameter's best value, then the first parameter again with their products held
        for name in fractions:
            screen_fraction(name, x_best)
        if products:
            cands, allx, ally = screen_main()
            x_best = _at_min(allx, ally)
            for name in fractions:
                screen_fraction(name, x_best)
    comb: dict = {}
    if not integer and (grids is None or main not in grids) and ps.comb_budget:
        # a tooth narrower than the grid's step: the grid samples a comb of such teeth at random (one hit by luck
        # looks unique), so the range is screened again at a step below the tooth's width, within the budget
        w = _tooth_width(allx, ally, q * max(float(np.min(ally)) / max(screen.n - 1, 1), 1.0), lo > 0)
        u_span = math.log(hi / lo) if lo > 0 else hi - lo
        step0 = u_span / max(x.size - 1, 1)
        comb = {"tooth_width": w, "grid_step": step0, "coordinate": "log" if lo > 0 else "linear",
                "points": int(x.size), "dense": False, "coarse_tooth_width": w, "coarse_grid_step": step0,
                "coarse_points": int(x.size)}
        # a set already over ``determined_span`` of the range at the smaller threshold (no IACT) does not determine at
        # the profile's own, and a denser screen only adds teeth to it: not screened again
        share0 = profile_set(allx, ally, q * max(float(np.min(ally)) / max(screen.n - 1, 1), 1.0), (lo, hi),
                             ps.screen_points, None, ps.determined_span)["share"]
        if w < step0 and share0 > ps.determined_span:
            comb["skipped"] = (f"the first screen's set already covers {share0:.0%} of the range (more than "
                               f"{ps.determined_span:.0%}): it does not determine, and more teeth only widen it")
        elif w < step0:
            n_dense = int(min(math.ceil(4 * u_span / w) + 1, max(x.size, ps.comb_budget // max(screen.n, 1))))
            if n_dense > x.size:
                xd = _grid(lo, hi, n_dense)
                cands, allx, ally = screen_main(xd)
                x_best = _at_min(allx, ally)
                comb.update(dense=True, points=int(n_dense), grid_step=u_span / (n_dense - 1),
                            tooth_width=_tooth_width(allx, ally, q * max(float(np.min(ally)) / max(screen.n - 1, 1),
                                                                          1.0), lo > 0))
                say(f"profile {main}: best tooth {w:.3g} wide, narrower than the grid's step {step0:.3g}: "
                    f"screened again at {n_dense} values")
        comb["resolved"] = bool(comb["tooth_width"] >= comb["grid_step"])
    y_min = float(np.min(ally))
    redchi = y_min / max(screen.n - 1, 1)
    thr = q * max(redchi, 1.0)
    screens = {main: list(zip(allx.tolist(), ally.tolist())), **screens}
    # 4: further parameters, one at a time at the best screened values
    best_vals = {main: x_best}
    mattered[main] = bool(np.ptp(ally) > thr)
    for name in fractions:
        best_vals[name] = held(best_vals[main])[name] if mattered[name] else params.value(name)
    for name in names[1:]:
        if name in fractions:
            continue
        a, b = profile[name]
        xo = np.linspace(a, b, ps.other_points)
        yo = screen.chi2_many([params.replace({**best_vals, name: float(v)}) for v in xo])
        screens[name] = list(zip(xo.tolist(), yo.tolist()))
        mattered[name] = bool(np.ptp(yo) > thr)
        best_vals[name] = _at_min(xo, yo) if mattered[name] else params.value(name)
    others = {n: best_vals[n] for n in names[1:]}

    def others_at(v: float) -> dict:  # the products held at every profile fit
        return {**others, **held(v)}
    t_screen = time.perf_counter() - t0

    # 3: profile fits at the candidate minima, chosen by ``score`` (the training error unless the caller says)
    fits, best = [], None

    def fit_at(v: float, keep: bool = True):
        nonlocal best
        at = others_at(v)
        pset = params.replace({main: float(v), **at})
        try:
            res = Identifier(level, pset, free, effects=effects, settings=st).fit(runs)
        except (ThsaError, RuntimeError) as exc:  # one value failing does not end the profile
            fits.append({"values": {main: float(v), **at}, "error": str(exc)})
            say(f"profile fit {main} = {v:.5g} failed: {exc}")
            return None
        s = float(score(res))
        held_out = (holdout_chi2(res, st.noise) if st.noise is not None and st.holdout_every else None)
        fits.append({"values": {main: float(v), **at}, "score": s, "training_chi2": training_chi2(res),
                     **({"holdout_chi2": held_out} if held_out is not None else {}), "chisqr": res.chisqr,
                     "converged": res.converged, **({} if keep else {"held": True})})
        say(f"profile fit {main} = {v:.5g}: {chosen_by} {s:.5g}")
        if keep and (best is None or s < best[0]):
            best = (s, float(v), res)
        return s, float(v), res

    for v in dict.fromkeys(cands):
        fit_at(v)
    if best is None:
        raise SolverError("profile", f"every profile fit of {main} failed: {fits[-1]['error']}")
    if ps.refine_fits and not integer:
        step = float(np.min(np.diff(np.sort(allx)))) if allx.size > 1 else 0.0
        v0 = best[1]
        for v in (v0 - 0.5 * step, v0 + 0.5 * step):
            if lo <= v <= hi:
                fit_at(v)

    def hold_file(d: dict, v_file: float) -> None:
        """A first parameter not determined: held at the parameter file's value where the set holds it and its
        profile fit scores within the gap the data resolve of the best (``best`` replaced), else at the best fit's;
        ``d`` records both scores and where it is held."""
        nonlocal best
        if d["file_in_set"]:
            held_fit = fit_at(v_file, keep=False)
            if held_fit is not None:
                g = float(gap(best[2])) if gap is not None else math.inf
                d["file_score_above_best"] = held_fit[0] - best[0]
                d["score_gap"] = g
                if held_fit[0] - best[0] <= g:
                    best = held_fit
                    d["held_at"] = v_file
        if d["held_at"] is None:
            d["held_at"] = best[1]
        say(f"profile {main}: not determined ({d['reason']}); held at {d['held_at']:.5g}")

    # is the first parameter determined?  its profile set at the threshold the tracer uses for held-out differences
    determination: dict = {}
    if mattered[main] and not integer:
        e_best = screen._errors_many([params.replace({main: x_best, **held(x_best)})])[0]
        e_best = e_best[np.isfinite(e_best)]
        tau = max(float(iact(e_best)), 1.0) if iact is not None and e_best.size >= 8 else 1.0
        # the runs merge at the resolution of the grid screened last: after a dense screen, teeth a coarse step apart
        # are separate ranges (merged at the coarse grid's two steps, a comb 0.8 % apart read as one range)
        d = profile_set(allx, ally, q * max(redchi, 1.0) * tau, (lo, hi),
                        comb["points"] if comb.get("dense") else ps.screen_points, best[1], ps.determined_span,
                        chosen_by)
        d.update(iact=tau, reduced_chi2=redchi, value_if_free=best[1], held_at=None, file_in_set=None,
                 chosen_by=chosen_by, **({"comb_check": comb} if comb else {}))
        if d["determined"] and comb and comb["tooth_width"] < COMB_HIT * comb["grid_step"]:
            d["determined"] = False
            d["reason"] = (f"the set is one tooth {comb['tooth_width']:.3g} wide ({comb['coordinate']} {main}), under "
                           f"{COMB_HIT:g} of the step of the {comb['points']} values screened ({comb['grid_step']:.3g}): "
                           f"teeth as narrow between the screened values are hit with less than even odds, and a "
                           f"comb of them is not excluded")
        if not d["determined"]:
            v_file = params.value(main)
            d["file_value"] = v_file
            if lo <= v_file <= hi:
                c_file = float(screen.chi2_many([params.replace({main: v_file, **held(v_file)})])[0])
                d["file_chi2_above_min"] = c_file - y_min
                d["file_in_set"] = bool(c_file <= y_min + d["threshold"])
            hold_file(d, v_file)
        determination[main] = d
    elif not integer:
        # a flat screen: no value of the first parameter changes the one-step error by the threshold, and one
        # profile fit was made, at the screen's first value (measured on a blind rig-sim cold check whose ratchet
        # slips through its initial free travel once: the pitch screened flat to the last digit and the fit at
        # 0.03 rad, the range's end, was reported as the pitch).  Not determined by the profile: held at the
        # parameter file's value where that fit's score is within the gap the data resolve (the fractions' products
        # kept), else at the fitted one, as for a set that does not determine it; both scores are kept
        v_file = float(min(max(params.value(main), lo), hi))
        d = {"determined": False, "flat": True, "components": [], "threshold": thr, "reduced_chi2": redchi,
             "reason": (f"the one-step screen changes by {float(np.ptp(ally)):.3g} over {lo:g}..{hi:g}, less than "
                        f"the threshold {thr:.3g}: the profile does not resolve it on these runs (one profile fit, at "
                        f"the screen's first value)"),
             "value_if_free": best[1], "held_at": None, "file_value": params.value(main),
             "file_in_set": bool(lo <= params.value(main) <= hi), "chosen_by": chosen_by}
        hold_file(d, v_file)
        determination[main] = d
    values = {main: best[1], **others_at(best[1])}
    # interval of the chosen value on the screened profile (nearest screened point, then its local minimum)
    intervals, at_bound = {}, {}
    for name, pts in screens.items():
        xs = np.array([a for a, _ in pts])
        ys = np.array([b for _, b in pts])
        # a fraction's screen is kept in units of its product with the first parameter
        scale = 1.0 / values[main] if name in fractions else 1.0
        i0 = int(np.argmin(np.abs(xs * scale - values[name])))
        while True:  # downhill to the screened local minimum the chosen value sits in
            nb = [j for j in (i0 - 1, i0 + 1) if 0 <= j < xs.size and ys[j] < ys[i0]]
            if not nb:
                break
            i0 = min(nb, key=lambda j: ys[j])
        iv = _interval(xs, ys, i0, thr) if mattered[name] else None
        intervals[name] = (iv[0] * scale, iv[1] * scale) if iv is not None else None
        if name in determination and not determination[name]["determined"]:
            comps = determination[name]["components"]  # the profile's set, not a local interval
            intervals[name] = (comps[0][0], comps[-1][1]) if comps else None
        rlo, rhi = profile[name]
        span = rhi - rlo
        at_bound[name] = ("min" if values[name] - rlo <= 1e-9 * span else
                          "max" if rhi - values[name] <= 1e-9 * span else None) if mattered[name] else None
    notes = [f"{n} does not change the one-step error by more than the threshold: held at {values[n]:g}"
             for n in names if not mattered[n] and n not in determination]
    notes += [f"{n} screened at the best {main}, then held as its product with it ({products[n]:.4g}) while {main} "
              f"was screened again" for n in products]
    notes += [f"{n} not determined by the runs ({d['reason']}): held at {d['held_at']:.5g} ({why_held(d)})"
              for n, d in determination.items() if not d["determined"]]
    return ProfileResult(best[2], values, intervals, at_bound, mattered, screens, fits, time.perf_counter() - t0,
                         thr, notes, t_screen, determination, chosen_by)
