"""Describing-function limit cycles of the cascade (re-exported by :mod:`thsa_control.loops.analysis`).

Describing functions
--------------------
:func:`describing_functions` gives the limit cycles that python-control's
describing-function analysis predicts for the set-valued friction of the
model (tabulated from the plant's ``friction_torque`` around zero speed) in
the velocity and position loops, and for the load-path backlash in the
position loop (measured on the surface side of the play).
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace

import control as ct
import numpy as np

from .loopmath import freq_response
from .design import Design
from .linear import OperatingCondition, PlantLinearization, PlantModel, linearize_conditions, plant_model
from .loop_analysis import AnalysisSettings, build_loops
from ..model import EFFECTS
from ..model.laws import values_of
from ..model.params import ParameterSet, default_parameters

__all__ = ["LimitCycle", "predict_limit_cycles", "describing_functions"]


@dataclass(frozen=True)
class LimitCycle:
    """A limit cycle predicted (or not) by describing-function analysis.

    Attributes
    ----------
    loop : str
        ``'velocity_loop'`` or ``'position_loop'`` (closed around the linear part).
    nonlinearity : str
        ``'friction'`` (the model's set-valued friction around zero speed:
        no-back disks, cold Coulomb drag, efficiency channel) or
        ``'backlash'`` (load-path play ``2 b`` in the position feedback).
    condition : OperatingCondition
        Load and temperature (trim speed 0: reversal / trim stop).
    predicted : bool
        True when ``H(jw) N(a) = -1`` has a solution.
    signal : str
        What oscillates at the nonlinearity's input.
    amplitude : float
        Its amplitude [``amplitude_unit``] (nan if none predicted).
    amplitude_unit : str
    frequency_hz : float
        [Hz] (nan if none).
    note : str
    """

    loop: str
    nonlinearity: str
    condition: OperatingCondition
    predicted: bool
    signal: str
    amplitude: float
    amplitude_unit: str
    frequency_hz: float
    note: str = ""


def predict_limit_cycles(response, omega, nonlinearity, amplitudes) -> list[tuple[float, float]]:
    """Describing-function limit cycles of a loop ``H`` with a nonlinearity ``F`` in its feedback.

    Solves ``H(jw) N(a) = -1`` with ``ct.describing_function_response``
    (negative feedback ``u = -F(y)``), ``H`` given by its samples on
    ``omega`` (turned into a smoothed FRD, so that discrete loops are
    evaluated on the unit circle, not at ``z = jw``).  Intersections at the
    last frequency (Nyquist, where every sampled response is real) are
    dropped: they are an artefact of holding a continuous nonlinearity.

    Parameters
    ----------
    response : array_like of complex, shape (W,)
        ``H(e^{jwh})`` or ``H(jw)`` [output unit / input unit].
    omega : array_like, shape (W,)
        [rad/s], increasing.
    nonlinearity : callable or python-control DescribingFunctionNonlinearity
        ``F``.
    amplitudes : array_like
        Input amplitudes of ``F`` to scan [unit of ``y``].

    Returns
    -------
    list of (amplitude, frequency [rad/s])

    Examples
    --------
    python-control's textbook case, ``8 / (s^3 + 2 s^2 + 2 s + 1)`` with a
    unit saturation, oscillates at ``w = sqrt(2)``:

    >>> import numpy as np, control as ct
    >>> w = np.geomspace(0.01, 100, 300)
    >>> H = ct.tf([8], [1, 2, 2, 1])
    >>> [(round(a, 2), round(f, 3)) for a, f in predict_limit_cycles(
    ...     H(1j * w), w, ct.saturation_nonlinearity(1), np.linspace(1, 4, 10))]
    [(3.34, 1.414)]
    """
    omega = np.asarray(omega, float)
    frd = ct.frd(np.asarray(response, complex), omega, smooth=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # python-control's Nyquist and refinement warnings
        res = ct.describing_function_response(frd, nonlinearity, np.asarray(amplitudes, float), omega=omega,
                                              warn_nyquist=False)
    return [(float(a), float(w)) for a, w in (res.intersections or [])
            if a > 0 and 0 < w < omega[-1] * (1 - 1e-6)]


#: Points of python-control's describing-function quadrature (``ct.describing_function``'s ``num_points``).
_DF_POINTS = 100


class _TabulatedFriction(ct.DescribingFunctionNonlinearity):
    """The friction torque [N m] tabulated against the motor speed [rad/s], interpolated linearly.

    Its describing function is python-control's quadrature (``ct.describing_function``: the first harmonic of
    the torque over :data:`_DF_POINTS` points of one period of ``a sin``), with the table interpolated at the
    period's points in one call instead of one call per point: the same numbers, bit for bit.
    """

    def __init__(self, speed, torque):
        super().__init__()
        self.speed, self.torque = np.asarray(speed, float), np.asarray(torque, float)
        theta, self._dtheta = np.linspace(0, 2 * np.pi, _DF_POINTS, endpoint=False, retstep=True)
        self._sin, self._cos = np.sin(theta), np.cos(theta)

    def __call__(self, v):
        return float(np.interp(v, self.speed, self.torque))

    def _isstatic(self):
        return True

    def describing_function(self, a):
        if a <= 0:
            raise NotImplementedError  # python-control's own checks and value at zero
        scale = self._dtheta / np.pi / a
        f = np.interp(a * self._sin, self.speed, self.torque)
        return (f @ self._sin) * scale + 1j * ((f @ self._cos) * scale)


def _friction_map(model: PlantModel, lin: PlantLinearization, k: int, w_max: float):
    """Static friction torque [N m] vs motor speed [rad/s] at point k, from the plant (one mapped call)."""
    b = lin.batch
    pos = np.geomspace(1e-9, w_max, 400)
    w = np.concatenate([-pos[::-1], [0.0], pos])
    X = np.repeat(b.X[:, k:k + 1], w.size, axis=1)
    names = model.named.states
    X[names.index("motor_speed")] = w
    values = values_of(model.params)
    for e in model.effects:  # each effect's states at a reversal (both pawls engaged: each direction meets
        hint = EFFECTS[e].linear.at_reversal  # its loaded disk)
        for s, v in (hint(values) if hint is not None else {}).items():
            X[names.index(s)] = v
    _, Y = model.named.evaluate_many(X, b.U[:, k:k + 1], b.P[:, k:k + 1])
    tf = Y[model.named.outputs.index("friction_torque")]
    return w, tf


def describing_functions(design: Design, params: ParameterSet | None = None, *,
                         settings: AnalysisSettings | None = None, temperatures: Sequence[float] | None = None,
                         loads: Sequence[float] | None = None, model: PlantModel | None = None,
                         n_frequencies: int = 300) -> tuple[LimitCycle, ...]:
    """Limit cycles predicted by describing functions (python-control) at trim stop / reversal.

    The linear part is the plant linearised at zero speed, where the
    continuous model's set-valued friction contributes nothing, so the
    linear model is exactly the smooth part (inertia, viscous drag,
    electrics) and the whole friction goes into the nonlinearity.  Three
    loops per condition:

    * velocity loop with friction: ``H`` = disturbance torque -> motor speed
      with the velocity loop closed, ``F`` = the friction torque of the plant
      vs motor speed (tabulated from ``friction_torque``; describing function
      by ``ct.describing_function``);
    * position loop with friction: the same with the position loop closed;
    * position loop with backlash: ``H`` = the open position loop, ``F`` =
      ``ct.friction_backlash_nonlinearity(2 * loadpath.backlash)`` on the
      fed-back position (as if it were measured on the surface side).

    ``H`` is the discrete loop's response on a grid up to Nyquist, handed to
    ``ct.describing_function_response`` as an FRD.

    Parameters
    ----------
    design : Design
    params : ParameterSet, optional
    settings : AnalysisSettings, optional
        Level and effects; default temperatures.
    temperatures : sequence of float, optional
        [degC]; default ``settings.temperatures``.
    loads : sequence of float, optional
        [N]; default 0 and the largest grid load.
    model : PlantModel, optional
    n_frequencies : int
        Frequency points of ``H``.

    Returns
    -------
    tuple of LimitCycle
    """
    settings = settings or AnalysisSettings()
    params = params or default_parameters()
    model = model or plant_model(settings.level, settings.effects, params, settings=settings.linearization)
    temps = tuple(settings.temperatures if temperatures is None else temperatures)
    if loads is None:
        loads = (0.0, float(max(abs(f) for f in settings.load_forces)))
    conds = [OperatingCondition(0.0, float(f), float(t)) for t in temps for f in loads]
    lin = linearize_conditions(model, conds)  # invalid (zero speed) by design: see the docstring
    dsettings = replace(settings, n_frequencies=int(n_frequencies))
    loops = build_loops(lin, design, dsettings)
    omega, h = loops.omega, loops.h
    z = np.exp(1j * omega * h)
    cl_v, _ = loops.closed["velocity_loop"]
    cl_x, _ = loops.closed["position_loop"]
    H = {
        ("velocity_loop", "friction"): freq_response(cl_v.sub([1], [2]), z),
        ("position_loop", "friction"): freq_response(cl_x.sub([1], [2]), z),
        ("position_loop", "backlash"): freq_response(loops.open["position_loop"], z),
    }
    backlash = params.value("loadpath.backlash")
    r = model.kinematic_ratio
    out = []
    for k, c in enumerate(conds):
        friction = _TabulatedFriction(*_friction_map(model, lin, k, 2e3))
        for (loop, kind), resp in H.items():
            if kind == "friction":
                amps = np.geomspace(1e-3, 1e3, 60)
                nl, signal, unit = friction, "motor speed", "rad/s"
            else:
                amps = 0.5 * (2 * backlash) * (1 + np.geomspace(1e-3, 1e2, 60))
                nl, signal, unit = ct.friction_backlash_nonlinearity(2 * backlash), "nut position", "m"
            hits = predict_limit_cycles(resp[k], omega, nl, amps)
            if hits:
                a, wf = max(hits, key=lambda p: p[0])
                extra = f"; {len(hits)} intersections, largest amplitude kept" if len(hits) > 1 else ""
                if unit == "rad/s":
                    note = f"nut speed amplitude {a * r * 1e3:.3g} mm/s{extra}"
                else:
                    note = f"position amplitude {a * 1e3:.3g} mm vs half play {backlash * 1e3:.3g} mm{extra}"
                out.append(LimitCycle(loop, kind, c, True, signal, a, unit, wf / (2 * np.pi), note))
            else:
                note = "no intersection of H(jw) with -1/N(a): no limit cycle predicted"
                ph0 = float(np.degrees(np.angle(resp[k][0])))
                if kind == "friction" and abs(ph0) > 170.0:
                    note += (f"; H approaches the negative real axis at the lowest frequency (phase {ph0:.0f} deg at "
                             f"{omega[0] / (2 * np.pi):.2g} Hz, integral action against friction): a slow stick-slip "
                             "hunting is not excluded, describing functions cannot resolve it")
                out.append(LimitCycle(loop, kind, c, False, signal, float("nan"), unit, float("nan"), note))
    return tuple(out)
