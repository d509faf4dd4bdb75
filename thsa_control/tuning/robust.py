"""Linear robustness of the velocity loop over temperature as smooth constraints on its gains.

The plant is linearised once per robust temperature over the analysis grid
(trim speed x load; ``loops/linear.py``, the same batch the loop analysis
uses) and the velocity loop's plant ``G(z)`` (current reference -> motor
speed, with the closed current loop inside; ``loops/analysis.py``) is taken
on a frequency grid.  The operating points do not depend on the velocity
gains, so for gains ``(kp, ki)`` the open loop is exactly
``L(z) = (kp + ki h / (z - 1)) G(z)`` and the constraints are cheap casadi
expressions of the gains.  With ``m = |L|`` and ``psi`` the angle of ``-L``
(the distance in phase from -180 deg), at every valid point and frequency:

* sensitivity peak: ``Ms_max |1 + L| - 1 >= 0``;
* phase margin: ``(psi / PM_min)^2 + (ln m / sigma)^2 - 1 >= 0``: outside an
  ellipse around the critical point in the (log magnitude, phase) plane,
  exactly the phase margin at a crossover ``m = 1``;
* gain margin (by magnitude, for the lower margin of a conditionally stable
  loop too): ``(ln m / ln GM_min)^2 + (psi / sigma)^2 - 1 >= 0``.

Each is aggregated per temperature with the Kreisselmeier-Steinhauser soft
minimum (``-1/rho log sum exp(-rho c)``, never above the true minimum, so
it is conservative), giving one smooth constraint per requirement and
temperature whose value says by how much it is met or missed.  The tuned
design is then checked exactly by :func:`exact_margins` (the loop analysis
with its bisection-refined margins).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from ..errors import DesignError
from ..loops.loopmath import freq_response, frequency_grid
from ..loops.analysis import DEFAULT_ANALYSIS_EFFECTS
from ..loops.loop_analysis import AnalysisSettings, build_loops, saturation_flags, analyse_loops
from ..loops.design import Design
from ..loops.linear import linearize_conditions, plant_model
from ..model.params import ParameterSet

__all__ = ["ROBUST_REQUIREMENTS", "RobustConstraints", "exact_margins", "MarginSummary"]

#: The velocity-loop requirements turned into constraints (``[requirements.velocity_loop]`` keys).
ROBUST_REQUIREMENTS = ("min_phase_margin_deg", "min_gain_margin_db", "max_sensitivity_peak")
_SPEEDS = (0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3, 15e-3)


def _settings(level, effects, temperatures, speeds=_SPEEDS) -> AnalysisSettings:
    return AnalysisSettings(level=level, effects=tuple(effects), temperatures=tuple(float(t) for t in temperatures),
                            nut_speeds=tuple(speeds))


@dataclass(frozen=True)
class _Block:
    temperature: float
    G: np.ndarray  # (n_points, n_freq) complex
    labels: tuple[str, ...]


class RobustConstraints:
    """Smooth margin constraints of the velocity loop at every temperature of the robust set.

    Parameters
    ----------
    design : Design
        Current loop, control period and delay (the velocity gains are the variables).
    params : ParameterSet
    temperatures : sequence of float
        [degC].
    requirements : mapping
        Limits (keys of :data:`ROBUST_REQUIREMENTS`); default the design's
        ``[requirements.velocity_loop]``.
    level, effects : the plant of the linearisation (default level B + the analysis' default effects:
        temperature_friction, standby_motor).
    rho : float
        Sharpness of the soft minimum.
    sigma : float
        Width of the crossover windows (log magnitude and phase [rad]).
    n_frequencies, f_min : the frequency grid (up to Nyquist).
    """

    def __init__(self, design: Design, params: ParameterSet, temperatures, requirements=None, *, level: str = "B",
                 effects=DEFAULT_ANALYSIS_EFFECTS, rho: float = 100.0, sigma: float = 0.15,
                 n_frequencies: int = 300, f_min: float = 0.5):
        req = dict(design.requirements.get("velocity_loop", {}) if requirements is None else requirements)
        self.requirements = {k: float(req[k]) for k in ROBUST_REQUIREMENTS if k in req}
        if not self.requirements:
            raise DesignError(design.source, "no [requirements.velocity_loop] margin to keep (min_phase_margin_deg, "
                                             "min_gain_margin_db or max_sensitivity_peak)")
        self.design, self.params = design, params
        self.temperatures = tuple(float(t) for t in temperatures)
        self.level, self.effects = level, tuple(effects)
        self.rho, self.sigma = rho, sigma
        h = design.control_period
        self.omega = frequency_grid(h, f_min, n_frequencies)
        z = np.exp(1j * self.omega * h)
        self._kv_unit = (np.ones_like(z), h / (z - 1.0))  # d Kv / d kp, d Kv / d ki
        settings = _settings(level, effects, self.temperatures)
        model = plant_model(level, effects, params, settings=settings.linearization)
        lin = linearize_conditions(model, settings.grid())
        loops = build_loops(lin, design, settings)
        L = freq_response(loops.open["velocity_loop"], z)
        kv = design.velocity_kp * self._kv_unit[0] + design.velocity_ki * self._kv_unit[1]
        G = L / kv[None, :]
        valid = lin.valid & ~np.array([bool(r) for r in saturation_flags(lin, design, params)])
        self.blocks = []
        for T in self.temperatures:
            idx = [k for k, c in enumerate(lin.conditions) if c.temperature == T and valid[k]]
            self.blocks.append(_Block(T, G[idx], tuple(lin.conditions[k].label() for k in idx)))
        self.names = tuple(f"{key} at {T:g} degC" for T in self.temperatures for key in self.requirements)

    def _terms(self, L, lib):
        """Constraint terms (>= 0 feasible) for loop responses split as (re, im)."""
        re, im = L
        out = {}
        if "max_sensitivity_peak" in self.requirements:
            out["max_sensitivity_peak"] = lib.sqrt((1 + re) ** 2 + im ** 2) * self.requirements["max_sensitivity_peak"] - 1.0
        lnm = 0.5 * lib.log(re ** 2 + im ** 2)
        psi = lib.arctan2(-im, -re)
        if "min_phase_margin_deg" in self.requirements:
            pm = math.radians(self.requirements["min_phase_margin_deg"])
            out["min_phase_margin_deg"] = (psi / pm) ** 2 + (lnm / self.sigma) ** 2 - 1.0
        if "min_gain_margin_db" in self.requirements:
            lg = self.requirements["min_gain_margin_db"] / 20.0 * math.log(10.0)
            out["min_gain_margin_db"] = (lnm / lg) ** 2 + (psi / self.sigma) ** 2 - 1.0
        return out

    def values(self, kp: float, ki: float, *, soft: bool = True) -> np.ndarray:
        """Constraint values in :attr:`names` order (soft minimum, or the exact minimum on the grid)."""
        out = []
        for b in self.blocks:
            u0, u1 = self._kv_unit
            kv = kp * u0 + ki * u1
            L = b.G * kv[None, :]
            terms = self._terms((L.real, L.imag), _NpLib)
            for key in self.requirements:
                c = terms[key].ravel()
                if soft:
                    cmin = c.min()
                    out.append(cmin - np.log(np.sum(np.exp(-self.rho * (c - cmin)))) / self.rho)
                else:
                    out.append(c.min())
        return np.array(out)

    def casadi_constraints(self, kp, ki):
        """Soft-minimum constraints as casadi expressions of ``kp``, ``ki`` (>= 0 feasible)."""
        out = []
        u0, u1 = self._kv_unit
        for b in self.blocks:
            n = b.G.shape[0]
            Gr = ca.DM(np.ascontiguousarray(b.G.real).ravel())
            Gi = ca.DM(np.ascontiguousarray(b.G.imag).ravel())
            a_re = ca.DM(np.tile(u0.real, n)) * kp + ca.DM(np.tile(u1.real, n)) * ki
            a_im = ca.DM(np.tile(u0.imag, n)) * kp + ca.DM(np.tile(u1.imag, n)) * ki
            re = a_re * Gr - a_im * Gi
            im = a_re * Gi + a_im * Gr
            terms = self._terms((re, im), _CaLib)
            for key in self.requirements:
                c = terms[key]
                cmin = ca.mmin(c)
                out.append(cmin - ca.log(ca.sum1(ca.exp(-self.rho * (c - cmin)))) / self.rho)
        return ca.vertcat(*out)


class _NpLib:
    sqrt, log, exp, arctan2 = np.sqrt, np.log, np.exp, np.arctan2


class _CaLib:
    sqrt, log, exp, arctan2 = ca.sqrt, ca.log, ca.exp, ca.atan2


@dataclass(frozen=True)
class MarginSummary:
    """Exact worst velocity-loop margins of a design at one level and temperature.

    ``phase_margin_deg``, ``gain_margin_db`` (smallest magnitude), ``ms`` (largest)
    over the valid points, with where; ``stable`` all valid points closed-loop
    stable; ``checked``/``skipped`` point counts; ``failures`` the requirement
    violations as text.
    """

    level: str
    temperature: float
    phase_margin_deg: float
    phase_margin_at: str
    gain_margin_db: float
    gain_margin_at: str
    ms: float
    ms_at: str
    stable: bool
    checked: int
    skipped: int
    failures: tuple[str, ...]

    @property
    def passed(self) -> bool:
        """Every requirement met and every valid point stable."""
        return self.stable and not self.failures


def exact_margins(design: Design, params: ParameterSet, temperatures, *, level: str = "B",
                  effects=DEFAULT_ANALYSIS_EFFECTS, requirements=None) -> list[MarginSummary]:
    """Velocity-loop margins from the loop analysis (bisection-refined), per temperature."""
    from ..loops.requirements import check_requirements

    req = dict(design.requirements.get("velocity_loop", {}) if requirements is None else requirements)
    req = {k: v for k, v in req.items() if k in ROBUST_REQUIREMENTS}
    settings = _settings(level, effects, temperatures)
    a = analyse_loops(design, params, settings=settings, steps=False)
    check = check_requirements(a, {"velocity_loop": req})
    vl = a.loops["velocity_loop"]
    out = []
    for T in settings.temperatures:
        at = np.array([c.temperature == T for c in a.conditions]) & a.valid
        idx = np.flatnonzero(at)
        pm, gm, ms = vl.margins.phase_margin_deg[idx], np.abs(vl.margins.gain_margin_db[idx]), vl.margins.ms[idx]

        def arg(vals, fn):
            if vals.size == 0 or np.all(np.isnan(vals)):
                return float("nan"), "-"
            k = int(fn(vals))
            return float(vals[k]), a.conditions[idx[k]].label()

        pmv, pma = arg(pm, np.nanargmin)
        gmv, gma = arg(gm, np.nanargmin)
        msv, msa = arg(ms, np.nanargmax)
        fails = tuple(f"{v.requirement} = {v.limit:g}: {v.value:.4g} at {v.condition.label()}"
                      for v in check.violations if v.condition.temperature == T)
        unstable = [c for (_, k, c) in check.unstable if c.temperature == T]
        fails += tuple(f"closed loop unstable at {c.label()}" for c in unstable)
        out.append(MarginSummary(level, T, pmv, pma, gmv, gma, msv, msa, not unstable, int(idx.size),
                                 int(np.count_nonzero([c.temperature == T for c in a.conditions])) - int(idx.size),
                                 fails))
    return out
