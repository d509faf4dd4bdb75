"""Loop analysis: analytic reference loops, cross-checks with python-control, the nominal design over
the grid, requirements, describing functions, configurations, and linear vs nonlinear simulation."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import control as ct
import numpy as np
import pytest

from thsa_control.loops.analysis import (
    LOOPS,
    AnalysisSettings,
    analyse_configurations,
    analyse_loops,
    check_requirements,
    describing_functions,
    loop_margins,
    predict_limit_cycles,
    step_metrics,
)
from thsa_control.loops.design import parse_design
from thsa_control.errors import DesignError
from thsa_control.loops.linear import OperatingCondition
from thsa_control.model import build_plant
from thsa_control.sim.scenarios import Scenario
from thsa_control.sim.simulate import SimulationSettings, Simulator

# A grid small enough for the tests, large enough to hold the nominal design's worst points
# (2 mm/s under 55 kN aiding at -55 degC) and every kind of invalid point.
SMALL = AnalysisSettings(nut_speeds=(0.0, 1e-3, 2e-3, 10e-3), load_forces=(-55e3, 0.0, 55e3),
                         temperatures=(-55.0, 25.0, 70.0))


@pytest.fixture(scope="module")
def grid_analysis(design, params):
    return analyse_loops(design, params, settings=SMALL)


# ------------------------------------------------------------------------------------------------
# reference loops with an analytic answer
# ------------------------------------------------------------------------------------------------
# Discrete integrator loop L(z) = a / (z - 1), a = K h.  With theta = w h:
#   |L| = a / (2 sin(theta / 2)), arg L = -(pi/2 + theta/2)
#   crossover: theta_c = 2 asin(a / 2); PM = 90 deg - theta_c / 2; delay margin = PM / w_c
#   phase crossover at Nyquist (z = -1): GM = 2 / a
#   S = (z - 1) / (z - 1 + a): Ms = 2 / (2 - a) at Nyquist
#   T = a / (z - 1 + a): |T|^2 = 1/2 at cos(theta) = (2 - 2a - a^2) / (2 (1 - a))
@pytest.mark.parametrize("K", [10.0, 100.0, 1000.0])
def test_integrator_loop_margins_are_analytic(K):
    h = 1e-4
    a = K * h
    m = loop_margins([[1.0]], [[1.0]], [[a]], [[0.0]], h)
    wc = 2 / h * math.asin(a / 2)
    pm = 90 - math.degrees(wc * h / 2)
    bw = math.acos((2 - 2 * a - a**2) / (2 * (1 - a))) / h
    # crossings are refined by bisection on the exact response: 1e-9 relative
    assert m.crossover_hz[0] == pytest.approx(wc / (2 * math.pi), rel=1e-9)
    assert m.phase_margin_deg[0] == pytest.approx(pm, rel=1e-9)
    assert m.delay_margin_s[0] == pytest.approx(math.radians(pm) / wc, rel=1e-9)
    assert m.gain_margin_db[0] == pytest.approx(20 * math.log10(2 / a), rel=1e-9)
    assert m.phase_crossover_hz[0] == pytest.approx(1 / (2 * h), rel=1e-12)
    assert m.ms[0] == pytest.approx(2 / (2 - a), rel=1e-9)
    assert m.bandwidth_hz[0] == pytest.approx(bw / (2 * math.pi), rel=1e-9)


def test_conditionally_stable_loop_reports_the_lower_gain_margin():
    # L(s) = K (s + 1)^2 / s^3 is stable only for K above a limit and has a -180 deg crossing below
    # crossover: the margin closest to 0 dB (python-control's choice) is the lower one, negative in dB.
    h = 1e-3
    L = ct.c2d(ct.ss(ct.tf([20, 40, 20], [1, 0, 0, 0])), h, "zoh")
    m = loop_margins(L.A, L.B, L.C, L.D, h)
    w = np.geomspace(1e-2, math.pi / h * (1 - 1e-9), 5000)
    resp = ct.frequency_response(L, w)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gm, pm, sm, wpc, wgc, wms = ct.stability_margins((resp.magnitude.ravel(), np.degrees(resp.phase.ravel()), w))
    assert m.gain_margin_db[0] < 0
    # python-control interpolates 5000 points of the response: 1e-6 dB / deg, 1e-6 relative
    assert m.gain_margin_db[0] == pytest.approx(20 * math.log10(gm), abs=1e-6)
    assert m.phase_margin_deg[0] == pytest.approx(pm, abs=1e-6)
    assert m.crossover_hz[0] * 2 * math.pi == pytest.approx(wgc, rel=1e-6)
    assert m.phase_crossover_hz[0] * 2 * math.pi == pytest.approx(wpc, rel=1e-6)
    # both margins are kept: the lower one above, and the upper one at the crossing near Nyquist
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        gms = ct.stability_margins((resp.magnitude.ravel(), np.degrees(resp.phase.ravel()), w), returnall=True)[0]
    db = 20 * np.log10(np.asarray(gms))
    assert m.gain_margin_lower_db[0] == pytest.approx(db[db < 0].max(), abs=1e-6) == m.gain_margin_db[0]
    if np.any(db > 0):
        assert m.gain_margin_upper_db[0] == pytest.approx(db[db > 0].min(), abs=1e-6)
    else:  # python-control's grid stops below Nyquist, where this loop's upper crossing is
        assert m.gain_margin_upper_db[0] == pytest.approx(-20 * math.log10(abs(L(-1.0))), abs=1e-9)
    assert m.gain_margin_upper_db[0] > 0


def test_step_metrics_of_a_first_order_lag():
    # y = 1 - exp(-t/tau): rise 10-90 % = tau ln 9, settling into 2 % = tau ln 50, no overshoot
    tau = 0.5
    t = np.linspace(0, 10, 200001)
    m = step_metrics(t, (1 - np.exp(-t / tau))[None], np.array([1.0]))
    assert m.rise_time_s[0] == pytest.approx(tau * math.log(9), abs=1e-4)
    assert m.settling_time_s[0] == pytest.approx(tau * math.log(50), abs=1e-4)
    assert m.overshoot_percent[0] == 0.0


# ------------------------------------------------------------------------------------------------
# the cascade against python-control (state space, dense frequency grid)
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("cond", [OperatingCondition(5e-3, 20e3, 25.0), OperatingCondition(2e-3, -55e3, -55.0)])
def test_loops_match_python_control(design, params, cond):
    a = analyse_loops(design, params, [cond])
    lm = a.linearization[0]
    h, r = design.control_period, a.linearization.model.kinematic_ratio
    sub = lm.subsystem(inputs=["voltage_primary"], outputs=["motor_current", "motor_speed", "nut_speed"])
    n = sub.A.shape[0]
    Aa = np.block([[sub.A, np.zeros((n, 1))], [sub.C[2:3], np.zeros((1, 1))]])
    Ca = np.block([[sub.C, np.zeros((3, 1))], [np.zeros((1, n)), np.ones((1, 1))]])
    P = ct.c2d(ct.ss(Aa, np.vstack([sub.B, [[0.0]]]), Ca, 0), h, "zoh")  # with the nut kinematics
    Pm = ct.c2d(ct.ss(sub.A, sub.B, sub.C, 0), h, "zoh")  # without (its integrator would be an
    # unobservable pole at z = 1 of the current and velocity loops)
    pi = lambda kp, ki: ct.ss([[1.0]], [[1.0]], [[ki * h]], [[kp]], h)  # noqa: E731 - kp + ki h / (z - 1)
    Kc, Kv = pi(design.current_kp, design.current_ki), pi(design.velocity_kp, design.velocity_ki)
    if design.computation_delay_samples:  # the voltage is applied one period after the sample: z^-1
        Kc = ct.series(Kc, ct.ss([[0.0]], [[1.0]], [[1.0]], [[0.0]], h))
    Kx = ct.ss([[0.0]], [[1.0]], [[design.position_kp / r]], [[0.0]], h)  # kp / r z^-1
    ii = lm.states.index("motor_current")
    RL = ct.c2d(ct.ss(lm.A[ii:ii + 1, ii:ii + 1], lm.B[ii:ii + 1, :1], [[1.0]], 0), h, "zoh")
    Pcm = ct.feedback(ct.series(Kc, Pm), ct.ss([], [], [], [[1, 0, 0]], h))
    Pc = ct.feedback(ct.series(Kc, P), ct.ss([], [], [], [[1, 0, 0, 0]], h))
    Pv = ct.feedback(ct.series(Kv, Pc), ct.ss([], [], [], [[0, 1, 0, 0]], h))
    loops = {"current_loop": ct.series(Kc, RL), "velocity_loop": ct.series(Kv, Pcm[1, 0]),
             "position_loop": ct.series(Kx, Pv[3, 0])}
    w = np.geomspace(0.2 * math.pi, math.pi / h * (1 - 1e-9), 5000)
    for name, L in loops.items():
        resp = ct.frequency_response(L, w)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            gm, pm, sm, wpc, wgc, wms = ct.stability_margins(
                (resp.magnitude.ravel(), np.degrees(np.unwrap(resp.phase.ravel())), w))
        m = a.loops[name].margins
        # python-control interpolates 5000 points of its own evaluation of L: 1e-5 relative / deg; Ms from
        # the grid maximum, which can only be below the refined peak
        assert m.crossover_hz[0] * 2 * math.pi == pytest.approx(wgc, rel=1e-5), name
        assert m.phase_margin_deg[0] == pytest.approx(pm, abs=1e-5), name
        ms_grid = np.max(1 / np.abs(1 + resp.complex.ravel()))
        assert ms_grid * (1 - 1e-6) <= m.ms[0] <= ms_grid * (1 + 1e-3), name
        # python-control's frd grid stops below Nyquist, where the current loop's GM is without a delay
        if name != "current_loop" or design.computation_delay_samples:
            assert m.gain_margin_db[0] == pytest.approx(20 * math.log10(gm), abs=1e-5), name
        T = ct.feedback(L, 1)
        horizon = {"current_loop": 0.004, "velocity_loop": 0.3, "position_loop": 2.0}[name]
        decim = a.settings.step_decimation[LOOPS.index(name)]
        tt = np.arange(0, horizon + h / 2, h)
        info = ct.step_info(T, T=tt)
        si = a.loops[name].step_info
        assert si.rise_time_s[0] == pytest.approx(info["RiseTime"], abs=decim * h * 1.01), name
        assert si.settling_time_s[0] == pytest.approx(info["SettlingTime"], abs=decim * h * 1.01), name
        assert si.overshoot_percent[0] == pytest.approx(info["Overshoot"], abs=0.05), name
        # the closed-loop poles are python-control's
        np.testing.assert_allclose(np.sort(np.abs(a.loops[name].poles[0])), np.sort(np.abs(T.poles())),
                                   rtol=1e-6, atol=1e-9)
    # without a delay the current loop's phase reaches -180 deg only at Nyquist: its gain margin is -1 / L(-1)
    nodelay = analyse_loops(replace(design, computation_delay_samples=0), params, [cond], steps=False)
    L_ny = ct.series(pi(design.current_kp, design.current_ki), RL)(-1.0)
    assert nodelay.loops["current_loop"].margins.gain_margin_db[0] == pytest.approx(-20 * math.log10(abs(L_ny)),
                                                                                    rel=1e-9)


def test_computation_delay_costs_phase_at_crossover(design, params):
    cond = [OperatingCondition(10e-3, 20e3, 25.0)]
    assert design.computation_delay_samples == 1  # the nominal design declares the real controller's delay
    a0 = analyse_loops(replace(design, computation_delay_samples=0), params, cond, steps=False)
    a1 = analyse_loops(design, params, cond, steps=False)
    m0, m1 = a0.loops["current_loop"].margins, a1.loops["current_loop"].margins
    # z^-1 lags by w h: 360 f_c h deg (about 21 deg at the 600 Hz design's crossover); the crossover moves a
    # little, so 3 deg
    assert m0.phase_margin_deg[0] - m1.phase_margin_deg[0] == pytest.approx(360 * m0.crossover_hz[0] * 1e-4, abs=3.0)
    assert m1.gain_margin_db[0] < m0.gain_margin_db[0]


# ------------------------------------------------------------------------------------------------
# the nominal design over the grid
# ------------------------------------------------------------------------------------------------
def test_grid_worst_points_validity_and_saturation(grid_analysis):
    a = grid_analysis
    assert len(a) == 36 and a.grid is not None
    speeds = np.array([c.nut_speed for c in a.conditions])
    # zero speed: 9 points; against the no-back under 55 kN aiding (the loaded disk set carries the 55 kN alone,
    # beyond twice the preload) the steady motion needs about 14.7 A at 1 mm/s and 25 degC (tests/handcalc.py,
    # without the standby rotor's and the cold drags), under the 15 A limit, and > 15 A at 1 mm/s when cold
    # (15.6 A at -55 degC, the cold drag's low-speed rise): 1 point
    assert np.all(~a.valid[speeds == 0.0])
    sat = [c.label() for c in np.array(a.conditions)[a.saturated]]
    assert sat == ["1 mm/s, -55 kN (aiding), -55 degC"]
    assert all("current limit 15 A" in r[0] for c, r in a.invalid_points() if c.nut_speed != 0)
    assert a.valid.sum() == 36 - 9 - 1
    # every metric has a named worst point, and it is a valid one
    worst = {(w.loop, w.metric): w for w in a.worst_points()}
    # 9 metrics per loop, the upper gain margin of each, the lower one only where a loop is conditionally
    # stable (the velocity loop, aiding at 2 mm/s), and the 2 load-step metrics of the outer loops
    assert len(worst) == 3 * 10 + 1 + 2 * 2
    assert {m for (lp, m) in worst if m == "gain_margin_lower_db"} and ("current_loop", "gain_margin_lower_db") \
        not in worst and ("position_loop", "gain_margin_lower_db") not in worst
    assert all(a.valid[w.index] for w in worst.values())
    pm = worst[("velocity_loop", "phase_margin_deg")]
    # the loaded disk's Stribeck drop, with the cold drag's low-speed rise on top (valid: 15 A not reached)
    assert pm.condition.label() == "2 mm/s, -55 kN (aiding), -55 degC"
    assert 60 < pm.value < 75
    gm = worst[("velocity_loop", "gain_margin_db")]
    assert gm.value < 0 and gm.condition == pm.condition  # conditionally stable: a lower gain margin
    assert gm.text().startswith("velocity_loop gain_margin_db: conditionally stable (lower gain margin -13")
    lower = worst[("velocity_loop", "gain_margin_lower_db")]
    assert lower.value == gm.value and lower.index == gm.index
    upper = a.loops["velocity_loop"].margins.gain_margin_upper_db
    assert np.all(upper[a.valid] > 20)  # the upper one, near Nyquist, is far away everywhere
    assert worst[("current_loop", "phase_margin_deg")].uniform  # R and L do not depend on the point
    assert all(np.all(a.loops[loop].stable[a.valid]) for loop in LOOPS)


def test_nominal_design_meets_its_requirements(grid_analysis):
    check = check_requirements(grid_analysis)
    assert check.passed, check.summary()
    assert check.checked_points == 26 and check.skipped_points == 10
    assert {r.loop for r in check.rows} == set(LOOPS)


def test_violated_requirement_names_point_and_value(grid_analysis, design):
    doc = design.to_toml_dict()
    doc["requirements"] = {"velocity_loop": {"max_overshoot_percent": 20.0, "min_phase_margin_deg": 45.0},
                           "position_loop": {"min_bandwidth_hz": 5.0}}
    strict = parse_design(doc, source="strict.toml")
    check = check_requirements(replace(grid_analysis, design=strict))
    assert not check.passed
    worst_os = grid_analysis.worst("velocity_loop", "overshoot_percent")
    v = next(v for v in check.violations if v.requirement == "max_overshoot_percent" and v.index == worst_os.index)
    assert v.value == pytest.approx(worst_os.value) and v.value > 20
    assert worst_os.condition.label() in v.text() and f"{v.value:.4g}" in v.text()
    row = next(r for r in check.rows if r.requirement == "min_bandwidth_hz")
    assert not row.passed and row.n_failed == check.checked_points  # 2 Hz design vs 5 Hz asked
    assert "FAIL" in check.summary() and "velocity_loop.max_overshoot_percent = 20" in check.summary()
    assert next(r for r in check.rows if r.requirement == "min_phase_margin_deg").passed


@pytest.mark.parametrize("table, match", [
    ({"speed_loop": {"min_phase_margin_deg": 45}}, r"unknown table \[requirements.speed_loop\]"),
    ({"velocity_loop": {"min_phase_margin": 45}}, "unknown key 'min_phase_margin'"),
    ({"velocity_loop": {"min_phase_margin_deg": "45"}}, "must be a finite number"),
])
def test_bad_requirement_tables_are_named(design, table, match):
    doc = design.to_toml_dict()
    doc["requirements"] = table
    with pytest.raises(DesignError, match=match):
        parse_design(doc, source="bad.toml")


# ------------------------------------------------------------------------------------------------
# describing functions, configurations
# ------------------------------------------------------------------------------------------------
def test_describing_function_machinery_finds_backlash_limit_cycles():
    # K / (s (s + 1)) with a unit backlash: no limit cycle at K = 0.5, two intersections at K = 5
    w = np.geomspace(0.01, 100, 400)
    amps = 0.5 * (1 + np.geomspace(1e-3, 1e2, 60))
    low = predict_limit_cycles(ct.tf([0.5], [1, 1, 0])(1j * w), w, ct.friction_backlash_nonlinearity(1.0), amps)
    high = predict_limit_cycles(ct.tf([5.0], [1, 1, 0])(1j * w), w, ct.friction_backlash_nonlinearity(1.0), amps)
    assert low == [] and len(high) == 2


def test_tabulated_friction_describing_function_is_python_controls_quadrature():
    """The friction table's describing function (evaluated on the whole period at once) is the number
    python-control's quadrature gives for the same table called point by point, to the bit; a Coulomb-like
    table gives 4 T / (pi a) to the quadrature's accuracy."""
    from thsa_control.loops.describing import _TabulatedFriction

    pos = np.geomspace(1e-9, 2e3, 400)
    w = np.concatenate([-pos[::-1], [0.0], pos])
    torque = 0.3 * np.tanh(w / 1e-3) + 2e-4 * w + 0.05 * np.sign(w) * np.exp(-np.abs(w) / 5.0)
    table = _TabulatedFriction(w, torque)
    amps = np.geomspace(1e-3, 1e3, 60)
    ours = ct.describing_function(table, amps)
    theirs = ct.describing_function(lambda v: float(np.interp(v, w, torque)), amps)
    np.testing.assert_array_equal(ours, theirs)
    coulomb = _TabulatedFriction(w, 0.3 * np.sign(w))
    assert ct.describing_function(coulomb, 10.0) == pytest.approx(4 * 0.3 / (np.pi * 10.0), rel=2e-3)


