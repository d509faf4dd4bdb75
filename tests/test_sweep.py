"""thsa sweep (issue #19): spec validation, sampling, the Dask engine (local and cluster), resume, the report.

The sims are level A runs of a constant-speed scenario against a constant
opposing load, whose steady current the hand-written torque balance of
``handcalc.hand_current`` gives: a uniformly distributed gear drag gives a
uniformly distributed current between the two hand-computed ends.
"""

from __future__ import annotations

import json
import math
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from handcalc import hand_current
from scipy import stats

from thsa_control.cli import main
from thsa_control.errors import OutputError
from thsa_control.sweep.analysis import clopper_pearson, sobol_indices
from thsa_control.sweep.sampling import saltelli_blocks
from thsa_control.sweep.engine import SweepError, scheduler_address
from thsa_control.sweep.spec import SweepSpecError, load_spec, parse_spec

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "PYTHONPATH": str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", "")}
SPEED_MM_S, LOAD_N = 5.0, 20e3
FRICTION = (4e-5, 2e-4)  # gear.viscous_friction [N m s/rad], around the embedded 8e-5

STEADY = (f'{{ name = "steady", description = "{SPEED_MM_S} mm/s against {LOAD_N:g} N", duration = 1.5, '
          f'speed_target = [[0.0, 0.0], [0.2, {SPEED_MM_S * 1e-3}]], accel_limit = 0.03, load = [[0.0, {LOAD_N}]] }}')


def _spec_text(samples: int, chunk: int, seed: int = 7, duration: float = 1.5, extra: str = "") -> str:
    return f"""name = "friction_uniform"
seed = {seed}
level = "A"
designs = ["nominal"]
scenarios = [{STEADY.replace("duration = 1.5", f"duration = {duration}")}]
[sampling]
method = "random"
samples = {samples}
chunk_runs = {chunk}
[parameters."gear.viscous_friction"]
distribution = "uniform"
min = {FRICTION[0]}
max = {FRICTION[1]}
[metrics]
keep = ["plateau_current_A", "current_peak_A"]
[limits.plateau_current_A]
max = 2.19
{extra}"""


