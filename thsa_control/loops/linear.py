"""THSA adapter of the generic :mod:`linearization` package.

This module owns the THSA-specific side of linearisation: it wraps a plant of
:func:`thsa_control.model.build_plant` as a :class:`linearization.NamedModel`,
turns operating conditions (trim nut speed [m/s], load [N], temperature
[degC], active motor) into operating-point specifications, and translates the
generic validity checks into THSA words (zero speed / stick, backlash edge,
Stribeck region).  It does no loop analysis (``analysis.py``) and no plotting
(``report/``); it never imports matplotlib.

The adapted model
-----------------
The adapter names no effect: each effect declares what linearisation needs
(:class:`~thsa_control.model.LinearHints`: states re-expressed relative to
another, drifting states, validity guards, the state that probes the main
body's inertia, operating-point guesses), and the adapter reads these for the
effects of the plant.  With the library's effects:

* **States**: the plant's states, except that at level D ``surface_position``
  is re-expressed as ``loadpath_deflection = nut_position - surface_position``
  [m] (positive: the nut pushes the surface), so that a steady motion, in
  which both positions ramp, is an equilibrium of every non-drifting state.
* **Drifting states** (excluded from the linear models): ``nut_position``
  and, at levels C and D, the pawl clearances ``pawl_clearance_comp`` and
  ``pawl_clearance_tens``.  In a steady motion they ramp at a constant rate
  (``r w`` and ``+-w/N``), and nothing in the dynamics depends on them away
  from an edge.  The position loop gets its nut kinematics back as an
  integrator of ``nut_speed`` (``analysis.py``).
* **Inputs**: ``voltage_primary``, ``voltage_standby`` [V], ``load_force``
  [N, compressive positive] and ``disturbance_torque`` [N m at the motor
  shaft, positive in the extending direction, like the motor torque].  The
  disturbance torque is an extra test input (zero in every operating point)
  used for load-torque responses and the describing-function loop of
  friction; it enters the speed balance through ``1/J`` taken from the
  plant's own expression (``d(dw/dt)/d(motor_current) / Kt``).
* **Parameters**: the plant's parameters, then the operating conditions that
  are held for a linearisation but are not small signals: ``enable_primary``,
  ``enable_standby`` (0/1) and ``temperature`` [degC].  Holding the
  temperature as a parameter keeps the kink of the cold-friction law at
  25 degC (``max(T_ref - T, 0)``) out of the smoothness check: temperature
  does not move on the time scale of the loops.

Operating points
----------------
An :class:`OperatingCondition` holds the load force, the disturbance torque
(0), the inactive channel's voltage (0), the motor speed (``nut_speed / r``,
held as a state so that the solver never steps across the friction jump at
zero speed) and the drifting states; the solver finds the active channel's
voltage, the currents and (level D) the load-path deflection and surface
speed.  The problem is square, so the whole grid goes through one mapped
casadi Newton solve (:func:`linearization.find_operating_points`) and one
:func:`linearization.linearize_batch` call.

Pawl clearances (levels C, D): in a steady motion one pawl is engaged (the
one that locks the direction of motion; its clearance is held at 0 by the
discrete map and runs negative in the continuous form, which reads ``c <= 0``
as engaged) and the other ratchets freely (``0 < c < pitch``).  By default
the point is placed strictly inside both sets (engaged at ``-pitch/2``, free
at ``+pitch/2``); ``pawl="edge"`` puts the engaged one at exactly 0, the
instant it engages after a reversal, which is a backlash edge.

Validity
--------
A point is invalid, with its reason, when

* its nut speed is within ``min_speed`` of zero: friction is set-valued there
  (stick), the continuous right-hand side jumps, and a linear model would be
  silently wrong (``"zero speed"``);
* a pawl clearance or the load-path deflection sits within a band of a
  contact edge (``"backlash edge"``);
* the generic finite-difference check finds a kink or a jump in a state or a
  control input (the reason of :mod:`linearization` is kept, prefixed).

A kink in the ``load_force`` column only (the load changes sign: the
efficiency and the no-back disks depend on ``|F|``) does not invalidate the
loops; it is recorded as a note: the response to a load step is then
one-sided.  Negative local friction slopes (Stribeck region) are valid but
reported: they remove damping and can make the mechanical mode unstable.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np
from numpy.typing import NDArray

from linearization import (
    LinearModel,
    LinearModelBatch,
    NamedModel,
    OperatingPointBatch,
    OperatingPointSpec,
    SolverSettings,
    find_operating_points,
    linearize_batch,
)

from ..errors import ModelError, SolverError
from .conditions import (
    ACTIVE_CHANNELS, CONDITION_PARAMETERS, INPUTS, Active, ConditionGrid, LinearizationSettings, OperatingCondition,  # noqa: F401
    conditions_tuple,
)
from ..model import EFFECTS, OperatingContext, Plant, build_plant
from ..model.laws import back_emf_constant, drivetrain_modes, drivetrain_stiffness, values_of
from ..model.params import ParameterSet, default_parameters

__all__ = [
    "INPUTS",
    "CONDITION_PARAMETERS",
    "LinearizationSettings",
    "OperatingCondition",
    "ConditionGrid",
    "PlantModel",
    "PlantLinearization",
    "plant_model",
    "operating_points",
    "linearize_conditions",
    "linearize_condition",
    "current_driven",
    "format_linear_model",
]

@dataclass(frozen=True, eq=False)
class PlantModel:
    """A THSA plant wrapped for linearisation (see the module notes).

    Build it with :func:`plant_model`.

    Attributes
    ----------
    level : str or None
        Model level.
    plant : Plant
        The plant (casadi Functions of ``thsa_control.model``).
    named : linearization.NamedModel
        The adapted model.
    params : ParameterSet
        Actuator parameters.
    p_plant : numpy.ndarray
        ``params`` in the plant's order.
    guard : casadi.Function
        ``(x, u, p) -> margins`` of the validity guards (negative: violated).
    guard_names : tuple of str
        One name per margin.
    settings : LinearizationSettings
    friction_slope_fn : casadi.Function
        ``(x, u, p) -> d(friction_torque)/d(motor_speed)`` [N m s/rad].
    """

    level: str | None
    plant: Plant
    named: NamedModel
    params: ParameterSet
    p_plant: NDArray[np.float64]
    guard: ca.Function
    guard_names: tuple[str, ...]
    settings: LinearizationSettings
    friction_slope_fn: ca.Function

    @property
    def effects(self) -> tuple[str, ...]:
        """Effect set of the plant."""
        return self.plant.effects

    @property
    def kinematic_ratio(self) -> float:
        """Nut travel per motor radian ``r = lead / (2 pi N)`` [m/rad] (the plant's)."""
        return self.plant.kinematic_ratio(self.p_plant)

    @property
    def torque_constant(self) -> float:
        """Motor torque constant [N m/A] (the plant's)."""
        return self.plant.torque_constant(self.p_plant)

    def describe(self) -> str:
        """One line: level, effects, drifting states."""
        lvl = self.level if self.level is not None else "-"
        eff = ", ".join(self.effects) or "functional"
        rotors = ("two rotors: the active motor drags the standby rotor" if "standby_motor" in self.effects
                  else "one rotor (the standby rotor left out)")
        line = f"level {lvl} ({eff}); {rotors}"
        if "drivetrain_compliance" in self.effects:
            k = drivetrain_stiffness(self.params)
            j_m, j_r = self.plant.inertia(self.p_plant)
            f = drivetrain_modes(k, j_m, j_r, self.params.value("gear.efficiency"))[0] / (2 * math.pi)  # motor driving
            line += f"; compliant drive train, rotor/screw torsional resonance near {f:.0f} Hz (assumed stiffness)"
        return line + f"; drifting (excluded): {', '.join(self.named.drifting_states)}"

    def params_inertia_load(self) -> float:
        """Inertia of the gear-output side at the motor shaft [kg m^2] (the plant's main body)."""
        return self.plant.inertia(self.p_plant)[0]


#: Default model level and effects of the linear workflow: :func:`plant_model`, the loop analysis
#: (``AnalysisSettings``), ``open_loop`` / ``closed_loop``, ``thsa report`` and ``thsa linearize``.
DEFAULT_LEVEL = "B"
#: The cold friction law and the standby motor, whose rotor the primary drags (the plant that exists).
DEFAULT_EFFECTS: tuple[str, ...] = ("temperature_friction", "standby_motor")



def plant_model(level: str | None = DEFAULT_LEVEL, effects: Iterable[str] | None = None,
                params: ParameterSet | None = None, *, settings: LinearizationSettings | None = None) -> PlantModel:
    """Wrap the plant of ``level`` + ``effects`` as a named model for linearisation.

    The model is in SI units (m, m/s, N, rad/s, A, V; temperature in degC);
    ``thsa linearize`` takes the speed in mm/s and converts it.

    Parameters
    ----------
    level : {'A', 'B', 'C', 'D'} or None
        Model level; default :data:`DEFAULT_LEVEL` (as ``thsa report`` / ``thsa linearize``).
    effects : iterable of str, optional
        Effects added (e.g. ``["temperature_friction", "standby_motor"]``); default
        :data:`DEFAULT_EFFECTS` (as the CLI); ``()`` for none.
    params : ParameterSet, optional
        Actuator; default the embedded one.
    settings : LinearizationSettings, optional
        Validity bands and solver settings.

    Returns
    -------
    PlantModel

    Raises
    ------
    ModelError
        Unknown level or effect.

    Examples
    --------
    >>> m = plant_model("D", ())
    >>> m.named.states[:5]
    ('motor_current', 'motor_speed', 'nut_position', 'loadpath_deflection', 'surface_speed')
    >>> m.named.drifting_states
    ('nut_position', 'pawl_clearance_comp', 'pawl_clearance_tens')
    """
    params = params or default_parameters()
    settings = settings or LinearizationSettings()
    effects = DEFAULT_EFFECTS if effects is None else tuple(effects)
    plant = build_plant(level, effects, params=params)
    names = plant.state_names
    n_x, n_p = len(names), len(plant.parameters)
    hints = [EFFECTS[e].linear for e in plant.effects]
    # states re-expressed relative to a reference (state -> (new name, reference)): new = reference - state
    relative = {s: rel for h in hints for s, rel in h.relative.items() if s in names}
    states = tuple(relative[s][0] if s in relative else s for s in names)
    x = ca.SX.sym("x", n_x)
    u = ca.SX.sym("u", len(INPUTS))
    p = ca.SX.sym("p", n_p + len(CONDITION_PARAMETERS))
    pp = p[:n_p]
    pdict = {n: pp[k] for k, n in enumerate(plant.parameters)}
    U = dict(zip(INPUTS, ca.vertsplit(u)))
    C = dict(zip(CONDITION_PARAMETERS, ca.vertsplit(p[n_p:])))
    xs = list(ca.vertsplit(x))
    for s, (_, ref) in relative.items():
        # The plant reads the two positions only through their difference.  Feeding it
        # (reference, state) = (difference, 0) gives that difference exactly, with no
        # cancellation error, so the reference acts on nothing but its own outputs.
        i_s, i_ref = names.index(s), names.index(ref)
        xs[i_ref], xs[i_s] = x[i_s], ca.SX(0.0)
    plant_u = {"voltage_primary": U["voltage_primary"], "voltage_standby": U["voltage_standby"],
               "enable_primary": C["enable_primary"], "enable_standby": C["enable_standby"],
               "load_force": U["load_force"], "temperature": C["temperature"],
               "brake": 0.0, "surface_jam": 0.0, "loadpath_failure": 0.0}  # fault inputs healthy
    missing = [n for n in plant.inputs if n not in plant_u]
    if missing:  # pragma: no cover - INPUTS are fixed by structure.py
        raise ModelError(f"plant input(s) {missing} have no counterpart in the linearisation adapter")
    xdot, y = plant.f(ca.vertcat(*xs), ca.vertcat(*(plant_u[n] for n in plant.inputs)), pp)
    xdot = list(ca.vertsplit(xdot))
    if relative:
        ys = list(ca.vertsplit(y))
        for s, (_, ref) in relative.items():
            i_s, i_ref = names.index(s), names.index(ref)
            xdot[i_s] = xdot[i_ref] - xdot[i_s]  # d(reference - state)/dt
            if ref in plant.outputs:
                ys[plant.outputs.index(ref)] = x[i_ref]
            if s in plant.outputs:
                ys[plant.outputs.index(s)] = x[i_ref] - x[i_s]
        y = ca.vertcat(*ys)
    i_w = names.index("motor_speed")
    # the disturbance torque enters the main body: 1/J from the plant's own speed balance, through the
    # torque that enters it with unit gain (the motor's, or the effect's that couples it: the spring of a
    # compliant drive train)
    probe, gain = "motor_current", plant.kt_fn(pp)
    for h in hints:
        if h.inertia_probe is not None:
            probe, gain = h.inertia_probe[0], h.inertia_probe[1](pdict)
    inv_j = ca.jacobian(xdot[i_w], x[names.index(probe)]) / gain
    xdot[i_w] = xdot[i_w] + inv_j * U["disturbance_torque"]
    f = ca.Function("thsa_linear_adapter", [x, u, p], [ca.vertcat(*xdot), y], ["x", "u", "p"], ["xdot", "y"])
    drifting = ("nut_position",) + tuple(s for h in hints for s in h.drifting if s in names)
    named = NamedModel(f, states, INPUTS, plant.outputs, tuple(plant.parameters) + CONDITION_PARAMETERS,
                       drifting_states=drifting)

    # validity guards (x, u, p) -> margins, negative = violated
    r = plant.ratio_fn(pp)
    guards = [ca.fabs(r * x[i_w]) - settings.min_speed]
    gnames = ["zero_speed"]
    xnamed = dict(zip(states, ca.vertsplit(x)))
    for h in hints:
        for g in h.guards:
            guards.append(g.distance(xnamed, pdict) - getattr(settings, g.band))
            gnames.append(g.name)
    guard = ca.Function("thsa_validity", [x, u, p], [ca.vertcat(*guards)], ["x", "u", "p"], ["margins"])
    # local slope of the set-valued friction channels with motor speed (computed here rather than
    # read from the linear model's C, because the generic package drops outputs that depend
    # structurally on an excluded drifting state, as friction_torque does on the pawl clearances)
    t_f = y[plant.outputs.index("friction_torque")]
    slope = ca.Function("thsa_friction_slope", [x, u, p], [ca.densify(ca.jacobian(t_f, x[i_w]))],
                        ["x", "u", "p"], ["slope"])
    return PlantModel(level=None if level is None else str(level).upper(), plant=plant, named=named, params=params,
                      p_plant=plant.p_vector(params), guard=guard, guard_names=tuple(gnames), settings=settings,
                      friction_slope_fn=slope)


def _p_grid(model: PlantModel, conds: Sequence[OperatingCondition]) -> NDArray[np.float64]:
    cols = []
    for c in conds:
        if c.active == "standby" and "standby_motor" not in model.effects:
            raise ModelError(f"condition '{c.label()}' needs the standby_motor effect; "
                             f"the plant has {list(model.effects)}")
        en = (1.0, 0.0) if c.active == "primary" else (0.0, 1.0)
        cols.append(np.concatenate([model.p_plant, en, [c.temperature]]))
    return np.column_stack(cols)


def _spec(model: PlantModel, c: OperatingCondition) -> OperatingPointSpec:
    r = model.kinematic_ratio
    w = c.nut_speed / r
    kt = model.torque_constant
    v_active, i_active = ACTIVE_CHANNELS[c.active]
    v_off = "voltage_standby" if c.active == "primary" else "voltage_primary"
    i_guess = c.load_force * r / kt
    guess_x = {i_active: i_guess}
    # The speed is held as a state, not solved for through the output nut_speed: the
    # solver then never steps across w = 0, where the friction of the continuous form jumps.
    states = {"nut_position": 0.0, "motor_speed": w}
    plant, params = model.plant, model.params

    def rest_state():
        return dict(zip(plant.state_names, plant.initial_state(params, load_force=c.load_force)))

    ctx = OperatingContext(speed=w, nut_speed=c.nut_speed, load_force=c.load_force, current=i_guess,
                           torque_constant=kt, values=values_of(params), pawl=model.settings.pawl,
                           rest_state=rest_state)
    for e in model.effects:  # each effect holds or guesses its own states
        hint = EFFECTS[e].linear.operating_point
        if hint is not None:
            held, guesses = hint(ctx)
            states.update(held)
            guess_x.update(guesses)
    return OperatingPointSpec(
        inputs={v_off: 0.0, "load_force": c.load_force, "disturbance_torque": 0.0},
        states=states,
        guess_x=guess_x,
        guess_u={v_active: back_emf_constant(params) * w + params.value("motor.resistance") * i_guess},
    )


def operating_points(model: PlantModel, conditions) -> OperatingPointBatch:
    """Solve the operating points of ``conditions`` (one mapped Newton solve).

    Parameters
    ----------
    model : PlantModel
        From :func:`plant_model`.
    conditions : OperatingCondition, ConditionGrid or sequence of OperatingCondition
        Where.

    Returns
    -------
    linearization.OperatingPointBatch

    Raises
    ------
    SolverError
        When a point has no steady motion (names the condition and the
        worst equation).
    """
    conds = conditions_tuple(conditions)
    P = _p_grid(model, conds)
    specs = [_spec(model, c) for c in conds]
    ops = find_operating_points(model.named, P, specs, settings=SolverSettings(tol=model.settings.solver_tol),
                                on_failure="mark")
    bad = np.flatnonzero(~ops.converged)
    if bad.size:
        k = int(bad[0])
        raise SolverError("operating point", f"no steady motion at '{conds[k].label()}' "
                          f"(residual {ops.residuals[k]:.3g}; {len(bad)} of {len(conds)} points failed)",
                          {"failed": [conds[int(j)].label() for j in bad]})
    return ops


@dataclass(frozen=True, eq=False)
class PlantLinearization:
    """Linear models of the plant at operating conditions, with THSA validity.

    Attributes
    ----------
    model : PlantModel
    conditions : tuple of OperatingCondition
    batch : linearization.LinearModelBatch
        Matrices and operating points (generic validity kept inside).
    valid : numpy.ndarray of bool, shape (N,)
        False at zero speed, at a backlash edge, or where the generic check
        finds a kink or jump in a state or a control input.
    reasons : tuple of tuple of str
        Why each invalid point is invalid (empty when valid).
    notes : tuple of tuple of str
        Facts that do not invalidate the loops: a load-direction kink, a
        Stribeck region (negative friction slope), negative net damping.
    friction_slope : numpy.ndarray, shape (N,)
        Local slope of the set-valued friction channels (no-back disks,
        cold Coulomb drag, efficiency channel) with motor speed
        ``d T_f / d w`` [N m s/rad at the motor shaft]; negative in a
        Stribeck region.
    net_damping : numpy.ndarray, shape (N,)
        ``-J d(dw/dt)/dw``: all speed-proportional torque at the motor shaft
        (viscous drags, friction slope, load-path damping) [N m s/rad];
        negative means an unstable open-loop mechanical mode.
    inertia : numpy.ndarray, shape (N,)
        Total inertia at the motor shaft [kg m^2] (from ``1/J`` of the model).
    """

    model: PlantModel
    conditions: tuple[OperatingCondition, ...]
    batch: LinearModelBatch
    valid: NDArray[np.bool_]
    reasons: tuple[tuple[str, ...], ...]
    notes: tuple[tuple[str, ...], ...]
    friction_slope: NDArray[np.float64]
    net_damping: NDArray[np.float64]
    inertia: NDArray[np.float64]

    def __len__(self) -> int:
        return len(self.conditions)

    def __getitem__(self, k: int) -> LinearModel:
        """Linear model of point ``k`` with the THSA validity and reasons."""
        lm = self.batch[k]
        return replace(lm, valid=bool(self.valid[k]), invalid_reasons=self.reasons[k])

    @property
    def stribeck(self) -> NDArray[np.bool_]:
        """True where the friction slope is negative enough to matter (see :func:`_is_stribeck`)."""
        return _is_stribeck(self.friction_slope, self.net_damping)

    def ad_fd_discrepancy(self, k: int = 0) -> float:
        """AD vs central finite differences of the kept ``A``, ``B``, ``C``, ``D`` at point ``k``.

        Largest ``|FD - AD| / max(|AD|, |FD|, floor)`` over the entries.  The
        floor is the larger of ``1e-9`` times the largest entry of the row and
        the round-off level of a difference quotient ``1e3 eps |f_i| / h_j``
        (step ``h_j = 1e-6 max(1, |z_j|)``), so that entries at round-off
        level (``1e-23`` next to ``1e3``) do not count as disagreement.
        Reported by ``thsa linearize``.
        """
        from linearization import finite_difference_jacobians

        lm = self.batch[k]
        op = lm.operating_point
        named = self.model.named
        A, B, C, D = finite_difference_jacobians(named, op.x, op.u, op.p)
        ks = [named.states.index(s) for s in lm.states]
        ko = [named.outputs.index(o) for o in lm.outputs]
        eps = np.finfo(float).eps
        hx = 1e-6 * np.maximum(1.0, np.abs(op.x[ks]))
        hu = 1e-6 * np.maximum(1.0, np.abs(op.u))
        fx, fy = np.abs(op.xdot[ks]), np.abs(op.y[ko])
        worst = 0.0
        for ad, fd, f, h in ((lm.A, A[np.ix_(ks, ks)], fx, hx), (lm.B, B[ks], fx, hu),
                             (lm.C, C[np.ix_(ko, ks)], fy, hx), (lm.D, D[ko], fy, hu)):
            if not ad.size:
                continue
            row = np.max(np.maximum(np.abs(ad), np.abs(fd)), axis=1, keepdims=True)
            floor = np.maximum(1e-9 * row, 1e3 * eps * f[:, None] / h[None, :])
            denom = np.maximum(np.maximum(np.abs(ad), np.abs(fd)), floor)
            with np.errstate(invalid="ignore", divide="ignore"):
                rel = np.where(denom > 0, np.abs(fd - ad) / denom, 0.0)
            worst = max(worst, float(np.nanmax(rel)))
        return worst

    def channel(self, k: int | None = None) -> tuple[str, str]:
        """(voltage input, current output) of the active channel of point ``k`` (default: first)."""
        return ACTIVE_CHANNELS[self.conditions[0 if k is None else k].active]

    def invalid_points(self) -> list[tuple[OperatingCondition, tuple[str, ...]]]:
        """``(condition, reasons)`` of every invalid point."""
        return [(self.conditions[k], self.reasons[k]) for k in np.flatnonzero(~self.valid)]

    def report(self) -> str:
        """Matrices, poles and validity of each linear model (:func:`format_linear_model`)."""
        return format_linear_model(self)

    def to_dict(self) -> dict:
        """Per condition: validity, reasons, A/B/C/D with names (SI), JSON-able."""
        from ..report.results import linearization_to_dict

        return linearization_to_dict(self)

    def plot(self, ax=None):
        """Poles of every linear model in the s-plane; ``ax``: one Axes."""
        from ..report.results import plot_linearization_poles

        return plot_linearization_poles(self, ax)


def _is_stribeck(slope, damping):
    """A friction slope that removes at least 1 % of the other speed-proportional damping."""
    other = np.abs(np.asarray(damping) - np.asarray(slope))
    return np.asarray(slope) < -0.01 * np.maximum(other, 1e-12)


def _classify(model: PlantModel, conds, batch: LinearModelBatch, slope, damping):
    hints = [EFFECTS[e].linear for e in model.effects]
    kinks = {k: m for h in hints for k, m in h.kinks.items()}
    # the effects' clearance and contact states: a kink there is a backlash edge
    edge_states = tuple(s for h in hints for s in h.drifting) + tuple(
        new for h in hints for new, _ in h.relative.values())
    reasons, notes = [], []
    min_mm = model.settings.min_speed * 1e3
    for k, c in enumerate(conds):
        why, note = [], []
        texts = sorted(batch.invalid_reasons[k], key=lambda t: "validity guard" not in t)
        for text in texts:
            if "validity guard 'zero_speed'" in text:
                why.append(f"zero speed (stick): nut speed {c.nut_speed * 1e3:g} mm/s is within "
                           f"{min_mm:g} mm/s of zero, where friction is set-valued; use the describing-function view")
            elif "validity guard" in text and "_edge" in text:
                which = text.split("'")[1]
                why.append(f"backlash edge ({which.replace('_edge', '')}): {text}")
            elif "input 'load_force'" in text:
                note.append(f"load kink (|F| laws at F = 0, or the no-back's light disk set unloading: at |F| = 2 "
                            f"preload for equal disk sets): the load-step response is one-sided; {text}")
            elif "input 'disturbance_torque'" in text:  # pragma: no cover - the torque enters linearly
                note.append(text)
            elif "state 'motor_speed'" in text or "d(motor_speed)" in text:
                why.append(f"friction discontinuity at this speed (stick/slip): {text}")
            elif any(k in text for k in kinks):
                why.append(f"{next(m for k, m in kinks.items() if k in text)}: {text}")
            elif any(s in text for s in edge_states):
                why.append(f"backlash edge: {text}")
            else:
                why.append(text)
        if batch.valid[k] or why:
            pass
        if not why and not batch.valid[k] and not note:  # pragma: no cover - defensive
            why.append("; ".join(batch.invalid_reasons[k]))
        if not why:
            if _is_stribeck(slope[k], damping[k]):
                note.append(f"Stribeck region: friction slope {slope[k]:.3g} N m s/rad < 0 removes damping "
                            "(destabilising)")
            if damping[k] < 0:
                note.append(f"net damping {damping[k]:.3g} N m s/rad < 0: the open-loop mechanical mode is unstable")
        reasons.append(tuple(why))
        notes.append(tuple(note))
    return tuple(reasons), tuple(notes)


def linearize_conditions(model: PlantModel, conditions, *, ops: OperatingPointBatch | None = None,
                         parallelization: str = "serial") -> PlantLinearization:
    """Linear models at many operating conditions: one solve, one ``linearize_batch`` call.

    Parameters
    ----------
    model : PlantModel
        From :func:`plant_model`.
    conditions : OperatingCondition, ConditionGrid or sequence of OperatingCondition
        Where.
    ops : linearization.OperatingPointBatch, optional
        Already solved points of the same conditions (skips the solve).
    parallelization : {'serial', 'openmp', 'thread'}
        casadi ``map`` parallelisation.

    Returns
    -------
    PlantLinearization

    Raises
    ------
    SolverError
        When a condition has no steady motion.

    Examples
    --------
    >>> m = plant_model("B", ["temperature_friction"])
    >>> lin = linearize_conditions(m, [OperatingCondition(5e-3, 20e3, -30.0), OperatingCondition(0.0, 20e3, -30.0)])
    >>> lin.valid.tolist()
    [True, False]
    >>> lin.reasons[1][0][:10]
    'zero speed'
    """
    conds = conditions_tuple(conditions)
    if ops is None:
        ops = operating_points(model, conds)
    s = model.settings
    batch = linearize_batch(model.named, ops.X, ops.U, ops.P, fd_check=s.fd_check, kink_rtol=s.kink_rtol,
                            validity=model.guard, validity_names=model.guard_names,
                            parallelization=parallelization)
    iw = batch.states.index("motor_speed")
    inv_j = batch.B[:, iw, batch.inputs.index("disturbance_torque")]
    inertia = 1.0 / inv_j
    damping = -batch.A[:, iw, iw] * inertia
    n = ops.X.shape[1]
    fn = model.friction_slope_fn if n == 1 else model.friction_slope_fn.map(n, parallelization)
    slope = np.asarray(fn(ops.X, ops.U, ops.P), dtype=float).reshape(-1)
    reasons, notes = _classify(model, conds, batch, slope, damping)
    valid = np.array([not r for r in reasons], dtype=bool)
    return PlantLinearization(model=model, conditions=conds, batch=batch, valid=valid, reasons=reasons,
                              notes=notes, friction_slope=slope, net_damping=damping, inertia=inertia)


def linearize_condition(model: PlantModel, condition: OperatingCondition) -> PlantLinearization:
    """:func:`linearize_conditions` at one condition (``result[0]`` is its LinearModel)."""
    return linearize_conditions(model, [condition])


def current_driven(lm: LinearModel, current: str = "motor_current") -> LinearModel:
    """The same linear model with a current state turned into an input (ideal current loop).

    The state ``current`` is removed; its column of ``A`` (``C``) becomes an
    input column of ``B`` (``D``) named like the state.  So
    ``current_driven(lm).transfer_function("motor_current", "motor_speed")``
    is the mechanical plant seen by the velocity loop when the current
    follows its reference exactly: ``Kt / (J s + b)`` at level A.

    Parameters
    ----------
    lm : linearization.LinearModel
        A linear model whose states include ``current``.
    current : str
        Name of the current state [A].

    Returns
    -------
    linearization.LinearModel

    Raises
    ------
    ValueError
        If ``current`` is not a state of ``lm``.
    """
    if current not in lm.states:
        raise ValueError(f"{current!r} is not a state of the linear model; states are {list(lm.states)}")
    j = lm.states.index(current)
    keep = [i for i in range(len(lm.states)) if i != j]
    return replace(
        lm,
        A=lm.A[np.ix_(keep, keep)],
        B=np.hstack([lm.A[keep, j:j + 1], lm.B[keep, :]]),
        C=lm.C[:, keep],
        D=np.hstack([lm.C[:, j:j + 1], lm.D]),
        states=tuple(lm.states[i] for i in keep),
        inputs=(current,) + tuple(lm.inputs),
    )


_KEY_OUTPUTS = ("motor_current", "standby_current", "motor_speed", "nut_speed", "loadpath_force", "surface_speed",
                "friction_torque")


def _matrix(name: str, M, rows, cols) -> list[str]:
    width = max([len(c) for c in cols] + [11])
    lines = [f"{name} =", " " * 22 + " ".join(f"{c[:width]:>{width}s}" for c in cols)]
    for rname, row in zip(rows, M):
        lines.append(f"  {rname[:20]:20s}" + " ".join(f"{v:>{width}.5g}" for v in row))
    return lines


def format_linear_model(lin: PlantLinearization, k: int = 0) -> str:
    """Printable model of point ``k``: condition, validity, matrices, poles, transfer functions.

    ``C`` and ``D`` are shown for the key outputs only (currents, speeds,
    forces); the saved ``.npz`` has all of them.
    """
    lm = lin[k]
    cond = lin.conditions[k]
    op = lm.operating_point
    v_in, i_out = lin.channel(k)
    out = [f"THSA linear model at {cond.label()}",
           f"  {lin.model.describe()}",
           f"  operating point: {v_in} = {op.input(v_in):.6g} V, {i_out} = {op.output(i_out):.6g} A, "
           f"motor_speed = {op.output('motor_speed'):.6g} rad/s, nut_speed = {op.output('nut_speed') * 1e3:.6g} mm/s",
           f"  valid: {'yes' if lin.valid[k] else 'NO'}; AD vs central finite differences: "
           f"{lin.ad_fd_discrepancy(k):.2e} (largest relative difference)"]
    out += [f"  invalid: {r}" for r in lin.reasons[k]]
    out += [f"  note: {n}" for n in lin.notes[k]]
    out.append(f"  inertia {lin.inertia[k]:.6g} kg m^2, net damping {lin.net_damping[k]:.6g} N m s/rad, "
               f"friction slope {lin.friction_slope[k]:.6g} N m s/rad (at the motor shaft)")
    out += _matrix("A", lm.A, lm.states, lm.states)
    out += _matrix("B", lm.B, lm.states, lm.inputs)
    key = [o for o in _KEY_OUTPUTS if o in lm.outputs]
    sub = lm.subsystem(outputs=key)
    out += _matrix("C (key outputs)", sub.C, key, lm.states)
    out += _matrix("D (key outputs)", sub.D, key, lm.inputs)
    poles = np.sort_complex(lm.poles())
    out.append("poles [1/s]: " + ", ".join(f"{p.real:.6g}" + (f"{p.imag:+.6g}j" if abs(p.imag) > 0 else "")
                                           for p in poles))
    tf_i = current_driven(lm, i_out).transfer_function(i_out, "motor_speed", minimal=True)
    out.append(f"current -> motor speed (ideal current loop) [rad/s per A]:\n{_tf_text(tf_i)}")
    tf_v = lm.transfer_function(v_in, "motor_speed", minimal=True)
    out.append(f"voltage -> motor speed [rad/s per V]:\n{_tf_text(tf_v)}")
    return "\n".join(out)


def _tf_text(tf) -> str:
    num = np.atleast_1d(np.squeeze(tf.num[0][0]))
    den = np.atleast_1d(np.squeeze(tf.den[0][0]))
    lead = den[0]
    return "  (" + _poly(num / lead) + ") / (" + _poly(den / lead) + ")"


def _poly(c) -> str:
    n = len(c) - 1
    text = ""
    for i, v in enumerate(c):
        pw = n - i
        s = "" if pw == 0 else ("s" if pw == 1 else f"s^{pw}")
        term = f"{abs(v):.6g}" + (f" {s}" if s else "")
        text += (("-" if v < 0 else "") + term) if i == 0 else ((" - " if v < 0 else " + ") + term)
    return text
