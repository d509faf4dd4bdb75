"""A plain ball-screw positioning axis (issue #11, "Rigs other than the papers' actuator cannot be described").

One small motor on a 1:1 coupling, a 5 mm lead screw, a light carriage; no
no-back, no load cell; a position P loop around a P-only velocity loop, and a
current added at the controller output.  Checked here:

* the parameter file of such a rig loads although its values lie outside the
  papers' search bounds (physical validity bounds are separate); physically
  invalid values are refused, naming the parameter;
* the run's JSON holds the position loop and the controller-output current
  (``controller.position_loop``, ``controller.current_feedforward``): the
  virtual rig writes them, the reader validates them (file, key, value
  named), the closed-loop replay closes the same loop, so write -> read ->
  replay reproduces the run to the sensor noise, and without them it does not;
* the kinematics: a run stating other kinematics than the parameter set is
  refused, naming both values; a run stating none takes the parameter set's;
* the plain drive identifies (a rotor inertia below the papers' search bound,
  Coulomb friction, a force offset) from the current-driven mechanics.
"""

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest

from thsa_control.cli import main
from thsa_control.data.rigdata import read_run
from thsa_control.errors import ParameterError, RigDataError
from thsa_control.fit.identify import IdentificationSettings, Identifier
from thsa_control.fit.kinematics import run_kinematics
from thsa_control.fit.replay import replay_closed_loop, run_design, run_inputs
from thsa_control.fit.virtual_rig import VirtualRig, position_inputs
from thsa_control.loops.design import Design
from thsa_control.model import build_plant
from thsa_control.model.params import ParameterSet, default_parameters, load_parameters

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "plain_ball_screw.toml"
EFFECTS = ("coulomb_friction", "force_offset")  # on level None: no no-back
NOISE = {"motor_speed_rpm": 0.5, "nut_position_mm": 0.001, "motor_current_A": 0.01}
TRUTH = {"motor.rotor_inertia": 8e-7, "drive.coulomb_torque": 0.02, "drive.axial_force_offset": 20.0}


def plain_params() -> ParameterSet:
    """The example file, made a miniature axis (light screw and carriage: the rotor is a third of the inertia)."""
    p = load_parameters(EXAMPLE, base=default_parameters())
    return p.replace({"screw.inertia": 1e-6, "surface.mass": 1.0, "loadpath.mass": 0.2})


def plain_design() -> Design:
    """P velocity loop (ki = 0) inside a position P loop; current PI for the small motor (1.3 ms L/R)."""
    return Design("plain axis", current_kp=7.5, current_ki=5600.0, velocity_kp=0.02, velocity_ki=0.0,
                  current_limit=6.0, position_kp=30.0, control_period=1e-4, voltage_limit=27.0, max_speed=0.1)


def plain_inputs():
    """Moves both ways; a 0.3 A pulse (10 ms ramps: the 1 kHz column resolves it) added at the controller
    output on top of a 0.05 A offset."""
    return position_inputs([0, 0.2, 0.7, 1.0, 1.5, 2.0], [0, 0, 0.02, 0.02, -0.005, -0.005],
                           current_ff=lambda t: 0.05 + np.interp(t, [0.8, 0.81, 1.3, 1.31], [0, 0.3, 0.3, 0]),
                           accel_limit=2.0)


@pytest.fixture(scope="module")
def truth_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("plain")
    rig = VirtualRig(None, EFFECTS, params=plain_params().replace(TRUTH), design=plain_design(), noise=NOISE, seed=3)
    csv, _ = rig.record(plain_inputs(), d / "plain_moves")
    return csv


# ---------------------------------------------------------------- parameters: physical vs search bounds
def test_plain_parameter_file_loads_outside_the_papers_search_bounds():
    base = default_parameters()
    p = plain_params()
    j = p["motor.rotor_inertia"]
    assert j.value == 6e-7 < base["motor.rotor_inertia"].min  # below the papers' search bound (1e-6)
    assert j.min <= j.value <= j.max and j.min > 0  # search bounds moved with the value, inside (0, inf)
    assert (p.value("gear.ratio"), p.value("screw.lead")) == (1.0, 0.005)
    # the papers' value reflected to a plain drive's carriage: J (2 pi N / p)^2; the old bound alone was a tonne
    assert base["motor.rotor_inertia"].min * (2 * math.pi * 65.61 / 0.012) ** 2 > 1000.0


