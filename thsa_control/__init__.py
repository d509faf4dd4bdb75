"""thsa-control: design and check the controls of an electrical THSA.

The plant at levels A-D is one casadi effect library (``thsa_control.model``);
the simulator, and later the linearisation, tuning and identification,
consume the same expressions.  Only ``thsa_control.report`` imports
matplotlib.
"""

from .loops.design import Design, derive_gains, load_design, nominal_design_path
from .errors import DesignError, ModelError, ParameterError, RigDataError, ScenarioError, SolverError, ThsaError
from .model import EFFECTS, LEVELS, Plant, build_plant, resolve_effects
from .model.params import Parameter, ParameterSet, default_parameters, load_parameters
from .sim.scenarios import SCENARIOS, Scenario, get_scenario
from .sim.simulate import InputSeries, SimulationResult, SimulationSettings, Simulator, simulate
from .fit.identify import IdentificationResult, IdentificationSettings, Identifier, ParameterEstimate
from .fit.replay import ReplayResult, ReplaySettings, analyse_replay, replay, replay_closed_loop, replay_open_loop
from .fit.virtual_rig import VirtualRig, excitation_inputs
from .loops.linear import ConditionGrid, OperatingCondition, PlantLinearization, current_driven, linearize_conditions, plant_model
from .loops.analysis import (AnalysisSettings, DesignAnalysis, LoopAnalysis, analyse_configurations, analyse_design,
                       analyse_loops, check_requirements, describing_functions)
from .loops.statespace import closed_loop, open_loop

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
    "check_requirements", "describing_functions", "open_loop", "closed_loop",
    "__version__",
]
