"""Exceptions of thsa-control.

Every error names its culprit (file, column, row, parameter, effect, value) and
subclasses a built-in so that callers may catch ``ValueError`` or
``RuntimeError`` without knowing this package.  Nothing here imports the rest
of the package.
"""

from __future__ import annotations

__all__ = [
    "ThsaError",
    "ParameterError",
    "ModelError",
    "DesignError",
    "ScenarioError",
    "RigDataError",
    "SolverError",
    "SignalError",
    "OutputError",
    "UsageError",
]


class ThsaError(Exception):
    """Base class of every error raised on purpose by thsa-control."""


class ParameterError(ThsaError, ValueError):
    """A parameter is unknown, missing, outside its bounds or malformed.

    Parameters
    ----------
    name : str
        Parameter name (``motor.resistance`` style).
    message : str
        What is wrong with it.
    """

    def __init__(self, name: str, message: str):
        self.name = name
        super().__init__(f"parameter '{name}': {message}")


class ModelError(ThsaError, ValueError):
    """An unknown level or effect, or an effect set that cannot be built."""


class DesignError(ThsaError, ValueError):
    """A controller design is malformed, unstable or cannot meet a requirement.

    Parameters
    ----------
    source : str
        File or object the design came from.
    message : str
        What is wrong (names the table and key).
    """

    def __init__(self, source: str, message: str):
        self.source = source
        super().__init__(f"design '{source}': {message}")


class ScenarioError(ThsaError, ValueError):
    """An unknown scenario or a malformed scenario definition."""


class RigDataError(ThsaError, ValueError):
    """A rig run violates ``thsa-rig-run/1``.

    Parameters
    ----------
    file : str
        Path of the offending file.
    problems : list of (column, row, message)
        Every violation found; ``column`` or ``row`` may be ``None`` when the
        problem is not tied to one.  Rows count data rows from 1 (the header is
        row 0).
    """

    def __init__(self, file: str, problems: list[tuple[str | None, int | None, str]]):
        self.file = str(file)
        self.problems = list(problems)
        lines = []
        for column, row, message in self.problems:
            where = []
            if column is not None:
                where.append(f"column '{column}'")
            if row is not None:
                where.append(f"row {row}")
            lines.append(f"  {', '.join(where) + ': ' if where else ''}{message}")
        super().__init__(f"{self.file}: {len(self.problems)} problem(s)\n" + "\n".join(lines))


class SolverError(ThsaError, RuntimeError):
    """A numerical solver failed (status and statistics attached).

    Parameters
    ----------
    solver : str
        Which solver.
    status : str
        Its return status.
    stats : dict, optional
        Its statistics.
    """

    def __init__(self, solver: str, status: str, stats: dict | None = None):
        self.solver = solver
        self.status = status
        self.stats = dict(stats or {})
        super().__init__(f"{solver} failed: {status}")


class SignalError(ThsaError, ValueError):
    """A signal handed to an analysis is malformed (shape, length, NaN, order).

    Parameters
    ----------
    signal : str
        Name of the signal (``measured['nut_position']``, ``time``, ...).
    message : str
        What is wrong with it.
    """

    def __init__(self, signal: str, message: str):
        self.signal = signal
        super().__init__(f"signal '{signal}': {message}")


class OutputError(ThsaError, ValueError):
    """An output folder may not be written (foreign, a file, holds an input, not writable).

    Parameters
    ----------
    path : str
        The output path as given.
    message : str
        Why it is refused.
    """

    def __init__(self, path: str, message: str):
        self.path = path
        super().__init__(f"output folder '{path}' {message}")


class UsageError(ThsaError, ValueError):
    """A command-line option has a value that cannot work (names the option and the reason)."""