@pytest.mark.parametrize("text, name, fragment", [
    ("[screw]\nefficiency_direct = 1.2\n", "screw.efficiency_direct", r"\(0, 1\]"),
    ("[motor]\nrotor_inertia = 0.0\n", "motor.rotor_inertia", r"\(0, inf\)"),
    ("[gear]\nratio = -2.0\n", "gear.ratio", r"\(0, inf\)"),
    ("[surface]\nmass = { value = 5.0, min = -1.0 }\n", "surface.mass", "widen the physical bounds"),
    ('[gear]\nefficiency = { value = 0.9, valid = "(0, 1.5]" }\n', "gear.efficiency", "widen the physical bounds"),
    ('[gear]\nefficiency = { value = 0.9, valid = "0..1" }\n', "gear.efficiency", "not an interval"),
])
def test_physically_invalid_values_are_refused_naming_the_parameter(text, name, fragment):
    with pytest.raises(ParameterError, match=rf"{name}.*{fragment}"):
        ParameterSet.from_toml(text, source_name="plain.toml", base=default_parameters())


def test_a_narrower_valid_interval_and_its_round_trip():
    p = ParameterSet.from_toml('[gear]\nefficiency = { value = 0.5, valid = "[0.4, 0.99]" }\n', source_name="x",
                               base=default_parameters())
    e = p["gear.efficiency"]
    assert (e.hard_min, e.hard_max, e.valid) == (0.4, 0.99, "[0.4, 0.99]")
    again = load_parameters_text(p.to_toml())
    assert again["gear.efficiency"] == e and again["motor.rotor_inertia"] == p["motor.rotor_inertia"]


def load_parameters_text(text):
    return ParameterSet.from_toml(text, source_name="again.toml", base=default_parameters())


def test_plain_parameter_file_round_trips_with_its_bounds(tmp_path):
    p = plain_params()
    path = p.save(tmp_path / "p.toml")
    assert load_parameters(path, base=default_parameters()) == p  # a saved whole set replays alone


def test_per_fit_search_bounds_inside_the_physical_ones(truth_run):
    p = plain_params()
    with pytest.raises(ParameterError, match=r"gear.efficiency.*widen the physical bounds"):
        Identifier(None, p, ["gear.efficiency"], effects=EFFECTS, bounds={"gear.efficiency": (0.5, 1.2)},
                   settings=IdentificationSettings(max_nfev=0)).fit(read_run(truth_run))
    with pytest.raises(ParameterError, match=r"motor.rotor_inertia.*do not contain the initial value"):
        Identifier(None, p, ["motor.rotor_inertia"], effects=EFFECTS, bounds={"motor.rotor_inertia": (1e-6, 1e-5)},
                   settings=IdentificationSettings(max_nfev=0)).fit(read_run(truth_run))


# ---------------------------------------------------------------- the run's controller: write -> read -> replay
def test_virtual_rig_writes_the_position_loop_and_the_controller_output_current(truth_run):
    run = read_run(truth_run)
    c = run.controller
    assert (c.position_loop.kp, c.position_loop.max_speed, c.position_loop.accel_limit) == (30.0, 0.1, 2.0)
    assert c.velocity_loop.ki == 0.0  # P-only velocity loop
    assert c.current_feedforward.column == "current_ff_A" and run.has("current_ff_A")
    assert np.isclose(np.max(run.extra["current_ff_A"]), 0.35) and np.isclose(run.extra["current_ff_A"][0], 0.05)
    d = run_design(run)
    assert (d.position_kp, d.max_speed, d.velocity_ki) == (30.0, 0.1, 0.0)
    u = run_inputs(run, d.control_period)
    assert np.all(u.signals["position_mode"] == 1.0) and u.accel_limit == 2.0
    assert np.isclose(u.signals["current_ff"].max(), 0.35)


