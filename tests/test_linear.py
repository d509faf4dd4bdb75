"""THSA linearisation: physics oracles for the adapter of the generic linearization package.

Reference values are hand-derived from the parameters of
``default_actuator.toml`` (the formulas are in each test); tolerances say why
they are what they are.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from linearization import LinearModel, finite_difference_jacobians
from thsa_control.cli import main
from thsa_control.loops.linear import (
    ConditionGrid,
    LinearizationSettings,
    OperatingCondition,
    current_driven,
    linearize_condition,
    linearize_conditions,
    plant_model,
)


@pytest.fixture(scope="module")
def model_a(params):
    return plant_model("A", (), params)


@pytest.fixture(scope="module")
def model_a_temp(params):
    return plant_model("A", ("temperature_friction",), params)


@pytest.fixture(scope="module")
def model_b_temp(params):
    return plant_model("B", ("temperature_friction",), params)


def _hand(params):
    """Kt, J, b and r of the level-A plant seen from the motor while it drives the gearbox.

    The gearbox passes eta_g of the torque that enters it, so everything on its
    output side (screw and nut inertia, gear drag) weighs 1/eta_g at the motor:
    J = J_rotor + J_out / eta_g, b = b_bearing + b_gear / eta_g.
    """
    v = params.value
    n = v("gear.ratio")
    r = v("screw.lead") / (2 * math.pi * n)
    kt = 1.5 * v("motor.pole_pairs") * v("motor.flux_linkage")
    eta = v("gear.efficiency")
    j = v("motor.rotor_inertia") + (v("screw.inertia") / n**2 + (v("loadpath.mass") + v("surface.mass")) * r**2) / eta
    b = v("motor.bearing_viscous_friction") + v("gear.viscous_friction") / eta
    return kt, j, b, r


# Level A has linear (viscous) friction; the efficiency channel |F| r c1 and the ideal no-back are
# Coulomb torques whose slope is zero away from zero speed, and the load torque F r c0 does not depend
# on speed.  At level A the motor drives the gearbox at every point (the ideal no-back takes an aiding
# load), so the current -> speed transfer function is Kt / (J s + b) with the driving-gear J and b.
@pytest.mark.parametrize("speed, load", [(5e-3, 20e3), (15e-3, -55e3), (-2e-3, 30e3), (0.5e-3, 0.0)])
def test_level_a_current_to_speed_is_kt_over_js_plus_b(model_a, params, speed, load):
    kt, j, b, r = _hand(params)
    lin = linearize_condition(model_a, OperatingCondition(speed, load, 25.0))
    lm = lin[0]
    assert lin.valid[0], lin.reasons[0]
    tf = current_driven(lm).transfer_function("motor_current", "motor_speed", minimal=True)
    num, den = np.squeeze(tf.num[0][0]), np.squeeze(tf.den[0][0])
    assert np.atleast_1d(num).size == 1 and den.size == 2
    # normalised coefficients: Kt/J and b/J, 1e-6 relative (AD is exact; the cancellation of the
    # electrical pole by minreal is the only numerical step)
    assert float(num) / den[0] == pytest.approx(kt / j, rel=1e-6)
    assert den[1] / den[0] == pytest.approx(b / j, rel=1e-6)
    assert lin.inertia[0] == pytest.approx(j, rel=1e-9)
    assert lin.net_damping[0] == pytest.approx(b, rel=1e-9)
    # and the steady motion: the nut moves at the held speed, the current carries the load
    op = lm.operating_point
    assert op.output("nut_speed") == pytest.approx(speed, rel=1e-12)
    assert op.drift_rates["nut_position"] == pytest.approx(speed, rel=1e-12)
    assert lm.excluded_states == ("nut_position",)


@pytest.mark.parametrize("level, effects, cond", [
    ("A", (), OperatingCondition(5e-3, 20e3, 25.0)),
    ("B", ("temperature_friction",), OperatingCondition(1e-3, -55e3, -55.0)),
    ("D", ("temperature_friction",), OperatingCondition(10e-3, 20e3, -30.0)),
])
def test_ad_matches_central_finite_differences(params, level, effects, cond):
    model = plant_model(level, effects, params)
    lin = linearize_condition(model, cond)
    lm = lin[0]
    op = lm.operating_point
    A, B, C, D = finite_difference_jacobians(model.named, op.x, op.u, op.p)
    ks = [model.named.states.index(s) for s in lm.states]
    # central differences with h = 1e-6 max(1, |z|): truncation O(h^2 f''') and round-off
    # O(eps |f| / h); 1e-6 of each row's largest entry covers both
    for ad, fd in ((lm.A, A[np.ix_(ks, ks)]), (lm.B, B[ks])):
        scale = np.max(np.abs(ad), axis=1, keepdims=True)
        assert np.all(np.abs(fd - ad) <= 1e-6 * scale), (ad, fd)
    assert lin.ad_fd_discrepancy(0) < 1e-5


@pytest.mark.parametrize("level", ["A", "B", "C", "D"])
def test_zero_speed_is_reported_invalid_not_silently_linearised(params, level):
    model = plant_model(level, ("temperature_friction",), params)
    lin = linearize_conditions(model, [OperatingCondition(0.0, 20e3, 25.0), OperatingCondition(5e-3, 20e3, 25.0)])
    assert lin.valid.tolist() == [False, True]
    assert lin.reasons[0][0].startswith("zero speed (stick)")
    # the generic smoothness check sees the friction jump as well
    assert any("motor_speed" in r for r in lin.reasons[0])
    assert lin[0].valid is False and lin[0].invalid_reasons == lin.reasons[0]
    assert lin.invalid_points()[0][0].nut_speed == 0.0


def test_backlash_edges_are_invalid(params):
    # level D: the load-path contact closes at |deflection| = backlash, i.e. at a load of
    # 2 kds b = 2 * 1.48e6 * 0.67e-3 = 1983.2 N carried by the disk springs alone
    edge = 2 * params.value("loadpath.disk_spring_stiffness") * params.value("loadpath.backlash")
    model = plant_model("D", (), params)
    lin = linearize_conditions(model, [OperatingCondition(5e-3, edge, 25.0), OperatingCondition(5e-3, 20e3, 25.0)])
    assert not lin.valid[0] and lin.valid[1]
    assert any(r.startswith("backlash edge") for r in lin.reasons[0])
    # level C: the pawl that locks the motion, at the instant it engages (clearance exactly 0)
    model = plant_model("C", (), params, settings=LinearizationSettings(pawl="edge"))
    lin = linearize_condition(model, OperatingCondition(5e-3, 20e3, 25.0))
    assert not lin.valid[0]
    assert any("backlash edge" in r and "pawl_clearance_tens" in r for r in lin.reasons[0])
    # ... and inside the engaged set (the default) the same motion is smooth
    assert linearize_condition(plant_model("C", (), params), OperatingCondition(5e-3, 20e3, 25.0)).valid[0]


def test_level_d_steady_motion_is_an_equilibrium_of_the_deflection(params):
    model = plant_model("D", (), params)
    lin = linearize_condition(model, OperatingCondition(5e-3, 20e3, 25.0))
    lm = lin[0]
    op = lm.operating_point
    assert "loadpath_deflection" in lm.states and "surface_position" not in model.named.states
    # static deflection on the upper contact: (F + ku b) / (2 kds + ku)
    v = params.value
    ku, kds, b = v("loadpath.contact_stiffness_upper"), v("loadpath.disk_spring_stiffness"), v("loadpath.backlash")
    assert op.state("loadpath_deflection") == pytest.approx((20e3 + ku * b) / (2 * kds + ku), rel=1e-9)
    assert op.state("surface_speed") == pytest.approx(5e-3, rel=1e-9)
    assert op.output("loadpath_force") == pytest.approx(20e3, rel=1e-9)
    assert op.residual < 1e-8
    assert set(lm.excluded_states) == {"nut_position", "pawl_clearance_comp", "pawl_clearance_tens"}


def test_temperature_friction_changes_the_plant_monotonically(model_a_temp, params):
    temps = (70.0, 25.0, 0.0, -30.0, -55.0)
    v = params.value
    kt, j, b25, r = _hand(params)
    # above the cold Stribeck speed (10 mm/s = 343 rad/s >> 50 rad/s) the law is viscous:
    # b(T) = b_bearing + b_gear exp(a_v (25 - T)) / eta_g (the gear drag is on the gearbox's output side),
    # rising as it gets colder
    eta = v("gear.efficiency")
    fast = linearize_conditions(model_a_temp, [OperatingCondition(10e-3, 20e3, t) for t in temps])
    expected = v("motor.bearing_viscous_friction") + v("gear.viscous_friction") * np.exp(
        v("friction.viscous_temperature_coefficient") * (25.0 - np.array(temps))) / eta
    np.testing.assert_allclose(fast.net_damping, expected, rtol=1e-9)
    assert np.all(np.diff(fast.net_damping) > 0)  # more damping when cold
    dc = np.array([current_driven(fast[k]).transfer_function("motor_current", "motor_speed").dcgain()
                   for k in range(len(temps))])
    np.testing.assert_allclose(dc, kt / expected, rtol=1e-9)  # Kt / b(T): less speed per ampere when cold
    assert np.all(np.diff(dc) < 0)
    # in the low-speed rise (1 mm/s = 34 rad/s), the extra cold Coulomb drag falls with speed: its
    # slope d/dw [Tc(T) (1 + r_st exp(-(w/w_st)^2))] is negative and grows with the cold
    slow = linearize_conditions(model_a_temp, [OperatingCondition(1e-3, 20e3, t) for t in temps])
    w = 1e-3 / r
    tc = v("friction.cold_coulomb_torque") * (np.exp(v("friction.coulomb_temperature_coefficient")
                                                     * np.maximum(25.0 - np.array(temps), 0.0)) - 1.0)
    ws = v("friction.cold_stribeck_speed")
    slope = tc * v("friction.cold_stribeck_ratio") * np.exp(-(w / ws) ** 2) * (-2 * w / ws**2)
    b_slow = v("motor.bearing_viscous_friction") + (v("gear.viscous_friction") * np.exp(
        v("friction.viscous_temperature_coefficient") * (25.0 - np.array(temps))) + slope) / eta
    np.testing.assert_allclose(slow.net_damping, b_slow, rtol=1e-9)
    assert np.all(np.diff(slow.friction_slope[1:]) < 0)
    assert slow.stribeck.tolist() == [False, False, True, True, True]


def test_stribeck_slope_of_the_noback_disk_is_reported_as_destabilising(model_b_temp, params):
    # 1 mm/s with 55 kN aiding (tensile, extension): the tensile-side disk slips under
    # N = 55 kN (beyond twice the preload the light set is unloaded and the loaded one carries the load alone);
    # its Stribeck law mu(ws) N / gear ratio falls with speed
    v = params.value
    kt, j, b, r = _hand(params)
    n = v("gear.ratio")
    lin = linearize_condition(model_b_temp, OperatingCondition(1e-3, -55e3, 25.0))
    w = 1e-3 / r
    ws, wst = w / n, v("noback.stribeck_speed_pos")
    normal = 55e3
    assert normal > 2 * v("noback.preload")
    slope = (v("noback.mu_static_pos") - v("noback.mu_coulomb_pos")) * math.exp(-(ws / wst) ** 2) * (
        -2 * ws / wst**2) / n * normal / n
    # the motor drives the gearbox here: the disk's slope and the gear drag weigh 1/eta_g at the motor
    eta = v("gear.efficiency")
    net = v("motor.bearing_viscous_friction") + (v("gear.viscous_friction") + slope) / eta
    assert lin.net_damping[0] == pytest.approx(net, rel=1e-9)
    assert lin.friction_slope[0] < 0
    assert lin.valid[0] and lin.stribeck[0] and lin.net_damping[0] < 0
    assert any(note.startswith("Stribeck region") for note in lin.notes[0])
    assert any("unstable" in note for note in lin.notes[0])
    # with the current imposed (what the velocity loop sees through a fast current loop) the
    # mechanical pole is in the right half plane, at -net damping / J; driven by voltage, the
    # back-EMF (Kt Ke / R = 0.057 N m s/rad) still damps it
    assert current_driven(lin[0]).poles().real.max() == pytest.approx(-lin.net_damping[0] / lin.inertia[0],
                                                                      rel=1e-9)
    assert lin[0].poles().real.max() < 0


def test_standby_configuration_uses_the_standby_channel(params):
    model = plant_model("B", ("standby_motor",), params)
    lin = linearize_conditions(model, [OperatingCondition(5e-3, 20e3, 25.0, "primary"),
                                       OperatingCondition(5e-3, 20e3, 25.0, "standby")])
    assert lin.channel(0) == ("voltage_primary", "motor_current")
    assert lin.channel(1) == ("voltage_standby", "standby_current")
    op_p, op_s = lin[0].operating_point, lin[1].operating_point
    assert op_s.output("motor_current") == pytest.approx(0.0, abs=1e-9)  # primary off
    assert op_s.output("standby_current") == pytest.approx(op_p.output("motor_current"), rel=1e-9)
    # identical motors, both rotors dragged either way: the same mechanics
    assert lin.inertia[0] == pytest.approx(lin.inertia[1], rel=1e-12)
    kt, j, b, r = _hand(params)
    ratchets = 2 * params.value("noback.ratchet_inertia") / params.value("gear.ratio") ** 2
    # two rotors on the motor side; the ratchets on the gearbox's output side (1/eta_g while driving)
    assert lin.inertia[0] == pytest.approx(j + params.value("motor.rotor_inertia")
                                           + ratchets / params.value("gear.efficiency"), rel=1e-9)
    with pytest.raises(Exception, match="standby_motor"):
        linearize_condition(plant_model("A", (), params), OperatingCondition(5e-3, 0.0, 25.0, "standby"))


def test_grid_is_one_batch_and_ordered(model_b_temp):
    grid = ConditionGrid((1e-3, 5e-3), (-20e3, 20e3), (-30.0, 25.0))
    lin = linearize_conditions(model_b_temp, grid)
    assert len(lin) == 8 and lin.batch.A.shape == (8, 2, 2)
    assert [c.label() for c in lin.conditions[:2]] == ["1 mm/s, -20 kN (aiding), -30 degC",
                                                      "1 mm/s, 20 kN (opposing), -30 degC"]


def test_cli_linearize_prints_and_saves(tmp_path, capsys):
    out = tmp_path / "model.npz"
    assert main(["linearize", "--level", "A", "--speed", "5", "--load", "20000", "--temperature", "-30",
                 "--save", str(out)]) == 0
    text = capsys.readouterr().out
    for piece in ("A =", "B =", "poles [1/s]", "current -> motor speed", "voltage -> motor speed", "valid: yes",
                  "5 mm/s, 20 kN (opposing), -30 degC"):
        assert piece in text
    lm = LinearModel.load(out)
    # the default effects: temperature friction and the dragged standby rotor (its current a state)
    assert lm.states == ("motor_current", "motor_speed", "standby_current") and lm.valid
    assert lm.operating_point.output("nut_speed") == pytest.approx(5e-3)


@pytest.mark.parametrize("argv, message", [
    (["--temperature", "90"], "temperature = 90"),
    (["--effects", "magic"], "unknown effect 'magic'"),
])
def test_cli_linearize_bad_input_exit_2_and_saves_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / "model.npz"
    base = ["linearize", "--level", "A", "--speed", "5", "--load", "0", "--save", str(out)]
    assert main(base + argv) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()
