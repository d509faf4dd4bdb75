"""Run a sweep on Dask: chunks of runs per task, results appended to Parquet as chunks finish, resume.

Where the work runs
    ``scheduler=None``: a ``dask.distributed.LocalCluster`` of ``workers``
    processes (default: one per core), started and stopped here; an address:
    an existing Dask cluster, unchanged; ``scheduler_file``: the JSON file a
    scheduler started with ``dask scheduler --scheduler-file FILE`` writes
    (the batch-system way: scheduler and workers started as jobs on a shared
    file system), read by :func:`scheduler_address`.  All run the same tasks.

What a task does
    :func:`simulate_chunk` simulates a chunk of :class:`~.spec.RunSpec` (the
    runs of one plant in one batched call of the compiled library) and
    returns one row (dict) per run.  It is the one place that simulates.  The
    simulators (plant, compiled loop) are built once per worker process and
    spec, kept in :data:`_WORKER_SIMULATORS`.

The compiled model on the workers
    The client simulates the first run of each plant before submitting
    anything (the compile happens there once, and a bad metric name or
    design fails before any task is sent), reads the compiled libraries'
    bytes and ships them with the spec; each worker puts them into its own
    cache (``sim/codegen.install_library``: verified, atomic), so a remote
    worker neither needs the client's file system nor, when its platform
    matches, a C compiler; when they do not load there it builds its own.

Output folder ``DIR``
    ``sweep.json`` (the sweep's identity: the spec's SHA-256 with its input
    files, number of runs, chunk size), ``spec.toml`` (a copy), ``runs/``
    (one Parquet file per finished chunk, ``chunk-NNNNNN.parquet``, written
    by the client under a temporary name then renamed: a file is complete or
    absent).  A rerun with the same spec skips the chunks on disk; a chunk
    whose worker died is rerun by Dask, and only its first result is written,
    so every run is in the table exactly once.  ``read_results`` gives the
    table sorted by run index.

Bit-identical results for one seed whatever the workers: every value of a
run is fixed on the client from the seed and the run index before the work
is split; a worker only simulates.
"""

from __future__ import annotations

import json
import logging
import math
import os
import re
import shutil
import signal
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..errors import OutputError, ThsaError
from .spec import RunSpec, SweepSpec

__all__ = [
    "SweepError",
    "SweepRun",
    "chunk_ranges",
    "prepare_folder",
    "read_results",
    "results_schema",
    "run_inputs",
    "run_sweep",
    "scheduler_address",
    "simulate_chunk",
]

FORMAT = "thsa-sweep/1"
_CHUNK_RE = re.compile(r"^chunk-(\d{6})\.parquet$")
#: worker process -> {spec sha: {plant effects: Simulator}}
_WORKER_SIMULATORS: dict = {}
#: Seconds to wait for a scheduler before giving up.
CONNECT_TIMEOUT_S = 5.0


class SweepError(ThsaError, RuntimeError):
    """The sweep cannot run (scheduler unreachable, output folder of another sweep, a task that kept failing)."""


# ------------------------------------------------------------------ one run
def run_inputs(spec: SweepSpec, rs: RunSpec):
    """``(design, scenario, params)`` of one run: the spec's with the run's values applied."""
    from ..sim.events import FaultEvent

    values = dict(rs.values)
    design = spec.designs[rs.design][1]
    scenario = spec.scenarios[rs.scenario]
    pvals = {v.name: values[v.name] for v in spec.variables if v.kind == "parameter"}
    params = spec.params.replace(pvals) if pvals else spec.params
    if "temperature_C" in values:
        scenario = scenario.with_temperature(values["temperature_C"])
    if "load_scale" in values:
        s = values["load_scale"]
        scenario = replace(scenario, load=tuple((t, f * s) for t, f in scenario.load))
    if spec.faults:
        times = {v.index: values[v.name] for v in spec.variables if v.kind == "fault_time"}
        events = []
        for k, ev in enumerate(spec.faults):
            ev = dict(ev)
            if k in times:
                ev["time"] = times[k]
            if ev.get("kind") == "sensor" and ev.get("mode") == "noise" and "seed" not in ev:
                ev["seed"] = int(np.random.SeedSequence([spec.seed, rs.run, k]).generate_state(1)[0])
            events.append(FaultEvent(**ev))
        scenario = replace(scenario, faults=tuple(events))
    return design, scenario, params