def test_write_read_replay_round_trip_to_the_sensor_noise(truth_run, tmp_path):
    run = read_run(truth_run)
    truth = plain_params().replace(TRUTH)
    plant = build_plant(None, EFFECTS, params=truth)
    fits = replay_closed_loop(run, plant, truth).fits
    # residual at the sensor noise (motor speed 0.5 rpm = 0.052 rad/s, LVDT 1 um, current 10 mA)
    assert fits["nut_position"].rms < 2e-6
    assert fits["motor_speed"].rms < 1.5 * 0.5 * math.pi / 30
    assert fits["motor_current"].rms < 0.02
    # the position loop is closed in the replay: the recorded speed command (an output of the rig's position
    # loop; a rig may not log it) is not needed.  Zeroed, the replay with the position loop still matches;
    # without the extensions it is another experiment
    header, *rows = truth_run.read_text().splitlines()
    i_cmd = header.split(",").index("speed_cmd_mm_s")
    zeroed = [",".join("0" if j == i_cmd else v for j, v in enumerate(r.split(","))) for r in rows]
    errors = {}
    for drop in (None, "position_loop", "current_feedforward"):
        stem = tmp_path / f"no_{drop}"
        stem.with_suffix(".csv").write_text("\n".join([header] + zeroed) + "\n")
        meta = json.loads(truth_run.with_suffix(".json").read_text())
        meta["controller"].pop(drop, None)
        stem.with_suffix(".json").write_text(json.dumps(meta))
        errors[drop] = replay_closed_loop(read_run(stem.with_suffix(".csv")), plant, truth).fits["nut_position"].rms
    assert errors[None] < 2e-6
    assert errors["position_loop"] > 1000 * errors[None] and errors["current_feedforward"] > 20 * errors[None], errors


@pytest.mark.parametrize("edit, key, fragment", [
    (lambda c: c["position_loop"].update(kp_1_per_s=-3.0), "controller.position_loop.kp_1_per_s", "-3.0"),
    (lambda c: c["position_loop"].pop("kp_1_per_s"), "controller.position_loop.kp_1_per_s", "missing"),
    (lambda c: c["position_loop"].update(max_speed_mm_s="fast"), "controller.position_loop.max_speed_mm_s", "'fast'"),
    (lambda c: c.update(position_loop=[30.0]), "controller.position_loop", "must be an object"),
    (lambda c: c["current_feedforward"].update(column="ff_missing"), "controller.current_feedforward.column",
     "'ff_missing'"),
    (lambda c: c["current_feedforward"].update(column="motor_current_A"), "controller.current_feedforward.column",
     "a standard column"),
    (lambda c: c["current_feedforward"].update(offset_A="0.1"), "controller.current_feedforward.offset_A", "'0.1'"),
    (lambda c: c.update(current_feedforward={}), "controller.current_feedforward", "offset_A"),
])
def test_bad_controller_extensions_name_file_key_and_value(truth_run, tmp_path, edit, key, fragment):
    shutil.copy(truth_run, tmp_path / "bad.csv")
    meta = json.loads(truth_run.with_suffix(".json").read_text())
    edit(meta["controller"])
    (tmp_path / "bad.json").write_text(json.dumps(meta))
    with pytest.raises(RigDataError, match=rf"bad.json:{key}.*{fragment}") as err:
        read_run(tmp_path / "bad.csv")
    assert err.value.file.endswith("bad.json")


def test_position_loop_needs_the_position_command_and_a_feedforward_column_every_value(truth_run, tmp_path):
    lines = truth_run.read_text().splitlines()
    header = lines[0].split(",")
    i_pos, i_ff = header.index("position_cmd_mm"), header.index("current_ff_A")
    rows = [line.split(",") for line in lines[1:]]
    rows[5][i_ff] = ""  # one missing feed-forward sample
    keep = [j for j in range(len(header)) if j != i_pos]
    text = "\n".join(",".join(r[j] for j in keep) for r in [header] + rows) + "\n"
    (tmp_path / "cut.csv").write_text(text)
    shutil.copy(truth_run.with_suffix(".json"), tmp_path / "cut.json")
    with pytest.raises(RigDataError) as err:
        read_run(tmp_path / "cut.csv")
    msg = str(err.value)
    assert "cut.json:controller.position_loop" in msg and "no position_cmd_mm column" in msg
    assert "current_ff_A" in msg and "row 6" in msg and "every sample is needed" in msg


