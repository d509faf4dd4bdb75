"""Gain optimisation with casadi's nlpsol (IPOPT) against the nonlinear validation runs.

Variables: the logarithms of the tuned velocity gains relative to the source
design (``q = ln(g / g_source)``, well scaled, bounded to a factor
``bound_factor`` either way).  Objective: ``J(g) / J(g_source)`` from
:class:`~.objective.Objective` (closed-loop nonlinear runs, gradient by casadi
forward sensitivities through the simulator's step), handed to IPOPT as a
casadi ``Callback`` that computes value and gradient in one pass and caches
them by ``q``.  Constraints: the current above the clamp (integral of the
squared excess, <= ``excess_tolerance``; the same for the nut speed above the
allowed overshoot on plateaus; on the objective's runs and on the same runs at
``constraint_level`` and ``constraint_temperatures``) and the smooth margin constraints of
:class:`~.robust.RobustConstraints` at every temperature of the robust set
(plain casadi expressions).  Hessian: limited-memory BFGS.

Every start is solved; the best feasible one is kept and checked on the
exact compiled simulator and with the exact loop analysis.
"""

from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..errors import SolverError, ThsaError
from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS
from ..loops.design import Design, derive_gains
from ..model.params import ParameterSet
from .objective import Objective, ObjectiveSettings, design_with_gains, gains_of
from .robust import RobustConstraints, exact_margins

__all__ = ["TuneSettings", "StartResult", "TuningResult", "InfeasibleRequirement", "tune", "default_starts"]


class InfeasibleRequirement(SolverError):
    """No gains meet a requirement; ``constraint`` names it and ``shortfall`` says by how much."""

    def __init__(self, constraint: str, detail: str, stats: dict | None = None):
        self.constraint = constraint
        self.detail = detail
        ThsaError.__init__(self, f"infeasible requirement {constraint}: {detail}")
        self.solver, self.status, self.stats = "ipopt", "infeasible", dict(stats or {})


@dataclass(frozen=True)
class TuneSettings:
    """What ``thsa tune`` optimises.

    Parameters
    ----------
    temperature : float
        Temperature of the objective's runs [degC].
    robust_temperatures : tuple of float
        Temperatures of the margin constraints [degC].
    level, effects : the plant (default level B + temperature_friction + standby_motor, the two-rotor plant).
    tuned : tuple of str
        Velocity gains varied.
    bound_factor : float
        Gains stay within this factor of the source design's.
    excess_tolerance : float
        Allowed integral of the squared current above the clamp [A^2 s] and of
        the squared speed above the allowed overshoot [(mm/s)^2 s].
    constraint_level : str or None
        The peak-current and overshoot constraints also cover the runs at
        this level (the no-back backlash of levels C/D makes the loaded
        breakaway's current spike, the velocity PI saturating and the current
        loop overshooting the clamp, and the low-speed plateau overshoot) ...
    constraint_temperatures : tuple of float or None
        ... at these temperatures (None: the coldest robust temperature and 25 degC).
    max_iter, tol : IPOPT's iteration limit and tolerance.
    objective : ObjectiveSettings
    progress : bool
        Print progress on stderr.
    """

    temperature: float = -30.0
    robust_temperatures: tuple[float, ...] = (-55.0, -30.0, 25.0, 70.0)
    level: str = "B"
    effects: tuple[str, ...] = DEFAULT_ANALYSIS_EFFECTS
    tuned: tuple[str, ...] = ("velocity_kp", "velocity_ki")
    bound_factor: float = 10.0
    excess_tolerance: float = 1e-8
    constraint_level: str | None = "D"
    constraint_temperatures: tuple[float, ...] | None = None
    max_iter: int = 60
    tol: float = 1e-7
    objective: ObjectiveSettings = field(default_factory=ObjectiveSettings)
    progress: bool = True

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        if set(self.tuned) - {"velocity_kp", "velocity_ki"} or not self.tuned:
            raise ValueError(f"TuneSettings.tuned = {self.tuned!r}: the margin constraints take the velocity gains "
                             "velocity_kp and/or velocity_ki")
        if not (self.bound_factor > 1 and math.isfinite(self.bound_factor)):
            raise ValueError(f"TuneSettings.bound_factor = {self.bound_factor!r} must be > 1")
        if not (isinstance(self.max_iter, int) and self.max_iter >= 1):
            raise ValueError(f"TuneSettings.max_iter = {self.max_iter!r} must be an integer >= 1")
        if not self.robust_temperatures:
            raise ValueError("TuneSettings.robust_temperatures must not be empty")


