"""Named casadi models: the one object every linearisation tool consumes.

A model is a casadi ``Function`` ``f(x, u, p) -> (xdot, y)`` with
``name_in=['x', 'u', 'p']`` and ``name_out=['xdot', 'y']`` (SX or MX, dense
column vectors) plus a name for every state, input, output and parameter.
This module owns that pairing, checks it once at construction, and answers
"which index is the signal called ...?" with errors that name the culprit.

Imports numpy and casadi only; never imports ``thsa_control``.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

import casadi as ca
import numpy as np

from ._typing import ArrayLike, Float1D, Float2D
from .buffered import call_dense
from .errors import ModelStructureError, UnknownSignalError

__all__ = ["NamedModel", "SignalKind"]

#: The four families of named signals of a model.
SignalKind = Literal["state", "input", "output", "parameter"]

_IN_NAMES = ("x", "u", "p")
_OUT_NAMES = ("xdot", "y")


def _as_names(kind: str, names: Iterable[str]) -> tuple[str, ...]:
    """Turn ``names`` into a tuple of unique non-empty strings, or raise."""
    if isinstance(names, str):
        raise ModelStructureError(
            f"{kind} names must be a sequence of str, got the single string {names!r}"
        )
    out = tuple(names)
    for name in out:
        if not isinstance(name, str) or not name:
            raise ModelStructureError(f"{kind} name {name!r} is not a non-empty str")
    seen: set[str] = set()
    dupes = [n for n in out if n in seen or seen.add(n)]  # type: ignore[func-returns-value]
    if dupes:
        raise ModelStructureError(f"duplicate {kind} names: {sorted(set(dupes))}")
    return out


@dataclass(frozen=True, eq=False)
class NamedModel:
    """A casadi model ``f(x, u, p) -> (xdot, y)`` with named signals.

    Parameters
    ----------
    function : casadi.Function
        Continuous-time model with inputs ``x`` [state units], ``u`` [input
        units], ``p`` [parameter units] and outputs ``xdot`` [state units / s]
        and ``y`` [output units], all column vectors.
    states, inputs, outputs, parameters : tuple of str
        One name per element of ``x``, ``u``, ``y`` and ``p``, in order.
    drifting_states : tuple of str, optional
        States that may drift at a constant rate in a steady motion (a
        position whose derivative is a speed).  They are excluded from the
        equilibrium condition ``xdot = 0`` and, by default, from the linear
        model.  Default ``()``.

    Raises
    ------
    ModelStructureError
        If the ``Function`` does not have the inputs ``x, u, p`` and outputs
        ``xdot, y``, if a size differs from the number of names (the message
        names the signal family and both sizes), if a name is repeated, or if
        a drifting state is not a state.

    Examples
    --------
    >>> import casadi as ca
    >>> x, u, p = ca.SX.sym("x", 2), ca.SX.sym("u", 1), ca.SX.sym("p", 1)
    >>> f = ca.Function("f", [x, u, p], [ca.vertcat(x[1], u - p * x[1]), x[0]],
    ...                 ["x", "u", "p"], ["xdot", "y"])
    >>> m = NamedModel(f, ("position", "velocity"), ("force",), ("position",),
    ...                ("damping",), drifting_states=("position",))
    >>> m.state_index("velocity"), m.n_x, m.n_u, m.n_y, m.n_p
    (1, 2, 1, 1, 1)
    >>> xdot, y = m.evaluate([0.0, 2.0], [1.0], {"damping": 0.5})
    >>> xdot.tolist(), y.tolist()
    ([2.0, 0.0], [0.0])
    """

    function: ca.Function
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    parameters: tuple[str, ...]
    drifting_states: tuple[str, ...] = ()
    # Memo of derived casadi Functions (Jacobians, solvers, maps).  Not part of
    # the model's identity; filled lazily by the other modules of the package.
    _cache: dict[Any, Any] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        f = self.function
        if not isinstance(f, ca.Function):
            raise ModelStructureError(
                f"function must be a casadi.Function, got {type(f).__name__}"
            )
        for attr in ("states", "inputs", "outputs", "parameters", "drifting_states"):
            object.__setattr__(self, attr, _as_names(attr[:-1], getattr(self, attr)))
        if f.n_in() != 3 or tuple(f.name_in()) != _IN_NAMES:
            raise ModelStructureError(
                f"function {f.name()!r} must have inputs {list(_IN_NAMES)}, "
                f"has {f.name_in()}"
            )
        if f.n_out() != 2 or tuple(f.name_out()) != _OUT_NAMES:
            raise ModelStructureError(
                f"function {f.name()!r} must have outputs {list(_OUT_NAMES)}, "
                f"has {f.name_out()}"
            )
        checks = (
            ("input", 0, "x", self.states),
            ("input", 1, "u", self.inputs),
            ("input", 2, "p", self.parameters),
            ("output", 0, "xdot", self.states),
            ("output", 1, "y", self.outputs),
        )
        for io, k, label, names in checks:
            shape = f.size_in(k) if io == "input" else f.size_out(k)
            n = shape[0] * shape[1]
            is_column = shape[1] == 1 or n == 0
            if n != len(names) or not is_column:
                raise ModelStructureError(
                    f"function {f.name()!r} {io} {label!r} has shape {shape} but "
                    f"{len(names)} names were given for it (expected a "
                    f"({len(names)}, 1) column vector)"
                )
        for name in self.drifting_states:
            if name not in self.states:
                raise UnknownSignalError("state", name, self.states)

    # ------------------------------------------------------------------ sizes
    @property
    def n_x(self) -> int:
        """Number of states."""
        return len(self.states)

    @property
    def n_u(self) -> int:
        """Number of inputs."""
        return len(self.inputs)

    @property
    def n_y(self) -> int:
        """Number of outputs."""
        return len(self.outputs)

    @property
    def n_p(self) -> int:
        """Number of parameters."""
        return len(self.parameters)

    # --------------------------------------------------------------- lookups
    def names(self, kind: SignalKind) -> tuple[str, ...]:
        """Names of one family of signals.

        Parameters
        ----------
        kind : {'state', 'input', 'output', 'parameter'}
            Signal family.

        Returns
        -------
        tuple of str
            The names, in vector order.

        Raises
        ------
        ValueError
            If ``kind`` is not one of the four families.
        """
        table = {
            "state": self.states,
            "input": self.inputs,
            "output": self.outputs,
            "parameter": self.parameters,
        }
        if kind not in table:
            raise ValueError(f"unknown signal kind {kind!r}; valid: {sorted(table)}")
        return table[kind]

    def index(self, kind: SignalKind, name: str) -> int:
        """Position of the signal ``name`` in its vector.

        Parameters
        ----------
        kind : {'state', 'input', 'output', 'parameter'}
            Signal family.
        name : str
            Signal name.

        Returns
        -------
        int
            Zero-based index.

        Raises
        ------
        UnknownSignalError
            If ``name`` is not a signal of that family; the message lists the
            valid names.
        """
        names = self.names(kind)
        try:
            return names.index(name)
        except ValueError:
            raise UnknownSignalError(kind, name, names) from None

    def state_index(self, name: str) -> int:
        """Index of state ``name`` (see :meth:`index`)."""
        return self.index("state", name)

    def input_index(self, name: str) -> int:
        """Index of input ``name`` (see :meth:`index`)."""
        return self.index("input", name)

    def output_index(self, name: str) -> int:
        """Index of output ``name`` (see :meth:`index`)."""
        return self.index("output", name)

    def parameter_index(self, name: str) -> int:
        """Index of parameter ``name`` (see :meth:`index`)."""
        return self.index("parameter", name)

    def indices(self, kind: SignalKind, names: Iterable[str]) -> tuple[int, ...]:
        """Indices of several signals of one family, in the order given.

        Raises
        ------
        UnknownSignalError
            On the first unknown name.
        """
        if isinstance(names, str):
            names = (names,)
        return tuple(self.index(kind, n) for n in names)

    # --------------------------------------------------------------- vectors
    def vector(
        self,
        kind: SignalKind,
        values: Mapping[str, float] | ArrayLike | None,
        *,
        default: float | None = None,
    ) -> Float1D:
        """Build the numeric vector of one signal family.

        Parameters
        ----------
        kind : {'state', 'input', 'output', 'parameter'}
            Signal family.
        values : mapping of str to float, array_like or None
            Either values by name [signal units] or a full vector in model
            order.  ``None`` means "all missing".
        default : float or None, optional
            Value of names missing from a mapping.  ``None`` (default) makes a
            missing name an error.

        Returns
        -------
        numpy.ndarray
            Vector of length ``len(self.names(kind))``.

        Raises
        ------
        UnknownSignalError
            If a mapping has a name the model does not have.
        ValueError
            If a vector has the wrong length, a value is not finite, or a name
            is missing and ``default`` is None (the message names it).
        """
        names = self.names(kind)
        if values is None:
            values = {}
        if isinstance(values, Mapping):
            for key in values:
                if key not in names:
                    raise UnknownSignalError(kind, key, names)
            missing = [n for n in names if n not in values]
            if missing and default is None:
                raise ValueError(f"missing {kind} values for {missing}")
            vec = np.array([float(values.get(n, default)) for n in names], dtype=float)
        else:
            vec = np.asarray(values, dtype=float).reshape(-1)
            if vec.size != len(names):
                raise ValueError(
                    f"{kind} vector has {vec.size} elements, the model has "
                    f"{len(names)} {kind}s {list(names)}"
                )
        bad = [names[i] for i in np.flatnonzero(~np.isfinite(vec))]
        if bad:
            raise ValueError(f"non-finite {kind} values for {bad}")
        return vec

    def parameter_vector(self, p: Mapping[str, float] | ArrayLike) -> Float1D:
        """Numeric parameter vector from a mapping (all names required) or a vector."""
        return self.vector("parameter", p)

    def as_dict(self, kind: SignalKind, vec: ArrayLike) -> dict[str, float]:
        """Name a numeric vector of one family: ``{name: value}``."""
        vals = np.asarray(vec, dtype=float).reshape(-1)
        names = self.names(kind)
        if vals.size != len(names):
            raise ValueError(f"{kind} vector has {vals.size} elements, expected {len(names)}")
        return {n: float(v) for n, v in zip(names, vals)}

    # ------------------------------------------------------------ evaluation
    @property
    def symbol_type(self) -> type:
        """``casadi.SX`` for an SX function, else ``casadi.MX``."""
        return ca.SX if self.function.is_a("SXFunction") else ca.MX

    def dense_function(self) -> ca.Function:
        """The model with dense outputs (structural zeros filled), memoised."""
        key = ("dense",)
        if key not in self._cache:
            sym = self.symbol_type
            x = sym.sym("x", self.n_x)
            u = sym.sym("u", self.n_u)
            p = sym.sym("p", self.n_p)
            xdot, y = self.function(x, u, p)
            self._cache[key] = ca.Function(
                f"{self.function.name()}_dense",
                [x, u, p],
                [ca.densify(xdot), ca.densify(y)],
                list(_IN_NAMES),
                list(_OUT_NAMES),
            )
        return self._cache[key]

    def mapped_function(self, n: int, parallelization: str = "serial") -> ca.Function:
        """:meth:`dense_function` mapped over ``n`` column-stacked points, memoised."""
        key = ("dense_map", int(n), parallelization)
        if key not in self._cache:
            self._cache[key] = self.dense_function().map(int(n), parallelization)
        return self._cache[key]

    def evaluate(
        self,
        x: Mapping[str, float] | ArrayLike,
        u: Mapping[str, float] | ArrayLike,
        p: Mapping[str, float] | ArrayLike,
    ) -> tuple[Float1D, Float1D]:
        """Evaluate ``xdot`` [state units / s] and ``y`` [output units] at one point.

        Parameters
        ----------
        x, u, p : mapping or array_like
            State, input and parameter values, by name (all required) or as
            vectors in model order.

        Returns
        -------
        xdot, y : numpy.ndarray
            State derivatives and outputs.
        """
        xv = self.vector("state", x)
        uv = self.vector("input", u)
        pv = self.parameter_vector(p)
        xdot, y = self.dense_function()(xv, uv, pv)
        return np.asarray(xdot, dtype=float).reshape(-1), np.asarray(y, dtype=float).reshape(-1)

    def evaluate_many(
        self, X: Float2D, U: Float2D, P: Float2D, parallelization: str = "serial"
    ) -> tuple[Float2D, Float2D]:
        """Evaluate at column-stacked points with one mapped casadi call.

        Parameters
        ----------
        X : numpy.ndarray, shape (n_x, N)
            States [state units].
        U : numpy.ndarray, shape (n_u, N)
            Inputs [input units].
        P : numpy.ndarray, shape (n_p, N) or (n_p, 1)
            Parameters [parameter units]; one column is broadcast.
        parallelization : {'serial', 'openmp', 'thread'}, optional
            casadi ``map`` parallelisation.  Default ``'serial'``.

        Returns
        -------
        XDOT : numpy.ndarray, shape (n_x, N)
        Y : numpy.ndarray, shape (n_y, N)
        """
        X, U, P = self.stack_points(X, U, P)
        n = X.shape[1]
        xdot, y = call_dense(self.mapped_function(n, parallelization), X, U, P)
        return xdot.reshape(self.n_x, n), y.reshape(self.n_y, n)

    def stack_points(
        self, X: ArrayLike, U: ArrayLike, P: ArrayLike
    ) -> tuple[Float2D, Float2D, Float2D]:
        """Check and broadcast column-stacked ``X``, ``U``, ``P`` to a common width.

        A single column (or a 1-D vector) of any of them is repeated.

        Raises
        ------
        ValueError
            If a row count differs from the number of names or the widths are
            inconsistent; the message names the argument.
        """
        arrays = []
        for label, arr, rows in (("X", X, self.n_x), ("U", U, self.n_u), ("P", P, self.n_p)):
            a = np.asarray(arr, dtype=float)
            if a.ndim == 1:
                a = a.reshape(-1, 1) if a.size == rows else a.reshape(rows, -1)
            if a.ndim != 2 or a.shape[0] != rows:
                raise ValueError(
                    f"{label} must have {rows} rows (one per name), got shape {a.shape}"
                )
            arrays.append(a)
        widths = {a.shape[1] for a in arrays} - {1}
        if len(widths) > 1:
            raise ValueError(
                "X, U, P must have the same number of columns (or one column), "
                f"got {[a.shape[1] for a in arrays]}"
            )
        n = widths.pop() if widths else 1
        return tuple(np.broadcast_to(a, (a.shape[0], n)).copy() for a in arrays)  # type: ignore[return-value]