def _write(tmp_path, text, name="spec.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def _doc(**changes) -> dict:
    import tomllib

    doc = tomllib.loads(_spec_text(8, 4))
    for k, v in changes.items():
        if v is None:
            doc.pop(k, None)
        else:
            doc[k] = v
    return doc


# ---------------------------------------------------------------- spec validation (no simulation)
@pytest.mark.parametrize("change, key", [
    ({"parameters": {"gear.viscous_frictoin": {"distribution": "uniform", "min": 1e-5, "max": 2e-5}}},
     "parameters.gear.viscous_frictoin"),
    ({"metrics": {"keep": ["plateau_current_A", "peak_curent"]}}, "metrics.keep[1]"),
    ({"parameters": {"gear.viscous_friction": {"distribution": "uniform", "min": 2e-5, "max": 2e-5}}},
     "parameters.gear.viscous_friction.max"),
    ({"parameters": {"gear.viscous_friction": {"distribution": "grid", "values": []}}},
     "parameters.gear.viscous_friction.values"),
    ({"parameters": {"gear.efficiency": {"distribution": "normal", "mean": 0.95, "sd": 0.02}}},
     "parameters.gear.efficiency"),
    ({"parameters": {"gear.efficiency": {"distribution": "uniform", "min": 0.9, "max": 1.1}}},
     "parameters.gear.efficiency"),
    ({"conditions": {"temperature": {"distribution": "uniform", "min": -80, "max": 20}}}, "conditions.temperature"),
    ({"sampling": {"method": "montecarlo"}}, "sampling.method"),
    ({"seed": None}, "seed"),
    ({"limits": {"current_peak_A": {"maximum": 3}}}, "limits.current_peak_A.maximum"),
    ({"scenarios": ["no_such_scenario"]}, "scenarios[0]"),
    ({"designs": ["no_such_design"]}, "designs[0]"),
    ({"faults": [{"kind": "surface_jam", "time": {"distribution": "uniform", "min": 0.5, "max": 2.0}}]},
     "faults[0].time"),
    ({"colour": "blue"}, "colour"),
    ({"metrics": {"keep": ["plateau_current_A", "first_detection_s"]}}, "metrics.keep[1]"),
])
def test_bad_spec_names_the_key(change, key):
    with pytest.raises(SweepSpecError) as err:
        parse_spec(_doc(**change), source="bad.toml", base_dir=ROOT)
    assert f": {key}:" in str(err.value)


def test_bad_spec_exits_2_before_any_work(tmp_path, capsys):
    spec = _write(tmp_path, _spec_text(8, 4).replace('"current_peak_A"]', '"current_peek_A"]'))
    assert main(["sweep", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "metrics.keep[1]" in err and "current_peek_A" in err and "did you mean current_peak_A" in err
    assert not (tmp_path / "out").exists()


def test_unreachable_scheduler_exits_2_within_seconds(tmp_path, capsys, monkeypatch):
    """Exit 2 naming the address once the connect timeout has passed, before any compile.  The timeout is
    set to 1 s here (Dask retries a refused connection until then: the default 5 s would idle a test worker)."""
    from thsa_control.sweep import engine

    assert engine.CONNECT_TIMEOUT_S <= 10.0  # the user's wait: seconds
    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 1.0)
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nobody listens there now
    spec = _write(tmp_path, _spec_text(4, 2))
    t0 = time.perf_counter()
    code = main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--scheduler", f"tcp://127.0.0.1:{port}", "-q"])
    elapsed = time.perf_counter() - t0
    assert code == 2
    err = capsys.readouterr().err
    assert f"tcp://127.0.0.1:{port}" in err and "within 1 s" in err
    assert elapsed < 1.0 + 5.0  # the connect timeout, before any compile (the same 5 s margin as at 5 s)
    assert not list((tmp_path / "out" / "runs").glob("*.parquet"))


def test_scheduler_file_is_read_once_written_whole(tmp_path):
    """The scheduler creates its file before it writes it: an empty, then a partial file is waited on, and the
    address is read once the JSON is whole."""
    import threading

    f = tmp_path / "scheduler.json"
    whole = json.dumps({"type": "Scheduler", "address": "tcp://127.0.0.1:8786"})

    def write():
        time.sleep(0.2)
        f.write_text("")
        time.sleep(0.2)
        f.write_text(whole[:20])
        time.sleep(0.2)
        f.write_text(whole)

    t = threading.Thread(target=write)
    t.start()
    try:
        assert scheduler_address(f, timeout=10.0) == "tcp://127.0.0.1:8786"
    finally:
        t.join()


@pytest.mark.parametrize("text, seen", [(None, "no file"), ("", "an empty file"), ('{"address": ', "no JSON"),
                                        ('{"type": "Scheduler"}', "without 'address'"),
                                        ('{"address": ""}', "'address' = ''"), (b"\xff\xfe", "not UTF-8")])
def test_scheduler_file_never_written_names_the_file_and_what_it_held(tmp_path, text, seen):
    f = tmp_path / "scheduler.json"
    if isinstance(text, bytes):
        f.write_bytes(text)
    elif text is not None:
        f.write_text(text)
    t0 = time.perf_counter()
    with pytest.raises(SweepError) as e:
        scheduler_address(f, timeout=0.3)
    assert time.perf_counter() - t0 < 0.3 + 2.0
    assert str(f) in str(e.value) and seen in str(e.value) and "within 0.3 s" in str(e.value)


def test_scheduler_that_exits_before_writing_its_file_is_named_at_once(tmp_path):
    f = tmp_path / "scheduler.json"
    f.write_text("")
    t0 = time.perf_counter()
    with pytest.raises(SweepError, match="exited with code 3"):
        scheduler_address(f, timeout=30.0, exited=lambda: 3)
    assert time.perf_counter() - t0 < 5.0  # not the 30 s timeout


def test_missing_scheduler_file_exits_2_with_no_run_written(tmp_path, capsys, monkeypatch):
    from thsa_control.sweep import engine

    monkeypatch.setattr(engine, "CONNECT_TIMEOUT_S", 0.5)
    spec = _write(tmp_path, _spec_text(4, 2))
    missing = tmp_path / "nowhere" / "scheduler.json"
    code = main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--scheduler-file", str(missing), "-q"])
    assert code == 2
    err = capsys.readouterr().err
    assert f"--scheduler-file {missing}" in err and "no file" in err
    assert not list((tmp_path / "out" / "runs").glob("*.parquet"))


def test_folder_of_another_sweep_is_refused(tmp_path):
    from thsa_control.sweep.engine import prepare_folder

    out = tmp_path / "out"
    prepare_folder(load_spec(_write(tmp_path, _spec_text(8, 4))), out)
    other = load_spec(_write(tmp_path, _spec_text(8, 4, seed=8), "other.toml"))
    with pytest.raises(OutputError, match="another spec"):
        prepare_folder(other, out)
    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    with pytest.raises(OutputError, match="not written by thsa"):
        prepare_folder(other, foreign, force=True)
    assert (foreign / "notes.txt").read_text() == "mine"


def test_plan_is_fixed_by_seed_and_run_index(tmp_path):
    spec = load_spec(_write(tmp_path, _spec_text(10, 4)))
    a = spec.run_specs(range(10))
    b = load_spec(_write(tmp_path, _spec_text(20, 4), "more.toml")).run_specs(range(10))
    assert [r.values for r in a] == [r.values for r in b]  # random sampling: sample j does not depend on n
    vals = [dict(r.values)["gear.viscous_friction"] for r in a]
    assert all(FRICTION[0] <= v <= FRICTION[1] for v in vals) and len(set(vals)) == 10


def test_a_run_gets_its_values(tmp_path):
    """Temperature, load scale, fault instant and parameters of the plan reach the run's scenario and parameters."""
    from thsa_control.sweep.engine import run_inputs

    text = """name = "campaign"
seed = 3
level = "D"
scenarios = ["jam"]
[sampling]
samples = 4
[[faults]]
kind = "surface_jam"
time = { distribution = "uniform", min = 1.5, max = 4.5 }
[[faults]]
kind = "sensor"
sensor = "rvdt"
mode = "noise"
value = 0.001
time = 1.0
end = 1.2
[conditions.temperature]
distribution = "grid"
values = [-55.0, 70.0]
[conditions.load_scale]
distribution = "grid"
values = [-1.0, 0.5]
[parameters."limiter.mu_static"]
distribution = "uniform"
min = 0.1
max = 0.15
[metrics]
keep = ["first_detection_s"]
"""
    spec = load_spec(_write(tmp_path, text))
    assert spec.total_runs == 16 and spec.grid_points == 4
    base = spec.scenarios[0]
    seeds = set()
    for rs in spec.run_specs(range(16)):
        v = dict(rs.values)
        _, sc, p = run_inputs(spec, rs)
        assert sc.temperature == v["temperature_C"] and p.value("limiter.mu_static") == v["limiter.mu_static"]
        assert [f for _, f in sc.load] == [f * v["load_scale"] for _, f in base.load]
        jam, noise = sc.faults
        assert jam.kind == "surface_jam" and jam.time == v["fault_time_s"] and 1.5 <= jam.time <= 4.5
        seeds.add(noise.seed)  # sensor noise: one seed per run, from the spec's seed and the run index
    assert len(seeds) == 16
    assert [dict(r.values)["temperature_C"] for r in spec.run_specs(range(0, 16, 4))] == [-55.0, -55.0, 70.0, 70.0]


def test_sobol_estimators_on_a_linear_function():
    # f = x1 + 2 x2 on the unit square: Var = 1/12 + 4/12, S1 = ST = (1/5, 4/5)
    n, d = 1024, 2
    X = saltelli_blocks(n, d, seed=3)
    f = X[:, 0] + 2 * X[:, 1]
    blocks = f.reshape(d + 2, n)
    s1, st = sobol_indices(blocks[0], blocks[1], list(blocks[2:]))
    assert s1 == pytest.approx([0.2, 0.8], abs=0.03)
    assert st == pytest.approx([0.2, 0.8], abs=0.03)


def test_clopper_pearson_covers_the_binomial():
    lo, hi = clopper_pearson(3, 50)
    # exact: P(X >= 3 | p = lo) = 2.5 % and P(X <= 3 | p = hi) = 2.5 %
    assert stats.binom.sf(2, 50, lo) == pytest.approx(0.025, rel=1e-6)
    assert stats.binom.cdf(3, 50, hi) == pytest.approx(0.025, rel=1e-6)


def test_saltelli_sweep_analysis_gives_sobol_indices_of_the_table(tmp_path):
    """The analysis finds the Sobol' indices of a metric known in closed form from the plan's values."""
    from thsa_control.sweep.analysis import analyse_sweep
    from thsa_control.sweep.engine import _rows_table

    text = _spec_text(512, 64).replace('method = "random"', 'method = "saltelli"') + """
[parameters."gear.efficiency"]
distribution = "uniform"
min = 0.9
max = 0.98
"""
    spec = load_spec(_write(tmp_path, text))
    assert spec.total_runs == 512 * 4
    rows = []
    for rs in spec.run_specs(range(spec.total_runs)):
        v = dict(rs.values)  # metric = a + b x1 + c x2, uniform inputs: S_i = b_i^2 var_i / sum
        x1 = (v["gear.viscous_friction"] - FRICTION[0]) / (FRICTION[1] - FRICTION[0])
        x2 = (v["gear.efficiency"] - 0.9) / 0.08
        rows.append({"run": rs.run, "design": "nominal", "scenario": "steady", "grid": rs.grid, "sample": rs.sample,
                     **v, "plateau_current_A": 2.0 + x1 + 2.0 * x2, "current_peak_A": 3.0,
                     "pass:plateau_current_A": True, "error": ""})
    a = analyse_sweep(spec, _rows_table(spec, rows))
    got = {s.input: s for s in a.sensitivity if s.metric == "plateau_current_A"}
    assert got["gear.viscous_friction"].first_order == pytest.approx(0.2, abs=0.03)
    assert got["gear.efficiency"].first_order == pytest.approx(0.8, abs=0.03)
    assert got["gear.efficiency"].total == pytest.approx(0.8, abs=0.03)
    ranked = [s.input for s in a.sensitivity if s.metric == "plateau_current_A"]
    assert ranked == ["gear.efficiency", "gear.viscous_friction"]


def test_compiled_library_shipped_to_a_fresh_cache_is_used(tmp_path, monkeypatch, params, design):
    """What a remote worker does: the client's library bytes, checked, put into its own (empty) cache."""
    from thsa_control.model import build_plant
    from thsa_control.sim.codegen import install_library, library_files
    from thsa_control.sim.scenarios import get_scenario
    from thsa_control.sim.simulate import Simulator

    sc = get_scenario("cold_ramp")
    info = Simulator(build_plant("A")).run(sc, design, params).info["compile"]
    files = library_files(info["path"])
    assert sorted(k.rsplit(".", 1)[1] for k in files) == ["json", "so"]
    monkeypatch.setenv("THSA_CACHE_DIR", str(tmp_path / "remote"))
    bad = {k: (v[:-1] + bytes([v[-1] ^ 1]) if k.endswith(".so") else v) for k, v in files.items()}
    assert not install_library(bad)  # corrupted on the way: refused
    assert not list((tmp_path / "remote").glob("*.so"))
    assert install_library(files)
    info2 = Simulator(build_plant("A")).run(sc, design, params).info["compile"]
    assert info2["cached"] and info2["compile_s"] == 0.0
    assert Path(info2["path"]).parent == tmp_path / "remote"


def test_a_run_that_cannot_simulate_is_a_failed_row_not_a_crash(tmp_path):
    """A sampled motor current limit below the design's clamp: the design refuses those runs; they are kept,
    named, without metrics and failing every limit."""
    from thsa_control.sweep.engine import simulate_chunk

    text = _spec_text(6, 6) + """
[parameters."motor.max_current"]
distribution = "uniform"
min = 10.0
max = 20.0
"""
    spec = load_spec(_write(tmp_path, text))
    rows = simulate_chunk(spec, spec.run_specs(range(6)))
    bad = [r for r in rows if r["motor.max_current"] < 15.0]
    good = [r for r in rows if r["motor.max_current"] >= 15.0]
    assert bad and good
    assert all("motor.max_current" in r["error"] and math.isnan(r["plateau_current_A"])
               and r["pass:plateau_current_A"] is False for r in bad)
    assert all(r["error"] == "" and math.isfinite(r["plateau_current_A"]) for r in good)


# ---------------------------------------------------------------- sweeps (Dask)
def _cli(args, **kw):
    return subprocess.run([sys.executable, "-m", "thsa_control.cli", *args], env=ENV, capture_output=True, text=True,
                          check=False, **kw)


def _table(out):
    from thsa_control.sweep.engine import read_results

    return read_results(out)


@pytest.mark.slow
def test_known_distribution_of_the_steady_current(tmp_path, params):
    """The current over a uniform gear drag is uniform between the hand-computed ends; the sweep reproduces it."""
    n = 40
    spec = _write(tmp_path, _spec_text(n, 10))
    out = tmp_path / "out"
    assert main(["sweep", str(spec), "--out", str(out), "--workers", "1", "-q"]) == 0
    t = _table(out).to_pydict()
    assert t["run"] == list(range(n)) and set(t["error"]) == {""}
    c, i = np.array(t["gear.viscous_friction"]), np.array(t["plateau_current_A"])
    hand = np.array([hand_current(params.replace({"gear.viscous_friction": x}).value, "A", SPEED_MM_S, LOAD_N)
                     for x in c])
    assert np.max(np.abs(i - hand)) < 1e-3  # each run: the torque balance (1e-3 A: discrete ripple)
    lo, hi = (hand_current(params.replace({"gear.viscous_friction": x}).value, "A", SPEED_MM_S, LOAD_N)
              for x in FRICTION)
    # the distribution: uniform on [lo, hi]
    assert stats.kstest(i, stats.uniform(lo, hi - lo).cdf).pvalue > 0.05
    for q in (0.25, 0.5, 0.75):  # P(I <= quantile) within the exact interval of the sweep's fraction
        k = int(np.sum(i <= lo + q * (hi - lo)))
        a, b = clopper_pearson(k, n)
        assert a <= q <= b
    # the limit 2.19 A: its probability from the hand distribution lies in the reported interval
    rep = json.loads((out / "report" / "report.json").read_text())
    jsonschema = pytest.importorskip("jsonschema")  # in the test extra
    jsonschema.Draft202012Validator(json.loads((ROOT / "docs" / "sweep_report_schema.json").read_text())).validate(rep)
    f = next(x for x in rep["failure_probabilities"] if x["requirement"].startswith("plateau_current_A")
             and x["group"] == "all")
    p_hand = (hi - 2.19) / (hi - lo)
    assert f["clopper_pearson_95"][0] <= p_hand <= f["clopper_pearson_95"][1]
    assert f["failures"] == int(np.sum(i > 2.19))
    sens = [s for s in rep["sensitivity"] if s["metric"] == "plateau_current_A"]
    assert sens[0]["input"] == "gear.viscous_friction" and sens[0]["spearman"] == pytest.approx(1.0)
    # the worst case replays alone with its command: the same current, to the bit
    worst = next(w for w in rep["worst_cases"] if w["metric"] == "plateau_current_A" and w["rank"] == 1)
    assert worst["value"] == pytest.approx(float(np.max(i)), rel=0, abs=0)
    cmd = worst["replay"].split()
    cmd[cmd.index("--out") + 1] = str(tmp_path / "replay")
    assert main(cmd[1:] + ["-q"]) == 0
    summary = json.loads((tmp_path / "replay" / "summary.json").read_text())
    peak = next(x for x, r in zip(t["current_peak_A"], t["run"]) if r == worst["run"])
    assert summary["levels"]["A"]["peak_abs_current_A"] == peak
    assert (out / "report" / "report.html").stat().st_size > 10_000
    # --check: the runs above the limit fail the command (the rerun finds every run done and simulates none)
    assert main(["sweep", str(spec), "--out", str(out), "--check", "-q"]) == 1
    assert _table(out).num_rows == n


class _Cluster:
    """A Dask scheduler and two single-thread workers in their own process groups."""

    def __init__(self, tmp_path):
        self.file = tmp_path / "scheduler.json"
        self.procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler", "--host", "127.0.0.1",
                                        "--port", "0", "--no-dashboard", "--scheduler-file", str(self.file)],
                                       env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                       start_new_session=True)]
        self.address = scheduler_address(self.file, timeout=60.0, exited=self.procs[0].poll)
        for _ in range(2):
            self.procs.append(subprocess.Popen(
                [sys.executable, "-m", "distributed.cli.dask_worker", self.address, "--nthreads", "1",
                 "--nworkers", "1", "--no-dashboard"], env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                start_new_session=True))
        from distributed import Client

        with Client(self.address, timeout=30) as c:
            c.wait_for_workers(2, timeout=60)

    def kill(self, i: int) -> None:
        os.killpg(self.procs[i].pid, signal.SIGKILL)
        self.procs[i].wait()

    def close(self) -> None:
        for p in reversed(self.procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in self.procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)


