"""Jacobians A, B, C, D by casadi AD, checked by finite differences.

The AD Jacobian ``Function`` ``(x, u, p) -> (A, B, C, D, xdot, y)`` is built
once per model and memoised on it; it is evaluated at one point or mapped
over many (``Function.map``).  The finite-difference checks are vectorised in
the same way: every perturbed point of every operating point goes through a
single mapped call of the model.

Non-smoothness detection
------------------------
A linear model is only meaningful where ``f`` is differentiable.  At a kink
(``|v|``, a backlash contact edge) the forward and backward slopes differ; at
a jump (Coulomb friction ``sign(v)`` at ``v = 0``) both one-sided difference
quotients grow like ``1/h`` and disagree with the AD Jacobian (which then
reports the derivative of one branch, e.g. ``d sign/dv = 0``).  For each
column (state or input) ``j`` and row ``i`` we compute, with
``h_j = eps * max(1, |z_j|)``::

    jump_ij(h) = max(|D+ - D-|, |D+ - J|, |D- - J|)

and flag the column when, for some row, the jump is (1) larger than
``kink_rtol * max(|J_ij|, |D+|, |D-|)``, (2) above the round-off level
``1e3 * eps_machine * |f_i| / h_j``, and (3) does not shrink when the step is
divided by 10 (for a smooth ``f`` it shrinks like ``h``; at a kink it stays,
at a jump it grows).  Condition (3) is what keeps strong but smooth curvature
(a Stribeck curve) from being flagged.

Limits: a kink lying between ``h_j / 10`` and ``h_j`` away from the point is
not flagged (it only shows in ``fd_discrepancy``), and a kink smaller than
the round-off level of ``f`` is invisible.

Imports numpy and casadi only; never imports ``thsa_control``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Literal

import casadi as ca
import numpy as np

from ._typing import ArrayLike, Float1D, Float2D, Float3D
from .buffered import call_dense
from .linear_model import LinearModel
from .model import NamedModel
from .operating_point import OperatingPoint

__all__ = [
    "jacobian_function",
    "jacobians",
    "finite_difference_jacobians",
    "linearize",
    "DriftingMode",
]

#: What to do with drifting states in the linear model.
DriftingMode = Literal["exclude", "keep"]

_EPS_MACHINE = float(np.finfo(float).eps)
_SMALL_STEP = 0.1  # ratio of the second (confirmation) step to the first
_ROUNDOFF_FACTOR = 1e3  # headroom of the round-off estimate of a difference quotient


def jacobian_function(model: NamedModel) -> ca.Function:
    """AD Jacobian ``Function`` of ``model``, built once and memoised on it.

    Parameters
    ----------
    model : NamedModel
        The model.

    Returns
    -------
    casadi.Function
        ``(x, u, p) -> (A, B, C, D, xdot, y)`` with dense outputs; ``A =
        d xdot/dx``, ``B = d xdot/du``, ``C = dy/dx``, ``D = dy/du``.

    Examples
    --------
    >>> from linearization.examples import mass_spring_damper
    >>> jac = jacobian_function(mass_spring_damper())
    >>> jac.name_out()
    ['A', 'B', 'C', 'D', 'xdot', 'y']
    """
    key = ("jacobian",)
    if key not in model._cache:
        sym = model.symbol_type
        x = sym.sym("x", model.n_x)
        u = sym.sym("u", model.n_u)
        p = sym.sym("p", model.n_p)
        xdot, y = model.function(x, u, p)
        # Structural dependence of y on x, before densification (used to find
        # the outputs that depend on an excluded drifting state).
        model._cache[("C_sparsity",)] = ca.jacobian(y, x).sparsity()
        outs = [
            ca.jacobian(xdot, x),
            ca.jacobian(xdot, u),
            ca.jacobian(y, x),
            ca.jacobian(y, u),
            xdot,
            y,
        ]
        model._cache[key] = ca.Function(
            f"{model.function.name()}_jacobian",
            [x, u, p],
            [ca.densify(o) for o in outs],
            ["x", "u", "p"],
            ["A", "B", "C", "D", "xdot", "y"],
        )
    return model._cache[key]


def _stack_jacobians(model: NamedModel, outs: Sequence[np.ndarray], n: int) -> Float3D:
    """Mapped (A, B, C, D) outputs -> array (n, n_x + n_y, n_x + n_u)."""
    nx, nu, ny = model.n_x, model.n_u, model.n_y

    def unstack(val: np.ndarray, rows: int, cols: int) -> Float3D:
        arr = np.asarray(val, dtype=float).reshape(rows, n * cols)
        return arr.reshape(rows, n, cols).transpose(1, 0, 2)

    J = np.zeros((n, nx + ny, nx + nu))
    J[:, :nx, :nx] = unstack(outs[0], nx, nx)
    J[:, :nx, nx:] = unstack(outs[1], nx, nu)
    J[:, nx:, :nx] = unstack(outs[2], ny, nx)
    J[:, nx:, nx:] = unstack(outs[3], ny, nu)
    return J


def _ad_jacobians(
    model: NamedModel, X: Float2D, U: Float2D, P: Float2D, parallelization: str = "serial"
) -> Float3D:
    """AD Jacobians at N column-stacked points: array (N, n_x + n_y, n_x + n_u)."""
    n = X.shape[1]
    key = ("jacobian_map", n, parallelization)
    if key not in model._cache:
        fn = jacobian_function(model)
        model._cache[key] = fn if n == 1 else fn.map(n, parallelization)
    outs = call_dense(model._cache[key], X, U, P)
    return _stack_jacobians(model, outs, n)


@dataclass(frozen=True)
class _FiniteDifferences:
    """One-sided and central difference quotients, shape (N, n_f, n_z)."""

    forward: Float3D
    backward: Float3D
    forward_small: Float3D
    backward_small: Float3D
    central: Float3D
    roundoff: Float3D
    roundoff_small: Float3D
    f0: Float2D  # (n_f, N) nominal [xdot; y]
    step: Float2D  # (N, n_z) first forward step actually taken [column units]


def _finite_differences(
    model: NamedModel,
    X: Float2D,
    U: Float2D,
    P: Float2D,
    eps: float,
    parallelization: str = "serial",
) -> _FiniteDifferences:
    """All difference quotients at N points with a single mapped model call."""
    nx, nu = model.n_x, model.n_u
    nz, n = nx + nu, X.shape[1]
    Z = np.vstack([X, U])  # (nz, N)
    h = eps * np.maximum(1.0, np.abs(Z))  # (nz, N)
    steps = ((1.0, 1.0), (-1.0, 1.0), (1.0, _SMALL_STEP), (-1.0, _SMALL_STEP))
    ns = len(steps)
    pert = np.broadcast_to(Z[:, :, None, None], (nz, n, ns, nz)).copy()
    idx = np.arange(nz)
    for s, (sign, scale) in enumerate(steps):
        pert[idx, :, s, idx] += sign * scale * h
    # The step actually taken, after rounding of z + h.
    dz = np.stack([pert[idx, :, s, idx] - Z for s in range(ns)], axis=1)  # (nz, ns, N)
    cols = pert.reshape(nz, n * ns * nz)
    Zall = np.hstack([cols, Z])
    Pall = np.hstack([np.repeat(P, ns * nz, axis=1), P])
    XDOT, Y = model.evaluate_many(Zall[:nx], Zall[nx:], Pall, parallelization)
    F = np.vstack([XDOT, Y])  # (nf, M)
    nf = F.shape[0]
    Fp = F[:, : n * ns * nz].reshape(nf, n, ns, nz)
    F0 = F[:, n * ns * nz :]  # (nf, N)
    dzt = dz.transpose(2, 1, 0)  # (N, ns, nz)

    with np.errstate(invalid="ignore", divide="ignore"):
        quot = []
        noise = []
        for s in range(ns):
            dF = Fp[:, :, s, :].transpose(1, 0, 2) - F0.T[:, :, None]  # (N, nf, nz)
            quot.append(dF / dzt[:, None, s, :])
            mag = np.maximum(np.abs(Fp[:, :, s, :].transpose(1, 0, 2)), np.abs(F0.T)[:, :, None])
            noise.append(_ROUNDOFF_FACTOR * _EPS_MACHINE * mag / np.abs(dzt[:, None, s, :]))
        central = (
            (Fp[:, :, 0, :] - Fp[:, :, 1, :]).transpose(1, 0, 2)
            / (dzt[:, None, 0, :] - dzt[:, None, 1, :])
        )
    return _FiniteDifferences(
        forward=quot[0],
        backward=quot[1],
        forward_small=quot[2],
        backward_small=quot[3],
        central=central,
        roundoff=np.maximum(noise[0], noise[1]),
        roundoff_small=np.maximum(noise[2], noise[3]),
        f0=F0,
        step=dzt[:, 0, :],
    )


def _row_names(model: NamedModel) -> tuple[str, ...]:
    return tuple(f"d({s})/dt" for s in model.states) + tuple(f"output {o}" for o in model.outputs)


def _column_names(model: NamedModel) -> tuple[str, ...]:
    return tuple(f"state {s!r}" for s in model.states) + tuple(f"input {u!r}" for u in model.inputs)


def _smoothness(
    model: NamedModel, J: Float3D, fd: _FiniteDifferences, kink_rtol: float
) -> tuple[Float1D, list[list[str]]]:
    """fd_discrepancy per point and non-smoothness reasons per point."""
    n = J.shape[0]
    with np.errstate(invalid="ignore", divide="ignore"):
        diff_c = np.abs(fd.central - J)
        scale_c = np.maximum(np.abs(J), np.abs(fd.central))
        rel_c = np.where(diff_c == 0.0, 0.0, diff_c / scale_c)
        rel_c = np.where(np.isfinite(rel_c), rel_c, np.inf)
    discrepancy = rel_c.reshape(n, -1).max(axis=1) if rel_c.size else np.zeros(n)

    def jump(fw: Float3D, bw: Float3D) -> Float3D:
        return np.maximum.reduce([np.abs(fw - bw), np.abs(fw - J), np.abs(bw - J)])

    with np.errstate(invalid="ignore"):
        jump_h = jump(fd.forward, fd.backward)
        jump_s = jump(fd.forward_small, fd.backward_small)
        scale = np.maximum.reduce([np.abs(J), np.abs(fd.forward), np.abs(fd.backward)])
        nonfinite = ~(
            np.isfinite(fd.forward)
            & np.isfinite(fd.backward)
            & np.isfinite(fd.forward_small)
            & np.isfinite(fd.backward_small)
        )
        flagged = (
            (jump_h > kink_rtol * scale)
            & (jump_h > fd.roundoff)
            & (jump_s > fd.roundoff_small)
            & (jump_s > 0.5 * jump_h)
        ) | nonfinite
    rows, cols = _row_names(model), _column_names(model)
    reasons: list[list[str]] = [[] for _ in range(n)]
    for k, j in zip(*np.nonzero(flagged.any(axis=1))):
        if nonfinite[k, :, j].any():
            i = int(np.argmax(nonfinite[k, :, j]))
            reasons[k].append(
                f"not differentiable in {cols[j]}: finite differences of {rows[i]} "
                "are not finite (the model is undefined next to this point)"
            )
            continue
        rel = np.where(flagged[k, :, j], jump_h[k, :, j] / np.maximum(scale[k, :, j], 1e-300), -1)
        i = int(np.argmax(rel))
        fw, bw, ad = fd.forward[k, i, j], fd.backward[k, i, j], J[k, i, j]
        growth = jump_s[k, i, j] / jump_h[k, i, j]
        if growth > 3.0:
            # Difference quotients grow like 1/h: a jump in the value of f,
            # of about (slope error) * (step).
            size = max(abs(fw - ad), abs(bw - ad)) * float(fd.step[k, j])
            reasons[k].append(
                f"not differentiable in {cols[j]}: {rows[i]} jumps by about {size:.3g} "
                f"across this point (one-sided slopes {fw:.3g} forward, {bw:.3g} "
                f"backward grow as the step shrinks; AD slope {ad:.3g})"
            )
        else:
            reasons[k].append(
                f"not differentiable in {cols[j]}: slope of {rows[i]} jumps by "
                f"{jump_h[k, i, j]:.3g} (forward {fw:.3g}, backward {bw:.3g}, AD {ad:.3g}; "
                f"relative jump {rel[i]:.3g} > {kink_rtol:g}): kink at this point"
            )
    return np.asarray(discrepancy, dtype=float), reasons


# --------------------------------------------------------------------------
# Validity guards supplied by the caller.
# --------------------------------------------------------------------------
def _guard_setup(
    model: NamedModel, validity: ca.Function | None, validity_names: Sequence[str] | None
) -> tuple[ca.Function | None, tuple[str, ...]]:
    """Check a guard Function and name each of its margins."""
    if validity is None:
        if validity_names is not None:
            raise ValueError("validity_names given without a validity Function")
        return None, ()
    if not isinstance(validity, ca.Function):
        raise TypeError(f"validity must be a casadi.Function, got {type(validity).__name__}")
    sizes = (model.n_x, model.n_u, model.n_p)
    if validity.n_in() != 3 or any(
        validity.numel_in(k) != sizes[k] for k in range(3)
    ):
        raise ValueError(
            f"validity Function {validity.name()!r} must take (x, u, p) of sizes {sizes}, "
            f"takes {[validity.size_in(k) for k in range(validity.n_in())]}"
        )
    auto: list[str] = []
    for k in range(validity.n_out()):
        if validity.size2_out(k) != 1 and validity.numel_out(k) > 0:
            raise ValueError(
                f"validity output {validity.name_out(k)!r} must be a column vector, "
                f"has shape {validity.size_out(k)}"
            )
        label, numel = validity.name_out(k), validity.numel_out(k)
        auto += [label] if numel == 1 else [f"{label}[{m}]" for m in range(numel)]
    if validity_names is None:
        return validity, tuple(auto)
    names = tuple(validity_names)
    if len(names) != len(auto):
        raise ValueError(
            f"{len(names)} validity_names for {len(auto)} margins of {validity.name()!r}"
        )
    return validity, names


def _guard_margins(
    fn: ca.Function, X: Float2D, U: Float2D, P: Float2D, parallelization: str
) -> Float2D:
    """Margins (n_g, N) at column-stacked points, one mapped call."""
    n = X.shape[1]
    outs = call_dense(fn.map(n, parallelization) if n > 1 else fn, X, U, P)
    rows = [o.reshape(-1, n) for o in outs]
    return np.vstack(rows) if rows else np.zeros((0, n))


# --------------------------------------------------------------------------
# Shared core of linearize() and linearize_batch().
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class _Core:
    """Everything computed at N points, before the drifting-state reduction."""

    J: Float3D  # (N, n_x + n_y, n_x + n_u)
    fd_discrepancy: Float1D  # (N,)
    reasons: tuple[tuple[str, ...], ...]
    guard_names: tuple[str, ...]
    guard_margins: Float2D  # (n_g, N)
    keep_x: tuple[int, ...]
    keep_y: tuple[int, ...]
    excluded_states: tuple[str, ...]
    excluded_outputs: tuple[str, ...]


def _output_depends_structurally(model: NamedModel, excluded: Sequence[int]) -> set[int]:
    """Outputs whose expression contains an excluded state (casadi sparsity)."""
    if not excluded:
        return set()
    jacobian_function(model)  # builds the memo below
    rows, cols = model._cache[("C_sparsity",)].get_triplet()
    return {r for r, c in zip(rows, cols) if c in set(excluded)}


def linearize_core(
    model: NamedModel,
    X: Float2D,
    U: Float2D,
    P: Float2D,
    *,
    drifting: DriftingMode = "exclude",
    fd_check: bool = True,
    fd_eps: float = 1e-6,
    kink_rtol: float = 1e-3,
    validity: ca.Function | None = None,
    validity_names: Sequence[str] | None = None,
    parallelization: str = "serial",
) -> _Core:
    """Jacobians, checks and reasons at N column-stacked points (internal)."""
    if drifting not in ("exclude", "keep"):
        raise ValueError(f"drifting={drifting!r}; valid: 'exclude', 'keep'")
    if not (fd_eps > 0 and np.isfinite(fd_eps)):
        raise ValueError(f"fd_eps must be > 0, got {fd_eps!r}")
    if not (kink_rtol > 0 and np.isfinite(kink_rtol)):
        raise ValueError(f"kink_rtol must be > 0, got {kink_rtol!r}")
    guard_fn, guard_names = _guard_setup(model, validity, validity_names)
    X, U, P = model.stack_points(X, U, P)
    n = X.shape[1]
    bad = [k for k in range(n) if not np.all(np.isfinite(np.r_[X[:, k], U[:, k], P[:, k]]))]
    if bad:
        raise ValueError(f"operating points {bad[:10]} contain non-finite values")

    J = _ad_jacobians(model, X, U, P, parallelization)
    reasons: list[list[str]] = [[] for _ in range(n)]
    if fd_check:
        fd = _finite_differences(model, X, U, P, fd_eps, parallelization)
        discrepancy, smooth_reasons = _smoothness(model, J, fd, kink_rtol)
        for k in range(n):
            reasons[k] += smooth_reasons[k]
    else:
        discrepancy = np.full(n, np.nan)

    nx = model.n_x
    excluded_idx = (
        tuple(model.state_index(s) for s in model.drifting_states) if drifting == "exclude" else ()
    )
    keep_x = tuple(i for i in range(nx) if i not in excluded_idx)
    dropped_y = _output_depends_structurally(model, excluded_idx)
    keep_y = tuple(j for j in range(model.n_y) if j not in dropped_y)
    # A drifting state must not act on the kept dynamics, or the motion is
    # not a steady drift and dropping it changes the model.
    for e in excluded_idx:
        col = J[:, :nx, e][:, list(keep_x)]  # (N, n_keep)
        scale = np.maximum(1.0, np.abs(J[:, :nx, :]).max(axis=2))[:, list(keep_x)]
        for k, r in zip(*np.nonzero(np.abs(col) > 1e-12 * scale)):
            i = keep_x[r]
            reasons[k].append(
                f"state {model.states[e]!r} is declared drifting but d({model.states[i]})/dt "
                f"depends on it (slope {J[k, i, e]:.3g}): not a steady drift, "
                "so it cannot be excluded"
            )

    if guard_fn is not None:
        margins = _guard_margins(guard_fn, X, U, P, parallelization)
        for g, k in zip(*np.nonzero(~(margins >= 0.0))):
            reasons[k].append(
                f"validity guard {guard_names[g]!r} violated: margin {margins[g, k]:.3g} < 0"
            )
    else:
        margins = np.zeros((0, n))

    return _Core(
        J=J,
        fd_discrepancy=np.asarray(discrepancy, dtype=float),
        reasons=tuple(tuple(r) for r in reasons),
        guard_names=guard_names,
        guard_margins=margins,
        keep_x=keep_x,
        keep_y=keep_y,
        excluded_states=tuple(model.states[i] for i in excluded_idx),
        excluded_outputs=tuple(model.outputs[j] for j in sorted(dropped_y)),
    )


def jacobian_blocks(model: NamedModel, core: _Core) -> tuple[Float3D, Float3D, Float3D, Float3D]:
    """Reduced (A, B, C, D) stacks, point index first."""
    nx = model.n_x
    kx, ky = list(core.keep_x), list(core.keep_y)
    J = core.J
    A = J[:, :nx, :nx][:, kx][:, :, kx]
    B = J[:, :nx, nx:][:, kx, :]
    C = J[:, nx:, :nx][:, ky][:, :, kx]
    D = J[:, nx:, nx:][:, ky, :]
    return A, B, C, D


def jacobians(
    model: NamedModel,
    x: Mapping[str, float] | ArrayLike,
    u: Mapping[str, float] | ArrayLike,
    p: Mapping[str, float] | ArrayLike,
) -> tuple[Float2D, Float2D, Float2D, Float2D]:
    """AD Jacobians ``A, B, C, D`` of the full model at one point (no checks).

    Parameters
    ----------
    model : NamedModel
        The model.
    x, u, p : mapping or array_like
        States, inputs, parameters, by name or as vectors.

    Returns
    -------
    A, B, C, D : numpy.ndarray
        ``d xdot/dx``, ``d xdot/du``, ``dy/dx``, ``dy/du``.

    Examples
    --------
    >>> from linearization.examples import mass_spring_damper
    >>> A, B, C, D = jacobians(mass_spring_damper(), [0, 0], [0], [2.0, 1.0, 8.0])
    >>> A.tolist(), B.ravel().tolist()
    ([[0.0, 1.0], [-4.0, -0.5]], [0.0, 0.5])
    """
    X = model.vector("state", x)[:, None]
    U = model.vector("input", u)[:, None]
    P = model.parameter_vector(p)[:, None]
    J = _ad_jacobians(model, X, U, P)[0]
    nx = model.n_x
    return J[:nx, :nx], J[:nx, nx:], J[nx:, :nx], J[nx:, nx:]


def finite_difference_jacobians(
    model: NamedModel,
    x: Mapping[str, float] | ArrayLike,
    u: Mapping[str, float] | ArrayLike,
    p: Mapping[str, float] | ArrayLike,
    *,
    eps: float = 1e-6,
    scheme: Literal["central", "forward", "backward"] = "central",
) -> tuple[Float2D, Float2D, Float2D, Float2D]:
    """Finite-difference ``A, B, C, D`` at one point (cross-check of AD).

    The step of each column is ``eps * max(1, |value|)`` (python-control's
    scheme); all perturbed points go through one mapped model call.

    Parameters
    ----------
    model : NamedModel
        The model.
    x, u, p : mapping or array_like
        States, inputs, parameters, by name or as vectors.
    eps : float, optional
        Relative step [-].  Default 1e-6.
    scheme : {'central', 'forward', 'backward'}, optional
        Difference quotient.  Default ``'central'``.

    Returns
    -------
    A, B, C, D : numpy.ndarray

    Examples
    --------
    >>> import numpy as np
    >>> from linearization.examples import mass_spring_damper
    >>> A, *_ = finite_difference_jacobians(mass_spring_damper(), [0, 0], [0], [2.0, 1.0, 8.0])
    >>> np.allclose(A, [[0, 1], [-4, -0.5]], rtol=1e-8)
    True
    """
    if scheme not in ("central", "forward", "backward"):
        raise ValueError(f"scheme={scheme!r}; valid: 'central', 'forward', 'backward'")
    X = model.vector("state", x)[:, None]
    U = model.vector("input", u)[:, None]
    P = model.parameter_vector(p)[:, None]
    J = getattr(_finite_differences(model, X, U, P, eps), scheme)[0]
    nx = model.n_x
    return J[:nx, :nx], J[:nx, nx:], J[nx:, :nx], J[nx:, nx:]


def linearize(
    model: NamedModel,
    op: OperatingPoint,
    *,
    drifting: DriftingMode = "exclude",
    fd_check: bool = True,
    fd_eps: float = 1e-6,
    kink_rtol: float = 1e-3,
    validity: ca.Function | None = None,
    validity_names: Sequence[str] | None = None,
) -> LinearModel:
    """Linear model of ``model`` at ``op`` by casadi AD, with validity checks.

    Parameters
    ----------
    model : NamedModel
        The model.
    op : OperatingPoint
        Where to linearise (from :func:`find_operating_point` or
        :meth:`OperatingPoint.from_values`); its names must be the model's.
    drifting : {'exclude', 'keep'}, optional
        ``'exclude'`` (default) removes the model's drifting states from
        ``A``, ``B``, ``C`` and the outputs that depend on them (reported in
        ``excluded_states`` / ``excluded_outputs``); ``'keep'`` keeps them
        (their integrators appear as poles at 0).
    fd_check : bool, optional
        Cross-check AD with finite differences and detect kinks and jumps
        (see the module notes).  Default True.  When False no smoothness
        check is made and ``fd_discrepancy`` is NaN.
    fd_eps : float, optional
        Relative finite-difference step [-]; the step of a column is
        ``fd_eps * max(1, |value|)``.  Default 1e-6.
    kink_rtol : float, optional
        Smallest relative jump of a one-sided slope reported as
        non-smoothness [-].  Default 1e-3.
    validity : casadi.Function, optional
        Model-specific guards ``(x, u, p) -> margins``; a negative margin
        makes the model invalid, and the reason names the guard.
    validity_names : sequence of str, optional
        One name per margin; default from the guard's output names
        (``name[k]`` for vector outputs).

    Returns
    -------
    LinearModel
        ``valid`` is False, with ``invalid_reasons``, at a kink or jump, a
        violated guard, or a drifting state that acts on the dynamics.

    Raises
    ------
    ValueError
        If ``op`` belongs to another model, or an option is invalid.

    Examples
    --------
    >>> from linearization.examples import mass_spring_damper
    >>> m = mass_spring_damper()
    >>> op = OperatingPoint.from_values(m, [0.0, 0.0], [0.0], [2.0, 1.0, 8.0])
    >>> lm = linearize(m, op)
    >>> lm.A.tolist(), lm.valid, lm.fd_discrepancy < 1e-7
    ([[0.0, 1.0], [-4.0, -0.5]], True, True)
    """
    for label, mine, theirs in (
        ("states", model.states, op.states),
        ("inputs", model.inputs, op.inputs),
        ("outputs", model.outputs, op.outputs),
        ("parameters", model.parameters, op.parameters),
    ):
        if tuple(mine) != tuple(theirs):
            raise ValueError(
                f"operating point {label} {list(theirs)} differ from the model's {list(mine)}"
            )
    core = linearize_core(
        model, op.x[:, None], op.u[:, None], op.p[:, None],
        drifting=drifting, fd_check=fd_check, fd_eps=fd_eps, kink_rtol=kink_rtol,
        validity=validity, validity_names=validity_names,
    )
    A, B, C, D = jacobian_blocks(model, core)
    return LinearModel(
        A=A[0], B=B[0], C=C[0], D=D[0],
        states=tuple(model.states[i] for i in core.keep_x),
        inputs=model.inputs,
        outputs=tuple(model.outputs[j] for j in core.keep_y),
        operating_point=op,
        fd_discrepancy=float(core.fd_discrepancy[0]),
        valid=not core.reasons[0],
        invalid_reasons=core.reasons[0],
        excluded_states=core.excluded_states,
        excluded_outputs=core.excluded_outputs,
        guard_margins={g: float(core.guard_margins[i, 0]) for i, g in enumerate(core.guard_names)},
    )
