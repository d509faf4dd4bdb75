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
from collections.abc import Callable
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from ..errors import SolverError, ThsaError
from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS
from ..loops.design import Design, derive_gains
from ..model.params import ParameterSet
from .objective import Objective, ObjectiveSettings, design_with_gains, gains_of
from .robust import RobustConstraints, exact_margins
from .validation import VALIDATION_SUITE, get_validation_scenario

__all__ = ["TuneSettings", "StartResult", "TuningResult", "InfeasibleRequirement", "tune", "default_starts",
           "objective_settings_for", "linear_temperatures"]


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
        ... at these temperatures (None: the coldest check temperature; the verdict adds every other
        run it fails on).
    check_levels, check_temperatures : what ``thsa check`` judges the validation runs at: the tuned
        design is judged there (:func:`thsa_control.verdict.evaluate_design`) before it is returned, and
        every run whose current peak or overshoot fails becomes a constraint run of the next round.
    max_rounds : int
        Rounds of (solve, judge, add the failing runs / tighten the linear constraint that failed).
    max_iter, tol : IPOPT's iteration limit and tolerance (no wall-clock limit: the answer does not
        depend on the machine's load).
    objective : ObjectiveSettings
    progress : bool or callable
        Print progress on stderr; a callable (e.g. a :class:`thsa_control.progress.Progress`) gets each
        message instead.
    suite : tuple of str or None
        Validation runs judged and used as constraint runs (None: the validation suite of ``thsa check``).
    requirements : dict or None
        ``[requirements.velocity_loop]`` of the constraints (None: the design's).
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
    check_levels: tuple[str, ...] = ("A", "B", "C", "D")
    check_temperatures: tuple[float, ...] = (-55.0, -30.0, 25.0, 70.0)
    max_rounds: int = 4
    max_iter: int = 60
    tol: float = 1e-7
    objective: ObjectiveSettings = field(default_factory=ObjectiveSettings)
    progress: bool | Callable[[str], None] = True
    suite: tuple[str, ...] | None = None
    requirements: dict | None = None

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
        The multi-start of the first round (later rounds, from the best gains, are in ``rounds``).
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
    verdict : thsa_control.verdict.Verdict
        The tuned design judged on every requirement (passed: ``tune`` raises otherwise).
    rounds : tuple of dict
        Gains, constraint runs and failing requirements of each round.
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
    verdict: object = None
    rounds: tuple = ()

    @property
    def reduction(self) -> float:
        """Relative reduction of the objective [-]."""
        return 1.0 - self.objective_after / self.objective_before


class _Cache:
    """Value and gradient of the objective and the excesses, computed together, cached by q."""

    def __init__(self, objective: Objective, g0: np.ndarray, J0: float, progress: bool, label: str,
                 extras=()):
        self.obj, self.g0, self.J0, self.progress, self.label = objective, g0, J0, progress, label
        self.extras = list(extras)
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
            for extra in self.extras:
                _, _, ex2, dex2 = extra.value_and_gradient(self.gains(q))
                ex, dex = ex + ex2, dex + dex2
            g = self.gains(q)
            self.key, self.val = k, np.concatenate([[J / self.J0], ex])
            self.jac = np.vstack([dJ * g / self.J0, dex * g[None, :]])
            self.n_jac += 1
            self.history.append((np.asarray(q, float).ravel().copy(), (self.val, self.jac)))
            if self.progress:
                gs = " ".join(f"{n}={v:.5g}" for n, v in zip(self.obj.tuned, g))
                msg = f"[{self.label}] eval {self.n_jac:3d}: J/J0 = {J / self.J0:.6f}  {gs}"
                if callable(self.progress):
                    self.progress(msg)
                else:
                    print("  " + msg, file=sys.stderr, flush=True)
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


def objective_settings_for(design: Design, **kw) -> ObjectiveSettings:
    """Objective settings whose excess constraints aim inside the design's validation limits.

    The overshoot constraint keeps 10 % of ``max_overshoot_percent`` in reserve, the current one 1 % of the
    smaller of the clamp and ``max_current_peak_A`` (brief excursions pass the integral constraint).
    """
    from ..verdict import validation_limits

    lim = validation_limits(design)
    frac = 0.99 * min(lim["max_current_peak_A"][0], design.current_limit) / design.current_limit
    return ObjectiveSettings(overshoot_limit=0.9 * lim["max_overshoot_percent"][0] / 100.0, current_fraction=frac,
                             **kw)


def _say(settings: TuneSettings, msg: str) -> None:
    if callable(settings.progress):
        settings.progress(msg.removeprefix("tune: "))
    elif settings.progress:
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
    osettings = settings.objective  # its excess limits tighten when a constrained run still fails the verdict
    main_sim = Simulator(plant)
    objective = Objective(main_sim, params, design, scen, tuned=settings.tuned, settings=osettings)
    _say(settings, f"tune: {len(scen)} run(s) at {settings.temperature:g} degC, level {settings.level} "
                   f"+ {', '.join(settings.effects) or 'no effect'}; compiling the objective ...")
    objective.stage_functions()
    g_src = gains_of(design, settings.tuned)
    J0 = objective.value(g_src)
    suite = tuple(settings.suite or VALIDATION_SUITE)
    lin_temps = linear_temperatures(design, settings)
    _say(settings, f"tune: source objective J0 = {J0:.6g}; judging the requirements the velocity gains cannot change ...")
    _fixed_requirements(design, params, settings)
    run_set: dict[tuple[str, float, str], None] = {}
    if settings.constraint_level:
        temps = settings.constraint_temperatures or (min(settings.check_temperatures),)
        for T in temps:
            for name in suite:
                run_set[(settings.constraint_level, float(T), name)] = None
    plants: dict[str, object] = {}

    def extras_for(keys):
        by_level: dict[str, list] = {}
        for (lv, T, name) in keys:
            by_level.setdefault(lv, []).append(get_validation_scenario(name).with_temperature(T))
        out = []
        for lv, runs in sorted(by_level.items()):
            if lv not in plants:
                plants[lv] = Simulator(build_plant(lv, settings.effects, params=params))
            ob = Objective(plants[lv], params, design, runs, tuned=settings.tuned, settings=osettings)
            ob.stage_functions()
            out.append(ob)
        return out

    _say(settings, f"tune: linearising over the design's analysis grid at {', '.join(f'{t:g}' for t in lin_temps)} degC ...")
    robust = RobustConstraints(design, params, lin_temps, level=settings.level, effects=settings.effects,
                               requirements=settings.requirements)
    starts = starts or default_starts(design, params)
    n = len(settings.tuned)
    q = ca.MX.sym("q", n)
    gains_sym = [g_src[j] * ca.exp(q[j]) for j in range(n)]
    kp = gains_sym[settings.tuned.index("velocity_kp")] if "velocity_kp" in settings.tuned else design.velocity_kp
    ki = gains_sym[settings.tuned.index("velocity_ki")] if "velocity_ki" in settings.tuned else design.velocity_ki
    lb = math.log(1.0 / settings.bound_factor)
    results = []
    ok_status = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
    rounds = []
    tol_ex = settings.excess_tolerance
    verdict = None
    best = None
    extras = []
    _linear_feasibility(robust, q, kp, ki, starts, g_src, settings, design, params, lb)
    for rnd in range(1, settings.max_rounds + 1):
        extras = extras_for(run_set) if run_set else []
        _say(settings, f"tune: round {rnd}: constraint runs " + (", ".join(
            f"{lv} {T:g} degC {nm}" for lv, T, nm in run_set) or "none"))
        g_rob = robust.casadi_constraints(kp, ki)
        rob_fn = ca.Function("robust", [q], [g_rob])
        names = ("current above the clamp", "speed above the allowed overshoot") + robust.names

        def margins_of(qv, sim_val, rob_fn=rob_fn):
            """Constraint values (>= 0 feasible) at q from the cached simulation values."""
            ex = np.asarray(sim_val[1:], float) / tol_ex
            return np.concatenate([1.0 - ex, np.asarray(rob_fn(qv), float).ravel()])

        def solve(cache, x0, lo, hi, g_rob=g_rob, margins_of=margins_of):
            sim = _Sim(cache, n)
            simq = sim(q)
            # sqrt(1 + excess / tol) <= sqrt(2): smooth, and it grows like sqrt far from feasibility (better scaled)
            nlp = {"x": q, "f": simq[0], "g": ca.vertcat(ca.sqrt(1.0 + simq[1:] / tol_ex), g_rob)}
            opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                    "ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": settings.max_iter,
                    "ipopt.tol": settings.tol, "ipopt.acceptable_tol": 1e-5, "error_on_fail": False}
            solver = ca.nlpsol(f"tune_{rnd}_{len(results)}", "ipopt", nlp, opts)
            sol = solver(x0=x0, lbx=lo, ubx=hi, lbg=[-np.inf, -np.inf] + [0.0] * g_rob.size1(),
                         ubg=[math.sqrt(2.0)] * 2 + [np.inf] * g_rob.size1())
            stats = solver.stats()
            qf = np.asarray(sol["x"], float).ravel()
            return qf, float(sol["f"]), margins_of(qf, cache.value(qf)[0]), stats

        round_starts = starts if best is None else {f"round {rnd} from the round-{rnd - 1} gains": design_with_gains(
            design, settings.tuned, best.gains)}
        round_results = []
        for label, start in round_starts.items():
            cache = _Cache(objective, g_src, J0, settings.progress, label, extras)
            x0 = np.log(np.clip(gains_of(start, settings.tuned) / g_src, 1.0 / settings.bound_factor,
                                settings.bound_factor))
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
                    fb, qb = min(hist, key=lambda h: (h[0], tuple(h[1])))
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
            res = StartResult(label, tuple(float(v) for v in g_src * np.exp(x0)),
                              tuple(float(v) for v in g_src * np.exp(qf)), fval, status, success, iters, wall,
                              float(cons[k]), names[k])
            if status.startswith("Maximum_Iterations_Exceeded"):
                _say(settings, f"tune: start '{label}': the iteration limit ({settings.max_iter}) was hit")
            _say(settings, f"tune: start '{label}': {res.status} after {res.iterations} iterations, {wall:.1f} s, "
                           f"J/J0 = {res.objective:.6f}, worst constraint {res.worst_constraint} = {res.constraint_min:.3g}")
            round_results.append((res, stats))
        if rnd == 1:  # the multi-start; later rounds restart from the best gains (recorded in ``rounds``)
            results += round_results
        feasible = [r for r, _ in round_results if r.constraint_min >= -1e-6 and r.status.startswith(
            ("Solve_Succeeded", "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded"))]
        if not feasible:
            r, stats = min(round_results, key=lambda rs: (-rs[0].constraint_min, rs[0].start))
            if r.constraint_min < -1e-6:
                cand = design_with_gains(design, settings.tuned, np.array(r.gains))
                detail = _shortfall(r.worst_constraint, cand, params, settings)
                raise InfeasibleRequirement(r.worst_constraint, f"{detail} (IPOPT: {r.status} after {r.iterations} "
                                                               f"iterations)", stats)
            raise SolverError("ipopt", f"not converged from any start (last: {r.status} after {r.iterations} "
                                       f"iterations, J/J0 = {r.objective:.4g})", stats)
        best = min(feasible, key=lambda r: (round(r.objective, 12), r.start))
        tuned = design_with_gains(design, settings.tuned, best.gains)
        _say(settings, f"tune: round {rnd}: judging {', '.join(f'{v:.5g}' for v in best.gains)} on every requirement "
                       "(the verdict of thsa check) ...")
        verdict = _judge(tuned, params, settings, suite)
        rounds.append({"round": rnd, "gains": list(best.gains), "constraint_runs": [list(k) for k in run_set],
                       "failing": list(verdict.failing()), "excess_tolerance": tol_ex,
                       "overshoot_limit": osettings.overshoot_limit, "current_fraction": osettings.current_fraction})
        if verdict.passed:
            _say(settings, f"tune: round {rnd}: every requirement met")
            break
        _say(settings, f"tune: round {rnd}: not met: {', '.join(verdict.failing())}")
        n_before = len(run_set)
        failing_runs = _add_failing_runs(verdict, run_set, settings, design)
        added = len(run_set) > n_before
        if failing_runs and not added:
            # a constrained run still fails its peak current or overshoot as the verdict measures it: aim the
            # excess constraints lower by the shortfall (at least 0.5 % of the command / of the clamp)
            osettings = _tighter_excess(osettings, verdict, design)
            _say(settings, f"tune: round {rnd}: constrained runs still exceed; overshoot constraint now "
                           f"{100 * osettings.overshoot_limit:.3g} %, current constraint "
                           f"{osettings.current_fraction:.4g} x clamp")
            objective = Objective(main_sim, params, design, scen, tuned=settings.tuned, settings=osettings)
            objective.stage_functions()
            added = True
        tightened = _tighten(verdict, robust)
        if not added and not tightened:
            break
    if verdict is None or not verdict.passed:
        failing = verdict.failures if verdict is not None else ()
        first = failing[0] if failing else None
        name = first.requirement if first else "unknown"
        detail = (f"after {len(rounds)} round(s) the best gains ({', '.join(f'{v:.5g}' for v in best.gains)}) still "
                  "miss: " + "; ".join(f"{r.requirement} = {r.limit:g}: worst {r.value:.4g} {r.unit} at "
                                       f"{r.worst_point}" for r in failing))
        raise InfeasibleRequirement(name, detail)
    _say(settings, "tune: checking on the exact compiled simulator and the loop analysis ...")
    T_before = objective.reference_terms(g_src)
    T_after = objective.reference_terms(np.array(best.gains))
    w = settings.objective.weights
    m_before = exact_margins(design, params, settings.robust_temperatures, level=settings.level, effects=settings.effects)
    m_after = exact_margins(tuned, params, settings.robust_temperatures, level=settings.level, effects=settings.effects)
    return TuningResult(tuned, design, tuple(r for r, _ in results), best, settings.tuned, T_before, T_after,
                        float(np.sum(T_before @ w)), float(np.sum(T_after @ w)), tuple(s.name for s in scen),
                        m_before, m_after, settings, time.perf_counter() - t_all, _evaluations(objective, extras),
                        verdict, tuple(rounds))