def _simulator(spec: SweepSpec, effects: tuple[str, ...]):
    from ..model import build_plant
    from ..sim.simulate import SimulationSettings, Simulator

    sims = _WORKER_SIMULATORS.setdefault(spec.sha256, {})
    if effects not in sims:
        plant = build_plant(spec.level, effects, params=spec.params)
        sims[effects] = Simulator(plant, SimulationSettings(output_period=spec.output_period))
    return sims[effects]


def _simulate_one(spec: SweepSpec, rs: RunSpec):
    """``(result or None, error text, fault time)`` of one run."""
    t_fault = math.nan
    try:
        design, scenario, params = run_inputs(spec, rs)
        t_fault = min((f.time for f in scenario.faults), default=math.nan)
        sim = _simulator(spec, spec.plant_effects(scenario))
        return sim.run(scenario, design, params), "", t_fault
    except ThsaError as exc:  # a run that diverges or that the actuator cannot do: a failed run, kept
        return None, str(exc).strip() or type(exc).__name__, t_fault


def simulate_chunk(spec: SweepSpec, runs: list[RunSpec], libraries: tuple = ()) -> list[dict]:
    """Simulate ``runs`` and return one row per run (the task of a worker).

    The runs of one plant go to the compiled library together
    (``Simulator.run_batch``, one thread: a worker is one core), each result
    bit-identical to a single run.  Row: ``run``, ``design``, ``scenario``,
    ``grid``, ``sample``, the varied values, the metrics (nan for a run that
    failed), ``pass:METRIC`` per limit (False for nan), ``error`` (empty when
    the run simulated).
    """
    from ..sim.codegen import install_library
    from .metrics import compute_metrics

    if libraries and not _WORKER_SIMULATORS.get(("installed", spec.sha256)):
        for files in libraries:
            install_library(files)
        _WORKER_SIMULATORS[("installed", spec.sha256)] = True
    results: dict[int, tuple] = {}  # index in runs -> (result or None, error, fault time)
    groups: dict[tuple, list] = {}
    for k, rs in enumerate(runs):
        try:
            design, scenario, params = run_inputs(spec, rs)
        except ThsaError as exc:  # values the actuator cannot have: a failed run, kept
            results[k] = (None, str(exc).strip() or type(exc).__name__, math.nan)
            continue
        t_fault = min((f.time for f in scenario.faults), default=math.nan)
        groups.setdefault(spec.plant_effects(scenario), []).append((k, design, scenario, params, t_fault))
    for effects, items in groups.items():
        try:
            sim = _simulator(spec, effects)
            batch = sim.run_batch([it[2] for it in items], [it[1] for it in items], [it[3] for it in items],
                                  threads=1)
            for it, res in zip(items, batch):
                results[it[0]] = (res, "", it[4])
        except ThsaError:  # one run or more fails (diverges, refused): find them, keep the others
            for k, design, scenario, params, t_fault in items:
                try:
                    results[k] = (_simulator(spec, effects).run(scenario, design, params), "", t_fault)
                except ThsaError as exc:
                    results[k] = (None, str(exc).strip() or type(exc).__name__, t_fault)
    rows = []
    for k, rs in enumerate(runs):
        label, design = spec.designs[rs.design]
        row = {"run": rs.run, "design": label, "scenario": spec.scenarios[rs.scenario].name, "grid": rs.grid,
               "sample": rs.sample, **dict(rs.values)}
        result, error, t_fault = results[k]
        if result is None:
            row.update({m: math.nan for m in spec.metrics})
        else:
            row.update(compute_metrics(result, design, spec.metrics, fault_time=t_fault))
        for lim in spec.limits:
            row[f"pass:{lim.metric}"] = lim.passed(row[lim.metric])
        row["error"] = error
        rows.append(row)
    return rows


