"""Identification: truth recovery on virtual-rig data, honest intervals, flags, errors.

Truth runs come from the virtual rig with a cascade sampled at 1 kHz and recorded at 1 kHz: the
identification's current-driven map then *is* the truth's discrete plant (the current state at the
start of each control period is what the rig records), so the only error left is the sensor noise and
the reported intervals can be checked against the truth exactly.  (Recorded at 1 kHz from a 10 kHz
cascade, the current between samples is unknown: that bias is measured in bench/bench_identify.py.)
"""

from __future__ import annotations

import dataclasses
import math
import os
from pathlib import Path

import numpy as np
import pytest

import json

from thsa_control.cli import main
from thsa_control.model import build_plant
from thsa_control.fit.replay import replay_closed_loop
from thsa_control.errors import ParameterError, RigDataError
from thsa_control.fit.identify import IdentificationSettings, Identifier
from thsa_control.model.params import default_parameters, load_parameters
from thsa_control.data.rigdata import read_run
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs

from handcalc import example_disk_law

ROOT = Path(__file__).resolve().parents[1]


def shared_example() -> Path | None:
    base = Path(os.environ["THSA_SHARED_DIR"]) if os.environ.get("THSA_SHARED_DIR") else ROOT / "tests" / "data"
    path = base / "rig-data" / "examples" / "excitation_tensile_12kN.csv"
    return path if path.exists() else None

#: Sensor noise of the truth runs (the shared example's speed and position sensors).
NOISE = {"motor_speed_rpm": 2.0, "nut_position_mm": 0.005}
SETTINGS = IdentificationSettings(channels=("motor_speed", "nut_position"))
FREE = {
    "A": ("motor.rotor_inertia", "gear.viscous_friction", "screw.efficiency_direct", "screw.efficiency_inverse"),
    # the excitation's 12 kN compression exceeds twice the 3 kN preload: the light (tensile-side) disk set is
    # unloaded, so mu_coulomb_pos acts nowhere in these runs and is not free; under the
    # constant load the aided current is mu |F| / N - |F| r eta_i: mu_coulomb_neg and the inverse
    # efficiency are collinear, so only the first is free
    "B": ("motor.rotor_inertia", "screw.efficiency_direct", "noback.mu_coulomb_neg"),
}
#: A second actuator, every free parameter moved from the default by 5-20 %.
OTHER = {"screw.efficiency_direct": 0.85, "screw.efficiency_inverse": 0.80, "gear.viscous_friction": 1.2e-4,
         "noback.mu_coulomb_pos": 0.0055, "noback.mu_coulomb_neg": 0.0038, "motor.rotor_inertia": 2.2e-4}


@pytest.fixture(scope="module")
def record(tmp_path_factory, rig_1khz):
    """``record(level, truth, seed, duration)`` -> RigRun, memoised."""
    d = tmp_path_factory.mktemp("ident")
    cache = {}

    def _record(level, truth, seed=1, duration=4.0):
        key = (level, id(truth), seed, duration)
        if key not in cache:
            u = excitation_inputs(duration, bipolar=True, load=12e3, control_period=1e-3, seed=seed)
            stem = d / f"{level}_{len(cache)}"
            VirtualRig(level, params=truth, design=rig_1khz, noise=NOISE, sample_rate_hz=1000.0, seed=seed).record(u, stem)
            cache[key] = read_run(stem.with_suffix(".csv"))
        return cache[key]

    return _record


def _start(truth, free):
    """Initial values: 15 % above the truth, efficiencies 5 % below."""
    return truth.replace({n: truth.value(n) * (0.95 if "efficiency" in n else 1.15) for n in free})


