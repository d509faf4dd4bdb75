"""Plant model: functional structure, effect library and levels (casadi only)."""

from .effects import EFFECT_ORDER, EFFECTS, Effect
from .levels import LEVELS, resolve_effects
from .plant import Plant, build_plant
from .structure import INPUTS, StateInfo

__all__ = ["EFFECTS", "EFFECT_ORDER", "Effect", "LEVELS", "resolve_effects", "Plant", "build_plant", "INPUTS", "StateInfo"]
