"""Faults and monitoring (issue #10): jam with torque-limiter slip, primary load-path failure,
motor failure with standby take-over, sensor faults, the monitors' false-alarm margins, energy.

All runs are the closed loop with the monitors in it, on the fault plant (level D with the
compliant drive train, the limiter, the secondary path, the jam, the brakes, the claw stops and
the standby motor), memoised per session.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from thsa_control.errors import ScenarioError
from thsa_control.faults.analysis import (
    FAULT_PLANT_EFFECTS, RIGID_EFFECTS, analyse_fault_case, fault_scenarios, false_alarm_margins, normal_scenarios,
    persisted_peak, sweep_monitors,
)
from thsa_control.sim.events import FaultEvent
from thsa_control.sim.scenarios import load_scenario_file
from thsa_control.sim.monitor_settings import MonitorSettings
from thsa_control.model import build_plant
from thsa_control.model.laws import limiter_slip_torques
from thsa_control.sim.metrics import energy_residual
from thsa_control.sim.scenarios import get_scenario
from thsa_control.sim.simulate import SimulationSettings, Simulator

from conftest import ROOT

M = MonitorSettings()


@pytest.fixture(scope="module")
def sims(params):
    return {
        "fault": Simulator(build_plant("D", FAULT_PLANT_EFFECTS, params=params)),
        "fault_fine": Simulator(build_plant("D", FAULT_PLANT_EFFECTS, params=params), SimulationSettings(output_period=None)),
        "rigid": Simulator(build_plant("D", RIGID_EFFECTS, params=params)),
        "rigid_fine": Simulator(build_plant("D", RIGID_EFFECTS, params=params), SimulationSettings(output_period=None)),
    }


@pytest.fixture(scope="module")
def frun(sims, design, params):
    cache = {}

    def _run(scenario, kind="fault"):
        sc = get_scenario(scenario) if isinstance(scenario, str) else scenario
        key = (sc, kind)
        if key not in cache:
            cache[key] = sims[kind].run(sc, design, params)
        return cache[key]

    return _run


def _first(res, signal, t0=0.0):
    idx = np.flatnonzero((np.asarray(res[signal]) > 0.5) & (res.time >= t0))
    return float(res.time[idx[0]]) if idx.size else math.inf


def _p(params, name):
    return params.value(name)


# ---- jam --------------------------------------------------------------------------------------

def test_jam_slips_the_limiter_and_the_discrepancy_monitor_trips(frun, params):
    res = frun("jam")
    t_s, t_k = limiter_slip_torques({n: params.value(n) for n in params})
    before, after = res.time < 3.5, res.time >= 3.5
    torque = np.abs(np.asarray(res["limiter_torque"]))
    # the motor torque rises to the limiter threshold only after the jam, and the limiter slips
    assert torque[before].max() < 0.9 * t_s
    assert torque[after].max() == pytest.approx(t_s, rel=0.01)
    t_slip = _first(res, "limiter_slipping", 3.5)
    assert 3.5 < t_slip < 3.8
    assert np.abs(res["motor_torque"][res.index_at(t_slip)]) * _p(params, "gear.ratio") == pytest.approx(t_s, rel=0.05)
    # the RVDT (screw) and motor-sensor speeds diverge while it slips
    slipping = np.asarray(res["limiter_slipping"]) > 0.5
    gap = np.abs(np.asarray(res["measured_motor_speed"]) - np.asarray(res["screw_speed"]) * _p(params, "gear.ratio"))
    assert np.median(gap[slipping]) > 200.0  # rad/s at the motor: the motor keeps the commanded 515 rad/s
    # the discrepancy monitor trips one confirmation time after its quantity crosses the threshold
    crossed = res.time[np.flatnonzero(np.abs(np.asarray(res["monitor_discrepancy"])) > M.discrepancy_threshold)[0]]
    assert _first(res, "trip_discrepancy") - crossed == pytest.approx(M.discrepancy_confirmation, abs=1.5e-3)
    # safed: both channels off, brakes on, motors stopped
    end = res.time > 4.5
    assert np.all(res["brakes_engaged"][end] == 1) and np.all(res["energised_primary"][end] == 0)
    assert np.all(res["motor_speed"][end] == 0.0)


def test_the_limiter_bounds_the_screw_torque_and_the_structure_load(frun, params, design):
    res = frun("jam")
    t_s, _ = limiter_slip_torques({n: params.value(n) for n in params})
    # the slip torque bounds the transmitted (screw) torque at every sample
    assert np.all(np.abs(res["limiter_torque"]) <= np.asarray(res["limiter_slip_torque"]) * (1 + 1e-9))
    # the axial force the screw can push with the slip torque: T 2 pi eta_d / lead
    f_max = t_s * 2 * math.pi * _p(params, "screw.efficiency_direct") / _p(params, "screw.lead")
    assert np.max(np.abs(res["loadpath_force"])) <= 1.02 * f_max
    # without the limiter the same jam loads the drive train up to the motor's stall torque, beyond it
    plain = Simulator(build_plant("D", ("drivetrain_compliance", "surface_jam", "motor_brakes"), params=params))
    stalled = plain.run(replace(get_scenario("jam"), required_effects=()), design, params)
    assert np.max(np.abs(stalled["limiter_torque"])) > 1.03 * t_s


# ---- primary load-path failure ------------------------------------------------------------------

def test_loadpath_failure_moves_the_load_to_the_secondary_path_after_the_clearance(frun, params):
    res = frun("loadpath_failure")
    c = _p(params, "secondary.clearance")
    sec = np.abs(np.asarray(res["secondary_path_force"]))
    gimbal = np.abs(np.asarray(res["gimbal_displacement"]))
    assert np.all(sec[res.time < 7.5] == 0.0)  # unloaded in normal operation
    assert np.all(gimbal[sec > 0] > c)  # carries load only beyond the clearance
    end = res.time > 9.0
    load = np.asarray(res["load_force"])[end]
    np.testing.assert_allclose(sec[end], np.abs(load), rtol=0.02)  # ... and then the whole load
    assert np.all(np.abs(res["primary_attachment_force"][end]) < 1.0)
    # the LVDT monitor trips one confirmation time after the displacement crosses its threshold
    crossed = res.time[np.flatnonzero(gimbal > M.lvdt_threshold)[0]]
    assert 7.5 < crossed < 7.51
    assert _first(res, "trip_lvdt") - crossed == pytest.approx(M.lvdt_confirmation, abs=1.5e-3)
    # the actuator ends locked: both motors off, brakes on, nothing moves
    assert np.all(res["brakes_engaged"][end] == 1) and np.all(res["energised_standby"][end] == 0)
    assert np.all(res["motor_speed"][end] == 0.0) and np.all(res["nut_speed"][end] == 0.0)
    # the surface moved by the clearance plus the secondary path's deflection under the load
    moved = res["surface_position"][-1] - res["surface_position"][res.index_at(7.49)]
    k_s = _p(params, "secondary.stiffness")
    assert c < abs(moved) < c + 2 * 29e3 / k_s + 0.5e-3


# ---- motor failure --------------------------------------------------------------------------------

@pytest.mark.parametrize("scenario, t_fault", [("motor_fault_monitored", 1.8), ("motor_fault_monitored_rising_load", 1.35)])
def test_standby_takes_over_after_the_delay(frun, scenario, t_fault):
    res = frun(scenario, "rigid")
    t_trip = _first(res, "trip_speed")
    assert t_fault < t_trip < t_fault + 0.06
    # primary disabled at the trip, standby energised one take-over delay later
    assert _first(res, "energised_standby") - t_trip == pytest.approx(M.takeover_delay, abs=1.5e-3)
    after = res.time > t_trip + 0.1
    assert np.all(res["motor_current"][after] == 0) and np.all(res["energised_standby"][after] == 1)
    assert not np.any(res["safed"] > 0.5)
    assert np.mean(res["nut_speed"][res.time > 2.5]) == pytest.approx(-5e-3, rel=1e-3)


def test_recovery_time_is_reported(design, params, sims):
    case = analyse_fault_case("motor_fault_monitored", design, params, sim=sims["rigid"], smooth_s=0.0)
    papers = analyse_fault_case(
        replace(get_scenario("motor_fault_monitored"), standby_enable=((0.0, 0.0), (1.815, 1.0))), design, params,
        sim=sims["rigid"], smooth_s=0.0, monitors=replace(M, reconfigure=False))
    # papers: about 0.15 s with the 15 ms delay; ours is shorter (bumpless hand-over), and the monitored
    # take-over (detection + delay, about 40 ms) recovers later than the papers' fixed 15 ms
    assert 0.0 < papers.recovery_s < case.recovery_s < 0.3
    assert case.takeover_s == pytest.approx(case.detection_s["speed"] + M.takeover_delay, abs=1.5e-3)
    # the papers' case enables the standby by schedule, the monitors only watch: their flag stays low, and the
    # take-over is the schedule's 15 ms after the fault (issue #18: the flag "never rises although torque recovers")
    assert case.takeover_source == "monitor" and papers.takeover_source == "schedule"
    assert np.max(papers.series["standby_active"]) == 0.0
    assert papers.takeover_s == pytest.approx(0.015, abs=1.5e-3)


# ---- monitors: false alarms and detections -----------------------------------------------------

def test_no_monitor_trips_on_the_normal_scenarios(design, params, sims, capsys):
    margins = false_alarm_margins(design, params, sim=sims["fault"])
    assert {m.scenario for m in margins} == {s.name for s in normal_scenarios()} and len(normal_scenarios()) >= 4
    assert not any(m.tripped for m in margins)
    with capsys.disabled():
        for mon in ("discrepancy", "lvdt", "speed"):
            worst = min((m for m in margins if m.monitor == mon), key=lambda m: m.margin)
            print(f"\nfalse-alarm margin {mon}: {worst.margin:.2f} ({worst.scenario})", end="")
    assert all(m.margin > 1.5 for m in margins)


def test_sweep_no_false_alarm_and_every_fault_detected(design, params, sims):
    points = sweep_monitors(design, params, scales=(0.75, 1.0, 1.25), delays_s=(M.takeover_delay,), sim=sims["fault"])
    names = {s.name for s in fault_scenarios()}
    assert len(names) >= 4
    for p in points:
        assert p.normal_trips == ()
        assert set(p.detection_s) == names and all(math.isfinite(t) for t in p.detection_s.values())
    # larger thresholds detect later
    for n in names:
        times = [p.detection_s[n] for p in points]
        assert times == sorted(times)


def test_persisted_peak():
    t = np.arange(0, 1, 1e-3)
    q = np.where((t > 0.2) & (t < 0.205), 5.0, 1.0)  # a 5 ms spike on a level of 1
    assert persisted_peak(t, q, 0.003) == 5.0
    assert persisted_peak(t, q, 0.010) == 1.0


# ---- sensor faults ---------------------------------------------------------------------------

def test_sensor_faults(frun, params):
    base = get_scenario("backdrive_bipolar_ramp")
    sc = replace(base, name="sensors", duration=3.0, monitors=M, faults=(
        FaultEvent("sensor", 1.5, sensor="rvdt", mode="offset", value=1.0),
        FaultEvent("sensor", 2.0, end=2.2, sensor="motor_speed", mode="noise", value=5.0, seed=1),
        FaultEvent("sensor", 2.5, sensor="lvdt", mode="stuck"),
        FaultEvent("sensor", 2.5, sensor="motor_speed", mode="loss", end=2.5002),
    ))
    res = frun(sc)
    # an RVDT offset of 1 rad is a discrepancy: the monitor trips one confirmation time later
    assert _first(res, "trip_discrepancy") - 1.5 == pytest.approx(M.discrepancy_confirmation, abs=1.5e-3)
    assert res["measured_screw_angle"][res.index_at(1.6)] - res["screw_speed"][0] > 0.9
    noisy = res.window(2.0, 2.2)
    err = np.asarray(res["measured_motor_speed"])[noisy] - np.asarray(res["motor_speed"])[noisy]
    assert np.std(err) == pytest.approx(5.0, rel=0.3)
    held = res.window(2.5, 3.0)
    assert np.ptp(res["measured_gimbal_displacement"][held]) == 0.0


# ---- energy ------------------------------------------------------------------------------------

# The rising-load channel failure runs on the rigid drive train here: on the compliant one its 55 kN
# aiding motion is a stick-slip limit cycle, and the main body's kinetic energy at each stick (not a
# fault effect: plant.py counts friction losses at the end-of-step speed) leaves 0.51 % unbalanced.
@pytest.mark.parametrize("scenario, kind", [("jam", "fault_fine"), ("loadpath_failure", "fault_fine"),
                                            ("motor_fault_monitored", "fault_fine"),
                                            ("motor_fault_monitored_rising_load", "rigid_fine")])
def test_fault_runs_conserve_energy(frun, scenario, kind):
    sc = get_scenario(scenario)
    if scenario == "loadpath_failure":
        sc = replace(sc, duration=8.5)
    res = frun(sc, kind)
    # the same tolerance as a normal run (test_model.test_energy_balance): 0.5 % of the throughput,
    # with the limiter slip, jam, fracture, brake and contact losses counted
    assert abs(energy_residual(res)) < 5e-3
    assert np.min(res["loss_power"]) > -1e-6 * np.max(np.abs(res["electrical_power"]))
    if scenario == "jam":
        assert np.sum(res["limiter_slipping"]) > 0


# ---- claw stops ----------------------------------------------------------------------------------

def test_claw_stop_ends_the_travel_and_slips_the_limiter(sims, design, params):
    sim = sims["fault"]
    sc = replace(get_scenario("backdrive_bipolar_ramp"), name="to_the_stop", duration=3.0,
                 speed_target=((0.0, 0.0), (0.5, 15e-3)), load=((0.0, 0.0),), monitors=M)
    x0 = sim.plant.initial_state(params, nut_position=_p(params, "claw.travel_max") - 0.015)
    res = sim.run(sc, design, params, x0=x0)
    over = np.asarray(res["nut_position"]) - _p(params, "claw.travel_max")
    assert np.max(over) < 2e-4  # stopped at the end of travel (claw stiffness)
    assert np.max(np.abs(res["claw_torque"])) > 100.0
    assert np.any(res["limiter_slipping"] > 0.5) and np.any(res["trip_discrepancy"] > 0.5)


# ---- scenario files ----------------------------------------------------------------------------

def test_scenario_file_example_runs(frun):
    sc = load_scenario_file(ROOT / "examples" / "jam_cold_with_rvdt_noise.toml")
    assert sc.temperature == -30.0 and [f.kind for f in sc.faults] == ["surface_jam", "sensor"]
    res = frun(replace(sc, duration=3.5))
    assert _first(res, "limiter_slipping") > 2.5 and _first(res, "safed") < 3.5


def test_scenario_file_errors_name_the_field(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text('base = "jam"\n[[faults]]\nkind = "surface_jam"\ntime = 1.0\nspeed = 3\n')
    with pytest.raises(ScenarioError, match=r"faults\[0\].*speed"):
        get_scenario(str(bad))
    bad.write_text('base = "jam"\n[[faults]]\nkind = "meteor"\ntime = 1.0\n')
    with pytest.raises(ScenarioError, match="meteor"):
        get_scenario(str(bad))
    bad.write_text('base = "jam"\n[monitors]\nspeed_threshold = -3.0\n')
    with pytest.raises(ScenarioError, match="speed_threshold"):
        get_scenario(str(bad))
    bad.write_text('name = "x"\nduration = 1.0\n')
    with pytest.raises(ScenarioError, match="missing"):
        get_scenario(str(bad))


def test_fault_needs_its_effect(design, params):
    with pytest.raises(ScenarioError, match="surface_jam"):
        Simulator(build_plant("D", params=params)).run(replace(get_scenario("jam"), required_effects=()), design, params)


# ---- command line --------------------------------------------------------------------------------

def test_simulate_jam_writes_torques_slip_sensor_speeds_and_flags(tmp_path):
    import json

    from thsa_control.cli import main
    from thsa_control.data.rigdata import read_run

    out = tmp_path / "jam"
    assert main(["simulate", "--scenario", "jam", "--level", "D", "--out", str(out)]) == 0
    assert (out / "jam_D_faults.png").stat().st_size > 20_000
    run = read_run(out / "jam_D.csv")
    for col in ("limiter_torque_Nm", "limiter_slip_speed_rpm", "limiter_slipping", "measured_motor_speed_rpm",
                "trip_discrepancy", "trip_speed", "trip_lvdt", "safed", "brakes_engaged", "jam_force_N"):
        assert col in run.extra, col
    assert max(run.extra["trip_discrepancy"]) == 1.0
    meta = json.loads((out / "jam_D.json").read_text())
    assert "torque_limiter" in meta["generator"]["effects"]


@pytest.mark.slow
def test_faults_command_writes_the_report(tmp_path, capsys):
    import json

    from thsa_control.cli import main

    out = tmp_path / "faults"
    assert main(["faults", "--no-sweep", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    text = captured.out
    assert "thsa faults: " in captured.err and "1/" in captured.err  # progress, one line per case, on stderr
    assert "false-alarm margin speed" in text and "jam: surface_jam at 3.5 s" in text
    # every case line names its plant as the HTML's sections do: the rigid-drive repeat is labelled
    assert "motor_fault_monitored [rigid drive train]: " in text and "-- rigid drive train --" in text
    assert "take-over 15.0 ms (scheduled by the scenario" in text
    lines = [ln.split(":")[0] for ln in text.splitlines() if " at " in ln and "; trips:" in ln]
    assert len(lines) == len(set(lines))
    data = json.loads((out / "faults.json").read_text())
    assert data["format"] == "thsa-faults/1"
    assert {c["scenario"] for c in data["cases"]} == {s.name for s in fault_scenarios()}
    assert "fig-case_jam" in (out / "report.html").read_text()


def test_faults_command_rejects_bad_sweep(tmp_path, capsys):
    from thsa_control.cli import main

    assert main(["faults", "--scales", "a,b", "--out", str(tmp_path / "x")]) == 2
    assert "--scales" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
