"""Controller designs as data: load, validate and derive the cascade gains.

A design file (TOML, under ``designs/``) holds the gains of the rig's cascade
in the units the rig uses::

    control_period_s = 1e-4
    computation_delay_samples = 0        # optional, 0 or 1
    [current_loop]  kp_V_per_A, ki_V_per_A_s, voltage_limit_V (optional: V_dc/sqrt(3))
    [velocity_loop] kp_A_per_rad_s, ki_A_per_rad, current_limit_A
    [position_loop] kp_per_s, max_speed_mm_s (optional, 15)
    [switching]     bumpless_handover (optional, false): hold the velocity
                    integrator through a fault gap and preset the current
                    integrator of the channel taking over (back-EMF feed-forward)
    [derivation]    the loop bandwidths the gains come from (optional)
    [requirements.<loop>]  what the analysis checks (optional; <loop> is current_loop,
                    velocity_loop or position_loop; keys in REQUIREMENT_KEYS, see analysis.py)
    [validation]    what `thsa check` asks of the nonlinear validation runs (optional; keys in
                    VALIDATION_KEYS: max_speed_error_percent, max_overshoot_percent,
                    max_settling_time_s, max_current_peak_A, max_current_rate_A_per_s)
    [tuning]        provenance written by `thsa tune` (optional; kept as data, never read back
                    as gains)

Gains are derived from stated bandwidths by :func:`derive_gains`: the current
PI cancels the stator pole (``kp = L wc``, ``ki = R wc``, a first-order closed
loop of bandwidth ``wc``); the velocity PI gives crossover ``wv`` on the
rigid-body plant ``Kt / (J s)`` with its zero ``zero_ratio`` below
(``kp = J wv / Kt``, ``ki = kp wv / zero_ratio``); the position P loop has
``kp = wx``.
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DesignError
from ..model.laws import back_emf_constant, kinematic_ratio, torque_constant
from ..model.params import ParameterSet

__all__ = ["Design", "load_design", "parse_design", "check_control_period", "derive_gains", "reflected_inertia",
           "nominal_design_path", "VALIDATION_KEYS", "REQUIREMENT_KEYS",
           "REQUIREMENT_LOOPS", "validate_requirements", "validate_validation"]

_TABLES = {
    "current_loop": {"kp_V_per_A": True, "ki_V_per_A_s": True, "voltage_limit_V": False},
    "velocity_loop": {"kp_A_per_rad_s": True, "ki_A_per_rad": True, "current_limit_A": True},
    "position_loop": {"kp_per_s": True, "max_speed_mm_s": False},
}
_TOP = {"name", "description", "control_period_s", "computation_delay_samples", "derivation", "requirements",
        "switching", "analysis", "validation", "tuning", *_TABLES}


@dataclass(frozen=True)
class Design:
    """Gains and settings of the cascade (SI units).

    Attributes
    ----------
    current_kp [V/A], current_ki [V/(A s)], voltage_limit [V] (None: V_dc/sqrt(3)),
    velocity_kp [A s/rad], velocity_ki [A/rad], current_limit [A],
    position_kp [1/s], max_speed [m/s], control_period [s],
    computation_delay_samples (0 or 1), requirements, derivation (dicts as given),
    analysis (the ``[analysis]`` grid of ``thsa report``, checked by
    ``thsa_control.loops.analysis.AnalysisSettings.from_design``).
    """

    name: str
    current_kp: float
    current_ki: float
    velocity_kp: float
    velocity_ki: float
    current_limit: float
    position_kp: float
    control_period: float = 1e-4
    voltage_limit: float | None = None
    max_speed: float = 0.015
    computation_delay_samples: int = 0
    bumpless_handover: bool = False
    source: str = "<memory>"
    description: str = ""
    derivation: dict = field(default_factory=dict)
    requirements: dict = field(default_factory=dict)
    validation: dict = field(default_factory=dict)
    tuning: dict = field(default_factory=dict)
    analysis: dict = field(default_factory=dict)

    def __post_init__(self):
        checks = {
            "current_loop.kp_V_per_A": self.current_kp, "current_loop.ki_V_per_A_s": self.current_ki,
            "velocity_loop.kp_A_per_rad_s": self.velocity_kp, "velocity_loop.ki_A_per_rad": self.velocity_ki,
            "velocity_loop.current_limit_A": self.current_limit, "position_loop.kp_per_s": self.position_kp,
            "control_period_s": self.control_period, "position_loop.max_speed_mm_s": self.max_speed,
        }
        if self.voltage_limit is not None:
            checks["current_loop.voltage_limit_V"] = self.voltage_limit
        for key, value in checks.items():
            if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
                raise DesignError(self.source, f"{key} = {value!r} is not a finite number")
            # a zero position gain opens the position loop; a zero velocity ki is a P velocity loop
            if value < 0 or (value == 0 and key not in ("position_loop.kp_per_s", "velocity_loop.ki_A_per_rad")):
                raise DesignError(self.source, f"{key} = {value!r} must be positive")
        if not isinstance(self.bumpless_handover, bool):
            raise DesignError(self.source, f"switching.bumpless_handover = {self.bumpless_handover!r} must be true or false")
        if self.computation_delay_samples not in (0, 1):
            raise DesignError(self.source, f"computation_delay_samples = {self.computation_delay_samples!r} must be 0 or 1")

    def check_against(self, params: ParameterSet) -> None:
        """Raise :class:`DesignError` if the design asks more than the actuator has."""
        check_control_period(self.control_period, params, self.source, "control_period_s")
        imax = params.value("motor.max_current")
        if self.current_limit > imax * (1 + 1e-9):
            raise DesignError(self.source, f"velocity_loop.current_limit_A = {self.current_limit:g} exceeds motor.max_current = {imax:g} A")
        vmax = params.value("inverter.dc_bus_voltage") / math.sqrt(3.0)
        if self.voltage_limit is not None and self.voltage_limit > vmax * (1 + 1e-4):
            raise DesignError(self.source, f"current_loop.voltage_limit_V = {self.voltage_limit:g} exceeds V_dc/sqrt(3) = {vmax:.6g} V")

    def controller_vector(self, params: ParameterSet, *, accel_limit: float, jerk_limit: float = math.inf,
                          motor_off_at_zero: bool = True) -> np.ndarray:
        """Values in ``controllers.CONTROLLER_PARAMETERS`` order (SI)."""
        self.check_against(params)
        vmax = params.value("inverter.dc_bus_voltage") / math.sqrt(3.0)
        r = kinematic_ratio(params)
        return np.array([
            self.current_kp, self.current_ki, self.voltage_limit if self.voltage_limit is not None else vmax,
            self.velocity_kp, self.velocity_ki, self.current_limit, self.position_kp,
            float(self.computation_delay_samples), accel_limit, jerk_limit, self.max_speed,
            1.0 if motor_off_at_zero else 0.0, r, 1.0 if self.bumpless_handover else 0.0,
            params.value("motor.resistance"), back_emf_constant(params),
        ], dtype=float)

    def to_toml_dict(self) -> dict:
        """The design as a TOML-ready dict in the file's units."""
        doc = {"name": self.name, "description": self.description, "control_period_s": self.control_period,
               "computation_delay_samples": self.computation_delay_samples,
               "current_loop": {"kp_V_per_A": self.current_kp, "ki_V_per_A_s": self.current_ki},
               "velocity_loop": {"kp_A_per_rad_s": self.velocity_kp, "ki_A_per_rad": self.velocity_ki,
                                 "current_limit_A": self.current_limit},
               "position_loop": {"kp_per_s": self.position_kp, "max_speed_mm_s": self.max_speed * 1e3}}
        if self.voltage_limit is not None:
            doc["current_loop"]["voltage_limit_V"] = self.voltage_limit
        if self.derivation:
            doc["derivation"] = dict(self.derivation)
        if self.requirements:
            doc["requirements"] = dict(self.requirements)
        if self.validation:
            doc["validation"] = dict(self.validation)
        if self.tuning:
            doc["tuning"] = dict(self.tuning)
        if self.bumpless_handover:
            doc["switching"] = {"bumpless_handover": True}
        if self.analysis:
            doc["analysis"] = dict(self.analysis)
        return doc


