"""What limits an added effect's window error drop: the record's ceiling against what the tracer reached.

Traces RUN.csv as ``thsa trace RUN.csv --model A`` does (every fit recorded), then, on the scored window of EFFECT
(the samples its ``window_reduction`` is judged on: its held-out window samples, outside the base's transients where
the engine scores it so), prints the noise-weighted squared error per held-out sample of each channel (chi2/n, in
units of the channel weights the trace used) and the RMS drop against the model the effect was added to, for:

* ``before``: the model the effect was added to (its parameters, segment states refitted);
* ``fitted``: the effect as the tracer fitted it;
* ``values``: the effect at the values given by ``--set NAME=VALUE`` (the simulator's truth where the structures
  correspond; the other free parameters and the segment states refitted): what the true structure with the true
  parameters reaches in the tracer's discretisation;
* ``twin``: the model the effect was added to, on ``--twin TWIN.csv`` (the same simulator seed and scenario without
  the effect: the same noise, so its window error is what a perfect model of the effect would leave, within the
  closed loop's small change of trajectory), scored on the same window;
* with ``--substeps S``: ``before`` and ``values`` again at S plant steps per sample (the replay's discretisation).

``--sensor-noise CH=SIGMA`` (the sensor's specified noise, e.g. rig-sim's truth file) prints what a model leaving
only that noise would reach: ``1 - sigma / (weight sqrt(chi2/n before))``.

Run: ``python bench/window_ceiling.py RUN.csv --effect drivetrain_compliance --set gear.torsional_stiffness=1e4
--set gear.torsional_damping=2 --sensor-noise motor_speed=0.216 --substeps 4``
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np

import thsa_control.trace.engine as engine
from thsa_control.cli.common import read_runs
from thsa_control.fit.profile import chi2_by_channel
from thsa_control.model.params import ParameterSet, default_parameters
from thsa_control.trace import TraceSettings, trace
from thsa_control.trace.candidates import CANDIDATES, _window
from thsa_control.trace.scoring import _fit_job


def _record(log: list):
    """Wrap the engine's job runner so that every (job, fit) is kept."""
    run_jobs = engine._run_jobs

    def recorded(jobs, workers, progress):
        out = run_jobs(jobs, workers, progress)
        log.extend(zip(jobs, out))
        return out
    return recorded


