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
  loop too): ``(ln m / ln GM_min)^2 + (psi / sigma)^2 - 1 >= 0``;
* delay margin: ``(psi / (w tau_min))^2 + (ln m / sigma)^2 - 1 >= 0``: the
  phase-margin ellipse with the phase a delay ``tau_min`` costs at ``w``, so
  that every gain crossover keeps ``psi >= w tau_min``;
* bandwidth: ``sqrt(2) |L| / |1 + L| - 1 >= 0`` at every frequency below
  ``min_bandwidth_hz`` (the closed loop stays above -3 dB there);
* step overshoot and settling of the closed velocity loop (``L / (1 + L)``,
  unit step, the analysis' definitions): the step response is the inverse
  FFT of the closed loop on a uniform frequency grid (exact for the discrete
  loop up to time aliasing beyond ``fft_horizon``), its overshoot and its
  distance from the 2 % band after the settling time are constraints with
  analytic gradients (:class:`StepConstraints`, a numeric casadi callback).

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
from ..loops.design import Design
from ..loops.linear import linearize_conditions, plant_model
from ..loops.loop_analysis import AnalysisSettings, analyse_loops, build_loops, saturation_flags
from ..model.params import ParameterSet

__all__ = ["ROBUST_REQUIREMENTS", "RobustConstraints", "exact_margins", "MarginSummary"]

#: The velocity-loop requirements turned into frequency-response constraints (``[requirements.velocity_loop]`` keys).
ROBUST_REQUIREMENTS = ("min_phase_margin_deg", "min_gain_margin_db", "max_sensitivity_peak", "min_delay_margin_s",
                       "min_bandwidth_hz")
#: ... and into step-response constraints.
STEP_REQUIREMENTS = ("max_overshoot_percent", "max_settling_time_s")
#: Every velocity-loop requirement the tuner keeps as a constraint (``max_rise_time_s`` is judged by the check only).
TUNED_REQUIREMENTS = ROBUST_REQUIREMENTS + STEP_REQUIREMENTS
_SPEEDS = (0.5e-3, 1e-3, 2e-3, 5e-3, 10e-3, 15e-3)


def _settings(level, effects, temperatures, speeds=_SPEEDS, design: Design | None = None) -> AnalysisSettings:
    """The analysis grid at ``temperatures``: the design's ``[analysis]`` speeds and loads when given."""
    if design is not None:
        return AnalysisSettings.from_design(design, level=level, effects=tuple(effects),
                                            temperatures=tuple(float(t) for t in temperatures))
    return AnalysisSettings(level=level, effects=tuple(effects), temperatures=tuple(float(t) for t in temperatures),
                            nut_speeds=tuple(speeds))


@dataclass(frozen=True)
class _Block:
    temperature: float
    G: np.ndarray  # (n_points, n_freq) complex
    labels: tuple[str, ...]


class RobustConstraints:
    """Smooth requirement constraints of the velocity loop at every temperature of the robust set.

    Parameters
    ----------
    design : Design
        Current loop, control period and delay (the velocity gains are the variables); its
        ``[analysis]`` grid gives the speeds and loads (the grid ``thsa check`` judges).
    params : ParameterSet
    temperatures : sequence of float
        [degC].
    requirements : mapping
        Limits (keys of :data:`TUNED_REQUIREMENTS`); default the design's
        ``[requirements.velocity_loop]``.
    level, effects : the plant of the linearisation (default level B + the analysis' default effects:
        temperature_friction, standby_motor).
    rho : float
        Sharpness of the soft minimum.
    sigma : float
        Width of the crossover windows (log magnitude and phase [rad]).
    n_frequencies, f_min : the frequency grid (up to Nyquist).
    fft_horizon : float
        Period of the uniform frequency grid of the step constraints [s].
    grid_speeds : sequence of float or None
        Trim speeds [m/s] (None: the design's analysis grid).
    """

    def __init__(self, design: Design, params: ParameterSet, temperatures, requirements=None, *, level: str = "B",
                 effects=DEFAULT_ANALYSIS_EFFECTS, rho: float = 100.0, sigma: float = 0.15,
                 n_frequencies: int = 300, f_min: float = 0.5, fft_horizon: float = 0.4096, grid_speeds=None):
        req = dict(design.requirements.get("velocity_loop", {}) if requirements is None else requirements)
        self.requirements = {k: float(req[k]) for k in ROBUST_REQUIREMENTS if k in req}
        self.step_requirements = {k: float(req[k]) for k in STEP_REQUIREMENTS if k in req}
        if not self.requirements and not self.step_requirements:
            raise DesignError(design.source, "no [requirements.velocity_loop] the tuner can keep ("
                                             + ", ".join(TUNED_REQUIREMENTS) + ")")
        self.design, self.params = design, params
        self.temperatures = tuple(float(t) for t in temperatures)
        self.level, self.effects = level, tuple(effects)
        self.rho, self.sigma = rho, sigma
        h = design.control_period
        self.h = h
        self.omega = frequency_grid(h, f_min, n_frequencies)
        z = np.exp(1j * self.omega * h)
        self._kv_unit = (np.ones_like(z), h / (z - 1.0))  # d Kv / d kp, d Kv / d ki
        settings = _settings(level, effects, self.temperatures, speeds=grid_speeds or _SPEEDS,
                             design=None if grid_speeds else design)
        self.analysis_settings = settings
        model = plant_model(level, effects, params, settings=settings.linearization)
        lin = linearize_conditions(model, settings.grid())
        loops = build_loops(lin, design, settings)
        L = freq_response(loops.open["velocity_loop"], z)
        kv = design.velocity_kp * self._kv_unit[0] + design.velocity_ki * self._kv_unit[1]
        G = L / kv[None, :]
        valid = lin.valid & ~np.array([bool(r) for r in saturation_flags(lin, design, params)])
        self.blocks = []
        idx_all = []
        for T in self.temperatures:
            idx = [k for k, c in enumerate(lin.conditions) if c.temperature == T and valid[k]]
            idx_all.append(idx)
            self.blocks.append(_Block(T, G[idx], tuple(lin.conditions[k].label() for k in idx)))
        self.names = tuple(f"{key} at {T:g} degC" for T in self.temperatures for key in self.requirements)
        self.step = None
        if self.step_requirements:
            n_fft = int(round(fft_horizon / h))
            zu = np.exp(2j * np.pi * np.arange(n_fft // 2 + 1) / n_fft)
            flat = [k for idx in idx_all for k in idx]
            Lu = freq_response(loops.open["velocity_loop"], zu[1:])  # z = 1 excluded: the PI's integrator
            kvu = design.velocity_kp + design.velocity_ki * h / (zu[1:] - 1.0)
            Gu = np.zeros((len(flat), zu.size), complex)
            Gu[:, 1:] = (Lu / kvu[None, :])[flat]
            owner = np.concatenate([[j] * len(idx) for j, idx in enumerate(idx_all)]).astype(int) if flat else \
                np.zeros(0, int)
            self.step = StepConstraints(Gu, zu, h, n_fft, self.step_requirements, owner, self.temperatures,
                                        [lin.conditions[k].label() for k in flat], rho=rho,
                                        horizon=settings.step_horizons[1])
            self.names += self.step.names

    def limit(self, key: str):
        """The limit a constraint keeps now (None: not a constraint)."""
        if key in self.requirements:
            return self.requirements[key]
        return self.step.req.get(key) if self.step is not None else None

    def set_limit(self, key: str, value: float) -> None:
        """Tighten (or change) the limit of one constraint; the next :meth:`casadi_constraints` uses it."""
        if key in self.requirements:
            self.requirements[key] = float(value)
        elif self.step is not None and key in self.step.req:
            self.step.set_limit(key, value)
        else:
            raise KeyError(key)

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
        if "min_delay_margin_s" in self.requirements:
            wt = self._omega_rep(lib, re) * self.requirements["min_delay_margin_s"]
            out["min_delay_margin_s"] = (psi / wt) ** 2 + (lnm / self.sigma) ** 2 - 1.0
        if "min_bandwidth_hz" in self.requirements:
            below = self._omega_rep(lib, re) <= 2 * math.pi * self.requirements["min_bandwidth_hz"]
            t = math.sqrt(2.0) * lib.sqrt(re ** 2 + im ** 2) / lib.sqrt((1 + re) ** 2 + im ** 2) - 1.0
            out["min_bandwidth_hz"] = lib.where(below, t, 1.0)
        return out

    def _omega_rep(self, lib, like):
        """The frequency of every element of a (points x frequencies) response, in its layout."""
        if lib is _NpLib:
            return np.broadcast_to(self.omega[None, :], like.shape)
        n = like.size1() // self.omega.size
        return ca.DM(np.tile(self.omega, n))

    def values(self, kp: float, ki: float, *, soft: bool = True) -> np.ndarray:
        """Frequency-response constraint values in :attr:`names` order (soft minimum, or the exact minimum on
        the grid), then the step constraints."""
        out = []
        for b in self.blocks:
            u0, u1 = self._kv_unit
            kv = kp * u0 + ki * u1
            L = b.G * kv[None, :]
            terms = self._terms((L.real, L.imag), _NpLib)
            for key in self.requirements:
                c = np.asarray(terms[key]).ravel()
                if c.size == 0:
                    out.append(1.0)
                elif soft:
                    cmin = c.min()
                    out.append(cmin - np.log(np.sum(np.exp(-self.rho * (c - cmin)))) / self.rho)
                else:
                    out.append(c.min())
        if self.step is not None:
            out.extend(self.step.value_and_jacobian(kp, ki)[0])
        return np.array(out)

    def casadi_constraints(self, kp, ki):
        """Constraints as casadi expressions of ``kp``, ``ki`` (>= 0 feasible): the soft minima of the
        frequency-response terms, then the step constraints (a numeric callback with its Jacobian)."""
        out = []
        u0, u1 = self._kv_unit
        for b in self.blocks:
            n = b.G.shape[0]
            if n == 0:
                out.extend([ca.MX(1.0)] * len(self.requirements))
                continue
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
        if self.step is not None:
            self._step_cb = _StepCallback(self.step)
            out.append(self._step_cb(ca.vertcat(kp, ki)))
        return ca.vertcat(*out)


class StepConstraints:
    """Overshoot and settling of the closed velocity loop's unit step, with analytic gradients in (kp, ki).

    ``G`` (points x (n_fft/2 + 1)): the velocity loop's plant on the uniform grid
    ``z_k = exp(2 pi i k / n_fft)`` (column 0, ``z = 1``, unused: the PI integrator makes ``T(1) = 1``).
    The step response is ``cumsum(irfft(T))``; per point its worst sample, then a soft minimum over the
    points of each temperature.
    """

    def __init__(self, G, z, h, n_fft, requirements, owner, temperatures, labels, *, rho=100.0, horizon=0.3):
        self.G, self.h, self.n_fft = G, h, n_fft
        self.req = dict(requirements)
        self.owner, self.temperatures, self.labels = np.asarray(owner, int), tuple(temperatures), list(labels)
        self.rho = rho
        zz = z[1:]
        self.u0 = np.ones(z.size, complex)
        self.u1 = np.zeros(z.size, complex)
        self.u1[1:] = h / (zz - 1.0)
        self.K = min(int(round(horizon / h)) + 1, n_fft)
        self._last = None  # (kp, ki, limits) -> (values, Jacobian) of the last call
        self.set_limit(None, None)
        self.names = tuple(f"{key} at {T:g} degC" for T in self.temperatures for key in self.req)
        self.n_out = len(self.names)

    def set_limit(self, key, value) -> None:
        """Change one limit (``key`` None: only recompute the settling window)."""
        if key is not None:
            self.req[key] = float(value)
        t = np.arange(self.K) * self.h
        self.settle_mask = t >= self.req.get("max_settling_time_s", np.inf) - self.h

    def responses(self, kp, ki):
        """Step responses (points x K) and their derivatives in kp, ki."""
        kv = kp * self.u0 + ki * self.u1
        L = self.G * kv[None, :]
        T = np.empty_like(L)
        T[:, 1:] = L[:, 1:] / (1.0 + L[:, 1:])
        T[:, 0] = 1.0
        dTdL = np.zeros_like(L)
        dTdL[:, 1:] = 1.0 / (1.0 + L[:, 1:]) ** 2
        dTdG = dTdL * self.G
        # the running sum of the first K samples only: a cumulative sum is sequential, so these are the first K
        # values of the whole one
        K = self.K
        y = np.cumsum(np.fft.irfft(T, n=self.n_fft, axis=1)[:, :K], axis=1)
        dy = [np.cumsum(np.fft.irfft(dTdG * u[None, :], n=self.n_fft, axis=1)[:, :K], axis=1)
              for u in (self.u0, self.u1)]
        return y, dy

    def _soft(self, c, dc):
        """Soft minimum (and its gradient) of per-point values ``c`` with gradients ``dc`` (points x 2)."""
        if c.size == 0:
            return 1.0, np.zeros(2)
        cmin = c.min()
        w = np.exp(-self.rho * (c - cmin))
        return cmin - np.log(w.sum()) / self.rho, (w / w.sum()) @ dc

    def value_and_jacobian(self, kp, ki):
        """Constraint values (>= 0 feasible) in :attr:`names` order and their Jacobian (n_out x 2).

        The last call's result is kept: the solver asks for the values and for the Jacobian at the same gains
        through two casadi callbacks (:class:`_StepCallback`, :class:`_StepJac`)."""
        key = (float(kp).hex(), float(ki).hex(), tuple(sorted(self.req.items())))  # -0.0 is not 0.0 here
        if self._last is not None and self._last[0] == key:
            return self._last[1][0].copy(), self._last[1][1].copy()
        vals, jac = self._value_and_jacobian(kp, ki)
        self._last = (key, (vals, jac))
        return vals.copy(), jac.copy()

    def _value_and_jacobian(self, kp, ki):
        y, dy = self.responses(kp, ki)
        P = y.shape[0]
        vals, jac = [], []
        rows = np.arange(P)
        per_key = {}
        if "max_overshoot_percent" in self.req:
            lim = self.req["max_overshoot_percent"] / 100.0
            k = np.argmax(y, axis=1)
            c = 1.0 - (y[rows, k] - 1.0) / lim
            dc = -np.stack([d[rows, k] for d in dy], axis=1) / lim
            per_key["max_overshoot_percent"] = (c, dc)
        if "max_settling_time_s" in self.req:
            m = self.settle_mask
            if m.any():
                e = (y[:, m] - 1.0) / 0.02
                k = np.argmax(np.abs(e), axis=1)
                ek = e[rows, k]
                c = 1.0 - ek ** 2
                dc = -2 * ek[:, None] * np.stack([d[:, m][rows, k] for d in dy], axis=1) / 0.02
            else:  # the settling time asked is beyond the horizon: met whenever the response is stable
                c, dc = np.ones(P), np.zeros((P, 2))
            per_key["max_settling_time_s"] = (c, dc)
        for j, _ in enumerate(self.temperatures):
            sel = self.owner == j
            for key in self.req:
                c, dc = per_key[key]
                v, g = self._soft(c[sel], dc[sel])
                vals.append(v)
                jac.append(g)
        return np.array(vals), np.array(jac).reshape(len(vals), 2)


class _StepJac(ca.Callback):
    def __init__(self, step: StepConstraints):
        ca.Callback.__init__(self)
        self.step = step
        self.construct("step_jac", {})

    def get_n_in(self):
        return 2

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(2, 1) if i == 0 else ca.Sparsity.dense(self.step.n_out, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.step.n_out, 2)

    def eval(self, arg):
        x = np.asarray(arg[0], float).ravel()
        return [ca.DM(self.step.value_and_jacobian(x[0], x[1])[1])]


class _StepCallback(ca.Callback):
    """The step constraints as a casadi Function of ``(kp, ki)`` with their analytic Jacobian."""

    def __init__(self, step: StepConstraints):
        ca.Callback.__init__(self)
        self.step = step
        self._jac = None
        self.construct("step_constraints", {})

    def get_n_in(self):
        return 1

    def get_n_out(self):
        return 1

    def get_sparsity_in(self, i):
        return ca.Sparsity.dense(2, 1)

    def get_sparsity_out(self, i):
        return ca.Sparsity.dense(self.step.n_out, 1)

    def eval(self, arg):
        x = np.asarray(arg[0], float).ravel()
        return [ca.DM(self.step.value_and_jacobian(x[0], x[1])[0])]

    def has_jacobian(self, *args):
        return True

    def get_jacobian(self, name, inames, onames, opts):
        self._jac = _StepJac(self.step)
        x = ca.MX.sym(inames[0], 2)
        out = ca.MX.sym(inames[1], self.step.n_out)
        return ca.Function(name, [x, out], [self._jac(x, out)], inames, onames, opts)


class _NpLib:
    sqrt, log, exp, arctan2, where = np.sqrt, np.log, np.exp, np.arctan2, np.where


class _CaLib:
    sqrt, log, exp, arctan2 = ca.sqrt, ca.log, ca.exp, ca.atan2

    @staticmethod
    def where(mask, a, b):
        m = ca.DM(np.asarray(mask, float).ravel())
        return m * a + (1 - m) * b


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


# ------------------------------------------------------------------------------------------------ beyond the grid
#: Parameter spread of :func:`robustness_spread`: case -> (description, parameter factors, extra effects, extra delay).
#: Friction: every drag and loss of the drive scaled (viscous drags, the cold breakaway torque, the no-back disk
#: coefficients, the gear and screw losses 1 - eta).  Inertia: rotors, screw and ratchets.  Stiffness: the
#: drivetrain_compliance effect at the ends of the assumed ranges of gear.torsional_stiffness (3e4..3e5 N m/rad)
#: and screw.torsional_stiffness (2e4..8e4 N m/rad), as their sources state.
_FRICTION = ("motor.bearing_viscous_friction", "gear.viscous_friction", "friction.cold_coulomb_torque",
             "noback.mu_coulomb_pos", "noback.mu_coulomb_neg")
_LOSSES = ("gear.efficiency", "screw.efficiency_direct", "screw.efficiency_inverse")
_INERTIA = ("motor.rotor_inertia", "screw.inertia", "noback.ratchet_inertia")
SPREAD_CASES: dict[str, tuple[str, dict, tuple, int]] = {
    "model as is": ("the tuning plant", {}, (), 0),
    "friction -50 %": ("every drag and loss x0.5", {"friction": 0.5}, (), 0),
    "friction +50 %": ("every drag and loss x1.5", {"friction": 1.5}, (), 0),
    "inertia -20 %": ("rotors, screw, ratchets x0.8", {"inertia": 0.8}, (), 0),
    "inertia +20 %": ("rotors, screw, ratchets x1.2", {"inertia": 1.2}, (), 0),
    "soft drive train": ("drivetrain_compliance, gear 3e4, screw 2e4 N m/rad",
                         {"gear.torsional_stiffness": 3e4, "screw.torsional_stiffness": 2e4}, ("drivetrain_compliance",), 0),
    "stiff drive train": ("drivetrain_compliance, gear 3e5, screw 8e4 N m/rad",
                          {"gear.torsional_stiffness": 3e5, "screw.torsional_stiffness": 8e4}, ("drivetrain_compliance",), 0),
    "one more sample of delay": ("computation delay + 1 sample (margins only: the simulator's controller has 0 or 1)",
                                 {}, (), 1),
}


def spread_parameters(params: ParameterSet, changes: dict) -> ParameterSet:
    """``params`` with a case of :data:`SPREAD_CASES` applied."""
    vals = {}
    for key, v in changes.items():
        if key == "friction":
            vals.update({n: params.value(n) * v for n in _FRICTION})
            vals.update({n: 1.0 - (1.0 - params.value(n)) * v for n in _LOSSES})
        elif key == "inertia":
            vals.update({n: params.value(n) * v for n in _INERTIA})
        else:
            vals[key] = v
    return params.replace(vals)


@dataclass(frozen=True)
class SpreadRow:
    """One design under one case: worst velocity-loop margins over the grid and the cold-run ISE."""

    case: str
    design: str
    phase_margin_deg: float
    gain_margin_db: float
    delay_margin_s: float
    ms: float
    unstable_points: int
    cold_ise: float  # nan when not simulated


@dataclass(frozen=True)
class SpreadReport:
    rows: tuple[SpreadRow, ...]
    scenario: str
    temperature: float
    temperatures: tuple[float, ...]
    flagged: tuple[str, ...]
    notes: tuple[str, ...] = ()

    def text(self) -> str:
        lines = [f"robustness beyond the grid (worst over the grid at {', '.join(f'{t:g}' for t in self.temperatures)} "
                 f"degC; ISE of {self.scenario} at {self.temperature:g} degC):",
                 f"  {'case':26s} {'design':8s} {'PM deg':>7s} {'|GM| dB':>8s} {'DM ms':>7s} {'Ms':>6s} {'unst':>4s} "
                 f"{'cold ISE':>10s}"]
        for r in self.rows:
            lines.append(f"  {r.case:26s} {r.design:8s} {r.phase_margin_deg:7.1f} {r.gain_margin_db:8.1f} "
                         f"{1e3 * r.delay_margin_s:7.2f} {r.ms:6.3f} {r.unstable_points:4d} "
                         + (f"{r.cold_ise:10.4g}" if math.isfinite(r.cold_ise) else f"{'-':>10s}"))
        lines.append("  FLAG: " + "; ".join(self.flagged) if self.flagged else
                     "  the tuned design keeps its advantage in every case (no case where only the tuned design "
                     "misses a margin, cold ISE >= 10 % below the nominal's wherever simulated)")
        lines += ["  note: " + n for n in self.notes]
        return "\n".join(lines)

    def as_dict(self) -> dict:
        return {"scenario": self.scenario, "temperature_C": self.temperature,
                "margin_temperatures_C": list(self.temperatures), "flagged": list(self.flagged),
                "notes": list(self.notes),
                "cases": {k: v[0] for k, v in SPREAD_CASES.items()},
                "rows": [{"case": r.case, "design": r.design, "phase_margin_deg": round(r.phase_margin_deg, 3),
                          "gain_margin_db": round(r.gain_margin_db, 3), "delay_margin_s": float(f"{r.delay_margin_s:.6g}"),
                          "sensitivity_peak": round(r.ms, 4), "unstable_points": r.unstable_points,
                          "cold_ise": float(f"{r.cold_ise:.6g}") if math.isfinite(r.cold_ise) else -1.0}
                         for r in self.rows]}


def _worst_margins(design: Design, params, temps, level, effects, extra_delay: int):
    from ..loops.loop_analysis import margins_with_extra_delay

    m, v, unstable = margins_with_extra_delay(design, params, _settings(level, effects, temps, design=design),
                                              extra_delay=extra_delay)
    return (float(np.nanmin(m.phase_margin_deg[v])), float(np.nanmin(np.abs(m.gain_margin_db[v]))),
            float(np.nanmin(m.delay_margin_s[v])), float(np.nanmax(m.ms[v])), int(np.count_nonzero(unstable)))


def robustness_spread(nominal: Design, tuned: Design, params: ParameterSet, *, temperature: float = -30.0,
                      scenario: str = "cold_ramp", level: str = "B", effects=DEFAULT_ANALYSIS_EFFECTS,
                      temperatures=(-55.0, -30.0, 25.0, 70.0), cases=None) -> SpreadReport:
    """Nominal and tuned designs side by side under the parameter spread of :data:`SPREAD_CASES`.

    Flags the tuned design when, in some case, its cold-run ISE is not at least 10 % below the nominal's
    (its advantage vanished) or it has fewer margin than a requirement asks where the nominal has enough.
    """
    from ..model import build_plant
    from ..sim.simulate import SimulationSettings, Simulator
    from .validation import get_validation_scenario, run_metrics

    rows, flags, notes = [], [], []
    req = tuned.requirements.get("velocity_loop", {})
    for case in (cases or SPREAD_CASES):
        desc, changes, extra_eff, extra_delay = SPREAD_CASES[case]
        p = spread_parameters(params, changes)
        eff = tuple(effects) + tuple(e for e in extra_eff if e not in effects)
        by = {}
        for label, d in (("nominal", nominal), ("tuned", tuned)):
            pm, gm, dm, ms, unst = _worst_margins(d, p, temperatures, level, eff, extra_delay)
            ise = float("nan")
            if not extra_delay:
                sim = Simulator(build_plant(level, eff, params=p), SimulationSettings(output_period=None))
                ise = run_metrics(sim.run(get_validation_scenario(scenario).with_temperature(temperature), d, p)).ise
            by[label] = SpreadRow(case, label, pm, gm, dm, ms, unst, ise)
            rows.append(by[label])
        n, t = by["nominal"], by["tuned"]
        if math.isfinite(t.cold_ise) and not t.cold_ise <= 0.9 * n.cold_ise:
            flags.append(f"{case}: cold ISE {t.cold_ise:.4g} tuned vs {n.cold_ise:.4g} nominal (advantage vanished)")
        checks = (("min_phase_margin_deg", "phase_margin_deg", 1), ("min_gain_margin_db", "gain_margin_db", 1),
                  ("min_delay_margin_s", "delay_margin_s", 1), ("max_sensitivity_peak", "ms", -1))
        for key, attr, sgn in checks:
            if key in req:
                ok_t = sgn * (getattr(t, attr) - req[key]) >= 0 and t.unstable_points == 0
                ok_n = sgn * (getattr(n, attr) - req[key]) >= 0 and n.unstable_points == 0
                if ok_n and not ok_t:
                    flags.append(f"{case}: tuned velocity_loop.{key} {getattr(t, attr):.4g} misses {req[key]:g} "
                                 f"(nominal {getattr(n, attr):.4g} keeps it)")
                elif not ok_n and not ok_t:
                    notes.append(f"{case}: both designs miss velocity_loop.{key} = {req[key]:g} (tuned "
                                 f"{getattr(t, attr):.4g}, nominal {getattr(n, attr):.4g}; unstable points "
                                 f"{t.unstable_points} / {n.unstable_points})")
    return SpreadReport(tuple(rows), scenario, float(temperature), tuple(float(t) for t in temperatures), tuple(flags),
                        tuple(dict.fromkeys(notes)))
