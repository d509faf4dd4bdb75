"""Generic numerical linearisation of named casadi models.

A model is a casadi ``Function`` ``f(x, u, p) -> (xdot, y)`` wrapped with the
names of its states, inputs, outputs and parameters (:class:`NamedModel`).
This package finds operating points with chosen signals held, linearises by
casadi AD with a finite-difference cross-check and detection of kinks and
jumps (where a linear model is not valid), converts to python-control
objects with the names kept, and does the same over a grid of points in one
vectorised call.

This package never imports ``thsa_control``: it knows nothing about
actuators and depends only on numpy, scipy, casadi and python-control.

Examples
--------
>>> from linearization import (OperatingPointSpec, find_operating_point,
...                            linearize, mass_spring_damper)
>>> m = mass_spring_damper()
>>> p = {"mass": 1.0, "damping": 2.0, "stiffness": 4.0}
>>> op = find_operating_point(m, p, OperatingPointSpec(inputs={"force": 1.0}))
>>> lm = linearize(m, op)
>>> tf = lm.transfer_function("force", "position")  # 1 / (s^2 + 2 s + 4)
>>> [round(float(c), 9) for c in tf.den[0][0]]
[1.0, 2.0, 4.0]
"""

from .batch import LinearModelBatch, frequency_response_batch, linearize_batch
from .errors import ModelStructureError, OperatingPointError, UnknownSignalError
from .examples import mass_spring_damper
from .jacobian import finite_difference_jacobians, jacobian_function, jacobians, linearize
from .linear_model import LinearModel
from .model import NamedModel
from .operating_point import (
    OperatingPoint,
    OperatingPointBatch,
    OperatingPointSpec,
    SolverSettings,
    find_operating_point,
    find_operating_points,
)

__all__ = [
    # model
    "NamedModel",
    # operating points
    "OperatingPointSpec",
    "SolverSettings",
    "OperatingPoint",
    "OperatingPointBatch",
    "find_operating_point",
    "find_operating_points",
    # linearisation
    "linearize",
    "LinearModel",
    "jacobian_function",
    "jacobians",
    "finite_difference_jacobians",
    # batch
    "linearize_batch",
    "LinearModelBatch",
    "frequency_response_batch",
    # errors
    "ModelStructureError",
    "UnknownSignalError",
    "OperatingPointError",
    # examples
    "mass_spring_damper",
]
