"""Is an angle-periodic candidate's gain periodic?  The repetition test of a ripple or a cogging fit (numerics only).

A torque periodic in an angle of the drive (the screw friction ripple once per screw revolution, the motor's
cogging at its order) is the same torque in every period of that angle: within one period it is indistinguishable
from any drag that depends on the nut position (a friction bump at one place, a worn spot, a trend of the base's
drags along the stroke), and only its *repetition* over the nut travel tells it from them.  A fit of such a
candidate to a residual that is local in nut position (rig-sim's friction bump: 8 N m at the screw over a few
millimetres) buys its held-out drop in the one period that holds the local structure and nothing, or a loss,
elsewhere.

:func:`repetition_test` splits a candidate's held-out chi2 drop by where the nut was: per held-out segment (the
segments are separate shooting segments, each started from its own fitted state), the segment's drop and its
span of nut position.  It finds the one period of travel (a window of the candidate's period, placed anywhere)
whose segments carry the largest part of the drop, leaves those segments out and asks whether the rest still
passes the held-out test of an effect with the candidate's ``k`` parameters.  The threshold (given by the
caller) is the ``chi2(k)`` quantile scaled like the tracer's ambiguity gap (the candidate fit's reduced held-out
chi2 and the held-out residual's integrated autocorrelation time: a structured remainder inflates every chi2
difference by its size and correlation, a quasi-likelihood scaling): a periodic effect present in the data
explains the other periods as well, by the same amplitude and phase, so its gain outside any one period is
as significant as a whole effect's; a local structure's is not.  It needs the travel to span two periods (the
candidates' resolution rule, :data:`~thsa_control.trace.candidates.RESOLVES`), else nothing is left to repeat.
The tracer runs it only for a period of two bins of its nut-position test or more
(:func:`thsa_control.trace.engine._repetition`): the screw ripple's lead, not the cogging's 0.01 mm, which no drag
local at the scale the tracer resolves projects on.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np


def run_segment_drops(pb: Mapping, pa: Mapping, noise: Mapping[str, float], sel: np.ndarray | None = None):
    """One run's predictions before (``pb``) and after (``pa``): per shooting segment, the noise-weighted chi2
    drop over its held-out samples (those of ``sel`` too, where given) and how many samples it counts.

    Returns ``(hold, starts, seg, drop, counted)``: the held-out flags, the segment starts as sample indices, the
    segment of each sample (-1 before the first), and per segment the drop and the counted samples."""
    hold = np.asarray(pb["holdout"], bool)
    n = hold.size
    t = np.asarray(pb["time"], float)[:n]
    st = np.asarray(pb["segment_starts"])
    st = np.searchsorted(t, st) if st.dtype.kind == "f" else st.astype(int)
    seg = np.searchsorted(st, np.arange(n), side="right") - 1
    keep = hold & (seg >= 0) if sel is None else hold & (seg >= 0) & np.asarray(sel, bool)[:n]
    d = np.zeros(len(st))
    counted = np.zeros(len(st), int)
    for c, y in pb["measured"].items():
        if c not in pa["simulated"] or not noise.get(c):
            continue
        y = np.asarray(y, float)[:n]
        eb = ((y - np.asarray(pb["simulated"][c], float)[:n]) / noise[c]) ** 2
        ea = ((y - np.asarray(pa["simulated"][c], float)[:n]) / noise[c]) ** 2
        m = keep & np.isfinite(eb) & np.isfinite(ea)
        np.add.at(d, seg[m], (eb - ea)[m])
        np.add.at(counted, seg[m], 1)
    return hold, st, seg, d, counted


def segment_drops(before: dict, after: dict, noise: Mapping[str, float], position: Mapping[str, np.ndarray],
                  mask: Mapping[str, np.ndarray] | None = None) -> list[dict]:
    """Per held-out segment: its noise-weighted chi2 drop (``before`` less ``after``, over the samples of ``mask``)
    and the nut position span of those samples (``position``: run -> nut position per sample [m])."""
    out = []
    for r, pb in before["predictions"].items():
        pa = after["predictions"].get(r)
        if pa is None or r not in position:
            continue
        hold, _st, seg, d, counted = run_segment_drops(pb, pa, noise, None if mask is None else mask[r])
        n = hold.size
        sel = hold & (seg >= 0)
        if mask is not None:
            sel &= np.asarray(mask[r], bool)[:n]
        x = np.asarray(position[r], float)[:n]
        for i in np.flatnonzero(counted > 0):
            xi = x[sel & (seg == i) & np.isfinite(x)]
            if xi.size:
                out.append({"run": r, "drop": float(d[i]), "x_min": float(xi.min()), "x_max": float(xi.max())})
    return out


def repetition_test(segments: list[dict], period: float, threshold: float) -> dict:
    """Leave out the one period of nut travel whose held-out segments carry the largest drop; the rest must pass
    ``threshold``, and the typical period of travel must gain (median of the per-period drops > 0).

    ``segments``: :func:`segment_drops`.  ``period``: the candidate's period in nut travel [m] (a screw lead for
    the ripple).  A segment is in the window ``[a, a + period)`` when its span of nut position meets it; the
    windows tried start at every segment's lowest position (the best window starts at one of them).
    Returns the total drop, the left-out window and its drop and share, the rest, the threshold, the number of
    periods of travel the held-out segments cover and those with a net gain, the median per-period drop (of the
    periods where the candidate changes the prediction), and ``repeats`` (rest > threshold and that median > 0).
    """
    if not segments or not period > 0:
        return {"repeats": True, "reason": "no held-out segment with a nut position", "segments": len(segments)}
    lo = np.array([s["x_min"] for s in segments])
    hi = np.array([s["x_max"] for s in segments])
    d = np.array([s["drop"] for s in segments])
    span = float(hi.max() - lo.min())
    if span < 2 * period:  # nothing left to repeat in: the record cannot tell (the resolution rule's business)
        return {"repeats": True, "period": float(period), "travel": span, "segments": int(d.size),
                "reason": f"the held-out segments span {span * 1e3:.3g} mm of nut travel, less than two periods "
                          f"({2 * period * 1e3:.3g} mm): repetition not testable"}
    total = float(d.sum())
    best, best_a = -math.inf, float(lo.min())
    for a in np.unique(lo):
        inside = (hi >= a) & (lo < a + period)
        v = float(d[inside].sum())
        if v > best:
            best, best_a = v, float(a)
    rest = total - best
    # the travel in whole periods from the lowest position, and the net gain per period
    x0 = float(lo.min())
    k = np.floor((0.5 * (lo + hi) - x0) / period).astype(int)
    per = {int(i): float(d[k == i].sum()) for i in np.unique(k)}
    # the typical period must gain too: leaving one period out does not see a gain that two places of the travel
    # carry (measured on rig-sim's load sweep with a preloaded load path: a ripple fitted to the load path's two
    # zero crossings gained 2783 and 2010 there and lost in 5 of the other 8 periods, rest 1095 over its threshold
    # 1010); a period where the candidate changes nothing (no moving held-out sample) says nothing and is not counted
    acting = [v for v in per.values() if abs(v) > 1e-9 * max(abs(total), 1.0)]
    typical = float(np.median(acting)) if acting else 0.0
    return {"repeats": bool(rest > threshold and typical > 0), "period": float(period), "travel": span,
            "total_drop": total, "median_period_drop": typical,
            "left_out": [best_a, best_a + float(period)], "left_out_drop": best,
            "left_out_share": best / total if total > 0 else None, "rest_drop": rest, "threshold": float(threshold),
            "segments": int(d.size), "periods_covered": len(per),
            "periods_gaining": int(sum(1 for v in per.values() if v > 0)),
            "drop_per_period": [per[i] for i in sorted(per)],
            "period_starts": [x0 + i * float(period) for i in sorted(per)]}


def halves_test(segments: list[dict], threshold: float) -> dict:
    """The repetition test of a period too short to leave one out (the cogging's 0.01-0.03 mm of nut travel): the
    held-out segments split at their median nut position (the motor angle is the nut position times a constant, so
    the two halves are two parts of the angle travel, each of many periods), and the held-out drop of *each* half
    must pass ``threshold``.  A torque periodic in the angle gains by the same amplitude and phase in every part of
    the travel, so each half's gain is that of a whole effect; a fit to a structured remainder (the base's drags at
    creep speed) gains where that structure happens to project on it (measured: rig-sim check_slow, rig base,
    nothing planted, seed 622: a 12 / rev fit gained 18.0 in the first half of the travel and 4.5 in the second).
    Leaving out the half with the larger drop, as :func:`repetition_test` leaves out the period with the largest,
    judges the rest.  Returns ``repeats`` (the weaker half above ``threshold``), the total and per-half drops and
    segment counts, the split position; untestable (``repeats`` True, a ``reason``) with fewer than two segments.
    """
    if len(segments) < 2:
        return {"repeats": True, "segments": len(segments),
                "reason": f"{len(segments)} held-out segment(s) in its window: the halves of the travel not testable"}
    mid = np.array([0.5 * (s["x_min"] + s["x_max"]) for s in segments])
    d = np.array([s["drop"] for s in segments])
    order = np.argsort(mid, kind="stable")
    lo_i, hi_i = order[:mid.size // 2], order[mid.size // 2:]
    halves = [float(d[lo_i].sum()), float(d[hi_i].sum())]
    return {"repeats": bool(min(halves) > threshold), "total_drop": float(d.sum()), "half_drops": halves,
            "half_segments": [int(lo_i.size), int(hi_i.size)], "split_at": float(mid[hi_i].min()),
            "rest_drop": min(halves), "threshold": float(threshold), "segments": int(d.size)}


def describe(test: dict) -> str:
    """The refusal reason of a candidate whose gain does not repeat."""
    if "half_drops" in test:  # a period too short to leave one out (halves_test)
        a, b = test["half_drops"]
        return (f"not periodic over the travel: of its held-out drop {test['total_drop']:.4g} it gains {a:.4g} "
                f"below {test['split_at'] * 1e3:.4g} mm of nut travel and {b:.4g} beyond ({test['half_segments'][0]} "
                f"and {test['half_segments'][1]} held-out segments); the weaker half does not pass the held-out test "
                f"({test['threshold']:.3g}: chi2 quantile x reduced chi2 {test.get('reduced_chi2', 1.0):.3g} x IACT "
                f"{test.get('iact', 1.0):.3g})")
    a, b = test["left_out"]
    where = f"one period of nut travel, {a * 1e3:.3g} .. {b * 1e3:.3g} mm"
    loc = test.get("local_structure")
    if loc:  # the position-local residual the candidate was fitted to (the signature's nut-position test)
        where += (f" (where the {loc['variable']} test finds a local residual, {loc['peak_bin'][0] * 1e3:.3g} .. "
                  f"{loc['peak_bin'][1] * 1e3:.3g} mm, p {loc['p_value']:.2g})")
    others = test["periods_covered"] - 1
    other = f"the other {others} period{'s' if others != 1 else ''} of travel"
    if test["rest_drop"] > test["threshold"]:  # passed the leave-one-out test; the typical period does not gain
        return (f"not periodic over the travel: its held-out drop {test['total_drop']:.4g} comes from "
                f"{test['periods_gaining']} of {test['periods_covered']} periods of travel (the largest "
                f"{test['left_out_drop']:.4g} in {where}); the typical period does not gain (median per-period drop "
                f"{test['median_period_drop']:.3g})")
    if test["rest_drop"] <= 0:
        return (f"not periodic over the travel: it gains {test['left_out_drop']:.4g} of held-out chi2 in {where} and "
                f"makes the held-out error worse over {other} ({test['rest_drop']:.4g})")
    return (f"not periodic over the travel: it gains {test['left_out_drop']:.4g} of its held-out drop "
            f"{test['total_drop']:.4g} in {where}; over {other} {test['rest_drop']:.4g}, which does not pass the "
            f"held-out test ({test['threshold']:.3g}: chi2 quantile x reduced chi2 {test.get('reduced_chi2', 1.0):.3g} "
            f"x IACT {test.get('iact', 1.0):.3g})")
