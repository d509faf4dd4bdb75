"""Model levels: named sets of effects over the one functional structure.

``A`` is the functional model (efficiencies, linear friction, the ideal
irreversible no-back); each level adds effects to the one below (B replaces
the ideal no-back by the friction disks).  ``resolve_effects("A",
remove=["noback_ideal"])`` is the reversible functional model.  ``temperature_friction`` (the papers' model G) and
``standby_motor`` may be added to any set.

Examples
--------
>>> resolve_effects("C")
('noback_backlash', 'noback_quadrant_friction')
>>> resolve_effects("A", add=["noback_quadrant_friction"])
('noback_quadrant_friction',)
>>> resolve_effects("B", add=["temperature_friction"])
('temperature_friction', 'noback_quadrant_friction')
"""

from __future__ import annotations

from collections.abc import Iterable

from ..errors import ModelError
from .effect import EFFECTS, effect_order

__all__ = ["LEVELS", "resolve_effects"]

LEVELS: dict[str, tuple[str, ...]] = {
    "A": ("noback_ideal",),
    "B": ("noback_quadrant_friction",),
    "C": ("noback_quadrant_friction", "noback_backlash"),
    "D": ("noback_quadrant_friction", "noback_backlash", "loadpath_compliance"),
}


def resolve_effects(level: str | None = "A", add: Iterable[str] = (), remove: Iterable[str] = ()) -> tuple[str, ...]:
    """Effect set of ``level`` plus ``add`` minus ``remove``, in application order.

    Parameters
    ----------
    level : {"A", "B", "C", "D"} or None
        Base level (None: the empty set).
    add, remove : iterable of str
        Effect names.

    Raises
    ------
    ModelError
        Unknown level or effect, or an effect whose requirement is missing.
    """
    if level is None:
        base: tuple[str, ...] = ()
    else:
        key = str(level).strip().upper()
        if key not in LEVELS:
            raise ModelError(f"unknown model level {level!r}; levels are {', '.join(LEVELS)}")
        base = LEVELS[key]
    add, remove = list(add), list(remove)
    for name in add + remove:
        if name not in EFFECTS:
            raise ModelError(f"unknown effect {name!r}; effects are {', '.join(effect_order())}")
    chosen = (set(base) | set(add)) - set(remove)
    for name in list(chosen):
        chosen -= set(EFFECTS[name].supersedes) - set(add)
    for name in chosen:
        clash = set(EFFECTS[name].supersedes) & chosen
        if clash:
            raise ModelError(f"effects {name!r} and {sorted(clash)[0]!r} model the same part; choose one")
    for name in chosen:
        for req in EFFECTS[name].requires:
            if req not in chosen:
                raise ModelError(f"effect {name!r} needs effect {req!r} in the same set")
    return tuple(e for e in effect_order() if e in chosen)
