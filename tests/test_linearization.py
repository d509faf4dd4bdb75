"""Physics oracles for the generic ``linearization`` package.

Every reference value below is an analytic solution of a textbook model
(mass-spring-damper, Coulomb / Stribeck friction, DC motor, cart, dead-zone
spring) written out next to the case.  Tolerances say why they are what they
are.  These tests build their own casadi models (they do not reuse
``linearization.examples``) so that the oracle is independent of the package.
"""

from __future__ import annotations

import casadi as ca
import control as ct
import numpy as np
import pytest

from linearization import (
    LinearModel,
    ModelStructureError,
    NamedModel,
    OperatingPoint,
    OperatingPointError,
    OperatingPointSpec,
    SolverSettings,
    UnknownSignalError,
    finite_difference_jacobians,
    find_operating_point,
    find_operating_points,
    frequency_response_batch,
    jacobians,
    linearize,
    linearize_batch,
)

# --------------------------------------------------------------------------
# Models (each a few lines of textbook physics)
# --------------------------------------------------------------------------


def _function(name, x, u, p, xdot, y):
    return ca.Function(name, [x, u, p], [xdot, y], ["x", "u", "p"], ["xdot", "y"])


def build_msd(sym=ca.SX) -> NamedModel:
    """m a = F - c v - k x; outputs position [m] and velocity [m/s]."""
    x, u, p = sym.sym("x", 2), sym.sym("u", 1), sym.sym("p", 3)
    pos, vel, force = x[0], x[1], u[0]
    m, c, k = p[0], p[1], p[2]
    xdot = ca.vertcat(vel, (force - c * vel - k * pos) / m)
    return NamedModel(
        _function("msd", x, u, p, xdot, ca.vertcat(pos, vel)),
        states=("position", "velocity"), inputs=("force",),
        outputs=("position", "velocity"), parameters=("mass", "damping", "stiffness"),
    )


def build_coulomb() -> NamedModel:
    """m dv/dt = F + F_f, F_f = -Fc sign(v) - b v; output friction force [N]."""
    x, u, p = ca.SX.sym("x", 1), ca.SX.sym("u", 1), ca.SX.sym("p", 3)
    v, force = x[0], u[0]
    m, fc, b = p[0], p[1], p[2]
    friction = -fc * ca.sign(v) - b * v
    return NamedModel(
        _function("coulomb", x, u, p, (force + friction) / m, friction),
        states=("velocity",), inputs=("force",), outputs=("friction_force",),
        parameters=("mass", "coulomb_force", "viscous_coefficient"),
    )


def stribeck_force(v, fc, fs, vs, b):
    """F_f = -(Fc + (Fs - Fc) exp(-(v/vs)^2)) sign(v) - b v  [N]."""
    return -(fc + (fs - fc) * np.exp(-((v / vs) ** 2))) * np.sign(v) - b * v


def build_stribeck() -> NamedModel:
    x, u, p = ca.SX.sym("x", 1), ca.SX.sym("u", 1), ca.SX.sym("p", 5)
    v, force = x[0], u[0]
    m, fc, fs, vs, b = (p[i] for i in range(5))
    friction = -(fc + (fs - fc) * ca.exp(-((v / vs) ** 2))) * ca.sign(v) - b * v
    return NamedModel(
        _function("stribeck", x, u, p, (force + friction) / m, friction),
        states=("velocity",), inputs=("force",), outputs=("friction_force",),
        parameters=("mass", "coulomb_force", "static_force", "stribeck_velocity",
                    "viscous_coefficient"),
    )


def build_deadzone_spring() -> NamedModel:
    """Shaft with backlash: torque k * deadzone(twist, gap); J dw/dt = T_in - T_shaft."""
    x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 3)
    twist, speed = x[0], x[1]
    k, gap, inertia = p[0], p[1], p[2]
    dead = ca.if_else(twist > gap, twist - gap, ca.if_else(twist < -gap, twist + gap, 0))
    torque = k * dead
    return NamedModel(
        _function("backlash", x, u, p, ca.vertcat(speed, (u[0] - torque) / inertia), torque),
        states=("twist", "speed"), inputs=("torque",), outputs=("shaft_torque",),
        parameters=("stiffness", "half_gap", "inertia"),
    )


DC_PARAMS = {"inertia": 2e-3, "viscous": 1e-4, "torque_constant": 0.05,
             "resistance": 1.2, "inductance": 1e-3}


