"""Does the no-back hold? What the record shows with the drive off, and the margin the fitted model gives.

A no-back's one function is to hold the load when the motors are de-energised.  Two independent readings:

* **observed** (:func:`drive_off_holds`, model-free): every stretch of a record in which both motor channels carry
  no torque (the enable flags at 0, or the speed command at exactly 0 on a rig whose JSON says
  ``motor_disabled_when_cmd_zero``) under a load of one sign.  The screw's rotation in the direction the load
  pushes it is read from the speed sensor (the motor's, through the gear ratio, else the screw's) and integrated.
  A disk set that holds lets the screw turn through at most the pawl's free travel, one tooth pitch, and then stops
  it; one that does not hold lets the load back-drive the screw for as long as the load stays on.  So a stretch
  **slips** when the screw is still turning at its end (above 5 % of the record's largest speed with the drive on,
  beyond its noise, and not braked: at least half the stretch's largest speed) *and* has turned through more than
  one pawl pitch (the pitch alone does not tell: the disks brake the screw over some travel after the pawl takes up
  its play, so a healthy stop can turn it through more than a pitch, 1.3 pitches on rig-sim's
  rig_ratchet_backlash_lowgain, but braked to rest); it **holds** when the screw is still at its end; a stretch still turning at its end within one pitch is **undecided** (a pawl's free travel being crossed,
  or a slip: the record alone cannot tell them apart, the model can).
* **model margin** (:func:`holding_margin`): the loaded disk set's fitted static coefficient over the holding
  limit ``lead x inverse efficiency / 2 pi`` (:func:`~.candidates._rule_holding`), with its 95 % interval and the
  range the assumed inverse efficiency spans.

:func:`holding_finding` puts the two together for the trace: an observed slip the found effects do not carry as a
fault is a structured remainder (``unexplained``), and a fault the record's own stops contradict is said.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from ..model.params import ParameterSet
from .candidates import HOLDING_COEFFICIENTS
from .signature import MIN_HOLD

__all__ = ["drive_off_holds", "holding_margin", "holding_finding", "MIN_DRIVE_OFF", "END_FRACTION",
           "MIN_LOAD_FRACTION", "MIN_LOAD", "SLIP_Z", "BRAKED_FRACTION", "INVERSE_EFFICIENCY_SPREAD", "CURVE_POINTS"]

#: the shortest drive-off stretch tested [s]: the load-cell drift test's shortest hold
MIN_DRIVE_OFF = MIN_HOLD
#: the end of a stretch whose speed says whether the screw still turns: its last tenth, at least 5 samples
END_FRACTION = 0.1
#: a stretch is under load where |load| exceeds this share of the record's largest |load| and :data:`MIN_LOAD`
MIN_LOAD_FRACTION = 0.05
MIN_LOAD = 1000.0
#: standard errors of the mean (the speed sensor's noise from its first differences) the end speed must exceed
SLIP_Z = 5.0
#: the end speed, as a share of the stretch's largest, under which the screw is being braked (a pawl taken up)
BRAKED_FRACTION = 0.5
#: +- around the file's inverse efficiency over which the holding limit is shown (the spread of catalogue
#: ball-screw efficiencies, as :func:`.candidates._rule_efficiency`'s 0.05)
INVERSE_EFFICIENCY_SPREAD = 0.05
#: the most points of a stretch's back-driven travel curve kept for the report (every k-th sample, the last kept)
CURVE_POINTS = 200

_SOURCE = (f"drive-off stretches of at least {MIN_DRIVE_OFF:g} s under a load above {100 * MIN_LOAD_FRACTION:g} % of "
           f"the record's largest and {MIN_LOAD:g} N (assumed: below that the load's back-driving torque is of the "
           "drive train's drags); the screw's rotation from the speed sensor; slips: still turning at the end (the "
           f"last {100 * END_FRACTION:g} %: above 5 % of the largest speed with the drive on, {SLIP_Z:g} standard "
           f"errors and {100 * BRAKED_FRACTION:g} % of the stretch's largest speed: not braked) after more than one "
           "pawl pitch (a pawl lets the screw turn through its free travel, at most one tooth pitch, then the disks "
           "stop it)")


def _drive_off(run) -> np.ndarray:
    """Samples where neither motor channel carries torque."""
    cmd = np.asarray(run.signals["speed_cmd"], float)
    off = (cmd == 0) if run.motor_disabled_when_cmd_zero else np.zeros(cmd.shape, bool)
    cols = run.source_columns
    if "primary_enable" in cols or "standby_enable" in cols:
        enabled = (np.asarray(run.signals["primary_enable"]) > 0.5) | (np.asarray(run.signals["standby_enable"]) > 0.5)
        off |= ~enabled
    return off


def _screw_rate(run) -> tuple[np.ndarray, str] | tuple[None, None]:
    """The screw's angular speed [rad/s] and the sensor it comes from (the motor's through the gear ratio, else the
    screw's), None where the run has neither."""
    if "motor_speed" in run.source_columns:
        return np.asarray(run.signals["motor_speed"], float) / run.gear_ratio, "motor_speed"
    if "screw_speed" in run.source_columns:
        return np.asarray(run.signals["screw_speed"], float), "screw_speed"
    return None, None


