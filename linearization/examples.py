"""Tiny textbook models used in the docstring examples of :mod:`linearization`.

They are generic physics (no actuator knowledge) and are also handy for
trying the API.  Imports casadi only; never imports ``thsa_control``.
"""

from __future__ import annotations

import casadi as ca

from .model import NamedModel

__all__ = ["mass_spring_damper"]


def mass_spring_damper() -> NamedModel:
    """Mass on a linear spring and viscous damper, driven by a force.

    ``m * dv/dt = F - c * v - k * x``, ``dx/dt = v``.

    States ``position`` [m] and ``velocity`` [m/s] (positive in the direction
    of the force); input ``force`` [N]; outputs ``position`` [m] and
    ``velocity`` [m/s]; parameters ``mass`` [kg], ``damping`` [N s/m],
    ``stiffness`` [N/m].

    Returns
    -------
    NamedModel

    Examples
    --------
    >>> m = mass_spring_damper()
    >>> m.states, m.parameters
    (('position', 'velocity'), ('mass', 'damping', 'stiffness'))
    """
    x = ca.SX.sym("x", 2)
    u = ca.SX.sym("u", 1)
    p = ca.SX.sym("p", 3)
    position, velocity = x[0], x[1]
    force = u[0]
    mass, damping, stiffness = p[0], p[1], p[2]
    acceleration = (force - damping * velocity - stiffness * position) / mass
    f = ca.Function(
        "mass_spring_damper",
        [x, u, p],
        [ca.vertcat(velocity, acceleration), ca.vertcat(position, velocity)],
        ["x", "u", "p"],
        ["xdot", "y"],
    )
    return NamedModel(
        f,
        states=("position", "velocity"),
        inputs=("force",),
        outputs=("position", "velocity"),
        parameters=("mass", "damping", "stiffness"),
    )
