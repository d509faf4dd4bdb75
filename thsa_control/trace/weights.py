"""Does a found effect's estimate depend on how the channels are weighted?

The tracer weights each channel by its sensor's noise: right where the model leaves only that noise.  A channel that
keeps several times its noise of error the model cannot describe (a current-driven replay of a 40 ms PRBS, whose
current steps within a logged sample, leaves the motor speed at 2.6 x the resolver's noise) then outweighs the others,
and a found effect's parameters absorb what they can of that error: on rig-sim's whole speed excitation the
drive-train compliance's damping came out 17.6 +- 0.5 N m s/rad (rig-sim's 2), at a stiffness 25 % low, with the
screw speed (the channel the compliance shows on) best near rig-sim's values (docs/trace_notes.md, "A damping the
motor speed chose").

The maximum-likelihood fit of channels whose error spread is unknown scales each channel by that spread.  After the
search, each found effect's fitted parameters are fitted again on the final model with every channel scaled by the
larger of its sensor noise and the final model's residual RMS on it (the other parameters held at their final
values).  Where a channel is at its noise the two weightings are the same; where they differ the estimate depends on
the weighting, an assumption, and the entry reports both values and the range they span.  The tracer's decisions (the
held-out scores) keep the sensor-noise weights: scored with residual scales, records lose effects the sensor-noise
scores find (the cogging on rig_cogging, the compliances on the reversal and step records).

Pure functions on the fits' summaries; the fits run in :mod:`thsa_control.trace.engine`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

__all__ = ["MAX_REWEIGHTS", "SCALE_TOLERANCE", "WEIGHT_SHIFT_FLOOR", "checked_parameters", "compare", "ml_channel_scales",
           "moved", "scales_settled", "stderr_of", "structural_channels", "weight_verdict"]

#: Smallest relative shift between the two weightings' estimates that is reported as a dependence on the weights
#: (beside the statistical test): smaller ones are inside what the tracer's other ranges already carry.
WEIGHT_SHIFT_FLOOR = 0.1


#: Reweighting rounds at most (each fit's residual sets the next fit's scales), and the relative change of every
#: scale below which they have settled.
MAX_REWEIGHTS = 6
SCALE_TOLERANCE = 0.05


def scales_settled(old: Mapping[str, float], new: Mapping[str, float]) -> bool:
    """Every channel's scale changed by less than :data:`SCALE_TOLERANCE` of its old value."""
    return all(abs(new[c] - old[c]) <= SCALE_TOLERANCE * old[c] for c in old)


def ml_channel_scales(noise: Mapping[str, float], residual_rms: Mapping[str, float]) -> dict[str, float]:
    """Each channel's scale: the larger of its sensor noise and the residual RMS the model leaves on it."""
    return {c: max(float(s), float(residual_rms.get(c, 0.0))) for c, s in noise.items()}


def stderr_of(e: Mapping) -> float | None:
    """An estimate's standard error for comparing two fits: from the run's own information (``stderr_data``), the
    posterior one where that is missing or not finite; None where neither is finite (held, profiled)."""
    sd = e.get("stderr_data")
    if sd is None or not math.isfinite(sd):
        sd = e.get("stderr")
    return float(sd) if sd is not None and math.isfinite(sd) else None


def checked_parameters(step: Mapping, final_fit: Mapping) -> tuple[str, ...]:
    """The found effect's parameters the final fit estimated with a standard error (not held, not profiled)."""
    est = final_fit.get("estimates") or {}
    free = set(final_fit.get("free") or ())
    out = []
    for n, p in (step.get("parameters") or {}).items():
        if p.get("held") or p.get("profiled") or n not in free or n not in est:
            continue
        if stderr_of(est[n]) is None:
            continue
        out.append(n)
    return tuple(out)


def moved(va: float, sa: float, vb: float, sb: float, z: float) -> bool:
    """Two estimates differ: by more than ``z`` combined standard errors and by more than
    :data:`WEIGHT_SHIFT_FLOOR` of the larger magnitude (also the tracer's rule for a found effect's parameter that
    moved after it was added)."""
    shift = abs(va - vb)
    return shift > z * math.hypot(sa, sb) and shift > WEIGHT_SHIFT_FLOOR * max(abs(va), abs(vb))