def parse_design(doc: dict, source: str = "<dict>") -> Design:
    """Validate a design document (the TOML's content) and build a :class:`Design`.

    Raises
    ------
    DesignError
        Unknown or missing table or key, non-numeric, negative or zero gain.
    """
    unknown = set(doc) - _TOP
    if unknown:
        raise DesignError(source, f"unknown key(s) {sorted(unknown)}; allowed: {sorted(_TOP)}")
    values = {}
    for table, keys in _TABLES.items():
        if table not in doc:
            raise DesignError(source, f"missing table [{table}]")
        if not isinstance(doc[table], dict):
            raise DesignError(source, f"[{table}] must be a table")
        extra = set(doc[table]) - set(keys)
        if extra:
            raise DesignError(source, f"unknown key(s) {sorted(extra)} in [{table}]; allowed: {sorted(keys)}")
        for key, required in keys.items():
            if key in doc[table]:
                values[f"{table}.{key}"] = doc[table][key]
            elif required:
                raise DesignError(source, f"missing {table}.{key}")
    if "control_period_s" not in doc:
        raise DesignError(source, "missing control_period_s")
    for key in ("derivation", "requirements", "switching", "analysis", "validation", "tuning"):
        if key in doc and not isinstance(doc[key], dict):
            raise DesignError(source, f"[{key}] must be a table")
    delay = doc.get("computation_delay_samples", 0)
    validate_requirements(doc.get("requirements", {}), source)
    validate_validation(doc.get("validation", {}), source)
    switching = doc.get("switching", {})
    extra = set(switching) - {"bumpless_handover"}
    if extra:
        raise DesignError(source, f"unknown key(s) {sorted(extra)} in [switching]; allowed: ['bumpless_handover']")
    max_speed_mm = values.get("position_loop.max_speed_mm_s", 15.0)
    if not isinstance(max_speed_mm, (int, float)) or isinstance(max_speed_mm, bool):
        raise DesignError(source, f"position_loop.max_speed_mm_s = {max_speed_mm!r} is not a number")
    return Design(
        name=str(doc.get("name", Path(source).stem)), description=str(doc.get("description", "")),
        current_kp=values["current_loop.kp_V_per_A"], current_ki=values["current_loop.ki_V_per_A_s"],
        voltage_limit=values.get("current_loop.voltage_limit_V"),
        velocity_kp=values["velocity_loop.kp_A_per_rad_s"], velocity_ki=values["velocity_loop.ki_A_per_rad"],
        current_limit=values["velocity_loop.current_limit_A"], position_kp=values["position_loop.kp_per_s"],
        max_speed=max_speed_mm * 1e-3, control_period=doc["control_period_s"],
        computation_delay_samples=delay, bumpless_handover=switching.get("bumpless_handover", False), source=source,
        derivation=dict(doc.get("derivation", {})), requirements=dict(doc.get("requirements", {})),
        validation=dict(doc.get("validation", {})), tuning=dict(doc.get("tuning", {})),
        analysis=dict(doc.get("analysis", {})),
    )