def _task(spec: SweepSpec, runs: list[RunSpec], libraries: tuple = ()) -> tuple[list[dict], float, float, float]:
    """A worker's task: :func:`simulate_chunk`, and the CPU seconds of its thread, of the whole worker process
    (Dask's own threads included) and the wall seconds it took there."""
    t0, c0, w0 = time.thread_time(), time.process_time(), time.perf_counter()
    rows = simulate_chunk(spec, runs, libraries)
    return rows, time.thread_time() - t0, time.process_time() - c0, time.perf_counter() - w0


# ------------------------------------------------------------------ table
def results_schema(spec: SweepSpec):
    """The Arrow schema of the results table."""
    import pyarrow as pa

    cols = [("run", pa.int64()), ("design", pa.string()), ("scenario", pa.string()), ("grid", pa.int64()),
            ("sample", pa.int64())]
    cols += [(c, pa.float64()) for c in spec.input_columns]
    cols += [(m, pa.float64()) for m in spec.metrics]
    cols += [(f"pass:{lim.metric}", pa.bool_()) for lim in spec.limits]
    cols += [("error", pa.string())]
    return pa.schema(cols, metadata={"thsa_sweep": spec.sha256})


def _rows_table(spec: SweepSpec, rows: list[dict]):
    import pyarrow as pa

    schema = results_schema(spec)
    return pa.table({f.name: pa.array([r[f.name] for r in rows], type=f.type) for f in schema}, schema=schema)


def chunk_ranges(spec: SweepSpec) -> list[range]:
    n, c = spec.total_runs, spec.chunk_runs
    return [range(a, min(a + c, n)) for a in range(0, n, c)]


def _chunk_path(folder: Path, c: int) -> Path:
    return folder / "runs" / f"chunk-{c:06d}.parquet"


def _write_chunk(folder: Path, c: int, table) -> None:
    import pyarrow.parquet as pq

    target = _chunk_path(folder, c)
    tmp = target.with_name(f".{target.name}.{os.getpid()}.tmp")
    try:
        pq.write_table(table, tmp)
        with open(tmp, "rb") as f:
            os.fsync(f.fileno())
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)


def _chunk_ok(path: Path, rng: range, sha: str) -> bool:
    import pyarrow.parquet as pq

    try:
        meta = pq.read_metadata(path)
        schema = pq.read_schema(path)
    except Exception:  # noqa: BLE001 - any unreadable file is rerun
        return False
    return (meta.num_rows == len(rng) and (schema.metadata or {}).get(b"thsa_sweep", b"").decode() == sha)


def read_results(folder: str | Path):
    """The results table of a sweep folder (every chunk on disk), sorted by run index.

    Raises
    ------
    SweepError
        When a run appears twice (never written so by :func:`run_sweep`).
    """
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    folder = Path(folder)
    parts = sorted(p for p in (folder / "runs").glob("chunk-*.parquet") if _CHUNK_RE.match(p.name))
    if not parts:
        raise SweepError(f"{folder}: no results (runs/chunk-*.parquet)")
    table = pa.concat_tables([pq.read_table(p) for p in parts])
    table = table.sort_by("run")
    runs = table.column("run")
    if len(pc.unique(runs)) != len(runs):
        raise SweepError(f"{folder}: a run appears twice in the table")
    return table


# ------------------------------------------------------------------ folder
def _manifest(spec: SweepSpec) -> dict:
    return {"format": FORMAT, "name": spec.name, "spec": spec.source, "spec_sha256": spec.sha256,
            "total_runs": spec.total_runs, "chunk_runs": spec.chunk_runs, "chunks": len(chunk_ranges(spec))}