@pytest.mark.slow
@pytest.mark.parametrize("level", ["A", "B"])
@pytest.mark.parametrize("which", ["default", "other"])
def test_recovers_truth_within_intervals(record, params, level, which):
    """Every free parameter within its 99 % interval (|error| < 2.58 stderr), with stderr small enough for
    the check to mean something (< 3 % of the value), and the fit moved every parameter."""
    truth = params if which == "default" else params.replace({n: v for n, v in OTHER.items() if n in params})
    free = FREE[level]
    res = Identifier(level, _start(truth, free), free, settings=SETTINGS).fit(record(level, truth))
    assert res.success
    for n in free:
        e = res.estimates[n]
        lo, hi = e.interval(0.99)
        # floor: the replay holds the sampled current over each 1 ms sample while the rig's current moves
        # within it; the gearbox loss follows the motor torque (power flow at the gearbox), so at level B
        # (reversals against the no-back) that leaves a 1e-4 relative bias, below any physical meaning
        floor = 2e-4 * abs(truth.value(n))
        assert lo - floor <= truth.value(n) <= hi + floor, (n, e.value, truth.value(n), e.stderr)
        assert e.relative_stderr < 0.03, (n, e.relative_stderr)
        assert not e.at_initial and e.at_bound is None
    # noise-only residual: the channel RMS is the sensor noise (2 rpm, 5 um) within 5 %
    noise = res.noise[res.runs[0]]
    assert abs(noise["motor_speed"] / (2.0 * 2 * math.pi / 60) - 1) < 0.05
    assert abs(noise["nut_position"] / 5e-6 - 1) < 0.05
    fit = res.channel_fits[res.runs[0]]
    assert fit["motor_speed"].fit_percent > res.initial_channel_fits[res.runs[0]]["motor_speed"].fit_percent


@pytest.mark.slow
def test_interval_coverage(record, params):
    """Over 8 noise seeds x 4 parameters of level A, the 95 % intervals hold the truth at least 26 times in 32
    (binomial: a true coverage of 95 % gives fewer than 26 with probability 0.3 %; a stderr
    underestimated by 2x would give about 20).  The residual is the sensor noise, so the segment-clustered standard
    error (stderr_segments) is the information's on average: the mean ratio over the 32 estimates within 0.6 .. 1.4
    (measured 0.56 .. 1.33 for single estimates on seeds 10-13; on rig-sim records with a model mismatch it is
    several times it, 21 for a drive-train damping pulled by stops)."""
    free = FREE["A"]
    hits, ratios = 0, []
    for seed in range(10, 18):
        res = Identifier("A", _start(params, free), free, settings=SETTINGS).fit(record("A", params, seed, 3.0))
        for n in free:
            lo, hi = res.estimates[n].interval(0.95)
            hits += lo <= params.value(n) <= hi
            ratios.append(res.estimates[n].stderr_segments / res.estimates[n].stderr)
    assert hits >= 26, hits
    assert 0.6 < np.mean(ratios) < 1.4, ratios
    # the report flags an estimate the segments spread more than twice, and only such a one
    import dataclasses
    from types import MappingProxyType

    assert ("OVER THE SEGMENTS" in res.fit_report()) == any(r > 2 for r in ratios[-len(free):])
    e = res.estimates[free[0]]
    wide = dataclasses.replace(res, estimates=MappingProxyType(
        {**res.estimates, free[0]: dataclasses.replace(e, stderr_segments=3.0 * e.stderr)}))
    assert f"+/- {3.0 * e.stderr:.4g} OVER THE SEGMENTS (3 x)" in wide.fit_report()


@pytest.mark.slow
def test_intervals_shrink_as_data_grows(record, params):
    """Two runs (multi-experiment) against one: every stderr falls, by about 1/sqrt(2) (0.55..0.85)."""
    free = FREE["A"]
    one = Identifier("A", _start(params, free), free, settings=SETTINGS).fit(record("A", params, 1, 2.0))
    two = Identifier("A", _start(params, free), free, settings=SETTINGS).fit([record("A", params, 1, 2.0),
                                                                              record("A", params, 2, 2.0)])
    assert two.runs == (one.runs[0], two.runs[1]) and two.n_data > 1.9 * one.n_data
    for n in free:
        ratio = two.estimates[n].stderr / one.estimates[n].stderr
        assert 0.55 < ratio < 0.85, (n, ratio)


@pytest.mark.slow
def test_inseparable_parameters_are_flagged(record, params):
    """Motor-bearing and gear viscous friction act on the same speed: only their sum is seen.  The pair is
    flagged (|rho| > 0.95), its stderr is undetermined, and the sum is recovered (within 3 %)."""
    pair = ("motor.bearing_viscous_friction", "gear.viscous_friction")
    res = Identifier("A", params, pair, settings=SETTINGS).fit(record("A", params, 1, 2.0))
    assert set(res.not_identifiable) == set(pair)
    (a, b, rho), = res.high_correlations
    assert {a, b} == set(pair) and abs(rho) > 0.95
    total = sum(res.values.values())
    truth = sum(params.value(n) for n in pair)
    assert abs(total / truth - 1) < 0.03
    assert "NOT IDENTIFIABLE" in res.fit_report()


