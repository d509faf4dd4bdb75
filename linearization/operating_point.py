"""Operating points: solve ``f(x, u, p) = 0`` with chosen signals held.

An :class:`OperatingPointSpec` says which inputs, states and outputs are held
(and at what value); the remaining states and inputs are the unknowns.  The
equations are ``xdot[i] = 0`` for every non-drifting state and
``y[j] = target`` for every held output.  Drifting states (positions moving at
a constant rate in a steady motion) are not unknowns: their value is the held
or guessed one, and their derivative is reported as a drift rate.  (So an
output that depends only on a drifting state cannot be solved for: hold the
state instead.)

Square problems are solved with a casadi rootfinder (``newton`` by default,
``kinsol`` on request); non-square ones with ``nlpsol('ipopt')`` when this
casadi build has it, else with a damped Gauss-Newton (Levenberg-Marquardt)
loop on casadi-evaluated residuals and Jacobians, which is also the fallback
when the first method does not converge.  Failure raises
:class:`~linearization.errors.OperatingPointError` naming the residual norm
and the worst equation.

Imports numpy and casadi only; never imports ``thsa_control``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import casadi as ca
import numpy as np

from ._typing import ArrayLike, Float1D, Float2D
from .errors import OperatingPointError, UnknownSignalError
from .model import NamedModel

__all__ = [
    "OperatingPointSpec",
    "SolverSettings",
    "OperatingPoint",
    "OperatingPointBatch",
    "find_operating_point",
    "find_operating_points",
    "OperatingPointError",
]

_METHODS = ("auto", "newton", "kinsol", "ipopt", "gauss-newton")


def _float_dict(label: str, values: Mapping[str, float] | None) -> dict[str, float] | None:
    if values is None:
        return None
    if not isinstance(values, Mapping):
        raise TypeError(f"{label} must be a mapping name -> value, got {type(values).__name__}")
    out = {}
    for key, val in values.items():
        fval = float(val)
        if not np.isfinite(fval):
            raise ValueError(f"{label}[{key!r}] is not finite: {val!r}")
        out[str(key)] = fval
    return out


@dataclass(frozen=True)
class OperatingPointSpec:
    """What is held at an operating point, and where the search starts.

    Parameters
    ----------
    inputs : mapping of str to float, optional
        Held inputs [input units].  The other inputs are unknowns.
    outputs : mapping of str to float, optional
        Held outputs (targets) [output units]; each adds one equation.
    states : mapping of str to float, optional
        Held states [state units].  A held non-drifting state keeps its
        equation ``xdot = 0`` (so it frees one input to be solved for).
    guess_x : mapping of str to float or None, optional
        Initial guess of unknown states, and value of non-held drifting
        states [state units].  Missing names start at 0.
    guess_u : mapping of str to float or None, optional
        Initial guess of unknown inputs [input units].  Missing names start
        at 0.

    Examples
    --------
    >>> spec = OperatingPointSpec(inputs={"load": 0.5}, outputs={"speed": 100.0})
    >>> spec.outputs
    {'speed': 100.0}
    """

    inputs: Mapping[str, float] = field(default_factory=dict)
    outputs: Mapping[str, float] = field(default_factory=dict)
    states: Mapping[str, float] = field(default_factory=dict)
    guess_x: Mapping[str, float] | None = None
    guess_u: Mapping[str, float] | None = None

    def __post_init__(self) -> None:
        for attr in ("inputs", "outputs", "states", "guess_x", "guess_u"):
            object.__setattr__(self, attr, _float_dict(attr, getattr(self, attr)))
            if attr in ("inputs", "outputs", "states") and getattr(self, attr) is None:
                object.__setattr__(self, attr, {})

    def validate(self, model: NamedModel) -> None:
        """Check every name against ``model``.

        Raises
        ------
        UnknownSignalError
            Naming the first unknown signal and listing the valid names.
        """
        for kind, values in (
            ("input", self.inputs),
            ("output", self.outputs),
            ("state", self.states),
            ("state", self.guess_x or {}),
            ("input", self.guess_u or {}),
        ):
            names = model.names(kind)  # type: ignore[arg-type]
            for key in values:
                if key not in names:
                    raise UnknownSignalError(kind, key, names)

    def pattern(self, model: NamedModel) -> tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]:
        """Indices of held states, inputs and outputs, in model order."""
        self.validate(model)
        return (
            tuple(i for i, n in enumerate(model.states) if n in self.states),
            tuple(i for i, n in enumerate(model.inputs) if n in self.inputs),
            tuple(i for i, n in enumerate(model.outputs) if n in self.outputs),
        )


@dataclass(frozen=True)
class SolverSettings:
    """Settings of the operating-point solver.

    Parameters
    ----------
    method : {'auto', 'newton', 'kinsol', 'ipopt', 'gauss-newton'}, optional
        ``'auto'`` (default) uses casadi ``newton`` on square problems and
        ``ipopt`` (or Gauss-Newton if ipopt is missing) otherwise.
    tol : float, optional
        Largest accepted absolute equation residual [unit of each equation].
        Default 1e-9.
    max_iter : int, optional
        Iteration limit of each method.  Default 100.
    fallback : bool, optional
        Retry with damped Gauss-Newton when the first method fails.
        Default True.
    """

    method: Literal["auto", "newton", "kinsol", "ipopt", "gauss-newton"] = "auto"
    tol: float = 1e-9
    max_iter: int = 100
    fallback: bool = True

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raise ``ValueError`` naming the first invalid setting."""
        if self.method not in _METHODS:
            raise ValueError(f"SolverSettings.method={self.method!r}; valid: {_METHODS}")
        if not (self.tol > 0 and np.isfinite(self.tol)):
            raise ValueError(f"SolverSettings.tol must be > 0, got {self.tol!r}")
        if int(self.max_iter) < 1:
            raise ValueError(f"SolverSettings.max_iter must be >= 1, got {self.max_iter!r}")
        if self.method == "ipopt" and not ca.has_nlpsol("ipopt"):
            raise ValueError("SolverSettings.method='ipopt' but this casadi build has no ipopt")


