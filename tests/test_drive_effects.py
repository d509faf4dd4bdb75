"""Generic drive effects: neutral at their defaults, analytic torque balances, simulation, linearisation.

Reference values are written out here from the effects' documented laws.
"""

import math

import numpy as np
import pytest

from thsa_control.model import EFFECT_ORDER, build_plant
from thsa_control.model.effects.drive import DRIVE_EFFECTS

DRIVE = tuple(DRIVE_EFFECTS)


def _u(plant, **kw):
    u = np.zeros(len(plant.inputs))
    u[plant.index("input", "enable_primary")] = 1.0
    u[plant.index("input", "temperature")] = 25.0
    for k, v in kw.items():
        u[plant.index("input", k)] = v
    return u


def _consts(params):
    P = params.value
    r = P("screw.lead") / (2 * math.pi * P("gear.ratio"))
    kt = 1.5 * P("motor.pole_pairs") * P("motor.flux_linkage")
    return r, kt, P("screw.efficiency_direct"), P("screw.efficiency_inverse"), P("gear.efficiency"), \
        P("motor.bearing_viscous_friction"), P("gear.viscous_friction")


def _motor_torque(params, w, screw_side):
    """Motor torque at steady speed ``w`` for a screw-side demand [N m at the motor shaft]: the gearbox takes
    (1 - eta) of the power when the motor drives (demand / eta) and gives back eta of it when driven."""
    _, _, _, _, eta_g, b_m, _ = _consts(params)
    t_g = screw_side / eta_g if screw_side * w > 0 else screw_side * eta_g
    return b_m * w + t_g


def test_registered_in_application_order():
    assert set(DRIVE) <= set(EFFECT_ORDER)
    # force_offset changes the axial force, which the no-back reads: it must come first
    assert EFFECT_ORDER.index("force_offset") < EFFECT_ORDER.index("noback_quadrant_friction")


@pytest.mark.parametrize("effect", DRIVE)
@pytest.mark.parametrize("level", ["A", "B"])
def test_effect_at_its_neutral_values_is_the_base_exactly(params, effect, level, rng):
    base = build_plant(level, params=params)
    plant = build_plant(level, [effect], params=params)
    assert plant.state_names == base.state_names
    p = plant.p_vector(params)
    for _ in range(20):
        x = base.initial_state(params, load_force=0.0)
        x[1] = rng.normal(0, 300.0) * rng.integers(0, 2)  # half the draws at standstill
        x[0] = rng.normal(0, 5.0)
        x[2] = rng.normal(0, 0.05)
        u = _u(base, load_force=rng.normal(0, 2e4), voltage_primary=rng.normal(0, 50))
        for fa, fb in ((plant.f(x, u, p), base.f(x, u, p)), (plant.step(x, u, p, 1e-4), base.step(x, u, p, 1e-4))):
            np.testing.assert_array_equal(np.asarray(fa[0]), np.asarray(fb[0]))
            np.testing.assert_array_equal(np.asarray(fa[1]), np.asarray(fb[1]))


def _steady_current(plant, params, w, load, nut_position=0.0):
    """Current that makes the speed derivative of the continuous RHS vanish (piecewise linear in the current:
    the gearbox efficiency depends on the power-flow direction, so a few secant steps)."""
    p = plant.p_vector(params)
    x = plant.initial_state(params)
    x[plant.index("state", "motor_speed")] = w
    x[plant.index("state", "nut_position")] = nut_position
    u = _u(plant, load_force=load)
    k = plant.index("state", "motor_speed")

    def rate(i):
        x[0] = i
        return float(np.asarray(plant.f(x, u, p)[0]).ravel()[k])

    i0, i1 = 0.0, 1.0
    r0, r1 = rate(i0), rate(i1)
    for _ in range(20):
        if r1 == r0:
            break
        i0, i1 = i1, i1 - r1 * (i1 - i0) / (r1 - r0)
        r0, r1 = r1, rate(i1)
        if abs(r1) < 1e-12:
            break
    return i1