@pytest.fixture
def cluster(tmp_path):
    c = _Cluster(tmp_path)
    yield c
    c.close()


@pytest.mark.slow
def test_local_default_and_dask_cluster_give_bit_identical_tables(tmp_path, cluster):
    spec = _write(tmp_path, _spec_text(12, 3))
    a, b = tmp_path / "local", tmp_path / "cluster"
    r = _cli(["sweep", str(spec), "--out", str(a), "--workers", "2"], timeout=300)
    assert r.returncode == 0, r.stderr
    assert "12/12 runs" in r.stderr and "runs/s" in r.stderr and "ETA" in r.stderr  # progress on stderr
    r = _cli(["sweep", str(spec), "--out", str(b), "--scheduler", cluster.address], timeout=300)
    assert r.returncode == 0, r.stderr
    ta, tb = _table(a), _table(b)
    assert ta.num_rows == 12 and ta.equals(tb)
    assert len(list((b / "runs").glob("chunk-*.parquet"))) == 4


def _wait_for_chunks(folder: Path, proc, at_least: int, timeout: float = 180.0) -> int:
    deadline = time.time() + timeout
    while time.time() < deadline:
        n = len(list((folder / "runs").glob("chunk-*.parquet"))) if (folder / "runs").exists() else 0
        if n >= at_least:
            return n
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.02)
    raise AssertionError("no chunk finished in time")


