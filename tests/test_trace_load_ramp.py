"""The residual signature's position tests on a record whose load ramps through the motion (issue #21): an elastic
surface (rig-sim's ``spring_load_ramp``: 30 kN/s while the nut moves) or a load sweep changes the load by more than
the transient threshold within every 0.3 s of the motion, so the plain transient mask left none of its moving
samples and neither position test ran, silently.  There a steady ramp of the load is no transient, only a change of
its rate is (``base_transients(load_steps=True)``, as the candidates' scoring has it).

Synthetic: rig-sim's spring ramp (+12 mm/s out for 1.5 s, stop, back), the load 5 kN plus 2.5 MN/m of travel, the
missing torque planted in the speed residual of a stand-in fit (tests/test_trace_angle.py's way): a friction bump
opposing the motion where the nut crosses 9 mm each way, beside a load-dependent drag and a start transient.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from test_trace_angle import _Plant
from thsa_control.data.rigdata import RigRun
from thsa_control.model.params import default_parameters
from thsa_control.trace.residual import _load_ramp_steady, _signature
from thsa_control.trace.signature import SignatureSettings, base_transients

FS, LEAD, RATIO, J = 1000.0, 0.012, 65.61, 4.2e-4  # rig-sim's record rate, lead, gear ratio; the rotors' inertia
SEG = 0.1  # multiple-shooting segment length [s]


def _speed(t, starts=(1.0, 4.0), length=1.5, top=12e-3, accel=30e-3):
    """Trapezoids of +-``top`` [m/s] (the first out, the second back) starting at ``starts``, ``length`` s each."""
    v = np.zeros_like(t)
    for k, t0 in enumerate(starts):
        tau = t - t0
        up = np.clip(tau * accel, 0.0, top)
        down = np.clip((length + top / accel - tau) * accel, 0.0, top)
        v += (1.0 if k % 2 == 0 else -1.0) * np.where((tau >= 0) & (tau <= length + top / accel),
                                                      np.minimum(up, down), 0.0)
    return v


def _spring(seed: int, bump: float = 0.0, x_c: float = 9e-3, load_drag: float = 4e-7, spring: float = 2.5e6,
            duration: float = 7.0):
    """The spring ramp record and its stand-in fit.  ``bump`` [N m at the motor]: a Gaussian friction bump (0.66 mm
    standard deviation, rig-sim's 1.3 mm width) at ``x_c``; ``load_drag`` [N m/N]: a drag growing with the load (a
    no-back or an efficiency of another rig's base), ``spring`` [N/m] the surface's stiffness (0: a constant load)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1 / FS)
    v = _speed(t)
    x = np.cumsum(v) / FS
    load = 5e3 + spring * x
    sgn = np.sign(v)
    since = t - np.array([max([s for s in (1.0, 4.0) if s <= tt] or [0.0]) for tt in t])
    missing = -sgn * (bump * np.exp(-0.5 * ((x - x_c) / 0.66e-3) ** 2) + load_drag * load
                      + 0.03 * np.exp(-since / 0.1))
    return _stand_in("synthetic_spring", rng, t, v, load, missing, 2.0 + 1e-4 * load * sgn, duration)


def _stand_in(name, rng, t, v, load, missing, current, duration):
    """The record of nut speed ``v`` [m/s] under ``load`` [N] with the ``current`` [A], and a stand-in fit whose speed
    residual is the integral of the ``missing`` torque [N m] over the inertia plus the resolver's white noise (2 rpm,
    rig-sim's at 1 ms), the measured signals with their sensors' noise."""
    w = v * 2 * math.pi * RATIO / LEAD
    x = np.cumsum(v) / FS
    e_w = np.cumsum(missing) / FS / J + 0.2 * rng.standard_normal(t.size)
    w_meas = w + 0.2 * rng.standard_normal(t.size)
    sig = {"motor_speed": w_meas, "nut_position": x + 2e-6 * rng.standard_normal(t.size),
           "load_force": load + 20.0 * rng.standard_normal(t.size), "motor_current": current,
           "temperature": np.full(t.size, 25.0), "primary_enable": (v != 0).astype(float),
           "standby_enable": np.zeros(t.size), "speed_cmd": v}
    run = RigRun(name, Path("synthetic.csv"), Path("synthetic.json"), {}, t, sig, gear_ratio=RATIO,
                 screw_lead=LEAD, source_columns={c: c for c in ("motor_speed", "nut_position", "motor_current")})
    fit = {"predictions": {run.name: {"measured": {"motor_speed": w_meas}, "simulated": {"motor_speed": w_meas - e_w},
                                      "segment_starts": np.arange(0.0, duration, SEG),
                                      "holdout": (np.floor(t / SEG) % 3 == 2)}}}
    return run, fit


def _sig(run, fit):
    return _signature(fit, [run], default_parameters(), _Plant(), SignatureSettings())


def _position_tests(sig):
    return [d for d in sig["tests"] if d["variable"].startswith("nut_position (")]


