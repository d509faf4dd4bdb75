"""Backward check after forward selection, and the order of the kept effects by what each explains (numerics only).

Forward selection adds, each round, the candidate with the largest held-out drop *given the model of that round*.
An effect added early may have won its round partly on the residual of an effect added later (on rig-sim's
drive-train compliance run the rig base's load path came first, on a speed excitation whose null adds nothing).
So after each round that adds an effect every earlier found effect is judged again *given the later ones*: taken
out (with the effects it implied, the declared ones it replaced restored, a lifted base correction bounded
again), the model refitted from the current values (a warm start; a model fitted before is reused), and the
criterion that admitted it applied to what it still explains: the held-out chi2 drop against the ``chi2(k)``
quantile and ``null_factor`` times the drop it buys on a null run of the model without it, the window RMS drop,
its own channel not worse, the training samples' AIC, its parameters determined and not collapsing to zero, a
constant torque improving most held-out segments of its window.  One that no longer earns its place is removed
(the weakest first, then the others are judged again) and not offered again.  Base-step content (the base
corrections, the declared component detailed) is not judged: it is what the base contains.

The kept found effects are then reported in the order of what each explains given all the others: its
leave-one-out held-out chi2 drop, noise-weighted (so that channels add), over *all* held-out samples.  Not over the
samples its admission was scored on: those differ by window (a candidate acting everywhere is scored outside the
base's transients, one acting at load changes or reversals on every sample), and sums of squared errors over
different sample sets do not compare (measured on rig_drivetrain_compliance: the load path's leave-one-out drop
3026 on all samples, the drive-train compliance's 964 outside the transients and 5446 on all samples; a speed
chirp is mostly "transient" by the speed-change rule).  Both drops are reported.

Nothing here fits by itself: the engine passes ``fit_jobs(jobs) -> fits`` and ``make_job``; nothing draws.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

from ..model import EFFECTS, CandidateSpec, build_plant, resolve_effects
from ..model.params import ParameterSet
from .scoring import (
    PAIR_CANDIDATES,
    _null_runs,
    admission_tests,
    beats_null,
    determination,
    null_drop,
    pair_amplitude_zero,
)

#: how the kept effects are ordered (trace.json ``order.measure``)
ORDER_MEASURE = ("leave-one-out held-out chi2 drop over all held-out samples: the rise of the noise-weighted held-out "
                 "squared error when the effect is taken out of the final model and the model refitted, i.e. what it "
                 "explains given all the other kept effects, summed over one sample set for every effect")


@dataclass
class Added:
    """Bookkeeping of one found effect (not written to trace.json)."""

    name: str
    spec: CandidateSpec
    round: int
    job: dict  # the job that admitted it (its judge: reference magnitudes of its parameters)
    k: int  # parameters counted in its chi2(k) test
    drop_when_added: float  # its held-out chi2 drop where it was scored (its round's ranking)
    drop_when_added_all: float = math.nan  # the same over all held-out samples
    replaced: tuple[str, ...] = ()  # effects its addition took out of the model (a declared idealised one)
    implied: tuple[str, ...] = ()  # effects it pulled in
    rebound: dict = field(default_factory=dict)  # beyond a base correction: parameter -> its plausible (lo, hi)
    beyond_base: bool = False
    freed: tuple[str, ...] = ()  # parameters freed with it (its own, its implied effects', declared references)


def reduced_model(a: Added, cur_effects, cur_free, cur_params: ParameterSet):
    """The model without ``a``: (effects, free parameters, parameter set).  Its implied effects go with it unless
    another kept effect needs them; what it replaced comes back unless a kept effect supersedes it; a lifted base
    correction gets its plausible bound back (value clipped into it)."""
    if a.beyond_base:
        pset = cur_params.replace_parameters({n: _bounded(cur_params[n], lo, hi) for n, (lo, hi) in a.rebound.items()})
        return tuple(cur_effects), tuple(cur_free), pset
    others = [e for e in cur_effects if e != a.name]
    needed = {r for e in others if e not in a.implied for r in EFFECTS[e].requires}
    drop = {a.name} | {i for i in a.implied if i not in needed}
    keep = [e for e in cur_effects if e not in drop]
    superseded = {x for e in keep for x in EFFECTS[e].supersedes}
    restore = [r for r in a.replaced if r not in keep and r not in superseded]
    effs = resolve_effects(None, add=keep + restore)
    plant = build_plant(None, effs, params=cur_params)
    stays = {n for i in a.implied if i in keep for n in EFFECTS[i].parameters}  # an implied effect another needs
    free = tuple(n for n in cur_free if n in plant.parameters and (n not in a.freed or n in stays))
    return effs, free, cur_params


def _bounded(p, lo, hi):
    import dataclasses

    return dataclasses.replace(p, value=min(max(p.value, lo), hi), min=lo, max=hi)


def model_key(effects, free, pset: ParameterSet) -> tuple:
    """A fitted model's identity: its effects, free parameters and their bounds (a lifted base correction)."""
    return (tuple(sorted(effects)), tuple(sorted(free)),
            tuple((n, pset[n].min, pset[n].max) for n in sorted(free) if n in pset))


