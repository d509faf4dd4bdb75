"""Registering an effect is all it takes: a toy effect defined here is simulated, linearised, identified and traced.

The toy effect (an extra constant drag torque at the motor shaft, with its own
parameter) is declared and registered in this file only; no file of the
package names it.  It then gets the registry's contract (the suite of
``test_effect_registry`` run on it), and it is available to ``simulate``,
``linearize``, ``identify --free`` and ``trace --candidates`` through the
Python API and the command line.  The registration is undone after each test.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import test_effect_registry as suite

from thsa_control.cli import main
from thsa_control.loops.design import load_design, nominal_design_path
from thsa_control.loops.linear import OperatingCondition, operating_points, plant_model
from thsa_control.model import (
    EFFECT_ORDER, EFFECTS, CandidateSpec, Effect, Phase, build_plant, register, resolve_effects, unregister,
)
from thsa_control.model.params import Parameter, default_parameters
from thsa_control.model.structure import FrictionChannel
from thsa_control.sim.scenarios import get_scenario
from thsa_control.sim.simulate import Simulator
from thsa_control.trace import CANDIDATES, candidate_specs

TOY = "toy_constant_drag"
DRAG = "toy.drag_torque"
TRUTH = 0.05  # N m at the motor shaft


def _apply(a) -> None:
    t = a.p[DRAG]
    a.channels.append(FrictionChannel("toy_drag", t, t, t, t))  # against the motion, holds at rest
    a.loss("toy_drag", lambda res: res.channel["toy_drag"] * res.speed)


def _toy_effect() -> Effect:
    return Effect(
        TOY, "a test's toy: a constant drag torque at the motor shaft", (), (DRAG,), (), _apply,
        phase=Phase.DRIVE,
        candidate=CandidateSpec(TOY, (DRAG,), {DRAG: 0.01}, "moving"),
        neutral={DRAG: 0.0},
        parameter_defaults=(Parameter(DRAG, 0.0, "N m", "assumed: a test's toy effect, off by default",
                                      min=0.0, max=0.5),),
    )


@pytest.fixture
def toy():
    eff = register(_toy_effect())
    try:
        yield eff
    finally:
        unregister(TOY)
    assert TOY not in EFFECTS and TOY not in EFFECT_ORDER and TOY not in CANDIDATES
    assert DRAG not in default_parameters()


@pytest.fixture
def drag_file(tmp_path):
    """A parameter file that switches the toy on (over the embedded actuator)."""
    path = tmp_path / "toy.toml"
    path.write_text(f"[toy]\ndrag_torque = {TRUTH}\n", encoding="utf-8")
    return path


def test_registration_is_undone_and_unknown_before():
    assert TOY not in EFFECTS
    with pytest.raises(Exception, match="unknown effect"):
        resolve_effects("A", add=[TOY])


def test_default_parameters_follow_the_registry():
    """default_parameters() is parsed once per state of the registry (the same immutable set until it changes):
    registering the toy adds its parameter, registering it again gives a new set, unregistering removes it."""
    before = default_parameters()
    assert default_parameters() is before and DRAG not in before
    register(_toy_effect())
    try:
        with_toy = default_parameters()
        assert DRAG in with_toy and with_toy.value(DRAG) == 0.0 and with_toy is default_parameters()
        assert with_toy.names[:len(before)] == before.names
        register(_toy_effect(), replace=True)  # a new definition under the same name
        again = default_parameters()
        assert again is not with_toy and DRAG in again
    finally:
        unregister(TOY)
    after = default_parameters()
    assert DRAG not in after and after.names == before.names


def test_a_registered_effect_gets_the_whole_contract(toy, rng):
    params = default_parameters()
    assert params.value(DRAG) == 0.0 and TOY in EFFECT_ORDER
    assert EFFECT_ORDER.index(TOY) < EFFECT_ORDER.index("noback_quadrant_friction")  # its phase places it
    suite.test_effect_declares_its_contract(TOY)
    suite.test_every_effect_set_has_the_same_outputs(params, TOY)
    suite.test_at_neutral_parameters_the_effect_is_the_base(params, TOY, rng)
    suite.test_power_balance_closes(params.replace({DRAG: TRUTH}), TOY, rng)
    suite.test_f_and_step_agree_at_a_small_step(params.replace({DRAG: TRUTH}), TOY, rng)


def test_toy_is_simulated(toy, tmp_path, drag_file):
    params = default_parameters().replace({DRAG: TRUTH})
    design = load_design(nominal_design_path())
    scenario = get_scenario("unipolar_speed_bipolar_load")
    with_toy = Simulator(build_plant("B", [TOY], params=params)).run(scenario, design, params)
    without = Simulator(build_plant("B", params=params)).run(scenario, design, params)
    # the drag shows in the current the motor needs while the speed holds (about T / (Kt eta_g))
    kt = build_plant("B", params=params).torque_constant(params)
    w = np.asarray(without["motor_speed"])
    moving = np.abs(w) > 0.5 * np.max(np.abs(w))
    extra = np.median(np.abs(np.asarray(with_toy["motor_current"])[moving])
                      - np.abs(np.asarray(without["motor_current"])[moving]))
    expect = TRUTH / kt
    assert expect * 0.8 < extra < expect / params.value("gear.efficiency") * 1.2, (extra, expect)
    out = tmp_path / "sim"
    assert main(["simulate", "--scenario", "unipolar_speed_bipolar_load", "--level", "B", "--effects", TOY,
                 "--params", str(drag_file), "--out", str(out)]) == 0
    assert any(out.iterdir())


def test_toy_is_linearised(toy, drag_file, capsys):
    params = default_parameters().replace({DRAG: TRUTH})
    cond = OperatingCondition(0.005, 0.0, 25.0)
    cur = {}
    for effects in ((TOY,), ()):
        model = plant_model("B", effects, params)
        ops = operating_points(model, cond)
        cur[effects] = float(ops.X[list(ops.states).index("motor_current"), 0])
    kt = build_plant("B", params=params).torque_constant(params)
    # the steady current carries the drag through the gearbox: T / (Kt eta_g) more
    assert cur[(TOY,)] - cur[()] == pytest.approx(TRUTH / kt / params.value("gear.efficiency"), rel=0.05)
    assert main(["linearize", "--level", "B", "--speed", "5", "--load", "0", "--effects", TOY,
                 "--params", str(drag_file)]) == 0
    assert TOY in capsys.readouterr().out


def test_toy_is_a_tracer_candidate(toy):
    params = default_parameters()
    assert CANDIDATES[TOY].free == (DRAG,)
    assert TOY in [s.name for s in candidate_specs(("noback_ideal",), params)]  # offered by default


@pytest.fixture
def toy_run(toy, tmp_path, rig_1khz):
    from handcalc import RIG_NOISE

    from thsa_control.data.rigdata import read_run
    from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs

    truth = default_parameters().replace({DRAG: TRUTH})
    u = excitation_inputs(2.0, bipolar=True, load=0.0, control_period=1e-3, seed=3, temperature=25.0)
    stem = tmp_path / "toy_run"
    VirtualRig("A", effects=(TOY,), params=truth, design=rig_1khz, noise=RIG_NOISE, seed=3).record(u, stem)
    return read_run(stem.with_suffix(".csv"))


@pytest.mark.slow
def test_toy_is_identified_and_traced_from_the_command_line(toy_run, tmp_path):
    out = tmp_path / "id"
    assert main(["identify", str(toy_run.csv_path), "--model", "A", "--effects", TOY, "--free", DRAG,
                 "--max-nfev", "40", "--out", str(out)]) == 0
    est = json.loads((out / "result.json").read_text())["parameters"][DRAG]
    assert est["value"] == pytest.approx(TRUTH, rel=0.1) and math.isfinite(est["stderr"])
    tr = tmp_path / "tr"
    assert main(["trace", str(toy_run.csv_path), "--model", "A", "--candidates", TOY, "--workers", "1",
                 "--max-nfev", "30", "--quiet", "--out", str(tr)]) == 0
    doc = json.loads((tr / "trace.json").read_text())
    assert [e["name"] for e in doc["effects_added"]] == [TOY], doc["rounds"]


def test_registration_refuses_an_effect_without_its_declarations():
    import dataclasses

    for missing in ({"candidate": None}, {"neutral": None}):
        with pytest.raises(ValueError, match="declare"):
            register(dataclasses.replace(_toy_effect(), **missing))
    assert TOY not in EFFECTS
    with pytest.raises(ValueError, match="already registered"):
        register(dataclasses.replace(_toy_effect(), name="coulomb_friction",
                                     candidate=CandidateSpec("coulomb_friction", (DRAG,))))


def test_the_contract_catches_a_broken_effect(rng):
    """The registry suite is not a formality: a drag that forgets its loss breaks the power balance, an
    output without a neutral value breaks "same outputs for every set", a wrong neutral value is seen."""
    import dataclasses

    def no_loss(a):
        t = a.p[DRAG]
        a.channels.append(FrictionChannel("toy_drag", t, t, t, t))

    def undeclared_output(a):
        _apply(a)
        a.output("toy_torque", "N m", a.p[DRAG])

    cases = ((no_loss, {DRAG: 0.0}, suite.test_power_balance_closes),
             (undeclared_output, {DRAG: 0.0}, lambda p, n, r: suite.test_every_effect_set_has_the_same_outputs(p, n)),
             (_apply, {DRAG: 0.01}, suite.test_at_neutral_parameters_the_effect_is_the_base))
    for apply, neutral, check in cases:
        register(dataclasses.replace(_toy_effect(), apply=apply, neutral=neutral))
        try:
            params = default_parameters().replace({DRAG: TRUTH})
            with pytest.raises(AssertionError):
                check(params, TOY, rng)
        finally:
            unregister(TOY)