def prepare_folder(spec: SweepSpec, out: str | Path, *, force: bool = False, command: str = "thsa sweep") -> Path:
    """Create ``out`` for ``spec`` or check that it holds the same sweep (resume); returns its path.

    A folder of another sweep (or another thsa output) is refused unless
    ``force``, which removes only what thsa wrote there; a folder thsa did not
    write is always refused.
    """
    from ..report.build import MARKER, check_output_folder

    inputs = [spec.source, *spec.design_paths, *(s for s in spec.scenario_sources if s.endswith(".toml"))]
    if spec.params_path:
        inputs.append(spec.params_path)
    folder = check_output_folder(out, force=False, inputs=inputs)
    manifest_path = folder / "sweep.json"
    if folder.exists() and any(folder.iterdir()):
        try:
            old = json.loads(manifest_path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            old = None
        same = isinstance(old, dict) and old.get("spec_sha256") == spec.sha256 and \
            old.get("chunk_runs") == spec.chunk_runs
        if not same:
            if not force:
                what = "a sweep of another spec (or other chunking)" if old else "another thsa output"
                raise OutputError(str(out), f"holds {what}; give a new folder, or --force to discard those results")
            for entry in list(folder.iterdir()):  # the marker says thsa wrote all of it
                if entry.name == MARKER:
                    continue
                shutil.rmtree(entry) if entry.is_dir() and not entry.is_symlink() else entry.unlink()
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "runs").mkdir(exist_ok=True)
    for stale in (folder / "runs").glob(".chunk-*.tmp"):  # a write cut by a kill
        stale.unlink(missing_ok=True)
    if not (folder / MARKER).exists():
        (folder / MARKER).write_text(json.dumps({"written_by": "thsa-control", "command": command}) + "\n",
                                     encoding="utf-8")
    if not manifest_path.exists():
        tmp = manifest_path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(_manifest(spec), indent=2) + "\n", encoding="utf-8")
        os.replace(tmp, manifest_path)
        try:
            shutil.copyfile(spec.source, folder / "spec.toml")
        except OSError:
            pass
    return folder


def _done_chunks(spec: SweepSpec, folder: Path) -> set[int]:
    ranges = chunk_ranges(spec)
    done = set()
    for p in (folder / "runs").glob("chunk-*.parquet"):
        m = _CHUNK_RE.match(p.name)
        if not m:
            continue
        c = int(m.group(1))
        if c < len(ranges) and _chunk_ok(p, ranges[c], spec.sha256):
            done.add(c)
        else:
            p.unlink(missing_ok=True)  # ours (runs/chunk-*), incomplete or of an older layout: rerun
    return done


# ------------------------------------------------------------------ the run
class SweepRun:
    """What :func:`run_sweep` did: counts and timings (for the report and the bench)."""

    def __init__(self, total: int, resumed: int):
        self.total = total
        self.resumed = resumed  # runs already on disk at the start
        self.simulated = 0
        self.wall_s = 0.0
        self.compute_s = 0.0
        self.workers = 0
        self.address = ""
        self.completions: list[tuple[float, int, float]] = []  # per chunk: (s since the tasks were sent, runs, CPU s)
        self.task_cpu_s = 0.0  # CPU seconds of the tasks' threads (the simulations and their metrics)
        self.worker_cpu_s = 0.0  # CPU seconds of the worker processes meanwhile (Dask's own threads included)
        self.task_wall_s = 0.0
        self.client_cpu_s = 0.0  # CPU seconds of this process meanwhile (scheduler of a local cluster, Parquet)

    def steady_rate(self) -> float:
        """Runs per second after each worker's first chunk (its start-up: imports, plant, library) [1/s]."""
        k = max(self.workers, 1)
        if len(self.completions) <= k:
            return math.nan
        t0 = self.completions[k - 1][0]
        n = sum(c[1] for c in self.completions[k:])
        return n / (self.completions[-1][0] - t0) if self.completions[-1][0] > t0 else math.nan

    def steady_cpu_per_run(self) -> float:
        """Workers' CPU seconds per run after each worker's first chunk (what a dedicated core spends) [s]."""
        rest = self.completions[max(self.workers, 1):]
        n = sum(c[1] for c in rest)
        return sum(c[2] for c in rest) / n if n else math.nan


