"""Plant model: kinematics, statics, effects switching, balances, stiction.

Reference values are hand-derived from the parameter values (formulas written
out here, independently of the model code) or quoted from the papers.
"""

import math

import numpy as np
import pytest

from thsa_control.errors import ModelError
from thsa_control.model import EFFECT_ORDER, EFFECTS, LEVELS, build_plant, resolve_effects
from thsa_control.sim.metrics import energy_residual
from thsa_control.sim.scenarios import Scenario

from handcalc import hand_current, plant_inputs


def test_kinematics_one_mm_per_s_is_328_rpm(params):
    # FORMAT.md: 1 mm/s nut = 5 rpm screw = 328.05 rpm motor
    plant = build_plant("A")
    x = plant.initial_state(params)
    x[plant.index("state", "motor_speed")] = 328.05 * 2 * math.pi / 60
    xdot, y = (np.asarray(v).ravel() for v in plant.f(x, plant_inputs(plant, temperature=25), plant.p_vector(params)))
    assert xdot[plant.index("state", "nut_position")] == pytest.approx(1e-3, rel=1e-6)
    assert y[plant.index("output", "screw_speed")] * 60 / (2 * math.pi) == pytest.approx(5.0, rel=1e-6)


def _constant_motion(speed_mm_s, load_N):
    return Scenario("steady", "constant speed and load", 2.5, ((0.0, 0.0), (0.2, speed_mm_s * 1e-3)), 0.03,
                    ((0.0, 0.0), (0.2, 0.0), (0.7, load_N)))


@pytest.mark.parametrize("level", ["A", "B"])
@pytest.mark.parametrize("speed_mm_s, load_N", [(5.0, 20e3), (-5.0, 20e3), (8.0, -15e3), (-8.0, -15e3),
                                                (5.0, 29e3), (-5.0, 29e3), (2.0, 1e3), (-2.0, -1e3)])
def test_steady_current_equals_torque_balance(run, params, level, speed_mm_s, load_N):
    res = run(_constant_motion(speed_mm_s, load_N), level)
    m = res.window(2.0, 2.5)
    assert np.mean(res["nut_speed"][m]) == pytest.approx(speed_mm_s * 1e-3, rel=1e-6)
    # the integral action leaves no steady error; 1e-3 A covers the discrete ripple
    assert np.mean(res["motor_current"][m]) == pytest.approx(hand_current(params.value, level, speed_mm_s, load_N), abs=1e-3)


@pytest.mark.parametrize("share", [0.4, 0.6])
@pytest.mark.parametrize("speed_mm_s, load_N", [(2.0, 4e3), (-2.0, -4e3)])
def test_steady_current_with_unequal_noback_disk_sets(run, params, share, speed_mm_s, load_N):
    # 4 kN opposing: the light disk set slips with what is left of its preload, preload - (1 - s) |F| for the loaded
    # set's share s; the closed loop's steady current against the hand balance at an assumed share's range ends
    ps = params.replace({"noback.load_share": share})
    res = run(_constant_motion(speed_mm_s, load_N), "B", params_override=ps)
    m = res.window(2.0, 2.5)
    assert np.mean(res["motor_current"][m]) == pytest.approx(hand_current(ps.value, "B", speed_mm_s, load_N), abs=1e-3)
    # and it differs from the equal sets' by more than that: the share is seen
    assert abs(hand_current(ps.value, "B", speed_mm_s, load_N) - hand_current(params.value, "B", speed_mm_s, load_N)) > 0.02


def test_light_disk_normal_force_shrinks_with_load(params):
    # paper 001: the light disk's force "is limited within the spring preload and grows smaller
    # with the increase in compressive load"; the flange between the two disk sets balances the load,
    # N_comp - N_tens = F, the sets sharing it (preload +- F/2) until the light one unloads at 2 preload
    plant = build_plant("B")
    p = plant.p_vector(params)
    pre = params.value("noback.preload")

    def normal_forces(F):
        y = np.asarray(plant.f(plant.initial_state(params), plant_inputs(plant, load_force=F, temperature=25), p)[1])
        y = y.ravel()
        return tuple(y[plant.index("output", f"noback_normal_force_{side}")] for side in ("comp", "tens"))

    for F in (0.0, 1e3, 2.9e3, 5e3, 5.999e3, 6.001e3, 29e3, -1e3, -5e3, -29e3):
        comp, tens = normal_forces(F)
        assert comp - tens == pytest.approx(F, abs=1e-9)  # the flange's force balance
        assert min(comp, tens) >= 0.0 and min(comp, tens) <= pre
        if abs(F) < 2 * pre:  # both sets carry: the load change shared
            assert comp == pytest.approx(pre + F / 2) and tens == pytest.approx(pre - F / 2)
        else:  # the light set unloaded: the loaded one carries the load alone
            assert max(comp, tens) == pytest.approx(abs(F)) and min(comp, tens) == 0.0
    # the light set's force falls as the load grows, and is gone beyond twice the preload
    light = [normal_forces(F)[1] for F in (0, 2e3, 4e3, 8e3)]
    assert light[0] > light[1] > light[2] > light[3] == 0.0