def build_dc_motor(sym=ca.SX) -> NamedModel:
    """J w' = K i - b w - T_L ; L i' = v - R i - K w."""
    x, u, p = sym.sym("x", 2), sym.sym("u", 2), sym.sym("p", 5)
    w, i = x[0], x[1]
    v, t_load = u[0], u[1]
    inertia, b, k, r, ind = (p[j] for j in range(5))
    xdot = ca.vertcat((k * i - b * w - t_load) / inertia, (v - r * i - k * w) / ind)
    return NamedModel(
        _function("dc_motor", x, u, p, xdot, ca.vertcat(w, i, k * i)),
        states=("speed", "current"), inputs=("voltage", "load_torque"),
        outputs=("speed", "current", "motor_torque"), parameters=tuple(DC_PARAMS),
    )


def build_cart(declared_drifting=("position",)) -> NamedModel:
    """m dv/dt = F - c v ; dx/dt = v (position drifts in a steady motion)."""
    x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 2)
    pos, vel = x[0], x[1]
    m, c = p[0], p[1]
    return NamedModel(
        _function("cart", x, u, p, ca.vertcat(vel, (u[0] - c * vel) / m),
                  ca.vertcat(pos, vel)),
        states=("position", "speed"), inputs=("force",), outputs=("position", "speed"),
        parameters=("mass", "friction_coefficient"), drifting_states=declared_drifting,
    )


def build_pendulum() -> NamedModel:
    """Smooth nonlinear oracle: m l^2 w' = -m g l sin(th) - d w|w|... made smooth: -d w^3."""
    x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 3)
    th, w = x[0], x[1]
    m, length, d = p[0], p[1], p[2]
    wdot = (u[0] * ca.cos(th) - m * 9.81 * length * ca.sin(th) - d * w**3) / (m * length**2)
    return NamedModel(
        _function("pendulum", x, u, p, ca.vertcat(w, wdot),
                  ca.vertcat(length * ca.sin(th), u[0] * w)),
        states=("angle", "rate"), inputs=("torque",), outputs=("horizontal", "power"),
        parameters=("mass", "length", "drag"),
    )


@pytest.fixture(scope="module")
def msd():
    return build_msd()


@pytest.fixture(scope="module")
def dc_motor():
    return build_dc_motor()


# --------------------------------------------------------------------------
# Mass-spring-damper: A, B, C, D and 1 / (m s^2 + c s + k)
# --------------------------------------------------------------------------
# (m [kg], c [N s/m], k [N/m]); analytic matrices. Tolerance 1e-9: AD is exact
# up to the rounding of a couple of divisions, so only round-off remains.
MSD_CASES = [(1.0, 0.5, 2.0), (2.5, 3.0, 40.0), (0.1, 0.02, 1e3)]


@pytest.mark.parametrize("m,c,k", MSD_CASES)
def test_msd_matrices_are_analytic(msd, m, c, k):
    op = find_operating_point(msd, [m, c, k], OperatingPointSpec(inputs={"force": 1.0}))
    assert op.state("position") == pytest.approx(1.0 / k, rel=1e-12)  # static k x = F
    lm = linearize(msd, op)
    np.testing.assert_allclose(lm.A, [[0, 1], [-k / m, -c / m]], rtol=1e-9, atol=0)
    np.testing.assert_allclose(lm.B, [[0], [1 / m]], rtol=1e-9, atol=0)
    np.testing.assert_allclose(lm.C, np.eye(2), rtol=1e-9, atol=0)
    np.testing.assert_allclose(lm.D, np.zeros((2, 1)), atol=0)
    assert lm.valid and lm.invalid_reasons == ()


@pytest.mark.parametrize("m,c,k", MSD_CASES)
def test_msd_transfer_function(msd, m, c, k):
    op = OperatingPoint.from_values(msd, [0, 0], [0], [m, c, k])
    tf = linearize(msd, op).transfer_function("force", "position")
    num, den = np.asarray(tf.num[0][0], float), np.asarray(tf.den[0][0], float)
    num = np.concatenate([np.zeros(3 - num.size), num]) / den[0]
    den = den / den[0]
    # 1 / (m s^2 + c s + k) = (1/m) / (s^2 + c/m s + k/m); 1e-9 relative to the
    # largest coefficient (ss2tf goes through a polynomial fit of eigenvalues).
    scale = max(1.0, k / m)
    np.testing.assert_allclose(den, [1, c / m, k / m], rtol=0, atol=1e-9 * scale)
    np.testing.assert_allclose(num, [0, 0, 1 / m], rtol=0, atol=1e-9 * max(1.0, 1 / m))
    # And the same transfer function at a test frequency, evaluated directly.
    s = 3.7j
    assert complex(tf(s)) == pytest.approx(1 / (m * s**2 + c * s + k), rel=1e-9)


