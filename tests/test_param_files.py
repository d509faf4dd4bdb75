"""Silent wrong results from input files (issue #7, item 4): parameter files and rig JSON/CSV contradictions.

Before this fix: ``unit = "mOhm"`` was simulated as ohms; an override could
widen bounds (efficiency 1.5 accepted); ``true``, ``"1.3"``, ``vary = "yes"``
and ``pole_pairs = 3.5`` were accepted; a rig JSON could contradict its CSV
(sample rate, temperature) and a run with loads in kN was read as newtons.

The rig runs here are not made by our model: a hand-written quasi-static
actuator (torque constant 0.28 N m/A, efficiency 0.8, Coulomb current
0.15 A, sensor noise) with FORMAT kinematics.
"""

import math

import numpy as np
import pytest

from thsa_control.cli import main
from thsa_control.data.rigdata import read_run, write_run
from thsa_control.errors import ParameterError, RigDataError
from thsa_control.model.params import Parameter, ParameterSet, default_parameters, load_parameters


@pytest.fixture(scope="module")
def base():
    return default_parameters()


def override(base, text, tmp_path=None):
    return ParameterSet.from_toml(text, source_name="over.toml", base=base)


# ---------------------------------------------------------------- units
def test_milliohm_is_converted(base):
    p = override(base, '[motor]\nresistance = { value = 1300.0, unit = "mOhm" }\n')
    r = p["motor.resistance"]
    assert math.isclose(r.value, 1.3) and r.unit == "Ohm"
    assert 'unit = "Ohm"' in p.to_toml() and "mOhm" not in p.to_toml()  # saved in the parameter's own unit


def test_milliohm_value_of_ohm_size_is_refused_not_simulated(base):
    # 1.23 mOhm is 0.00123 Ohm: below the motor's physical range, refused (never simulated as 1.23 Ohm)
    with pytest.raises(ParameterError, match=r"motor.resistance.*0.00123 Ohm outside"):
        override(base, '[motor]\nresistance = { value = 1.23, unit = "mOhm" }\n')


@pytest.mark.parametrize("text, fragment", [
    ('[motor]\nresistance = { value = 1.23, unit = "V" }\n', "cannot be converted"),
    ('[motor]\ninductance = { value = 2.25, unit = "furlong" }\n', "cannot be converted"),
    ('[gear]\nratio = { value = 65.61, unit = "mm" }\n', "cannot be converted"),
])
def test_unknown_or_wrong_dimension_units_are_refused(base, text, fragment):
    with pytest.raises(ParameterError, match=fragment):
        override(base, text)


def test_other_units_convert(base):
    p = override(base, '[motor]\ninductance = { value = 2.0, unit = "mH" }\n[screw]\nlead = { value = 10.0, unit = "mm" }\n'
                       '[loadpath]\ncontact_stiffness_upper = { value = 50.0, unit = "kN/mm" }\n')
    assert math.isclose(p.value("motor.inductance"), 2e-3)
    assert math.isclose(p.value("screw.lead"), 0.010)
    assert math.isclose(p.value("loadpath.contact_stiffness_upper"), 5e7)


# ---------------------------------------------------------------- physical bounds
@pytest.mark.parametrize("text", [
    "[gear]\nefficiency = 1.5\n",
    "[gear]\nefficiency = { value = 1.5, max = 2.0 }\n",
    "[screw]\nefficiency_direct = { value = 0.9, max = 1.2 }\n",
    "[surface]\nmass = { value = -5.0, min = -10.0 }\n",
    "[motor]\nrotor_inertia = { value = 1e-4, min = -1.0 }\n",
])
def test_override_cannot_move_a_physical_bound(base, text):
    with pytest.raises(ParameterError, match="outside its bounds|widen the physical bounds"):
        override(base, text)


def test_override_may_narrow_the_search_bounds(base):
    p = override(base, "[gear]\nefficiency = { value = 0.9, min = 0.8, max = 0.95, vary = true }\n")
    e = p["gear.efficiency"]
    assert (e.min, e.max, e.hard_min, e.hard_max, e.vary) == (0.8, 0.95, 0.0, 1.0, True)
    assert e.valid == "(0, 1]"
    with pytest.raises(ParameterError, match=r"gear.efficiency.*\(0, 1\]"):
        e.with_value(1.01)  # outside the physical bounds
    moved = e.with_value(0.97)  # physically valid, outside the search bounds: they move with the value
    assert moved.min <= 0.97 <= moved.max <= 1.0


def test_api_parameter_cannot_be_built_outside_its_hard_bounds():
    with pytest.raises(ParameterError, match="widen"):
        Parameter("x.eff", 0.9, "-", "assumed: test", min=0.0, max=1.5, hard_min=0.0, hard_max=1.0)


