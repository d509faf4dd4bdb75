"""What a sweep's table says: distributions, failure probabilities, worst cases, sensitivities (numbers only).

* **Distributions**: per metric and design x scenario group, the count of
  finite values, mean, standard deviation, 5/50/95 % quantiles, extremes;
  the values themselves for the report's histograms.
* **Failure probabilities**: per limit (and for "any limit"), the failures
  ``k`` of ``n`` runs and the exact (Clopper-Pearson) 95 % interval of the
  probability.  A run that failed to simulate, or whose metric is not a
  number, counts as a failure: a requirement is only met when shown.
* **Worst cases**: the runs with the largest (or, for a lower limit, the
  smallest) value of each limited metric, else of each metric, with their
  varied values; :func:`replay_command` is the ``thsa simulate`` command
  that runs one again alone.
* **Sensitivity**: Spearman's rank correlation of each varied quantity with
  each metric per group, ranked by magnitude; with ``saltelli`` sampling the
  first-order and total Sobol' indices (Saltelli 2010 and Jansen
  estimators, from the A, B, AB_i blocks, averaged over the grid points),
  ranked by the total index.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from .spec import SweepSpec

__all__ = [
    "FailureRate",
    "MetricSummary",
    "Sensitivity",
    "SweepAnalysis",
    "WorstCase",
    "analyse_sweep",
    "clopper_pearson",
    "replay_command",
    "sobol_indices",
]

CONFIDENCE = 0.95


def clopper_pearson(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Exact two-sided interval of a binomial probability from ``k`` failures in ``n`` trials.

    >>> lo, hi = clopper_pearson(0, 30)
    >>> lo, round(hi, 4)
    (0.0, 0.1157)
    """
    if n <= 0:
        return (0.0, 1.0)
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


@dataclass(frozen=True)
class MetricSummary:
    metric: str
    group: str
    n: int
    finite: int
    mean: float
    sd: float
    p05: float
    p50: float
    p95: float
    min: float
    max: float
    values: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class FailureRate:
    requirement: str
    group: str
    failures: int
    runs: int

    @property
    def probability(self) -> float:
        return self.failures / self.runs if self.runs else math.nan

    @property
    def interval(self) -> tuple[float, float]:
        return clopper_pearson(self.failures, self.runs)


@dataclass(frozen=True)
class WorstCase:
    metric: str
    rank: int
    run: int
    design: str
    scenario: str
    value: float
    inputs: dict
    error: str


@dataclass(frozen=True)
class Sensitivity:
    metric: str
    group: str
    input: str
    spearman: float
    p_value: float
    first_order: float = math.nan  # Sobol' S1 (saltelli sampling)
    total: float = math.nan  # Sobol' ST


@dataclass(frozen=True)
class SweepAnalysis:
    spec: dict
    runs: int
    failed_runs: int
    summaries: tuple[MetricSummary, ...]
    failures: tuple[FailureRate, ...]
    worst: tuple[WorstCase, ...]
    sensitivity: tuple[Sensitivity, ...]
    errors: tuple[tuple[int, str], ...]  # first failed runs (run, error)
    inputs: dict = field(default_factory=dict, repr=False)  # varied quantity -> values, one per run (run order)
    groups: np.ndarray = field(default_factory=lambda: np.zeros(0, str), repr=False)  # "design / scenario" per run

    def to_dict(self) -> dict:
        """JSON-ready (non-finite numbers as strings)."""
        def num(x):
            return float(x) if math.isfinite(x) else str(x)

        return {
            "spec": self.spec, "runs": self.runs, "failed_runs": self.failed_runs, "confidence": CONFIDENCE,
            "distributions": [{"metric": s.metric, "group": s.group, "n": s.n, "finite": s.finite,
                               **{k: num(getattr(s, k)) for k in ("mean", "sd", "p05", "p50", "p95", "min", "max")}}
                              for s in self.summaries],
            "failure_probabilities": [{"requirement": f.requirement, "group": f.group, "failures": f.failures,
                                       "runs": f.runs, "probability": num(f.probability),
                                       "clopper_pearson_95": [num(f.interval[0]), num(f.interval[1])]}
                                      for f in self.failures],
            "worst_cases": [{"metric": w.metric, "rank": w.rank, "run": w.run, "design": w.design,
                             "scenario": w.scenario, "value": num(w.value), "inputs": {k: num(v) for k, v in w.inputs.items()},
                             "error": w.error} for w in self.worst],
            "sensitivity": [{"metric": s.metric, "group": s.group, "input": s.input, "spearman": num(s.spearman),
                             "p_value": num(s.p_value), "sobol_first_order": num(s.first_order),
                             "sobol_total": num(s.total)} for s in self.sensitivity],
            "errors": [{"run": r, "error": e} for r, e in self.errors],
        }