# --------------------------------------------------------------------------
# AD vs finite differences
# --------------------------------------------------------------------------
@pytest.mark.parametrize("x0", [[0.3, -0.7], [2.0, 1.5], [-1.2, 0.05]])
def test_ad_matches_central_finite_differences(x0):
    model = build_pendulum()
    p = [0.8, 0.5, 0.3]
    AD = jacobians(model, x0, [0.4], p)
    FD = finite_difference_jacobians(model, x0, [0.4], p, eps=1e-6)
    # Central differences with h = 1e-6: truncation ~h^2 |f'''| ~ 1e-11 and
    # round-off ~ eps_machine |f| / h ~ 1e-10 for O(1)..O(100) entries -> 1e-7.
    for ad, fd in zip(AD, FD):
        np.testing.assert_allclose(fd, ad, rtol=1e-7, atol=1e-7)
    lm = linearize(model, OperatingPoint.from_values(model, x0, [0.4], p))
    assert lm.fd_discrepancy < 1e-6
    assert lm.valid, lm.invalid_reasons
    # One-sided differences are first order: their error is O(h), not O(h^2).
    FW = finite_difference_jacobians(model, x0, [0.4], p, eps=1e-6, scheme="forward")
    np.testing.assert_allclose(FW[0], AD[0], rtol=1e-4, atol=1e-4)


def test_mx_model_gives_the_same_answers_as_sx():
    sx, mx = build_dc_motor(ca.SX), build_dc_motor(ca.MX)
    spec = OperatingPointSpec(inputs={"load_torque": 0.2}, outputs={"speed": 50.0})
    op_sx = find_operating_point(sx, DC_PARAMS, spec)
    op_mx = find_operating_point(mx, DC_PARAMS, spec)
    np.testing.assert_allclose(op_mx.u, op_sx.u, rtol=1e-12)
    np.testing.assert_allclose(linearize(mx, op_mx).A, linearize(sx, op_sx).A, rtol=1e-12)


# --------------------------------------------------------------------------
# Non-smoothness: Coulomb jump, dead-zone kink, Stribeck curvature
# --------------------------------------------------------------------------
COULOMB_P = {"mass": 2.0, "coulomb_force": 3.0, "viscous_coefficient": 0.5}


def test_coulomb_friction_at_zero_speed_is_invalid():
    model = build_coulomb()
    lm = linearize(model, OperatingPoint.from_values(model, [0.0], [0.0], COULOMB_P))
    assert not lm.valid
    assert len(lm.invalid_reasons) == 1
    reason = lm.invalid_reasons[0]
    assert "'velocity'" in reason and "jumps" in reason
    # The jump of dv/dt from v = 0 to v = 0+ is Fc / m = 1.5 m/s^2 (sign(0) = 0).
    assert "1.5" in reason
    assert lm.fd_discrepancy > 0.9  # FD ~ Fc/(m h) vs AD -b/m
    # Without the finite-difference check nothing can be detected, and the
    # result says that no check was made.
    unchecked = linearize(model, OperatingPoint.from_values(model, [0.0], [0.0], COULOMB_P),
                          fd_check=False)
    assert unchecked.valid and np.isnan(unchecked.fd_discrepancy)


@pytest.mark.parametrize("v0", [1.0, -1.0, 0.2])
def test_coulomb_friction_away_from_zero_has_viscous_slope(v0):
    model = build_coulomb()
    lm = linearize(model, OperatingPoint.from_values(model, [v0], [0.0], COULOMB_P))
    assert lm.valid, lm.invalid_reasons
    b, m = COULOMB_P["viscous_coefficient"], COULOMB_P["mass"]
    # d F_f / dv = -b exactly for v != 0 (AD; round-off only).
    assert lm.C[0, 0] == pytest.approx(-b, rel=1e-12)
    assert lm.A[0, 0] == pytest.approx(-b / m, rel=1e-12)


def test_deadzone_contact_edge_is_a_kink():
    model = build_deadzone_spring()
    k, gap, inertia = 1e4, 1e-3, 0.1
    p = [k, gap, inertia]
    edge = linearize(model, OperatingPoint.from_values(model, [gap, 0], [0], p))
    assert not edge.valid
    assert "'twist'" in edge.invalid_reasons[0] and "kink" in edge.invalid_reasons[0]
    inside = linearize(model, OperatingPoint.from_values(model, [0.0, 0], [0], p))
    engaged = linearize(model, OperatingPoint.from_values(model, [2 * gap, 0], [0], p))
    assert inside.valid and engaged.valid
    assert inside.A[1, 0] == 0.0  # free play: no restoring torque
    assert engaged.A[1, 0] == pytest.approx(-k / inertia, rel=1e-12)


