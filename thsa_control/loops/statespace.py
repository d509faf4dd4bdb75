"""The cascade's loops at one operating point as python-control objects.

:func:`open_loop` and :func:`closed_loop` return a discrete
``control.StateSpace`` (sampling period: the design's control period) with
named inputs, outputs and states, for the current, velocity and position
loops.  They are the very systems the grid analysis
(:func:`thsa_control.loops.analysis.analyse_loops`) evaluates, built by the
same batched loop math (:mod:`.loopmath`) from the same linearisation
(:mod:`.linear`), taken at one point; so ``control.stability_margins`` of an
open loop gives the analysis' margins, and ``control.feedback(open_loop(...),
1)`` its closed loop.

Units are SI throughout: the condition's nut speed in m/s, load in N
(compressive positive), temperature in degC; signals in A, rad/s (motor
speed), m/s (nut speed), m (nut position), N, N m.  (The command line,
``thsa linearize --speed``, takes mm/s.)

Signals
-------
============== ============================== ===============================================
loop           open loop ``L`` (error -> y)    closed loop (inputs -> outputs)
============== ============================== ===============================================
current        current_error [A] ->            current_ref [A] -> motor_current [A]
               motor_current [A]               (the RL plant, speed held)
velocity       speed_error [rad/s] ->          speed_ref [rad/s], load_force [N],
               motor_speed [rad/s]             disturbance_torque [N m] -> motor_current,
                                               motor_speed, nut_speed
position       position_error [m] ->           position_ref [m], load_force, disturbance_torque
               nut_position [m]                -> motor_current, motor_speed, nut_speed,
                                               nut_position
============== ============================== ===============================================
"""

from __future__ import annotations

from collections.abc import Iterable

import control as ct
import numpy as np

from ..errors import DesignError
from ..model.params import ParameterSet, default_parameters
from .loopmath import _SS
from .design import Design, load_design, nominal_design_path
from .linear import DEFAULT_LEVEL, OperatingCondition, PlantModel, linearize_conditions, plant_model
from .loop_analysis import LOOPS, AnalysisSettings, build_loops, saturation_flags

__all__ = ["open_loop", "closed_loop", "loop_frequency_response"]

_ERROR = {"current_loop": ("current_error", "motor_current"), "velocity_loop": ("speed_error", "motor_speed"),
          "position_loop": ("position_error", "nut_position")}
_REF = {"current_loop": "current_ref", "velocity_loop": "speed_ref", "position_loop": "position_ref"}


def _loop_name(loop: str) -> str:
    name = loop if loop.endswith("_loop") else f"{loop}_loop"
    if name not in LOOPS:
        raise ValueError(f"unknown loop {loop!r}; loops are 'current', 'velocity', 'position'")
    return name


def _condition(condition) -> OperatingCondition:
    if isinstance(condition, OperatingCondition):
        return condition
    try:
        return OperatingCondition(*condition)
    except TypeError:
        raise ValueError(f"condition {condition!r}: give an OperatingCondition or (nut_speed [m/s], load [N], "
                         "temperature [degC])") from None


def _state_names(lin, design: Design) -> dict[str, list[str]]:
    """State names of the blocks composed by ``loop_analysis.build_loops`` (same order)."""
    plant = list(lin.batch.states)
    kc = ["current_pi"] + [f"computation_delay_{k + 1}" for k in range(design.computation_delay_samples)]
    kv, kx, full = ["velocity_pi"], ["position_delay"], plant + ["nut_position"]
    return {
        "open current_loop": kc + ["motor_current"],
        "open velocity_loop": kv + plant + kc,
        "open position_loop": kx + full + kc + kv,
        "closed current_loop": ["motor_current"] + kc,
        "closed velocity_loop": plant + kc + kv,
        "closed position_loop": full + kc + kv + kx,
    }


def _setup(loop, condition, design, params, level, effects, model):
    name = _loop_name(loop)
    cond = _condition(condition)
    params = params or default_parameters()
    design = design or load_design(nominal_design_path())
    design.check_against(params)
    if model is None:
        model = plant_model(level, effects, params)
    lin = linearize_conditions(model, [cond])
    why = lin.reasons[0] + saturation_flags(lin, design, params)[0]
    if not lin.valid[0] or why:
        raise DesignError("operating point", f"{cond.label()} has no linear loop: {'; '.join(why)}")
    loops = build_loops(lin, design, AnalysisSettings(level=model.level or DEFAULT_LEVEL, effects=model.effects))
    return name, cond, design, loops, _state_names(lin, design)


def _to_ct(sys: _SS, dt: float, inputs, outputs, states, name: str) -> ct.StateSpace:
    A, B, C, D = (np.array(M[0]) for M in (sys.A, sys.B, sys.C, sys.D))
    if len(states) != A.shape[0]:  # pragma: no cover - guards the bookkeeping above
        states = A.shape[0]
    return ct.ss(A, B, C, D, dt, inputs=list(inputs), outputs=list(outputs), states=states, name=name)