@pytest.mark.parametrize("k_comp, k_tens", [(2.0e8, 3.0e8), (3.0e8, 2.0e8), (1.0e8, 1.0e8)])
def test_noback_disk_sets_share_a_load_change_by_their_stiffness(params, k_comp, k_tens):
    """Unequal disk sets (``noback.load_share`` = k_comp / (k_comp + k_tens)): the flange moves by ``x`` until the two
    sets' force changes balance the load, ``k_comp x + k_tens x = F``, so each set's change is its stiffness times the
    one ``x``; the light set unloads where ``preload = k_light x``.  Solved here from the two springs, not from the
    law: the model's normal forces must match at loads on both sides of each set's unloading point."""
    pre = params.value("noback.preload")
    share = k_comp / (k_comp + k_tens)
    plant = build_plant("B")
    ps = params.replace({"noback.load_share": share})
    p = plant.p_vector(ps)

    def model(F):
        y = np.asarray(plant.f(plant.initial_state(ps), plant_inputs(plant, load_force=F, temperature=25), p)[1]).ravel()
        return tuple(y[plant.index("output", f"noback_normal_force_{side}")] for side in ("comp", "tens"))

    def springs(F):
        # the flange between two preloaded springs: while both are in contact, x = F / (k_comp + k_tens); once the
        # light one has lost its preload it is off, and the loaded one carries F alone
        x = F / (k_comp + k_tens)
        comp, tens = pre + k_comp * x, pre - k_tens * x
        if tens < 0:
            return F, 0.0
        if comp < 0:
            return 0.0, -F
        return comp, tens

    unload_c, unload_t = pre * (k_comp + k_tens) / k_tens, pre * (k_comp + k_tens) / k_comp
    for F in (0.0, 1e3, 0.99 * unload_c, 1.01 * unload_c, 29e3, -1e3, -0.99 * unload_t, -1.01 * unload_t, -29e3):
        got, want = model(F), springs(F)
        assert got == pytest.approx(want, abs=1e-6), F
        assert got[0] - got[1] == pytest.approx(F, abs=1e-6)  # the flange's balance at every share
    # at twice the preload, where equal sets lose the light one, a stiffer compressive set (share > 0.5) still
    # leaves the light tensile set loaded, a softer one has lost it already
    light = model(2 * pre)[1]
    assert (light > 1.0) if share > 0.5 else (light == 0.0)


def test_levels_are_nested_and_effects_known():
    assert set(EFFECT_ORDER) == set(EFFECTS)
    for lower, upper in zip("ABC", "BCD"):
        superseded = {s for e in LEVELS[upper] for s in EFFECTS[e].supersedes}
        assert set(LEVELS[lower]) - superseded < set(LEVELS[upper])
    # the detailed no-back replaces level A's ideal one, never both
    assert resolve_effects("A", add=["noback_quadrant_friction"]) == resolve_effects("B")
    with pytest.raises(ModelError, match="same part"):
        resolve_effects(None, add=["noback_quadrant_friction", "noback_ideal"])
    assert resolve_effects("D", remove=["loadpath_compliance"]) == resolve_effects("C")
    with pytest.raises(ModelError, match="unknown effect 'friction'"):
        resolve_effects("A", add=["friction"])
    with pytest.raises(ModelError, match="unknown model level 'E'"):
        resolve_effects("E")
    with pytest.raises(ModelError, match="needs effect 'noback_quadrant_friction'"):
        resolve_effects("A", add=["noback_backlash"])


def _max_diff(r1, r2, names=("motor_current", "motor_speed", "nut_position", "noback_torque")):
    return max(float(np.max(np.abs(np.asarray(r1[n]) - np.asarray(r2[n])))) for n in names)


def test_temperature_friction_at_25C_is_the_base_friction(run):
    # the law reduces exactly to the level-A viscous drag at the reference temperature
    assert _max_diff(run("backdrive_bipolar_ramp", "B", ("temperature_friction",)),
                     run("backdrive_bipolar_ramp", "B")) < 1e-9


def test_zero_pawl_pitch_reproduces_level_B(run, params):
    p0 = params.replace({"noback.pawl_pitch": 0.0})
    assert _max_diff(run("backdrive_bipolar_ramp", "C", params_override=p0),
                     run("backdrive_bipolar_ramp", "B", params_override=p0)) < 1e-9