@pytest.mark.parametrize("w", [400.0, -400.0])
@pytest.mark.parametrize("load", [0.0, 15e3, -15e3])
def test_coulomb_and_offset_steady_current_is_the_torque_balance(params, w, load):
    tc, f0 = 0.08, 2500.0
    pr = params.replace({"drive.coulomb_torque": tc, "drive.static_torque_ratio": 0.5, "drive.stribeck_speed": 10.0,
                         "drive.axial_force_offset": f0})
    # the functional model without its ideal no-back: a plain reversible screw drive
    plant = build_plant(None, ["coulomb_friction", "force_offset"], params=pr)
    r, kt, eta_d, eta_i, _, _, b_g = _consts(pr)
    f = load + f0
    opposing = f * w > 0
    # at 400 rad/s the Stribeck term is exp(-1600): the kinetic torque is the Coulomb torque
    screw_side = b_g * w + math.copysign(tc, w) + f * r * (1 / eta_d if opposing else eta_i)
    assert _steady_current(plant, pr, w, load) == pytest.approx(_motor_torque(pr, w, screw_side) / kt, rel=1e-9)


@pytest.mark.parametrize("td, w, acts", [(0.05, 300.0, True), (0.05, -300.0, False), (-0.05, -300.0, True),
                                         (-0.05, 300.0, False)])
def test_direction_friction_acts_in_its_direction_only(params, td, w, acts):
    pr = params.replace({"drive.direction_coulomb_torque": td})
    plant = build_plant("A", ["direction_friction"], params=pr)
    base = build_plant("A", params=pr)
    _, kt, _, _, eta_g, _, _ = _consts(pr)
    extra = _steady_current(plant, pr, w, 0.0) - _steady_current(base, pr, w, 0.0)
    # unloaded, the motor drives: the extra friction costs td / eta_g at the motor
    assert extra == pytest.approx(math.copysign(abs(td), w) / eta_g / kt if acts else 0.0, abs=1e-12)


def test_ripple_and_cogging_follow_their_angles(params):
    a, b = 0.03, -0.02
    pr = params.replace({"drive.screw_ripple_torque_cos": a, "drive.screw_ripple_torque_sin": b,
                         "drive.cogging_torque_cos": 0.01, "drive.cogging_torque_sin": 0.004})
    r, kt, _, _, eta_g, _, _ = _consts(pr)
    base = build_plant("A", params=pr)
    ripple = build_plant("A", ["screw_friction_ripple"], params=pr)
    cog = build_plant("A", ["cogging_torque"], params=pr)
    lead, n = pr.value("screw.lead"), pr.value("drive.cogging_periods")
    for x in np.linspace(0.0, 0.02, 7):
        th_s = 2 * math.pi * x / lead
        expect = math.hypot(a, b) + a * math.cos(th_s) + b * math.sin(th_s)
        d = _steady_current(ripple, pr, 300.0, 0.0, x) - _steady_current(base, pr, 300.0, 0.0, x)
        assert d == pytest.approx(expect / eta_g / kt, abs=1e-12)
        th_m = n * x / r
        # the cogging torque acts on the rotors, beside the motor's: the motor needs that much less current
        d = _steady_current(cog, pr, 300.0, 0.0, x) - _steady_current(base, pr, 300.0, 0.0, x)
        assert d == pytest.approx(-(0.01 * math.cos(th_m) + 0.004 * math.sin(th_m)) / kt, abs=1e-12)


