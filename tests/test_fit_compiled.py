"""The fits' compiled residual and Jacobian (thsa_control/fit/shooting.py): the same numbers as casadi's interpreter.

The multiple-shooting residual of a run and its exact Jacobian are evaluated by one casadi Function per segment,
of the segment's own data, compiled to C once per model structure (the simulator's verified build cache) and
mapped over the segments.  Without a compiler, or with ``IdentificationSettings.compiled = False``, the same
Functions run in casadi's interpreter.  These tests check that both give the same residuals and Jacobians (to
1e-12 relative, on a committed rig-sim run of the ``rig`` base and a level-D plant that exercises every branch
of the segment start: free speeds and positions, the pawl clearances of the first segment from the parameters,
the quasi-static surface, difference-quotient speed sensors, held-out segments), that a fit and a trace reach
the same result either way, and that a machine without a C compiler fits with the interpreter.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from thsa_control.data.rigdata import read_run
from thsa_control.fit.identify import IdentificationSettings, Identifier
from thsa_control.fit.kinematics import run_kinematics
from thsa_control.fit.replay import current_driven_map
from thsa_control.fit.shooting import RunProblem
from thsa_control.model import build_plant
from thsa_control.model.params import default_parameters

HAVE_CC = shutil.which(os.environ.get("CC", "gcc")) is not None or shutil.which("cc") is not None
RIGSIM = Path(__file__).parent / "data" / "rigsim"
FREE = ("gear.viscous_friction", "noback.pawl_initial_clearance", "screw.efficiency_direct")


def _problems(run_name: str = "rig_ratchet_backlash", level: str = "D", effects=("standby_motor",), free=FREE):
    params = default_parameters()
    run = run_kinematics(read_run(RIGSIM / f"{run_name}.csv"), params)
    plant = build_plant(level, effects, params=params)
    mech = current_driven_map(plant, 1)
    st = IdentificationSettings(segment_duration=0.05, holdout_every=3, quasi_static_starts=True)
    compiled = RunProblem(run, plant, mech, params, free, st)
    interpreted = RunProblem(run, plant, mech, params, free, dataclasses.replace(st, compiled=False))
    return params, plant, compiled, interpreted


def _rel(a, b) -> float:
    a = a.toarray() if hasattr(a, "toarray") else np.asarray(a)
    b = b.toarray() if hasattr(b, "toarray") else np.asarray(b)
    assert a.shape == b.shape
    return float(np.max(np.abs(a - b)) / max(float(np.max(np.abs(b))), 1e-300))


@pytest.mark.skipif(not HAVE_CC, reason="no C compiler: nothing compiled to compare")
def test_compiled_and_interpreted_residuals_and_jacobians_agree():
    params, plant, comp, itp = _problems()
    assert comp.compiled and not itp.compiled
    # the problem exercises the branches of the segment start it claims to
    assert comp.quotient_steps and comp.holdout_samples.any() and "pawl_clearance_comp" in plant.state_names
    assert "surface_position" in plant.quasi_static_states and comp.M > 10
    nf = len(FREE)
    rng = np.random.default_rng(3)
    p0, sig = plant.p_vector(params), comp.sigma0
    scale = np.array([abs(params.value(n)) for n in FREE])
    # at a point away from the initial values
    z = np.r_[0.1 * rng.standard_normal(nf), comp.initial_decision()
              * (1 + 0.01 * rng.standard_normal(comp.n_dec_states))]
    r_c, r_i = comp.residuals(z, p0, scale, sig), itp.residuals(z, p0, scale, sig)
    assert np.all(np.isfinite(r_c)) and np.count_nonzero(r_c) > 0.5 * r_c.size
    assert _rel(r_c, r_i) <= 1e-12
    J_c, J_i = comp.jacobian(z, p0, scale, sig), itp.jacobian(z, p0, scale, sig)
    assert J_c.shape == (r_c.size, nf + comp.n_dec_states)
    # the friction and the efficiency act on the residual (the pawl's initial clearance may not: a wheel
    # that does not reach its pawl in the first segment)
    assert np.all(np.abs(J_c[:, [0, 2]].toarray()).max(axis=0) > 0)
    assert _rel(J_c, J_i) <= 1e-12
    S_c, S_i = (pb.jacobian(z, p0, scale, sig, states_only=True) for pb in (comp, itp))
    assert _rel(S_c, S_i) <= 1e-12
    np.testing.assert_array_equal(S_c.toarray(), J_c[:, nf:].toarray())
    # the Jacobian is the residual's: a central difference along a random direction agrees
    d = rng.standard_normal(z.size) * np.r_[np.full(nf, 1e-6), np.full(z.size - nf, 1e-6)]
    fd = (comp.residuals(z + d, p0, scale, sig) - comp.residuals(z - d, p0, scale, sig)) / 2
    lin = J_c @ d
    ok = np.abs(lin) > 1e-3 * np.abs(lin).max()
    assert np.median(np.abs(fd[ok] - lin[ok]) / np.abs(lin[ok])) < 1e-3


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_CC, reason="no C compiler: nothing compiled to compare")
def test_a_fit_reaches_the_same_estimates_compiled_and_interpreted():
    params = default_parameters()
    run = run_kinematics(read_run(RIGSIM / "null_rig_trim_s1.csv"), params)
    free = ("gear.viscous_friction", "screw.efficiency_direct")
    st = IdentificationSettings(segment_duration=0.05, holdout_every=3, max_nfev=30)
    res = {c: Identifier("A", params, free, effects=("standby_motor",),
                         settings=dataclasses.replace(st, compiled=c)).fit(run) for c in (True, False)}
    for n in free:
        a, b = res[True].estimates[n], res[False].estimates[n]
        assert a.value == pytest.approx(b.value, rel=1e-9, abs=1e-12 * max(abs(a.max), 1.0))
        assert a.stderr == pytest.approx(b.stderr, rel=1e-6)
    assert res[True].nfev == res[False].nfev and res[True].chisqr == pytest.approx(res[False].chisqr, rel=1e-12)


_PROBE = r"""
import json, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from tests.test_fit_compiled import _problems, FREE
params, plant, comp, _ = _problems("rig_coulomb", "A", ("standby_motor",), FREE[::2])
z = np.r_[np.zeros(2), comp.initial_decision()]
scale = np.array([abs(params.value(n)) for n in FREE[::2]])
r = comp.residuals(z, plant.p_vector(params), scale, comp.sigma0)
J = comp.jacobian(z, plant.p_vector(params), scale, comp.sigma0)
print(json.dumps({"compiled": comp.compiled, "r": r.tolist(), "J": J.toarray().sum(axis=0).tolist()}))
"""


def test_no_compiler_fits_with_the_interpreter(tmp_path):
    """A machine without a C compiler: the residual comes from casadi's interpreter, with one note on
    stderr, and equals the compiled one where a compiler exists."""
    empty = tmp_path / "nobin"
    empty.mkdir()
    root = str(Path(__file__).resolve().parents[1])
    env = {**os.environ, "CC": str(tmp_path / "nocc"), "PATH": str(empty), "THSA_CACHE_DIR": str(tmp_path / "c"),
           "PYTHONPATH": root + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.run([sys.executable, "-c", _PROBE, root], capture_output=True, text=True, env=env, cwd=root)
    assert proc.returncode == 0, proc.stderr[-2000:]
    out = json.loads(proc.stdout)
    assert out["compiled"] is False
    assert proc.stderr.count("note:") == 1 and "no C compiler" in proc.stderr
    assert list((tmp_path / "c").glob("*.so")) == []
    if HAVE_CC:
        env2 = {k: v for k, v in env.items() if k not in ("CC", "THSA_CACHE_DIR")}
        env2["PATH"] = os.environ.get("PATH", "")
        proc2 = subprocess.run([sys.executable, "-c", _PROBE, root], capture_output=True, text=True, env=env2,
                               cwd=root)
        assert proc2.returncode == 0, proc2.stderr[-2000:]
        ref = json.loads(proc2.stdout)
        assert ref["compiled"] is True
        assert _rel(np.array(out["r"]), np.array(ref["r"])) <= 1e-12
        assert _rel(np.array(out["J"]), np.array(ref["J"])) <= 1e-12


@pytest.mark.slow
@pytest.mark.skipif(not HAVE_CC, reason="no C compiler: nothing compiled to compare")
def test_a_trace_names_the_same_effects_and_values_compiled_and_interpreted(monkeypatch):
    """A trace of a committed rig-sim run (``rig`` base, a planted Coulomb drag) with the fits compiled and with
    every fit in casadi's interpreter: the same effects, the same parameters and the same held-out drops to
    the printed precision."""
    from thsa_control.fit import shooting
    from thsa_control.trace import TraceSettings, trace

    params = default_parameters()
    run = run_kinematics(read_run(RIGSIM / "rig_coulomb.csv"), params)
    settings = TraceSettings(candidates=("coulomb_friction", "direction_friction", "force_offset"), workers=1,
                             max_effects=1)

    def summary(doc):
        added = [(e["name"], {n: f"{p['value']:.4g}" for n, p in e["parameters"].items()})
                 for e in doc["effects_added"]]
        scored = [(c["name"], f"{c['holdout_chi2_drop']:.4g}" if c.get("holdout_chi2_drop") is not None else None)
                  for r in doc["rounds"] for c in r["candidates"]]
        return added, scored, doc["unexplained"]

    compiled = trace(run, "A", params=params, settings=settings).to_dict()
    monkeypatch.setattr(shooting._SegmentFunctions, "evaluators", lambda self, compiled: (self.functions, False))
    interpreted = trace(run, "A", params=params, settings=settings).to_dict()
    assert summary(compiled) == summary(interpreted)
    assert summary(compiled)[0] and summary(compiled)[1]  # an effect was added, candidates were scored