def _warm_up(spec: SweepSpec) -> tuple:
    """Simulate the first run of each plant here (compile once, fail early); the libraries' bytes to ship."""
    from ..sim.codegen import library_files
    from .metrics import compute_metrics

    seen, libraries = set(), []
    runs = spec.run_specs(range(spec.total_runs)[::max(spec.runs_per_point * spec.grid_points, 1)])
    for rs in runs:
        design, scenario, _ = run_inputs(spec, rs)
        key = (spec.plant_effects(scenario), bool(scenario.faults or scenario.monitors is not None))
        if key in seen:
            continue
        seen.add(key)
        result, _, t_fault = _simulate_one(spec, rs)
        if result is None:
            continue  # a failing run is a result of the sweep, not an error of it
        compute_metrics(result, design, spec.metrics, fault_time=t_fault)  # names every missing signal
        path = result.info.get("compile", {}).get("path", "")
        files = library_files(path) if path else {}
        if files and files not in libraries:
            libraries.append(files)
    return tuple(libraries)


class _Terminate(BaseException):
    pass


def local_cores() -> int:
    """Cores this process may run on (the affinity mask; ``os.cpu_count()`` where there is none)."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def scheduler_address(file: str | Path, timeout: float | None = None, exited=None) -> str:
    """The address a Dask scheduler wrote to its scheduler file (``dask scheduler --scheduler-file FILE``).

    The scheduler creates the file before it writes it, and a batch job may start the client before the scheduler
    job runs: a missing, empty or partly written file is waited on until ``timeout`` (default
    :data:`CONNECT_TIMEOUT_S`), then a :class:`SweepError` names the file and what it held.  Dask's own
    ``Client(scheduler_file=...)`` waits for a missing file without end and gives up on a partial one after 0.1 s
    with an unbound-variable error (distributed 2026.8).  ``exited``: a callable that returns the scheduler
    process's exit code once it has ended (``subprocess.Popen.poll``), for a scheduler started by the caller."""
    file = Path(file)
    timeout = CONNECT_TIMEOUT_S if timeout is None else timeout
    deadline = time.monotonic() + timeout
    seen = "no file"
    while True:
        try:
            text = file.read_text()
            address = json.loads(text)["address"]
            if isinstance(address, str) and address:
                return address
            seen = f"'address' = {address!r}"
        except FileNotFoundError:
            seen = "no file"
        except UnicodeDecodeError:
            seen = "no text (not UTF-8)"
        except json.JSONDecodeError:
            seen = "an empty file" if not text.strip() else f"no JSON ({len(text)} bytes)"
        except (KeyError, TypeError):
            seen = "JSON without 'address'"
        except OSError as exc:
            raise SweepError(f"--scheduler-file {file}: cannot be read ({exc.strerror or exc})") from None
        code = exited() if exited is not None else None
        if code is not None:
            raise SweepError(f"--scheduler-file {file}: the Dask scheduler exited with code {code} before writing "
                             f"its address ({seen})")
        if time.monotonic() >= deadline:
            raise SweepError(f"--scheduler-file {file}: no scheduler address within {timeout:g} s ({seen}; a "
                             "scheduler started with 'dask scheduler --scheduler-file FILE' writes it)")
        time.sleep(0.05)


