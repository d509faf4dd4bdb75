"""Batched simulation (issue #17, item 3): one C call for many runs, one output block, views as results.

Every batched run must carry the bits of the same run simulated alone (whatever the thread count),
the results must be views of one (runs x signals x samples) block, and a bad member must be named
by its index.  The scenario sampling that feeds the batch (constant inputs as zero-stride views)
must give the bits of ``Scenario.inputs``.
"""

from dataclasses import replace

import numpy as np
import pytest

from thsa_control.errors import ScenarioError, ThsaError
from thsa_control.model import build_plant
from thsa_control.sim.scenarios import SCENARIOS, Scenario, get_scenario
from thsa_control.sim.simulate import RUN_INPUTS, InputSeries, Simulator, stack_signals


@pytest.fixture(scope="module")
def sim(params):
    return Simulator(build_plant("A", params=params))


@pytest.fixture(scope="module")
def short():
    return replace(get_scenario("backdrive_bipolar_ramp"), duration=1.6)


def _same(a, b):
    return a.names == b.names and np.asarray(a.time).tobytes() == np.asarray(b.time).tobytes() and all(
        a[n].tobytes() == b[n].tobytes() for n in a.names)


def test_batch_is_bit_identical_to_single_runs_and_views_one_block(sim, short, design, params):
    name = "gear.viscous_friction"
    sets = [params.replace({name: params[name].value * f}) for f in (0.5, 1.0, 3.0)]
    scs = [short, short, short.with_temperature(-40.0)]
    one = sim.run_batch(scs, design, sets, threads=1)
    two = sim.run_batch(scs, design, sets, threads=2)
    assert len(one) == len(two) == 3
    (block, idx), = two.blocks
    n_out = len(two[0].time)
    assert block.shape == (3, len(two[0].names), n_out) and idx == (0, 1, 2)
    assert n_out == round(1.6 / 1e-3)
    for r, (sc, p) in enumerate(zip(scs, sets)):
        alone = sim.run(sc, design, p)
        assert _same(two[r], alone) and _same(one[r], alone)
        assert np.shares_memory(two[r]["motor_current"], block)  # a view, not a copy
        with pytest.raises(ValueError):
            two[r]["motor_current"][0] = 0.0  # read-only
    # the runs differ (no result handed to all), and stack_signals gives the block's numbers
    assert two[0]["motor_current"].tobytes() != two[1]["motor_current"].tobytes()
    assert two[0]["motor_current"].tobytes() != two[2]["motor_current"].tobytes()
    t, Y = stack_signals(two, ["motor_current", "nut_speed"])
    assert Y.shape == (3, 2, n_out) and Y[2, 1].tobytes() == two[2]["nut_speed"].tobytes()


def test_runs_of_different_lengths_go_to_separate_blocks_in_order(sim, short, design, params):
    runs = sim.run_batch([short, replace(short, duration=0.8), short], design, params, threads=2)
    assert [len(r.time) for r in runs] == [1600, 800, 1600]
    assert sorted(idx for _, idx in runs.blocks) == [(0, 2), (1,)]
    assert runs[0].info["batch"] == 2 and runs[1].info["batch"] == 1
    assert _same(runs[1], sim.run(replace(short, duration=0.8), design, params))


def test_bad_member_is_named_by_its_index(sim, short, design, params):
    needs = replace(short, name="needs_standby", required_effects=("standby_motor",))
    with pytest.raises(ScenarioError, match=r"run 2 \('needs_standby'\).*standby_motor"):
        sim.run_batch([short, short, needs], design, params)
    x0 = sim.plant.initial_state(params)
    with pytest.raises(ThsaError, match=r"run 1 \('backdrive_bipolar_ramp'\) diverged \(non-finite signal at t = 0 s\)"):
        sim.run_batch(short, design, params, x0=[x0, np.full_like(x0, np.nan), x0])
    with pytest.raises(ValueError, match="different lengths"):
        sim.run_batch([short, short], design, [params] * 3)


def test_single_run_reports_divergence(sim, short, design, params):
    x0 = sim.plant.initial_state(params)
    with pytest.raises(ThsaError, match="diverged"):
        sim.run(short, design, params, x0=np.full_like(x0, np.nan))


def _bits(a):
    return np.ascontiguousarray(np.asarray(a, dtype=float)).tobytes()


@pytest.mark.parametrize("scenario", [*SCENARIOS.values(),
                                      Scenario("neg_zero_load", "", 1.0, ((0.0, 0.0),), 0.03, ((0.0, -0.0), (0.5, -0.0))),
                                      Scenario("late_step", "", 1.0, ((0.3, 0.01), (0.6, 0.01)), 0.03, ((0.2, 5.0),)),
                                      Scenario("flat_load", "", 1.0, ((0.0, 0.0),), 0.03, ((0.0, 7.0), (0.5, 7.0),
                                                                                          (0.5, 7.0), (0.9, 7.0))),
                                      Scenario("position", "", 1.0, ((0.0, 0.0),), 0.03, ((0.0, 1.0),),
                                               position_cmd=((0.0, 0.0), (0.5, 0.002)))],
                         ids=lambda s: s.name)
def test_sampling_with_constant_views_gives_the_bits_of_scenario_inputs(scenario):
    series = InputSeries.from_scenario(scenario, 1e-4)
    want = scenario.inputs(series.time)
    for name, value in want.items():
        got = series.signals[name]
        assert got.shape == series.time.shape and not got.flags.writeable, name
        assert _bits(got) == _bits(value), (scenario.name, name)
    assert _bits(series.matrix()[RUN_INPUTS.index("current_ff")]) == _bits(np.zeros(len(series.time)))