@dataclass(frozen=True)
class StartResult:
    """One IPOPT solve: ``start`` name, initial and final gains, relative objective, status."""

    start: str
    initial_gains: tuple[float, ...]
    gains: tuple[float, ...]
    objective: float
    status: str
    success: bool
    iterations: int
    wall_s: float
    constraint_min: float
    worst_constraint: str


@dataclass(frozen=True)
class TuningResult:
    """Outcome of :func:`tune`.

    Attributes
    ----------
    design : Design
        The tuned design (best feasible start).
    source : Design
    starts : tuple of StartResult
    best : StartResult
    tuned : tuple of str
    terms_before, terms_after : ndarray (n_runs, 4)
        Cost integrals of each run, source and tuned, from the compiled simulator.
    objective_before, objective_after : float
        ``J`` (absolute).
    run_names : tuple of str
    margins_before, margins_after : list of MarginSummary
        Exact margins at the robust temperatures.
    settings : TuneSettings
    wall_s : float
    evaluations : dict
        Objective evaluations (counts, seconds).
    """

    design: Design
    source: Design
    starts: tuple[StartResult, ...]
    best: StartResult
    tuned: tuple[str, ...]
    terms_before: np.ndarray
    terms_after: np.ndarray
    objective_before: float
    objective_after: float
    run_names: tuple[str, ...]
    margins_before: list
    margins_after: list
    settings: TuneSettings
    wall_s: float
    evaluations: dict

    @property
    def reduction(self) -> float:
        """Relative reduction of the objective [-]."""
        return 1.0 - self.objective_after / self.objective_before


class _Cache:
    """Value and gradient of the objective and the excesses, computed together, cached by q."""

    def __init__(self, objective: Objective, g0: np.ndarray, J0: float, progress: bool, label: str,
                 extra: Objective | None = None):
        self.obj, self.g0, self.J0, self.progress, self.label = objective, g0, J0, progress, label
        self.extra = extra
        self.key = None
        self.val = None
        self.jac = None
        self.n_jac = 0
        self.history = []  # (q, (value, jacobian)) of every evaluation

    def gains(self, q):
        return self.g0 * np.exp(np.asarray(q, float).ravel())

    def value(self, q):
        k = np.asarray(q, float).tobytes()
        if self.key != k:
            J, dJ, ex, dex = self.obj.value_and_gradient(self.gains(q))
            if self.extra is not None:
                _, _, ex2, dex2 = self.extra.value_and_gradient(self.gains(q))
                ex, dex = ex + ex2, dex + dex2
            g = self.gains(q)
            self.key, self.val = k, np.concatenate([[J / self.J0], ex])
            self.jac = np.vstack([dJ * g / self.J0, dex * g[None, :]])
            self.n_jac += 1
            self.history.append((np.asarray(q, float).ravel().copy(), (self.val, self.jac)))
            if self.progress:
                gs = " ".join(f"{n}={v:.5g}" for n, v in zip(self.obj.tuned, g))
                print(f"  [{self.label}] eval {self.n_jac:3d}: J/J0 = {J / self.J0:.6f}  {gs}", file=sys.stderr, flush=True)
        return self.val, self.jac


_NOUT = 3  # J / J0, current above the clamp, speed above the allowed overshoot


