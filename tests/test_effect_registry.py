"""The effect registry's contract, checked on every registered effect (a new effect gets it by registering).

For each effect of :data:`thsa_control.model.EFFECTS` (parametrized over the
registry, so an effect registered later is covered with no edit here):

* at its declared neutral parameter values the plant with the effect is the
  plant without it (``f`` and every signal the effect does not own, exactly,
  at random states and inputs), or it says why no value removes it;
* every effect set has the same output signals (the effect declares the
  neutral value of each output it writes);
* the continuous power balance closes: electrical power in minus the power
  into the load equals the losses plus the rate of the stored energy, all
  from the assembly's own terms;
* ``f`` and the discrete ``step`` agree at a small step;
* it is a tracer candidate (spec of its own parameters, a known window and
  channel) or says why not; its linearisation hints name its own states and
  known settings.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from thsa_control.fit.replay import FIT_CHANNELS
from thsa_control.loops.linear import LinearizationSettings
from thsa_control.model import EFFECTS, CandidateSpec, NoNeutral, NotCandidate, build_plant, resolve_effects
from thsa_control.model.params import default_parameters
from thsa_control.trace.engine import WINDOWS  # the tracer's window kinds

NAMES = tuple(EFFECTS)
FAULT_INPUTS = ("brake", "surface_jam", "loadpath_failure")


def _with_requirements(name: str) -> tuple[str, ...]:
    return resolve_effects(None, add=[*EFFECTS[name].requires, name])


def _base(name: str) -> tuple[str, ...]:
    return resolve_effects(None, add=list(EFFECTS[name].requires))


def _p(plant, params, override=()):
    p = plant.p_vector(params)
    for n, v in dict(override).items():
        p[plant.parameters.index(n)] = v
    return p


def _draw(plant, params, rng, *, moving: bool, p=None):
    """A random state (rest state under a random load, then random currents, speeds and small positions)
    and random healthy inputs."""
    p = plant.p_vector(params) if p is None else p
    load = float(rng.normal(0.0, 2e4))
    x = np.asarray(plant.init(rng.normal(0.0, 0.02), load, p)).ravel()
    w = float(rng.choice([-1.0, 1.0]) * rng.uniform(20.0, 300.0)) if moving else float(rng.normal(0.0, 100.0))
    r = plant.kinematic_ratio(p)
    for i, s in enumerate(plant.states):
        if s.name == "motor_speed":
            x[i] = w
        elif s.name == "rotor_speed":
            x[i] = w * (1.0 + rng.normal(0.0, 1e-3))
        elif s.name == "surface_speed":
            x[i] = r * w * (1.0 + rng.normal(0.0, 1e-3))
        elif s.kind == "lag" and s.unit == "A":
            x[i] = rng.normal(0.0, 5.0)
        elif s.kind == "velocity":
            x[i] = rng.normal(0.0, 1e-3)
        elif s.kind == "position" and s.name != "nut_position":
            x[i] += rng.normal(0.0, 1e-6)
    u = np.zeros(len(plant.inputs))
    standby_on = float(rng.integers(0, 2))
    for n, v in (("voltage_primary", rng.normal(0.0, 60.0)), ("voltage_standby", rng.normal(0.0, 60.0)),
                 ("enable_primary", 1.0), ("enable_standby", standby_on), ("load_force", load),
                 ("temperature", rng.uniform(-40.0, 60.0))):
        u[plant.index("input", n)] = v
    if not standby_on and "standby_current" in plant.state_names:
        # an inverter that is off has let its current decay (the off-state decay law is the diodes' and
        # does not model the back-EMF; the current is gone within milliseconds)
        x[plant.index("state", "standby_current")] = 0.0
    return x, u


@pytest.fixture(scope="module")
def params():
    return default_parameters()


@pytest.mark.parametrize("name", NAMES)
def test_effect_declares_its_contract(name):
    e = EFFECTS[name]
    assert e.summary and callable(e.apply)
    assert isinstance(e.candidate, (CandidateSpec, NotCandidate)), f"{name}: no tracer candidate spec nor exclusion"
    if isinstance(e.candidate, NotCandidate):
        assert e.candidate.reason.strip()
    else:
        spec = e.candidate
        assert spec.name == name and spec.window in WINDOWS and spec.channel in FIT_CHANNELS
        assert spec.free or spec.profile, f"{name}: a candidate with nothing to fit"
    assert isinstance(e.neutral, (dict, NoNeutral)), f"{name}: no neutral parameters nor the reason it has none"
    if isinstance(e.neutral, NoNeutral):
        assert e.neutral.reason.strip()
    own = {s.name for s in e.states}
    assert set(e.linear.drifting) <= own
    assert set(e.linear.relative) <= own
    for g in e.linear.guards:
        assert hasattr(LinearizationSettings(), g.band), f"{name}: guard {g.name} names no settings field {g.band}"
    for r in e.requires:
        assert r in EFFECTS


@pytest.mark.parametrize("name", NAMES)
def test_every_effect_set_has_the_same_outputs(params, name):
    base = build_plant(None, params=params)
    plant = build_plant(None, _with_requirements(name), params=params)
    assert plant.outputs == base.outputs


@pytest.mark.parametrize("name", NAMES)
def test_at_neutral_parameters_the_effect_is_the_base(params, name, rng):
    e = EFFECTS[name]
    if isinstance(e.neutral, NoNeutral):
        pytest.skip(f"{name} has no neutral value: {e.neutral.reason}")
    base = build_plant(None, _base(name), params=params)
    plant = build_plant(None, _with_requirements(name), params=params)
    pe, pb = _p(plant, params, e.neutral), _p(base, params, e.neutral)
    common = [plant.index("state", s) for s in base.state_names]
    own_outputs = {o.name for o in e.outputs}
    keep = [k for k, o in enumerate(base.outputs) if o not in own_outputs]
    for _ in range(12):
        x, u = _draw(plant, params, rng, moving=bool(rng.integers(0, 2)), p=pe)
        xb = x[common]
        xd, y = (np.asarray(v).ravel() for v in plant.f(x, u, pe))
        xdb, yb = (np.asarray(v).ravel() for v in base.f(xb, u, pb))
        np.testing.assert_array_equal(xd[common], xdb, err_msg=f"{name}: state derivatives differ")
        np.testing.assert_array_equal(y[keep], yb[keep], err_msg=f"{name}: signals differ")


def _power_terms(plant):
    x, u, p = ca.SX.sym("x", len(plant.states)), ca.SX.sym("u", len(plant.inputs)), ca.SX.sym("p", len(plant.parameters))
    xdot, y = plant.f(x, u, p)
    o = {n: y[k] for k, n in enumerate(plant.outputs)}
    stored_rate = ca.mtimes(ca.jacobian(o["stored_energy"], x), xdot)
    power_in = o["electrical_power"] - o["load_power"]
    return ca.Function("balance", [x, u, p], [power_in, o["loss_power"], stored_rate])


@pytest.mark.parametrize("name", NAMES)
def test_power_balance_closes(params, name, rng):
    plant = build_plant(None, _with_requirements(name), params=params)
    bal = _power_terms(plant)
    p = plant.p_vector(params)
    for _ in range(12):
        x, u = _draw(plant, params, rng, moving=True)
        pin, loss, stored = (float(v) for v in bal(x, u, p))
        scale = max(abs(pin), abs(loss), abs(stored), 1.0)
        assert abs(pin - loss - stored) < 1e-8 * scale, (
            f"{name}: power in {pin:.6g} W, losses {loss:.6g} W, stored-energy rate {stored:.6g} W")


def _draw_motoring(plant, params, rng):
    """A state where the motors drive the load and accelerate the drive (power flows motor -> load).

    At rest under a random load (springs in equilibrium), every body moving with the motor shaft, the
    current well above what the load needs.  The structure's two forms resolve the gearbox efficiency
    alike there; where the load drives the gearbox while the drive decelerates, the discrete map bounds
    the kinetic efficiency loss by its static value (a difference of the two schemes, not of an effect).
    """
    _, u = _draw(plant, params, rng, moving=True)
    p = plant.p_vector(params)
    sgn = float(rng.choice([-1.0, 1.0]))
    load = sgn * rng.uniform(0.0, 2e4)  # opposing the motion
    x = np.asarray(plant.init(0.0, load, p)).ravel()
    w = sgn * rng.uniform(20.0, 300.0)
    r, kt = plant.kinematic_ratio(p), plant.torque_constant(p)
    for name, value in (("motor_speed", w), ("rotor_speed", w), ("surface_speed", r * w),
                        ("motor_current", sgn * (3.0 * abs(load) * r / (0.8 * kt) + 2.0)),
                        ("standby_current", sgn * rng.uniform(0.0, 2.0))):
        if name in plant.state_names:
            x[plant.index("state", name)] = value
    u[plant.index("input", "enable_standby")] = 1.0
    u[plant.index("input", "load_force")] = load
    return x, u


@pytest.mark.parametrize("name", NAMES)
def test_f_and_step_agree_at_a_small_step(params, name, rng):
    plant = build_plant(None, _with_requirements(name), params=params)
    p = plant.p_vector(params)
    h = 1e-10
    # custom states have their own discrete update (a clearance stopped at its face): not a rate
    smooth = [i for i, s in enumerate(plant.states) if s.kind != "custom"]
    for _ in range(6):
        x, u = _draw_motoring(plant, params, rng)
        xdot = np.asarray(plant.f(x, u, p)[0]).ravel()
        x_next = np.asarray(plant.step(x, u, p, h)[0]).ravel()
        fd = (x_next - x) / h
        # first-order agreement: a semi-implicit step uses rates anywhere over the step (their change
        # over it bounds the difference); the difference quotient carries a round-off of ~eps |x| / h
        drift = np.abs(np.asarray(plant.f(x_next, u, p)[0]).ravel() - xdot)[smooth]
        tol = 1e-5 * np.abs(xdot[smooth]) + 1e-6 + 1e-7 * np.abs(x[smooth]) + 2.0 * drift
        bad = np.abs(fd[smooth] - xdot[smooth]) > tol
        assert not bad.any(), (name, [(plant.states[smooth[k]].name, fd[smooth][k], xdot[smooth][k])
                                      for k in np.flatnonzero(bad)])