#: ``[requirements.<loop>]`` tables and their keys (checked at every valid grid point by
#: ``thsa_control.loops.analysis.check_requirements``; gain margins are compared by magnitude).
REQUIREMENT_LOOPS = ("current_loop", "velocity_loop", "position_loop")
REQUIREMENT_KEYS = ("min_phase_margin_deg", "min_gain_margin_db", "min_delay_margin_s", "min_bandwidth_hz",
                    "max_sensitivity_peak", "max_overshoot_percent", "max_settling_time_s", "max_rise_time_s")


def validate_requirements(req: dict, source: str) -> None:
    """Raise :class:`DesignError` naming the first unknown ``[requirements.<loop>]`` table or key, or a bad value.

    Public: ``thsa tune --require`` checks its overrides with it (re-exported by :mod:`thsa_control.verdict`).
    """
    for loop, table in req.items():
        if loop not in REQUIREMENT_LOOPS:
            raise DesignError(source, f"unknown table [requirements.{loop}]; allowed: {list(REQUIREMENT_LOOPS)}")
        if not isinstance(table, dict):
            raise DesignError(source, f"[requirements.{loop}] must be a table")
        for key, value in table.items():
            if key not in REQUIREMENT_KEYS:
                raise DesignError(source, f"unknown key {key!r} in [requirements.{loop}]; allowed: {list(REQUIREMENT_KEYS)}")
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
                raise DesignError(source, f"requirements.{loop}.{key} = {value!r} must be a finite number >= 0")