# ---------------------------------------------------------------- types
@pytest.mark.parametrize("text, fragment", [
    ("[motor]\nresistance = true\n", "not a number"),
    ('[motor]\nresistance = "1.3"\n', "not a number"),
    ('[motor]\nresistance = { value = 1.3, vary = "yes" }\n', "vary 'yes' must be true or false"),
    ("[motor]\npole_pairs = 3.5\n", "whole number"),
    ('[motor]\nresistance = { value = 1.3, min = "0" }\n', "min '0' is not a number"),
    ("[motor]\nresistance = { value = 1.3, source = 5 }\n", "must be a string"),
    ("[motor]\nresistance = { value = 1.3, unit = 1 }\n", "must be a string"),
    ("[motor]\npole_pairs = { value = 3.0, integer = false }\n", "'integer' cannot be changed"),
])
def test_every_field_is_type_checked(base, text, fragment):
    with pytest.raises(ParameterError, match=fragment):
        override(base, text)


def test_integer_parameter_accepts_whole_numbers(base):
    assert override(base, "[motor]\npole_pairs = 4\n").value("motor.pole_pairs") == 4.0


def test_non_utf8_and_nested_parameter_files(tmp_path, base):
    f = tmp_path / "p.toml"
    f.write_bytes(b"[motor]\nresistance = 1.3 # \xe9\n")
    with pytest.raises(ParameterError, match="not UTF-8"):
        load_parameters(f, base=base)
    f.write_text("a = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(ParameterError, match="p.toml"):
        load_parameters(f, base=base)


def test_cli_refuses_a_bad_parameter_file(tmp_path, capsys):
    f = tmp_path / "p.toml"
    f.write_text('[motor]\nresistance = { value = 1.23, unit = "mOhm" }\n')
    out = tmp_path / "o"
    assert main(["simulate", "--scenario", "cold_ramp", "--level", "A", "--quiet", "--params", str(f),
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "motor.resistance" in err and "Traceback" not in err and not out.exists()


# ---------------------------------------------------------------- rig runs
LEAD, RATIO = 0.012, 65.61


def other_actuator_run(rng, *, n=6000, rate=1000.0, load_scale=1.0, max_load=20e3):
    """FORMAT columns of a quasi-static actuator that is not our model (Kt 0.28, eff 0.8, Coulomb 0.15 A)."""
    t = np.arange(n) / rate
    cmd = 3.0 * np.sign(np.sin(2 * np.pi * t / 2.0))  # mm/s, reversing every second
    cmd[np.abs(np.sin(2 * np.pi * t / 2.0)) < 0.05] = 0.0
    load = max_load * (0.2 + 0.8 * t / t[-1])  # N, compressive, rising over the run
    torque = load * LEAD / (2 * np.pi * RATIO * 0.8)  # N m at the motor, opposing extension
    current = np.sign(cmd) * (0.15 + np.abs(torque) / 0.28) + 0.02 * rng.standard_normal(n)
    return {"time_s": t, "speed_cmd_mm_s": cmd, "load_force_N": load * load_scale + 50 * load_scale * rng.standard_normal(n),
            "motor_speed_rpm": 328.05 * cmd + 2.0 * rng.standard_normal(n), "motor_current_A": current}


META = {"temperature_C": 20.0, "sample_rate_hz": 1000.0}


def test_loads_in_newtons_are_read(tmp_path):
    rng = np.random.default_rng(1)
    csv, _ = write_run(tmp_path / "n", other_actuator_run(rng), META)
    assert read_run(csv).signals["load_force"].max() > 15e3


def test_loads_in_kilonewtons_are_refused(tmp_path):
    rng = np.random.default_rng(2)
    with pytest.raises(RigDataError, match="load_force_N looks like kN"):
        write_run(tmp_path / "kn", other_actuator_run(rng, load_scale=1e-3), META)


def test_unloaded_run_in_newtons_is_not_taken_for_kilonewtons(tmp_path):
    rng = np.random.default_rng(3)
    cols = other_actuator_run(rng, max_load=0.0)
    cols["load_force_N"] = 30.0 * rng.standard_normal(cols["time_s"].size)  # sensor noise only
    csv, _ = write_run(tmp_path / "u", cols, META)
    assert read_run(csv).warnings == ()


@pytest.mark.parametrize("rate", [500.0, 2000.0, 1200.0])
def test_sample_rate_contradicting_the_time_column_is_refused(tmp_path, rate):
    rng = np.random.default_rng(4)
    with pytest.raises(RigDataError, match="contradicts the JSON's sample_rate_hz"):
        write_run(tmp_path / "r", other_actuator_run(rng), {**META, "sample_rate_hz": rate})


def test_sample_rate_agreeing_within_tolerance_is_read(tmp_path):
    rng = np.random.default_rng(5)
    csv, _ = write_run(tmp_path / "r", other_actuator_run(rng), {**META, "sample_rate_hz": 1050.0})
    assert read_run(csv).sample_rate_hz == 1050.0


def test_temperature_column_contradicting_the_json_is_refused(tmp_path):
    rng = np.random.default_rng(6)
    cols = other_actuator_run(rng)
    cols["temperature_C"] = -30.0 + 0.5 * rng.standard_normal(cols["time_s"].size)
    with pytest.raises(RigDataError, match="contradicts the JSON's temperature_C = 25"):
        write_run(tmp_path / "t", cols, {**META, "temperature_C": 25.0})
    csv, _ = write_run(tmp_path / "t", cols, {**META, "temperature_C": -30.0})
    assert abs(read_run(csv).signals["temperature"].mean() + 30.0) < 0.1
