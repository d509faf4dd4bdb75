"""The torque constant drifting in time (issue #21, rig-sim's ``kt_temperature``): the measured current of comparable
passes (same direction, speed command, load and nut positions) changing in proportion to itself over the record.

Synthetic reversal records (fast), the committed rig-sim runs read from their CSVs (no trace, fast), and the test's
level over seeds.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import binom

from thsa_control.data.rigdata import read_run
from thsa_control.model.params import default_parameters
from thsa_control.trace.residual import amps_per_newton, current_drift_of_runs
from thsa_control.trace.signature import (
    STRUCTURED_VARIABLES,
    TORQUE_CONSTANT_DRIFT,
    current_drift_test,
)

DATA = Path(__file__).resolve().parent / "data" / "rigsim"
#: current per newton of nut load through a lossless drive with the file's kinematics and torque constant
APN = 0.012 / (2 * math.pi * 65.61 * 0.324)


def _reversals(seed: int, *, rate=0.0, drag_rate=0.0, levels=(3.0, -3.9), load_drift=0.0, temp_rise=0.0, ar=0.0,
               drag_slope=0.0, wander=0.0, dt=2e-3, sd_i=0.043):
    """A reversal record at 25 kN: +-6 mm/s every 1.2 s from 0.6 s (rig-sim's ``reversals_under_load``), ramps of
    0.2 s.  The current is ``levels`` per direction x (1 + ``rate`` t) + ``drag_rate`` t x direction (a drag drifting
    in time) + ``drag_slope`` x nut position x direction (a drag along the stroke) + noise (``ar`` its lag-1
    correlation).  ``load_drift`` [N/s] moves the load reading only, ``temp_rise`` [K] the housing temperature over
    the record, ``wander`` [s] lengthens every extension so that the stroke creeps (passes cover other positions).
    Returns the arrays of :func:`current_drift_test`."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 10.0, dt)
    v = np.zeros_like(t)
    edge, sign = 0.6, 1.0
    while edge < 9.4:
        length = 1.2 + (wander if sign > 0 else 0.0)
        v[(t >= edge) & (t < min(edge + length, 9.4))] = 0.006 * sign
        edge += length
        sign = -sign
    cmd = v.copy()
    v = np.convolve(v, np.ones(100) / 100, mode="same")  # 0.2 s ramps
    w = v * 2 * np.pi / 0.012 * 65.61 + 0.3 * rng.standard_normal(t.size)
    x = np.cumsum(v) * dt
    d = np.sign(cmd)
    lev = np.where(d > 0, levels[0], np.where(d < 0, levels[1], 0.0))
    e = rng.standard_normal(t.size)
    if ar:  # AR(1) of unit variance: e_k = ar e_(k-1) + sqrt(1 - ar^2) u_k
        from scipy.signal import lfilter

        e = lfilter([math.sqrt(1 - ar**2)], [1.0, -ar], e)
    i = lev * (1 + rate * t) + drag_rate * t * d + drag_slope * x * d + sd_i * e
    f = 25e3 + load_drift * t + 25.0 * rng.standard_normal(t.size)
    temp = 25.0 + temp_rise * t / t[-1]
    return t, i, w, f, cmd, x, temp


def _test(rec, **kw):
    kw.setdefault("alpha", 1e-6)
    t, i, w, f, cmd, x, temp = rec
    return current_drift_test(t, i, w, f, cmd, x, temp, amps_per_newton=APN, **kw)


def test_the_variable_is_a_structured_remainder():
    assert TORQUE_CONSTANT_DRIFT in STRUCTURED_VARIABLES


def test_amps_per_newton_is_the_file_torque_constant_through_the_kinematics():
    assert amps_per_newton(default_parameters(), 0.012, 65.61) == pytest.approx(APN, rel=1e-3)


def test_a_current_proportional_drift_is_named_with_its_rate():
    """-1e-3 /s of itself (the rotor cooling by about 1 K/s at -0.12 %/K): named, the rate within 3 standard errors,
    over the 4 + 3 passes of the two operating points."""
    d = _test(_reversals(1, rate=-1e-3))
    assert d is not None and d["significant"] and d["verdict"] == "torque constant", d["verdict"]
    assert d["variable"] == TORQUE_CONSTANT_DRIFT
    assert abs(d["relative_rate"] + 1e-3) < 3 * d["stderr"], (d["relative_rate"], d["stderr"])
    assert sorted(len(c["passes"]) for c in d["classes"]) == [3, 4]


def test_no_drift_is_not_named():
    d = _test(_reversals(2))
    assert d is not None and not d["significant"] and d["verdict"] == "no current-proportional drift"


def test_a_drifting_load_reading_splits_the_operating_points():
    """A load cell drifting at 40 N/s with the current constant: passes 2.4 s apart read loads 96 N apart, four times
    the load whose current is one level's standard error; no operating point is compared, nothing named."""
    d = _test(_reversals(3, load_drift=40.0))
    assert d is None or not d["significant"]


def test_a_drag_along_the_stroke_is_no_drift_when_the_stroke_creeps():
    """The stroke creeps by 0.3 s of travel per cycle and the current grows along it (a drag rising 0.1 A/mm): the
    passes' levels over their own positions would trend in time; compared over the positions all cover they do
    not."""
    d = _test(_reversals(4, drag_slope=100.0, wander=0.3))
    assert d is None or not d["significant"], d and (d["relative_rate"], d["p_value"], d["classes"])


def test_a_housing_temperature_change_is_not_named_a_torque_constant():
    """The same drift while the housing warms by 8 K (more than the signature's 5 K for a temperature dependence): a
    drag following the lubricant's temperature explains it as well: significant drift, not named."""
    d = _test(_reversals(5, rate=-1e-3, temp_rise=8.0))
    assert d["p_value"] < 1e-6 and d["verdict"] == "housing temperature" and not d["significant"]


def test_a_drag_drifting_in_time_is_told_from_a_torque_constant_where_the_currents_differ():
    """Operating points of very different currents (+1 A extending, -6 A retracting): a drag drifting by 4 mA/s in
    each direction is one absolute rate, which the current-proportional law does not fit (its levels scatter about
    it by 8 times their noise); the drag law explains it beyond the torque constant's, and nothing is named."""
    d = _test(_reversals(7, drag_rate=-4e-3, levels=(1.0, -6.0)))
    alt = d["drag_alternative"]
    assert alt["vif"] < 10 and alt["p_value"] < 1e-6, alt
    assert alt["drag_beyond_torque_constant_p"] < alt["torque_constant_beyond_drag_p"], alt
    assert d["verdict"] != "torque constant" and not d["significant"], (d["verdict"], alt)
    # and the current-proportional drift on the same operating points is named
    d = _test(_reversals(6, rate=-1e-3, levels=(1.0, -6.0)))
    assert d["verdict"] == "torque constant" and d["significant"], (d["verdict"], d["drag_alternative"])


def test_a_drift_of_one_operating_point_only_is_not_a_torque_constant():
    """The extending current drifts by -1.5e-3 /s of itself, the retracting one not at all (a drag of one quadrant
    drifting, as the rig base's no-back drags only while the motor drives against the load): the retracting passes
    resolve the shared rate and do not show it; not named."""
    t, i, w, f, cmd, x, temp = _reversals(11)
    i = np.where(cmd > 0, i + 3.0 * -1.5e-3 * t, i)
    d = _test((t, i, w, f, cmd, x, temp))
    assert not d["significant"] and d["verdict"] != "torque constant", (d["verdict"], d["per_class"])


@pytest.mark.slow
@pytest.mark.parametrize("ar", [0.0, 0.8])
def test_level_over_seeds(ar):
    """No drift, white or AR(1) 0.8 current noise: the rate's p is uniform enough that the rejection rate at 0.05
    lies in the binomial 99.9 % band of 300 seeds (or below it: the overdispersion rule only widens)."""
    n = 300
    ps = np.array([_test(_reversals(1000 + s, ar=ar))["p_value"] for s in range(n)])
    lo, hi = binom.ppf(0.0005, n, 0.05), binom.ppf(0.9995, n, 0.05)
    assert int(np.sum(ps < 0.05)) <= hi, np.sum(ps < 0.05)
    assert int(np.sum(ps < 0.05)) >= lo - 5, np.sum(ps < 0.05)  # not grossly conservative either


# ---- the committed rig-sim runs (records only, no trace)
def _record_test(name: str):
    return current_drift_of_runs([read_run(DATA / f"{name}.csv")], default_parameters())


def _rotor_rate(name: str, d: dict) -> float:
    """The relative rate of the current the truth's thermal model gives over the compared passes: the rotor's rise
    integrated from the record's own current (rig-sim README: tau dT/dt = r_th P_cu - dT, P_cu = 1.5 R i^2, flux x (1 +
    alpha (T - 20)), R x (1 + alpha_R (T - 20))), the current scaling as 1 / flux, its slope over the passes' times."""
    truth = json.loads((DATA / f"{name}.truth.json").read_text())
    kp = {k: v["si"] for k, v in truth["effects"]["kt_temperature"]["params"].items()}
    r0 = truth["parameters"]["R_stator_ohm"]["value"]
    run = read_run(DATA / f"{name}.csv")
    t = np.asarray(run.time, float)
    i = np.asarray(run.signals["motor_current"], float)
    th = np.asarray(run.signals["temperature"], float)
    rise = np.empty_like(t)
    r = kp["initial_rise_K"]
    for k in range(t.size):
        rise[k] = r
        if k + 1 < t.size:
            res = r0 * (1 + kp["alpha_R_per_K"] * (th[k] + r - 20))
            r += (t[k + 1] - t[k]) * (1.5 * res * i[k] ** 2 * kp["r_th_K_W"] - r) / kp["tau_th_s"]
    scale = 1.0 / (1 + kp["alpha_flux_per_K"] * (th + rise - 20))
    times = [p["time"] for c in d["classes"] for p in c["passes"]]
    m = (t >= min(times)) & (t <= max(times))
    return float(np.polyfit(t[m], scale[m], 1)[0] / np.mean(scale[m]))


def test_the_rotor_cooling_on_rig_sim_reversals_is_named():
    """rig_kt_temperature_reversals (rotor 40 K above the housing at the start, cooling at 25 s): named, and the rate
    is the truth's thermal model's within 3 standard errors."""
    d = _record_test("rig_kt_temperature_reversals")
    assert d is not None and d["significant"], d and (d["p_value"], d["verdict"])
    expected = _rotor_rate("rig_kt_temperature_reversals", d)
    assert expected < 0
    assert abs(d["relative_rate"] - expected) < 3 * d["stderr"], (d["relative_rate"], d["stderr"], expected)


@pytest.mark.parametrize("name", sorted(p.stem for p in DATA.glob("*.csv") if p.stem != "rig_kt_temperature_reversals"))
def test_no_other_committed_run_is_named(name):
    """Every other committed rig-sim run (nulls, library effects, the other out-of-library effects: the load-cell
    drift, the cold friction, the Kt run of one pass per direction): not named."""
    d = _record_test(name)
    assert d is None or not d["significant"], (d["relative_rate"], d["p_value"], d["verdict"])


def test_the_report_panel_draws_the_passes_and_the_shared_rate():
    """The signature figure's panel: each comparable pass's current relative to its operating point's level against
    time, per operating point, with the shared rate and the verdict."""
    import matplotlib

    matplotlib.use("Agg")
    from thsa_control.report.trace import plot_signature

    d = _record_test("rig_kt_temperature_reversals")
    fig = plot_signature({"tests": [d], "curves": {}})
    ax = next(a for a in fig.get_axes() if "comparable passes" in a.get_title())
    assert any("torque constant (STRUCTURED)" in t.get_text() for t in ax.texts)
    labels = ax.get_legend_handles_labels()[1]
    assert any(lb.startswith("extending") for lb in labels) and any(lb.startswith("retracting") for lb in labels)


def test_each_run_of_a_set_has_its_own_passes():
    """Two runs glued end to end (``group``): a reversal record at 6 mm/s and one 30 x faster.  Each run's passes come
    from its own samples: the slow run keeps the passes it has alone (glued, its whole motion lay inside the fast
    run's stop band, 5 % of the largest speed, and it had none)."""
    slow = _reversals(3)
    fast = list(_reversals(4))
    fast[2] = fast[2] * 30.0  # motor speed
    fast[4] = fast[4] * 30.0  # speed command
    fast[0] = fast[0] + slow[0][-1] + 1.0
    glued = [np.concatenate([a, b]) for a, b in zip(slow, fast)]
    grp = np.r_[np.zeros(slow[0].size), np.ones(fast[0].size)]
    t, i, w, f, cmd, x, temp = glued
    both = current_drift_test(t, i, w, f, cmd, x, temp, group=grp, amps_per_newton=APN)
    alone = _test(slow)
    got = [[(p["start"], p["end"]) for p in c["passes"]] for c in both["classes"] if c["group"] == 0.0]
    want = [[(p["start"], p["end"]) for p in c["passes"]] for c in alone["classes"]]
    assert got and got == want


def test_a_pass_never_spans_two_runs_of_a_set():
    """One reversal record cut in two runs in the middle of a steady extension (time, direction, command and load
    continuous across the cut): no pass of the set crosses the cut, and a class holds one run's passes only (the
    docstring's "same direction and group"), where the record as one run has a pass across it."""
    rec = _reversals(6)
    t = rec[0]
    cut = int(np.searchsorted(t, 6.1))  # inside the third extension (steady 5.7-6.3 s)
    whole = _test(rec)
    assert any(p["start"] < t[cut] < p["end"] for c in whole["classes"] for p in c["passes"])
    grp = (np.arange(t.size) >= cut).astype(float)
    d = current_drift_test(*rec, group=grp, amps_per_newton=APN)
    for c in d["classes"]:
        for p in c["passes"]:
            assert (p["end"] < t[cut]) == (c["group"] == 0.0) and (p["start"] >= t[cut]) == (c["group"] == 1.0), p


def test_the_pass_breaking_the_common_range_is_dropped():
    """Four extensions at one operating point: three over 0-10, 0-10 and 2-6 mm, one long one over 9-30 mm.  The long
    one breaks the common range; dropping it leaves 2-6 mm for the other three (dropping the shortest first, as
    before, emptied the class)."""
    dt, v = 2e-3, 0.006
    rng = np.random.default_rng(5)
    cols = {k: [] for k in ("t", "w", "cmd", "x")}
    t0 = 0.0
    for a, b in ((0.0, 0.010), (0.0, 0.010), (0.002, 0.006), (0.009, 0.030)):
        for moving, dur in ((False, 1.0), (True, (b - a) / v + 0.8)):
            tt = t0 + np.arange(0.0, dur, dt)
            cols["t"].append(tt)
            cols["w"].append(np.full(tt.size, v * 2 * np.pi / 0.012 * 65.61 if moving else 0.0))
            cols["cmd"].append(np.full(tt.size, v if moving else 0.0))
            cols["x"].append(a + v * (tt - t0 - 0.4) if moving else np.full(tt.size, a))
            t0 = tt[-1] + dt
    t, w, cmd, x = (np.concatenate(cols[k]) for k in ("t", "w", "cmd", "x"))
    i = np.where(cmd > 0, 3.0, 0.0) + 0.043 * rng.standard_normal(t.size)
    f = 25e3 + 25.0 * rng.standard_normal(t.size)
    d = current_drift_test(t, i, w, f, cmd, x, amps_per_newton=APN)
    assert d is not None and len(d["classes"]) == 1
    c = d["classes"][0]
    assert len(c["passes"]) == 3
    lo, hi = c["position_range"]  # the short pass's steady travel (its 0.3 s start transient off): ~1.4-6.6 mm
    assert 0.001 < lo < hi < 0.007 and hi - lo > 0.004, (lo, hi)


def test_a_drift_that_one_operating_point_resolves_is_not_named_without_the_drag_told_apart():
    """Extending at 3 A, retracting at 0.05 A (a small current does not resolve a relative rate): only the extending
    passes resolve the -1e-3 /s drift, and a drag of that point drifting in time fits it as well (not told apart
    at the level): "every resolving point shows it" is then one point, and no torque constant is named.  The same
    drift on two resolving points is."""
    d = _test(_reversals(3, rate=-1e-3, levels=(3.0, -0.05)))
    assert d["p_value"] < 1e-6 and sum(c["resolves_shared_rate"] for c in d["per_class"]) == 1
    assert not d["significant"] and d["verdict"] == "one operating point, not told from a drag", d["verdict"]
    d = _test(_reversals(3, rate=-1e-3, levels=(3.0, -3.9)))
    assert d["significant"] and d["verdict"] == "torque constant"
