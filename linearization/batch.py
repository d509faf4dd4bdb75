"""Linearisation over a grid of operating points in one vectorised call.

:func:`linearize_batch` evaluates the AD Jacobian ``Function`` mapped over
all points (``Function.map``) and runs the finite-difference and
non-smoothness checks of :mod:`linearization.jacobian` through a single
mapped call of the model as well; there is no Python loop over points in the
numerics.  :func:`frequency_response_batch` evaluates ``C (jwI - A)^-1 B + D``
for every point and frequency with batched ``numpy.linalg.solve``.

Imports numpy and casadi only; never imports ``thsa_control``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ._typing import ArrayLike, Complex2D, Float1D, Float2D, Float3D
from .errors import UnknownSignalError
from .jacobian import DriftingMode, jacobian_blocks, linearize_core
from .linear_model import LinearModel
from .model import NamedModel
from .operating_point import OperatingPoint

__all__ = ["LinearModelBatch", "linearize_batch", "frequency_response_batch"]

# Largest number of complex (n x n) systems solved in one numpy call; bounds
# the memory of frequency_response_batch to ~ _CHUNK * n^2 * 16 bytes.
_CHUNK = 200_000


@dataclass(frozen=True, eq=False)
class LinearModelBatch:
    """Linear models at N points, stacked with the point index first.

    Parameters
    ----------
    A : numpy.ndarray, shape (N, n_x, n_x)
    B : numpy.ndarray, shape (N, n_x, n_u)
    C : numpy.ndarray, shape (N, n_y, n_x)
    D : numpy.ndarray, shape (N, n_y, n_u)
        Matrices of each point (after exclusions), as in :class:`LinearModel`.
    states, inputs, outputs : tuple of str
        Names of the rows and columns of the matrices.
    X, U, Y, P, XDOT : numpy.ndarray, shape (n_signals, N)
        The operating points (full model signals), one column each.
    model_states, model_inputs, model_outputs, model_parameters : tuple of str
        Names of the rows of ``X``, ``U``, ``Y``, ``P``.
    drifting_states : tuple of str
        Drifting states of the model.
    fd_discrepancy : numpy.ndarray, shape (N,)
        AD vs central finite-difference relative discrepancy per point.
    valid : numpy.ndarray of bool, shape (N,)
    invalid_reasons : tuple of tuple of str
        Reasons per point (empty when valid).
    excluded_states, excluded_outputs : tuple of str
        As in :class:`LinearModel` (the same for every point).
    guard_names : tuple of str
        Names of the validity-guard margins.
    guard_margins : numpy.ndarray, shape (n_g, N)
        Margins per point (negative = violated).
    """

    A: Float3D
    B: Float3D
    C: Float3D
    D: Float3D
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    X: Float2D
    U: Float2D
    Y: Float2D
    P: Float2D
    XDOT: Float2D
    model_states: tuple[str, ...]
    model_inputs: tuple[str, ...]
    model_outputs: tuple[str, ...]
    model_parameters: tuple[str, ...]
    drifting_states: tuple[str, ...]
    fd_discrepancy: Float1D
    valid: np.ndarray
    invalid_reasons: tuple[tuple[str, ...], ...]
    excluded_states: tuple[str, ...] = ()
    excluded_outputs: tuple[str, ...] = ()
    guard_names: tuple[str, ...] = ()
    guard_margins: Float2D | None = None

    def __len__(self) -> int:
        return int(self.A.shape[0])

    def __getitem__(self, k: int) -> LinearModel:
        """The ``k``-th point as a :class:`LinearModel`."""
        n = len(self)
        if not -n <= k < n:
            raise IndexError(f"point {k} out of range for a batch of {n}")
        xdot = self.XDOT[:, k]
        eq = [i for i, s in enumerate(self.model_states) if s not in self.drifting_states]
        op = OperatingPoint(
            x=self.X[:, k], u=self.U[:, k], y=self.Y[:, k], p=self.P[:, k],
            states=self.model_states, inputs=self.model_inputs,
            outputs=self.model_outputs, parameters=self.model_parameters,
            residual=float(np.max(np.abs(xdot[eq]))) if eq else 0.0,
            drift_rates={
                s: float(xdot[self.model_states.index(s)]) for s in self.drifting_states
            },
            xdot=xdot, drifting_states=self.drifting_states, method="given",
        )
        margins = self.guard_margins if self.guard_margins is not None else np.zeros((0, n))
        return LinearModel(
            A=self.A[k], B=self.B[k], C=self.C[k], D=self.D[k],
            states=self.states, inputs=self.inputs, outputs=self.outputs,
            operating_point=op, fd_discrepancy=float(self.fd_discrepancy[k]),
            valid=bool(self.valid[k]), invalid_reasons=self.invalid_reasons[k],
            excluded_states=self.excluded_states, excluded_outputs=self.excluded_outputs,
            guard_margins={g: float(margins[i, k]) for i, g in enumerate(self.guard_names)},
        )

    def poles(self) -> np.ndarray:
        """Eigenvalues of every ``A`` [1/s], shape (N, n_x), complex."""
        return np.linalg.eigvals(self.A).astype(complex)


def linearize_batch(
    model: NamedModel,
    X: ArrayLike,
    U: ArrayLike,
    P: ArrayLike,
    *,
    drifting: DriftingMode = "exclude",
    fd_check: bool = True,
    fd_eps: float = 1e-6,
    kink_rtol: float = 1e-3,
    validity: ca.Function | None = None,
    validity_names: Sequence[str] | None = None,
    parallelization: str = "serial",
) -> LinearModelBatch:
    """Linearise at N column-stacked operating points in one mapped call.

    Same checks and options as :func:`~linearization.jacobian.linearize`,
    evaluated with ``Function.map`` over all points.

    Parameters
    ----------
    model : NamedModel
        The model.
    X : array_like, shape (n_x, N)
        States of the points [state units] (already solved, e.g.
        ``find_operating_points(...).X``).
    U : array_like, shape (n_u, N)
        Inputs [input units].
    P : array_like, shape (n_p, N) or (n_p, 1)
        Parameters [parameter units]; one column is broadcast.
    drifting, fd_check, fd_eps, kink_rtol, validity, validity_names
        See :func:`~linearization.jacobian.linearize`.
    parallelization : {'serial', 'openmp', 'thread'}, optional
        casadi ``map`` parallelisation.  Default ``'serial'``.

    Returns
    -------
    LinearModelBatch

    Raises
    ------
    ValueError
        If the shapes do not match the model's names or a value is not
        finite (the message names the argument or the points).

    Examples
    --------
    >>> import numpy as np
    >>> from linearization.examples import mass_spring_damper
    >>> m = mass_spring_damper()
    >>> P = np.array([[1.0, 2.0, 4.0], [0.0, 0.0, 0.0], [4.0, 4.0, 4.0]])
    >>> batch = linearize_batch(m, np.zeros((2, 3)), np.zeros((1, 3)), P)
    >>> batch.A[:, 1, 0].tolist(), batch.valid.tolist()
    ([-4.0, -2.0, -1.0], [True, True, True])
    """
    X, U, P = model.stack_points(X, U, P)
    core = linearize_core(
        model, X, U, P,
        drifting=drifting, fd_check=fd_check, fd_eps=fd_eps, kink_rtol=kink_rtol,
        validity=validity, validity_names=validity_names, parallelization=parallelization,
    )
    A, B, C, D = jacobian_blocks(model, core)
    XDOT, Y = model.evaluate_many(X, U, P, parallelization)
    return LinearModelBatch(
        A=A, B=B, C=C, D=D,
        states=tuple(model.states[i] for i in core.keep_x),
        inputs=model.inputs,
        outputs=tuple(model.outputs[j] for j in core.keep_y),
        X=X, U=U, Y=Y, P=P, XDOT=XDOT,
        model_states=model.states, model_inputs=model.inputs,
        model_outputs=model.outputs, model_parameters=model.parameters,
        drifting_states=model.drifting_states,
        fd_discrepancy=core.fd_discrepancy,
        valid=np.array([not r for r in core.reasons], dtype=bool),
        invalid_reasons=core.reasons,
        excluded_states=core.excluded_states,
        excluded_outputs=core.excluded_outputs,
        guard_names=core.guard_names,
        guard_margins=core.guard_margins,
    )


def frequency_response_batch(
    batch: LinearModelBatch, input: str, output: str, omega: ArrayLike
) -> Complex2D:
    """``G(jw) = C (jwI - A)^-1 B + D`` from one input to one output, every point.

    Parameters
    ----------
    batch : LinearModelBatch
        The linear models.
    input : str
        Input name.
    output : str
        Output name.
    omega : array_like, shape (n_omega,)
        Angular frequencies [rad/s].

    Returns
    -------
    numpy.ndarray of complex, shape (N, n_omega)
        Frequency response [output unit / input unit].  A frequency that is
        a pole of a point gives ``inf`` there.

    Raises
    ------
    UnknownSignalError
        If ``input`` or ``output`` is not in the batch.

    Examples
    --------
    >>> import numpy as np
    >>> from linearization.examples import mass_spring_damper
    >>> m = mass_spring_damper()
    >>> P = np.array([[1.0], [0.0], [4.0]])
    >>> batch = linearize_batch(m, np.zeros((2, 1)), np.zeros((1, 1)), P)
    >>> G = frequency_response_batch(batch, "force", "position", [0.0, 1.0])
    >>> np.round(G.real, 12).tolist()  # 1 / (k - m w^2)
    [[0.25, 0.333333333333]]
    """
    if input not in batch.inputs:
        raise UnknownSignalError("input", input, batch.inputs)
    if output not in batch.outputs:
        raise UnknownSignalError("output", output, batch.outputs)
    j_in, j_out = batch.inputs.index(input), batch.outputs.index(output)
    w = np.asarray(omega, dtype=float).reshape(-1)
    n_pts, nx = batch.A.shape[0], batch.A.shape[1]
    b = batch.B[:, :, j_in]  # (N, n)
    c = batch.C[:, j_out, :]  # (N, n)
    d = batch.D[:, j_out, j_in]  # (N,)
    out = np.empty((n_pts, w.size), dtype=complex)
    if nx == 0:
        out[:] = d[:, None]
        return out
    eye = np.eye(nx)
    step = max(1, _CHUNK // max(1, n_pts))
    for start in range(0, w.size, step):
        ws = w[start : start + step]
        M = 1j * ws[None, :, None, None] * eye - batch.A[:, None, :, :]  # (N, W, n, n)
        rhs = np.broadcast_to(b[:, None, :, None], M.shape[:-1] + (1,)).astype(complex)
        try:
            sol = np.linalg.solve(M, rhs)[..., 0]  # (N, W, n)
            singular = np.zeros(M.shape[:2], dtype=bool)
        except np.linalg.LinAlgError:
            sol, singular = _solve_each(M, rhs)
        block = np.einsum("kn,kwn->kw", c, sol) + d[:, None]
        block[singular] = complex(np.inf, 0.0)
        out[:, start : start + ws.size] = block
    return out


def _solve_each(M: np.ndarray, rhs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Slice-wise solve, used only when some slice is singular (w on a pole)."""
    sol = np.zeros(M.shape[:-1], dtype=complex)
    singular = np.zeros(M.shape[:2], dtype=bool)
    for k in range(M.shape[0]):
        for i in range(M.shape[1]):
            try:
                sol[k, i] = np.linalg.solve(M[k, i], rhs[k, i])[:, 0]
            except np.linalg.LinAlgError:
                singular[k, i] = True
    return sol, singular
