"""The sampled-data cascade: shaping limits, position loop, de-energising at zero command."""

import numpy as np
import pytest

from thsa_control.sim.scenarios import Scenario


def test_shaper_respects_rate_and_acceleration_limits(run):
    sc = Scenario("jerk", "step to 10 mm/s with accel 30 mm/s^2 and jerk 300 mm/s^3", 2.0,
                  ((0.0, 0.0), (0.2, 10e-3)), 30e-3, ((0.0, 0.0),), jerk_limit=300e-3)
    res = run(sc, "A", output_period=None)
    v = np.asarray(res["speed_cmd"])
    h = res.info["control_period_s"]
    a = np.diff(v) / h
    j = np.diff(a) / h
    assert np.max(np.abs(a)) <= 30e-3 * (1 + 1e-9)
    assert np.max(np.abs(j)) <= 300e-3 * (1 + 1e-6)
    assert np.max(v) <= 10e-3 * (1 + 1e-9)  # no overshoot of the target
    assert v[-1] == 10e-3  # lands exactly on it
    # a jerk-limited trapezoid takes longer than the rate-limited one by a / j = 0.1 s
    t_reach = res.time[np.argmax(v >= 10e-3)]
    assert t_reach == pytest.approx(0.2 + 10 / 30 + 0.1, abs=2e-3)


def test_motors_off_exactly_while_command_is_zero(run):
    res = run("backdrive_bipolar_ramp", "B")
    off = np.asarray(res["speed_cmd"]) == 0.0
    assert np.all(res["energised_primary"][off] == 0) and np.all(res["energised_primary"][~off] == 1)
    assert np.all(res["motor_voltage"][off] == 0)


def test_position_loop_tracks_a_position_step(run, design):
    sc = Scenario("position", "position step of 2 mm at 0.2 s, P loop", 2.0, ((0.0, 0.0),), 30e-3,
                  ((0.0, 0.0), (0.2, 0.0), (0.5, 5e3)), position_cmd=((0.0, 0.0), (0.2, 0.0), (0.2001, 2e-3)))
    res = run(sc, "B")
    x = np.asarray(res["nut_position"])
    # first order with time constant 1/kp once the speed is no longer limited: 2 mm within 2 % after ~1 s
    assert x[-1] == pytest.approx(2e-3, rel=2e-2)
    assert np.max(np.abs(res["speed_cmd"])) <= design.max_speed * (1 + 1e-9)
    # no overshoot beyond the shaping/integrator transient
    assert np.max(x) < 2e-3 * 1.05
    t = res.time
    early = (t > 0.25) & (t < 0.3)
    assert np.all(np.asarray(res["speed_cmd"])[early] > 0)
