"""Which constant-torque explainers a record can tell apart, and which kind of record would (numerics only).

A Coulomb drag, a direction drag, an axial force the load cell does not see, the screw's efficiencies and a
no-back disk's coefficient all change the torque the motor must give; on one load and one speed each
direction of motion sees two constant torques, which several of them explain alike.  The ambiguity rule of
the tracer (held-out drops closer than noise can separate) says *that* the data cannot tell them apart; this
module says *why* and *what would*:

* :func:`torque_sensitivities`: the change of the torque at the motor shaft per unit of each parameter, at
  operating points (motor speed, load, nut position, temperature), from the model's own expressions (the
  plant's right-hand side, ``J d(speed)/dt`` by a finite step of each parameter; no law written twice).
  Only effects without dynamic states of their own take part: a compliance or a clearance does not change
  the steady torque.
* :func:`collinearity`: for each explainer, the share of its torque over the record's moving samples that
  the other explainers reproduce (uncentred multiple ``R^2`` of a least-squares fit, no intercept: a constant
  torque is itself an explainer) and the variance inflation factor ``1 / (1 - R^2)``.  The explainers that
  make up the reproduction are named.
* :func:`separability`: the same on the record completed with operating points of another kind, derived from
  the record's own (the other direction of motion at the same loads, a quarter of the loads, the loads of the other
  sign, no load, half the speed): which kind brings each explainer's inflation down.

``VIF_LIMIT = 10`` (``R^2 = 0.9``) is the usual multicollinearity limit of regression diagnostics (Kutner,
Nachtsheim, Neter & Li, *Applied Linear Statistical Models*, 5th ed., sec. 10.5: a largest VIF above 10
signals that collinearity unduly influences the least-squares estimates): above it, an explainer's standard
error is more than ``sqrt(10) = 3.2`` times what it would be alone.  The result is reported; it does not
change what the tracer selects.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence

import numpy as np

from ..data.rigdata import RigRun, measured_motor_speed, stop_band
from ..model import EFFECTS, build_plant
from ..model.params import ParameterSet

#: variance inflation above which two explainers are "the same part of the residual" on a record (see above)
VIF_LIMIT = 10.0
#: an explainer whose share of another's least-squares reproduction is below this is not named beside it (a
#: presentation cut: the reproduction is reported in full under ``weights``)
NAME_SHARE = 0.1
#: moving samples used per record (evenly spaced; the sensitivities are smooth in the operating point)
MAX_POINTS = 2000


def _operating_points(runs: Sequence[RigRun], max_points: int = MAX_POINTS) -> dict[str, np.ndarray]:
    """The runs' moving samples (motor speed beyond 5 % of its largest value): speed, load, nut position,
    temperature, current, evenly thinned to ``max_points``."""
    cols: dict[str, list] = {k: [] for k in ("speed", "load", "position", "temperature", "current")}
    for r in runs:
        w = np.nan_to_num(np.asarray(measured_motor_speed(r), float))
        m = np.abs(w) > stop_band(w)
        s = r.signals
        x = np.asarray(s["nut_position"], float) if r.has("nut_position") else np.zeros(w.size)
        temp = np.asarray(s["temperature"], float) if r.has("temperature") else np.full(w.size, 25.0)
        cur = np.asarray(s["motor_current"], float) if r.has("motor_current") else np.zeros(w.size)
        for k, v in (("speed", w), ("load", np.asarray(s["load_force"], float)), ("position", np.nan_to_num(x)),
                     ("temperature", np.nan_to_num(temp, nan=25.0)), ("current", np.nan_to_num(cur))):
            cols[k].append(v[m])
    out = {k: np.concatenate(v) if v else np.zeros(0) for k, v in cols.items()}
    n = out["speed"].size
    if n > max_points:
        idx = np.linspace(0, n - 1, max_points).round().astype(int)
        out = {k: v[idx] for k, v in out.items()}
    return out


def steady_effects(effects: Sequence[str]) -> tuple[str, ...]:
    """The effects of a model that change the steady torque: those with no state but first-order lags (a
    compliance or a clearance adds states and leaves the steady torque as it is)."""
    return tuple(e for e in effects if all(s.kind == "lag" for s in EFFECTS[e].states))


def torque_sensitivities(effects: Sequence[str], params: ParameterSet, names: Sequence[str],
                         points: Mapping[str, np.ndarray], steps: Mapping[str, float], plant=None) -> np.ndarray:
    """``S[i, k]``: change of the resisting torque at the motor shaft [N m] per unit of ``names[k]`` at operating
    point ``i`` (``points``: arrays ``speed`` [rad/s at the motor], ``load`` [N, compressive positive],
    ``position`` [m], ``temperature`` [degC], ``current`` [A]).

    A forward step ``steps[name]`` (signed: a direction drag acts one way only, so its sign is the one the fit
    found) of each parameter through the plant's right-hand side, times the main body's inertia.  ``plant``: the plant
    of ``effects`` at ``params`` where the caller has built it.
    """
    plant = build_plant(None, list(effects), params=params) if plant is None else plant
    p0 = plant.p_vector(params)
    n = points["speed"].size
    if n == 0:
        return np.zeros((0, len(names)))
    sn = plant.state_names
    i_speed = sn.index("motor_speed")
    X = np.zeros((len(sn), n))
    for i in range(n):
        X[:, i] = np.asarray(plant.init(float(points["position"][i]), float(points["load"][i]), p0)).ravel()
    X[i_speed] = points["speed"]
    if "motor_current" in sn:
        X[sn.index("motor_current")] = points["current"]  # the start of the steady-current search below
    U = np.zeros((len(plant.inputs), n))
    U[plant.inputs.index("enable_primary")] = 1.0
    U[plant.inputs.index("load_force")] = points["load"]
    U[plant.inputs.index("temperature")] = points["temperature"]
    fmap = plant.f.map(n)
    # the main body's inertia at each point (the reflected masses pass the efficiencies of the power flow there)
    j_main = np.asarray(plant.inertia_fn.map(n)(X, np.repeat(p0[:, None], n, axis=1))[0]).ravel()

    def accel(p):
        P = np.repeat(p[:, None], n, axis=1)
        return np.asarray(fmap(X, U, P)[0])[i_speed]

    # the steady operating point: the current that holds the speed (the gearbox loss depends on the torque the
    # motor puts in, so the measured current's share that accelerates the body would bias it); a few secant steps
    if "motor_current" in sn:
        ic = sn.index("motor_current")
        for _ in range(4):
            a1 = accel(p0)
            X[ic] += 0.1
            slope = (accel(p0) - a1) / 0.1
            X[ic] -= 0.1
            ok = np.abs(slope) > 0
            X[ic, ok] -= a1[ok] / slope[ok]
    a0 = accel(p0)
    S = np.zeros((n, len(names)))
    for k, name in enumerate(names):
        h = steps[name]
        p = p0.copy()
        p[plant.parameters.index(name)] += h
        S[:, k] = -j_main * (accel(p) - a0) / h
    return S


def collinearity(S: np.ndarray, names: Sequence[str], targets: Sequence[str]) -> dict[str, dict]:
    """Per target column: uncentred ``R^2`` of its least-squares reproduction by the other columns, the variance
    inflation ``1/(1-R^2)``, the reproduction's weights (each other column's share of the reproduced torque,
    ``|c_k| ||S_k|| / sum``) and the explainers named beside it (share >= :data:`NAME_SHARE`).  A target whose
    torque is zero on these points has no entry (the record does not exercise it)."""
    out = {}
    norms = np.linalg.norm(S, axis=0)
    for t in targets:
        j = list(names).index(t)
        if not norms[j] > 0:
            continue
        others = [k for k in range(len(names)) if k != j and norms[k] > 0]
        y = S[:, j]
        if not others:
            out[t] = {"r2": 0.0, "vif": 1.0, "same_part_as": [], "weights": {}}
            continue
        A = S[:, others] / norms[others]
        c, *_ = np.linalg.lstsq(A, y, rcond=None)
        r2 = float(max(0.0, 1.0 - np.sum((y - A @ c) ** 2) / np.sum(y ** 2)))
        share = np.abs(c) / max(float(np.sum(np.abs(c))), 1e-300)
        weights = {names[k]: float(s) for k, s in zip(others, share)}
        vif = 1.0 / max(1.0 - r2, 1e-12)
        out[t] = {"r2": r2, "vif": vif,
                  "same_part_as": [n for n, s in sorted(weights.items(), key=lambda kv: -kv[1]) if s >= NAME_SHARE]
                  if vif > VIF_LIMIT else [],
                  "weights": weights}
    return out


#: kinds of record that complete one, each a map of the record's operating points (derived from the record's
#: own: the same speeds, loads and positions, changed in one respect)
RECORD_KINDS: dict[str, tuple[str, Callable[[dict], dict]]] = {
    "other_direction": ("the other direction of motion at the same loads",
                        lambda p: {**p, "speed": -p["speed"]}),
    # a quarter, not a half: a constant against a load-proportional torque at loads L and L/2 (equal counts) has
    # R^2 = 0.75^2 / 0.625 = 0.9, exactly the limit; at L and L/4 R^2 = 0.74 (inflation 3.8)
    "second_load_level": ("a second load level (a quarter of the record's loads, same directions)",
                          lambda p: {**p, "load": 0.25 * p["load"]}),
    "opposite_load": ("the loads of the other sign (tensile for compressive), same directions",
                      lambda p: {**p, "load": -p["load"]}),
    "no_load": ("the same motion without load",
                lambda p: {**p, "load": np.zeros_like(p["load"])}),
    "half_speed": ("the same loads and directions at half the speed",
                   lambda p: {**p, "speed": 0.5 * p["speed"]}),
}


def separability(runs: Sequence[RigRun], effects: Sequence[str], params: ParameterSet,
                 base: Mapping[str, str], targets: Mapping[str, str], steps: Mapping[str, float]) -> dict:
    """What this record can tell apart among the constant-torque explainers, and which kind of record would.

    ``base``: parameter -> the effect (or explainer) it belongs to, for what the model carries already (the base
    corrections, the detailed no-back's disk coefficients, the declared drag: held or free, since another record
    would free a held one); ``targets``: parameter -> effect, the constant-torque candidates to report on (a base
    correction's own parameter included: beyond its bound it is a candidate); each target is reproduced by the
    ``base`` parameters other than itself.  ``steps``: the finite step of each parameter (signed).

    Returns ``{"vif_limit", "points", "effects", "record_kinds", "explainers": {param: {effect, r2, vif,
    same_part_as, weights, separated_by: {kind: vif}}}}``: a target with ``vif > vif_limit`` explains on this
    record the same part of the residual as ``same_part_as``; the kinds (single, or two joined by ``+``) with
    ``vif <= vif_limit`` in ``separated_by`` would tell it from them.
    """
    from ..model import resolve_effects

    names = list(dict.fromkeys([n for n in base if n in params] + [n for n in targets if n in params]))
    owner = {**{n: base[n] for n in base}, **{n: targets[n] for n in targets}}
    eff = steady_effects(effects) + tuple(e for e in dict.fromkeys(owner.values()) if e in EFFECTS)
    eff = tuple(resolve_effects(None, add=list(steady_effects(list(dict.fromkeys(eff))))))
    # a parameter of an effect left out (one with dynamic states) changes no steady torque: not an explainer here
    plant = build_plant(None, list(eff), params=params)  # built once: the record's points and every kind's
    have = set(plant.parameters)
    names = [n for n in names if n in have]
    pts = _operating_points(runs)
    S = torque_sensitivities(eff, params, names, pts, steps, plant)
    extra = {k: torque_sensitivities(eff, params, names, fn(pts), steps, plant) for k, (_, fn) in RECORD_KINDS.items()}
    kinds = dict(RECORD_KINDS)
    doc = {"vif_limit": VIF_LIMIT, "points": int(pts["speed"].size), "effects": list(eff),
           "record_kinds": {k: v[0] for k, v in kinds.items()}, "explainers": {}}
    for t in targets:
        if t not in names:
            continue
        cols = [n for n in names if n == t or (n in base and n != t)]
        idx = [names.index(n) for n in cols]
        c = collinearity(S[:, idx], cols, [t]).get(t)
        if c is None:  # the record does not exercise it
            continue
        by = {}
        for k, Sx in extra.items():
            cx = collinearity(np.vstack([S[:, idx], Sx[:, idx]]), cols, [t]).get(t)
            if cx is not None:
                by[k] = cx["vif"]
        if c["vif"] > VIF_LIMIT and not any(v <= VIF_LIMIT for v in by.values()):
            # no single kind does it: two kinds joined
            ks = list(extra)
            for i, a in enumerate(ks):
                for b in ks[i + 1:]:
                    cx = collinearity(np.vstack([S[:, idx], extra[a][:, idx], extra[b][:, idx]]), cols, [t]).get(t)
                    if cx is not None:
                        by[f"{a}+{b}"] = cx["vif"]
        doc["explainers"][t] = {"effect": owner[t], **c, "separated_by": by}
    return doc


def separability_sentences(doc: dict) -> list[str]:
    """Plain sentences for the report: each explainer the record cannot tell apart, with whom, and which kinds of
    record would separate it (none of this is written per effect: it is read off ``doc``)."""
    if not doc:
        return []
    lim = doc["vif_limit"]
    kinds = doc["record_kinds"]

    def say(k):
        return " together with ".join(kinds[x] for x in k.split("+"))

    lines = []
    for t, e in doc["explainers"].items():
        if e["vif"] <= lim:
            continue

        good = sorted(((v, k) for k, v in e["separated_by"].items() if v <= lim))
        bad = [k for k, v in e["separated_by"].items() if v > lim and "+" not in k]
        s = (f"{t} ({e['effect']}) explains the same part of the residual as {', '.join(e['same_part_as'])}: "
             f"they reproduce {100 * e['r2']:.1f} % of its torque over this record's moving samples (variance "
             f"inflation {e['vif']:.3g} > {lim:g}): this record's torques alone cannot tell them apart (where one is "
             "named, the base corrections' plausible bounds decided).")
        if good:
            s += " A record with " + " or ".join(f"{say(k)} (inflation {v:.3g})" for v, k in good) \
                 + " would separate them"
            s += (f"; {', '.join(kinds[k] for k in bad)} would not." if bad else ".")
        elif any("+" in k for k in e["separated_by"]):
            s += " No kind of record tried would separate them, alone or two together."
        else:
            s += " No kind of record tried would separate them alone."
        lines.append(s)
    return lines


def explainer_steps(params: ParameterSet, names: Sequence[str], fitted: Mapping[str, float],
                    magnitude: Mapping[str, float]) -> dict[str, float]:
    """A finite step per parameter: 1e-3 of its reference magnitude (``magnitude``: plausible bound, else the file
    value, else a thousandth of its range), with the sign of its fitted value where that is not zero (a direction
    drag acts one way only)."""
    out = {}
    for n in names:
        ref = max(abs(magnitude.get(n, 0.0)), abs(params.value(n)))
        if not ref > 0:  # neither a plausible magnitude nor a file value: a thousandth of its range
            span = params[n].max - params[n].min
            ref = 1e-3 * span if math.isfinite(span) and span > 0 else 1.0
        v = fitted.get(n, params.value(n))
        out[n] = math.copysign(1e-3 * ref, v if v != 0 else 1.0)
    return out


#: a constant torque beyond the base no larger than this many times the torque a current-sensor offset gives is
#: read as that offset's (:func:`current_offset_torque`): the offset reading biases the active motor's torque by
#: ``Kt I0`` while the model takes the recorded current for every motor's, so the model's torque error lies between
#: one and two times ``Kt I0`` (one or both motors' recorded share)
CURRENT_OFFSET_FACTOR = 2.0


def current_offset_torque(test: Mapping, effects: Sequence[str], params: ParameterSet, values: Mapping[str, Mapping],
                          bounds: Mapping[str, tuple], runs: Sequence[RigRun], kt: float) -> dict | None:
    """Whether a current-sensor offset read with the drive off (``test``: the signature's ``sensor_offset`` test,
    significant) can be the constant torque a candidate finds beyond its plausible bound.

    The current loop regulates the offset reading, so with the drive on the active motor gives ``Kt I0`` less torque
    than the recorded current says, of one sign in both directions of motion: to a model driven by the recorded
    current that is a constant torque no drag or force of the rig has.  ``values``: the candidate's parameters
    beyond their bound (name -> ``value``, ``ci95``), ``bounds``: name -> (lo, hi) of the plausible base; the part
    beyond the bound nearest to it (the 95 % interval's end, the value where there is none) times the parameter's
    torque at the motor (:func:`torque_sensitivities`, mean magnitude over the record's moving samples) is compared
    with ``CURRENT_OFFSET_FACTOR Kt |I0|`` (``estimate_excess_torque``: the same at the estimate, for the report).
    Returns the numbers (``explained``: within it), or None where the record has no moving sample or no parameter
    beyond its bound."""
    names = [n for n in values if n in bounds]
    pts = _operating_points(runs)
    if not names or pts["speed"].size == 0:
        return None
    steps = explainer_steps(params, names, {n: float(values[n]["value"]) for n in names},
                            {n: max(abs(bounds[n][0]), abs(bounds[n][1])) for n in names})
    S = torque_sensitivities(steady_effects(effects), params, names, pts, steps)
    excess = estimate = 0.0
    parts = {}
    for k, n in enumerate(names):
        lo, hi = bounds[n][0], bounds[n][1]
        v = float(values[n]["value"])
        ci = values[n].get("ci95") or [v] * 2

        def outside(u: float) -> float:  # how far u lies beyond the plausible range (0 inside it)
            return max(u - hi, lo - u, 0.0)

        # the least excess the fit allows: its interval's end nearest to the plausible range (0 where it reaches it)
        beyond = min(outside(u) for u in ci)
        sens = float(np.mean(np.abs(S[:, k])))
        t = sens * beyond
        parts[n] = {"beyond_bound": beyond, "torque_at_motor": t, "estimate_torque_at_motor": sens * outside(v)}
        excess += t
        estimate += parts[n]["estimate_torque_at_motor"]
    offset_torque = kt * abs(float(test["offset"]))
    return {"offset_A": float(test["offset"]), "offset_torque": offset_torque, "excess_torque": excess,
            "estimate_excess_torque": estimate, "factor": CURRENT_OFFSET_FACTOR, "parameters": parts,
            "explained": bool(excess <= CURRENT_OFFSET_FACTOR * offset_torque)}
