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
from ..model.params import ParameterSet, default_parameters
from .threads import limit_blas_threads
from .signature import SignatureSettings, missing_torque, sensor_consistency, signature_tests

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


def _window(kind: str, run: RigRun) -> np.ndarray:
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
    if kind == "cold":
        temp = np.asarray(s["temperature"], float)
        return np.abs(temp - 25.0) > 5.0
    raise ValueError(f"unknown window {kind!r}")


# ----------------------------------------------------------------------------- fits (run in workers)
def _fit_job(job: dict) -> dict:
    """One identification, summarised (picklable in and out)."""
    t0 = time.perf_counter()
    limit_blas_threads(1)
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
    return {"label": job["label"], "effects": list(res.effects), "free": list(job["free"]), "estimates": est,
            "aic": res.aic, "bic": res.bic, "chisqr": res.chisqr, "nfev": res.nfev, "converged": res.converged,
            "status": res.status, "time_s": time.perf_counter() - t0, "predictions": preds,
            "params_toml": res.to_parameter_set().to_toml(), "profile": prof.to_dict() if prof is not None else None}


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


def _plausibility(fit: dict, spec: CandidateSpec) -> tuple[bool, list[str]]:
    """Plausible: no parameter at a bound, none collapsing to zero, at least one determined by the data.

    A parameter the runs do not excite (undetermined: e.g. the retraction friction of a run that only
    extends) stays near its file value and does not disqualify the candidate.
    """
    why, determined = [], 0
    est = [(n, fit["estimates"][n]) for n in spec.free if n in fit["estimates"]]
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
    if (est or spec.profile) and determined == 0:
        why.append("no parameter determined by the data")
    return not why, why


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
def _signature(fit: dict, runs: Sequence[RigRun], params: ParameterSet, plant, s: SignatureSettings) -> dict:
    inertia = plant.inertia(params)[1]  # the signature's missing torque at the motor shaft (what the current drives)
    torque: list = []
    vars_: dict = {}
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
        }
        del dt
        for name, (kind, v) in cols.items():
            vars_.setdefault(name, (kind, []))[1].append(np.asarray(v, float))
    if not torque:
        return {"missing_torque_rms": None, "tests": [], "sensors": []}
    e_all = np.concatenate(torque)
    variables = {n: (k, np.concatenate(v)) for n, (k, v) in vars_.items()}
    tests = signature_tests(e_all, variables, unit="N m", settings=s)
    sensors = []
    for run in runs:
        for d in sensor_consistency(run.time, {c: run.signals[c] for c in ("motor_speed", "screw_speed", "nut_position")
                                               if c in run.source_columns},
                                    gear_ratio=run.gear_ratio, lead=run.screw_lead, alpha=s.alpha):
            d["run"] = run.name
            sensors.append(d)
    ok = np.isfinite(e_all)
    return {"residual": "missing torque at the motor shaft, J d(speed residual)/dt", "unit": "N m",
            "reflected_inertia": inertia, "missing_torque_rms": float(np.sqrt(np.mean(e_all[ok] ** 2))),
            "tests": tests, "sensors": sensors}


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
    uncertain = tuple(n for n in uncertain if n in base_plant.parameters)
    # the replay is current-driven: the rig's controller plays no part (and need not be one we model)
    fit_runs = [dataclasses.replace(r, controller=None) for r in runs]
    channels = tuple(c for c in ("motor_speed", "nut_position", "screw_speed")
                     if any(c in r.source_columns for r in runs))
    noise = {c: float(np.mean([estimate_noise(r.signals[c]) for r in runs if c in r.source_columns]))
             for c in channels}

    def id_settings(prior: bool = True, no_prior=()) -> IdentificationSettings:
        return IdentificationSettings(no_prior=tuple(no_prior), segment_duration=st.segment_duration, substeps=st.substeps, channels=channels,
                                      noise=noise, max_nfev=st.max_nfev, tolerance=st.tolerance, time_budget=st.fit_time_budget,
                                      prior_relative_sd=st.prior_relative_sd if prior else None,
                                      holdout_every=st.holdout_every)

    def job(label, effs, free, pset, data, prior=True, profile=None):
        # priors on the declared uncertain parameters only: a candidate's values are seeds
        return {"label": label, "effects": tuple(effs), "free": tuple(free), "params_toml": pset.to_toml(),
                "settings": id_settings(prior, [n for n in free if n not in uncertain]), "runs": data,
                "profile": dict(profile or {})}

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
    windows_cache = {spec: {r.name: _window(spec, r) for r in runs}
                     for spec in ("moving", "all", "loaded", "reversal", "reversal_or_stop", "cold")}
    while len(added) < st.max_effects:
        specs = candidate_specs(cur_effects, cur_params, st.candidates)
        scorable, skipped = [], []
        for spec in specs:
            win = windows_cache[spec.window]
            if sum(int(w.sum()) for w in win.values()) < 50:
                skipped.append({"name": spec.name, "reason": f"does not act on these runs (window '{spec.window}' empty)"})
            else:
                scorable.append(spec)
        if not scorable:
            break
        jobs = []
        for spec in scorable:
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
            jobs.append(job(spec.name, effs, free, pset, fit_runs, profile=spec.profile))
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
            plausible, why = _plausibility(f, spec)
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
                **({"profile": f["profile"]} if f.get("profile") else {}),
                "_noise": noise,
                "_spec": spec,
            })
        # calibrate the promising ones on a null run of the current model (same inputs, its own noise)
        promising = [s for s in scored if s.get("prelim")]
        if promising:
            null = _null_runs(current, fit_runs, noise, st.seed + len(rounds))
            say(f"calibrating {len(promising)} candidate(s) on a null run")
            null_base = _run_jobs([job("null base", cur_effects, cur_free, cur_params, null)], 1, None)[0]
            null_fits = _run_jobs([job(f"null {s['name']}", s["_job"]["effects"], s["_job"]["free"],
                                       ParameterSet.from_toml(s["_job"]["params_toml"]), null,
                                       profile=s["_job"]["profile"]) for s in promising],
                                  st.workers, say)
            nb = sum(_chi2_by_channel(null_base, noise, "holdout").values()) if "error" not in null_base else math.nan
            for s, nf in zip(promising, null_fits):
                nd = (nb - sum(_chi2_by_channel(nf, noise, "holdout").values())) if "error" not in nf else math.nan
                s["null_chi2_drop"] = nd
        for s in scored:
            if "error" in s:
                continue
            nd = s.get("null_chi2_drop")
            s["significant"] = bool(s["prelim"] and nd is not None and math.isfinite(nd)
                                    and s["holdout_chi2_drop"] > st.null_factor * max(nd, 0.0))
        scored.sort(key=lambda s: -(s.get("holdout_chi2_drop") or -math.inf))
        rounds.append({"round": len(rounds) + 1, "model": list(cur_effects), "skipped": skipped,
                       "candidates": [_public(s) for s in scored]})
        best = next((s for s in scored if s.get("significant")), None)
        if best is None:
            say("no candidate is significant: stop")
            break
        rivals = _rivals(best, scored, st.alpha)
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
        added.append({"name": best["name"], "parameters": best["parameters"], "error_reduction": best["error_reduction"],
                      "aic_drop": best["aic_drop"], "bic_drop": best["bic_drop"], "score": best["score"],
                      "window": best["window"], "window_reduction": best["window_reduction"],
                      "error_before": _channel_errors(current), "error_after": _channel_errors(f),
                      "segments_explained": _explained_regimes(current, f, runs),
                      **({"profile": best["profile"]} if best.get("profile") else {})})
        current, cur_effects = f, tuple(best["_job"]["effects"])
        cur_params = ParameterSet.from_toml(f["params_toml"])
        cur_free = tuple(best["_job"]["free"])
    sig_before = _signature(first, runs, ParameterSet.from_toml(first["params_toml"]), base_plant, st.signature)
    final_plant = base_plant if tuple(cur_effects) == tuple(declared) else build_plant(None, cur_effects, params=cur_params)
    sig_after = _signature(current, runs, cur_params, final_plant, st.signature)
    structured = [t for t in sig_after["tests"] + sig_after["sensors"] if t["significant"]]
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
    out = {}
    for n in (*spec.free, *spec.profile):
        e = f["estimates"].get(n)
        if e is None:
            continue
        sd = e["stderr"]
        ci = [e["value"] - 1.96 * sd, e["value"] + 1.96 * sd] if sd is not None else e.get("interval")
        out[n] = {"value": e["value"], "stderr": sd, "unit": e["unit"], "ci95": list(ci) if ci else None,
                  "at_bound": e["at_bound"], **({"profiled": True} if e.get("profiled") else {})}
    return out


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