def test_describing_functions_of_the_nominal_design(design, params):
    cycles = describing_functions(design, params, settings=SMALL, temperatures=(-55.0, 25.0), loads=(0.0, 55e3))
    assert len(cycles) == 2 * 2 * 3
    assert {(c.loop, c.nonlinearity) for c in cycles} == {("velocity_loop", "friction"), ("position_loop", "friction"),
                                                          ("position_loop", "backlash")}
    # the nominal cascade: the model's friction and the load-path play predict no limit cycle
    assert not any(c.predicted for c in cycles)
    assert all(c.condition.nut_speed == 0.0 and math.isnan(c.amplitude) for c in cycles)


def test_active_and_standby_configurations(design, params):
    conf = analyse_configurations(design, params, settings=SMALL, temperatures=(25.0,), loads=(20e3,),
                                  nut_speed=10e-3)
    p, s = conf.primary, conf.standby
    assert p.conditions[0].active == "primary" and s.conditions[0].active == "standby"
    assert "standby_motor" in p.linearization.model.effects
    # identical motors, both rotors always dragged: the same margins either way
    for loop in LOOPS:
        assert p.loops[loop].margins.phase_margin_deg[0] == pytest.approx(s.loops[loop].margins.phase_margin_deg[0],
                                                                          rel=1e-9)
    # without the dragged standby rotor the inertia nearly halves and, the velocity loop crossing over on
    # the integrator Kt / (J s), its crossover rises roughly as 1 / J
    one_rotor = replace(SMALL, effects=tuple(e for e in SMALL.effects if e != "standby_motor"))
    single = analyse_loops(design, params, [OperatingCondition(10e-3, 20e3, 25.0)], settings=one_rotor, steps=False)
    ratio = single.linearization.inertia[0] / p.linearization.inertia[0]
    assert ratio == pytest.approx(0.53, abs=0.01)
    fc1 = single.loops["velocity_loop"].margins.crossover_hz[0]
    fc2 = p.loops["velocity_loop"].margins.crossover_hz[0]
    assert fc2 / fc1 == pytest.approx(ratio, rel=0.1)
    assert len(conf.rows()) == 2 * 3