def build_smooth_flat() -> NamedModel:
    """Smooth terms whose slope is zero at the origin, plus a large offset."""
    x, u, p = ca.SX.sym("x", 1), ca.SX.sym("u", 1), ca.SX.sym("p", 1)
    a, w = x[0], u[0]
    # offset p = 1e10: |f| >> its changes, so the difference quotients are
    # dominated by round-off (~ ulp(1e10) / h ~ 0.6) - noise, not a kink.
    xdot = p[0] + a**2 + a**3 + w**2
    return NamedModel(_function("flat", x, u, p, xdot, ca.vertcat(ca.cos(a), a**2 * w)),
                      ("a",), ("w",), ("cos_a", "a2w"), ("offset",))


@pytest.mark.parametrize("point", [(0.0, 0.0), (1e-7, -1e-7), (0.0, 3.0)])
def test_smooth_points_with_zero_slope_are_valid(point):
    # At a = w = 0 every Jacobian entry is 0 while the one-sided quotients are
    # +-h (a^2), h^2 (a^3): relatively "large" but shrinking with the step, so
    # they are curvature, not a kink.  The 1e10 offset checks the round-off floor.
    model = build_smooth_flat()
    lm = linearize(model, OperatingPoint.from_values(model, [point[0]], [point[1]], [1e10]))
    assert lm.valid, lm.invalid_reasons
    assert lm.A[0, 0] == pytest.approx(2 * point[0] + 3 * point[0] ** 2, abs=1e-15)
    assert lm.B[0, 0] == pytest.approx(2 * point[1], abs=1e-15)


def test_pendulum_at_rest_is_valid():
    model = build_pendulum()  # cubic drag -d w^3: zero slope, nonzero curvature at w = 0
    lm = linearize(model, OperatingPoint.from_values(model, [0.0, 0.0], [0.0], [0.8, 0.5, 0.3]))
    assert lm.valid, lm.invalid_reasons
    # d(rate)/dt = -g/l angle at rest (small-angle pendulum).
    assert lm.A[1, 0] == pytest.approx(-9.81 / 0.5, rel=1e-12)


STRIBECK_P = {"mass": 2.0, "coulomb_force": 3.0, "static_force": 5.0,
              "stribeck_velocity": 0.01, "viscous_coefficient": 0.5}


@pytest.mark.parametrize("ratio", [0.3, 0.5, 0.7071, 1.0])
def test_stribeck_region_has_negative_local_damping(ratio):
    model = build_stribeck()
    fc, fs = STRIBECK_P["coulomb_force"], STRIBECK_P["static_force"]
    vs, b, m = STRIBECK_P["stribeck_velocity"], STRIBECK_P["viscous_coefficient"], STRIBECK_P["mass"]
    v = ratio * vs
    lm = linearize(model, OperatingPoint.from_values(model, [v], [0.0], STRIBECK_P))
    # Local damping c_loc = -dF_f/dv = b - 2 (Fs - Fc) v / vs^2 exp(-(v/vs)^2)  [N s/m]
    c_loc = b - 2 * (fs - fc) * v / vs**2 * np.exp(-(ratio**2))
    assert c_loc < 0  # oracle sanity: this is the Stribeck (falling) region
    assert -lm.C[0, 0] == pytest.approx(c_loc, rel=1e-10)
    assert lm.A[0, 0] == pytest.approx(-c_loc / m, rel=1e-10)
    assert lm.poles()[0].real > 0  # negative damping: locally unstable
    # Smooth there despite strong curvature: the detector must not flag it.
    assert lm.valid, lm.invalid_reasons
    # Independent check of the slope by a hand-made central difference
    # (h = 1e-7 vs = 1e-9 m/s; error ~ h^2 f''' / 6 relative ~ 1e-8).
    h = 1e-7 * vs
    fd = (stribeck_force(v + h, fc, fs, vs, b) - stribeck_force(v - h, fc, fs, vs, b)) / (2 * h)
    assert -fd == pytest.approx(c_loc, rel=1e-6)


# --------------------------------------------------------------------------
# Operating points
# --------------------------------------------------------------------------
def _dc_expected(speed, t_load):
    """Steady state: K i = b w + T_L ; v = R i + K w."""
    p = DC_PARAMS
    current = (p["viscous"] * speed + t_load) / p["torque_constant"]
    return current, p["resistance"] * current + p["torque_constant"] * speed