def test_closed_loop_steady_current_with_coulomb_and_offset(params, design):
    """Simulated under the cascade: the plateau current is the torque balance (integral action)."""
    from thsa_control.sim.scenarios import Scenario
    from thsa_control.sim.simulate import SimulationSettings, Simulator

    pr = params.replace({"drive.coulomb_torque": 0.1, "drive.axial_force_offset": -3000.0})
    sc = Scenario("steady", "constant speed", 1.5, ((0.0, 0.0), (0.1, 5e-3)), 0.05, ((0.0, 0.0),))
    res = Simulator(build_plant(None, ["coulomb_friction", "force_offset"], params=pr),
                    SimulationSettings(output_period=1e-3)).run(sc, design, pr)
    r, kt, eta_d, eta_i, _, _, b_g = _consts(pr)
    w = 5e-3 / r
    torque = _motor_torque(pr, w, b_g * w + 0.1 - 3000.0 * r * eta_i)  # the offset pulls: it aids extension
    m = res.window(1.2, 1.5)
    assert np.mean(res["motor_current"][m]) == pytest.approx(torque / kt, rel=1e-4)


def test_linearisation_sees_the_cogging_stiffness(params):
    """d(speed rate)/d(position) of the continuous RHS is the cogging stiffness over the inertia."""
    import casadi as ca

    pr = params.replace({"drive.cogging_torque_cos": 0.01})
    plant = build_plant("A", ["cogging_torque"], params=pr)
    x = ca.SX.sym("x", len(plant.states))
    A = ca.Function("A", [x], [ca.jacobian(plant.f(x, _u(plant), plant.p_vector(pr))[0], x)])
    r, kt, *_ = _consts(pr)
    n = pr.value("drive.cogging_periods")
    xp = np.array([0.0, 200.0, 0.0])
    Am = np.asarray(A(xp))
    # T = a cos(n x / r): dT/dx = -a n / r sin(0) = 0 at x = 0; at a quarter period it is -a n / r.
    # The cogging torque enters like the motor's: d(rate)/dx = dT/dx * d(rate)/d(current) / Kt
    assert Am[1, 2] == pytest.approx(0.0, abs=1e-9)
    xq = np.array([0.0, 200.0, math.pi / 2 * r / n])
    Aq = np.asarray(A(xq))
    assert Aq[1, 2] == pytest.approx(-0.01 * n / r * Aq[1, 0] / kt, rel=1e-9)


def test_cogging_step_is_its_torque_impulse_over_the_step(params):
    """The discrete step integrates the cogging's torque impulse over the angle the step sweeps: at a speed where one
    step sweeps several of its periods (18 per revolution at 80 rev/s, 2 ms: 18 rad) its speed change is the one of the
    same step cut into 2000 substeps (rig-sim's truth averages out likewise), not the full amplitude sampled at the
    step's start; at a slow speed it is the plain torque (the continuous form is unchanged).  The gearbox is lossless
    here: its loss on the cogging torque's magnitude is a drag of its own, averaged differently."""
    pr = params.replace({"drive.cogging_torque_cos": 0.05, "drive.cogging_torque_sin": 0.0,
                         "drive.cogging_periods": 18.0, "gear.viscous_friction": 0.0,
                         "motor.bearing_viscous_friction": 0.0, "gear.efficiency": 1.0})
    off = pr.replace({"drive.cogging_torque_cos": 0.0})
    plant = build_plant("A", ["cogging_torque"], remove=["noback_ideal"], params=pr)
    u = _u(plant, enable_primary=0.0)  # the drive off: no current (its back-EMF would brake the fine steps)
    r, *_ = _consts(pr)
    h = 2e-3

    def dw(p, w0, x0, k):  # speed change over h in k steps, no current, no load
        x = np.array([0.0, w0, x0])
        for _ in range(k):
            x = np.asarray(plant.step(x, u, plant.p_vector(p), h / k)[0]).ravel()
        return x[1] - w0

    for w0, x0 in ((2 * math.pi * 80.0, 0.3e-6), (2 * math.pi * 80.0, 2.1e-6), (2 * math.pi * 0.5, 1.0e-6)):
        fine = dw(pr, w0, x0, 2000) - dw(off, w0, x0, 2000)
        coarse = dw(pr, w0, x0, 1) - dw(off, w0, x0, 1)
        j = float(plant.inertia_fn(np.array([0.0, w0, x0]), plant.p_vector(pr))[0])
        sampled = 0.05 * math.cos(18.0 * x0 / r) * h / j  # the torque at the step's start, held over it
        assert coarse == pytest.approx(fine, abs=0.02 * abs(sampled) + 1e-9), (w0, coarse, fine, sampled)
        if w0 > 100:
            assert abs(coarse) < 0.2 * abs(sampled), (coarse, sampled)