def _linear_feasibility(robust: RobustConstraints, q, kp, ki, starts, g_src, settings: TuneSettings, design: Design,
                        params, lb: float) -> None:
    """Raise :class:`InfeasibleRequirement` when no gains within the bounds meet the linear requirements.

    Cheap (no simulation): maximise ``t`` subject to every smooth linear constraint ``>= t``; a negative optimum
    names the constraint that stays violated, before any simulation-based iteration can blame another one.
    """
    g_rob = robust.casadi_constraints(kp, ki)
    t = ca.MX.sym("t")
    n = q.size1()
    nlp = {"x": ca.vertcat(q, t), "f": -t, "g": g_rob - t}
    opts = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
            "ipopt.hessian_approximation": "limited-memory", "ipopt.max_iter": 200, "error_on_fail": False}
    solver = ca.nlpsol("tune_linear_feasibility", "ipopt", nlp, opts)
    rob_fn = ca.Function("robust_feas", [q], [g_rob])
    best = None
    for label, start in starts.items():
        x0 = np.log(np.clip(gains_of(start, settings.tuned) / g_src, 1.0 / settings.bound_factor, settings.bound_factor))
        c0 = np.asarray(rob_fn(x0), float).ravel()
        sol = solver(x0=np.concatenate([x0, [min(c0.min(), 1.0)]]), lbx=[lb] * n + [-np.inf], ubx=[-lb] * n + [1.0],
                     lbg=0.0, ubg=np.inf)
        qf = np.asarray(sol["x"], float).ravel()[:n]
        c = np.asarray(rob_fn(qf), float).ravel()
        if best is None or c.min() > best[1].min():
            best = (qf, c)
    qf, c = best
    if c.min() < -1e-6:
        k = int(np.argmin(c))
        name = robust.names[k]
        cand = design_with_gains(design, settings.tuned, g_src * np.exp(qf))
        raise InfeasibleRequirement(name, _shortfall(name, cand, params, settings)
                                    + " (no gains within the bounds meet the linear requirements)")
    _say(settings, f"tune: the linear requirements can be met (worst smooth constraint {c.min():.3g} at the most "
                   "feasible gains)")