def _complete(folder: Path, n: int):
    t = _table(folder)
    assert t.column("run").to_pylist() == list(range(n))  # every run, once
    assert set(t.column("error").to_pylist()) == {""}
    return t


@pytest.mark.slow
def test_worker_killed_mid_sweep_loses_nothing_and_counts_nothing_twice(tmp_path, cluster):
    from thsa_control.sweep.engine import simulate_chunk

    n = 60
    spec_path = _write(tmp_path, _spec_text(n, 2, duration=3.0))
    out = tmp_path / "out"
    # the cluster reached through its scheduler file (the batch-system way; the address is tested above)
    proc = subprocess.Popen([sys.executable, "-m", "thsa_control.cli", "sweep", str(spec_path), "--out", str(out),
                             "--scheduler-file", str(cluster.file)], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    at_kill = _wait_for_chunks(out, proc, 1)
    cluster.kill(1)  # one of the two workers, with its nanny
    _, stderr = proc.communicate(timeout=300)
    assert proc.returncode == 0, stderr
    assert at_kill < n // 2  # the worker died mid-sweep
    t = _complete(out, n)
    spec = load_spec(spec_path)  # the values are those of the runs, recomputed here for a few
    rows = simulate_chunk(spec, spec.run_specs([0, n // 2, n - 1]))
    got = dict(zip(t.column("run").to_pylist(), t.column("plateau_current_A").to_pylist()))
    assert [got[r["run"]] for r in rows] == [r["plateau_current_A"] for r in rows]


@pytest.mark.slow
def test_sigterm_mid_sweep_then_rerun_completes_each_row_once(tmp_path):
    n = 60
    spec = _write(tmp_path, _spec_text(n, 2, duration=3.0))
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "thsa_control.cli", "sweep", str(spec), "--out", str(out),
                             "--workers", "1"], env=ENV, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    _wait_for_chunks(out, proc, 1)
    proc.send_signal(signal.SIGTERM)
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signal.SIGTERM, stderr
    kept = len(list((out / "runs").glob("chunk-*.parquet")))
    assert 1 <= kept < n // 2 and "rerun the same command to resume" in stderr
    assert not list((out / "runs").glob(".chunk-*"))  # no half-written file
    r = _cli(["sweep", str(spec), "--out", str(out), "--workers", "1"], timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"resuming: {2 * kept} of {n} runs already" in r.stderr
    assert f"{n - 2 * kept} runs simulated" in r.stdout
    _complete(out, n)