def structural_channels(scales: Mapping[str, float], noise: Mapping[str, float], ratio: float) -> list[str]:
    """Channels whose residual scale exceeds ``ratio`` x their sensor noise: error the model cannot describe."""
    return [c for c in scales if noise.get(c) and scales[c] / noise[c] > ratio]


def weight_verdict(final_fit: Mapping, alternatives: Mapping[str, Mapping], names: Sequence[str],
                   scales: Mapping[str, float], noise: Mapping[str, float], z: float,
                   structural: Sequence[str]) -> dict:
    """Compare the final fit's estimates of ``names`` with those of the ``alternatives`` (weighting -> fit summary:
    ``"residual_scales"``, the channels at their residual spread; ``"without_structural_channels"``, the channels
    the model leaves at their noise only).

    A parameter depends on the weights when an alternative that determines it (estimate beyond ``z`` standard
    errors from zero) differs from the final estimate by more than ``z`` combined standard errors and by more than
    :data:`WEIGHT_SHIFT_FLOOR` of the larger magnitude.  Its range is the hull of the 95 % intervals (value +- 1.96
    standard errors) of the final fit and of those alternatives, inside the parameter's physical range."""
    out: dict = {"channel_scales": dict(scales),
                 "scale_over_noise": {c: scales[c] / noise[c] for c in scales if noise.get(c)},
                 "structural_channels": list(structural),
                 "weightings": {k: ("error: " + f["error"]) if "error" in f else "fitted"
                                for k, f in alternatives.items()},
                 "parameters": {}, "depends_on_weights": [], "range": {}}
    for n in names:
        entry, rng = compare(final_fit["estimates"][n], {k: None if "error" in f else f["estimates"].get(n)
                                                          for k, f in alternatives.items()}, z)
        out["parameters"][n] = {"sensor_noise_weights": entry.pop("reference"), **entry}
        if rng is not None:
            out["depends_on_weights"].append(n)
            out["range"][n] = rng
    return out


def compare(a: Mapping, others: Mapping[str, Mapping | None], z: float,
            determined_only: bool = True) -> tuple[dict, list[float] | None]:
    """One estimate ``a`` (an estimate entry: value, standard errors, min, max) against the same parameter from
    other fits (name -> entry, None where that fit has none): ``(entry, range)``.  ``entry``: ``"reference"`` and
    each other fit's value and standard error (:func:`stderr_of`).  ``range``: where a fit that determines it
    (estimate beyond ``z`` standard errors from zero) differs by more than ``z`` combined standard errors and
    :data:`WEIGHT_SHIFT_FLOOR` (:func:`moved`), the hull of the 95 % intervals (value +- 1.96 standard errors) of
    ``a`` and of those fits, inside the parameter's physical range; else None.  ``determined_only`` False: a fit
    whose estimate is within ``z`` standard errors of zero counts too (the every-segment fit of the same model: a
    soft zone it puts at zero, 0 +- 0.24 um against the search's 16.8 +- 0.23 um, has moved)."""
    sa, va = stderr_of(a), float(a["value"])
    entry = {"reference": {"value": va, "stderr": sa}}
    lo, hi, shifted = (va - 1.96 * sa, va + 1.96 * sa, False) if sa is not None else (va, va, False)
    for k, b in others.items():
        if b is None:
            continue
        sb, vb = stderr_of(b), float(b["value"])
        entry[k] = {"value": vb, "stderr": sb}
        if sa is None or sb is None or (determined_only and abs(vb) <= z * sb):  # not determined by that fit
            continue
        if moved(va, sa, vb, sb, z):
            shifted = True
            lo, hi = min(lo, vb - 1.96 * sb), max(hi, vb + 1.96 * sb)
    if not shifted:
        return entry, None
    return entry, within_range(lo, hi, a)


def within_range(lo: float, hi: float, e: Mapping) -> list[float]:
    """``[lo, hi]`` inside an estimate entry's physical range (its ``min`` and ``max`` where finite): a range or
    an interval reported for a value never reaches where the parameter cannot be (a damping below zero)."""
    mn, mx = e.get("min"), e.get("max")
    return [max(lo, float(mn)) if mn is not None and math.isfinite(mn) else lo,
            min(hi, float(mx)) if mx is not None and math.isfinite(mx) else hi]
