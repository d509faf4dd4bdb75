"""Component identification from component-rig tables (issue 4, item 5).

The *component table*: a small CSV written by a component
rig (or by :func:`generate_component_table`), one header line of column names
preceded by ``#`` comment lines that carry its provenance, as in the NIST StRD
files.  It reads, validates, writes and generates such tables and fits the
effect library's component laws to them.  It never re-writes the physics: every
model value and every Jacobian comes from the casadi Functions of
:data:`thsa_control.model.laws.LAWS`, evaluated vectorised with
``law.function.map(n)`` and differentiated by casadi.  It imports numpy, scipy,
casadi and the package's ``errors``, ``params``, ``units`` and ``model.laws``;
never matplotlib.

The tables themselves (kinds, reading, writing, generating) are in
:mod:`thsa_control.fit.component_tables`; their public names are importable from here.

How the fit works
-----------------
Least squares of ``law(inputs, p) - measured`` over the free parameters with
``scipy.optimize.least_squares`` (trust-region reflective), the exact casadi
Jacobian, each parameter scaled by its initial magnitude, and the
:class:`~thsa_control.model.params.ParameterSet` bounds.  Standard errors come from
the Jacobian at the optimum, ``cov = s^2 (J^T J)^-1`` with
``s^2 = RSS / (n - k)``; confidence intervals use Student's t.

The load-path law is piecewise linear with a kink at ``|deflection| = b``: the
residual is not differentiable in the backlash wherever a data point sits on
the edge, and the cost has a local minimum between every two data points.  The
fit therefore *profiles* the backlash: for fixed ``b`` the law is linear in the
three stiffnesses, so they are solved exactly by bounded linear least squares
(design matrix = the casadi Jacobian); the profile cost ``S(b)`` is smooth
between consecutive data deflections, so it is evaluated once inside every such
interval (at most ``profile_points`` intervals) and refined with a bounded
scalar search in the three best intervals.  A final joint least-squares polish
from the profile optimum gives the covariance.  ``global_stage=True`` instead
runs scipy's differential evolution over all free parameters (log-scaled for
wide positive ranges), as the papers do, before the same polish; it works for
every kind.

Examples
--------
>>> import numpy as np
>>> from thsa_control.model.params import default_parameters
>>> p = default_parameters()
>>> table = generate_component_table("loadpath_stiffness", p, noise=50.0, rng=1)
>>> fit = fit_component(table, params=p)
>>> round(fit.values["loadpath.backlash"] * 1e3, 2), fit.n_data
(0.67, 61)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np
from scipy import optimize, stats

from thsa_control.errors import ParameterError
from thsa_control.model.laws import LAWS
from thsa_control.model.params import ParameterSet, default_parameters
from thsa_control.fit.component_tables import (  # noqa: F401 - re-exported
    DEFAULT_GRIDS,
    KINDS,
    MAX_ROWS_LISTED,
    ComponentKind,
    ComponentTable,
    Float1D,
    generate_component_table,
    read_component_table,
    _Model,
    write_component_table,
)

__all__ = [
    "ComponentKind",
    "KINDS",
    "DEFAULT_GRIDS",
    "ComponentTable",
    "ComponentFit",
    "read_component_table",
    "write_component_table",
    "generate_component_table",
    "fit_component",
    "format_component_fit",
]

#: Correlation above which two parameters are flagged as not identifiable together.
CORRELATION_LIMIT = 0.95


# ---------------------------------------------------------------- the result
@dataclass(frozen=True, eq=False)
class ComponentFit:
    """Result of :func:`fit_component` (lmfit style; the inputs are untouched).

    Parameters
    ----------
    kind : str
        Table kind.
    laws : tuple of str
        Laws fitted (names in :data:`~thsa_control.model.laws.LAWS`).
    source : str
        Table file, or ``<table>``.
    method : str
        What was run (local, profile, global stage).
    names : tuple of str
        Free parameters, in the order of :attr:`correlation`.
    values, stderr, init : dict of str to float
        Fitted value, standard error (1 sigma; NaN when not identifiable) and
        initial value of each free parameter [SI units of the parameter].
    units : dict of str to str
        Unit of each free parameter.
    held : dict of str to float
        Law parameters held at their value.
    correlation : ndarray
        Correlation matrix of the free parameters.
    n_data, n_free : int
    cost : float
        Residual sum of squares [output unit^2].
    rms_residual : float
        ``sqrt(cost / n_data)`` [N m or N].
    residual_std : float
        ``sqrt(cost / (n_data - n_free))``, the noise estimate [N m or N].
    aic, bic : float
        ``n ln(RSS/n) + 2k`` and ``n ln(RSS/n) + k ln n``.
    residuals : ndarray
        ``measured - model`` per row [N m or N].
    at_bound : tuple of str
        Free parameters at (within 1e-6 relative of) a bound.
    not_identifiable : tuple of str
        Parameters the data cannot determine (singular Jacobian direction).
    correlated_pairs : tuple of (str, str, float)
        Pairs with ``|correlation| > 0.95``: not identifiable together.
    nfev : int
        Model evaluations (all stages).
    success : bool
    message : str
    """

    kind: str
    laws: tuple[str, ...]
    source: str
    method: str
    names: tuple[str, ...]
    values: dict[str, float]
    stderr: dict[str, float]
    init: dict[str, float]
    units: dict[str, str]
    held: dict[str, float]
    correlation: np.ndarray
    n_data: int
    n_free: int
    cost: float
    rms_residual: float
    residual_std: float
    aic: float
    bic: float
    residuals: np.ndarray
    at_bound: tuple[str, ...]
    not_identifiable: tuple[str, ...]
    correlated_pairs: tuple[tuple[str, str, float], ...]
    nfev: int
    success: bool
    message: str

    @property
    def law(self) -> str:
        """The fitted law name(s), joined by ``+``."""
        return "+".join(self.laws)

    @property
    def dof(self) -> int:
        """Degrees of freedom ``n_data - n_free``."""
        return self.n_data - self.n_free

    def confidence_interval(self, name: str, level: float = 0.95) -> tuple[float, float]:
        """Two-sided ``level`` interval of ``name`` (Student t, ``dof`` degrees of freedom) [SI]."""
        if name not in self.values:
            raise ParameterError(name, f"not a free parameter of this fit (free: {', '.join(self.names)})")
        if not 0.0 < level < 1.0:
            raise ValueError(f"level must be in (0, 1), got {level!r}")
        half = float(stats.t.ppf(0.5 + level / 2.0, max(self.dof, 1))) * self.stderr[name]
        return self.values[name] - half, self.values[name] + half

    def to_parameters(self, params: ParameterSet) -> ParameterSet:
        """``params`` with the fitted values, each source naming this fit (value ± stderr).

        Parameters flagged :attr:`not_identifiable` keep their value and source
        in ``params``: the data said nothing about them.

        Raises
        ------
        ParameterError
            A fitted name is not in ``params``.
        """
        new = {}
        for n in self.names:
            if n in self.not_identifiable:
                continue
            old = params[n]
            src = (f"identified: {self.kind} component table {self.source} "
                   f"({self.values[n]:.6g} +- {self.stderr[n]:.2g} {old.unit}, 1 sigma; was {old.value:.6g})")
            new[n] = type(old)(name=n, value=self.values[n], unit=old.unit, source=src, min=old.min,
                               max=old.max, vary=old.vary, description=old.description)
        return params.replace_parameters(new)

    def report(self) -> str:
        """lmfit-style text (see :func:`format_component_fit`)."""
        return format_component_fit(self)


def format_component_fit(fit: ComponentFit, *, min_correl: float = 0.3) -> str:
    """lmfit-style report of a :class:`ComponentFit`.

    Parameters
    ----------
    fit : ComponentFit
    min_correl : float
        Correlations with a smaller magnitude are not listed [-].

    Returns
    -------
    str
    """
    out = ["[[Fit Statistics]]",
           f"    # kind             = {fit.kind} ({', '.join(fit.laws)})",
           f"    # table            = {fit.source}",
           f"    # fitting method   = {fit.method}",
           f"    # function evals   = {fit.nfev}",
           f"    # data points      = {fit.n_data}",
           f"    # variables        = {fit.n_free}",
           f"    chi-square (RSS)   = {fit.cost:.6g}",
           f"    RMS residual       = {fit.rms_residual:.6g}",
           f"    residual std       = {fit.residual_std:.6g}",
           f"    Akaike info crit   = {fit.aic:.4f}",
           f"    Bayesian info crit = {fit.bic:.4f}",
           f"    success            = {fit.success} ({fit.message})",
           "[[Variables]]"]
    width = max(len(n) for n in fit.names) if fit.names else 0
    for n in fit.names:
        v, s = fit.values[n], fit.stderr[n]
        pct = f" ({100 * abs(s / v):.2f}%)" if v != 0 and math.isfinite(s) else ""
        flags = []
        if n in fit.at_bound:
            flags.append("at bound")
        if n in fit.not_identifiable:
            flags.append("NOT IDENTIFIABLE")
        if v == fit.init[n]:
            flags.append("at initial value")
        flag = f"  [{', '.join(flags)}]" if flags else ""
        out.append(f"    {n:<{width}}: {v:.6g} +/- {s:.3g}{pct} {fit.units[n]} (init = {fit.init[n]:.6g}){flag}")
    for n, v in fit.held.items():
        out.append(f"    {n:<{width}}: {v:.6g} (fixed)")
    pairs = []
    for i, a in enumerate(fit.names):
        for j in range(i + 1, len(fit.names)):
            r = fit.correlation[i, j]
            if math.isfinite(r) and abs(r) >= min_correl:
                pairs.append((abs(r), a, fit.names[j], r))
    if pairs:
        out.append(f"[[Correlations]] (unreported correlations are < {min_correl:.3f})")
        for _, a, b, r in sorted(pairs, reverse=True):
            tag = "  NOT IDENTIFIABLE TOGETHER" if abs(r) > CORRELATION_LIMIT else ""
            out.append(f"    C({a}, {b}) = {r:+.4f}{tag}")
    return "\n".join(out)


# ---------------------------------------------------------------- the fit
def _scales(x0: np.ndarray, lb: np.ndarray, ub: np.ndarray) -> np.ndarray:
    """Typical magnitude of each parameter: |x0|, else a thousandth of its finite range, else 1."""
    s = np.abs(x0).astype(float)
    for i in np.flatnonzero(s == 0):
        rng = ub[i] - lb[i]
        s[i] = 1e-3 * rng if math.isfinite(rng) and rng > 0 else 1.0
    return s


class _Problem:
    """Residuals of one table over the free parameters, in scaled coordinates ``z = x / s``."""

    def __init__(self, model: _Model, table: ComponentTable, params: ParameterSet, free: tuple[str, ...]):
        self.model = model
        self.y = np.asarray(table.measured, dtype=float)
        self.base = params.vector()
        self.idx = np.array([params.names.index(n) for n in free], dtype=int)
        self.lb = np.array([params[n].min for n in free])
        self.ub = np.array([params[n].max for n in free])
        self.x0 = self.base[self.idx].copy()
        self.s = _scales(self.x0, self.lb, self.ub)
        self.nfev = 0
        self._maps: dict[int, ca.Function] = {}

    def full(self, x: np.ndarray) -> np.ndarray:
        p = self.base.copy()
        p[self.idx] = x
        return p

    def residual_x(self, x: np.ndarray) -> np.ndarray:
        self.nfev += 1
        return self.model.evaluate(self.full(x)) - self.y

    def cost_x(self, x: np.ndarray) -> float:
        r = self.residual_x(x)
        return float(r @ r)

    def population_cost(self, xs: np.ndarray) -> np.ndarray:
        """Cost of each column of ``xs`` (free parameters x candidates), one mapped casadi call."""
        m = xs.shape[1]
        if m not in self._maps:
            self._maps[m] = self.model.value.map(m)
        P = np.repeat(self.base[:, None], m, axis=1)
        P[self.idx, :] = xs
        self.nfev += m
        out = np.asarray(self._maps[m](P))
        return np.sum((out - self.y[:, None]) ** 2, axis=0)

    def fun(self, z):
        return self.residual_x(z * self.s)

    def jac(self, z):
        _, j = self.model.jacobian(self.full(z * self.s))
        return j[:, self.idx] * self.s

    def local(self, x_start: np.ndarray) -> optimize.OptimizeResult:
        z0 = np.clip(x_start, self.lb, self.ub) / self.s
        res = optimize.least_squares(self.fun, z0, jac=self.jac, bounds=(self.lb / self.s, self.ub / self.s),
                                     method="trf", ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=2000)
        res.x_phys = res.x * self.s
        return res


def _profile_backlash(prob: _Problem, free: tuple[str, ...], deflection: np.ndarray,
                      profile_points: int) -> tuple[np.ndarray, int]:
    """Backlash profile with the stiffnesses solved linearly; returns the starting point and evaluations."""
    ib = free.index("loadpath.backlash")
    linear = [i for i, n in enumerate(free) if n in ("loadpath.disk_spring_stiffness",
                                                       "loadpath.contact_stiffness_upper",
                                                       "loadpath.contact_stiffness_lower")]
    x = prob.x0.copy()
    evals = 0

    def solve(b: float) -> tuple[float, np.ndarray]:
        nonlocal evals
        evals += 1
        xb = x.copy()
        xb[ib] = b
        if linear:
            xb[linear] = 0.0
        out, jac = prob.model.jacobian(prob.full(xb))
        if not linear:
            r = out - prob.y
            return float(r @ r), xb
        A = jac[:, prob.idx[linear]]
        rhs = prob.y - out  # the law is linear in the stiffnesses: out(k) = out(0) + A k
        scale = prob.s[linear]
        sol = optimize.lsq_linear(A * scale, rhs, bounds=(prob.lb[linear] / scale, prob.ub[linear] / scale),
                                  method="bvls")
        xb[linear] = sol.x * scale
        r = A @ xb[linear] - rhs
        return float(r @ r), xb

    lo = max(prob.lb[ib], 0.0)
    hi = min(prob.ub[ib], float(np.max(np.abs(deflection))))
    kinks = np.unique(np.abs(deflection))
    kinks = kinks[(kinks > lo) & (kinks < hi)]
    if kinks.size > profile_points:
        kinks = np.unique(np.quantile(kinks, np.linspace(0.0, 1.0, profile_points)))
    edges = np.concatenate([[lo], kinks, [hi]])
    mids = 0.5 * (edges[:-1] + edges[1:])
    costs = np.array([solve(b)[0] for b in mids])
    best_cost, best_x = math.inf, x
    for k in np.argsort(costs)[:3]:
        a, c = edges[k], edges[k + 1]
        if c - a > 0:
            r = optimize.minimize_scalar(lambda b: solve(b)[0], bounds=(a, c), method="bounded",
                                         options={"xatol": 1e-9 * max(hi, 1e-12)})
            cost, xb = solve(float(r.x))
        else:
            cost, xb = solve(float(a))
        if cost < best_cost:
            best_cost, best_x = cost, xb
    return best_x, evals


def _global_stage(prob: _Problem, search_factor: float, seed: int | None) -> tuple[np.ndarray, int]:
    """Differential evolution over the free parameters (log scale for wide positive ranges)."""
    lo, hi, logs = [], [], []
    for x0, lb, ub in zip(prob.x0, prob.lb, prob.ub):
        if x0 > 0:
            a, b = max(lb, x0 / search_factor), min(ub, x0 * search_factor)
        else:
            a, b = lb, (ub if math.isfinite(ub) else lb + 1.0)
        use_log = a > 0 and b / a > 20.0
        logs.append(use_log)
        lo.append(math.log(a) if use_log else a)
        hi.append(math.log(b) if use_log else b)
    logs = np.array(logs)

    def to_x(u):
        return np.where(logs, np.exp(u), u)

    def costs(u):  # the whole population in one call of the mapped law
        u = np.asarray(u, dtype=float).reshape(len(logs), -1)
        return prob.population_cost(to_x(u.T).T)

    res = optimize.differential_evolution(costs, list(zip(lo, hi)), seed=seed, tol=1e-10, maxiter=400,
                                          popsize=20, polish=False, init="sobol", vectorized=True,
                                          updating="deferred")
    return to_x(res.x), int(res.nfev)


def fit_component(table: ComponentTable, *, params: ParameterSet | None = None,
                  free: Sequence[str] | None = None, global_stage: bool = False,
                  seed: int | None = 0, search_factor: float = 10.0,
                  profile_points: int = 400, profile_backlash: bool = True) -> ComponentFit:
    """Fit the table's component law(s) through the effect library's casadi Functions.

    Parameters
    ----------
    table : ComponentTable
        From :func:`read_component_table` or :func:`generate_component_table`.
    params : ParameterSet, optional
        Initial values, bounds and held values; default
        :func:`~thsa_control.model.params.default_parameters`.  Not modified.
    free : sequence of str, optional
        Parameters to fit, all read by the table's law(s); default the kind's
        ``default_free`` (for a disk table only the directions present).
    global_stage : bool
        Run differential evolution first (search box ``[x0/search_factor,
        x0*search_factor]`` within the bounds, log-scaled when wide), then the
        local polish.  Without it a load-path fit with a free backlash profiles
        the backlash (module docstring).
    seed : int or None
        Seed of the global stage.
    search_factor : float
        Width of the global search box around the initial values (> 1).
    profile_points : int
        Most backlash intervals evaluated by the profile.
    profile_backlash : bool
        Profile a free load-path backlash (default).  False runs the local
        least squares alone from the initial values, which the backlash edge
        can trap in a local minimum (kept for comparison and tests).

    Returns
    -------
    ComponentFit

    Raises
    ------
    ParameterError
        A free name is unknown, not read by the law(s), or (disk tables) belongs
        to a direction with no data.
    ValueError
        Fewer data rows than free parameters, or a bad option.
    """
    params = default_parameters() if params is None else params
    if not search_factor > 1.0:
        raise ValueError(f"search_factor must be > 1, got {search_factor!r}")
    if int(profile_points) < 2:
        raise ValueError(f"profile_points must be >= 2, got {profile_points!r}")
    spec = table.spec
    model_probe = _Model(table, params.names)
    used = model_probe.parameters_used()
    all_law = tuple(dict.fromkeys(n for law in spec.laws for n in LAWS[law].parameters))
    if free is None:
        free = tuple(n for n in spec.default_free if n in used)
    else:
        free = tuple(free)
        for n in free:
            params[n]  # unknown names raise ParameterError
            if n not in all_law:
                raise ParameterError(n, f"not a parameter of the '{spec.name}' law(s); "
                                        f"they read: {', '.join(all_law)}")
            if n not in used:
                raise ParameterError(n, f"its rotation direction has no rows in {table.path or '<table>'}")
        twice = sorted({n for n in free if free.count(n) > 1})
        if twice:
            raise ParameterError(twice[0], "listed twice in free")
    if not free:
        raise ParameterError("free", "no free parameter to fit")
    if table.n_rows <= len(free):
        raise ValueError(f"{table.n_rows} data rows cannot determine {len(free)} free parameters")

    prob = _Problem(model_probe, table, params, free)
    stages = []
    extra_nfev = 0
    start = prob.x0
    if global_stage:
        start, n_de = _global_stage(prob, search_factor, seed)
        extra_nfev += n_de
        stages.append(f"differential evolution (scipy, {n_de} evaluations)")
    elif profile_backlash and "loadpath.backlash" in free:
        deflection = table.law_inputs()["deflection"]
        start, n_prof = _profile_backlash(prob, free, deflection, int(profile_points))
        extra_nfev += n_prof
        stages.append(f"backlash profile with linear stiffnesses ({n_prof} profile points)")
    res = prob.local(start)
    stages.append("least_squares (trf, exact casadi Jacobian, scaled, bounded)")
    x = res.x_phys
    cost_start = prob.cost_x(start)
    if cost_start < prob.cost_x(x):  # the polish never makes a global-stage optimum worse
        x = np.asarray(start, dtype=float)

    r = prob.residual_x(x)
    n, k = r.size, len(free)
    rss = float(r @ r)
    _, jac = prob.model.jacobian(prob.full(x))
    js = jac[:, prob.idx] * prob.s
    s2 = rss / max(n - k, 1)
    u, sv, vt = np.linalg.svd(js, full_matrices=False)
    tol = sv.max() * max(js.shape) * np.finfo(float).eps * 1e3 if sv.size else 0.0
    good = sv > tol
    cov_z = (vt[good].T / sv[good] ** 2) @ vt[good] * s2
    null = vt[~good]
    weak = np.zeros(k, dtype=bool)
    if null.size:
        weak = np.any(np.abs(null) > 1e-3, axis=0)
    cov = cov_z * np.outer(prob.s, prob.s)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    std[weak] = np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(std, std)
    corr[weak, :] = np.nan
    corr[:, weak] = np.nan
    np.fill_diagonal(corr, 1.0)
    at_bound = tuple(n_ for i, n_ in enumerate(free)
                     if abs(x[i] - prob.lb[i]) <= 1e-6 * prob.s[i] or abs(prob.ub[i] - x[i]) <= 1e-6 * prob.s[i])
    pairs = tuple((free[i], free[j], float(corr[i, j])) for i in range(k) for j in range(i + 1, k)
                  if math.isfinite(corr[i, j]) and abs(corr[i, j]) > CORRELATION_LIMIT)
    held = {n_: params[n_].value for n_ in all_law if n_ not in free and n_ in used}
    with np.errstate(divide="ignore"):
        loglik = n * math.log(rss / n) if rss > 0 else -math.inf
    return ComponentFit(
        kind=spec.name, laws=tuple(model_probe.groups), source=table.path or "<table>",
        method=" -> ".join(stages), names=free,
        values={n_: float(v) for n_, v in zip(free, x)},
        stderr={n_: float(v) for n_, v in zip(free, std)},
        init={n_: float(v) for n_, v in zip(free, prob.x0)},
        units={n_: params[n_].unit for n_ in free}, held=held, correlation=corr,
        n_data=n, n_free=k, cost=rss, rms_residual=math.sqrt(rss / n), residual_std=math.sqrt(s2),
        aic=loglik + 2 * k, bic=loglik + k * math.log(n), residuals=-r,
        at_bound=at_bound, not_identifiable=tuple(n_ for n_, w in zip(free, weak) if w),
        correlated_pairs=pairs, nfev=prob.nfev + extra_nfev, success=bool(res.success),
        message=str(res.message),
    )
