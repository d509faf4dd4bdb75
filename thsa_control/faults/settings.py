"""Moved to :mod:`thsa_control.sim.monitor_settings` (scenario data and the monitor loop extension live beside the
simulator, which never imports this package); this name is kept so that existing imports work."""

from ..sim.monitor_settings import *  # noqa: F401,F403
from ..sim.monitor_settings import __all__  # noqa: F401