@dataclass(frozen=True, eq=False)
class OperatingPoint:
    """A point ``(x, u, p)`` of a model, with its outputs and residuals.

    Parameters
    ----------
    x : numpy.ndarray
        States [state units].
    u : numpy.ndarray
        Inputs [input units].
    y : numpy.ndarray
        Outputs ``y(x, u, p)`` [output units].
    p : numpy.ndarray
        Parameters [parameter units].
    states, inputs, outputs, parameters : tuple of str
        Names of the elements of ``x``, ``u``, ``y``, ``p``.
    residual : float
        Largest absolute residual of the equations solved (``xdot = 0`` of
        the non-drifting states, held outputs) [unit of each equation].
    drift_rates : dict of str to float
        ``xdot`` of each drifting state [state units / s].
    xdot : numpy.ndarray
        All state derivatives at the point [state units / s].
    drifting_states : tuple of str
        Names of the drifting states of the model.
    method : str
        How the point was obtained (solver chain, or ``'given'``).
    """

    x: Float1D
    u: Float1D
    y: Float1D
    p: Float1D
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    parameters: tuple[str, ...]
    residual: float
    drift_rates: dict[str, float]
    xdot: Float1D
    drifting_states: tuple[str, ...] = ()
    method: str = "given"

    def __post_init__(self) -> None:
        for attr in ("x", "u", "y", "p", "xdot"):
            arr = np.array(getattr(self, attr), dtype=float).reshape(-1)
            arr.setflags(write=False)
            object.__setattr__(self, attr, arr)

    @classmethod
    def from_values(
        cls,
        model: NamedModel,
        x: Mapping[str, float] | ArrayLike,
        u: Mapping[str, float] | ArrayLike,
        p: Mapping[str, float] | ArrayLike,
    ) -> "OperatingPoint":
        """Wrap a given point (not necessarily an equilibrium) without solving.

        Parameters
        ----------
        model : NamedModel
            The model.
        x, u, p : mapping or array_like
            States, inputs, parameters, by name (all required) or as vectors.

        Returns
        -------
        OperatingPoint
            With ``residual`` the largest ``|xdot|`` of non-drifting states.

        Examples
        --------
        >>> from linearization.examples import mass_spring_damper
        >>> m = mass_spring_damper()
        >>> op = OperatingPoint.from_values(m, [0.1, 0.0], [0.0], [1.0, 0.5, 2.0])
        >>> round(op.residual, 12), op.output("position")
        (0.2, 0.1)
        """
        xv = model.vector("state", x)
        uv = model.vector("input", u)
        pv = model.parameter_vector(p)
        xdot, y = model.evaluate(xv, uv, pv)
        eq = [i for i, n in enumerate(model.states) if n not in model.drifting_states]
        residual = float(np.max(np.abs(xdot[eq]))) if eq else 0.0
        return cls(
            x=xv, u=uv, y=y, p=pv,
            states=model.states, inputs=model.inputs, outputs=model.outputs,
            parameters=model.parameters, residual=residual,
            drift_rates={n: float(xdot[model.state_index(n)]) for n in model.drifting_states},
            xdot=xdot, drifting_states=model.drifting_states, method="given",
        )

    def _get(self, names: tuple[str, ...], vec: Float1D, kind: str, name: str) -> float:
        try:
            return float(vec[names.index(name)])
        except ValueError:
            raise UnknownSignalError(kind, name, names) from None

    def state(self, name: str) -> float:
        """Value of state ``name`` [state unit]."""
        return self._get(self.states, self.x, "state", name)

    def input(self, name: str) -> float:
        """Value of input ``name`` [input unit]."""
        return self._get(self.inputs, self.u, "input", name)

    def output(self, name: str) -> float:
        """Value of output ``name`` [output unit]."""
        return self._get(self.outputs, self.y, "output", name)

    def parameter(self, name: str) -> float:
        """Value of parameter ``name`` [parameter unit]."""
        return self._get(self.parameters, self.p, "parameter", name)

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{'states': {...}, 'inputs': {...}, 'outputs': {...}, 'parameters': {...}}``."""
        return {
            "states": dict(zip(self.states, map(float, self.x))),
            "inputs": dict(zip(self.inputs, map(float, self.u))),
            "outputs": dict(zip(self.outputs, map(float, self.y))),
            "parameters": dict(zip(self.parameters, map(float, self.p))),
        }


@dataclass(frozen=True, eq=False)
class OperatingPointBatch:
    """Operating points over a grid, column-stacked.

    Parameters
    ----------
    X, U, Y, P, XDOT : numpy.ndarray, shape (n_signals, N)
        States, inputs, outputs, parameters and state derivatives, one column
        per point [signal units].
    states, inputs, outputs, parameters, drifting_states : tuple of str
        Names of the rows.
    residuals : numpy.ndarray, shape (N,)
        Largest absolute equation residual per point.
    converged : numpy.ndarray of bool, shape (N,)
        Whether the point met the solver tolerance.
    methods : tuple of str
        Solver chain per point.
    """

    X: Float2D
    U: Float2D
    Y: Float2D
    P: Float2D
    XDOT: Float2D
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    parameters: tuple[str, ...]
    drifting_states: tuple[str, ...]
    residuals: Float1D
    converged: np.ndarray
    methods: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.X.shape[1])

    def __getitem__(self, k: int) -> OperatingPoint:
        """The ``k``-th point as an :class:`OperatingPoint`."""
        n = len(self)
        if not -n <= k < n:
            raise IndexError(f"point {k} out of range for a batch of {n}")
        return OperatingPoint(
            x=self.X[:, k], u=self.U[:, k], y=self.Y[:, k], p=self.P[:, k],
            states=self.states, inputs=self.inputs, outputs=self.outputs,
            parameters=self.parameters, residual=float(self.residuals[k]),
            drift_rates={
                s: float(self.XDOT[self.states.index(s), k]) for s in self.drifting_states
            },
            xdot=self.XDOT[:, k], drifting_states=self.drifting_states,
            method=self.methods[k],
        )

    @property
    def drift_rates(self) -> dict[str, Float1D]:
        """``xdot`` of each drifting state per point [state units / s]."""
        return {s: self.XDOT[self.states.index(s)].copy() for s in self.drifting_states}


# --------------------------------------------------------------------------
# The algebraic problem for one "held" pattern, compiled once per model.
# --------------------------------------------------------------------------
class _Problem:
    """Residual r(z, q) for one held pattern; q = [p; x_fixed; u_fixed; y_target]."""

    def __init__(self, model: NamedModel, pattern: tuple[tuple[int, ...], ...]):
        held_x, held_u, held_y = pattern
        self.model = model
        drifting = {model.state_index(s) for s in model.drifting_states}
        self.free_x = tuple(i for i in range(model.n_x) if i not in held_x and i not in drifting)
        self.free_u = tuple(i for i in range(model.n_u) if i not in held_u)
        self.eq_x = tuple(i for i in range(model.n_x) if i not in drifting)
        self.held_y = held_y
        self.n_z = len(self.free_x) + len(self.free_u)
        self.n_eq = len(self.eq_x) + len(self.held_y)
        self.equation_names = tuple(f"d({model.states[i]})/dt = 0" for i in self.eq_x) + tuple(
            f"output {model.outputs[j]} = target" for j in self.held_y
        )

        sym = model.symbol_type
        z = sym.sym("z", self.n_z)
        q = sym.sym("q", model.n_p + model.n_x + model.n_u + len(held_y))
        p = q[: model.n_p]
        x_fixed = q[model.n_p : model.n_p + model.n_x]
        u_fixed = q[model.n_p + model.n_x : model.n_p + model.n_x + model.n_u]
        y_target = q[model.n_p + model.n_x + model.n_u :]
        zx = dict(zip(self.free_x, range(len(self.free_x))))
        zu = dict(zip(self.free_u, range(len(self.free_x), self.n_z)))
        x = ca.vertcat(*[z[zx[i]] if i in zx else x_fixed[i] for i in range(model.n_x)])
        u = ca.vertcat(*[z[zu[i]] if i in zu else u_fixed[i] for i in range(model.n_u)])
        if model.n_x == 0:
            x = sym(0, 1)
        if model.n_u == 0:
            u = sym(0, 1)
        xdot, y = model.function(x, u, p)
        parts = [xdot[i] for i in self.eq_x] + [
            y[j] - y_target[k] for k, j in enumerate(held_y)
        ]
        r = ca.densify(ca.vertcat(*parts)) if parts else sym(0, 1)
        self.z_sym, self.q_sym, self.r_sym = z, q, r
        self.residual_fn = ca.Function("op_residual", [z, q], [r], ["z", "q"], ["r"])
        self.jacobian_fn = ca.Function(
            "op_jacobian", [z, q], [ca.densify(ca.jacobian(r, z))], ["z", "q"], ["J"]
        )
        self._solvers: dict[Any, ca.Function] = {}

    @property
    def square(self) -> bool:
        return self.n_z == self.n_eq and self.n_z > 0

    def q_vector(self, p: Float1D, spec: OperatingPointSpec) -> Float1D:
        m = self.model
        guess_x = spec.guess_x or {}
        x_fixed = np.array(
            [spec.states.get(n, guess_x.get(n, 0.0)) for n in m.states], dtype=float
        )
        u_fixed = np.array([spec.inputs.get(n, 0.0) for n in m.inputs], dtype=float)
        y_target = np.array([spec.outputs[m.outputs[j]] for j in self.held_y], dtype=float)
        return np.concatenate([p, x_fixed, u_fixed, y_target])

    def z_guess(self, spec: OperatingPointSpec) -> Float1D:
        m = self.model
        gx, gu = spec.guess_x or {}, spec.guess_u or {}
        return np.array(
            [gx.get(m.states[i], 0.0) for i in self.free_x]
            + [gu.get(m.inputs[i], 0.0) for i in self.free_u],
            dtype=float,
        )

    def assemble(self, z: Float1D, q: Float1D) -> tuple[Float1D, Float1D]:
        m = self.model
        x = q[m.n_p : m.n_p + m.n_x].copy()
        u = q[m.n_p + m.n_x : m.n_p + m.n_x + m.n_u].copy()
        x[list(self.free_x)] = z[: len(self.free_x)]
        u[list(self.free_u)] = z[len(self.free_x) :]
        return x, u

    def residual(self, z: Float1D, q: Float1D) -> Float1D:
        return np.asarray(self.residual_fn(z, q), dtype=float).reshape(-1)

    def rootfinder(self, method: str, settings: SolverSettings) -> ca.Function:
        key = ("rf", method, settings.tol, settings.max_iter)
        if key not in self._solvers:
            opts = {
                "abstol": settings.tol * 1e-3,
                "max_iter": int(settings.max_iter),
                "error_on_fail": False,
            }
            self._solvers[key] = ca.rootfinder("op_rootfinder", method, self.residual_fn, opts)
        return self._solvers[key]

    def ipopt(self, settings: SolverSettings) -> ca.Function:
        key = ("ipopt", settings.tol, settings.max_iter)
        if key not in self._solvers:
            z, q, r = self.z_sym, self.q_sym, self.r_sym
            z0 = self.model.symbol_type.sym("z0", self.n_z)
            opts = {
                "print_time": False,
                "error_on_fail": False,
                "ipopt.print_level": 0,
                "ipopt.sb": "yes",
                "ipopt.tol": settings.tol * 1e-3,
                "ipopt.max_iter": int(settings.max_iter) * 10,
            }
            if self.n_eq < self.n_z:
                # Under-determined: the solution closest to the guess.
                nlp = {"x": z, "p": ca.vertcat(q, z0), "f": 0.5 * ca.sumsqr(z - z0), "g": r}
            else:
                nlp = {"x": z, "p": ca.vertcat(q, z0), "f": 0.5 * ca.sumsqr(r)}
            self._solvers[key] = ca.nlpsol("op_ipopt", "ipopt", nlp, opts)
        return self._solvers[key]


def _problem(model: NamedModel, spec: OperatingPointSpec) -> _Problem:
    pattern = spec.pattern(model)
    key = ("op_problem", pattern)
    if key not in model._cache:
        model._cache[key] = _Problem(model, pattern)
    return model._cache[key]


def _gauss_newton(prob: _Problem, z0: Float1D, q: Float1D, tol: float, max_iter: int) -> Float1D:
    """Levenberg-Marquardt on r(z); handles square, over- and under-determined."""
    z = z0.copy()
    r = prob.residual(z, q)
    if not np.all(np.isfinite(r)):
        return z
    cost = float(r @ r)
    lam = 1e-3
    for _ in range(4 * int(max_iter)):
        if r.size == 0 or np.max(np.abs(r)) <= tol:
            break
        J = np.asarray(prob.jacobian_fn(z, q), dtype=float).reshape(prob.n_eq, prob.n_z)
        col = np.sqrt(np.sum(J * J, axis=0))
        col = np.maximum(col, 1e-12 * max(1.0, float(np.max(col, initial=0.0))))
        lhs = np.vstack([J, np.sqrt(lam) * np.diag(col)])
        rhs = np.concatenate([-r, np.zeros(prob.n_z)])
        step = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
        z_new = z + step
        r_new = prob.residual(z_new, q)
        cost_new = float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
        if cost_new < cost:
            z, r, cost = z_new, r_new, cost_new
            lam = max(lam / 5.0, 1e-14)
        else:
            lam *= 4.0
            if lam > 1e14:
                break
        if np.max(np.abs(step)) <= 1e-15 * max(1.0, float(np.max(np.abs(z), initial=0.0))):
            break
    return z


def _max_abs(r: Float1D) -> float:
    if r.size == 0:
        return 0.0
    return float(np.max(np.abs(r))) if np.all(np.isfinite(r)) else np.inf


def _solve(
    prob: _Problem, z0: Float1D, q: Float1D, settings: SolverSettings
) -> tuple[Float1D, str, bool]:
    """Run the solver chain from z0; return (z, chain description, converged)."""
    if prob.n_z == 0:
        return z0, "none (no unknowns)", _max_abs(prob.residual(z0, q)) <= settings.tol
    method = settings.method
    if method == "auto":
        if prob.square:
            method = "newton"
        else:
            method = "ipopt" if ca.has_nlpsol("ipopt") else "gauss-newton"
    if method in ("newton", "kinsol") and not prob.square:
        raise ValueError(
            f"method {method!r} needs as many unknowns as equations; this spec has "
            f"{prob.n_z} unknowns and {prob.n_eq} equations ({list(prob.equation_names)})"
        )
    if method in ("newton", "kinsol"):
        z = np.asarray(prob.rootfinder(method, settings)(z0, q), dtype=float).reshape(-1)
    elif method == "ipopt":
        bounds = {"lbg": 0.0, "ubg": 0.0} if prob.n_eq < prob.n_z else {}
        sol = prob.ipopt(settings)(x0=z0, p=np.concatenate([q, z0]), **bounds)
        z = np.asarray(sol["x"], dtype=float).reshape(-1)
    else:
        z = _gauss_newton(prob, z0, q, settings.tol, settings.max_iter)
    best = _max_abs(prob.residual(z, q))
    chain = method
    if best > settings.tol and settings.fallback and method != "gauss-newton":
        start = z if best <= _max_abs(prob.residual(z0, q)) else z0
        z = _gauss_newton(prob, start, q, settings.tol, settings.max_iter)
        best = _max_abs(prob.residual(z, q))
        chain = f"{method} -> gauss-newton"
    return z, chain, best <= settings.tol


def _failure(prob: _Problem, z: Float1D, q: Float1D, chain: str, tol: float, where: str):
    r = prob.residual(z, q)
    finite = np.where(np.isfinite(r), np.abs(r), np.inf)
    worst = int(np.argmax(finite)) if r.size else 0
    name = prob.equation_names[worst] if r.size else "(none)"
    norm = float(np.linalg.norm(r)) if np.all(np.isfinite(r)) else np.inf
    unknowns = [prob.model.states[i] for i in prob.free_x] + [
        prob.model.inputs[i] for i in prob.free_u
    ]
    return OperatingPointError(
        f"no operating point found{where} with {chain}: residual norm {norm:.3g} "
        f"(tol {tol:.3g} on each equation); worst equation {name!r} with residual "
        f"{(r[worst] if r.size else 0.0):.3g}; {prob.n_z} unknowns {unknowns}, "
        f"{prob.n_eq} equations",
        residual_norm=norm,
        worst_equation=name,
        worst_residual=float(r[worst]) if r.size else 0.0,
        method=chain,
    )


def find_operating_point(
    model: NamedModel,
    p: Mapping[str, float] | ArrayLike,
    spec: OperatingPointSpec | None = None,
    *,
    settings: SolverSettings | None = None,
) -> OperatingPoint:
    """Solve for the unknown states and inputs of an operating point.

    Parameters
    ----------
    model : NamedModel
        The model ``f(x, u, p) -> (xdot, y)``.
    p : mapping of str to float or array_like
        Parameter values [parameter units], by name (all required) or as a
        vector in model order.
    spec : OperatingPointSpec, optional
        Held signals and guesses.  Default: nothing held (all states and
        inputs unknown; the solution closest to the guess is returned).
    settings : SolverSettings, optional
        Solver settings; default ``SolverSettings()``.

    Returns
    -------
    OperatingPoint
        The point; ``residual`` is the largest absolute equation residual.

    Raises
    ------
    OperatingPointError
        If the residual exceeds ``settings.tol``; names the residual norm and
        the worst equation.
    UnknownSignalError
        If ``spec`` or ``p`` names a signal the model does not have.

    Examples
    --------
    Mass-spring-damper held by a constant force: ``k x = F``.

    >>> from linearization.examples import mass_spring_damper
    >>> m = mass_spring_damper()
    >>> op = find_operating_point(m, {"mass": 1.0, "damping": 0.5, "stiffness": 2.0},
    ...                           OperatingPointSpec(inputs={"force": 3.0}))
    >>> round(op.state("position"), 12), round(op.state("velocity"), 12)
    (1.5, 0.0)
    """
    settings = settings or SolverSettings()
    spec = spec or OperatingPointSpec()
    pv = model.parameter_vector(p)
    prob = _problem(model, spec)
    q = prob.q_vector(pv, spec)
    z, chain, ok = _solve(prob, prob.z_guess(spec), q, settings)
    if not ok:
        raise _failure(prob, z, q, chain, settings.tol, "")
    return _point(prob, z, q, pv, chain)


def _point(prob: _Problem, z: Float1D, q: Float1D, pv: Float1D, chain: str) -> OperatingPoint:
    model = prob.model
    x, u = prob.assemble(z, q)
    xdot, y = model.evaluate(x, u, pv)
    return OperatingPoint(
        x=x, u=u, y=y, p=pv,
        states=model.states, inputs=model.inputs, outputs=model.outputs,
        parameters=model.parameters, residual=_max_abs(prob.residual(z, q)),
        drift_rates={n: float(xdot[model.state_index(n)]) for n in model.drifting_states},
        xdot=xdot, drifting_states=model.drifting_states, method=chain,
    )


def find_operating_points(
    model: NamedModel,
    P_grid: ArrayLike,
    specs: OperatingPointSpec | Sequence[OperatingPointSpec] | None = None,
    *,
    settings: SolverSettings | None = None,
    on_failure: Literal["raise", "mark"] = "raise",
    parallelization: Literal["serial", "openmp", "thread"] = "serial",
) -> OperatingPointBatch:
    """Solve operating points over a grid of parameters (and specs).

    Points sharing the same held pattern and a square system are solved in
    one call of a casadi rootfinder mapped over the points; points that fail
    there (and non-square patterns) are retried one by one with the full
    solver chain of :func:`find_operating_point`.

    Parameters
    ----------
    model : NamedModel
        The model.
    P_grid : array_like, shape (n_p, N)
        Parameters, one column per point [parameter units].  A single column
        is repeated to the number of specs.
    specs : OperatingPointSpec or sequence of N of them, optional
        Held signals per point; one spec is used for every point.
    settings : SolverSettings, optional
        Solver settings; default ``SolverSettings()``.
    on_failure : {'raise', 'mark'}, optional
        ``'raise'`` (default) raises on the first failed point; ``'mark'``
        keeps the best iterate and sets ``converged[k] = False``.
    parallelization : {'serial', 'openmp', 'thread'}, optional
        casadi ``map`` parallelisation of the mapped rootfinder.

    Returns
    -------
    OperatingPointBatch

    Raises
    ------
    OperatingPointError
        With ``on_failure='raise'``, naming the point index, residual norm and
        worst equation.

    Examples
    --------
    >>> import numpy as np
    >>> from linearization.examples import mass_spring_damper
    >>> m = mass_spring_damper()
    >>> P = np.array([[1.0, 1.0], [0.5, 0.5], [2.0, 4.0]])  # stiffness 2 and 4 N/m
    >>> ops = find_operating_points(m, P, OperatingPointSpec(inputs={"force": 2.0}))
    >>> np.round(ops.X[0], 12).tolist()
    [1.0, 0.5]
    """
    if on_failure not in ("raise", "mark"):
        raise ValueError(f"on_failure={on_failure!r}; valid: 'raise', 'mark'")
    settings = settings or SolverSettings()
    P = np.asarray(P_grid, dtype=float)
    if P.ndim == 1:
        P = P.reshape(model.n_p, -1) if P.size != model.n_p else P.reshape(-1, 1)
    if P.shape[0] != model.n_p:
        raise ValueError(f"P_grid must have {model.n_p} rows {list(model.parameters)}, got {P.shape}")
    if specs is None:
        specs = OperatingPointSpec()
    if isinstance(specs, OperatingPointSpec):
        spec_list = [specs] * P.shape[1]
    else:
        spec_list = list(specs)
        if P.shape[1] == 1:
            P = np.repeat(P, len(spec_list), axis=1)
        if len(spec_list) != P.shape[1]:
            raise ValueError(f"{len(spec_list)} specs for {P.shape[1]} parameter columns")
    n = P.shape[1]
    for k in range(n):
        if not np.all(np.isfinite(P[:, k])):
            raise ValueError(f"P_grid column {k} is not finite")

    probs = [_problem(model, s) for s in spec_list]
    Z: list[Float1D | None] = [None] * n
    Q = [probs[k].q_vector(P[:, k], spec_list[k]) for k in range(n)]
    chains = [""] * n
    ok = np.zeros(n, dtype=bool)

    # Mapped rootfinder per square pattern.
    groups: dict[int, list[int]] = {}
    for k, prob in enumerate(probs):
        groups.setdefault(id(prob), []).append(k)
    for idx in groups.values():
        prob = probs[idx[0]]
        method = settings.method if settings.method != "auto" else "newton"
        if not prob.square or method not in ("newton", "kinsol"):
            continue
        Z0 = np.column_stack([prob.z_guess(spec_list[k]) for k in idx])
        Qg = np.column_stack([Q[k] for k in idx])
        rf = prob.rootfinder(method, settings).map(len(idx), parallelization)
        Zs = np.asarray(rf(Z0, Qg), dtype=float).reshape(prob.n_z, len(idx))
        R = np.asarray(
            prob.residual_fn.map(len(idx))(Zs, Qg), dtype=float
        ).reshape(prob.n_eq, len(idx))
        for col, k in enumerate(idx):
            Z[k] = Zs[:, col]
            chains[k] = f"{method} (mapped)"
            ok[k] = _max_abs(R[:, col]) <= settings.tol

    # Per-point chain for what is left.
    for k in range(n):
        if ok[k]:
            continue
        prob, spec = probs[k], spec_list[k]
        z, chain, ok[k] = _solve(prob, prob.z_guess(spec), Q[k], settings)
        Z[k], chains[k] = z, (f"{chains[k]}; retry {chain}" if chains[k] else chain)
        if not ok[k] and on_failure == "raise":
            raise _failure(prob, z, Q[k], chains[k], settings.tol, f" at point {k}")

    X = np.empty((model.n_x, n))
    U = np.empty((model.n_u, n))
    res = np.empty(n)
    for k in range(n):
        X[:, k], U[:, k] = probs[k].assemble(Z[k], Q[k])  # type: ignore[arg-type]
        res[k] = _max_abs(probs[k].residual(Z[k], Q[k]))  # type: ignore[arg-type]
    XDOT, Y = model.evaluate_many(X, U, P)
    return OperatingPointBatch(
        X=X, U=U, Y=Y, P=P, XDOT=XDOT,
        states=model.states, inputs=model.inputs, outputs=model.outputs,
        parameters=model.parameters, drifting_states=model.drifting_states,
        residuals=res, converged=ok, methods=tuple(chains),
    )
