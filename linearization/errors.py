"""Exceptions of :mod:`linearization`.

Every error names its culprit (signal, equation, residual) and subclasses a
built-in so that callers can catch ``ValueError`` without knowing this
package.  Imports nothing but the standard library; never imports
``thsa_control``.
"""

from __future__ import annotations

from collections.abc import Sequence

__all__ = [
    "ModelStructureError",
    "UnknownSignalError",
    "OperatingPointError",
]


class ModelStructureError(ValueError):
    """A model's names do not match its casadi ``Function`` (sizes, I/O names)."""


class UnknownSignalError(KeyError, ValueError):
    """A signal name that the model does not have.

    Subclasses both ``KeyError`` (it is a failed lookup by name) and
    ``ValueError`` (the caller passed a bad value).

    Parameters
    ----------
    kind : str
        Which family of signals was searched (``'state'``, ``'input'``,
        ``'output'``, ``'parameter'``, ...).
    name : str
        The name that was not found.
    valid : sequence of str
        The names that exist for ``kind``.

    Examples
    --------
    >>> err = UnknownSignalError("state", "speed", ("position", "velocity"))
    >>> str(err)
    "unknown state 'speed'; valid states: 'position', 'velocity'"
    >>> isinstance(err, KeyError) and isinstance(err, ValueError)
    True
    """

    def __init__(self, kind: str, name: str, valid: Sequence[str]):
        self.kind = kind
        self.name = name
        self.valid = tuple(valid)
        listed = ", ".join(repr(v) for v in self.valid) or "(none)"
        self.message = f"unknown {kind} {name!r}; valid {kind}s: {listed}"
        super().__init__(self.message)

    def __str__(self) -> str:  # KeyError would repr() the message
        return self.message


class OperatingPointError(ValueError):
    """The operating-point solver did not satisfy the equations.

    Parameters
    ----------
    message : str
        Human-readable explanation (already names the worst equation).
    residual_norm : float
        Euclidean norm of the equation residuals at the returned iterate
        [mixed units, those of each equation].
    worst_equation : str
        Name of the equation with the largest absolute residual, e.g.
        ``"d(speed)/dt = 0"`` or ``"output speed = target"``.
    worst_residual : float
        Residual of that equation [unit of the equation].
    method : str
        Solver chain that was tried (e.g. ``"newton -> gauss-newton"``).
    """

    def __init__(
        self,
        message: str,
        *,
        residual_norm: float,
        worst_equation: str,
        worst_residual: float,
        method: str,
    ):
        self.residual_norm = float(residual_norm)
        self.worst_equation = worst_equation
        self.worst_residual = float(worst_residual)
        self.method = method
        super().__init__(message)