def linear_temperatures(design: Design, settings: TuneSettings) -> tuple[float, ...]:
    """Temperatures of the linear constraints: the robust set and every temperature of the design's analysis grid."""
    from ..loops.analysis import AnalysisSettings

    grid = AnalysisSettings.from_design(design).temperatures
    return tuple(sorted({float(t) for t in settings.robust_temperatures} | {float(t) for t in grid}))


def _judge(design: Design, params, settings: TuneSettings, suite):
    from ..verdict import evaluate_design

    return evaluate_design(design, params, levels=settings.check_levels, temperatures=settings.check_temperatures,
                           scenarios=suite, effects=settings.effects)


def _fixed_requirements(design: Design, params, settings: TuneSettings) -> None:
    """Requirements the tuned velocity gains cannot change (the current loop's) must hold already."""
    from ..loops.analysis import AnalysisSettings, analyse_loops
    from ..verdict import linear_verdict

    req = {k: v for k, v in design.requirements.items() if k == "current_loop"}
    if not req:
        return
    a = analyse_loops(design, params, settings=AnalysisSettings.from_design(design), steps=True)
    for r in linear_verdict(a, req):
        if not r.passed:
            raise InfeasibleRequirement(r.requirement, f"the current loop (not tuned) gives {r.value:.4g} {r.unit} at "
                                                       f"{r.worst_point} against the limit {r.limit:g}: no velocity "
                                                       "gain changes it")