def _connect(scheduler: str | None, workers: int | None, given: str | None = None):
    """``(client, cluster or None)``; SweepError within ``CONNECT_TIMEOUT_S`` when unreachable (``given``: what
    the user gave, where it was not the address itself)."""
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT_S, set_as_default=False)
        except (OSError, TimeoutError, ValueError) as exc:
            raise SweepError(f"{given or '--scheduler ' + scheduler}: cannot reach the Dask scheduler within "
                             f"{CONNECT_TIMEOUT_S:g} s ({str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__})") from None
        return client, None
    import dask

    n = workers or local_cores()
    # Dask's nannies set MALLOC_TRIM_THRESHOLD_=65536 in their workers: glibc then hands every freed
    # block back to the OS, and each run's arrays fault their pages in again (about 20 % more CPU per run,
    # bench/bench_sweep.py); the local workers keep glibc's own adaptive threshold
    environ = {k: v for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()
               if k != "MALLOC_TRIM_THRESHOLD_"}
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ}):
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.ERROR)
    return Client(cluster, set_as_default=False), cluster


def _quiet_at_shutdown() -> None:
    """Run on our own local cluster's workers before it closes: a worker whose heartbeat meets the scheduler already
    closed logs "Failed to communicate with scheduler during heartbeat" with a traceback at ERROR (measured once in
    a suite run, after the sweep had written every chunk and exited 0: stderr held a traceback).  The results are on
    disk by then; a user's own cluster's workers are not touched."""
    logging.getLogger("distributed").setLevel(logging.CRITICAL)


def _fmt_s(s: float) -> str:
    if not math.isfinite(s):
        return "?"
    return f"{s:.0f} s" if s < 120 else f"{s / 60:.1f} min" if s < 7200 else f"{s / 3600:.1f} h"


