"""A declared parameter defined at a reference condition the runs never reach is not determined by them (issue #21).

``gear.viscous_friction`` is the 25 degC drag (``temperature_friction`` reads it as ``b_25``).  A record that moves
only far from 25 degC measures the drag at its own temperature; fitted there, the 25 degC coefficient took what the
temperature effect explains (rig-sim's cold ramp at -30 degC: 7.4e-4 N m s/rad against the file's 8e-5, leaving
the temperature candidate 17 % of its window).  The tracer holds it at its file value and says so.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.errors import ParameterError
from thsa_control.fit.identify import IdentificationSettings, Identifier
from thsa_control.fit.kinematics import run_kinematics
from thsa_control.trace.candidates import (
    CANDIDATES,
    MIN_WINDOW_SAMPLES,
    _window,
    reference_not_determined,
)

DATA = Path(__file__).resolve().parent / "data" / "rigsim"
VISC = "gear.viscous_friction"


@pytest.fixture(scope="module")
def runs(params):
    return {n: run_kinematics(read_run(DATA / f"{n}.csv"), params)
            for n in ("rig_temp_friction", "null_rig_cold_s52", "null_rig_trim_s1")}


def _at(run, temperature):
    """The same record with its housing temperature read as ``temperature`` [degC] throughout."""
    return dataclasses.replace(run, name=f"{run.name}_at_{temperature:g}",
                               signals={**run.signals, "temperature": np.full(run.time.size, float(temperature))})


def test_the_temperature_effect_declares_its_reference_drag():
    assert CANDIDATES["temperature_friction"].reference == (VISC,)
    assert CANDIDATES["temperature_friction"].window == "cold"


def test_a_cold_only_record_does_not_determine_the_25C_drag(runs, params):
    for name in ("rig_temp_friction", "null_rig_cold_s52"):  # rig-sim's cold ramp at -30 degC, planted and null
        held = reference_not_determined([runs[name]], params, (VISC,))
        assert list(held) == [VISC] and "0 samples" in held[VISC], held
    warm = runs["null_rig_trim_s1"]
    assert reference_not_determined([warm], params, (VISC,)) == {}
    # the same motion: only the temperature decides
    assert list(reference_not_determined([_at(warm, -30.0)], params, (VISC,))) == [VISC]
    assert reference_not_determined([_at(warm, 22.0)], params, (VISC,)) == {}  # within 5 K of 25 degC
    assert list(reference_not_determined([_at(warm, 35.0)], params, (VISC,))) == [VISC]  # hot: outside too
    # a warm record traced with the cold one determines it; a parameter not asked for is not judged
    assert reference_not_determined([runs["rig_temp_friction"], warm], params, (VISC,)) == {}
    assert reference_not_determined([runs["rig_temp_friction"]], params, ("noback.mu_coulomb_pos",)) == {}


def test_the_rule_counts_moving_samples_at_the_reference_temperature(runs, params):
    """Fewer than MIN_WINDOW_SAMPLES moving samples within 5 K of 25 degC: not determined; that many: determined."""
    warm = runs["null_rig_trim_s1"]
    moving = np.flatnonzero(_window("moving", warm, params))
    for n_warm, held in ((MIN_WINDOW_SAMPLES - 1, True), (MIN_WINDOW_SAMPLES, False)):
        temp = np.full(warm.time.size, -30.0)
        temp[moving[:n_warm]] = 25.0
        run = dataclasses.replace(warm, signals={**warm.signals, "temperature": temp})
        assert (VISC in reference_not_determined([run], params, (VISC,))) is held


def test_identifier_fits_the_segment_states_only_when_asked(runs, params):
    """No parameter free: an error unless ``states_only`` (then the model's own segment predictions)."""
    run = runs["rig_temp_friction"]
    keep = run.time <= 1.6  # the start of the first ramp
    short = dataclasses.replace(run, controller=None, time=run.time[keep],
                                signals={k: np.asarray(v)[keep] for k, v in run.signals.items()})
    st = IdentificationSettings(channels=("motor_speed", "screw_speed"), max_nfev=5)
    with pytest.raises(ParameterError, match="no free parameters"):
        Identifier(None, params, (), effects=("standby_motor", "noback_ideal"), settings=st).fit(short)
    with pytest.raises(ParameterError, match="states_only"):
        Identifier(None, params, (VISC,), effects=("standby_motor", "noback_ideal"), settings=st,
                   states_only=True).fit(short)
    res = Identifier(None, params, (), effects=("standby_motor", "noback_ideal"), settings=st,
                     states_only=True).fit(short)
    assert res.estimates == {} and res.to_parameter_set().value(VISC) == params.value(VISC)
    pred = res.predictions[run.name]
    e = np.asarray(pred["measured"]["motor_speed"]) - np.asarray(pred["simulated"]["motor_speed"])
    assert np.all(np.isfinite(e)) and e.size == short.time.size


def test_only_the_cold_records_of_the_catalogue_hold_it(params):
    """Every committed rig-sim run at 25 degC determines the 25 degC drag (its trace is unchanged by the rule); the
    cold ramps (-30 degC: the temperature-friction run, its null, the worn-spot cold run and its null) do not.  The
    cold records are read from the records' own stated temperature, not listed by name."""
    import json
    held = {p.stem for p in sorted(DATA.glob("*.csv"))
            if reference_not_determined([run_kinematics(read_run(p), params)], params, (VISC,))}
    cold = {p.stem for p in sorted(DATA.glob("*.csv"))
            if abs(json.loads(p.with_suffix(".json").read_text())["temperature_C"] - 25.0) > 5.0}
    assert {"rig_temp_friction", "null_rig_cold_s52"} <= cold
    assert held == cold
