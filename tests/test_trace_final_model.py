"""The final model a trace reports (issue #21 review): ``trace.json``'s ``final_parameters`` with ``final_effects``
rebuild the model whose errors are ``error_after``; the declared uncertain set's fit before the base step (which
absorbs the base's drags into the viscous drag) is kept under a name that says so."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from handcalc import RIG_NOISE

from thsa_control.data.rigdata import read_run
from thsa_control.fit.identify import IdentificationSettings
from thsa_control.fit.virtual_rig import VirtualRig, excitation_inputs
from thsa_control.report.trace import conclusion_table_html
from thsa_control.trace import TraceSettings, trace
from thsa_control.trace.engine import final_model
from thsa_control.trace.scoring import _channel_errors, _fit_job


@pytest.fixture(scope="module")
def traced(tmp_path_factory, rig_1khz, params):
    """The virtual rig (level A) with a Coulomb drag of 0.03 N m (inside the base correction's plausible bound) under
    a load swinging +12 -> -12 -> +12 kN, traced with the base step: the declared fit alone reads the drag as viscous
    drag, the base step's Coulomb correction carries it."""
    duration, load = 3.0, 12e3
    u = excitation_inputs(duration, bipolar=True, load=load, control_period=1e-3, seed=3)
    sig = dict(u.signals)
    sig["load_force"] = np.interp(u.time, [0, duration / 2, duration], [load, -load, load])
    u = dataclasses.replace(u, signals=sig)
    stem = tmp_path_factory.mktemp("final") / "coulomb"
    VirtualRig("A", effects=("coulomb_friction",), params=params.replace({"drive.coulomb_torque": 0.03}),
               design=rig_1khz, noise=RIG_NOISE, seed=3).record(u, stem)
    run = read_run(stem.with_suffix(".csv"))
    st = TraceSettings(candidates=("force_offset",), base_corrections=True, max_effects=1, max_nfev=30, workers=1)
    return run, st, trace(run, "A", params=params, settings=st).to_dict()


def _replay_errors(run, st, doc, effects, pset):
    """The channel errors of a model replayed as the trace replays it: the same segments, channel weights and
    quasi-static starts, only the segment start states fitted."""
    chans = tuple(doc["channel_weights"]["rms"])
    ids = IdentificationSettings(segment_duration=st.segment_duration, substeps=st.substeps, channels=chans,
                                 noise=dict(doc["channel_weights"]["rms"]), max_nfev=st.max_nfev,
                                 tolerance=st.tolerance, holdout_every=st.holdout_every, quasi_static_starts=True)
    f = _fit_job({"label": "rebuilt", "effects": tuple(effects), "free": (), "params_toml": pset.to_toml(),
                  "settings": ids, "runs": [dataclasses.replace(run, controller=None)]})
    assert "error" not in f, f.get("error")
    return _channel_errors(f)


@pytest.mark.slow
def test_the_final_parameters_rebuild_the_traced_model(traced, params):
    """Rebuilt from ``final_effects`` and ``final_parameters`` over the parameter file, and replayed with only the
    segment states fitted, the model gives the trace's ``error_after`` on every channel to within 1 % (the states are
    refitted: the fit's tolerance).  The pre-base-step values (``declared_fit_before_base_step``) are not the final
    model's: there the viscous drag carried the Coulomb drag, and with the final effects they leave a larger error."""
    run, st, doc = traced
    assert doc["base_corrections"]["accepted"]
    fp = doc["final_parameters"]
    visc = "gear.viscous_friction"
    assert fp[visc]["source"] in ("fitted", "held") and fp[visc]["unit"] == "N m s/rad"
    assert "drive.coulomb_torque" in fp and fp["drive.coulomb_torque"]["value"] == pytest.approx(0.03, abs=0.01)
    before = doc["declared_fit_before_base_step"][visc]["value"]
    assert before > 2 * fp[visc]["value"], (before, fp[visc])  # the drag read as viscous drag before the base step
    effects, pset = final_model(doc, params)
    got = _replay_errors(run, st, doc, effects, pset)
    for c, e in doc["error_after"].items():
        assert got[c]["rms"] == pytest.approx(e["rms"], rel=0.01), (c, got[c], e)
    stale = _replay_errors(run, st, doc, effects, pset.replace({visc: before}))
    assert stale["motor_speed"]["rms"] > 1.5 * doc["error_after"]["motor_speed"]["rms"], stale
    # the report's conclusion table shows the final value, and the pre-base-step one as such
    html = conclusion_table_html(doc)
    assert "declared model (final values)" in html and "before the base step" in html


def test_the_conclusion_table_escapes_the_base_model_once():
    """The conclusion table's first two cells are escaped where the rows are drawn; the held and final-value rows of
    the declared model pass the base model's name as text (it was escaped twice in the held row: '&amp;lt;')."""
    doc = {"base_model": "rig <A&B>", "uncertain_parameters": ["gear.viscous_friction"],
           "declared_not_determined": [{"parameter": "gear.viscous_friction", "held_at": 8e-5, "unit": "N m s/rad",
                                        "reason": "not reached"}],
           "final_parameters": {"gear.viscous_friction": {"value": 8e-5, "unit": "N m s/rad", "stderr": None,
                                                          "source": "held"}},
           "effects_added": [], "effects_removed": [], "unexplained": False, "residual_signature": {}}
    html = conclusion_table_html(doc)
    assert html.count("<td>rig &lt;A&amp;B&gt;</td>") == 2 and "&amp;lt;" not in html, html


def test_an_old_trace_without_final_parameters_is_refused_by_name():
    """A trace.json written before ``final_parameters`` (its ``base_parameters`` were the fit before the base step):
    rebuilding the final model from it names the missing field instead of a bare KeyError."""
    from thsa_control.errors import ThsaError

    old = {"final_effects": ["noback_ideal"], "base_parameters": {"gear.viscous_friction": {"value": 3.6e-4}}}
    with pytest.raises(ThsaError, match="final_parameters"):
        final_model(old)