def open_loop(loop: str, condition, design: Design | None = None, params: ParameterSet | None = None, *,
              level: str | None = DEFAULT_LEVEL, effects: Iterable[str] | None = None,
              model: PlantModel | None = None) -> ct.StateSpace:
    """Open loop ``L(z)`` of one loop of the cascade at an operating point (discrete, SI units).

    ``L`` is the controller in series with what it controls (the inner loops
    closed), from the loop's error to its measured output; the loop is
    closed by unity negative feedback, ``control.feedback(L, 1)``.

    Parameters
    ----------
    loop : {'current', 'velocity', 'position'}
        Also accepted with the ``_loop`` suffix.
    condition : OperatingCondition or (nut_speed, load_force, temperature)
        SI: nut speed [m/s] (``thsa linearize --speed`` takes mm/s), load [N,
        compressive positive], temperature [degC].
    design : Design, optional
        Gains, control period and computation delay; default ``designs/nominal.toml``.
    params : ParameterSet, optional
        Actuator; default the embedded one.
    level, effects : optional
        Model level and effects; default those of :func:`~thsa_control.loops.linear.plant_model`
        and the CLI (``DEFAULT_LEVEL``, ``DEFAULT_EFFECTS``).
    model : PlantModel, optional
        A wrapped plant to reuse (then ``level`` and ``effects`` are ignored).

    Returns
    -------
    control.StateSpace
        Discrete (``dt`` = the control period), SISO: input ``current_error`` [A],
        ``speed_error`` [rad/s, motor] or ``position_error`` [m, nut]; output
        ``motor_current``, ``motor_speed`` or ``nut_position``; named states.

    Raises
    ------
    DesignError
        When the point has no linear loop (zero speed, backlash edge, saturated), with the reason.

    Examples
    --------
    >>> import control as ct
    >>> L = open_loop("velocity", OperatingCondition(10e-3, 20e3, 25.0))
    >>> L.dt, L.input_labels, L.output_labels
    (0.0001, ['speed_error'], ['motor_speed'])
    >>> gm, pm, sm, wpc, wgc, wms = ct.stability_margins(loop_frequency_response(L))  # no ss -> tf conversion
    >>> round(float(wgc) / (2 * 3.141592653589793), 1)  # crossover [Hz]; the design aimed at 30 Hz
    29.0
    """
    name, cond, design, loops, names = _setup(loop, condition, design, params, level, effects, model)
    inp, out = _ERROR[name]
    return _to_ct(loops.open[name], loops.h, [inp], [out], names[f"open {name}"], f"L_{name}")


def closed_loop(loop: str, condition, design: Design | None = None, params: ParameterSet | None = None, *,
                level: str | None = DEFAULT_LEVEL, effects: Iterable[str] | None = None,
                model: PlantModel | None = None) -> ct.StateSpace:
    """Closed loop of one loop of the cascade at an operating point (discrete, SI units).

    Parameters
    ----------
    loop, condition, design, params, level, effects, model
        As :func:`open_loop` (nut speed in m/s here; mm/s only on the command line).

    Returns
    -------
    control.StateSpace
        Discrete, named signals:

        * current: ``current_ref`` [A] -> ``motor_current`` [A] (the RL plant, speed held);
        * velocity: ``speed_ref`` [rad/s, motor], ``load_force`` [N], ``disturbance_torque``
          [N m at the motor shaft] -> ``motor_current`` [A], ``motor_speed`` [rad/s],
          ``nut_speed`` [m/s];
        * position: ``position_ref`` [m, nut], ``load_force``, ``disturbance_torque`` ->
          those and ``nut_position`` [m].

        The reference-to-measured-output channel equals ``control.feedback(open_loop(...), 1)``.

    Examples
    --------
    >>> import control as ct
    >>> T = closed_loop("position", (10e-3, 20e3, 25.0))
    >>> T.input_labels
    ['position_ref', 'load_force', 'disturbance_torque']
    >>> round(float(ct.dcgain(T[3, 0])), 6)  # nut position follows its reference
    1.0
    """
    name, cond, design, loops, names = _setup(loop, condition, design, params, level, effects, model)
    sys, _ = loops.closed[name]
    if name == "current_loop":
        inputs, outputs = ["current_ref"], ["motor_current"]
    else:
        inputs = [_REF[name], "load_force", "disturbance_torque"]
        outputs = ["motor_current", "motor_speed", "nut_speed"] + (["nut_position"] if sys.C.shape[1] == 4 else [])
    return _to_ct(sys, loops.h, inputs, outputs, names[f"closed {name}"], f"T_{name}")


def loop_frequency_response(sys: ct.StateSpace, omega=None, *, points: int = 4000) -> ct.FrequencyResponseData:
    """Frequency response of a discrete loop from its state space, for margins and Bode plots without warnings.

    ``control.stability_margins(loop_frequency_response(L))`` gives the
    margins of :func:`open_loop` (equal to the grid analysis') without the
    transfer-function conversion that makes scipy warn (see the module
    docstring); ``control.bode_plot(loop_frequency_response(L),
    display_margins=True)`` draws them.

    Parameters
    ----------
    sys : control.StateSpace
        A discrete system (:func:`open_loop`, :func:`closed_loop` or a channel of it).
    omega : array_like, optional
        Frequencies [rad/s] below Nyquist; default ``points`` log-spaced from 0.01 Hz to Nyquist.

    Returns
    -------
    control.FrequencyResponseData
        With the system's ``dt`` and signal names.

    Examples
    --------
    >>> import control as ct
    >>> L = open_loop("velocity", OperatingCondition(10e-3, 20e3, 25.0))
    >>> gm, pm, sm, wpc, wgc, wms = ct.stability_margins(loop_frequency_response(L))
    >>> round(float(wgc) / (2 * 3.141592653589793), 1)
    29.0
    """
    if not sys.isdtime(strict=True):
        raise ValueError("loop_frequency_response takes a discrete system (open_loop / closed_loop)")
    nyquist = np.pi / sys.dt
    if omega is None:
        omega = np.logspace(np.log10(2 * np.pi * 0.01), np.log10(nyquist), points)
    omega = np.asarray(omega, float)
    if np.any(omega <= 0) or np.any(omega > nyquist * (1 + 1e-12)):
        raise ValueError(f"omega must lie in (0, {nyquist:g}] rad/s (Nyquist of dt = {sys.dt:g} s)")
    return ct.frd(sys, omega, name=sys.name)