def _refit(job: dict, label: str, values: dict | None = None, runs=None, substeps: int | None = None) -> dict:
    """The job's model refitted with ``values`` held (and no profile, no identifiability screening)."""
    values = dict(values or {})
    p = ParameterSet.from_toml(job["params_toml"]).replace(values)
    st = job["settings"] if substeps is None else dataclasses.replace(job["settings"], substeps=substeps)
    free = tuple(n for n in job["free"] if n not in values)
    f = _fit_job({**job, "label": label, "params_toml": p.to_toml(), "free": free, "judge": {}, "second_stage": (),
                  "hold_at": {}, "absent": {}, "profile": {}, "profile_grid": None, "settings": st,
                  "runs": runs if runs is not None else job["runs"]})
    if "error" in f:
        raise SystemExit(f"window_ceiling: the {label} fit failed: {f['error']}")
    return f


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv")
    ap.add_argument("--effect", required=True)
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE")
    ap.add_argument("--twin", help="the same seed and scenario without the effect")
    ap.add_argument("--substeps", type=int, default=None)
    ap.add_argument("--sensor-noise", action="append", default=[], metavar="CHANNEL=SIGMA")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    values = {k: float(v) for k, v in (s.split("=", 1) for s in a.set)}
    spec_noise = {k: float(v) for k, v in (s.split("=", 1) for s in a.sensor_noise)}
    params = default_parameters()
    run = read_runs([a.csv], None, params)[0]  # as `thsa trace` reads it (kinematics from the file where unstated)
    log: list = []
    engine._run_jobs = _record(log)
    st = TraceSettings(workers=a.workers)
    doc = trace(run, "A", params=params, settings=st).to_dict()
    step = next((e for e in doc["effects_added"] if e["name"] == a.effect and not e.get("implied_by")), None)
    if step is None:
        raise SystemExit(f"window_ceiling: {a.effect} was not added (added: {doc['found_effects']})")
    # the added fit: the candidate job of that name whose estimates are the step's
    cand = [(j, f) for j, f in log if j["label"] == a.effect and "error" not in f
            and all(math.isclose(f["estimates"][n]["value"], v["value"], rel_tol=1e-9)
                    for n, v in step["parameters"].items() if n in f["estimates"])]
    if not cand:
        raise SystemExit(f"window_ceiling: the fit that added {a.effect} was not recorded")
    cj, cf = cand[-1]
    # the model it was added to: the round's null calibration ran it ("null base"), on the record it is refitted
    before_effects = tuple(e for e in cj["effects"] if e != a.effect)
    bj = next((j for j, f in log if j["label"] == "null base" and tuple(j["effects"]) == before_effects), None)
    if bj is None:
        raise SystemExit(f"window_ceiling: the model {a.effect} was added to was not recorded ({before_effects})")
    bj = {**bj, "runs": cj["runs"]}
    weights = doc["channel_weights"]["rms"]
    spec = CANDIDATES[a.effect]
    fitted = ParameterSet.from_toml(cf["params_toml"])
    masks = engine.score_masks([run], st.signature.transient_time)
    mask = masks.get(spec.window)
    win = _window(spec.window, run, fitted) & (mask[run.name] if mask is not None else True)
    before_params = ParameterSet.from_toml(bj["params_toml"])
    held = {n: before_params.value(n) for n in bj["free"]}  # the model before the effect, as fitted
    fits = {"before": _refit(bj, "before", held),
            "fitted": cf}
    if values:
        fits["values"] = _refit(cj, "values", values)
    if a.twin:
        twin = dataclasses.replace(read_runs([a.twin], None, params)[0], name=run.name, controller=None)
        fits["twin"] = _refit(bj, "twin", held, runs=[twin])
    sub = {}
    if a.substeps:
        sub["before"] = _refit(bj, f"before, {a.substeps} steps", held, substeps=a.substeps)
        if values:
            sub["values"] = _refit(cj, f"values, {a.substeps} steps", values, substeps=a.substeps)

    def report(title, fs):
        print(title)
        for sel, m in (("window", win), ("all held-out samples", np.ones_like(win))):
            rows = {}
            for name, f in fs.items():
                n: dict = {}
                c = chi2_by_channel(f["predictions"], weights, "holdout", {run.name: m}, counts=n)
                rows[name] = (c, n)
            c0 = rows["before"][0]
            print(f"  {sel}:")
            for name, (c, n) in rows.items():
                print(f"    {name:8s} " + "  ".join(
                    f"{ch} {c[ch] / max(n.get(ch, 1), 1):6.2f} ({1 - math.sqrt(c[ch] / c0[ch]) if c0[ch] else 0:+.0%})"
                    for ch in c) + f"   [held-out samples {max(n.values(), default=0)}]")
            for ch, sig in spec_noise.items():
                if ch in c0:
                    k = rows["before"][1].get(ch, 1)
                    print(f"    sensor noise only ({ch} {sig:g}): chi2/n {(sig / weights[ch]) ** 2:.2f}, drop "
                          f"{1 - sig / (weights[ch] * math.sqrt(c0[ch] / k)):+.0%}")
    print(f"{run.name}: {a.effect} added in round {step['round_added']}, window '{spec.window}' "
          f"({int(win.sum())} samples), trace's window_reduction "
          + ", ".join(f"{c} {v:.0%}" for c, v in step["window_reduction"].items())
          + "; " + ", ".join(f"{n} = {v['value']:.4g}" for n, v in step["parameters"].items()))
    print("chi2/n: noise-weighted squared error per held-out sample (channel weights "
          + ", ".join(f"{c} {w:.3g}" for c, w in weights.items()) + "); (drop): RMS drop against 'before'")
    report(f"at the trace's {st.substeps} plant step(s) per sample", fits)
    if sub:
        report(f"at {a.substeps} plant steps per sample", sub)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