#: ``[validation]`` keys: limits on the nonlinear validation runs of ``thsa check``
#: (``thsa_control.tuning.validation``); speed error in % as the papers define it.
VALIDATION_KEYS = ("max_speed_error_percent", "max_overshoot_percent", "max_settling_time_s",
                   "max_current_peak_A", "max_current_rate_A_per_s")


def validate_validation(table: dict, source: str) -> None:
    """Raise :class:`DesignError` naming an unknown ``[validation]`` key or a bad value."""
    for key, value in table.items():
        if key not in VALIDATION_KEYS:
            raise DesignError(source, f"unknown key {key!r} in [validation]; allowed: {list(VALIDATION_KEYS)}")
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value <= 0:
            raise DesignError(source, f"validation.{key} = {value!r} must be a finite number > 0")


def nominal_design_path() -> Path:
    """Path of ``designs/nominal.toml`` of the repository this package is installed from.

    Raises
    ------
    DesignError
        When the package is not installed from a checkout (``pip install -e .``)
        and the current folder has no ``designs/nominal.toml`` either.
    """
    for cand in (Path(__file__).resolve().parents[2] / "designs" / "nominal.toml",
                 Path.cwd() / "designs" / "nominal.toml", Path.cwd().parent / "designs" / "nominal.toml"):
        if cand.exists():
            return cand
    raise DesignError("designs/nominal.toml", "not found: install from the repository with 'pip install -e .' "
                      "or pass a design file")


#: Fastest admissible control period [s]: 1 MHz, above any inverter's current sampling.
MIN_CONTROL_PERIOD = 1e-6
#: At least this many control periods per electrical time constant L/R of the motor.
MIN_SAMPLES_PER_ELECTRICAL_TAU = 1.0


def check_control_period(period: float, params: ParameterSet, source: str, key: str = "control_period_s") -> None:
    """Refuse a control period [s] that the plant's electrical time constant L/R cannot live with.

    A sampled current loop needs at least one sample per L/R (1.83 ms for
    the default motor; the rig runs of the tests use 1 ms); below 1 us no
    inverter samples its current (and a simulation would need billions of
    steps).

    Raises
    ------
    DesignError
        Naming ``source`` and ``key``, with the reason.
    """
    tau_e = params.value("motor.inductance") / params.value("motor.resistance")
    upper = tau_e / MIN_SAMPLES_PER_ELECTRICAL_TAU
    if not (isinstance(period, (int, float)) and not isinstance(period, bool) and math.isfinite(period)):
        raise DesignError(source, f"{key} = {period!r} is not a finite number")
    if period < MIN_CONTROL_PERIOD:
        raise DesignError(source, f"{key} = {period:g} s is below {MIN_CONTROL_PERIOD:g} s (1 MHz): "
                                  "no inverter samples its current that fast")
    if period > upper:
        raise DesignError(source, f"{key} = {period:g} s is longer than the motor's electrical time constant "
                                  f"L/R = {tau_e * 1e3:.3g} ms: a sampled current loop needs at least one sample "
                                  f"per L/R (at most {upper:.3g} s)")