class _Jac(ca.Callback):
    def __init__(self, cache: _Cache, n: int, opts=None):
        ca.Callback.__init__(self)
        self.cache, self.n = cache, n
        self.construct("tune_jac", opts or {})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.n, 1) if i == 0 else ca.Sparsity.dense(_NOUT, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(_NOUT, self.n)

    def eval(self, arg):
        return [ca.DM(self.cache.value(np.asarray(arg[0]))[1])]


class _Sim(ca.Callback):
    def __init__(self, cache: _Cache, n: int, opts=None):
        ca.Callback.__init__(self)
        self.cache, self.n = cache, n
        self._jac = None
        self.construct("tune_sim", opts or {})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(self.n, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(_NOUT, 1)

    def eval(self, arg):
        return [ca.DM(self.cache.value(np.asarray(arg[0]))[0])]

    def has_jacobian(self, *args):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = _Jac(self.cache, self.n, {})
        x = ca.MX.sym(inames[0], self.n)
        out = ca.MX.sym(inames[1], _NOUT)
        return ca.Function(name, [x, out], [self._jac(x, out)], inames, onames, opts)


def default_starts(design: Design, params: ParameterSet) -> dict[str, Design]:
    """Starts of the optimisation: the source design, and the linear design rules for a stiffer cold loop.

    The rule start is :func:`~thsa_control.loops.design.derive_gains` with
    1.2 x the source's velocity crossover and the PI zero at crossover / 4
    (more integral action against the cold drag).
    """
    der = design.derivation
    wc = float(der.get("velocity_crossover_hz", 30.0)) * 1.2
    rules = derive_gains(params, current_bandwidth_hz=float(der.get("current_bandwidth_hz", 1000.0)),
                         velocity_crossover_hz=wc, velocity_pi_zero_ratio=4.0,
                         position_bandwidth_hz=float(der.get("position_bandwidth_hz", 2.0)),
                         rotors=int(der.get("rotors", 2)), computation_delay_samples=design.computation_delay_samples)
    return {"source": design, f"rules ({wc:g} Hz, zero ratio 4)": design_with_gains(
        design, ("velocity_kp", "velocity_ki"), (rules.velocity_kp, rules.velocity_ki))}


def _say(settings: TuneSettings, msg: str) -> None:
    if settings.progress:
        print(msg, file=sys.stderr, flush=True)


def tune(design: Design, params: ParameterSet, scenarios, settings: TuneSettings | None = None, *,
         starts: dict[str, Design] | None = None) -> TuningResult:
    """Optimise the velocity gains of ``design`` on ``scenarios`` (at ``settings.temperature``).

    Raises
    ------
    InfeasibleRequirement
        No start reaches a point meeting every constraint: names the
        constraint and by how much it is missed (exact margins).
    SolverError
        IPOPT did not converge from any start (status and statistics).
    """
    from ..model import build_plant
    from ..sim.simulate import Simulator

    settings = settings or TuneSettings()
    settings.validate()
    t_all = time.perf_counter()
    scen = [s.with_temperature(settings.temperature) for s in scenarios]
    plant = build_plant(settings.level, settings.effects, params=params)
    objective = Objective(Simulator(plant), params, design, scen, tuned=settings.tuned, settings=settings.objective)
    _say(settings, f"tune: {len(scen)} run(s) at {settings.temperature:g} degC, level {settings.level} "
                   f"+ {', '.join(settings.effects) or 'no effect'}; compiling the objective ...")
    objective.stage_functions()
    g_src = gains_of(design, settings.tuned)
    J0 = objective.value(g_src)
    extra = None
    if settings.constraint_level:
        temps = settings.constraint_temperatures or tuple(dict.fromkeys((min(settings.robust_temperatures), 25.0)))
        cplant = build_plant(settings.constraint_level, settings.effects, params=params)
        extra = Objective(Simulator(cplant), params, design, [s.with_temperature(t) for t in temps for s in scenarios],
                          tuned=settings.tuned, settings=settings.objective)
        _say(settings, f"tune: peak-current and overshoot constraints also on the runs at level {settings.constraint_level}, "
                       f"{', '.join(f'{t:g}' for t in temps)} degC")
        extra.stage_functions()
    _say(settings, f"tune: source objective J0 = {J0:.6g}; linearising at {', '.join(f'{t:g}' for t in settings.robust_temperatures)} degC ...")
    robust = RobustConstraints(design, params, settings.robust_temperatures, level=settings.level,
                               effects=settings.effects)
    starts = starts or default_starts(design, params)
    n = len(settings.tuned)
    q = ca.MX.sym("q", n)
    gains_sym = [g_src[j] * ca.exp(q[j]) for j in range(n)]
    kp = gains_sym[settings.tuned.index("velocity_kp")] if "velocity_kp" in settings.tuned else design.velocity_kp
    ki = gains_sym[settings.tuned.index("velocity_ki")] if "velocity_ki" in settings.tuned else design.velocity_ki
    g_rob = robust.casadi_constraints(kp, ki)
    lb = math.log(1.0 / settings.bound_factor)
    results = []
    rob_fn = ca.Function("robust", [q], [g_rob])
    names = ("current above the clamp", "speed above the allowed overshoot") + robust.names

    def margins_of(qv, sim_val):
        """Constraint values (>= 0 feasible) at q from the cached simulation values."""
        ex = np.asarray(sim_val[1:], float) / settings.excess_tolerance
        return np.concatenate([1.0 - ex, np.asarray(rob_fn(qv), float).ravel()])

    def solve(cache, x0, lo, hi):
        sim = _Sim(cache, n)
        simq = sim(q)
        # sqrt(1 + excess / tol) <= sqrt(2): smooth, and it grows like sqrt far from feasibility (better scaled)
        nlp = {"x": q, "f": simq[0], "g": ca.vertcat(ca.sqrt(1.0 + simq[1:] / settings.excess_tolerance), g_rob)}
        opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                "ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": settings.max_iter,
                "ipopt.tol": settings.tol, "ipopt.acceptable_tol": 1e-5, "error_on_fail": False}
        solver = ca.nlpsol(f"tune_{len(results)}", "ipopt", nlp, opts)
        sol = solver(x0=x0, lbx=lo, ubx=hi, lbg=[-np.inf, -np.inf] + [0.0] * g_rob.size1(),
                     ubg=[math.sqrt(2.0)] * 2 + [np.inf] * g_rob.size1())
        stats = solver.stats()
        qf = np.asarray(sol["x"], float).ravel()
        return qf, float(sol["f"]), margins_of(qf, cache.value(qf)[0]), stats

    ok_status = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    for label, start in starts.items():
        cache = _Cache(objective, g_src, J0, settings.progress, label, extra)
        x0 = np.log(np.clip(gains_of(start, settings.tuned) / g_src, 1.0 / settings.bound_factor, settings.bound_factor))
        _say(settings, f"tune: start '{label}' from {', '.join(f'{v:.5g}' for v in g_src * np.exp(x0))}")
        t0 = time.perf_counter()
        qf, fval, cons, stats = solve(cache, x0, [lb] * n, [-lb] * n)
        status = str(stats.get("return_status"))
        iters = int(stats.get("iter_count", -1))
        if status not in ok_status or cons.min() < -1e-6:
            # safeguard: IPOPT lost its way (the excess constraints are steep); restart from the best feasible
            # point evaluated so far, in a trust region of x1.5 around it, while that keeps improving
            first, tr = status, math.log(1.5)
            for _ in range(6):
                hist = [(v[0][0], qq) for qq, v in cache.history if margins_of(qq, v[0]).min() >= -1e-6]
                if not hist:
                    break
                fb, qb = min(hist, key=lambda h: h[0])
                _say(settings, f"tune: start '{label}': {status}; restarting from the best feasible iterate "
                               f"{', '.join(f'{v:.5g}' for v in g_src * np.exp(qb))} within x1.5")
                lo, hi = np.maximum(qb - tr, lb), np.minimum(qb + tr, -lb)
                qf2, f2, cons2, stats2 = solve(cache, qb, lo, hi)
                iters += int(stats2.get("iter_count", -1))
                st2 = str(stats2.get("return_status"))
                if cons2.min() >= -1e-6 and f2 <= fb:
                    qf, fval, cons, stats, status = qf2, f2, cons2, stats2, st2
                else:
                    qf, fval, cons, status = qb, fb, margins_of(qb, cache.value(qb)[0]), "Maximum_Iterations_Exceeded"
                on_edge = np.any((np.abs(qf - lo) < 1e-6) & (lo > lb + 1e-9)) or np.any(
                    (np.abs(qf - hi) < 1e-6) & (hi < -lb - 1e-9))
                if status in ok_status and not on_edge:
                    break
            status = f"{status} (restarted from feasible iterates after {first})"
        wall = time.perf_counter() - t0
        k = int(np.argmin(cons))
        success = status.startswith(ok_status) and cons.min() >= -1e-6
        res = StartResult(label, tuple(float(v) for v in g_src * np.exp(x0)), tuple(float(v) for v in g_src * np.exp(qf)),
                          fval, status, success, iters, wall, float(cons[k]), names[k])
        _say(settings, f"tune: start '{label}': {res.status} after {res.iterations} iterations, {wall:.1f} s, "
                       f"J/J0 = {res.objective:.6f}, worst constraint {res.worst_constraint} = {res.constraint_min:.3g}")
        results.append((res, stats))
    feasible = [r for r, _ in results if r.constraint_min >= -1e-6 and r.status.startswith(
        ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded"))]
    if not feasible:
        r, stats = min(results, key=lambda rs: -rs[0].constraint_min)
        gains = np.array(r.gains)
        cand = design_with_gains(design, settings.tuned, gains)
        detail = _shortfall(r.worst_constraint, cand, params, settings, robust)
        if r.constraint_min < -1e-6:
            raise InfeasibleRequirement(r.worst_constraint, f"{detail} (IPOPT: {r.status} after {r.iterations} "
                                                           f"iterations)", stats)
        raise SolverError("ipopt", f"not converged from any start (last: {r.status} after {r.iterations} iterations, "
                                   f"J/J0 = {r.objective:.4g})", stats)
    best = min(feasible, key=lambda r: r.objective)
    tuned = design_with_gains(design, settings.tuned, best.gains)
    _say(settings, "tune: checking on the exact compiled simulator and the loop analysis ...")
    T_before = objective.reference_terms(g_src)
    T_after = objective.reference_terms(np.array(best.gains))
    if extra is not None:
        ex_after = extra.reference_terms(np.array(best.gains))[:, 3:].sum(axis=0)
        if np.any(ex_after > settings.excess_tolerance * (1 + 1e-3)):
            _say(settings, f"tune: warning: constraint runs exceed the clamp / overshoot by {ex_after.tolist()}")
    w = settings.objective.weights
    m_before = exact_margins(design, params, settings.robust_temperatures, level=settings.level, effects=settings.effects)
    m_after = exact_margins(tuned, params, settings.robust_temperatures, level=settings.level, effects=settings.effects)
    return TuningResult(tuned, design, tuple(r for r, _ in results), best, settings.tuned, T_before, T_after,
                        float(np.sum(T_before @ w)), float(np.sum(T_after @ w)), tuple(s.name for s in scen),
                        m_before, m_after, settings, time.perf_counter() - t_all, _evaluations(objective, extra))


def _evaluations(objective: Objective, extra: Objective | None) -> dict:
    out = dict(objective.evaluations)
    if extra is not None:
        out["constraint_runs"] = dict(extra.evaluations)
    return out


def _shortfall(name: str, design: Design, params, settings: TuneSettings, robust: RobustConstraints) -> str:
    """By how much the best point misses constraint ``name``, in the requirement's units."""
    if name.startswith("current"):
        return "the current exceeds the clamp in the validation runs at every reachable gain"
    if name.startswith("speed above"):
        return (f"the nut speed overshoots the command by more than {100 * settings.objective.overshoot_limit:g} % "
                "on a plateau of the validation runs at every reachable gain")
    key, _, rest = name.partition(" at ")
    T = float(rest.split()[0])
    limit = robust.requirements[key]
    m = exact_margins(design, params, [T], level=settings.level, effects=settings.effects,
                      requirements=robust.requirements)[0]
    if key == "min_phase_margin_deg":
        return (f"at the least-infeasible point IPOPT reached, the phase margin at {T:g} degC is {m.phase_margin_deg:.3g} deg ({m.phase_margin_at}), "
                f"{limit - m.phase_margin_deg:.3g} deg short of the required {limit:g} deg")
    if key == "min_gain_margin_db":
        return (f"at the least-infeasible point IPOPT reached, the gain margin at {T:g} degC is {m.gain_margin_db:.3g} dB ({m.gain_margin_at}), "
                f"{limit - m.gain_margin_db:.3g} dB short of the required {limit:g} dB")
    return (f"at the least-infeasible point IPOPT reached, the sensitivity peak at {T:g} degC is {m.ms:.4g} ({m.ms_at}), "
            f"{m.ms - limit:.3g} above the allowed {limit:g}")
