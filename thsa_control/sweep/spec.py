"""The sweep description (TOML): what to run, what varies, what to keep; validated, every error naming its key.

Example (``examples/sweeps/`` has complete ones)::

    name = "robustness"
    seed = 20261124                 # the same seed gives the same table, whatever the workers
    level = "D"
    effects = ["temperature_friction"]
    designs = ["nominal", "cold"]   # designs/NAME.toml of the checkout, or paths (relative to this file)
    scenarios = ["cold_ramp", "low_speed"]   # named scenarios, scenario TOML files, or inline tables
    params = "my_actuator.toml"     # optional: parameter file over the embedded actuator
    output_period_s = 1e-3          # optional

    [sampling]
    method = "lhs"                  # random | lhs | sobol | saltelli | grid
    samples = 64                    # points per design x scenario x grid point (saltelli: base points)
    chunk_runs = 16                 # runs per task (optional; default: total / 400, within 16 .. 256)

    [parameters."gear.efficiency"]  # any parameter of the actuator
    distribution = "uniform"        # uniform, loguniform [min, max]; normal (mean, sd);
    min = 0.90                      # truncnormal (mean, sd, min, max); lognormal (median, sigma_log);
    max = 0.98                      # grid (values); "assumed": the range of sim/assumptions.py

    [conditions.temperature]        # scenario temperature [degC]; also conditions.load_scale [-]
    distribution = "grid"
    values = [-55, -30, 25, 70]

    [[faults]]                      # replaces the scenarios' faults (a fault campaign)
    kind = "surface_jam"
    time = { distribution = "uniform", min = 2.0, max = 4.5 }

    [monitors]                      # optional: MonitorSettings fields for every run
    discrepancy_threshold = 0.5

    [metrics]
    keep = ["current_peak_A", "first_detection_s"]   # sweep/metrics.py (default: DEFAULT_METRICS)

    [limits.current_peak_A]         # a requirement: the failure probability is reported
    max = 15.0

Total runs = designs x scenarios x grid points x samples (saltelli: samples x (d + 2)).
"""

from __future__ import annotations

import difflib
import hashlib
import json
import math
import tomllib
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from ..errors import ThsaError
from .metrics import DEFAULT_METRICS, FAULT_METRICS, check_metric_name
from .sampling import DISTRIBUTIONS, SAMPLING_METHODS, Distribution, unit_samples

__all__ = ["Limit", "RunSpec", "SweepSpec", "SweepSpecError", "Variable", "load_spec", "parse_spec"]

_TOP = {"name", "description", "seed", "level", "effects", "designs", "scenarios", "params", "output_period_s",
        "sampling", "parameters", "conditions", "faults", "monitors", "metrics", "limits"}
_CONDITIONS = {"temperature": "temperature_C", "load_scale": "load_scale"}
#: Runs per task when the spec does not say: about 400 chunks, within these bounds (small chunks show
#: progress and balance the workers; large ones keep the client, which writes one Parquet file per chunk,
#: off the critical path of a big campaign: bench/bench_sweep.py, docs/sweep_notes.md).
CHUNKS_TARGET, CHUNK_RUNS_MIN, CHUNK_RUNS_MAX = 400, 16, 256


class SweepSpecError(ThsaError, ValueError):
    """The sweep description is wrong; the message names the file and the key."""

    def __init__(self, source: str, key: str, message: str):
        self.source, self.key = source, key
        super().__init__(f"sweep {source}: {key}: {message}")


@dataclass(frozen=True)
class Variable:
    """A quantity that varies: ``kind`` parameter, temperature, load_scale or fault_time (``index``: which fault)."""

    name: str  # column of the results table
    kind: str
    dist: Distribution
    index: int = 0


@dataclass(frozen=True)
class Limit:
    """A requirement on a metric: fails when the value is outside [min, max] or not a number."""

    metric: str
    min: float = -math.inf
    max: float = math.inf

    def passed(self, value: float) -> bool:
        return bool(self.min <= value <= self.max)

    def describe(self) -> str:
        parts = ([f">= {self.min:g}"] if self.min > -math.inf else []) + ([f"<= {self.max:g}"] if self.max < math.inf else [])
        return f"{self.metric} {' and '.join(parts)}"