@pytest.mark.parametrize("method", ["auto", "newton", "kinsol", "gauss-newton"])
def test_dc_motor_operating_point_holding_speed(dc_motor, method):
    spec = OperatingPointSpec(inputs={"load_torque": 0.5}, outputs={"speed": 100.0})
    op = find_operating_point(dc_motor, DC_PARAMS, spec, settings=SolverSettings(method=method))
    current, voltage = _dc_expected(100.0, 0.5)  # 10.2 A, 17.24 V
    # Linear equations: the solvers hit them to round-off; 1e-9 relative.
    assert op.input("voltage") == pytest.approx(voltage, rel=1e-9)
    assert op.state("current") == pytest.approx(current, rel=1e-9)
    assert op.output("speed") == pytest.approx(100.0, rel=1e-12)
    assert op.input("load_torque") == 0.5
    assert op.residual <= 1e-9 and op.drift_rates == {}


def test_dc_motor_overdetermined_consistent_and_inconsistent(dc_motor):
    # Holding the speed state and the speed output is redundant but consistent.
    spec = OperatingPointSpec(
        inputs={"load_torque": 0.5}, outputs={"speed": 100.0}, states={"speed": 100.0}
    )
    op = find_operating_point(dc_motor, DC_PARAMS, spec)
    assert op.input("voltage") == pytest.approx(_dc_expected(100.0, 0.5)[1], rel=1e-9)
    # Holding the voltage too leaves 2 unknowns for 3 equations that disagree:
    # 10 V cannot sustain 100 rad/s (it needs 17.24 V).
    bad = OperatingPointSpec(inputs={"load_torque": 0.5, "voltage": 10.0},
                             outputs={"speed": 100.0})
    with pytest.raises(OperatingPointError) as info:
        find_operating_point(dc_motor, DC_PARAMS, bad)
    err = info.value
    assert err.residual_norm > 1.0
    assert err.worst_equation in str(err)
    assert err.worst_equation in ("output speed = target", "d(speed)/dt = 0", "d(current)/dt = 0")


def test_underdetermined_operating_point_satisfies_equations(dc_motor):
    spec = OperatingPointSpec(inputs={"load_torque": 0.5}, guess_u={"voltage": 12.0})
    op = find_operating_point(dc_motor, DC_PARAMS, spec)
    current, voltage = _dc_expected(op.state("speed"), 0.5)
    assert op.state("current") == pytest.approx(current, rel=1e-9)
    assert op.input("voltage") == pytest.approx(voltage, rel=1e-9)


def test_no_equilibrium_raises_naming_the_equation():
    x, u, p = ca.SX.sym("x", 1), ca.SX.sym("u", 1), ca.SX.sym("p", 1)
    model = NamedModel(_function("q", x, u, p, x**2 + p, x), ("level",), ("valve",),
                       ("level",), ("inflow",))
    # dx/dt = x^2 + c has roots x = +-sqrt(-c) for c < 0 and none for c > 0.
    spec = OperatingPointSpec(inputs={"valve": 0.0}, guess_x={"level": 0.5})
    with pytest.raises(OperatingPointError, match=r"d\(level\)/dt = 0"):
        find_operating_point(model, [1.0], spec)
    batch = find_operating_points(model, np.array([[-1.0, 1.0, -4.0]]), spec, on_failure="mark")
    assert batch.converged.tolist() == [True, False, True]
    np.testing.assert_allclose(batch.X[0, [0, 2]], [1.0, 2.0], rtol=1e-10)
    with pytest.raises(OperatingPointError, match="point 1"):
        find_operating_points(model, np.array([[-1.0, 1.0]]), spec)


def test_batch_operating_points_equal_single_solves(dc_motor):
    rng = np.random.default_rng(7)
    n = 50
    P = np.tile(np.array(list(DC_PARAMS.values()))[:, None], (1, n))
    P[2] *= rng.uniform(0.8, 1.2, n)  # torque constant +-20 %
    speeds = rng.uniform(10.0, 300.0, n)
    specs = [OperatingPointSpec(inputs={"load_torque": 0.3}, outputs={"speed": s}) for s in speeds]
    batch = find_operating_points(dc_motor, P, specs)
    assert batch.converged.all() and len(batch) == n
    for k in (0, 17, 49):
        single = find_operating_point(dc_motor, P[:, k], specs[k])
        np.testing.assert_allclose(batch.X[:, k], single.x, rtol=1e-10)
        np.testing.assert_allclose(batch.U[:, k], single.u, rtol=1e-10)
        assert batch[k].output("speed") == pytest.approx(speeds[k], rel=1e-10)


# --------------------------------------------------------------------------
# Drifting states (steady motion)
# --------------------------------------------------------------------------
CART_P = {"mass": 10.0, "friction_coefficient": 2.0}