def test_stiff_load_path_approaches_level_C(run, params):
    stiff = params.replace({"loadpath.backlash": 0.0, "loadpath.contact_stiffness_upper": 1e10,
                            "loadpath.contact_stiffness_lower": 1e10, "loadpath.disk_spring_stiffness": 1e9,
                            "loadpath.contact_damping": 1.8e6, "loadpath.disk_spring_damping": 1e5})
    d = run("backdrive_bipolar_ramp", "D", params_override=stiff)
    c = run("backdrive_bipolar_ramp", "C", params_override=stiff)
    # within 1 % of the 15 mm/s command and of the 4 A plateau current (the surface is 350 kg on a stiff spring)
    assert np.max(np.abs(d["nut_speed"] - c["nut_speed"])) < 0.01 * 15e-3
    m = d.window(1.6, 3.4)
    assert np.max(np.abs(d["motor_current"][m] - c["motor_current"][m])) < 0.04


def test_noback_holds_a_deenergised_actuator_and_reversible_A_backdrives(run):
    hold = Scenario("hold", "motors off, load ramp to 29 kN", 2.0, ((0.0, 0.0),), 0.03,
                    ((0.0, 0.0), (0.5, 29e3)))
    for level in "AB":  # level A: the ideal no-back holds too
        b = run(hold, level)
        assert np.all(b["motor_current"] == 0) and np.all(b["nut_position"] == 0.0)
        assert np.all(b["stuck"] == 1.0)
    a = run(hold, "A", remove=("noback_ideal",))
    assert a["nut_position"][-1] < -1e-3  # a reversible screw with no no-back back-drives


def test_losses_are_never_negative(run):
    for level in "ABCD":
        res = run("backdrive_bipolar_ramp", level)
        assert np.min(res["loss_power"]) > -1e-6 * np.max(np.abs(res["electrical_power"]))


@pytest.mark.parametrize("level", ["B", "D"])
def test_energy_balance(run, level):
    res = run("unipolar_speed_bipolar_load", level, output_period=None)
    # first-order scheme: the balance closes to O(h); 0.5 % of the energy throughput
    assert abs(energy_residual(res)) < 5e-3


def test_discrete_step_is_consistent_with_the_rhs(params):
    plant = build_plant("D", ["temperature_friction", "standby_motor"])
    p = plant.p_vector(params)
    x = plant.initial_state(params, load_force=12e3)
    x[plant.index("state", "motor_speed")] = 120.0
    x[plant.index("state", "motor_current")] = 3.0
    x[plant.index("state", "standby_current")] = 1.0
    x[plant.index("state", "pawl_clearance_comp")] = 0.05
    x[plant.index("state", "pawl_clearance_tens")] = 0.07  # off the stops, where the rates are smooth
    u = plant_inputs(plant, voltage_primary=40.0, voltage_standby=20.0, enable_primary=1, enable_standby=1,
           load_force=12e3, temperature=-20.0)
    xdot = np.asarray(plant.f(x, u, p)[0]).ravel()
    h = 1e-8
    fd = (np.asarray(plant.step(x, u, p, h)[0]).ravel() - x) / h
    # both forms come from the same terms: first-order agreement at h = 1e-8
    np.testing.assert_allclose(fd, xdot, rtol=1e-5, atol=1e-6)


def test_a_plant_is_built_once_per_effect_set_and_again_for_a_new_definition(params):
    """build_plant memoises per process (the same effect set and parameter names: the same Plant object, as the
    plant depends on nothing else); an effect registered again under its name (a new definition) and another
    parameter set's names give their own plant."""
    import dataclasses

    from thsa_control.model import register

    a = build_plant("B", ["temperature_friction"], params=params)
    assert build_plant("b", ("temperature_friction",), params=params) is a
    assert build_plant("B", params=params) is not a
    assert build_plant("A", params=params) is not build_plant("A", remove=["noback_ideal"], params=params)
    assert build_plant("A", params=params) is build_plant(None, ["noback_ideal"], params=params)  # the same set
    old = EFFECTS["temperature_friction"]
    register(dataclasses.replace(old, summary=old.summary + " (again)"), replace=True)
    try:
        b = build_plant("B", ["temperature_friction"], params=params)
        assert b is not a and b.state_names == a.state_names
        p = a.p_vector(params)
        x0 = np.asarray(a.init(0.0, 1e3, p), float).ravel() + 0.1  # moving, off equilibrium
        u = np.linspace(-1.0, 2.0, len(a.inputs))
        ya, yb = (np.asarray(pl.f(x0, u, p)[1], float) for pl in (a, b))
        np.testing.assert_array_equal(ya, yb)  # the same definition again: the same equations
    finally:
        register(old, replace=True)
    assert build_plant("B", ["temperature_friction"], params=params) is a
