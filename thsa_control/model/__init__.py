"""Plant model: functional structure, effect library and levels (casadi only).

What it owns, in layers (each imports only the ones above it):

``effect.py``
    The :class:`Effect` contract (states, parameters, outputs with neutral
    values, phase, tracer candidate spec, linearisation hints) and the
    registry :data:`EFFECTS` / :func:`register`: the one extension point.
``params.py``
    Parameters with unit, bounds and source (no physics).
``laws.py``
    Pure laws (screw-to-nut ratio, torque constant, motor electrics, friction,
    load path, stiffness, limiter), used by the structure, the effects and the
    tools; the component laws for component identification.
``structure.py``
    The functional structure (balances, sign conventions, the assembly the
    effects add to); it writes every effect's outputs at their neutral value.
``effects/``
    The effect modules; importing the package registers them.
``levels.py``, ``plant.py``
    The composition: named levels, and :func:`build_plant`, which assembles a
    set once and exports ``f``, ``step``, ``init`` and what the model knows
    (measurement map, kinematic ratio, torque constant, inertias).

It must not import anything of the workbench outside ``model/`` except
``thsa_control.errors`` (no numerics of other subpackages, no I/O beyond the
parameter files, no plotting).

Adding an effect: write a module in ``effects/`` whose ``apply(assembly)``
adds the terms and which calls :func:`register` with its declarations, and
import it in ``effects/__init__.py``.  Simulation, linearisation,
identification and the tracer then offer it.
"""

from . import effects as _effects  # noqa: F401  (registers the library's effects first)
from .effect import (
    EFFECT_ORDER, EFFECTS, CandidateSpec, Effect, Guard, LinearHints, NoNeutral, NotCandidate, OperatingContext, Output,
    Phase,
    effect_order, register, unregister,
)
from .laws import kinematic_ratio, torque_constant
from .levels import LEVELS, resolve_effects
from .plant import SENSORS, Plant, Sensor, build_plant
from .structure import INPUTS, StateInfo

__all__ = ["EFFECTS", "EFFECT_ORDER", "Effect", "Phase", "Output", "CandidateSpec", "NotCandidate", "NoNeutral", "Guard",
           "LinearHints", "OperatingContext", "register", "unregister", "effect_order", "LEVELS",
           "resolve_effects", "Plant", "Sensor", "SENSORS", "build_plant", "INPUTS", "StateInfo",
           "kinematic_ratio", "torque_constant"]