def test_cart_in_steady_motion_with_drifting_position():
    model = build_cart()
    spec = OperatingPointSpec(outputs={"speed": 2.0}, guess_x={"position": 5.0})
    op = find_operating_point(model, CART_P, spec)
    # F = c v = 4 N keeps 2 m/s; the position drifts at 2 m/s and stays at its guess.
    assert op.input("force") == pytest.approx(4.0, rel=1e-12)
    assert op.drift_rates == pytest.approx({"position": 2.0}, rel=1e-12)
    assert op.state("position") == 5.0
    lm = linearize(model, op)
    assert lm.excluded_states == ("position",)
    assert lm.excluded_outputs == ("position",)  # it would integrate the drift
    assert lm.states == ("speed",) and lm.outputs == ("speed",)
    np.testing.assert_allclose(lm.A, [[-0.2]], rtol=1e-12)  # -c / m
    assert lm.valid
    kept = linearize(model, op, drifting="keep")
    assert kept.states == ("position", "speed") and kept.excluded_states == ()
    np.testing.assert_allclose(sorted(kept.poles().real), [-0.2, 0.0], atol=1e-15)


def test_declared_drifting_state_that_acts_on_dynamics_is_reported():
    model = build_msd()
    drifting = NamedModel(model.function, model.states, model.inputs, model.outputs,
                          model.parameters, drifting_states=("position",))
    lm = linearize(drifting, OperatingPoint.from_values(drifting, [0, 0], [0], [1, 1, 4]))
    assert not lm.valid
    assert any("'position'" in r and "d(velocity)/dt" in r for r in lm.invalid_reasons)


def test_validity_guard_names_the_violated_margin(msd):
    x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 3)
    guard = ca.Function("guards", [x, u, p], [0.1 - ca.fabs(x[0]), 10 - ca.fabs(u[0])],
                        ["x", "u", "p"], ["stroke_margin", "force_margin"])
    inside = linearize(msd, OperatingPoint.from_values(msd, [0.05, 0], [1], [1, 1, 1]),
                       validity=guard)
    assert inside.valid and inside.guard_margins["stroke_margin"] == pytest.approx(0.05)
    outside = linearize(msd, OperatingPoint.from_values(msd, [0.3, 0], [1], [1, 1, 1]),
                        validity=guard)
    assert not outside.valid
    assert len(outside.invalid_reasons) == 1 and "'stroke_margin'" in outside.invalid_reasons[0]


# --------------------------------------------------------------------------
# Batch linearisation and frequency response
# --------------------------------------------------------------------------
def test_batch_of_50_equals_per_point_results():
    model = build_stribeck()
    rng = np.random.default_rng(11)
    n = 50
    V = rng.uniform(-0.05, 0.05, n)
    V[[3, 20]] = 0.0  # Coulomb/Stribeck jump: must be invalid in both paths
    X = V[None, :]
    U = rng.uniform(-1.0, 1.0, (1, n))
    P = np.tile(np.array(list(STRIBECK_P.values()))[:, None], (1, n))
    P[4] *= rng.uniform(0.5, 2.0, n)
    batch = linearize_batch(model, X, U, P)
    assert batch.A.shape == (n, 1, 1) and batch.D.shape == (n, 1, 1)
    assert not batch.valid[3] and not batch.valid[20]
    for k in range(n):
        single = linearize(model, OperatingPoint.from_values(model, X[:, k], U[:, k], P[:, k]))
        # Same casadi expressions evaluated mapped vs alone: equal to round-off.
        for name in "ABCD":
            np.testing.assert_allclose(getattr(batch, name)[k], getattr(single, name),
                                       rtol=1e-13, atol=0)
        assert bool(batch.valid[k]) == single.valid
        assert batch.invalid_reasons[k] == single.invalid_reasons
        assert batch.fd_discrepancy[k] == pytest.approx(single.fd_discrepancy, rel=1e-6, abs=1e-12)
        np.testing.assert_allclose(batch[k].A, single.A, rtol=1e-13)


def test_threaded_batch_equals_serial():
    model = build_coulomb()
    V = np.array([[-1.0, 0.0, 0.5, 2.0, 0.0, -0.1]])
    P = np.array(list(COULOMB_P.values()))
    serial = linearize_batch(model, V, np.zeros((1, 6)), P)
    threaded = linearize_batch(model, V, np.zeros((1, 6)), P, parallelization="thread")
    np.testing.assert_array_equal(threaded.A, serial.A)
    assert threaded.valid.tolist() == serial.valid.tolist() == [True, False, True, True, False, True]
    assert threaded.invalid_reasons == serial.invalid_reasons