_EXCESS_METRICS = {"max_current_peak_A": "current_peak_A", "max_overshoot_percent": "overshoot_percent"}


def _add_failing_runs(verdict, run_set: dict, settings: TuneSettings, design: Design) -> list:
    """Add every validation run whose current peak or overshoot failed to the constraint runs.

    Returns the failing runs (new or already constrained)."""
    from ..verdict import validation_limits

    limits = validation_limits(design)
    failing = []
    for key, doc in verdict.metrics.items():
        lv, T, name = key.split("|")
        for req, attr in _EXCESS_METRICS.items():
            if doc[attr] > limits[req][0]:
                failing.append((lv, float(T), name))
                run_set.setdefault((lv, float(T), name), None)
    return failing


def _tighter_excess(osettings: ObjectiveSettings, verdict, design: Design) -> ObjectiveSettings:
    """Objective settings whose overshoot / current limits sit below what the verdict measured failing."""
    from dataclasses import replace

    from ..verdict import validation_limits

    limits = validation_limits(design)
    over = max((d["overshoot_percent"] for d in verdict.metrics.values()), default=0.0)
    peak = max((d["current_peak_A"] for d in verdict.metrics.values()), default=0.0)
    ol, cf = osettings.overshoot_limit, osettings.current_fraction
    if over > limits["max_overshoot_percent"][0]:
        ol = max(0.0, ol - max(0.005, (over - limits["max_overshoot_percent"][0]) / 100.0))
    if peak > limits["max_current_peak_A"][0]:
        cf = max(0.5, cf - max(0.005, (peak - limits["max_current_peak_A"][0]) / design.current_limit))
    return replace(osettings, overshoot_limit=ol, current_fraction=cf)


