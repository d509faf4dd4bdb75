"""Faults and monitoring (the papers' model F): fault schedules, sensor faults, the
position-monitoring logic with its reconfiguration, run in the closed loop.

Modules: ``events`` (scheduled fault inputs of a scenario), ``settings``
(monitor thresholds), ``monitors`` (the casadi monitor and reconfiguration
logic), ``loop`` (the closed loop with sensors, monitors and faults, compiled),
``scenario_file`` (scenarios written in TOML), ``analysis`` (detection times,
peak loads, false-alarm margins, sweeps); the command is ``thsa_control/cli/faults.py``.
This ``__init__`` imports nothing, so that ``sim.scenarios`` can use
``events`` and ``settings`` without an import cycle.
"""