def test_frequency_response_batch_matches_python_control():
    model = build_msd()
    rng = np.random.default_rng(3)
    n = 12
    P = np.vstack([rng.uniform(0.5, 2.0, n), rng.uniform(0.2, 3.0, n), rng.uniform(1.0, 100.0, n)])
    batch = linearize_batch(model, np.zeros((2, n)), np.zeros((1, n)), P)
    omega = np.logspace(-2, 3, 300)
    G = frequency_response_batch(batch, "force", "position", omega)
    assert G.shape == (n, omega.size)
    for k in range(n):
        sys = batch[k].subsystem(["force"], ["position"]).to_statespace()
        ref = ct.frequency_response(sys, omega).complex.reshape(-1)
        # Same linear algebra problem in double precision; condition of
        # (jwI - A) <= ~1e3 here, so 1e-10 relative leaves ample margin.
        np.testing.assert_allclose(G[k], ref, rtol=1e-10, atol=0)
        analytic = 1 / (P[0, k] * (1j * omega) ** 2 + P[1, k] * 1j * omega + P[2, k])
        np.testing.assert_allclose(G[k], analytic, rtol=1e-10, atol=0)


def test_frequency_response_batch_multi_state_and_feedthrough(dc_motor):
    op = find_operating_point(
        dc_motor, DC_PARAMS, OperatingPointSpec(inputs={"load_torque": 0.1}, outputs={"speed": 80.0})
    )
    lm = linearize(dc_motor, op)
    batch = linearize_batch(dc_motor, op.x, op.u, op.p)
    omega = np.logspace(-1, 4, 200)
    for inp, out in (("voltage", "speed"), ("load_torque", "motor_torque"), ("voltage", "current")):
        G = frequency_response_batch(batch, inp, out, omega)[0]
        ref = ct.frequency_response(lm.subsystem([inp], [out]).to_statespace(), omega)
        np.testing.assert_allclose(G, ref.complex.reshape(-1), rtol=1e-10, atol=0)


# --------------------------------------------------------------------------
# Conversions, names, files
# --------------------------------------------------------------------------
def test_to_statespace_and_transfer_function_keep_names(dc_motor):
    op = find_operating_point(
        dc_motor, DC_PARAMS, OperatingPointSpec(inputs={"load_torque": 0.0}, outputs={"speed": 10.0})
    )
    lm = linearize(dc_motor, op)
    sys = lm.to_statespace(name="motor")
    assert sys.state_labels == ["speed", "current"]
    assert sys.input_labels == ["voltage", "load_torque"]
    assert sys.output_labels == ["speed", "current", "motor_torque"]
    assert sys.name == "motor"
    sub = lm.subsystem(inputs=["load_torque"], outputs=["motor_torque", "speed"])
    np.testing.assert_array_equal(sub.C, lm.C[[2, 0], :])
    np.testing.assert_array_equal(sub.B, lm.B[:, [1]])
    tf = lm.transfer_function("voltage", "speed")
    assert tf.input_labels == ["voltage"] and tf.output_labels == ["speed"]
    # DC gain speed/voltage = K / (K^2 + R b): static solution of the two balances.
    p = DC_PARAMS
    k_dc = p["torque_constant"] / (p["torque_constant"] ** 2 + p["resistance"] * p["viscous"])
    assert float(np.real(tf(0))) == pytest.approx(k_dc, rel=1e-9)


def test_npz_round_trip(tmp_path):
    model = build_coulomb()
    x, u, p = ca.SX.sym("x", 1), ca.SX.sym("u", 1), ca.SX.sym("p", 3)
    guard = ca.Function("g", [x, u, p], [1 - x[0]], ["x", "u", "p"], ["below_1"])
    lm = linearize(model, OperatingPoint.from_values(model, [0.0], [0.5], COULOMB_P),
                   validity=guard)
    path = lm.save(tmp_path / "coulomb")
    assert path.name == "coulomb.npz" and path.exists()
    back = LinearModel.load(path)
    for name in "ABCD":
        np.testing.assert_array_equal(getattr(back, name), getattr(lm, name))
    for attr in ("states", "inputs", "outputs", "valid", "invalid_reasons",
                 "excluded_states", "excluded_outputs", "guard_margins"):
        assert getattr(back, attr) == getattr(lm, attr), attr
    assert back.fd_discrepancy == lm.fd_discrepancy
    assert not back.valid and back.invalid_reasons  # the Coulomb reason survived
    op, bop = lm.operating_point, back.operating_point
    np.testing.assert_array_equal(bop.x, op.x)
    np.testing.assert_array_equal(bop.p, op.p)
    assert bop.parameters == op.parameters and bop.as_dict() == op.as_dict()
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left behind