# ------------------------------------------------------------------------------------------------
# linear model vs nonlinear simulation
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("level, effects, v0, load, temp", [
    ("B", ("temperature_friction",), 5e-3, 20e3, 25.0),     # Stribeck region of the preload disk
    ("B", ("temperature_friction",), 2e-3, 20e3, -55.0),    # cold: net damping < 0, plant unstable
    ("A", (), 10e-3, -20e3, -30.0),
])
def test_linear_model_predicts_the_small_signal_response(design, params, level, effects, v0, load, temp):
    dv = 0.1e-3  # 2..5 % of the trim speed: the friction slope stays that of the trim point
    sc = Scenario("small_speed_step", "trim, then a small speed step", 1.0, ((0.0, v0), (0.6, v0 + dv)), 10.0,
                  ((0.0, load),), temperature=temp, motor_off_at_zero=False)
    res = Simulator(build_plant(level, effects, params=params), SimulationSettings(output_period=1e-4)).run(
        sc, design, params)
    a = analyse_loops(design, params, [OperatingCondition(v0, load, temp)],
                      settings=AnalysisSettings(level=level, effects=effects))
    assert a.valid[0]
    lin = a.loops["velocity_loop"]
    cmd = np.asarray(res["speed_cmd"])
    k0 = int(np.argmax(cmd > v0 + dv / 2))  # the sample the shaped command steps
    y = np.asarray(res["nut_speed"])
    assert np.ptp(y[k0 - 1000:k0]) < 1e-3 * dv  # settled at the trim point before the step
    n = lin.step.shape[1]
    sim = (y[k0:k0 + n] - y[k0]) / dv
    # the simulator's plant is its own fixed-step scheme (exact current lag with frozen speed,
    # implicit friction), the linear model the exact ZOH of the AD Jacobian: 2 % of the step
    assert np.max(np.abs(sim - lin.step[0])) < 0.02
    assert sim.max() == pytest.approx(lin.step[0].max(), abs=0.01)


def test_analyse_design_builds_the_plant_model_once(design, params, monkeypatch):
    from thsa_control.loops import analysis, describing, linear, loop_analysis

    calls = []

    def counting(*args, **kwargs):
        calls.append(args[:2])
        return linear.plant_model(*args, **kwargs)

    for mod in (analysis, describing, loop_analysis):
        monkeypatch.setattr(mod, "plant_model", counting)
    settings = AnalysisSettings(nut_speeds=(2e-3,), load_forces=(20e3,), temperatures=(25.0,))
    assert "standby_motor" in settings.effects  # the default: configurations reuse the grid's model
    result = analysis.analyse_design(design, params, settings=settings, switching=False)
    assert len(calls) == 1
    assert result.configurations.primary.linearization.model is result.loops.linearization.model
