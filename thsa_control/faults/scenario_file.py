"""Moved to :mod:`thsa_control.sim.scenarios` (scenario files are read beside ``Scenario``); this name is kept
so that existing imports work."""

from ..sim.scenarios import load_scenario_file, scenario_from_dict, scenario_to_dict  # noqa: F401

__all__ = ["load_scenario_file", "scenario_from_dict", "scenario_to_dict"]
