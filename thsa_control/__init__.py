"""thsa-control: design and check the controls of an electrical THSA.

The plant at levels A-D is one casadi effect library (``thsa_control.model``);
the simulator, and later the linearisation, tuning and identification,
consume the same expressions.  Only ``thsa_control.report`` imports
matplotlib.
"""

# The public names are imported on first use (PEP 562), so that ``thsa --help``
# and ``import thsa_control.errors`` do not pay for casadi, python-control and
# scipy.  ``_LAZY`` maps each name to the module that defines it.
_LAZY = {
    ".loops.design": ("Design", "derive_gains", "load_design", "nominal_design_path"),
    ".errors": ("DesignError", "ModelError", "ParameterError", "RigDataError", "ScenarioError", "SolverError",
                "ThsaError"),
    ".model": ("EFFECTS", "LEVELS", "Plant", "build_plant", "resolve_effects"),
    ".model.params": ("Parameter", "ParameterSet", "default_parameters", "load_parameters"),
    ".sim.scenarios": ("SCENARIOS", "Scenario", "get_scenario"),
    ".sim.simulate": ("InputSeries", "SimulationResult", "SimulationSettings", "Simulator", "simulate"),
    ".fit.identify": ("IdentificationResult", "IdentificationSettings", "Identifier", "ParameterEstimate"),
    ".fit.replay": ("ReplayResult", "ReplaySettings", "analyse_replay", "replay", "replay_closed_loop",
                    "replay_open_loop"),
    ".fit.virtual_rig": ("VirtualRig", "excitation_inputs"),
    ".loops.linear": ("ConditionGrid", "OperatingCondition", "PlantLinearization", "current_driven",
                      "linearize_conditions", "plant_model"),
    ".loops.analysis": ("AnalysisSettings", "DesignAnalysis", "LoopAnalysis", "analyse_configurations",
                        "analyse_design", "analyse_loops", "check_requirements", "describing_functions"),
    ".loops.statespace": ("open_loop", "closed_loop", "loop_frequency_response"),
}
_WHERE = {name: module for module, names in _LAZY.items() for name in names}


def __getattr__(name: str):
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'thsa_control' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module, __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_WHERE))


__version__ = "0.1.0"

__all__ = [
    "Design", "derive_gains", "load_design", "nominal_design_path",
    "DesignError", "ModelError", "ParameterError", "RigDataError", "ScenarioError", "SolverError", "ThsaError",
    "EFFECTS", "LEVELS", "Plant", "build_plant", "resolve_effects",
    "Parameter", "ParameterSet", "default_parameters", "load_parameters",
    "SCENARIOS", "Scenario", "get_scenario",
    "InputSeries", "SimulationResult", "SimulationSettings", "Simulator", "simulate",
    "IdentificationResult", "IdentificationSettings", "Identifier", "ParameterEstimate",
    "ReplayResult", "ReplaySettings", "analyse_replay", "replay", "replay_closed_loop", "replay_open_loop",
    "VirtualRig", "excitation_inputs",
    "ConditionGrid", "OperatingCondition", "PlantLinearization", "current_driven", "linearize_conditions", "plant_model",
    "AnalysisSettings", "DesignAnalysis", "LoopAnalysis", "analyse_configurations", "analyse_design", "analyse_loops",
    "check_requirements", "describing_functions", "open_loop", "closed_loop", "loop_frequency_response",
    "__version__",
]