@pytest.mark.parametrize("effects", [["force_offset"], ["loadpath_compliance", "force_offset"],
                                     ["loadpath_compliance", "force_offset", "noback_quadrant_friction"]])
def test_an_unmeasured_axial_force_loads_the_load_path_and_takes_its_power(params, effects):
    """``force_offset`` is a force on the output that the load cell does not see (a fixture's weight, a cable).
    With a compliant load path it deflects the attachments like the measured load does: at rest under a load ``F``
    the surface sits where the plant without the offset puts it under ``F + f0`` (``f0 / k``: 38 um at 1.5 kN on the
    default contacts), in equilibrium; and the power it takes, ``f0 v``, closes the power balance (the electrical
    power less what the load and the offset take is the losses plus the stored energy's rate) at a state
    drawn moving, where the offset held at the parameter file's zero would let that term go untested."""
    import casadi as ca

    f0, load = 1500.0, 12e3
    pr = params.replace({"drive.axial_force_offset": f0})
    plant = build_plant(None, effects, params=pr)
    p = plant.p_vector(pr)
    x = np.asarray(plant.init(0.0, load, p)).ravel()
    u = _u(plant, load_force=load)
    u[plant.index("input", "enable_primary")] = 0.0
    if "loadpath_compliance" in effects:
        plain = build_plant(None, [e for e in effects if e != "force_offset"], params=pr)
        x_plain = np.asarray(plain.init(0.0, load + f0, plain.p_vector(pr))).ravel()
        s = plant.index("state", "surface_position")
        assert x[s] == pytest.approx(x_plain[plain.index("state", "surface_position")], rel=1e-12)
        x_zero = np.asarray(plain.init(0.0, load, plain.p_vector(pr))).ravel()
        k = pr.value("loadpath.contact_stiffness_upper") + 2 * pr.value("loadpath.disk_spring_stiffness")
        assert x_zero[s] - x[s] == pytest.approx(f0 / k, rel=0.05)  # beyond the preload: the upper contact
        xdot = np.asarray(plant.f(x, u, p)[0]).ravel()
        assert xdot[plant.index("state", "surface_speed")] == pytest.approx(0.0, abs=1e-9)
    xs, us, ps = ca.SX.sym("x", len(plant.states)), ca.SX.sym("u", len(plant.inputs)), ca.SX.sym("p", len(p))
    xdot, y = plant.f(xs, us, ps)
    o = {n: y[k] for k, n in enumerate(plant.outputs)}
    bal = ca.Function("b", [xs, us, ps], [o["electrical_power"] - o["load_power"], o["loss_power"],
                                          ca.mtimes(ca.jacobian(o["stored_energy"], xs), xdot)])
    r = plant.kinematic_ratio(p)
    for w in (300.0, -300.0):
        xm = x.copy()
        for name, v in (("motor_speed", w), ("rotor_speed", w), ("surface_speed", r * w), ("motor_current", 4.0)):
            if name in plant.state_names:
                xm[plant.index("state", name)] = v
        um = _u(plant, load_force=load, voltage_primary=40.0)
        pin, loss, stored = (float(v) for v in bal(xm, um, p))
        assert abs(pin - loss - stored) < 1e-8 * max(abs(pin), abs(loss), abs(stored), 1.0), (pin, loss, stored)