@dataclass(frozen=True)
class RunSpec:
    """One run: its index, which design / scenario / grid point / sample, and the varied values."""

    run: int
    design: int
    scenario: int
    grid: int
    sample: int
    values: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class SweepSpec:
    """A validated sweep (see the module docstring); ``sha256`` identifies it with its input files."""

    source: str
    name: str
    description: str
    seed: int
    level: str
    effects: tuple[str, ...]
    designs: tuple  # of (label, Design)
    design_paths: tuple[str, ...]
    scenarios: tuple  # of Scenario (faults and monitors of the campaign applied)
    scenario_sources: tuple[str, ...]  # name or absolute path given
    params: object  # ParameterSet
    params_path: str
    output_period: float
    method: str
    samples: int
    chunk_runs: int
    variables: tuple[Variable, ...]
    faults: tuple[dict, ...]  # FaultEvent fields; "time" may be a Variable name
    metrics: tuple[str, ...]
    limits: tuple[Limit, ...]
    sha256: str

    # ---- the plan
    @property
    def random_variables(self) -> tuple[Variable, ...]:
        return tuple(v for v in self.variables if not v.dist.is_grid)

    @property
    def grid_variables(self) -> tuple[Variable, ...]:
        return tuple(v for v in self.variables if v.dist.is_grid)

    @property
    def grid_points(self) -> int:
        return int(np.prod([len(v.dist.values) for v in self.grid_variables])) if self.grid_variables else 1

    @property
    def runs_per_point(self) -> int:
        """Samples per design x scenario x grid point."""
        if self.method == "grid":
            return 1
        if self.method == "saltelli":
            return self.samples * (len(self.random_variables) + 2)
        return self.samples

    @property
    def total_runs(self) -> int:
        return len(self.designs) * len(self.scenarios) * self.grid_points * self.runs_per_point

    def sample_matrix(self) -> np.ndarray:
        """Values of the random variables, one row per sample (drawn from ``seed`` on the client)."""
        rv = self.random_variables
        U = unit_samples(self.method, self.samples, len(rv), seed=self.seed) if self.method != "grid" \
            else np.zeros((1, 0))
        return np.column_stack([v.dist.ppf(U[:, k]) for k, v in enumerate(rv)]) if rv else np.zeros((len(U), 0))

    def grid_matrix(self) -> np.ndarray:
        """Values of the grid variables, one row per grid point (the first grid varies slowest)."""
        gv = self.grid_variables
        if not gv:
            return np.zeros((1, 0))
        mesh = np.meshgrid(*[np.asarray(v.dist.values, float) for v in gv], indexing="ij")
        return np.column_stack([m.ravel() for m in mesh])

    def run_specs(self, runs, samples: np.ndarray | None = None, grid: np.ndarray | None = None) -> list[RunSpec]:
        """The :class:`RunSpec` of each run index in ``runs`` (pass the matrices to avoid redrawing them)."""
        S = self.sample_matrix() if samples is None else samples
        G = self.grid_matrix() if grid is None else grid
        n_s, n_g, n_c = self.runs_per_point, self.grid_points, len(self.scenarios)
        rv, gv = self.random_variables, self.grid_variables
        out = []
        for run in runs:
            run = int(run)
            j = run % n_s
            g = (run // n_s) % n_g
            c = (run // (n_s * n_g)) % n_c
            d = run // (n_s * n_g * n_c)
            vals = [(v.name, float(S[j, k])) for k, v in enumerate(rv)] + \
                   [(v.name, float(G[g, k])) for k, v in enumerate(gv)]
            out.append(RunSpec(run, d, c, g, j, tuple(vals)))
        return out

    @property
    def input_columns(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.random_variables + self.grid_variables)

    def plant_effects(self, scenario) -> tuple[str, ...]:
        """Effects of the plant that runs ``scenario``: the spec's, the scenario's and its faults' needs."""
        from ..sim.events import effects_for_faults

        out = list(self.effects)
        for e in tuple(scenario.required_effects) + effects_for_faults(scenario.faults):
            if e not in out:
                out.append(e)
        return tuple(out)

    def describe(self) -> dict:
        """Plain summary (JSON-ready) for the report."""
        timed = {v.index: v.dist.describe() for v in self.variables if v.kind == "fault_time"}
        return {"name": self.name, "description": self.description, "source": self.source, "seed": self.seed,
                "level": self.level, "effects": list(self.effects), "designs": list(self.design_paths),
                "scenarios": list(self.scenario_sources), "params": self.params_path or "embedded actuator",
                "sampling": self.method, "samples": self.samples, "grid_points": self.grid_points,
                "total_runs": self.total_runs, "chunk_runs": self.chunk_runs,
                "variables": [{"name": v.name, "kind": v.kind, "distribution": v.dist.describe()} for v in self.variables],
                "faults": [{k: (timed[i] if k == "time" and i in timed else
                                v if not isinstance(v, float) or math.isfinite(v) else str(v)) for k, v in f.items()}
                           for i, f in enumerate(self.faults)],
                "metrics": list(self.metrics), "limits": [lim.describe() for lim in self.limits],
                "spec_sha256": self.sha256}


# ---------------------------------------------------------------- parsing
def _num(src, key, value, *, positive=False, integer=False):
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise SweepSpecError(src, key, f"{value!r} is not a finite number")
    if integer and value != int(value):
        raise SweepSpecError(src, key, f"{value!r} is not a whole number")
    if positive and value <= 0:
        raise SweepSpecError(src, key, f"{value!r} must be > 0")
    return int(value) if integer else float(value)


def _table(src, key, value) -> dict:
    if not isinstance(value, dict):
        raise SweepSpecError(src, key, f"must be a table, not {type(value).__name__}")
    return value


def _unknown(src, where, table, allowed):
    extra = sorted(set(table) - set(allowed))
    if extra:
        close = difflib.get_close_matches(extra[0], list(allowed), n=1)
        raise SweepSpecError(src, f"{where}{extra[0]}", "unknown key" + (f" (did you mean {close[0]!r}?)" if close else "")
                             + f"; allowed: {', '.join(sorted(allowed))}")


def _distribution(src, key, table, assumed=None) -> Distribution:
    table = _table(src, key, table)
    kind = table.get("distribution")
    if kind == "assumed":
        if assumed is None:
            raise SweepSpecError(src, f"{key}.distribution", "'assumed' applies only to the parameters of "
                                 "sim/assumptions.py (loadpath.disk_spring_damping, noback.pawl_initial_clearance)")
        _unknown(src, f"{key}.", table, {"distribution"})
        return Distribution("uniform", low=assumed[0], high=assumed[1])
    if kind not in DISTRIBUTIONS:
        raise SweepSpecError(src, f"{key}.distribution", f"{kind!r} unknown; distributions are "
                             f"{', '.join(DISTRIBUTIONS)}, assumed")
    need = DISTRIBUTIONS[kind]
    _unknown(src, f"{key}.", table, {"distribution", *need})
    missing = [k for k in need if k not in table]
    if missing:
        raise SweepSpecError(src, f"{key}.{missing[0]}", f"missing (a {kind} distribution needs {', '.join(need)})")
    if kind == "grid":
        vals = table["values"]
        if not isinstance(vals, list) or not vals:
            raise SweepSpecError(src, f"{key}.values", "empty distribution: give a non-empty list of numbers")
        vals = tuple(_num(src, f"{key}.values", v) for v in vals)
        if len(set(vals)) != len(vals):
            raise SweepSpecError(src, f"{key}.values", "repeats a value")
        return Distribution("grid", values=vals)
    v = {k: _num(src, f"{key}.{k}", table[k]) for k in need}
    if "sd" in v and v["sd"] <= 0:
        raise SweepSpecError(src, f"{key}.sd", f"{v['sd']:g}: empty distribution, sd must be > 0")
    if "sigma_log" in v and v["sigma_log"] <= 0:
        raise SweepSpecError(src, f"{key}.sigma_log", f"{v['sigma_log']:g}: empty distribution, must be > 0")
    if "median" in v and v["median"] <= 0:
        raise SweepSpecError(src, f"{key}.median", f"{v['median']:g} must be > 0")
    if "min" in v and not v["min"] < v["max"]:
        raise SweepSpecError(src, f"{key}.max", f"empty distribution: min {v['min']:g} is not below max {v['max']:g}")
    if kind == "loguniform" and v["min"] <= 0:
        raise SweepSpecError(src, f"{key}.min", f"{v['min']:g}: a log-uniform distribution needs min > 0")
    return Distribution(kind, low=v.get("min", math.nan), high=v.get("max", math.nan), mean=v.get("mean", math.nan),
                        sd=v.get("sd", math.nan), median=v.get("median", math.nan), sigma_log=v.get("sigma_log", math.nan))


def _within(src, key, dist: Distribution, par) -> None:
    """The distribution's support must lie in the parameter's physical interval."""
    lo, hi = dist.support
    if par.integer and not dist.is_grid:
        raise SweepSpecError(src, key, f"{par.name} is a whole number: give a grid of values")
    ok_lo = par.physically_valid(lo) if math.isfinite(lo) else par.hard_min == -math.inf
    ok_hi = par.physically_valid(hi) if math.isfinite(hi) else par.hard_max == math.inf
    if dist.kind == "lognormal":
        ok_lo = par.hard_min <= 0.0
    if dist.is_grid:
        ok_lo = ok_hi = all(par.physically_valid(x) for x in dist.values) and \
            (not par.integer or all(x == round(x) for x in dist.values))
    if not (ok_lo and ok_hi):
        hint = " (use truncnormal to bound a normal)" if dist.kind == "normal" else ""
        raise SweepSpecError(src, key, f"{dist.describe()} reaches outside the physically valid values "
                             f"{par.valid} {par.unit} of {par.name}{hint}")


def _resolve(base: Path, text: str) -> Path:
    p = Path(text)
    return p if p.is_absolute() else (base / p)


def _designs(src, base, value):
    from ..loops.design import load_design, nominal_design_path

    if value is None:
        value = ["nominal"]
    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        raise SweepSpecError(src, "designs", "give a non-empty list of design names or files")
    out, paths = [], []
    for i, item in enumerate(value):
        if not isinstance(item, str):
            raise SweepSpecError(src, f"designs[{i}]", f"{item!r} is not a design name or path")
        if item.endswith(".toml"):
            path = _resolve(base, item)
        else:
            try:
                path = nominal_design_path().parent / f"{item}.toml"
            except ThsaError as exc:
                raise SweepSpecError(src, f"designs[{i}]", str(exc)) from None
        if not path.is_file():
            raise SweepSpecError(src, f"designs[{i}]", f"design {item!r} not found ({path})")
        try:
            design = load_design(path)
        except ThsaError as exc:
            raise SweepSpecError(src, f"designs[{i}]", str(exc)) from None
        out.append((design.name or path.stem, design))
        paths.append(str(path.resolve()))
    labels = [lab for lab, _ in out]
    if len(set(labels)) != len(labels):
        out = [(f"{lab}#{i}", d) for i, (lab, d) in enumerate(out)]
    return tuple(out), tuple(paths)


def _scenarios(src, base, value):
    from ..sim.scenarios import load_scenario_file, scenario_from_dict
    from ..tuning.validation import get_validation_scenario

    if isinstance(value, str):
        value = [value]
    if not isinstance(value, list) or not value:
        raise SweepSpecError(src, "scenarios", "give a non-empty list of scenario names, files or tables")
    out, sources = [], []
    for i, item in enumerate(value):
        key = f"scenarios[{i}]"
        try:
            if isinstance(item, dict):
                sc = scenario_from_dict(item, where=f"{src} {key}")
                sources.append(f"inline {sc.name}")
            elif isinstance(item, str) and item.endswith(".toml"):
                path = _resolve(base, item)
                sc = load_scenario_file(path)
                sources.append(str(path.resolve()))
            elif isinstance(item, str):
                sc = get_validation_scenario(item)
                sources.append(item)
            else:
                raise SweepSpecError(src, key, f"{item!r} is not a scenario name, file or table")
        except SweepSpecError:
            raise
        except ThsaError as exc:
            raise SweepSpecError(src, key, str(exc)) from None
        out.append(sc)
    names = [s.name for s in out]
    if len(set(names)) != len(names):
        raise SweepSpecError(src, "scenarios", f"names a scenario twice ({names})")
    return out, tuple(sources)


def _faults(src, table_list, variables):
    from ..sim.events import FaultEvent

    if not isinstance(table_list, list) or not all(isinstance(t, dict) for t in table_list) or not table_list:
        raise SweepSpecError(src, "faults", "must be a non-empty array of tables ([[faults]])")
    names = {f.name for f in fields(FaultEvent)}
    out = []
    for k, t in enumerate(table_list):
        key = f"faults[{k}]"
        _unknown(src, f"{key}.", t, names)
        if "kind" not in t or "time" not in t:
            raise SweepSpecError(src, key, "needs kind and time")
        ev = dict(t)
        if ev.get("end") == "inf":
            ev["end"] = math.inf
        if isinstance(ev["time"], dict):
            dist = _distribution(src, f"{key}.time", ev["time"])
            if dist.support[0] < 0:
                raise SweepSpecError(src, f"{key}.time", f"{dist.describe()} reaches negative times")
            name = "fault_time_s" if k == 0 else f"fault{k + 1}_time_s"
            variables.append(Variable(name, "fault_time", dist, k))
            ev["time"] = dist.support[0] if not dist.is_grid else dist.values[0]  # checked below, replaced per run
        try:
            FaultEvent(**ev)
        except (ThsaError, TypeError) as exc:
            raise SweepSpecError(src, key, str(exc)) from None
        out.append(ev)
    return tuple(out)


def parse_spec(doc: dict, *, source: str = "<dict>", base_dir: str | Path = ".") -> SweepSpec:
    """Validate a parsed sweep TOML and build a :class:`SweepSpec` (see the module docstring)."""
    from ..model import resolve_effects
    from ..model.params import default_parameters, load_parameters
    from ..sim.assumptions import ASSUMED_RANGES
    from ..sim.monitor_settings import MonitorSettings
    from ..sim.scenarios import TEMPERATURE_RANGE

    src = source
    base = Path(base_dir)
    _unknown(src, "", doc, _TOP)
    name = doc.get("name", Path(source).stem)
    if not isinstance(name, str) or not name.strip():
        raise SweepSpecError(src, "name", f"{name!r} must be a non-empty string")
    if "seed" not in doc:
        raise SweepSpecError(src, "seed", "missing (an integer: the same seed gives the same results)")
    seed = _num(src, "seed", doc["seed"], integer=True)
    if seed < 0:
        raise SweepSpecError(src, "seed", f"{seed} must be >= 0")
    level = str(doc.get("level", "A")).upper()
    effects = doc.get("effects", [])
    if not isinstance(effects, list) or not all(isinstance(e, str) for e in effects):
        raise SweepSpecError(src, "effects", "must be a list of effect names")
    try:
        resolve_effects(level, add=effects)
    except ThsaError as exc:
        raise SweepSpecError(src, "level/effects", str(exc)) from None
    params_path = ""
    params = default_parameters()
    if "params" in doc:
        if not isinstance(doc["params"], str):
            raise SweepSpecError(src, "params", "must be a file name")
        path = _resolve(base, doc["params"])
        try:
            params = load_parameters(path, base=params)
        except ThsaError as exc:
            raise SweepSpecError(src, "params", str(exc)) from None
        params_path = str(path.resolve())
    designs, design_paths = _designs(src, base, doc.get("designs"))
    for (label, d), p in zip(designs, design_paths):
        try:
            d.check_against(params)
        except ThsaError as exc:
            raise SweepSpecError(src, "designs", f"{label}: {exc}") from None
    scenarios, scenario_sources = _scenarios(src, base, doc.get("scenarios"))
    output_period = _num(src, "output_period_s", doc.get("output_period_s", 1e-3), positive=True)
    for label, d in designs:
        ratio = output_period / d.control_period
        if ratio < 1 - 1e-9 or abs(ratio - round(ratio)) > 1e-6 * ratio:
            raise SweepSpecError(src, "output_period_s", f"{output_period:g} s is not a whole multiple of design "
                                 f"{label}'s control period {d.control_period:g} s")

    sampling = _table(src, "sampling", doc.get("sampling", {}))
    _unknown(src, "sampling.", sampling, {"method", "samples", "chunk_runs"})
    method = sampling.get("method", "random")
    if method not in SAMPLING_METHODS:
        raise SweepSpecError(src, "sampling.method", f"{method!r} unknown; methods are {', '.join(SAMPLING_METHODS)}")
    samples = _num(src, "sampling.samples", sampling.get("samples", 1), positive=True, integer=True)
    chunk_runs = _num(src, "sampling.chunk_runs", sampling["chunk_runs"], positive=True, integer=True) \
        if "chunk_runs" in sampling else None

    variables: list[Variable] = []
    assumed = {a.parameter: a for a in ASSUMED_RANGES}
    for pname, table in _table(src, "parameters", doc.get("parameters", {})).items():
        key = f"parameters.{pname}"
        if pname not in params:
            close = difflib.get_close_matches(pname, list(params), n=3)
            raise SweepSpecError(src, key, "unknown parameter" + (f" (did you mean {', '.join(close)}?)" if close else
                                                                 "; see default_actuator.toml for the names"))
        span = None
        if pname in assumed:
            a = assumed[pname]
            span = (a.to_parameter(params, min(a.values)), a.to_parameter(params, max(a.values)))
        dist = _distribution(src, key, table, span)
        _within(src, key, dist, params[pname])
        variables.append(Variable(pname, "parameter", dist))
    for cname, table in _table(src, "conditions", doc.get("conditions", {})).items():
        key = f"conditions.{cname}"
        if cname not in _CONDITIONS:
            raise SweepSpecError(src, key, f"unknown condition; conditions are {', '.join(_CONDITIONS)}")
        dist = _distribution(src, key, table)
        lo, hi = dist.support
        if cname == "temperature" and not (TEMPERATURE_RANGE[0] <= lo and hi <= TEMPERATURE_RANGE[1]):
            raise SweepSpecError(src, key, f"{dist.describe()} reaches outside the model's temperature range "
                                 f"{TEMPERATURE_RANGE[0]:g}..{TEMPERATURE_RANGE[1]:g} degC")
        variables.append(Variable(_CONDITIONS[cname], cname, dist))

    faults: tuple[dict, ...] = ()
    if "faults" in doc:
        faults = _faults(src, doc["faults"], variables)
    monitors = None
    if "monitors" in doc:
        mt = _table(src, "monitors", doc["monitors"])
        _unknown(src, "monitors.", mt, {f.name for f in fields(MonitorSettings)})
        monitors = MonitorSettings(**mt)
        try:
            monitors.validate()
        except ValueError as exc:
            raise SweepSpecError(src, "monitors", str(exc)) from None
    if faults or monitors is not None:
        from ..sim.events import FaultEvent

        fixed = tuple(FaultEvent(**ev) for ev in faults)
        scenarios = [replace(s, faults=fixed if faults else s.faults,
                             monitors=monitors or s.monitors or MonitorSettings()) for s in scenarios]
        for s in scenarios:
            for v in variables:
                if v.kind == "fault_time" and v.dist.support[1] >= s.duration:
                    raise SweepSpecError(src, f"faults[{v.index}].time", f"{v.dist.describe()} reaches the end of "
                                         f"scenario {s.name} ({s.duration:g} s)")

    if method == "grid" and any(not v.dist.is_grid for v in variables):
        bad = next(v for v in variables if not v.dist.is_grid)
        raise SweepSpecError(src, "sampling.method", f"'grid' samples nothing, but {bad.name} has a "
                             f"{bad.dist.kind} distribution")
    if method == "saltelli" and not any(not v.dist.is_grid for v in variables):
        raise SweepSpecError(src, "sampling.method", "'saltelli' needs at least one random (non-grid) variable")

    mt = _table(src, "metrics", doc.get("metrics", {}))
    _unknown(src, "metrics.", mt, {"keep"})
    keep = mt.get("keep", list(DEFAULT_METRICS))
    if not isinstance(keep, list) or not keep:
        raise SweepSpecError(src, "metrics.keep", "give a non-empty list of metric names")
    metrics = []
    for i, m in enumerate(keep):
        try:
            metrics.append(check_metric_name(m))
        except ValueError as exc:
            raise SweepSpecError(src, f"metrics.keep[{i}]", str(exc)) from None
    for i, m in enumerate(metrics):
        if m in FAULT_METRICS and not any(s.faults for s in scenarios):
            raise SweepSpecError(src, f"metrics.keep[{i}]", f"{m} is timed from a run's first fault, and no scenario "
                                 "has one: add [[faults]] or a fault scenario (e.g. jam)")
    limits = []
    for mname, lt in _table(src, "limits", doc.get("limits", {})).items():
        key = f"limits.{mname}"
        try:
            check_metric_name(mname)
        except ValueError as exc:
            raise SweepSpecError(src, key, str(exc)) from None
        lt = _table(src, key, lt)
        _unknown(src, f"{key}.", lt, {"min", "max"})
        if not lt:
            raise SweepSpecError(src, key, "give min and/or max")
        lim = Limit(mname, _num(src, f"{key}.min", lt["min"]) if "min" in lt else -math.inf,
                    _num(src, f"{key}.max", lt["max"]) if "max" in lt else math.inf)
        if not lim.min <= lim.max:
            raise SweepSpecError(src, key, f"min {lim.min:g} is above max {lim.max:g}")
        limits.append(lim)
        if mname not in metrics:
            metrics.append(mname)
    seen = [v.name for v in variables]
    if len(set(seen)) != len(seen):
        raise SweepSpecError(src, "parameters", "a quantity is varied twice")

    # the identity of the sweep: its content and that of every file it reads
    h = hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode())
    for p in (*design_paths, *(s for s in scenario_sources if s.endswith(".toml")), *( [params_path] if params_path else [])):
        h.update(Path(p).read_bytes())
    spec = SweepSpec(source=src, name=name, description=str(doc.get("description", "")), seed=seed, level=level,
                     effects=tuple(effects), designs=designs, design_paths=design_paths, scenarios=tuple(scenarios),
                     scenario_sources=scenario_sources, params=params, params_path=params_path,
                     output_period=output_period, method=method, samples=samples if method != "grid" else 1,
                     chunk_runs=chunk_runs or CHUNK_RUNS_MIN, variables=tuple(variables), faults=faults,
                     metrics=tuple(metrics), limits=tuple(limits), sha256=h.hexdigest())
    if chunk_runs is None:
        spec = replace(spec, chunk_runs=min(CHUNK_RUNS_MAX, max(CHUNK_RUNS_MIN, -(-spec.total_runs // CHUNKS_TARGET))))
    return spec


def load_spec(path: str | Path) -> SweepSpec:
    """Read and validate a sweep TOML file; :class:`SweepSpecError` names the file and the key."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SweepSpecError(str(path), "file", "not found") from None
    except OSError as exc:
        raise SweepSpecError(str(path), "file", f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise SweepSpecError(str(path), "file", f"not UTF-8 text (byte {exc.start})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SweepSpecError(str(path), "file", f"not valid TOML: {exc}") from None
    return parse_spec(doc, source=str(path), base_dir=path.parent)
