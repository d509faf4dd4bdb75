"""MATLAB exports (issue #18 item 8): linear models and simulation results round-trip through .mat files."""

from __future__ import annotations

import numpy as np
import pytest

import thsa_control as thsa
from thsa_control.data.matfile import (MAT_FORMAT, linear_model_to_mat, plant_units, read_mat, simulation_to_mat,
                                       statespace_to_mat, write_mat)


def test_linear_model_round_trips_with_names_units_and_operating_point(tmp_path):
    model = thsa.plant_model("A", ())
    cond = thsa.OperatingCondition(5e-3, 20e3, -30.0)
    lin = thsa.linearize_conditions(model, [cond])[0]
    path = write_mat(tmp_path / "model", linear_model_to_mat(lin, units=plant_units(model.plant), condition=cond))
    assert path.suffix == ".mat"
    m = read_mat(path)
    assert m["format"] == MAT_FORMAT and m["Ts"] == 0.0
    for k in "ABCD":
        np.testing.assert_array_equal(np.atleast_2d(m[k]).reshape(getattr(lin, k).shape), getattr(lin, k))
    assert m["states"] == list(lin.states) and m["inputs"] == list(lin.inputs) and m["outputs"] == list(lin.outputs)
    assert m["state_units"][lin.states.index("motor_speed")] == "rad/s"
    op = m["op"]
    assert op["nut_speed_m_s"] == 5e-3 and op["load_force_N"] == 20e3 and op["temperature_C"] == -30.0
    np.testing.assert_allclose(op["x"], lin.operating_point.x)
    assert op["x_names"] == list(lin.operating_point.states)


def test_discrete_loop_round_trips_with_its_sample_period(tmp_path):
    L = thsa.open_loop("velocity", (10e-3, 20e3, 25.0))
    m = read_mat(write_mat(tmp_path / "L.mat", statespace_to_mat(L)))
    assert m["Ts"] == pytest.approx(L.dt) and m["inputs"] == ["speed_error"] and m["outputs"] == ["motor_speed"]
    np.testing.assert_array_equal(m["A"], L.A)


def test_simulation_round_trips(tmp_path):
    design = thsa.load_design(thsa.nominal_design_path())
    res = thsa.simulate(thsa.get_scenario("cold_ramp"), design, thsa.default_parameters(), level="A")
    m = read_mat(write_mat(tmp_path / "run.mat", simulation_to_mat(res, level="A", temperature_C=-30.0)))
    np.testing.assert_array_equal(m["time"], res.time)
    np.testing.assert_array_equal(m["signals"]["nut_speed"], res["nut_speed"])
    assert m["units"]["nut_speed"] == "m/s" and m["level"] == "A" and m["scenario"] == res.name
    assert set(m["signals"]) == {n for n in res.names}  # every signal, under a MATLAB-valid name


def test_cli_linearize_takes_kilonewtons_and_writes_mat(tmp_path, capsys):
    from thsa_control.cli import main
    from thsa_control.cli.analysis import load_newtons

    assert load_newtons("20") == 20e3 and load_newtons("-55") == -55e3 and load_newtons("20kN") == 20e3
    assert load_newtons("20000N") == 20e3
    out = tmp_path / "m.mat"
    assert main(["linearize", "--level", "A", "--speed", "5", "--load", "20", "--temperature", "-30",
                 "--save", str(out)]) == 0
    captured = capsys.readouterr()
    assert "5 mm/s, 20 kN (opposing), -30 degC" in captured.out and "note:" not in captured.err
    assert read_mat(out)["op"]["load_force_N"] == 20e3
    # the old form (N) still works, with a note naming the new one
    assert main(["linearize", "--level", "A", "--speed", "5", "--load", "20000", "--temperature", "-30"]) == 0
    captured = capsys.readouterr()
    assert "20 kN (opposing)" in captured.out and "--load 20" in captured.err
    assert main(["linearize", "--level", "A", "--speed", "5", "--load", "abc"]) == 2
