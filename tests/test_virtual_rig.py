"""Virtual rig: runs in thsa-rig-run/1 with known truth, noise and quantisation as asked."""

from __future__ import annotations

import json

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.sim.scenarios import get_scenario
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs


def test_record_reads_back_with_truth(tmp_path, params):
    rig = VirtualRig("B", params=params.replace({"noback.preload": 2500.0}), sample_rate_hz=500.0, seed=4)
    csv_path, json_path = rig.record(get_scenario("cold_ramp"), tmp_path / "cold")
    run = read_run(csv_path)
    meta = json.loads(json_path.read_text())
    assert meta["truth"]["effects"] == ["noback_quadrant_friction"]
    assert meta["truth"]["parameters"]["noback.preload"] == 2500.0
    assert run.controller is not None and run.controller.control_period == 1e-4
    # 3 s at 500 Hz; the sample period is 20 control periods
    assert len(run.time) == 1500 and np.allclose(np.diff(run.time), 2e-3)
    assert run.motor_disabled_when_cmd_zero


def test_noise_and_quantisation_are_as_asked(tmp_path, params):
    """Noisy minus noise-free columns: RMS within 3 % of the asked value (n = 3000, so the
    standard error of an RMS estimate is 1.3 %), mean within 4 standard errors of zero;
    quantised columns are multiples of the step."""
    scenario = get_scenario("cold_ramp")
    clean = VirtualRig("B", sample_rate_hz=1000.0)
    noisy = VirtualRig("B", sample_rate_hz=1000.0, noise={"motor_speed_rpm": 2.0, "load_force_N": 50.0},
                       quantisation={"nut_position_mm": 0.001}, seed=7)
    clean.record(scenario, tmp_path / "clean")
    noisy.record(scenario, tmp_path / "noisy")
    a, b = read_run(tmp_path / "clean.csv"), read_run(tmp_path / "noisy.csv")
    from thsa_control.data.units import rad_s_to_rpm

    for signal, sigma, k in (("motor_speed", 2.0, rad_s_to_rpm(1.0)), ("load_force", 50.0, 1.0)):
        e = (b.signals[signal] - a.signals[signal]) * k
        assert abs(np.sqrt(np.mean(e**2)) / sigma - 1) < 0.03
        assert abs(np.mean(e)) < 4 * sigma / np.sqrt(e.size)
    x_mm = b.signals["nut_position"] * 1e3
    assert np.allclose(x_mm, np.round(x_mm / 0.001) * 0.001, atol=1e-9)
    assert np.max(np.abs(x_mm - a.signals["nut_position"] * 1e3)) <= 0.0005 + 1e-9
    np.testing.assert_array_equal(a.signals["speed_cmd"], b.signals["speed_cmd"])  # commands are exact


def test_seed_reproduces_and_changes(tmp_path):
    u = excitation_inputs(2.0)
    for name, seed in (("a", 1), ("b", 1), ("c", 2)):
        VirtualRig("A", noise={"motor_current_A": 0.05}, seed=seed).record(u, tmp_path / name)
    a, b, c = (read_run(tmp_path / f"{n}.csv").signals["motor_current"] for n in "abc")
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_excitation_shape():
    """Bipolar excitation: +3 mm/s then -3 mm/s plateaus, multisine + PRBS, exact zero at rest."""
    u = excitation_inputs(6.0, bipolar=True, load=12e3)
    v = u.signals["speed_target"]
    t = u.time
    assert v[0] == 0.0 and v[-1] == 0.0
    assert 2e-3 < np.mean(v[(t > 1.0) & (t < 2.4)]) < 4e-3
    assert -4e-3 < np.mean(v[(t > 3.3) & (t < 5.0)]) < -2e-3
    assert np.max(np.abs(v)) <= 3e-3 + 1.01e-3  # multisine peak normalised on a 4096-point grid
    assert u.signals["load_force"][-1] == 12e3


@pytest.mark.parametrize("kwargs, message", [
    ({"noise": {"speed_cmd_mm_s": 1.0}}, "not a sensor column"),
    ({"noise": {"motor_speed_rpm": -1.0}}, "must be a finite number >= 0"),
    ({"sample_rate_hz": 3000.0}, "multiple of the control period"),
])
def test_bad_options_are_named(tmp_path, kwargs, message):
    with pytest.raises(ValueError, match=message):
        VirtualRig("A", **kwargs).record(excitation_inputs(1.0), tmp_path / "x")
    assert not list(tmp_path.iterdir())