# ---------------------------------------------------------------- kinematics in one place
def test_run_stating_other_kinematics_is_refused_naming_both_values(truth_run):
    run = read_run(truth_run)  # the virtual rig states the plain drive's: 5 mm, 1.0
    assert run.kinematics_stated == ("screw_lead_mm", "gear_ratio")
    papers = default_parameters()
    with pytest.raises(RigDataError) as err:
        run_kinematics(run, papers)
    msg = str(err.value)
    assert "rig.screw_lead_mm" in msg and "states 5 but the parameter set's screw.lead is 12 mm" in msg
    assert "rig.gear_ratio" in msg and "states 1 but the parameter set's gear.ratio is 65.61" in msg
    with pytest.raises(RigDataError, match="rig.gear_ratio"):  # every replay goes through it
        replay_closed_loop(run, build_plant(None, EFFECTS, params=papers), papers)
    assert run_kinematics(run, plain_params()) is run  # agreeing kinematics: nothing changes


def test_run_stating_no_kinematics_takes_the_parameter_sets(truth_run, tmp_path):
    shutil.copy(truth_run, tmp_path / "bare.csv")
    meta = json.loads(truth_run.with_suffix(".json").read_text())
    del meta["rig"]
    (tmp_path / "bare.json").write_text(json.dumps(meta))
    run = read_run(tmp_path / "bare.csv")
    assert run.kinematics_stated == () and run.gear_ratio == 65.61  # FORMAT.md's seed until a model is known
    resolved = run_kinematics(run, plain_params())
    assert (resolved.gear_ratio, resolved.screw_lead) == (1.0, 0.005)
    # the reader's unit checks use the parameter set's kinematics when given (60 / 5 mm x 1 = 12 rpm per mm/s),
    # else FORMAT.md's seed (328.05 rpm per mm/s)
    given = read_run(tmp_path / "bare.csv", default_kinematics=(5.0, 1.0))
    speed = lambda r: " ".join(w for w in r.warnings if w.startswith("column 'motor_speed_rpm'"))  # noqa: E731
    assert "(12 rpm per mm/s" in speed(given) and "(328.05 rpm per mm/s" in speed(run)
    assert "0.0" in speed(run).split(" x the kinematic")[0]  # 27x too slow for the seed kinematics


def test_cli_refuses_a_kinematics_mismatch(truth_run, tmp_path, capsys):
    code = main(["residual", str(truth_run), "--model", "A", "--out", str(tmp_path / "o")])  # embedded actuator
    err = capsys.readouterr().err
    assert code == 2 and "rig.gear_ratio" in err and "65.61" in err
    assert not (tmp_path / "o").exists()


# ---------------------------------------------------------------- identification of the plain drive
def test_plain_drive_identifies_inertia_below_the_old_bound_coulomb_and_offset(truth_run):
    p = plain_params().replace({"drive.coulomb_torque": 0.01})  # the file's guesses: 6e-7, 0.01 N m, 0 N
    free = ["motor.rotor_inertia", "drive.coulomb_torque", "drive.axial_force_offset"]
    res = Identifier(None, p, free, effects=EFFECTS, settings=IdentificationSettings(max_nfev=60)).fit(
        read_run(truth_run))
    for name in free:
        est, true = res.estimates[name].value, TRUTH[name]
        assert abs(est / true - 1.0) < 0.10, (name, est, true)
    assert res.estimates["motor.rotor_inertia"].value < default_parameters()["motor.rotor_inertia"].min


@pytest.mark.parametrize("bounds, fragment", [
    ("motor.rotor_inertia=1e-6:1e-5", "do not contain the initial value"),
    ("motor.rotor_inertia=-1:1e-5", "widen the physical bounds"),
    ("motor.rotor_inertia=small", "is not NAME=LO:HI"),
])
def test_cli_per_fit_search_bounds_are_checked(truth_run, tmp_path, capsys, bounds, fragment):
    code = main(["identify", str(truth_run), "--model", "A", "--params", str(EXAMPLE), "--free", "motor.rotor_inertia",
                 "--bounds", bounds, "--out", str(tmp_path / "o"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and fragment in err and not (tmp_path / "o").exists()
