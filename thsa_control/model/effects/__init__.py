"""The effect modules: each registers its effects (:func:`thsa_control.model.effect.register`).

``papers``: the papers' incremental effects (standby motor, load-path and
drive-train compliance, temperature friction, the no-back in its three
forms).  ``drive``: generic drive effects a rig engineer suspects on any screw
drive.  ``faults``: the papers' model F.  Importing this package registers
them all, in this order (which, with each effect's phase, is the application
order).  A new effect is a new module here that calls ``register`` and one
import line below.
"""

from . import papers, drive, faults  # noqa: F401  (registration, in this order)
from ..effect import EFFECT_ORDER, EFFECTS, Effect

__all__ = ["EFFECTS", "EFFECT_ORDER", "Effect"]