def run_sweep(spec: SweepSpec, out: str | Path, *, scheduler: str | None = None, workers: int | None = None,
              force: bool = False, progress=None, command: str = "thsa sweep",
              scheduler_file: str | Path | None = None) -> SweepRun:
    """Run (or resume) ``spec`` into the folder ``out``; see the module docstring.

    Parameters
    ----------
    spec : SweepSpec
    out : path
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``); None: a local cluster.
    workers : int, optional
        Processes of the local cluster (default: the machine's cores).
    scheduler_file : path, optional
        The file a Dask scheduler writes its address to (:func:`scheduler_address`), instead of ``scheduler``.
    force : bool
        Discard the results of another sweep in ``out`` (only what thsa wrote).
    progress : thsa_control.progress.Progress, optional
        Done / total, rate and ETA on its stream.

    Raises
    ------
    SweepError
        Scheduler unreachable, a chunk that failed on every retry.
    OutputError
        ``out`` may not be used.
    """
    if sum(bool(x) for x in (scheduler, scheduler_file, workers)) > 1:
        raise SweepError("give one of --scheduler, --scheduler-file or --workers (a cluster has its own workers)")
    folder = prepare_folder(spec, out, force=force, command=command)
    ranges = chunk_ranges(spec)
    done = _done_chunks(spec, folder)
    pending = [c for c in range(len(ranges)) if c not in done]
    stats = SweepRun(spec.total_runs, sum(len(ranges[c]) for c in done))
    t_start = time.perf_counter()
    if progress is not None and done:
        progress.phase(f"resuming: {stats.resumed} of {spec.total_runs} runs already in {folder / 'runs'}")
    if not pending:
        stats.wall_s = time.perf_counter() - t_start
        return stats

    # SIGTERM/SIGHUP end the sweep like Ctrl-C: the cluster is shut down, finished chunks stay on disk
    previous = {}
    if threading.current_thread() is threading.main_thread():
        def _handler(signum, frame):
            raise _Terminate(signum)
        for sig in (signal.SIGTERM, getattr(signal, "SIGHUP", None)):
            if sig is not None:
                previous[sig] = signal.signal(sig, _handler)
    client = cluster = None
    try:
        if progress is not None:
            progress.phase(f"connecting to {scheduler}" if scheduler else
                           f"reading the scheduler's address from {scheduler_file}" if scheduler_file else
                           f"starting a local Dask cluster of {workers or local_cores()} worker process(es)")
        given = None
        if scheduler_file:
            scheduler = scheduler_address(scheduler_file)
            given = f"--scheduler-file {scheduler_file} (address {scheduler})"
            if progress is not None:
                progress.phase(f"connecting to {scheduler}")
        client, cluster = _connect(scheduler, workers, given)  # first: an unreachable scheduler fails within seconds
        if progress is not None:
            progress.phase("compiling the model and checking the metrics on the first run of each plant")
        libraries = _warm_up(spec)
        samples, grid = spec.sample_matrix(), spec.grid_matrix()
        stats.address = client.scheduler.address
        stats.workers = len(client.scheduler_info(n_workers=-1).get("workers", {})) if scheduler else \
            (workers or local_cores())
        from distributed import as_completed
        from distributed.scheduler import KilledWorker

        spec_f = client.scatter(spec, broadcast=True, hash=False)
        libs_f = client.scatter(libraries, broadcast=True, hash=False)
        futures = {}
        for c in pending:
            f = client.submit(_task, spec_f, spec.run_specs(ranges[c], samples, grid), libs_f,
                              key=f"thsa-sweep-{spec.sha256[:12]}-chunk-{c:06d}-{os.getpid()}-{t_start:.0f}",
                              pure=False)
            futures[f] = c
        n_done = stats.resumed
        t0, c0 = time.perf_counter(), time.process_time()
        for fut in as_completed(list(futures), loop=client.loop):
            c = futures[fut]
            if c in done:  # never twice
                continue
            try:
                rows, cpu_s, proc_s, wall_s = fut.result()
            except ImportError as exc:  # a cluster whose workers lack the package
                raise SweepError(f"the Dask workers cannot import what a sweep needs ({exc}); install thsa-control "
                                 "(the same version) in the workers' environment") from None
            except KilledWorker as exc:  # its workers kept dying (allowed-failures retries)
                raise SweepError(f"chunk {c} (runs {ranges[c].start}..{ranges[c].stop - 1}) killed every worker "
                                 f"that ran it ({str(exc).strip()[:300]}); the finished chunks are kept, rerun the "
                                 "same command to resume") from None
            _write_chunk(folder, c, _rows_table(spec, rows))
            done.add(c)
            n_done += len(rows)
            stats.simulated += len(rows)
            stats.completions.append((time.perf_counter() - t0, len(rows), cpu_s))
            stats.task_cpu_s += cpu_s
            stats.worker_cpu_s += proc_s
            stats.task_wall_s += wall_s
            fut.release()
            if progress is not None:
                el = time.perf_counter() - t0
                rate = stats.simulated / el if el > 0 else math.nan
                eta = (spec.total_runs - n_done) / rate if rate > 0 else math.inf
                progress.step(n_done, spec.total_runs, f"runs, {rate:.1f} runs/s, ETA {_fmt_s(eta)}")
        stats.compute_s = time.perf_counter() - t0
        stats.client_cpu_s = time.process_time() - c0
        if cluster is not None:  # our local cluster, every chunk on disk (a user's scheduler: cluster is None)
            try:
                client.run(_quiet_at_shutdown)
            except Exception:  # noqa: BLE001, S110 - about to close; the results are on disk
                pass
    except _Terminate as exc:
        signum = exc.args[0]
        if progress is not None:
            progress.phase(f"stopped by signal {signum}: {len(done)} of {len(ranges)} chunks on disk; "
                           "rerun the same command to resume")
        raise SystemExit(128 + signum) from None
    except KeyboardInterrupt:
        if progress is not None:
            progress.phase(f"interrupted: {len(done)} of {len(ranges)} chunks on disk; rerun the same command to "
                           "resume")
        raise
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
        for thing in (client, cluster):
            if thing is not None:
                try:
                    thing.close()
                except Exception:  # noqa: BLE001, S110 - shutting down; the results are on disk
                    pass
    stats.wall_s = time.perf_counter() - t_start
    if len(done) != len(ranges):
        raise SweepError(f"{len(ranges) - len(done)} chunk(s) missing after the sweep; rerun to resume")
    return stats
