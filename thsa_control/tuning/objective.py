"""The tuning objective: closed-loop nonlinear runs differentiated by casadi.

The simulator's ``sample`` Function (one control period: the cascade of
``loops/controllers.py`` and the plant step of ``model/plant.py``, the very
expressions the reference simulator compiles) is wrapped into a *stage*
that also accumulates the cost integrals of :data:`~.validation.COST_TERMS`,
with the tuned gains as an input.  Its forward sensitivity with respect to
the gains (``S_next = d stage/d s  S + d stage/d g``, casadi AD Jacobians of
the stage) is a second stage; ``mapaccum`` strings ``block`` periods of each
into one Function, which is compiled to C once (cached, like the simulator)
and chained over the run.  The gradient is thus exact for the discrete map
the simulator integrates: no smoothing of the friction was needed, because
the plant's implicit stick/slip step is continuous in its state (piecewise
smooth); the finite-difference test checks it.

Objective of a set of runs, for gains ``g``::

    J(g) = sum_runs  ISE + current_weight * int i^2 dt + rate_weight * int (di/dt / 1 kA/s)^2 dt

and the constraints ``int max(0, |i| - I_clamp)^2 dt <= tol`` (a smooth
measure of the current above the clamp, zero when the peak is within) and
the same for the nut speed above the allowed overshoot on plateaus.

One deviation from the reference simulator: an infinite jerk limit (no
acceleration limit in the shaper) is replaced by 1e12 m/s^3 in the objective,
because casadi's derivative of ``x / inf`` is NaN; with ``jerk * h`` far above
any acceleration it changes the shaped command by < 1e-12 relative.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import ThsaError
from ..loops.controllers import CONTROLLER_PARAMETERS, CONTROLLER_SIGNALS, CONTROLLER_STATES
from ..loops.design import Design
from ..model.params import ParameterSet
from ..sim.codegen import compile_functions
from ..sim.scenarios import Scenario
from ..sim.monitors import extensions_for
from ..sim.simulate import RUN_INPUTS, InputSeries, SimulationSettings, Simulator
from .validation import COST_TERMS, RATE_SCALE, cost_terms

__all__ = ["TUNABLE_GAINS", "ObjectiveSettings", "Objective", "design_with_gains", "gains_of"]

#: Gains the tuning may vary: controller parameter name -> Design attribute.
TUNABLE_GAINS: dict[str, str] = {
    "velocity_kp": "velocity_kp", "velocity_ki": "velocity_ki", "current_kp": "current_kp", "current_ki": "current_ki",
}
_FINITE_JERK = 1e12


def gains_of(design: Design, names) -> np.ndarray:
    """Values of the named gains of ``design`` (SI)."""
    return np.array([getattr(design, TUNABLE_GAINS[n]) for n in names], dtype=float)


def design_with_gains(design: Design, names, values, **changes) -> Design:
    """A copy of ``design`` with the named gains set (and other fields changed)."""
    from dataclasses import replace

    kw = {TUNABLE_GAINS[n]: float(v) for n, v in zip(names, values)}
    kw.update(changes)
    return replace(design, **kw)


@dataclass(frozen=True)
class ObjectiveSettings:
    """Weights and numerics of the objective.

    Parameters
    ----------
    current_weight : float
        Weight of ``int i^2 dt`` [(mm/s)^2 / A^2].
    rate_weight : float
        Weight of ``int (di/dt / 1 kA/s)^2 dt`` [(mm/s)^2].
    block : int
        Control periods per compiled ``mapaccum`` block.
    compiled : bool
        Compile the blocks to C (cached); False runs casadi's virtual machine.
    overshoot_limit : float
        Overshoot allowed on plateaus before ``overshoot_excess`` counts [-] (0.1: 10 %).
    current_fraction : float
        ``current_excess`` counts the current above this fraction of the clamp
        (0.99: a 1 % reserve, as the integral constraint tolerates brief excursions).
    """

    current_weight: float = 1e-6
    rate_weight: float = 0.05
    block: int = 1000
    compiled: bool = True
    overshoot_limit: float = 0.1
    current_fraction: float = 0.99

    def validate(self) -> None:
        """Raise ``ValueError`` naming the bad field."""
        for name in ("current_weight", "rate_weight"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise ValueError(f"ObjectiveSettings.{name} = {v!r} must be a finite number >= 0")
        if not (isinstance(self.block, int) and self.block >= 1):
            raise ValueError(f"ObjectiveSettings.block = {self.block!r} must be an integer >= 1")

    @property
    def weights(self) -> np.ndarray:
        """Weights of :data:`COST_TERMS` in J (the excesses are constraints, weight 0)."""
        return np.array([1.0, self.current_weight, self.rate_weight, 0.0, 0.0])


@dataclass(frozen=True)
class _Run:
    inputs: InputSeries
    scenario: Scenario | None
    extensions: tuple
    W: np.ndarray
    theta: np.ndarray
    s0: np.ndarray


class Objective:
    """Cost integrals of closed-loop runs as functions of the tuned gains, with exact gradients.

    Parameters
    ----------
    simulator : Simulator
        The plant (effect set) and its settings (``substeps``).
    params : ParameterSet
    design : Design
        The design whose other gains stay fixed.
    scenarios : sequence of Scenario or InputSeries
        The runs (temperatures included).
    tuned : sequence of str
        Names from :data:`TUNABLE_GAINS`.
    settings : ObjectiveSettings
    """

    def __init__(self, simulator: Simulator, params: ParameterSet, design: Design, scenarios, *,
                 tuned=("velocity_kp", "velocity_ki"), settings: ObjectiveSettings | None = None):
        self.simulator = simulator
        self.params = params
        self.design = design
        self.tuned = tuple(tuned)
        for n in self.tuned:
            if n not in TUNABLE_GAINS:
                raise ThsaError(f"cannot tune {n!r}; tunable gains are {', '.join(TUNABLE_GAINS)}")
        self.settings = settings or ObjectiveSettings()
        self.settings.validate()
        self.scenarios = tuple(scenarios)
        self._fns: dict = {}
        self._runs = None
        self.evaluations = {"value": 0, "gradient": 0, "value_s": 0.0, "gradient_s": 0.0}

    # ---- symbolic pieces
    def stage_functions(self, extensions=()) -> dict[str, ca.Function]:
        """``stage(s, w, theta, g) -> s_next`` and ``sens(s, S, w, theta, g) -> (s_next, S_next)``.

        ``s = [z; cost]``: simulator state (plant, controller, the loop
        extensions' states of a scenario that asks for them, e.g. the
        monitors of a fault scenario) and the running cost integrals;
        ``S = ds/dg`` (column-major flattened).
        """
        ext_key = tuple(e.key() for e in extensions)
        if ext_key in self._fns:
            return self._fns[ext_key]
        sim, plant = self.simulator, self.simulator.plant
        sample = sim.sample_function(tuple(extensions))
        nz, nw, nth = sample.size1_in(0), sample.size1_in(1), sample.size1_in(2)
        n_p = len(plant.parameters)
        ng, nc = len(self.tuned), len(COST_TERMS)
        outs = plant.outputs + CONTROLLER_SIGNALS
        s = ca.SX.sym("s", nz + nc)
        w = ca.SX.sym("w", nw)
        th = ca.SX.sym("theta", nth)
        g = ca.SX.sym("g", ng)
        th_g = ca.SX(th)
        for j, n in enumerate(self.tuned):
            th_g[n_p + CONTROLLER_PARAMETERS.index(n)] = g[j]
        z, c = s[:nz], s[nz:]
        z_next, y = sample(z, w, th_g)
        h = th[n_p + len(CONTROLLER_PARAMETERS)]
        e = (y[outs.index("speed_cmd")] - y[outs.index("nut_speed")]) * 1e3
        names = plant.state_names
        i = y[outs.index("motor_current")]
        i_next = z_next[names.index("motor_current")]
        if "standby_current" in names:
            i = i + y[outs.index("standby_current")]
            i_next = i_next + z_next[names.index("standby_current")]
        lim = self.settings.current_fraction * th[n_p + CONTROLLER_PARAMETERS.index("current_limit")]
        excess = ca.fmax(ca.fabs(i) - lim, 0.0)
        cmd = y[outs.index("speed_cmd")]
        cmd_next = z_next[len(names) + CONTROLLER_STATES.index("shaped_speed")]
        plateau = ca.logic_and(cmd_next == cmd, cmd != 0)
        over = ca.if_else(plateau, ca.fmax(ca.sign(cmd) * (y[outs.index("nut_speed")] - cmd)
                                           - self.settings.overshoot_limit * ca.fabs(cmd), 0.0), 0.0) * 1e3
        c_next = c + h * ca.vertcat(e ** 2, i ** 2, ((i_next - i) / h / RATE_SCALE) ** 2, excess ** 2, over ** 2)
        s_next = ca.vertcat(z_next, c_next)
        S = ca.SX.sym("S", (nz + nc) * ng)
        Sm = ca.reshape(S, nz + nc, ng)
        S_next = ca.jacobian(s_next, s) @ Sm + ca.jacobian(s_next, g)
        stage = ca.Function("tune_stage", [s, w, th, g], [s_next])
        sens = ca.Function("tune_sens", [ca.vertcat(s, S), w, th, g], [ca.vertcat(s_next, ca.vec(S_next))])
        B = self.settings.block
        fns = {"stage": stage, "sens": sens}
        for key, f in (("stage", stage), ("sens", sens)):
            acc = f.mapaccum(f"{f.name()}_acc", B)
            x = ca.MX.sym("x", f.size1_in(0))
            Wb = ca.MX.sym("W", nw, B)
            T = ca.MX.sym("theta", nth)
            G = ca.MX.sym("g", ng)
            out = acc(x, Wb, T, G)
            fns[key + "_block"] = ca.Function(f"{f.name()}_block{B}", [x, Wb, T, G], [out[:, B - 1]])
        if self.settings.compiled:
            tag = "thsa_tune_" + "_".join(self.tuned + tuple(e.name for e in extensions))
            compiled, _ = compile_functions([fns["stage"], fns["sens"], fns["stage_block"], fns["sens_block"]], tag)
            if compiled is not None:
                fns = dict(zip(("stage", "sens", "stage_block", "sens_block"), compiled))
        self._fns[ext_key] = fns
        return fns

    def runs(self) -> list[_Run]:
        """The runs with their input matrices, parameter vectors and initial states."""
        if self._runs is not None:
            return self._runs
        plant, h = self.simulator.plant, self.design.control_period
        out = []
        for sc in self.scenarios:
            scenario = sc if isinstance(sc, Scenario) else None
            inp = InputSeries.from_scenario(sc, h) if scenario is not None else sc
            extensions = extensions_for(scenario) if scenario is not None else ()
            loop = self.simulator.closed_loop(extensions)
            needed = tuple(inp.required_effects) + tuple(e for x in extensions for e in x.required_effects(scenario))
            missing = [e for e in dict.fromkeys(needed) if e not in plant.effects]
            if missing:
                raise ThsaError(f"run {inp.name!r} needs effect(s) {missing}; the plant has {list(plant.effects)}")
            jerk = inp.jerk_limit if math.isfinite(inp.jerk_limit) else _FINITE_JERK
            k = self.design.controller_vector(self.params, accel_limit=inp.accel_limit, jerk_limit=jerk,
                                              motor_off_at_zero=inp.motor_off_at_zero)
            theta = loop.theta(plant.p_vector(self.params), k, h)
            W = loop.input_matrix(inp, scenario)
            x0 = plant.initial_state(self.params, load_force=float(W[RUN_INPUTS.index("load_force"), 0]))
            s0 = np.concatenate([loop.initial_state(x0, k), np.zeros(len(COST_TERMS))])
            out.append(_Run(inp, scenario, extensions, W, theta, s0))
        self._runs = out
        return out

    # ---- evaluation
    def _chain(self, run: _Run, g: np.ndarray, sens: bool) -> np.ndarray:
        fns = self.stage_functions(run.extensions)
        B = self.settings.block
        ng = len(g)
        x = run.s0 if not sens else np.concatenate([run.s0, np.zeros(run.s0.size * ng)])
        blk, one = (fns["sens_block"], fns["sens"]) if sens else (fns["stage_block"], fns["stage"])
        W = run.W
        n = W.shape[1]
        nb = n // B
        for b in range(nb):
            x = blk(x, W[:, b * B:(b + 1) * B], run.theta, g)
        for k in range(nb * B, n):
            x = one(x, W[:, k], run.theta, g)
        return np.asarray(x, float).ravel()

    def terms(self, gains, *, gradient: bool = False):
        """Cost integrals of every run.

        Returns
        -------
        T : ndarray (n_runs, len(COST_TERMS))
        dT : ndarray (n_runs, len(COST_TERMS), n_gains), only with ``gradient=True``
        """
        g = np.asarray(gains, float).ravel()
        if g.size != len(self.tuned):
            raise ValueError(f"{g.size} gains given for {len(self.tuned)} tuned ({', '.join(self.tuned)})")
        runs = self.runs()
        nc = len(COST_TERMS)
        t0 = time.perf_counter()
        T, dT = [], []
        for run in runs:
            x = self._chain(run, g, gradient)
            ns = run.s0.size
            T.append(x[ns - nc:ns])
            if gradient:
                S = x[ns:].reshape(len(g), ns).T  # column-major (ns x ng)
                dT.append(S[ns - nc:ns, :])
        wall = time.perf_counter() - t0
        key = "gradient" if gradient else "value"
        self.evaluations[key] += 1
        self.evaluations[key + "_s"] += wall
        if gradient:
            return np.array(T), np.array(dT)
        return np.array(T)

    def value(self, gains) -> float:
        """``J(g)``."""
        return float(np.sum(self.terms(gains) @ self.settings.weights))

    def value_and_gradient(self, gains):
        """``J(g)``, ``dJ/dg``, the excesses (current, overshoot) and their gradients (2 x n_gains)."""
        T, dT = self.terms(gains, gradient=True)
        w = self.settings.weights
        J = float(np.sum(T @ w))
        dJ = np.einsum("rcg,c->g", dT, w)
        return J, dJ, T[:, 3:].sum(axis=0), dT[:, 3:, :].sum(axis=0)

    # ---- reference
    def reference_terms(self, gains) -> np.ndarray:
        """The same integrals from the compiled reference simulator (every control period sampled)."""
        design = design_with_gains(self.design, self.tuned, gains)
        sim = Simulator(self.simulator.plant, SimulationSettings(substeps=self.simulator.settings.substeps,
                                                                 output_period=None))
        out = []
        for run in self.runs():
            res = sim.run(run.scenario if run.scenario is not None else run.inputs, design, self.params,
                          extensions=run.extensions)
            terms = cost_terms(res, self.settings.current_fraction * design.current_limit,
                               self.simulator.plant.state_names,
                               self.settings.overshoot_limit)
            out.append([terms[k] for k in COST_TERMS])
        return np.array(out)