_TIGHTEN = {"min_phase_margin_deg": +1, "min_gain_margin_db": +1, "min_delay_margin_s": +1, "min_bandwidth_hz": +1,
            "max_sensitivity_peak": -1, "max_overshoot_percent": -1, "max_settling_time_s": -1}


def _tighten(verdict, robust: RobustConstraints) -> bool:
    """Tighten the smooth constraint of every failing velocity-loop requirement by twice its shortfall."""
    changed = False
    for r in verdict.failures:
        loop, _, key = r.requirement.partition(".")
        if loop != "velocity_loop" or key not in _TIGHTEN or not math.isfinite(r.value):
            continue
        target = robust.limit(key)
        if target is None:
            continue
        short = (r.limit - r.value) if _TIGHTEN[key] > 0 else (r.value - r.limit)
        new = target + _TIGHTEN[key] * 2.0 * max(short, 0.02 * abs(r.limit))
        if _TIGHTEN[key] < 0 and new <= 0:
            continue
        robust.set_limit(key, new)
        changed = True
    return changed


def _evaluations(objective: Objective, extras) -> dict:
    out = dict(objective.evaluations)
    if extras:
        out["constraint_runs"] = {k: sum(e.evaluations[k] for e in extras) for k in extras[0].evaluations}
    return out


def _shortfall(name: str, design: Design, params, settings: TuneSettings) -> str:
    """By how much the least-infeasible point misses constraint ``name``, in the requirement's units."""
    if name.startswith("current"):
        return "the current exceeds the clamp in the validation runs at every reachable gain"
    if name.startswith("speed above"):
        return (f"the nut speed overshoots the command by more than {100 * settings.objective.overshoot_limit:g} % "
                "on a plateau of the validation runs at every reachable gain")
    from ..loops.analysis import AnalysisSettings, analyse_loops
    from ..verdict import linear_verdict

    key, _, rest = name.partition(" at ")
    T = float(rest.split()[0])
    req = dict(design.requirements.get("velocity_loop", {}))
    if settings.requirements:
        req.update(settings.requirements)
    a = analyse_loops(design, params, settings=AnalysisSettings.from_design(design, level=settings.level,
                                                                            effects=settings.effects,
                                                                            temperatures=(T,)))
    row = next((r for r in linear_verdict(a, {"velocity_loop": {key: req[key]}}) if r.requirement.endswith(key)), None)
    if row is None or not math.isfinite(row.value):
        return f"no valid point to judge it at {T:g} degC"
    gap = (row.limit - row.value) if key.startswith("min_") else (row.value - row.limit)
    word = "short of the required" if key.startswith("min_") else "above the allowed"
    return (f"at the least-infeasible point IPOPT reached, velocity_loop.{key} at {T:g} degC is {row.value:.4g} "
            f"{row.unit} ({row.worst_point}), {gap:.3g} {row.unit} {word} {row.limit:g} {row.unit}")