def test_unknown_names_are_named_in_errors(msd):
    with pytest.raises(UnknownSignalError, match="'speed'.*'position', 'velocity'"):
        msd.state_index("speed")
    with pytest.raises(KeyError):  # also a KeyError, for dict-like use
        msd.parameter_index("spring")
    with pytest.raises(ValueError, match="unknown input 'torque'"):
        find_operating_point(msd, [1, 1, 1], OperatingPointSpec(inputs={"torque": 1.0}))
    with pytest.raises(UnknownSignalError, match="unknown parameter 'mas'"):
        msd.parameter_vector({"mas": 1.0, "damping": 1.0, "stiffness": 1.0})
    lm = linearize(msd, OperatingPoint.from_values(msd, [0, 0], [0], [1, 1, 1]))
    with pytest.raises(UnknownSignalError, match="unknown output 'angle'"):
        lm.transfer_function("force", "angle")
    with pytest.raises(UnknownSignalError, match="unknown input 'voltage'"):
        lm.subsystem(inputs=["voltage"])
    batch = linearize_batch(msd, np.zeros((2, 1)), np.zeros((1, 1)), [1, 1, 1])
    with pytest.raises(UnknownSignalError, match="unknown output 'speed'"):
        frequency_response_batch(batch, "force", "speed", [1.0])


def test_named_model_rejects_size_and_io_mismatches(msd):
    with pytest.raises(ModelStructureError, match=r"input 'u' has shape \(1, 1\).*2 names"):
        NamedModel(msd.function, msd.states, ("force", "extra"), msd.outputs, msd.parameters)
    with pytest.raises(ModelStructureError, match=r"output 'y'"):
        NamedModel(msd.function, msd.states, msd.inputs, ("position",), msd.parameters)
    x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 3)
    wrong = ca.Function("w", [x, u, p], [x, x], ["x", "u", "p"], ["dx", "y"])
    with pytest.raises(ModelStructureError, match="outputs"):
        NamedModel(wrong, msd.states, msd.inputs, msd.outputs, msd.parameters)
    with pytest.raises(ModelStructureError, match="duplicate"):
        NamedModel(msd.function, ("a", "a"), msd.inputs, msd.outputs, msd.parameters)
    with pytest.raises(UnknownSignalError, match="'angle'"):
        NamedModel(msd.function, msd.states, msd.inputs, msd.outputs, msd.parameters,
                   drifting_states=("angle",))


def test_linearize_rejects_an_operating_point_of_another_model(msd):
    cart = build_cart()
    op = OperatingPoint.from_values(cart, [0, 1], [2], CART_P)
    with pytest.raises(ValueError, match="states"):
        linearize(msd, op)
    with pytest.raises(ValueError, match="drifting"):
        linearize(cart, op, drifting="ignore")


# ----------------------------------------------------------------------------- call_dense (casadi buffer interface)
def test_call_dense_gives_the_ordinary_call_s_numbers_to_the_bit():
    """Mapped over points, with a matrix and a vector argument: the same numbers as the ordinary call; a
    broadcast argument and a sparse output take the ordinary call, with the same result."""
    import casadi as ca

    from linearization.buffered import call_dense

    x, p = ca.SX.sym("x", 3), ca.SX.sym("p", 2)
    y = ca.vertcat(ca.sin(x[0] * p[0]) + x[1] ** 2, ca.exp(-x[2]) * p[1])
    f = ca.Function("f", [x, p], [y, ca.jacobian(y, x)])  # the Jacobian is sparse
    fd = ca.Function("fd", [x, p], [ca.densify(y), ca.densify(ca.jacobian(y, x))])
    rng = np.random.default_rng(4)
    n = 7
    X, P = rng.normal(size=(3, n)), rng.normal(size=(2, n))
    m = fd.map(n)
    got = call_dense(m, X, P)
    ref = [np.asarray(v) for v in m(X, P)]
    assert [g.shape for g in got] == [(2, n), (2, 3 * n)]
    for g, r in zip(got, ref):
        np.testing.assert_array_equal(g, r)
    one = call_dense(fd, X[:, 0], P[:, :1])  # a vector as 1-D or as one column
    np.testing.assert_array_equal(one[1], np.asarray(fd(X[:, 0], P[:, 0])[1]))
    bc = call_dense(m, X, P[:, :1])  # one column broadcast by casadi: the ordinary call
    np.testing.assert_array_equal(bc[0], np.asarray(m(X, P[:, :1])[0]))
    sparse = call_dense(f, X[:, 0], P[:, 0])
    np.testing.assert_array_equal(sparse[1], np.asarray(ca.densify(f(X[:, 0], P[:, 0])[1])))
    with pytest.raises(ValueError, match="takes 2 arguments"):
        call_dense(f, X[:, 0])