def test_a_load_ramped_through_the_motion_leaves_steady_samples_for_the_position_tests():
    """On the spring the plain mask leaves no moving sample outside the transients; the load-steps mask leaves the
    middle of each pass, and a constant-load record keeps its plain mask, the same array."""
    s = SignatureSettings()
    run, _ = _spring(1)
    t, w, f = run.time, run.signals["motor_speed"], run.signals["load_force"]
    moving = np.abs(run.signals["speed_cmd"]) > 0
    plain = ~base_transients(t, w, f, s.transient_time)
    assert not np.any(plain & moving)
    used = _load_ramp_steady(t, w, f, plain, s)
    mid = (t > 1.8) & (t < 2.1)  # the out pass's steady speed and load rate (6.7 .. 11.3 mm: 1.76 .. 2.14 s)
    assert used[mid].all() and np.count_nonzero(used & moving) > 700
    assert not used[(t > 1.0) & (t < 1.4)].any()  # the acceleration stays a transient
    run0, _ = _spring(1, spring=0.0)
    t0, w0, f0 = run0.time, run0.signals["motor_speed"], run0.signals["load_force"]
    plain0 = ~base_transients(t0, w0, f0, s.transient_time)
    assert _load_ramp_steady(t0, w0, f0, plain0, s) is plain0


def test_a_friction_bump_on_an_elastic_load_is_tested_where_it_is_and_a_load_drag_alone_is_not_local():
    """A 0.15 N m bump at 9 mm (rig-sim's 10 N m at the screw) crossed each way: the pass-replicated test runs, finds
    it in its bin, opposing the motion.  Without the bump the same record (the drag growing with the load, the
    start transients) is not flagged over five seeds."""
    for seed in range(5):
        out = _sig(*_spring(seed, bump=0.15))
        loc = next(d for d in _position_tests(out) if d["variable"] == "nut_position (repeated over passes)")
        assert loc["significant"] and loc["law"].startswith("dissipative"), loc
        assert loc["peak_bin"][0] - loc["bin_width"] <= 9e-3 <= loc["peak_bin"][1] + loc["bin_width"], loc
        null = _sig(*_spring(seed))
        loc0 = next(d for d in _position_tests(null) if d["variable"] == "nut_position (repeated over passes)")
        assert not loc0["significant"] and loc0["p_value"] > 1e-3, loc0
        assert "nut_position (a place)" not in {d["test"] for d in null["not_tested"]}


def test_a_record_too_short_for_either_position_test_says_so():
    """The spring's passes cut to 0.8 s (4 mm of travel at steady speed and load rate, none outside the
    transients): no position test, and ``not_tested`` names it with the travel the tests saw."""
    run, fit = _spring(3, bump=0.15)
    v = _speed(run.time, length=0.8)
    run.signals["speed_cmd"] = v
    w = v * 2 * math.pi * RATIO / LEAD
    run.signals["motor_speed"] = w
    fit["predictions"][run.name]["measured"]["motor_speed"] = w
    fit["predictions"][run.name]["simulated"]["motor_speed"] = w
    run.signals["nut_position"] = np.cumsum(v) / FS
    run.signals["load_force"] = 5e3 + 2.5e6 * run.signals["nut_position"]
    out = _sig(run, fit)
    assert not _position_tests(out), out["tests"]
    nt = next(d for d in out["not_tested"] if d["test"] == "nut_position (a place)")
    assert nt["would_show"] == "a friction bump or a worn spot" and "14 mm" in nt["why"], nt
    assert all(v < 14e-3 for v in nt["travel_m"].values()), nt


def _sweep(seed: int, ripple: float = 0.0, duration: float = 12.0):
    """rig-sim's load sweep: -10 mm/s from 0.5 s to 11.5 s (30 mm/s^2) while the load follows a triangle of +-29 kN,
    period 10 s; ``ripple`` [N m at the motor] a friction ripple once per screw revolution, ``ripple (1 + sin)``,
    beside a drag growing with the load's magnitude and the start and stop transients."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, duration, 1 / FS)
    ramp = 10e-3 / 30e-3
    v = -np.clip(np.minimum((t - 0.5) / ramp, (11.5 - t) / ramp), 0.0, 1.0) * 10e-3
    x = np.cumsum(v) / FS
    phase = (t % 10.0) / 10.0
    load = 29e3 * (4 * np.abs(phase - 0.5) - 1)
    theta = 2 * math.pi * x / LEAD
    since = np.minimum(np.abs(t - 0.5), np.abs(t - 11.5))
    missing = np.sign(-v) * (ripple * (1 + np.sin(theta + 0.7)) + 2e-7 * np.abs(load) + 0.03 * np.exp(-since / 0.1))
    return _stand_in("synthetic_sweep", rng, t, v, load, missing, 2.0 + 1e-4 * load, duration)


def test_the_angle_tests_on_a_load_sweep_use_its_steady_samples_and_find_a_screw_ripple():
    """On the sweep (110 mm, 9 screw revolutions) the angle tests take the samples outside the transients where a
    steady load ramp is none: a 0.02 N m ripple at the screw's revolution (rig-sim's 1.3 N m at the screw) is
    flagged at its first harmonic and is structure, not "base" by the travel rule; without it the screw angle is
    not flagged over five seeds (the load drag and the transients beside it)."""
    for seed in range(5):
        out = _sig(*_sweep(seed, ripple=0.02))
        sa = next(d for d in out["tests"] if d["variable"] == "screw_angle")
        assert sa["significant"] and sa["dominant_harmonic"] == 1 and sa["remainder"] == "structured", sa
        null = _sig(*_sweep(seed))
        sa0 = next(d for d in null["tests"] if d["variable"] == "screw_angle")
        assert not sa0["significant"], sa0
        assert "why_base" not in sa0, sa0
