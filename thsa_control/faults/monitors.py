"""Moved to :mod:`thsa_control.sim.monitors` (scenario data and the monitor loop extension live beside the
simulator, which never imports this package); this name is kept so that existing imports work."""

from ..sim.monitors import *  # noqa: F401,F403
from ..sim.monitors import __all__  # noqa: F401