def test_data_stderr_leaves_out_the_regularising_priors(record, params):
    """Motor-bearing and gear viscous friction act on (almost) the same speed: only their sum is seen well.  A
    regularising prior (prior_relative_sd) on the gear's lends the bearing's a small posterior stderr; the runs'
    own information (``stderr_data``) cannot tell it from zero.  An explicit prior (external knowledge,
    ``priors``) counts as information."""
    pair = ("motor.bearing_viscous_friction", "gear.viscous_friction")
    run = record("A", params, 1, 2.0)
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), prior_relative_sd=0.05,
                               no_prior=pair[:1])
    e = Identifier("A", params, pair, settings=s).fit(run).estimates[pair[0]]
    assert e.stderr < 0.5 * abs(e.value), e  # "determined" through the other's prior
    assert e.stderr_data > 2 * abs(e.value) and e.stderr_data > 4 * e.stderr, e  # not by the run
    g = params.value(pair[1])
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), priors={pair[1]: (g, 0.1 * g)})
    e = Identifier("A", params, pair, settings=s).fit(run).estimates[pair[0]]
    assert math.isfinite(e.stderr) and e.stderr_data == pytest.approx(e.stderr, rel=1e-9), e


def test_saved_parameters_load_into_the_models(record, params, tmp_path):
    free = ("gear.viscous_friction", "screw.efficiency_direct")
    res = Identifier("A", _start(params, free), free, settings=SETTINGS).fit(record("A", params, 1, 2.0))
    path = res.save_parameters(tmp_path / "identified.toml")
    loaded = load_parameters(path, base=default_parameters())
    for n in free:
        assert loaded.value(n) == pytest.approx(res.estimates[n].value, rel=1e-9)
        assert loaded[n].source.startswith("identified:")
    assert loaded.value("motor.resistance") == params.value("motor.resistance")
    d = res.to_dict()
    assert set(d["parameters"]) == set(free) and d["n_free"] == 2


@pytest.mark.slow
def test_global_stage_finds_a_far_start(record, params):
    """Starting 3x off, differential evolution then the local fit land on the truth (within 99 % intervals)."""
    free = ("gear.viscous_friction", "screw.efficiency_inverse")
    start = params.replace({"gear.viscous_friction": 3 * params.value("gear.viscous_friction"),
                            "screw.efficiency_inverse": 0.4})
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), global_stage=True, global_maxiter=8,
                               global_popsize=6, global_span=5.0, seed=3)
    res = Identifier("A", start, free, settings=s).fit(record("A", params, 1, 2.0))
    assert res.global_stage["nfev"] > 0
    for n in free:
        lo, hi = res.estimates[n].interval(0.99)
        assert lo <= params.value(n) <= hi


@pytest.mark.parametrize("free, message", [
    ((), "no free parameters"),
    (("motor.magic",), "parameter 'motor.magic'"),
    (("noback.preload",), "not used by the model"),
])
def test_bad_free_parameters_are_named(record, params, free, message):
    with pytest.raises(ParameterError, match=message):
        Identifier("A", params, free).fit(record("A", params, 1, 2.0))


def test_evaluation_limit_returns_the_best_point_flagged(record, params):
    """Issue #7 item 5: the limit writes the best result so far, flagged as not converged, instead of nothing."""
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), max_nfev=2)
    calls = []
    res = Identifier("A", _start(params, FREE["A"]), FREE["A"], settings=s).fit(
        record("A", params, 1, 2.0), progress=lambda n, c, t: calls.append((n, c)))
    assert not res.converged and not res.success and "status 0" in res.status
    assert "NOT CONVERGED" in res.fit_report() and res.to_dict()["converged"] is False
    assert calls and calls[-1][1] <= calls[0][1]  # the progress reports the best cost, never rising
    # the best point is no worse than the start
    assert res.chisqr <= Identifier("A", _start(params, FREE["A"]), FREE["A"], settings=IdentificationSettings(
        channels=("motor_speed", "nut_position"), max_nfev=0)).fit(record("A", params, 1, 2.0)).chisqr * (1 + 1e-9)


def test_time_budget_returns_the_best_point_flagged(record, params):
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), time_budget=1e-3)
    res = Identifier("A", _start(params, FREE["A"]), FREE["A"], settings=s).fit(record("A", params, 1, 2.0))
    assert not res.converged and "time budget" in res.status
    assert all(math.isfinite(e.value) for e in res.estimates.values())


