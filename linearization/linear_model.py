"""The linear model of a named casadi model at one operating point.

:class:`LinearModel` is a frozen result: matrices ``A, B, C, D`` with the
names of their rows and columns, the operating point they were taken at,
what was excluded (drifting states), the finite-difference cross-check, and
whether the linearisation is valid there (with the reasons when it is not).
It converts to python-control objects with the names kept, and saves to and
loads from ``.npz`` (no pickles).

Imports numpy and python-control only; never imports ``thsa_control``.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ._typing import Float2D
from .errors import UnknownSignalError
from .operating_point import OperatingPoint

if TYPE_CHECKING:
    import control as ct

__all__ = ["LinearModel", "NPZ_FORMAT"]

#: Tag written in every ``.npz`` file; checked on load.
NPZ_FORMAT = "linearization.LinearModel/1"


def _frozen(arr: object, shape: tuple[int, int], label: str) -> Float2D:
    out = np.array(arr, dtype=float)
    if out.size == 0 and np.prod(shape) == 0:
        out = out.reshape(shape)
    if out.shape != shape:
        raise ValueError(f"{label} has shape {out.shape}, expected {shape} from the names")
    out.setflags(write=False)
    return out


def _select(kind: str, names: tuple[str, ...], wanted: Sequence[str] | None) -> list[int]:
    if wanted is None:
        return list(range(len(names)))
    if isinstance(wanted, str):
        wanted = (wanted,)
    out = []
    for name in wanted:
        if name not in names:
            raise UnknownSignalError(kind, name, names)
        out.append(names.index(name))
    return out


@dataclass(frozen=True, eq=False)
class LinearModel:
    """``dx/dt = A dx + B du``, ``dy = C dx + D du`` about an operating point.

    ``dx``, ``du``, ``dy`` are deviations from the operating point, in the
    units of the named states, inputs and outputs.

    Parameters
    ----------
    A : numpy.ndarray, shape (n_x, n_x)
        ``d xdot / dx`` [state unit / s per state unit].
    B : numpy.ndarray, shape (n_x, n_u)
        ``d xdot / du``.
    C : numpy.ndarray, shape (n_y, n_x)
        ``d y / dx``.
    D : numpy.ndarray, shape (n_y, n_u)
        ``d y / du``.
    states, inputs, outputs : tuple of str
        Names of the rows and columns (after exclusions).
    operating_point : OperatingPoint
        Where the model was linearised (full model signals).
    fd_discrepancy : float
        Largest relative difference between the AD Jacobian and central
        finite differences, element-wise relative to ``max(|AD|, |FD|)``
        [-]; NaN when no check was made.  Reported, never raised.
    valid : bool
        False when the point sits on a kink or jump of the model, or a
        validity guard is violated.
    invalid_reasons : tuple of str
        One sentence per problem, naming the state/input column or guard.
    excluded_states : tuple of str
        Drifting states removed from ``A``, ``B``, ``C``.
    excluded_outputs : tuple of str
        Outputs removed because they depend on an excluded state (they
        would integrate the drift).
    guard_margins : dict of str to float
        Value of each validity guard margin (negative = violated).

    Examples
    --------
    >>> lm = LinearModel(A=[[-2.0]], B=[[1.0]], C=[[1.0]], D=[[0.0]],
    ...                  states=("speed",), inputs=("torque",), outputs=("speed",))
    >>> lm.poles().tolist()
    [(-2+0j)]
    >>> lm.to_statespace().state_labels
    ['speed']
    """

    A: Float2D
    B: Float2D
    C: Float2D
    D: Float2D
    states: tuple[str, ...]
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    operating_point: OperatingPoint | None = None
    fd_discrepancy: float = float("nan")
    valid: bool = True
    invalid_reasons: tuple[str, ...] = ()
    excluded_states: tuple[str, ...] = ()
    excluded_outputs: tuple[str, ...] = ()
    guard_margins: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for attr in ("states", "inputs", "outputs", "invalid_reasons",
                     "excluded_states", "excluded_outputs"):
            val = getattr(self, attr)
            if isinstance(val, str):
                raise TypeError(f"{attr} must be a sequence of str, not a single str")
            object.__setattr__(self, attr, tuple(str(v) for v in val))
        nx, nu, ny = len(self.states), len(self.inputs), len(self.outputs)
        object.__setattr__(self, "A", _frozen(self.A, (nx, nx), "A"))
        object.__setattr__(self, "B", _frozen(self.B, (nx, nu), "B"))
        object.__setattr__(self, "C", _frozen(self.C, (ny, nx), "C"))
        object.__setattr__(self, "D", _frozen(self.D, (ny, nu), "D"))
        object.__setattr__(self, "valid", bool(self.valid))
        object.__setattr__(self, "fd_discrepancy", float(self.fd_discrepancy))
        object.__setattr__(
            self, "guard_margins", {str(k): float(v) for k, v in self.guard_margins.items()}
        )

    # ----------------------------------------------------------- conversions
    def to_statespace(self, name: str | None = None) -> ct.StateSpace:
        """python-control ``StateSpace`` with the state, input and output names.

        Parameters
        ----------
        name : str, optional
            System name; default chosen by python-control.

        Returns
        -------
        control.StateSpace

        Raises
        ------
        ValueError
            For a model with states and no inputs, which python-control 0.10
            cannot represent.
        """
        if self.inputs == () and self.states != ():
            # python-control 0.10 collapses an (n, 0) B matrix to (0, 0) and
            # then rejects it (statesp._ssmatrix), so say so plainly.
            raise ValueError(
                "python-control cannot represent a StateSpace with states and no "
                f"inputs (states {list(self.states)}); use A, C directly"
            )
        import control as ct  # here, not at import: python-control (and scipy.signal) take ~1.5 s to import

        kwargs = {} if name is None else {"name": name}
        return ct.ss(
            np.array(self.A), np.array(self.B), np.array(self.C), np.array(self.D),
            states=list(self.states), inputs=list(self.inputs),
            outputs=list(self.outputs), **kwargs,
        )

    def subsystem(
        self, inputs: Sequence[str] | None = None, outputs: Sequence[str] | None = None
    ) -> "LinearModel":
        """The same model restricted to some inputs and outputs (all states kept).

        Parameters
        ----------
        inputs, outputs : sequence of str, optional
            Names to keep, in the order wanted; ``None`` keeps all.

        Returns
        -------
        LinearModel

        Raises
        ------
        UnknownSignalError
            If a name is not an input/output of this linear model.

        Examples
        --------
        >>> lm = LinearModel(A=[[-1.0]], B=[[1.0, 2.0]], C=[[1.0], [3.0]],
        ...                  D=[[0.0, 0.0], [0.0, 5.0]], states=("x",),
        ...                  inputs=("a", "b"), outputs=("y", "z"))
        >>> sub = lm.subsystem(inputs=["b"], outputs=["z"])
        >>> sub.B.tolist(), sub.C.tolist(), sub.D.tolist()
        ([[2.0]], [[3.0]], [[5.0]])
        """
        iu = _select("input", self.inputs, inputs)
        iy = _select("output", self.outputs, outputs)
        return replace(
            self,
            B=self.B[:, iu],
            C=self.C[iy, :],
            D=self.D[np.ix_(iy, iu)],
            inputs=tuple(self.inputs[i] for i in iu),
            outputs=tuple(self.outputs[i] for i in iy),
        )

    def transfer_function(
        self, input: str, output: str, *, minimal: bool = False
    ) -> ct.TransferFunction:
        """SISO transfer function from ``input`` to ``output``.

        Parameters
        ----------
        input : str
            Input name.
        output : str
            Output name.
        minimal : bool, optional
            Cancel pole-zero pairs (``TransferFunction.minreal``).  Default False.

        Returns
        -------
        control.TransferFunction
            ``output(s) / input(s)`` [output unit / input unit].

        Raises
        ------
        UnknownSignalError
            If ``input`` or ``output`` is unknown.

        Examples
        --------
        >>> lm = LinearModel(A=[[-2.0]], B=[[1.0]], C=[[3.0]], D=[[0.0]],
        ...                  states=("speed",), inputs=("torque",), outputs=("speed",))
        >>> tf = lm.transfer_function("torque", "speed")  # 3 / (s + 2)
        >>> [float(c) for c in tf.num[0][0]], [float(c) for c in tf.den[0][0]]
        ([3.0], [1.0, 2.0])
        """
        import control as ct

        sub = self.subsystem(inputs=[input], outputs=[output])
        tf = ct.ss2tf(sub.to_statespace())
        return tf.minreal() if minimal else tf

    def poles(self) -> np.ndarray:
        """Eigenvalues of ``A`` [1/s], complex."""
        return np.linalg.eigvals(self.A).astype(complex)

    # ------------------------------------------------------------- file I/O
    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the model, its names and operating point to an ``.npz`` file.

        The file is written in a temporary file next to ``path`` and renamed,
        so a failure leaves no half-written file.  No pickles are used.

        Parameters
        ----------
        path : path-like
            Target file; ``.npz`` is appended when missing.

        Returns
        -------
        pathlib.Path
            The path written.
        """
        target = Path(path)
        if target.suffix != ".npz":
            target = target.with_name(target.name + ".npz")
        data: dict[str, np.ndarray] = {
            "format": np.array(NPZ_FORMAT),
            "A": np.asarray(self.A), "B": np.asarray(self.B),
            "C": np.asarray(self.C), "D": np.asarray(self.D),
            "states": np.array(self.states, dtype=str),
            "inputs": np.array(self.inputs, dtype=str),
            "outputs": np.array(self.outputs, dtype=str),
            "fd_discrepancy": np.array(self.fd_discrepancy),
            "valid": np.array(self.valid),
            "invalid_reasons": np.array(self.invalid_reasons, dtype=str),
            "excluded_states": np.array(self.excluded_states, dtype=str),
            "excluded_outputs": np.array(self.excluded_outputs, dtype=str),
            "guard_names": np.array(tuple(self.guard_margins), dtype=str),
            "guard_values": np.array(tuple(self.guard_margins.values()), dtype=float),
            "has_operating_point": np.array(self.operating_point is not None),
        }
        op = self.operating_point
        if op is not None:
            data.update({
                "op_x": op.x, "op_u": op.u, "op_y": op.y, "op_p": op.p, "op_xdot": op.xdot,
                "op_states": np.array(op.states, dtype=str),
                "op_inputs": np.array(op.inputs, dtype=str),
                "op_outputs": np.array(op.outputs, dtype=str),
                "op_parameters": np.array(op.parameters, dtype=str),
                "op_drifting_states": np.array(op.drifting_states, dtype=str),
                "op_residual": np.array(op.residual),
                "op_method": np.array(op.method),
            })
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
        try:
            with os.fdopen(fd, "wb") as fh:
                np.savez(fh, **data)
            os.replace(tmp, target)
        except BaseException:
            if os.path.exists(tmp):
                os.unlink(tmp)
            raise
        return target

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> "LinearModel":
        """Read a model written by :meth:`save`.

        Raises
        ------
        ValueError
            If the file is not a ``linearization.LinearModel/1`` archive.
        """

        def names(key: str) -> tuple[str, ...]:
            return tuple(str(v) for v in data[key].tolist())

        with np.load(Path(path), allow_pickle=False) as data:
            fmt = str(data["format"]) if "format" in data.files else "(none)"
            if fmt != NPZ_FORMAT:
                raise ValueError(f"{path}: format {fmt!r}, expected {NPZ_FORMAT!r}")
            op = None
            if bool(data["has_operating_point"]):
                op_states = names("op_states")
                xdot = np.asarray(data["op_xdot"], dtype=float)
                drifting = names("op_drifting_states")
                op = OperatingPoint(
                    x=data["op_x"], u=data["op_u"], y=data["op_y"], p=data["op_p"],
                    states=op_states, inputs=names("op_inputs"),
                    outputs=names("op_outputs"), parameters=names("op_parameters"),
                    residual=float(data["op_residual"]),
                    drift_rates={s: float(xdot[op_states.index(s)]) for s in drifting},
                    xdot=xdot, drifting_states=drifting, method=str(data["op_method"]),
                )
            return cls(
                A=data["A"], B=data["B"], C=data["C"], D=data["D"],
                states=names("states"), inputs=names("inputs"), outputs=names("outputs"),
                operating_point=op,
                fd_discrepancy=float(data["fd_discrepancy"]),
                valid=bool(data["valid"]),
                invalid_reasons=names("invalid_reasons"),
                excluded_states=names("excluded_states"),
                excluded_outputs=names("excluded_outputs"),
                guard_margins=dict(zip(names("guard_names"),
                                       map(float, data["guard_values"].tolist()))),
            )