def sobol_indices(fA: np.ndarray, fB: np.ndarray, fAB: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """First-order (Saltelli 2010) and total (Jansen) Sobol' indices from the A, B and AB_i outputs."""
    var = np.var(np.concatenate([fA, fB]), ddof=1)
    if not var > 0:
        return np.full(len(fAB), math.nan), np.full(len(fAB), math.nan)
    s1 = np.array([np.mean(fB * (f - fA)) / var for f in fAB])
    st = np.array([0.5 * np.mean((fA - f) ** 2) / var for f in fAB])
    return s1, st


def _col(table, name) -> np.ndarray:
    return np.asarray(table.column(name).to_numpy(zero_copy_only=False))


def analyse_sweep(spec: SweepSpec, table, *, worst_n: int = 3) -> SweepAnalysis:
    """Analyse the results table (``engine.read_results``) of ``spec``; see the module docstring."""
    n = table.num_rows
    designs, scenarios = _col(table, "design").astype(str), _col(table, "scenario").astype(str)
    errors = _col(table, "error").astype(str)
    runs = _col(table, "run").astype(int)
    failed = errors != ""
    groups = [("all", np.ones(n, bool))]
    pairs = sorted(set(zip(designs, scenarios)), key=lambda p: (list(designs).index(p[0]), list(scenarios).index(p[1])))
    if len(pairs) > 1:
        groups += [(f"{d} / {s}", (designs == d) & (scenarios == s)) for d, s in pairs]

    summaries = []
    for m in spec.metrics:
        v = _col(table, m).astype(float)
        for g, mask in groups:
            x = v[mask]
            f = x[np.isfinite(x)]
            q = np.quantile(f, [0.05, 0.5, 0.95]) if f.size else [math.nan] * 3
            summaries.append(MetricSummary(m, g, int(mask.sum()), int(f.size),
                                           float(np.mean(f)) if f.size else math.nan,
                                           float(np.std(f, ddof=1)) if f.size > 1 else math.nan,
                                           float(q[0]), float(q[1]), float(q[2]),
                                           float(np.min(f)) if f.size else math.nan,
                                           float(np.max(f)) if f.size else math.nan, x))

    failures = []
    any_fail = np.zeros(n, bool) | failed
    for lim in spec.limits:
        ok = _col(table, f"pass:{lim.metric}").astype(bool) & ~failed
        any_fail |= ~ok
        for g, mask in groups:
            failures.append(FailureRate(lim.describe(), g, int((~ok & mask).sum()), int(mask.sum())))
    for g, mask in groups:
        failures.append(FailureRate("any requirement" if spec.limits else "run fails to simulate", g,
                                    int((any_fail & mask).sum()), int(mask.sum())))

    inputs = {c: _col(table, c).astype(float) for c in spec.input_columns}
    worst = []
    limited = {lim.metric: lim for lim in spec.limits}
    for m in (list(limited) or list(spec.metrics)):
        v = _col(table, m).astype(float)
        lim = limited.get(m)
        low = lim is not None and lim.max == math.inf  # a lower limit: the smallest values are the worst
        ok = np.flatnonzero(~np.isnan(v))  # inf (e.g. no detection) is a value, and a bad one
        order = ok[np.argsort(v[ok] if low else -v[ok], kind="stable")]
        if lim is not None:  # runs without a value (failed) first: they are failures
            order = np.concatenate([np.flatnonzero(np.isnan(v)), order])
        for rank, i in enumerate(order[:worst_n], 1):
            worst.append(WorstCase(m, rank, int(runs[i]), str(designs[i]), str(scenarios[i]), float(v[i]),
                                   {c: float(inputs[c][i]) for c in inputs}, str(errors[i])))

    sens = []
    group_masks = [(f"{d} / {s}", (designs == d) & (scenarios == s)) for d, s in pairs]
    for m in spec.metrics:
        v = _col(table, m).astype(float)
        for g, mask in group_masks:
            s1 = st = {}
            if spec.method == "saltelli":
                s1, st = _saltelli(spec, table, v, mask)
            for c, x in inputs.items():
                ok = mask & np.isfinite(v) & np.isfinite(x)
                if ok.sum() < 3 or np.ptp(x[ok]) == 0 or np.ptp(v[ok]) == 0:
                    rho, p = math.nan, math.nan
                else:
                    r = stats.spearmanr(x[ok], v[ok])
                    rho, p = float(r.statistic), float(r.pvalue)
                sens.append(Sensitivity(m, g, c, rho, p, s1.get(c, math.nan), st.get(c, math.nan)))
    order = {m: k for k, m in enumerate(spec.metrics)}

    def strength(s):  # the total Sobol' index where computed, else |rank correlation|; nan last
        x = s.total if math.isfinite(s.total) else abs(s.spearman)
        return -x if math.isfinite(x) else 1.0

    sens.sort(key=lambda s: (order[s.metric], s.group, strength(s)))
    errs = tuple((int(r), str(e)) for r, e in zip(runs[failed][:20], errors[failed][:20]))
    return SweepAnalysis(spec.describe(), n, int(failed.sum()), tuple(summaries), tuple(failures), tuple(worst),
                         tuple(sens), errs, inputs, np.char.add(np.char.add(designs, " / "), scenarios))


def _saltelli(spec: SweepSpec, table, v: np.ndarray, mask: np.ndarray) -> tuple[dict, dict]:
    """Sobol' indices of the random variables in one design x scenario group (every grid point pooled)."""
    rv = spec.random_variables
    N, d = spec.samples, len(rv)
    sample = _col(table, "sample").astype(int)
    grid = _col(table, "grid").astype(int)
    s1s, sts = [], []
    for g in np.unique(grid[mask]):
        sel = mask & (grid == g)
        if sel.sum() != N * (d + 2):
            continue  # an incomplete block (a sweep read before it finished)
        f = np.full(N * (d + 2), math.nan)
        f[sample[sel]] = v[sel]
        if not np.all(np.isfinite(f)):
            continue
        blocks = f.reshape(d + 2, N)
        s1, st = sobol_indices(blocks[0], blocks[1], list(blocks[2:]))
        s1s.append(s1)
        sts.append(st)
    if not s1s:
        return {}, {}
    s1, st = np.mean(s1s, axis=0), np.mean(sts, axis=0)
    return ({x.name: float(a) for x, a in zip(rv, s1)}, {x.name: float(b) for x, b in zip(rv, st)})


def replay_command(spec: SweepSpec, run: int, scenario_file: str, params_file: str) -> str:
    """The ``thsa simulate`` command that runs sweep run ``run`` alone (its scenario and parameters in the files)."""
    from .engine import run_inputs

    rs, = spec.run_specs([run])
    _, scenario, _ = run_inputs(spec, rs)
    effects = spec.plant_effects(scenario)
    parts = ["thsa simulate", f"--scenario {scenario_file}", f"--level {spec.level}"]
    if effects:
        parts.append("--effects " + " ".join(effects))
    parts += [f"--design {spec.design_paths[rs.design]}", f"--params {params_file}",
              f"--output-period {spec.output_period:g}", f"--out replay_run_{run}"]
    return " ".join(parts)
