"""Fault analysis (the papers' model F): detection times, peak loads, false-alarm margins, sweeps.

Modules: ``analysis`` (detection times, peak loads, false-alarm margins,
sweeps, on runs of the closed loop with the monitors in it); the command
is ``thsa_control/cli/faults.py``.  The fault schedule of a scenario (``sim/events.py``), the
monitor settings (``sim/monitor_settings.py``), the monitors and
reconfiguration as a loop extension (``sim/monitors.py``) and the scenario
files (``sim/scenarios.py``) are part of the simulator, which never imports
this package.
"""
