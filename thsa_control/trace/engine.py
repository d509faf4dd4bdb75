"""Trace a residual to the effect the model lacks: candidates, forward selection, honest scoring.

:func:`trace` takes rig runs and a declared model (a level plus effects) and

1. fits the model's documented default uncertain parameters
   (:data:`DEFAULT_UNCERTAIN`, regularised by priors at the parameter file's
   values) by multiple shooting driven by the measured current
   (:class:`~thsa_control.fit.identify.Identifier`), with every
   ``holdout_every``-th segment held out of the parameter fit;
2. for every library effect the model does not declare (:data:`CANDIDATES`,
   plus any other registered effect, with its own parameters free), adds it,
   re-identifies the declared and the candidate's parameters, and scores it:

   * ``holdout_chi2_drop``: drop of the noise-weighted squared error on the
     held-out segments (data the parameter fit did not see);
   * ``window_reduction``: RMS drop of the held-out error inside the window
     where the effect acts (moving, loaded, near a reversal, cold ...);
   * plausibility: no identified parameter at a bound, none collapsing to
     zero (``|value| < 2 stderr``);
   * calibration: the same candidate fitted to a *null run* (the current
     model's own segment predictions driven by the same measured current,
     with white noise of the measured level) gives the drop noise alone buys;

   a candidate is significant when its held-out drop exceeds both the
   ``chi2(k)`` quantile at ``alpha`` and ``null_factor`` times its null drop,
   its window error falls by ``min_window_reduction``, the window error of its
   own channel (``CandidateSpec.channel``, where measured) does not grow by
   more than ``max_channel_increase``, and it is plausible;
3. keeps the most significant candidate, makes it part of the model and
   repeats (forward selection) until none is significant; when other
   plausible candidates explain the same part of the residual (held-out drops
   closer than noise can separate, see :func:`_rivals`) it names none of them,
   lists them under ``ambiguous`` and stops;
4. describes the remaining residual (:mod:`thsa_control.trace.signature`)
   and says ``unexplained`` when it is still structured.

Nothing here draws or writes files (:mod:`thsa_control.report.trace` does).
Candidate fits run in parallel processes (``workers``).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from ..data.rigdata import RigRun, measured_motor_speed, motor_speed_from
from ..errors import ThsaError
from ..fit.identify import IdentificationSettings, Identifier, estimate_noise
from ..fit.profile import chi2_by_channel
from ..fit.replay import channel_fit
from ..fit.residuals import quadrant, reversal_proximity
from ..model import EFFECTS, CandidateSpec, build_plant, resolve_effects
from ..model.laws import kinematic_ratio
from ..model.params import ParameterSet, default_parameters
from .threads import limit_blas_threads
from .signature import (SignatureSettings, binned_mean, cross_correlation, current_offset_test, missing_torque,
                        position_local_test, sensor_consistency, signature_tests)

__all__ = ["TraceSettings", "CandidateSpec", "CANDIDATES", "DEFAULT_UNCERTAIN", "TraceResult", "trace",
           "candidate_specs", "TRACE_FORMAT"]

TRACE_FORMAT = "thsa-trace/1"

#: The documented default uncertain parameters of each level (fitted before any candidate).
#: The efficiencies are held at the parameter file's values by default: with a
#: constant force on the nut, free efficiencies make a direction-dependent
#: torque that stands in for any missing friction (and, at the papers' loads,
#: a self-locking screw for a missing no-back); free them with ``uncertain``.
DEFAULT_UNCERTAIN: dict[str, tuple[str, ...]] = {
    "A": ("gear.viscous_friction",),
    "B": ("gear.viscous_friction", "noback.mu_coulomb_pos", "noback.mu_coulomb_neg"),
}
DEFAULT_UNCERTAIN["C"] = DEFAULT_UNCERTAIN["B"]
DEFAULT_UNCERTAIN["D"] = DEFAULT_UNCERTAIN["B"]


class _CandidateView(Mapping):
    """The registered effects' tracer candidate specs by name (a live view of the registry).

    Each effect declares its spec (or why it is not a candidate) with its other
    knowledge (:class:`~thsa_control.model.Effect`); this view lists the specs.
    """

    def __getitem__(self, name: str) -> CandidateSpec:
        spec = EFFECTS[name].candidate if name in EFFECTS else None
        if not isinstance(spec, CandidateSpec):
            raise KeyError(name)
        return spec

    def __iter__(self):
        return (n for n, e in EFFECTS.items() if isinstance(e.candidate, CandidateSpec))

    def __len__(self) -> int:
        return sum(1 for _ in self)


#: Candidate spec of every registered effect that is a candidate.
CANDIDATES: Mapping[str, CandidateSpec] = _CandidateView()


def not_candidates() -> tuple[str, ...]:
    """Effects that are configurations or faults, not candidates of a healthy rig's residual.

    Each says why (``Effect.candidate`` is a :class:`~thsa_control.model.NotCandidate`): the fault
    effects (a jam, a load-path failure, the end stops, the limiter's slip, the motor brakes) act
    through an event or a threshold that gives a fit no gradient on data where they do not fire.
    Name one in ``candidates`` to score it anyway.
    """
    return tuple(n for n, e in EFFECTS.items() if not isinstance(e.candidate, CandidateSpec))


#: The base correction's efficiency explainer: not an effect but the declared ball screw's efficiencies freed
#: within their plausible spread (the rig's screw may be a little better or worse than the file says; a
#: load-proportional drag while driving, such as a no-back that drags, is the same torque)
EFFICIENCY_EXPLAINER = CandidateSpec("efficiency", ("screw.efficiency_direct", "screw.efficiency_inverse"), {}, "loaded",
                                     base_correction=True, plausible={"screw.efficiency_direct": "efficiency",
                                                                      "screw.efficiency_inverse": "efficiency"})


def _rule_drag(params: ParameterSet, runs) -> tuple[float, str]:
    t = 0.03 * params.value("motor.rated_torque")
    return t, (f"3 % of motor.rated_torque ({params.value('motor.rated_torque'):g} N m) = {t:.3g} N m at the motor shaft: "
               "a healthy drive's no-load drag is about 2 % of rated torque (the parameter file's gear.viscous_friction "
               "source), with half as much again for a rig's seals and bearings")


def _rule_axial(params: ParameterSet, runs) -> tuple[float, str]:
    fmax = max((float(np.nanmax(np.abs(np.asarray(r.signals["load_force"], float)))) for r in runs), default=0.0)
    f = 100.0 + 0.01 * fmax
    return f, (f"100 N + 1 % of the largest measured load ({fmax:.0f} N) = {f:.0f} N: a load cell calibrated to 1 % of "
               "the range the rig uses plus 100 N of fixture weight and seal drag; an axial force of kilonewtons the "
               "load cell does not see is not a rig's base but an effect")


def _rule_periodic(params: ParameterSet, runs) -> tuple[float, str]:
    t = 0.05 * params.value("motor.rated_torque")
    return t, (f"5 % of motor.rated_torque = {t:.3g} N m amplitude at the motor shaft: servo-motor cogging and ball-screw "
               "friction ripple are a few per cent of rated torque (catalogue cogging below 2 %)")


def _rule_efficiency(params: ParameterSet, runs) -> tuple[float, str]:
    return 0.05, ("+-0.05 around the parameter file's efficiency: the spread of catalogue ball-screw efficiencies at "
                  "one lead and diameter")


#: Plausible magnitudes (rule -> function(params, runs) -> (bound, where the bound comes from)).
PLAUSIBLE: dict[str, Callable] = {"drag": _rule_drag, "axial_force": _rule_axial, "periodic": _rule_periodic,
                                  "efficiency": _rule_efficiency}




@dataclass(frozen=True)
class TraceSettings:
    """How :func:`trace` fits, scores and selects.

    Parameters
    ----------
    segment_duration, substeps : float, int
        Multiple shooting (as :class:`IdentificationSettings`).
    holdout_every : int
        Every k-th segment is held out of the parameter fits and scored.
    max_nfev : int
        Evaluation limit of each fit.
    fit_time_budget : float or None
        Wall-time limit of each fit [s] (best point kept, flagged).
    prior_relative_sd : float
        Priors of the declared uncertain parameters at the parameter file's values.
    uncertain : tuple of str or None
        Declared parameters to fit (None: :data:`DEFAULT_UNCERTAIN` of the level).
    candidates : tuple of str or None
        Candidate effects (None: every library effect not in the model).
    alpha : float
        Level of the ``chi2(k)`` test of the held-out drop.
    null_factor : float
        The held-out drop must exceed this many times the drop on the null run.
    min_window_reduction : float
        Required relative drop of the held-out RMS inside the candidate's window.
    max_channel_increase : float
        A candidate that makes the held-out RMS of its own channel (where it
        shows, :attr:`CandidateSpec.channel`) inside its window grow by more
        than this fraction is refused, whatever it buys on the others (a
        lagging motor-speed sensor fitted as a compliant drive train made the
        screw-speed error five times larger).  Other channels may trade: a
        cogging fit aligns its angle through the segments' nut positions and
        doubles the LVDT's small error.
    max_effects : int
        Forward selection stops after this many effects.
    workers : int
        Parallel processes for candidate fits (1: in this process).
    seed : int
        Noise of the null runs.
    signature : SignatureSettings
    base_corrections : bool or None
        Fit the base-correction step first (the constant-torque explainers
        and the screw efficiencies within their plausible magnitudes,
        :data:`PLAUSIBLE`), reported as base corrections, not as found
        effects.  None: on when the candidates are the default pool (a named
        candidate list is scored as effects only, as before).
    undetermined_relative_stderr : float
        A candidate's parameter whose standard error exceeds this multiple of
        its reference magnitude (file value, seed or plausible bound), or is
        undetermined, is not determined by the run: it is held at its file
        value, the candidate refitted and judged on what the others explain.
    window_tolerance : float
        A significant physical effect whose window RMS drop is within this of
        the best constant-torque explainer's comes before it
        (:func:`_physical_first`).
    """

    segment_duration: float = 0.05
    substeps: int = 1
    holdout_every: int = 3
    max_nfev: int = 40
    fit_time_budget: float | None = 120.0
    prior_relative_sd: float = 0.1
    tolerance: float = 1e-7
    uncertain: tuple[str, ...] | None = None
    candidates: tuple[str, ...] | None = None
    alpha: float = 1e-3
    null_factor: float = 3.0
    min_window_reduction: float = 0.05
    max_channel_increase: float = 0.1
    max_effects: int = 3
    workers: int = 2
    seed: int = 0
    signature: SignatureSettings = field(default_factory=SignatureSettings)
    base_corrections: bool | None = None
    undetermined_relative_stderr: float = 1.0
    window_tolerance: float = 0.01

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        if not (isinstance(self.holdout_every, int) and self.holdout_every >= 2):
            raise ValueError(f"TraceSettings.holdout_every = {self.holdout_every!r} must be an integer >= 2")
        if not (isinstance(self.workers, int) and self.workers >= 1):
            raise ValueError(f"TraceSettings.workers = {self.workers!r} must be an integer >= 1")
        if not (0 < self.alpha < 1):
            raise ValueError(f"TraceSettings.alpha = {self.alpha!r} must lie in (0, 1)")
        if not (isinstance(self.max_effects, int) and self.max_effects >= 0):
            raise ValueError(f"TraceSettings.max_effects = {self.max_effects!r} must be an integer >= 0")
        if self.candidates is not None:
            bad = [c for c in self.candidates if c not in EFFECTS]
            if bad:
                raise ValueError(f"TraceSettings.candidates: unknown effect(s) {bad}; effects are {', '.join(EFFECTS)}")


@dataclass(frozen=True)
class TraceResult:
    """What the tracer found (:meth:`to_dict` is ``trace.json``, schema ``docs/trace_schema.json``)."""

    doc: dict
    fits: dict  # label -> fit summary with time series (for the report)

    def to_dict(self) -> dict:
        return self.doc

    @property
    def effects_added(self) -> list[str]:
        return [e["name"] for e in self.doc["effects_added"]]

    @property
    def unexplained(self) -> bool:
        return bool(self.doc["unexplained"])


# ----------------------------------------------------------------------------- candidates
def _generic_spec(name: str, params: ParameterSet) -> CandidateSpec | None:
    """An effect without a table entry: its non-zero, finitely bounded parameters (at most 3) are free."""
    free = [n for n in EFFECTS[name].parameters
            if n in params and params[n].value != 0 and math.isfinite(params[n].max - params[n].min)][:3]
    return CandidateSpec(name, tuple(free), {}, "all") if free else None


def candidate_specs(model_effects: Iterable[str], params: ParameterSet, names: Sequence[str] | None = None
                    ) -> list[CandidateSpec]:
    """Candidates for a model: every library effect it does not declare (or ``names``)."""
    have = set(model_effects)
    excluded = not_candidates()
    pool = names if names is not None else [e for e in EFFECTS if e not in excluded]
    out = []
    for n in pool:
        if n in have:
            continue
        spec = CANDIDATES.get(n) or _generic_spec(n, params)
        if spec is not None and all(p in params for p in (*spec.free, *spec.profile)):
            out.append(spec)
    return out


#: The windows a candidate may act in (:attr:`CandidateSpec.window`, :func:`_window`).
WINDOWS = ("moving", "all", "loaded", "reversal", "reversal_or_stop", "cold", "resolved_cogging")


def _window(kind: str, run: RigRun, params: ParameterSet | None = None) -> np.ndarray:
    s = run.signals
    w = np.nan_to_num(measured_motor_speed(run))
    moving = np.abs(w) > 0.05 * max(float(np.max(np.abs(w))), 1e-9)
    load = np.asarray(s["load_force"], float)
    if kind == "all":
        return np.ones(w.shape, bool)
    if kind == "moving":
        return moving
    if kind == "loaded":
        return moving & (np.abs(load) > max(0.05 * float(np.max(np.abs(load))), 500.0))
    if kind == "reversal":
        return moving & (reversal_proximity(run.time, w, deadband=0.05 * float(np.max(np.abs(w)))) < 0.3)
    if kind == "reversal_or_stop":  # 0.3 s around a reversal, or after the motion stops (moving -> still)
        t = np.asarray(run.time, float)
        near = reversal_proximity(t, w, deadband=0.05 * float(np.max(np.abs(w)))) < 0.3
        for ts in t[1:][moving[:-1] & ~moving[1:]]:
            near |= (t >= ts) & (t < ts + 0.3)
        return near
    if kind == "resolved_cogging":  # moving slowly enough that the cogging's period spans 4 samples or more
        t = np.asarray(run.time, float)
        fs = 1.0 / float(np.median(np.diff(t))) if t.size > 1 else 0.0
        n = params.value("drive.cogging_periods") if params is not None and "drive.cogging_periods" in params else 6.0
        return moving & (n * np.abs(w) / (2 * math.pi) < fs / 4)
    if kind == "cold":
        temp = np.asarray(s["temperature"], float)
        return np.abs(temp - 25.0) > 5.0
    raise ValueError(f"unknown window {kind!r}")


# ----------------------------------------------------------------------------- fits (run in workers)
def _fit_job(job: dict) -> dict:
    """One identification, summarised (picklable in and out)."""
    t0 = time.perf_counter()
    limit_blas_threads(1)
    held: dict = {}
    try:
        params = ParameterSet.from_toml(job["params_toml"])
        prof = None
        if job.get("profile"):
            from ..fit.profile import profile_identify

            prof = profile_identify(job["runs"], params, job["free"], job["profile"], effects=job["effects"],
                                    settings=job["settings"])
            res = prof.result
        else:
            ident = Identifier(None, params, job["free"], effects=job["effects"], settings=job["settings"])
            res = ident.fit(job["runs"])
            held = _undetermined(res, job.get("judge") or {}, job.get("relative_stderr", 1.0))
            if held and len(held) < len(job.get("judge") or {}):
                # identifiability before plausibility: hold what the run does not determine at its file
                # value and judge the candidate on what the others explain
                keep = tuple(n for n in job["free"] if n not in held)
                params = params.replace({n: job["hold_at"][n] for n in held})
                settings = dataclasses.replace(job["settings"], no_prior=tuple(n for n in job["settings"].no_prior
                                                                               if n in keep))
                res = Identifier(None, params, keep, effects=job["effects"], settings=settings).fit(job["runs"])
                job = {**job, "free": keep}
                for n, h in held.items():
                    h["held_at"] = job["hold_at"][n]
            elif held:
                for h in held.values():
                    h["held_at"] = None  # nothing determined: the candidate is judged as such
    except (ThsaError, ValueError, RuntimeError) as exc:  # casadi raises RuntimeError
        return {"label": job["label"], "error": str(exc), "time_s": time.perf_counter() - t0}
    est = {n: {"value": e.value, "stderr": e.stderr if math.isfinite(e.stderr) else None, "init": e.init,
               "at_bound": e.at_bound, "min": e.min, "max": e.max, "unit": e.unit}
           for n, e in res.estimates.items()}
    if prof is not None:  # profiled: a value with an interval from the profile, no stderr
        for n, (lo, hi) in job["profile"].items():
            est[n] = {"value": prof.values[n], "stderr": None, "init": params.value(n), "at_bound": prof.at_bound[n],
                      "min": lo, "max": hi, "unit": params[n].unit, "interval": prof.interval[n],
                      "profiled": True, "mattered": prof.mattered[n]}
    preds = {r: {"time": p["time"], "measured": dict(p["measured"]), "simulated": dict(p["simulated"]),
                 "holdout": p["holdout"], "segment_starts": p["segment_starts"]} for r, p in res.predictions.items()}
    if prof is None:
        for n, h in held.items():
            if h.get("held_at") is not None:
                e = params[n]
                est[n] = {"value": h["held_at"], "stderr": None, "init": h["held_at"], "at_bound": None, "min": e.min,
                          "max": e.max, "unit": e.unit, "held": True, "undetermined": h}
            elif n in est:
                est[n]["undetermined"] = h
    return {"label": job["label"], "effects": list(res.effects), "free": list(job["free"]), "estimates": est,
            "held": {n: h for n, h in held.items() if h.get("held_at") is not None},
            "aic": res.aic, "bic": res.bic, "chisqr": res.chisqr, "nfev": res.nfev, "converged": res.converged,
            "status": res.status, "time_s": time.perf_counter() - t0, "predictions": preds,
            "params_toml": res.to_parameter_set().to_toml(), "profile": prof.to_dict() if prof is not None else None}


def _undetermined(res, judge: Mapping[str, float], rel: float) -> dict:
    """Parameters of ``judge`` (name -> reference magnitude) the fit does not determine.

    Not determined: an infinite standard error (a null direction of the
    Fisher information: the run has no information on it, or only together
    with another parameter), or one larger than ``rel`` times the parameter's
    reference magnitude (the run cannot tell the value from zero nor from
    twice its size).  A parameter so determined that it collapses to zero is
    not here: that is a verdict on the effect (:func:`_plausibility`).
    """
    out = {}
    for n, ref in judge.items():
        e = res.estimates.get(n)
        if e is None:
            continue
        sd = e.stderr
        if not math.isfinite(sd):
            out[n] = {"reason": "undetermined standard error (no information in this run, or only together with "
                                "another parameter)", "value_if_free": e.value, "stderr_if_free": None}
        elif sd > rel * ref:
            out[n] = {"reason": f"standard error {sd:.3g} {e.unit} exceeds {rel:g} x its reference magnitude "
                                f"{ref:.3g} {e.unit}", "value_if_free": e.value, "stderr_if_free": sd}
    return out


def _run_jobs(jobs: list[dict], workers: int, progress: Callable | None) -> list[dict]:
    if not jobs:
        return []
    if workers <= 1 or len(jobs) == 1:
        out = []
        for j in jobs:
            out.append(_fit_job(j))
            if progress:
                progress(f"fitted {j['label']} in {out[-1]['time_s']:.1f} s")
        return out
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    ctx = mp.get_context("fork") if "fork" in mp.get_all_start_methods() else None
    out: dict[int, dict] = {}
    with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=ctx) as ex:
        futs = {ex.submit(_fit_job, j): i for i, j in enumerate(jobs)}
        from concurrent.futures import as_completed

        for f in as_completed(futs):
            i = futs[f]
            out[i] = f.result()
            if progress:
                progress(f"fitted {jobs[i]['label']} in {out[i]['time_s']:.1f} s")
    return [out[i] for i in range(len(jobs))]


# ----------------------------------------------------------------------------- scoring
def _chi2_by_channel(fit: dict, noise: Mapping[str, float], select: str, windows: dict | None = None) -> dict:
    """Noise-weighted squared error per channel of a fit over held-out (``select="holdout"``) or all samples."""
    return chi2_by_channel(fit["predictions"], noise, select, windows)


def _rms_by_channel(fit: dict, mask_fn=None) -> dict:
    acc: dict[str, list] = {}
    for r, p in fit["predictions"].items():
        for c, y in p["measured"].items():
            e = np.asarray(y) - np.asarray(p["simulated"][c])
            m = np.isfinite(e)
            if mask_fn is not None:
                m &= mask_fn(r, p)
            acc.setdefault(c, []).append(e[m])
    return {c: float(np.sqrt(np.mean(np.concatenate(v) ** 2))) if sum(x.size for x in v) else math.nan
            for c, v in acc.items()}


def _channel_errors(fit: dict) -> dict:
    out = {}
    chans = {c for p in fit["predictions"].values() for c in p["measured"]}
    for c in sorted(chans):
        y = np.concatenate([np.asarray(p["measured"][c]) for p in fit["predictions"].values() if c in p["measured"]])
        s = np.concatenate([np.asarray(p["simulated"][c]) for p in fit["predictions"].values() if c in p["measured"]])
        f = channel_fit(c, y, s)
        out[c] = {"rms": f.rms, "nrmse": f.nrmse, "fit_percent": f.fit_percent, "unit": f.unit}
    return out


def _plausibility(fit: dict, spec: CandidateSpec, plaus: Mapping | None = None) -> tuple[bool, list[str]]:
    """Plausible: no parameter at a bound, none collapsing to zero, at least one determined by the data,
    no periodic torque larger than a healthy drive's (:data:`PLAUSIBLE`).

    A parameter the run does not determine was held at its file value (``held``) and is not judged: "collapses
    to zero" is a verdict only for a parameter the data determine.
    """
    why, determined = [], 0
    est = [(n, fit["estimates"][n]) for n in spec.free if n in fit["estimates"] and not fit["estimates"][n].get("held")]
    lost = [n for n in spec.free if fit["estimates"].get(n, {}).get("undetermined")
            and not fit["estimates"][n].get("held")]
    if lost:
        why.append("no parameter determined by the run: " + ", ".join(lost))
    periodic = [n for n in spec.free if spec.plausible.get(n) == "periodic"]
    if plaus and periodic and all(n in fit["estimates"] for n in periodic):
        amp = math.hypot(*(fit["estimates"][n]["value"] for n in periodic))
        bound, src = plaus["periodic"]
        if amp > bound:
            why.append(f"amplitude {amp:.3g} N m exceeds the plausible {bound:.3g} N m ({src})")
    for n in spec.profile:  # profiled: determined when its profile interval closes inside the search range
        e = fit["estimates"].get(n)
        if e is None or not e.get("mattered"):
            continue
        if e["at_bound"]:
            why.append(f"{n} at the {e['at_bound']} end of its profile range")
        elif e["interval"] is not None:
            determined += 1
    pairs = spec.name in ("screw_friction_ripple", "cogging_torque")
    for n, e in est:
        if e["at_bound"]:
            why.append(f"{n} at its {e['at_bound']} bound")
        sd = e["stderr"]
        if sd is None:
            continue
        determined += 1
        if not pairs and abs(e["value"]) < 2 * sd:
            why.append(f"{n} = {e['value']:.3g} collapses to zero (stderr {sd:.2g})")
    if pairs and len(est) == 2:
        (_, a), (_, b) = est
        amp = math.hypot(a["value"], b["value"])
        sd = math.hypot(a["stderr"] if a["stderr"] is not None else math.inf,
                        b["stderr"] if b["stderr"] is not None else math.inf)
        if not amp > 2 * sd:
            why.append(f"amplitude {amp:.3g} collapses to zero (stderr {sd:.2g})")
    if (est or spec.profile) and determined == 0 and not any("determined" in w for w in why):
        why.append("no parameter determined by the data")
    return not why, why


def _param_entry(e: dict) -> dict:
    sd = e["stderr"]
    ci = [e["value"] - 1.96 * sd, e["value"] + 1.96 * sd] if sd is not None else e.get("interval")
    return {"value": e["value"], "stderr": sd, "unit": e["unit"], "ci95": list(ci) if ci else None,
            "at_bound": e["at_bound"], **({"profiled": True} if e.get("profiled") else {}),
            **({"held": True} if e.get("held") else {})}


def _held_out(fit: dict) -> list[dict]:
    """The parameters a candidate fit held at their file values because the run does not determine them."""
    return [{"parameter": n, "held_at": h["held_at"], "unit": fit["estimates"].get(n, {}).get("unit", ""),
             "reason": h["reason"], "value_if_free": h["value_if_free"], "stderr_if_free": h["stderr_if_free"]}
            for n, h in (fit.get("held") or {}).items()]


def _held_params(toml: str, fit: dict) -> str:
    """A job's parameter set with the fit's held parameters at their held values (for its null run)."""
    held = fit.get("held") or {}
    if not held:
        return toml
    return ParameterSet.from_toml(toml).replace({n: h["held_at"] for n, h in held.items()}).to_toml()


def _signature_brief(sig: dict) -> dict:
    """What a round leaves: the structured tests (name, kind, size) and whether anything is structured."""
    tests = [t for t in sig.get("tests", []) + sig.get("sensors", []) if t["significant"]]
    above = [f"held-out residual above noise ({c}: {r:.2g} x)" for c, r in sig.get("residual_to_noise", {}).items()
             if r > sig.get("max_noise_ratio", math.inf)]
    return {"unexplained": bool(tests or above), "structured": [t["variable"] for t in tests] + above,
            "missing_torque_rms": sig.get("missing_torque_rms"),
            "tests": [{k: t[k] for k in ("variable", "kind", "size", "unit", "p_value") if k in t} for t in tests]}


def _base_correction(first: dict, declared, uncertain, params: ParameterSet, plaus: dict, fit_runs, noise, st,
                     job: Callable, say: Callable) -> dict:
    """The base-correction step: what every real drive has and the declared level may lack.

    The constant-torque explainers (a Coulomb drag, an axial force the load cell does not see) and the ball
    screw's efficiencies are fitted together with the declared uncertain set,
    each inside its plausible magnitude (:data:`PLAUSIBLE`, the bound's source reported) and with a prior at
    0 (the file's efficiency) of half that size, so that explainers that stand for the same torque share it
    instead of drifting along their common direction.  Accepted when the held-out chi2 drop passes the
    ``chi2(k)`` test.  An explainer at its bound is offered later as a found-effect candidate (the same
    effect beyond what a rig's base can be).
    """
    from scipy.stats import chi2

    # a drag is symmetric: the direction-dependent part of a rig's base is what the efficiencies (load
    # proportional) and an axial force give; a direction drag on top would double the plausible drag one way
    explainers = [CANDIDATES[n] for n in ("coulomb_friction", "force_offset")
                  if n in CANDIDATES and n not in declared] + [EFFICIENCY_EXPLAINER]
    bounds, priors, sources, owner = {}, {}, {}, {}
    for e in explainers:
        for n in e.free:
            if n not in params:
                continue
            b, src = plaus[e.plausible[n]]
            if e.plausible[n] == "efficiency":
                v = params.value(n)
                lo, hi, centre = max(v - b, params[n].min), min(v + b, params[n].max), v
            elif params[n].min >= 0:
                lo, hi, centre = 0.0, b, 0.0
            else:
                lo, hi, centre = -b, b, 0.0
            bounds[n], priors[n], sources[n], owner[n] = (lo, hi), (centre, 0.5 * b), src, e.name
    effs = resolve_effects(None, add=list(declared) + [e.name for e in explainers if e.name in EFFECTS])
    plant = build_plant(None, effs, params=params)
    bounds = {n: b for n, b in bounds.items() if n in plant.parameters}
    pset = params.replace({n: priors[n][0] for n in bounds}).replace_parameters(
        {n: dataclasses.replace(params[n], value=priors[n][0], min=lo, max=hi) for n, (lo, hi) in bounds.items()})
    free = tuple(dict.fromkeys(tuple(uncertain) + tuple(bounds)))
    jb = job("base correction", effs, free, pset, fit_runs, prior=True)
    jb["settings"] = dataclasses.replace(jb["settings"], priors={n: priors[n] for n in bounds},
                                         no_prior=tuple(n for n in jb["settings"].no_prior if n not in bounds))
    f = _run_jobs([jb], 1, None)[0]
    doc = {"explainers": {n: {"effect": owner[n], "bound": list(bounds[n]), "bound_source": sources[n]}
                          for n in bounds}}
    if "error" in f:
        doc.update(accepted=False, reason=f"fit failed: {f['error']}")
        return {"accepted": False, "doc": doc}
    b0 = sum(_chi2_by_channel(first, noise, "holdout").values())
    b1 = sum(_chi2_by_channel(f, noise, "holdout").values())
    thr = float(chi2.ppf(1 - st.alpha, len(bounds)))
    corrections = []
    for n in bounds:
        e = f["estimates"][n]
        lo, hi = bounds[n]
        hit = _at_edge(e["value"], lo, hi)
        corrections.append({"effect": owner[n], "parameter": n, **_param_entry(e), "bound": [lo, hi],
                            "bound_source": sources[n], "at_plausible_bound": bool(hit),
                            "change": e["value"] - priors[n][0]})
    accepted = b0 - b1 > thr
    doc.update(accepted=bool(accepted), holdout_chi2_drop=b0 - b1, chi2_threshold=thr, corrections=corrections,
               error_before=_channel_errors(first), error_after=_channel_errors(f), effects=list(effs),
               fit_time_s=f["time_s"])
    say(f"base correction {'accepted' if accepted else 'not significant'}: held-out chi2 drop {b0 - b1:.4g} "
        f"(threshold {thr:.3g}); " + ", ".join(f"{c['parameter']} = {c['value']:.4g}" for c in corrections))
    return {"accepted": bool(accepted), "doc": doc, "fit": f, "effects": effs, "free": free,
            "priors": {n: priors[n] for n in bounds},
            "bounds": {n: (*bounds[n], owner[n]) for n in bounds if owner[n] in EFFECTS}}


def _at_edge(v: float, lo: float, hi: float) -> bool:
    edge = 0.02 * (hi - lo)
    return v >= hi - edge or (lo < 0 and v <= lo + edge)


def _explainers_at_bound(fit: dict, base_bounds: Mapping[str, tuple]) -> dict[str, str]:
    """Explainer parameter -> its effect, for the base corrections at their plausible bound in ``fit``."""
    return {n: eff for n, (lo, hi, eff) in base_bounds.items()
            if n in fit["estimates"] and _at_edge(fit["estimates"][n]["value"], lo, hi)}


def _null_runs(fit: dict, runs: Sequence[RigRun], noise: Mapping[str, float], seed: int) -> list[RigRun]:
    """The fitted model's own segment predictions plus white noise of the measured level, as runs."""
    rng = np.random.default_rng(seed)
    out = []
    for run in runs:
        p = fit["predictions"][run.name]
        sig = dict(run.signals)
        for c, y in p["simulated"].items():
            y = np.asarray(y, float)[:len(run.time)]
            sig[c] = y + noise[c] * rng.standard_normal(y.size)
        out.append(dataclasses.replace(run, signals=sig))
    return out


# ----------------------------------------------------------------------------- signature
def _signature(fit: dict, runs: Sequence[RigRun], params: ParameterSet, plant, s: SignatureSettings,
               noise: Mapping[str, float] | None = None) -> dict:
    inertia = plant.inertia(params)[1]  # the signature's missing torque at the motor shaft (what the current drives)
    torque: list = []
    vars_: dict = {}
    local_in: dict[str, list] = {"e": [], "x": [], "d": []}
    for run in runs:
        pr = fit["predictions"][run.name]
        n = len(run.time)
        meas, sim = pr["measured"], pr["simulated"]
        # the speed error at the motor shaft, by the rule of a run's motor speed
        e = motor_speed_from(lambda c: (np.asarray(meas[c]) - np.asarray(sim[c]))[:n] if c in meas else None,
                             run.gear_ratio)
        if e is None:
            continue
        t = np.asarray(run.time, float)
        starts = np.searchsorted(t, pr["segment_starts"])
        torque.append(missing_torque(t, e, starts, inertia, s.window))
        w = np.nan_to_num(measured_motor_speed(run))
        dt = np.r_[np.diff(t), 0.0]
        angle = np.r_[0.0, np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t))]
        load = np.asarray(run.signals["load_force"], float)
        dv = 0.05 * max(float(np.max(np.abs(w))), 1e-9)
        on = (np.asarray(run.signals["primary_enable"]) > 0.5) | (np.asarray(run.signals["standby_enable"]) > 0.5)
        if run.motor_disabled_when_cmd_zero:
            on &= np.asarray(run.signals["speed_cmd"]) != 0
        cols = {
            "quadrant": ("category", quadrant(w, load, (dv, max(0.02 * float(np.max(np.abs(load))), 1.0)))),
            "motor_on": ("category", on.astype(float)),
            "temperature": ("quantile", np.asarray(run.signals["temperature"], float)),
            "time_since_reversal": ("quantile", np.minimum(reversal_proximity(t, w, deadband=dv), 10.0)),
            "nut_position": ("position", np.asarray(run.signals["nut_position"], float)
                             if "nut_position" in run.source_columns else np.full(n, np.nan)),
            "motor_angle": ("angle", angle),
            "screw_angle": ("angle", angle / run.gear_ratio),
            "speed_sign": ("category", np.sign(np.where(np.abs(w) > dv, w, 0.0))),
            # a slow drift (a load cell zero, a warming motor) and a torque-constant error (torque against current)
            "time (slow drift)": ("linear", t),
            "motor_current (torque constant)": ("linear", np.asarray(run.signals["motor_current"], float)),
        }
        del dt
        for name, (kind, v) in cols.items():
            vars_.setdefault(name, (kind, []))[1].append(np.asarray(v, float))
        # the pass-replicated position test (runs separated by a gap that ends every pass)
        gap = np.full(100, np.nan)
        local_in["e"] += [torque[-1], gap]
        local_in["x"] += [cols["nut_position"][1], gap]
        local_in["d"] += [cols["speed_sign"][1], np.zeros(100)]
    if not torque:
        return {"missing_torque_rms": None, "tests": [], "sensors": []}
    e_all = np.concatenate(torque)
    variables = {n: (k, np.concatenate(v)) for n, (k, v) in vars_.items()}
    tests = signature_tests(e_all, variables, unit="N m", settings=s)
    loc = position_local_test(np.concatenate(local_in["e"]), np.concatenate(local_in["x"]),
                              np.concatenate(local_in["d"]), bin_width=s.position_bin, alpha=s.local_alpha)
    if loc is not None:
        loc["unit"] = "N m"
        tests.insert(0, loc) if loc["significant"] else tests.append(loc)
    sensors = []
    for run in runs:
        for d in sensor_consistency(run.time, {c: run.signals[c] for c in ("motor_speed", "screw_speed", "nut_position")
                                               if c in run.source_columns},
                                    gear_ratio=run.gear_ratio, lead=run.screw_lead, alpha=s.alpha):
            d["run"] = run.name
            sensors.append(d)
        on = (np.asarray(run.signals["primary_enable"]) > 0.5) | (np.asarray(run.signals["standby_enable"]) > 0.5)
        if run.motor_disabled_when_cmd_zero:
            on &= np.asarray(run.signals["speed_cmd"]) != 0
        co = current_offset_test(run.signals["motor_current"], ~on, alpha=s.alpha)
        if co is not None:
            co["run"] = run.name
            sensors.append(co)
    ok = np.isfinite(e_all)
    ratio = {c: math.sqrt(v / n) for c, (v, n) in _holdout_chi2_and_count(fit, noise or {}).items() if n > 0}
    return {"residual": "missing torque at the motor shaft, J d(speed residual)/dt", "unit": "N m",
            "reflected_inertia": inertia, "missing_torque_rms": float(np.sqrt(np.mean(e_all[ok] ** 2))),
            "residual_to_noise": ratio, "max_noise_ratio": s.max_noise_ratio,
            "tests": tests, "sensors": sensors, "curves": _signature_curves(e_all, variables, runs, s)}


def _holdout_chi2_and_count(fit: dict, noise: Mapping[str, float]) -> dict:
    """Per channel: the held-out noise-weighted squared error and its sample count."""
    out: dict = {}
    for p in fit["predictions"].values():
        hold = np.asarray(p["holdout"], bool)
        for c, y in p["measured"].items():
            if c not in noise or not noise[c] > 0:
                continue
            e = (np.asarray(y) - np.asarray(p["simulated"][c]))[:hold.size]
            m = hold[:e.size] & np.isfinite(e)
            a, n = out.get(c, (0.0, 0))
            out[c] = (a + float(np.sum((e[m] / noise[c]) ** 2)), n + int(m.sum()))
    return out


def _signature_curves(e: np.ndarray, variables: dict, runs, s: SignatureSettings) -> dict:
    """Binned residual against nut position and motor / screw angle, and the redundant sensors'
    cross-correlation: the data of the report's signature plots."""
    out: dict = {}
    x = variables["nut_position"][1]
    if np.isfinite(x).sum() > 50 and np.nanmax(x) - np.nanmin(x) >= 2 * s.position_bin:
        lo, hi = float(np.nanmin(x)), float(np.nanmax(x))
        out["nut_position"] = binned_mean(e, x, np.arange(lo, hi + s.position_bin, s.position_bin))
    for name in ("motor_angle", "screw_angle"):
        out[name] = binned_mean(e, np.mod(variables[name][1], 2 * math.pi), np.linspace(0, 2 * math.pi, 37))
    cc = {}
    for run in runs:
        t = np.asarray(run.time, float)
        dt = float(np.median(np.diff(t))) if t.size > 1 else 1.0
        sig = run.signals
        if "motor_speed" in run.source_columns and "screw_speed" in run.source_columns:
            cc[f"{run.name}: motor_speed vs gear_ratio x screw_speed"] = cross_correlation(
                sig["motor_speed"], run.gear_ratio * np.asarray(sig["screw_speed"], float), dt)
        if "motor_speed" in run.source_columns and "nut_position" in run.source_columns:
            x_ = np.asarray(sig["nut_position"], float)
            cc[f"{run.name}: LVDT rate vs lead/(2 pi N) x motor_speed"] = cross_correlation(
                np.r_[0.0, np.diff(x_)] / dt, kinematic_ratio({"screw.lead": run.screw_lead, "gear.ratio": run.gear_ratio})
                * np.asarray(sig["motor_speed"], float), dt)
    out["cross_correlation"] = cc
    return out


def _regime_errors(fit: dict, runs: Sequence[RigRun]) -> dict:
    """RMS of each channel's error per regime (aiding/opposing/unloaded, motor on/off, temperature band)."""
    by_run = {r.name: r for r in runs}
    regimes: dict[str, Callable] = {}

    def quad(r, label):
        run = by_run[r]
        w = np.nan_to_num(np.asarray(run.signals["speed_cmd"], float))
        load = np.asarray(run.signals["load_force"], float)
        q = quadrant(w, load, (0.05 * max(float(np.max(np.abs(w))), 1e-12), max(0.02 * float(np.max(np.abs(load))), 1.0)))
        return q == label

    for label, name in ((1, "opposing"), (-1, "aiding"), (0, "unloaded_or_stopped")):
        regimes[name] = lambda r, p, label=label: quad(r, label)[:len(p["holdout"])]
    for val, name in ((1, "motor_on"), (0, "motor_off")):
        def on(r, p, val=val):
            run = by_run[r]
            m = (np.asarray(run.signals["primary_enable"]) > 0.5) | (np.asarray(run.signals["standby_enable"]) > 0.5)
            if run.motor_disabled_when_cmd_zero:
                m &= np.asarray(run.signals["speed_cmd"]) != 0
            return (m if val else ~m)[:len(p["holdout"])]
        regimes[name] = on
    for lo, hi in ((-60, 0), (0, 40), (40, 80)):
        regimes[f"temperature_{lo}_{hi}C"] = lambda r, p, lo=lo, hi=hi: (
            (np.asarray(by_run[r].signals["temperature"]) >= lo) & (np.asarray(by_run[r].signals["temperature"]) < hi)
        )[:len(p["holdout"])]
    out = {}
    for name, fn in regimes.items():
        rms = _rms_by_channel(fit, fn)
        if any(math.isfinite(v) for v in rms.values()):
            out[name] = {c: (v if math.isfinite(v) else None) for c, v in rms.items()}
    return out


# ----------------------------------------------------------------------------- the tracer
def trace(runs: RigRun | Sequence[RigRun], level: str | None = "A", effects: Iterable[str] = (), *,
          remove: Iterable[str] = (), params: ParameterSet | None = None, settings: TraceSettings | None = None,
          progress: Callable[[str], None] | None = None) -> TraceResult:
    """Fit the declared model, then add library effects by forward selection while one is significant.

    Parameters
    ----------
    runs : RigRun or sequence of RigRun
        Need ``motor_current`` and a speed or position channel.  Their
        controller is not used (the replay is driven by the measured current),
        so any rig the parameter file describes can be traced.
    level, effects, remove : declared model (a plain screw drive: ``"A"``
        with ``remove=["noback_ideal"]``, or ``None`` with its effects)
    params : ParameterSet, optional
        Initial values, bounds and priors (default: the embedded actuator).
    settings : TraceSettings, optional
    progress : callable, optional
        ``progress(message)`` for each step and fit.

    Returns
    -------
    TraceResult
    """
    t_start = time.perf_counter()
    st = settings or TraceSettings()
    st.validate()
    limit_blas_threads(1)
    runs = [runs] if isinstance(runs, RigRun) else list(runs)
    if not runs:
        raise ThsaError("trace: no run given")
    names = [r.name for r in runs]
    if len(set(names)) != len(names):
        raise ThsaError(f"trace: runs must have distinct names, got {names}")
    params = params or default_parameters()
    say = progress or (lambda msg: None)
    declared = resolve_effects(level, add=effects, remove=remove)
    lvl = (level or "A").upper()
    uncertain = tuple(st.uncertain) if st.uncertain is not None else DEFAULT_UNCERTAIN.get(lvl, DEFAULT_UNCERTAIN["A"])
    base_plant = build_plant(None, declared, params=params)

    def plant_of(effects, p):
        """The plant of an effect set (the declared one is built once)."""
        return base_plant if tuple(effects) == tuple(declared) else build_plant(None, effects, params=p)

    uncertain = tuple(n for n in uncertain if n in base_plant.parameters)
    # the replay is current-driven: the rig's controller plays no part (and need not be one we model)
    fit_runs = [dataclasses.replace(r, controller=None) for r in runs]
    channels = tuple(c for c in ("motor_speed", "nut_position", "screw_speed")
                     if any(c in r.source_columns for r in runs))
    noise = {c: float(np.mean([estimate_noise(r.signals[c]) for r in runs if c in r.source_columns]))
             for c in channels}

    def id_settings(prior: bool = True, no_prior=(), priors=None) -> IdentificationSettings:
        return IdentificationSettings(no_prior=tuple(no_prior), segment_duration=st.segment_duration, substeps=st.substeps, channels=channels,
                                      noise=noise, max_nfev=st.max_nfev, tolerance=st.tolerance, time_budget=st.fit_time_budget,
                                      prior_relative_sd=st.prior_relative_sd if prior else None,
                                      holdout_every=st.holdout_every, priors=dict(priors or {}) or None)

    plaus = {k: fn(params, runs) for k, fn in PLAUSIBLE.items()}
    base_priors: dict[str, tuple[float, float]] = {}  # the base corrections' priors (kept in every later fit)

    def job(label, effs, free, pset, data, prior=True, profile=None, spec=None, lift=()):
        # priors on the declared uncertain parameters and the base corrections only: a candidate's values are seeds
        pri = {n: v for n, v in base_priors.items() if n in free and n not in lift}
        judge = {}
        if spec is not None and not profile:
            for n in spec.free:
                if n in uncertain or n in base_priors:
                    continue
                ref = max(abs(params.value(n)), abs(spec.seeds.get(n, 0.0)),
                          plaus[spec.plausible[n]][0] if n in spec.plausible else 0.0)
                judge[n] = ref if ref > 0 else 0.01 * (params[n].max - params[n].min)
        return {"label": label, "effects": tuple(effs), "free": tuple(free), "params_toml": pset.to_toml(),
                "settings": id_settings(prior, [n for n in free if n not in uncertain and n not in pri], pri),
                "runs": data, "profile": dict(profile or {}), "judge": judge,
                "hold_at": {n: params.value(n) for n in judge}, "relative_stderr": st.undetermined_relative_stderr}

    say(f"fitting the declared model ({', '.join(declared) or 'level A'}): {', '.join(uncertain)}")
    t0 = time.perf_counter()
    base = _run_jobs([job("base", declared, uncertain, params, fit_runs)], 1, None)[0]
    if "error" in base:
        raise ThsaError(f"trace: the declared model cannot be fitted: {base['error']}")
    base_fit_time = time.perf_counter() - t0
    say(f"base fit: {base_fit_time:.1f} s")
    first = base
    current, cur_effects, cur_params, cur_free = base, declared, ParameterSet.from_toml(base["params_toml"]), uncertain
    added, rounds, cand_times, ambiguous = [], [], [], []
    use_base = st.base_corrections if st.base_corrections is not None else st.candidates is None
    base_doc = None
    at_plausible_bound: dict[str, str] = {}  # explainer parameter -> its effect, where the base correction hit the bound
    base_bounds: dict[str, tuple[float, float, str]] = {}  # explainer parameter -> (lo, hi, effect) while bounded
    if use_base:
        say("base-correction step: constant-torque explainers and screw efficiencies within plausible magnitudes")
        bc = _base_correction(first, declared, uncertain, params, plaus, fit_runs, noise, st, job, say)
        base_doc = bc["doc"]
        if bc["accepted"]:
            base_priors.update(bc["priors"])
            current, cur_effects = bc["fit"], tuple(bc["effects"])
            cur_params = ParameterSet.from_toml(current["params_toml"])
            cur_free = tuple(bc["free"])
            base_bounds = bc["bounds"]
            at_plausible_bound = _explainers_at_bound(current, base_bounds)
            base_doc["signature_after"] = _signature_brief(
                _signature(current, runs, cur_params, plant_of(cur_effects, cur_params), st.signature, noise))
    windows_cache = {spec: {r.name: _window(spec, r, params) for r in runs} for spec in WINDOWS}
    hurt: set[str] = set()
    while sum(1 for e in added if "implied_by" not in e) < st.max_effects:
        specs = candidate_specs(cur_effects, cur_params, st.candidates)
        # a base correction that ran to its plausible bound: the same effect, larger than a rig's base can be,
        # is a candidate of its own (its bound lifted to the parameter file's)
        specs += [dataclasses.replace(CANDIDATES[e], base_correction=False)
                  for e in dict.fromkeys(at_plausible_bound.values()) if e in CANDIDATES]
        scorable, skipped = [], []
        for spec in specs:
            win = windows_cache[spec.window]
            if sum(int(w.sum()) for w in win.values()) < 50:
                skipped.append({"name": spec.name, "reason": f"does not act on these runs (window '{spec.window}' empty)"})
            elif spec.name in hurt:
                skipped.append({"name": spec.name, "reason": f"made the held-out error worse in round {len(rounds)}"})
            else:
                scorable.append(spec)
        if not scorable:
            break
        # the longest fits first, so that the workers finish together (profiled, then the structural effects)
        scorable.sort(key=lambda sp: (not sp.profile, sp.base_correction, -len(sp.free)))
        jobs = []
        for spec in scorable:
            lift = tuple(n for n in spec.free if n in at_plausible_bound)
            if lift:  # beyond its base correction
                effs = cur_effects
                pset = cur_params.replace_parameters({n: dataclasses.replace(cur_params[n], min=params[n].min,
                                                                             max=params[n].max) for n in lift})
                jobs.append(job(spec.name, effs, cur_free, pset, fit_runs, lift=lift))
                continue
            req = [r for r in EFFECTS[spec.name].requires if r not in cur_effects]
            replaced = {x for e in req + [spec.name] for x in EFFECTS[e].supersedes}
            effs = resolve_effects(None, add=[e for e in cur_effects if e not in replaced] + req + [spec.name])
            pset = cur_params.replace({n: v for n, v in spec.seeds.items() if cur_params.value(n) == 0})
            if spec.profile:
                # a switch the model lacks distorts the declared fit (a missing pawl clearance drives the
                # retraction disk friction to 0): a profiled candidate restarts the declared parameters, and
                # centres their priors, at the parameter file's values
                pset = pset.replace({n: params.value(n) for n in uncertain})
            free = tuple(dict.fromkeys(cur_free + spec.free))
            jobs.append(job(spec.name, effs, free, pset, fit_runs, profile=spec.profile, spec=spec))
        say(f"round {len(rounds) + 1}: scoring {len(jobs)} candidates ({', '.join(s.name for s in scorable)})")
        fits = _run_jobs(jobs, st.workers, say)
        base_hold = _chi2_by_channel(current, noise, "holdout")
        scored = []
        for spec, f, jb in zip(scorable, fits, jobs):
            if "error" in f:
                scored.append({"name": spec.name, "error": f["error"], "significant": False, "score": None,
                               "error_reduction": {}})
                continue
            cand_times.append(f["time_s"])
            hold = _chi2_by_channel(f, noise, "holdout")
            drop = sum(base_hold.values()) - sum(hold.values())
            k = len(spec.free) + len(spec.profile)
            from scipy.stats import chi2

            thr = float(chi2.ppf(1 - st.alpha, k))
            win = windows_cache[spec.window]
            wb = _chi2_by_channel(current, noise, "holdout", win)
            wc = _chi2_by_channel(f, noise, "holdout", win)
            win_red = {c: (1 - math.sqrt(wc[c] / wb[c])) if wb.get(c, 0) > 0 else 0.0 for c in wc}
            rms_b, rms_c = _rms_by_channel(current), _rms_by_channel(f)
            err_red = {c: (1 - rms_c[c] / rms_b[c]) if rms_b[c] > 0 else 0.0 for c in rms_c}
            plausible, why = _plausibility(f, spec, plaus)
            if win_red.get(spec.channel, 0.0) < -st.max_channel_increase:
                plausible = False
                why.append(f"{spec.channel} error grows by {-win_red[spec.channel]:.0%}")
            prelim = drop > thr and max(win_red.values(), default=0.0) >= st.min_window_reduction and plausible
            scored.append({
                "name": spec.name, "score": drop / max(sum(base_hold.values()), 1e-300), "holdout_chi2_drop": drop,
                "chi2_threshold": thr, "error_reduction": err_red, "window": spec.window, "window_reduction": win_red,
                "aic_drop": current["aic"] - f["aic"], "bic_drop": current["bic"] - f["bic"],
                "plausible": plausible, "implausible_because": why, "parameters": _params_out(f, spec),
                "fit_time_s": f["time_s"], "converged": f["converged"], "prelim": prelim, "_fit": f, "_job": jb,
                "not_determined": _held_out(f),
                **({"beyond_base_correction": True} if any(n in at_plausible_bound for n in spec.free) else {}),
                **({"profile": f["profile"]} if f.get("profile") else {}),
                "_noise": noise,
                "_spec": spec,
            })
        # calibrate the promising ones on a null run of the current model (same inputs, its own noise)
        # calibrate the promising ones on a null run, strongest first, a batch (one per worker, the strongest
        # physical one included) at a time until one passes: the weaker ones are not needed then
        promising = sorted([s for s in scored if s.get("prelim")], key=lambda s: -s["holdout_chi2_drop"])
        if promising:
            null = _null_runs(current, fit_runs, noise, st.seed + len(rounds))
            null_base = _run_jobs([job("null base", cur_effects, cur_free, cur_params, null)], 1, None)[0]
            nb = sum(_chi2_by_channel(null_base, noise, "holdout").values()) if "error" not in null_base else math.nan
            todo = list(promising)

            def calibrate(batch, null=null, nb=nb):
                say(f"calibrating {', '.join(c['name'] for c in batch)} on a null run")
                null_fits = _run_jobs([{**c["_job"], "label": f"null {c['name']}", "runs": null,
                                        "free": tuple(c["_fit"]["free"]), "judge": {},
                                        "params_toml": _held_params(c["_job"]["params_toml"], c["_fit"])}
                                       for c in batch], st.workers, say)
                for c, nf in zip(batch, null_fits):
                    nd = (nb - sum(_chi2_by_channel(nf, noise, "holdout").values())) if "error" not in nf else math.nan
                    c["null_chi2_drop"] = nd
                return [c for c in batch if math.isfinite(c["null_chi2_drop"]) and c["holdout_chi2_drop"]
                        > st.null_factor * max(c["null_chi2_drop"], 0.0)]

            while todo:
                batch = todo[:max(st.workers, 2)]
                phys = next((c for c in todo if not _is_explainer(c)), None)
                if phys is not None and phys not in batch:
                    batch.append(phys)
                todo = [c for c in todo if c not in batch]
                passed = calibrate(batch)
                if passed:
                    # the ones the data cannot tell from the strongest that passed are calibrated too: the
                    # ambiguity rule reports them with their significance
                    top = max(passed, key=lambda c: c["holdout_chi2_drop"])
                    _rivals(top, [], st.alpha)
                    near = [c for c in todo if top["holdout_chi2_drop"] - c["holdout_chi2_drop"]
                            < top["_indistinct_below"]]
                    if near:
                        calibrate(near)
                    todo = [c for c in todo if c not in near]
                    break
            for c in todo:
                c["not_calibrated"] = "a stronger candidate passed its null calibration"
        for s in scored:
            if "error" in s:
                continue
            nd = s.get("null_chi2_drop")
            s["significant"] = bool(s["prelim"] and nd is not None and math.isfinite(nd)
                                    and s["holdout_chi2_drop"] > st.null_factor * max(nd, 0.0))
        scored.sort(key=lambda s: -(s.get("holdout_chi2_drop") or -math.inf))
        # a candidate that made the held-out error worse is not fitted again in the next round
        hurt = {c["name"] for c in scored if "error" not in c and c["holdout_chi2_drop"] < 0}
        rounds.append({"round": len(rounds) + 1, "model": list(cur_effects), "skipped": skipped,
                       "candidates": [_public(s) for s in scored]})
        best = next((s for s in scored if s.get("significant")), None)
        if best is None:
            say("no candidate is significant: stop")
            break
        best, yielded = _physical_first(best, scored, st.window_tolerance, current, noise, windows_cache)
        if yielded:
            rounds[-1]["physical_first"] = {"chosen": best["name"], "over": yielded}
            say(f"{best['name']} explains as much inside its window as the constant-torque "
                f"{', '.join(yielded)}: the physical effect comes first")
        rivals = _rivals(best, [s for s in scored if s["name"] not in yielded], st.alpha)
        if rivals:
            names_amb = [best["name"]] + [r["name"] for r in rivals]
            rounds[-1]["ambiguous"] = names_amb
            ambiguous.append({"round": len(rounds), "candidates": names_amb,
                              "holdout_chi2_drop": {s["name"]: s["holdout_chi2_drop"] for s in [best, *rivals]},
                              "indistinct_below": best["_indistinct_below"]})
            say(f"{', '.join(names_amb)} explain the same part of the residual (held-out chi2 drops within "
                f"{best['_indistinct_below']:.3g}): none is named; stop")
            break
        say(f"added {best['name']}: held-out chi2 drop {best['holdout_chi2_drop']:.4g} "
            f"(null {best.get('null_chi2_drop', float('nan')):.3g})")
        f = best["_fit"]
        step = {"name": best["name"], "parameters": best["parameters"], "error_reduction": best["error_reduction"],
                "aic_drop": best["aic_drop"], "bic_drop": best["bic_drop"], "score": best["score"],
                "window": best["window"], "window_reduction": best["window_reduction"],
                "holdout_chi2_drop": best["holdout_chi2_drop"],
                "error_before": _channel_errors(current), "error_after": _channel_errors(f),
                "segments_explained": _explained_regimes(current, f, runs),
                "not_determined": best["not_determined"],
                **({"beyond_base_correction": True} if best.get("beyond_base_correction") else {}),
                **({"profile": best["profile"]} if best.get("profile") else {})}
        refines = [x for x in EFFECTS[best["name"]].supersedes if x in cur_effects]
        if refines:  # a detailed model of a declared component (the rig's no-back for the level's ideal one)
            step["refines_declared"] = refines
        added.append(step)
        # effects the added one needs come with it (noback_backlash pulls in noback_quadrant_friction)
        for r in best["_job"]["effects"]:
            if r not in cur_effects and r != best["name"]:
                spec_r = CANDIDATES.get(r)
                names_r = (spec_r.free if spec_r else ()) or tuple(EFFECTS[r].parameters)
                added.append({"name": r, "implied_by": best["name"],
                              "parameters": {n: _param_entry(f["estimates"][n]) for n in names_r
                                             if n in f["estimates"]},
                              "held_at_file_values": [n for n in names_r if n not in f["estimates"]],
                              "error_reduction": best["error_reduction"], "window": best["window"],
                              "window_reduction": best["window_reduction"],
                              "error_before": step["error_before"], "error_after": step["error_after"],
                              "not_determined": [], "aic_drop": None, "bic_drop": None, "score": None})
        current, cur_effects = f, tuple(best["_job"]["effects"])
        cur_params = ParameterSet.from_toml(f["params_toml"])
        cur_free = tuple(f["free"])
        # the explainers still bounded are re-judged on the new fit: one at its bound is offered beyond it
        lifted = set(best["_spec"].free) if best.get("beyond_base_correction") else set()
        base_bounds = {n: b for n, b in base_bounds.items() if n not in lifted}
        at_plausible_bound = _explainers_at_bound(f, base_bounds)
        rounds[-1]["signature_after"] = _signature_brief(
            _signature(current, runs, cur_params, plant_of(cur_effects, cur_params), st.signature, noise))
    sig_before = _signature(first, runs, ParameterSet.from_toml(first["params_toml"]), base_plant, st.signature, noise)
    sig_after = _signature(current, runs, cur_params, plant_of(cur_effects, cur_params), st.signature, noise)
    structured = [t for t in sig_after["tests"] + sig_after["sensors"] if t["significant"]]
    structured += [{"variable": f"held-out residual above noise ({c}: {r:.2g} x)"}
                   for c, r in sig_after.get("residual_to_noise", {}).items() if r > st.signature.max_noise_ratio]
    doc = {
        "format": TRACE_FORMAT,
        "datasets": [{"name": r.name, "csv": str(r.csv_path), "samples": int(len(r.time)),
                      "duration_s": r.duration_s} for r in runs],
        "base_model": lvl if level is not None else None,
        "removed_effects": list(remove),
        "declared_effects": list(declared),
        "final_effects": list(cur_effects),
        "uncertain_parameters": list(uncertain),
        "base_parameters": {n: v for n, v in first["estimates"].items()},
        "effects_added": added,
        "found_effects": [e["name"] for e in added],
        "base_corrections": base_doc,
        "error_before": _channel_errors(first),
        "error_after": _channel_errors(current),
        "error_by_regime_before": _regime_errors(first, runs),
        "error_by_regime_after": _regime_errors(current, runs),
        "unexplained": bool(structured),
        "ambiguous": ambiguous,
        "residual_signature": {**sig_after, "structured": [t["variable"] for t in structured]},
        "residual_signature_before": sig_before,
        "candidates": rounds[0]["candidates"] if rounds else [],
        "rounds": rounds,
        "noise_rms": noise,
        "settings": _settings_dict(st),
        "timing": {"base_fit_s": base_fit_time, "candidate_fit_s": (float(np.median(cand_times)) if cand_times else None),
                   "total_s": time.perf_counter() - t_start},
    }
    return TraceResult(doc, {"before": first, "after": current})


def _is_explainer(s: dict) -> bool:
    return bool(s.get("_spec") is not None and CANDIDATES.get(s["name"]) is not None
                and CANDIDATES[s["name"]].base_correction)


def _physical_first(best: dict, scored: list[dict], tol: float, current: dict, noise, windows_cache: dict
                    ) -> tuple[dict, list[str]]:
    """Order by what is explained: when the best held-out drop is a constant-torque explainer's (a Coulomb or
    direction drag, an axial force) and a significant physical effect explains as much of the residual inside
    its own window, on its own channel (held-out RMS drop there at least the explainer's there, less ``tol``),
    the physical effect comes first; the explainers that yielded to it are returned (they are scored again in
    the next round).  On one load a no-back's aiding-quadrant friction is a direction drag; only the no-back
    says why."""
    if not _is_explainer(best):
        return best, []
    phys = [s for s in scored if s.get("significant") and not _is_explainer(s)]
    if not phys:
        return best, []
    p = max(phys, key=lambda s: s["holdout_chi2_drop"])
    spec = p["_spec"]
    win = windows_cache[spec.window]
    base = _chi2_by_channel(current, noise, "holdout", win).get(spec.channel, 0.0)
    if not base > 0:
        return best, []

    def red(s):
        return 1 - math.sqrt(_chi2_by_channel(s["_fit"], noise, "holdout", win).get(spec.channel, base) / base)

    if red(p) < red(best) - tol:
        return best, []
    return p, [s["name"] for s in scored if s.get("significant") and _is_explainer(s)
               and s["holdout_chi2_drop"] >= p["holdout_chi2_drop"]]


def _rivals(best: dict, scored: list[dict], alpha: float) -> list[dict]:
    """Plausible candidates whose held-out drop the data cannot tell from the best one's.

    Two fits differ by more than noise when their held-out chi2 differ by more
    than the ``chi2(1)`` quantile at ``alpha``, scaled by the best fit's reduced
    held-out chi2 when that exceeds 1 (the unmodelled part of the residual
    inflates every difference; a quasi-likelihood scaling).  On one speed and
    one load, for example, a constant force offset, a Coulomb friction and a
    direction-dependent friction are the same constant torque.
    """
    from scipy.stats import chi2

    hold = sum(_chi2_by_channel(best["_fit"], best["_noise"], "holdout").values())
    n = _holdout_samples(best["_fit"])
    gap = float(chi2.ppf(1 - alpha, 1)) * max(1.0, hold / max(n, 1))
    best["_indistinct_below"] = gap
    return [s for s in scored if s is not best and "error" not in s and s["plausible"]
            and best["holdout_chi2_drop"] - s["holdout_chi2_drop"] < gap]


def _holdout_samples(fit: dict) -> int:
    """Number of finite held-out samples over all channels of a fit."""
    n = 0
    for p in fit["predictions"].values():
        hold = np.asarray(p["holdout"], bool)
        for c, y in p["measured"].items():
            n += int(np.sum(hold & np.isfinite(np.asarray(y) - np.asarray(p["simulated"][c]))[:hold.size]))
    return n


def _params_out(f: dict, spec: CandidateSpec) -> dict:
    return {n: _param_entry(f["estimates"][n]) for n in (*spec.free, *spec.profile) if n in f["estimates"]}


def _explained_regimes(before: dict, after: dict, runs) -> dict:
    b, a = _regime_errors(before, runs), _regime_errors(after, runs)
    out = {}
    for reg, chans in b.items():
        for c, v in chans.items():
            w = a.get(reg, {}).get(c)
            if v and w is not None:
                out.setdefault(reg, {})[c] = 1 - w / v
    return out


def _public(s: dict) -> dict:
    return {k: v for k, v in s.items() if not k.startswith("_") and k != "prelim"}


def _settings_dict(st: TraceSettings) -> dict:
    d = {}
    for k, v in dataclasses.asdict(st).items():
        d[k] = list(v) if isinstance(v, tuple) else v
    return d