def _moving_band(rate: np.ndarray, off: np.ndarray) -> float:
    """The screw speed [rad/s] under which it counts as still: 5 % of the largest speed while the drive is on
    (the stop band of :func:`~.signature.base_transients`; not over the drive-off samples, which a slip fills with
    speeds of its own) and 5 noise standard deviations of the sensor (from its first differences)."""
    on = rate[~off] if (~off).any() else rate
    d = np.diff(rate)
    noise = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / math.sqrt(2) if d.size else 0.0
    return max(0.05 * float(np.max(np.abs(on))) if on.size else 0.0, 5.0 * noise, 1e-12)


def _curve(t: np.ndarray, y: np.ndarray) -> dict:
    """``t`` and ``y`` thinned to at most :data:`CURVE_POINTS` samples (every k-th, the last always kept)."""
    k = max(1, int(math.ceil(t.size / CURVE_POINTS)))
    idx = np.r_[np.arange(0, t.size, k), t.size - 1] if t.size else np.arange(0)
    idx = np.unique(idx)
    return {"t_s": [float(v) for v in t[idx]], "mm": [float(v) for v in y[idx]]}


def _stretches(key: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the runs of equal non-zero ``key``."""
    edges = np.flatnonzero(np.diff(np.r_[0, key, 0]) != 0)
    out = []
    for a, b in zip(edges[:-1], edges[1:]):
        if key[a] != 0:
            out.append((int(a), int(b)))
    return out


def drive_off_holds(runs: Sequence, params: ParameterSet) -> dict:
    """The record's own answer to "does the no-back hold?" (the module's first reading).

    Parameters
    ----------
    runs : sequence of RigRun
    params : ParameterSet
        ``noback.pawl_pitch`` [rad] (0 when the file has none: any rotation then counts).

    Returns
    -------
    dict
        ``verdict`` ("slips", "holds", "undecided" or "not tested"), ``why`` (not tested), ``stretches`` (each:
        ``run``, ``start``/``end`` [s], ``load_N`` (mean), ``side`` (compressive / tensile), ``screw_turn_rad`` and
        ``nut_travel_mm`` (in the direction the load pushes, from the speed sensor, counted from the first sample at
        rest or turning against the load), ``lvdt_travel_mm`` (the same
        from the LVDT, elastic deflection included), ``end_speed_mm_s`` with its ``end_stderr`` and ``band``,
        ``turning_at_end``, ``beyond_pitch``, ``state`` (slips / holds / undecided), ``lead_mm``, ``end_from_s``
        (where the end window starts, from the stretch's start) and ``curve`` (``t_s`` from the stretch's start and
        ``mm``, the cumulative back-driven travel from the rest sample, at most :data:`CURVE_POINTS` points)),
        ``held_up_to_N`` and ``slipped_at_N`` per side, ``pawl_pitch_rad``, ``pawl_pitch_mm`` (at the first
        stretch's lead), ``sensor`` and ``rule``.
    """
    pitch = params.value("noback.pawl_pitch") if "noback.pawl_pitch" in params else 0.0
    out: list[dict] = []
    sensors, why = set(), []
    for run in runs:
        rate, sensor = _screw_rate(run)
        off = _drive_off(run)
        if rate is None:
            why.append(f"{run.name}: no motor or screw speed sensor")
            continue
        if not off.any():
            why.append(f"{run.name}: the drive is never off (a speed loop holding the nut tests the loop, not the "
                       "no-back)")
            continue
        t = np.asarray(run.time, float)
        f = np.nan_to_num(np.asarray(run.signals["load_force"], float))
        fmin = max(MIN_LOAD, MIN_LOAD_FRACTION * float(np.max(np.abs(f))))
        key = np.where(off & (np.abs(f) > fmin), np.sign(f), 0.0).astype(int)
        band = _moving_band(np.nan_to_num(rate), off)  # [rad/s] of the screw
        to_mm = run.screw_lead / (2 * math.pi) * 1e3
        x = np.asarray(run.signals["nut_position"], float) if "nut_position" in run.source_columns else None
        stretch_found = False
        for a, b in _stretches(key):
            if t[b - 1] - t[a] < MIN_DRIVE_OFF:
                continue
            stretch_found = True
            sensors.add(sensor)
            push = -float(key[a])  # a compressive load pushes the nut back: retraction, negative rotation
            r = push * np.nan_to_num(rate[a:b])
            # the push-direction rotation from the first sample the screw is at rest or turns against the load (a
            # motor still coasting in the load's direction when the drive went off is no slip of the disks)
            rest = np.flatnonzero(r <= band)
            q = np.maximum(r[rest[0] if rest.size else 0:], 0.0)
            tq = t[a:b][rest[0] if rest.size else 0:]
            travel = np.r_[0.0, np.cumsum(0.5 * (q[1:] + q[:-1]) * np.diff(tq))] if q.size else np.zeros(1)
            turn = float(travel[-1])
            n_end = max(5, int(round(END_FRACTION * (b - a))))
            e = r[-n_end:]
            v_end = float(np.mean(e))
            # the sensor's noise from the first differences (a steady acceleration, which a slip is, is no noise)
            d = np.diff(e)
            se = float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2 * e.size)) if e.size > 2 else math.inf
            # and not being braked: a pawl's crossing ends with the disks decelerating the screw, a slip speeds up
            peak = float(np.max(q)) if q.size else 0.0
            turning = bool(v_end > band and v_end > SLIP_Z * se and v_end >= BRAKED_FRACTION * peak)
            beyond = bool(turn > pitch)
            state = "slips" if turning and beyond else "undecided" if turning else "holds"
            lv = None
            if x is not None and np.isfinite(x[a]) and np.isfinite(x[b - 1]):
                lv = float(push * (x[b - 1] - x[a]) * 1e3)
            out.append({"run": run.name, "start": float(t[a]), "end": float(t[b - 1]),
                        "load_N": float(np.mean(f[a:b])), "side": "compressive" if key[a] > 0 else "tensile",
                        "screw_turn_rad": turn, "nut_travel_mm": turn * to_mm, "lvdt_travel_mm": lv,
                        "end_speed_mm_s": v_end * to_mm, "end_stderr_mm_s": se * to_mm, "band_mm_s": band * to_mm,
                        "turning_at_end": turning, "beyond_pitch": beyond, "state": state,
                        "lead_mm": run.screw_lead * 1e3, "end_from_s": float(t[b - n_end] - t[a]),
                        "curve": _curve(tq - t[a] if q.size else np.zeros(1), travel * to_mm)})
        if not stretch_found:
            why.append(f"{run.name}: no drive-off stretch of {MIN_DRIVE_OFF:g} s or more under a load above "
                       f"{fmin:.0f} N")
    doc = {"pawl_pitch_rad": float(pitch),
           "pawl_pitch_mm": float(pitch) / (2 * math.pi) * out[0]["lead_mm"] if out else None,
           "sensor": ", ".join(sorted(sensors)) or None, "rule": _SOURCE, "stretches": out}
    if not out:
        return {**doc, "verdict": "not tested", "why": "; ".join(why) or "no run"}
    states = {s["state"] for s in out}
    doc["verdict"] = "slips" if "slips" in states else "holds" if states == {"holds"} else "undecided"
    for key_, state in (("held_up_to_N", "holds"), ("slipped_at_N", "slips")):
        doc[key_] = {side: max((abs(s["load_N"]) for s in out if s["state"] == state and s["side"] == side),
                               default=None) for side in ("compressive", "tensile")}
    if why:
        doc["not_tested_runs"] = why
    return doc


def _loaded_coefficient(side: str) -> str:
    return next(n for n, sign in HOLDING_COEFFICIENTS.items() if (sign > 0) == (side == "compressive"))


def holding_margin(final_parameters: Mapping, params: ParameterSet, sides: Sequence[str]) -> list[dict]:
    """The model's holding margin for each loaded ``side``: the final model's static coefficient of that side's disk
    set over the holding limit ``lead x eta_i / 2 pi``, where the runs determined it (``final_parameters`` holds it
    as fitted); ``ci95`` from its interval at the file's (or the fitted) inverse efficiency, and ``over_eta`` the
    margin's range at ``eta_i +- INVERSE_EFFICIENCY_SPREAD`` where the inverse efficiency is the file's assumed one.
    ``shown``: "holds with margin" (the interval's lower end above 1 at the highest inverse efficiency of the
    range), "does not hold" (its upper end below 1 at the lowest), else "not shown"."""
    lead = params.value("screw.lead")
    eta_p = final_parameters.get("screw.efficiency_inverse")
    eta = eta_p["value"] if eta_p else params.value("screw.efficiency_inverse")
    eta_fitted = bool(eta_p and eta_p.get("source") == "fitted")
    if eta_fitted:
        lo_eta, hi_eta = eta_p.get("ci95") or (eta, eta)
        eta_src = "the inverse efficiency as fitted, with its 95 % interval"
    else:
        lo_eta, hi_eta = max(eta - INVERSE_EFFICIENCY_SPREAD, 0.0), min(eta + INVERSE_EFFICIENCY_SPREAD, 1.0)
        eta_src = (f"the parameter file's inverse efficiency {eta:g} ({params[ 'screw.efficiency_inverse'].source}) "
                   f"+-{INVERSE_EFFICIENCY_SPREAD:g}, the spread of catalogue ball-screw efficiencies")
    out = []
    for side in sides:
        n = _loaded_coefficient(side)
        p = final_parameters.get(n)
        if not p or p.get("source") != "fitted" or not p.get("ci95"):
            out.append({"side": side, "parameter": n, "determined": False,
                        "why": "the final model does not fit it from this record (a declared ideal no-back, or held)"})
            continue
        mu, (mu_lo, mu_hi) = p["value"], p["ci95"]
        lim = lead * eta / (2 * math.pi)
        lim_lo, lim_hi = lead * lo_eta / (2 * math.pi), lead * hi_eta / (2 * math.pi)
        worst, best = mu_lo / lim_hi, mu_hi / lim_lo
        shown = "holds with margin" if worst > 1 else "does not hold" if best < 1 else "not shown"
        out.append({"side": side, "parameter": n, "determined": True, "coefficient": mu, "ci95": [mu_lo, mu_hi],
                    "limit": lim, "limit_range": [lim_lo, lim_hi], "margin": mu / lim,
                    "margin_ci95": [mu_lo / lim, mu_hi / lim], "margin_range": [worst, best],
                    "eta_inverse": eta, "eta_range": [lo_eta, hi_eta], "eta_source": eta_src, "shown": shown})
    return out


def holding_finding(observed: dict, margin: list[dict], added: Sequence[Mapping]) -> dict:
    """Both readings against the trace's found effects: ``fault_found`` (an added effect carries the no-back
    fault), ``remainder`` (the structured-remainder name when the record shows a slip that no found fault carries,
    else None) and ``notes`` (a fault the record's stops contradict; a margin not shown on a record whose stops
    hold)."""
    fault = any((e.get("fault") or {}).get("kind") == "no_back_does_not_hold" for e in added)
    notes, remainder = [], None
    slipped = [s for s in observed.get("stretches", []) if s["state"] == "slips"]
    if slipped and not fault:
        worst = max(slipped, key=lambda s: s["nut_travel_mm"])
        remainder = (f"no-back slips with the drive off (observed: {len(slipped)} stretch(es), "
                     f"{worst['nut_travel_mm']:.3g} mm back-driven at {abs(worst['load_N']) / 1e3:.3g} kN "
                     f"{worst['side']}, still {worst['end_speed_mm_s']:.3g} mm/s at the end)")
    if fault and observed.get("verdict") == "holds":
        notes.append("the found fault rests on the model's holding limit, but every drive-off stretch of the record "
                     "under load ends with the screw still: the unit held there (the limit's inverse efficiency may "
                     "be lower than the file's)")
    held = observed.get("held_up_to_N") or {}
    for m in margin:
        if m.get("determined") and m["shown"] == "not shown" and held.get(m["side"]):
            notes.append(f"{m['side']} side: the record's stops hold up to {held[m['side']] / 1e3:.3g} kN, but the "
                         f"model's margin {m['margin']:.3g} (95 % {m['margin_ci95'][0]:.3g}..{m['margin_ci95'][1]:.3g}"
                         f"; {m['margin_range'][0]:.3g}..{m['margin_range'][1]:.3g} over the inverse efficiency "
                         f"{m['eta_range'][0]:.3g}..{m['eta_range'][1]:.3g}) does not show it holds with margin")
    return {"fault_found": fault, "remainder": remainder, "notes": notes}