def test_prior_pulls_towards_the_parameter_file_and_is_reported(record, params):
    """The prior is centred on the parameter file's value: a tight one holds it, a loose one lets the data move it."""
    free = ("gear.viscous_friction", "screw.efficiency_inverse")
    start = params.replace({"screw.efficiency_inverse": 0.6})
    run = record("A", params, 1, 2.0)
    est = {}
    for sd in (1e-7, None):
        s = IdentificationSettings(channels=("motor_speed", "nut_position"), prior_relative_sd=sd)
        res = Identifier("A", start, free, settings=s).fit(run)
        est[sd] = res.values["screw.efficiency_inverse"]
        if sd is not None:
            assert set(res.priors) == set(free)
            assert res.priors["screw.efficiency_inverse"] == pytest.approx((0.6, 0.6e-7))
            assert "priors" in res.fit_report()
    assert abs(est[1e-7] - 0.6) < 1e-3  # held at the documented value
    assert abs(est[None] - 0.85) < 0.03  # the data alone find the truth


def test_holdout_segments_are_scored_apart(record, params):
    run = record("A", params, 1, 2.0)
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), holdout_every=3)
    res = Identifier("A", _start(params, FREE["A"]), FREE["A"], settings=s).fit(run)
    hold = res.holdout_fits[run.name]["motor_speed"]
    fit = res.channel_fits[run.name]["motor_speed"]
    assert hold.n > 0 and fit.n > 0 and hold.n + fit.n == len(run.time)
    # the right model generalises: held-out error of the order of the fitted one
    assert hold.rms < 2.0 * fit.rms


def test_refit_starts_where_the_earlier_fit_left_its_segments(record, params):
    """A refit of a fit's model (every segment, the held-out ones too) starts from that fit's segment states
    (``initial_states``): there its error is the earlier fit's optimum, below the error at the measured states, and a
    fit from there only descends.  A length that does not match the run's segment layout is named."""
    run = record("A", params, 1, 2.0)
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), holdout_every=3)
    first = Identifier("A", _start(params, FREE["A"]), FREE["A"], settings=s).fit(run)
    states = first.segment_states[run.name]
    assert states.ndim == 1 and states.size > 0 and np.all(np.isfinite(states))
    at = first.to_parameter_set()
    every = dataclasses.replace(s, holdout_every=0)
    still = dataclasses.replace(every, max_nfev=0)  # statistics at the start
    warm = Identifier("A", at, FREE["A"], settings=still).fit(run, initial_states=first.segment_states)
    cold = Identifier("A", at, FREE["A"], settings=still).fit(run)
    assert warm.chisqr < 0.95 * cold.chisqr, (warm.chisqr, cold.chisqr)  # measured 3819 against 4396
    assert np.array_equal(warm.segment_states[run.name], states)  # nothing moved them
    refit = Identifier("A", at, FREE["A"], settings=every).fit(run, initial_states=first.segment_states)
    assert refit.chisqr <= warm.chisqr * (1 + 1e-9)
    with pytest.raises(ValueError, match=f"initial_states\\['{run.name}'\\]: 3 values"):
        Identifier("A", at, FREE["A"], settings=still).fit(run, initial_states={run.name: np.ones(3)})


def test_no_measured_channel_is_named(record, params, tmp_path):
    """A run with the screw speed only (FORMAT.md allows it) cannot be fitted on motor speed and position."""
    src = record("A", params, 1, 2.0)
    lines = src.csv_path.read_text().splitlines()
    header = lines[0].split(",")
    keep = [i for i, c in enumerate(header) if c not in ("motor_speed_rpm", "nut_position_mm")]
    (tmp_path / "r.csv").write_text("\n".join(",".join(line.split(",")[i] for i in keep) for line in lines) + "\n")
    (tmp_path / "r.json").write_text(src.json_path.read_text())
    run = read_run(tmp_path / "r.csv")
    with pytest.raises(RigDataError, match="no fitted channel"):
        Identifier("A", params, ("gear.viscous_friction",), settings=SETTINGS).fit(run)