def load_design(path: str | Path) -> Design:
    """Load and validate a design file; errors name the file and the key."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise DesignError(str(path), f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise DesignError(str(path), f"not UTF-8 text (byte {exc.start}: {exc.reason})") from None
    except RecursionError:
        raise DesignError(str(path), "nested too deeply") from None
    except tomllib.TOMLDecodeError as exc:
        raise DesignError(str(path), f"not valid TOML: {exc}") from None
    return parse_design(doc, source=str(path))


def reflected_inertia(params: ParameterSet, level: str | None = "A", effects=()) -> float:
    """Inertia the motor current accelerates, at the motor shaft [kg m^2], as the plant states it.

    The rigid drive's whole inertia; with ``drivetrain_compliance`` the rotors'
    alone (the spring carries no torque at first).  No second copy of the sum
    the structure builds: :meth:`~thsa_control.model.Plant.inertia`.
    """
    from ..model import build_plant

    return build_plant(level, effects, params=params).inertia(params)[1]


def derive_gains(params: ParameterSet, *, current_bandwidth_hz: float, velocity_crossover_hz: float,
                 velocity_pi_zero_ratio: float, position_bandwidth_hz: float, name: str = "derived",
                 control_period_s: float = 1e-4, current_limit_A: float | None = None, rotors: int = 2,
                 computation_delay_samples: int = 0, **extra) -> Design:
    """Gains of the cascade from loop bandwidths at 25 degC (level-A plant, ``rotors`` rotors).

    Parameters
    ----------
    params : ParameterSet
        Actuator.
    current_bandwidth_hz : float
        Closed current-loop bandwidth [Hz].
    velocity_crossover_hz : float
        Velocity-loop crossover [Hz].
    velocity_pi_zero_ratio : float
        Crossover / PI zero [-].
    position_bandwidth_hz : float
        Position-loop bandwidth [Hz].
    rotors : {1, 2}
        Rotors on the shaft: 2 (default) is the actuator as built, the
        standby rotor dragged by the active motor (J x 1.89); 1 the primary
        alone.
    computation_delay_samples : {0, 1}
        Stored in the design; the bandwidths must leave room for it (the
        current loop's phase margin is 90 deg - w_c (1.5 h) with one sample).

    Examples
    --------
    >>> from thsa_control.model.params import default_parameters
    >>> d = derive_gains(default_parameters(), current_bandwidth_hz=1000, velocity_crossover_hz=30,
    ...                  velocity_pi_zero_ratio=5, position_bandwidth_hz=2, rotors=1)
    >>> round(d.current_kp, 3), round(d.current_ki, 1)
    (14.137, 7728.3)
    """
    wc = 2 * math.pi * current_bandwidth_hz
    wv = 2 * math.pi * velocity_crossover_hz
    kt = torque_constant(params)
    if rotors not in (1, 2):
        raise DesignError("derivation", f"rotors = {rotors!r} must be 1 or 2")
    j = reflected_inertia(params, "A", ("standby_motor",) if rotors == 2 else ())
    kpv = j * wv / kt
    derivation = dict(current_bandwidth_hz=current_bandwidth_hz, velocity_crossover_hz=velocity_crossover_hz,
                      velocity_pi_zero_ratio=velocity_pi_zero_ratio, position_bandwidth_hz=position_bandwidth_hz,
                      rotors=rotors, **extra)
    return Design(
        name=name, current_kp=params.value("motor.inductance") * wc, current_ki=params.value("motor.resistance") * wc,
        velocity_kp=kpv, velocity_ki=kpv * wv / velocity_pi_zero_ratio,
        current_limit=current_limit_A if current_limit_A is not None else params.value("motor.max_current"),
        position_kp=2 * math.pi * position_bandwidth_hz, control_period=control_period_s, derivation=derivation,
        computation_delay_samples=computation_delay_samples,
    )