def judge_removal(a: Added, full: dict, reduced: dict, *, noise, mask, window_mask, alpha: float,
                  min_window_reduction: float, max_channel_increase: float, z: float, robust: bool,
                  robust_test: str = "signed-rank") -> dict:
    """The admission criterion of ``a``, given the others: ``full`` (the current fit) against ``reduced`` (the
    fit without it).  Returns the record (before the null calibration); ``prelim`` says whether it passes the
    tests that need no null run."""
    spec = a.spec
    adm = admission_tests(reduced, full, noise, k=a.k, alpha=alpha, mask=mask, window=window_mask,
                          channel=spec.channel, min_window_reduction=min_window_reduction,
                          max_channel_increase=max_channel_increase, robust=robust, robust_test=robust_test,
                          given_others=True)
    drop, thr, win_red = adm["holdout_chi2_drop"], adm["chi2_threshold"], adm["window_reduction"]
    why = []
    if not adm["significant"]:
        why.append(f"held-out chi2 drop {drop:.4g} <= chi2({a.k}) quantile {thr:.3g}")
    if not adm["window_ok"]:
        why.append(f"window '{spec.window}' error drop {max(win_red.values(), default=0.0):.1%} < "
                   f"{min_window_reduction:.0%}")
    why += [w for w in (adm["channel_fail"], adm["all_samples_fail"], adm["aic_fail"]) if w]
    # its parameters in the current fit: determined, not collapsing to zero (the candidates' one test, on the runs'
    # own information; a parameter held when it was admitted stays held and is not judged)
    judge, absent = a.job.get("judge") or {}, a.job.get("absent") or {}
    verdicts = {}
    for n, ref in judge.items():
        e = full["estimates"].get(n)
        if e is None or e.get("held") or n not in full["free"]:
            continue
        verdicts[n] = determination(e["value"], e.get("stderr_data"), ref, z, absent.get(n, True))
        if e.get("at_bound"):
            why.append(f"{n} at its {e['at_bound']} bound")
    # "not determined" given the others is reported, not a reason to remove: it was judged in the effect's own fit
    # when it was admitted (its parameters judged there, the undetermined ones held); here the standard errors come
    # from the final fit's Fisher information, whose null directions at a switching law's point are a local
    # property (measured on rig_drivetrain_compliance: the load path's three parameters all of infinite standard
    # error in the final fit while taking it out raised the held-out error by 3026, 1179 when it was added).  An
    # effect whose part another explains fails on the drop and its null calibration.
    if spec.name in PAIR_CANDIDATES:
        # a cosine and sine pair is absent when its amplitude is, not when one part is (the forward rule, one copy);
        # a part the final fit's information does not determine: reported, not a reason, as for any parameter
        est = full["estimates"]
        if len(verdicts) == 2 and all(est[n].get("stderr_data") is not None for n in verdicts):
            na, nb = verdicts
            zero = pair_amplitude_zero(est[na], est[nb], nb, stderr=lambda e: e.get("stderr_data"))
            why += [f"{zero} given the others"] if zero else []
    else:
        why += [f"{n} = {full['estimates'][n]['value']:.3g} collapses to zero given the others"
                for n, v in verdicts.items() if v == "zero"]
    if adm["robust_fail"]:
        why.append(adm["robust_fail"])
    return {"name": a.name, "round_added": a.round, "holdout_chi2_drop_when_added": a.drop_when_added,
            "holdout_chi2_drop": drop, "holdout_chi2_drop_all_samples": adm["holdout_chi2_drop_all_samples"],
            "scored_outside_transients": mask is not None, "chi2_threshold": thr, "window": spec.window, "window_reduction": win_red,
            "error_reduction": adm["error_reduction"], "aic_drop": adm["aic_drop"], "determination": verdicts,
            "window_segments": adm["window_segments"], "fails": why, "prelim": not why,
            **({"window_on_all_samples": adm["window_on_all_samples"]} if adm["window_on_all_samples"] else {})}


def null_calibrate(recs: list[dict], reduceds: Mapping, jobs_of: Mapping, fit_runs, noise,
                   masks: Mapping, seed: int, null_factor: float, fit_jobs: Callable) -> None:
    """Null drop of each record's effect: the model without it and the current model, both fitted to a null run of
    the model without it (its own predictions plus white noise of the measured level); sets ``null_chi2_drop`` and
    adds a failure when the held-out drop is not ``null_factor`` times above it."""
    jobs, owners = [], []
    for i, r in enumerate(recs):
        null = _null_runs(reduceds[r["name"]], fit_runs, noise, seed + i)
        jr, jf = jobs_of[r["name"]]
        jobs += [{**jr, "label": f"null without {r['name']}", "runs": null, "judge": {}},
                 {**jf, "label": f"null with {r['name']}", "runs": null, "judge": {}}]
        owners.append(r)
    fits = fit_jobs(jobs)
    for k, r in enumerate(owners):
        nr, nf = fits[2 * k], fits[2 * k + 1]
        nd = null_drop(nr, nf, noise, masks[r["name"]])
        r["null_chi2_drop"] = nd
        if not beats_null(r["holdout_chi2_drop"], nd, null_factor):
            r["fails"].append(f"held-out chi2 drop {r['holdout_chi2_drop']:.4g} not above {null_factor:g} x its null "
                              f"drop {nd:.3g}")