@pytest.mark.slow
def test_shared_example_fit_improves(params):
    """Independent simulator, level B + sensor noise (current noise too): identifying the no-back's aiding
    friction and the screw's inverse efficiency at level B improves the speed fit of the segments.  The start is
    the example's own disk law (preload + |F| on the slipping disk, handcalc.example_disk_law): from level B's
    flange balance (|F| alone at 12 kN) the Coulomb coefficient alone cannot scale the Stribeck hump the
    simulator carries (speed RMS 164 -> 15 rad/s, against 62 -> 1.2 from its own law)."""
    path = shared_example()
    if path is None:
        pytest.skip("shared/rig-data/examples/excitation_tensile_12kN.csv not found (set THSA_SHARED_DIR)")
    run = read_run(path)
    start = example_disk_law(params, 12e3)
    free = ("gear.viscous_friction", "noback.mu_coulomb_pos", "screw.efficiency_inverse")
    s = IdentificationSettings(substeps=4, channels=("motor_speed", "nut_position"), tolerance=1e-6)
    res = Identifier("B", start, free, settings=s).fit(run)
    before = res.initial_channel_fits[run.name]["motor_speed"]
    after = res.channel_fits[run.name]["motor_speed"]
    assert res.success and after.rms < 0.1 * before.rms
    # one operating point (3 +- 1 mm/s, one load): viscous drag, no-back Coulomb friction and inverse
    # efficiency all scale the same aiding torque, and the result says so
    assert len(res.high_correlations) >= 2
    # the closed-loop replay (the rig's controller, not fitted) explains the current better afterwards:
    # measured 84.5 % -> 95.4 % (the same from the example's disk law as from the file's before the flange balance)
    b = replay_closed_loop(run, build_plant("B"), start)
    a = replay_closed_loop(run, build_plant("B"), res.to_parameter_set())
    assert a.fits["motor_current"].fit_percent > b.fits["motor_current"].fit_percent + 10


@pytest.mark.slow
def test_cli_identify_and_residual(record, params, tmp_path, capsys):
    """`thsa identify` writes result.json, parameters.toml and report.html; `thsa residual` its JSON and HTML;
    an unknown --free name exits 2, names it and writes nothing."""
    run = record("A", params, 1, 2.0)
    out = tmp_path / "id"
    assert main(["identify", str(run.csv_path), "--model", "A", "--free", "gear.viscous_friction",
                 "--out", str(out)]) == 0
    doc = json.loads((out / "result.json").read_text())
    assert doc["parameters"]["gear.viscous_friction"]["stderr"] > 0
    assert doc["runs"] == [run.name] and run.name in doc["replays"]
    assert load_parameters(out / "parameters.toml", base=default_parameters())
    assert (out / "report.html").read_text().count("data:image/png;base64") >= 3
    res_out = tmp_path / "res"
    assert main(["residual", str(run.csv_path), "--model", "A", "--mode", "open_loop", "--out", str(res_out)]) == 0
    assert "motor_speed" in json.loads((res_out / "residuals.json").read_text())["residuals"]
    bad = tmp_path / "bad"
    capsys.readouterr()
    assert main(["identify", str(run.csv_path), "--model", "A", "--free", "gear.magic", "--out", str(bad)]) == 2
    assert "gear.magic" in capsys.readouterr().err and not bad.exists()
    assert main(["residual", str(tmp_path / "none.csv"), "--model", "A", "--out", str(bad)]) == 2
    assert not bad.exists()


def test_state_only_jacobian_is_the_full_jacobians_state_columns(record, params):
    """The Jacobian by the segment states alone (the "before" and held-out state fits) is the full Jacobian's
    state columns, value for value, and the buffered residuals are casadi's."""
    import numpy as np

    from thsa_control.fit.replay import current_driven_map
    from thsa_control.fit.shooting import RunProblem

    run = record("A", params, 1, 2.0)
    free = FREE["A"]
    plant = build_plant("A", params=params)
    s = IdentificationSettings(channels=("motor_speed", "nut_position"), holdout_every=3)
    pb = RunProblem(run, plant, current_driven_map(plant), params, free, s)
    nf = len(free)
    rng = np.random.default_rng(0)
    z = np.r_[0.05 * rng.standard_normal(nf), pb.initial_decision()]
    p0, scale, sig = plant.p_vector(params), np.ones(nf), pb.sigma0
    full = pb.jacobian(z, p0, scale, sig)
    states = pb.jacobian(z, p0, scale, sig, states_only=True)
    assert full.shape == (states.shape[0], nf + states.shape[1]) and states.nnz > 0
    np.testing.assert_array_equal(states.toarray(), full[:, nf:].toarray())
    np.testing.assert_array_equal(pb.residuals(z, p0, scale, sig), np.asarray(pb.f_res(z, p0, scale, sig)).ravel())
    np.testing.assert_array_equal(full.toarray(), np.asarray(pb.f_jac(z, p0, scale, sig)[1].full()))
