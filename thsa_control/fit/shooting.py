"""The multiple-shooting problem of one rig run, and the noise estimate that weights it.

Owns :class:`RunProblem` (the residuals and exact Jacobian of one run: the
plant's current-driven map, :func:`thsa_control.fit.replay.current_driven_map`,
as a casadi ``mapaccum`` over each segment, mapped over the segments, each
segment starting from its own free initial speed and position), the guesses of
the segments' initial states, :func:`estimate_noise` (the channel weights) and
the fitted channels :data:`MECH_CHANNELS`.

The residual of one segment and its Jacobians are casadi Functions of the
segment's own data (measured current, load, channels, masks, start-state
guess: inputs, not constants), so one C library, built through the
simulator's verified cache (:func:`thsa_control.sim.codegen.compile_functions`),
serves every run and every segment of one model structure; all segments are
one call of that Function mapped over them.  Without a working C compiler (or
with ``IdentificationSettings.compiled = False``) the same Functions run in
casadi's interpreter: the same operations, so the same numbers to rounding
(``tests/test_fit_compiled.py``; bit-identical in practice).  :class:`thsa_control.fit.identify.Identifier`
builds one per run and solves them together; :mod:`thsa_control.fit.segmented`
reuses its predictions.

Imports casadi and numpy; no matplotlib, no file parsing.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import TYPE_CHECKING

import casadi as ca
import numpy as np

from ..data.rigdata import RigRun, motor_speed_from
from ..data.rigformat import speed_sensor_intervals
from ..errors import RigDataError, ThsaError
from ..model.params import ParameterSet
from ..model.plant import Plant
from .replay import COMPARED_OUTPUT, STEP_COUNT_TOL, mech_inputs, replay_closed_loop, run_design, sample_periods
from .segment_states import drivetrain_segment_guess

if TYPE_CHECKING:
    from .identify import IdentificationSettings

__all__ = ["HOLDOUT_LAYOUTS", "MECH_CHANNELS", "FREE_STATE_KINDS", "RunProblem", "estimate_noise", "held_out_segments",
           "segment_layout"]

#: Channels the mechanics are fitted on (RigRun signals, compared with the plant
#: outputs of :data:`~thsa_control.fit.replay.COMPARED_OUTPUT`: the LVDT with the surface position).
MECH_CHANNELS = ("motor_speed", "nut_position", "screw_speed")
#: Kinds of plant states that are free decision variables at each segment start.
FREE_STATE_KINDS = ("speed", "velocity", "position")


def estimate_noise(y: np.ndarray) -> float:
    """Noise RMS of a sampled signal from its second differences (robust, MAD based).

    For white noise of RMS ``s`` on a smooth signal, ``diff(y, 2)`` has RMS
    ``s sqrt(6)``.  Returns a floor of ``1e-9 * max|y|`` (and 1e-12) for
    noise-free data.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> t = np.linspace(0, 1, 5001)
    >>> round(estimate_noise(np.sin(2 * np.pi * t) + 0.01 * rng.standard_normal(t.size)), 3)
    0.01
    """
    y = np.asarray(y, float)
    d = np.diff(y[np.isfinite(y)], 2)
    if d.size < 3:
        return 1.0
    mad = 1.4826 * float(np.median(np.abs(d - np.median(d))))
    floor = max(1e-9 * float(np.max(np.abs(y[np.isfinite(y)]))), 1e-12)
    return max(mad / math.sqrt(6.0), floor)



# ----------------------------------------------------------------------------- problem per run
def segment_layout(time: np.ndarray, settings: IdentificationSettings) -> tuple[int, int, np.ndarray]:
    """``(L, M, holdout)``: samples per segment, segments, and which of the ``L * M`` (padded) samples lie in a
    held-out segment (:func:`held_out_segments`: one in each block of ``holdout_every``) of a run sampled at
    ``time``: the one layout of the multiple-shooting fit, used by whoever must leave its held-out samples out."""
    t = np.asarray(time, float)
    n = t.size
    dt = float(np.median(np.diff(t)))
    L = max(2, int(round(settings.segment_duration / dt)))
    M = int(math.ceil(n / L))
    seg_of = np.arange(L * M) // L
    return L, M, held_out_segments(M, settings.holdout_every, settings.holdout_layout)[seg_of]


#: the seed of the dithered held-out segments' places (:func:`held_out_segments`): fixed, so a fit is repeatable
HOLDOUT_SEED = 20261129

#: how the held-out segments are placed in their blocks (:attr:`IdentificationSettings.holdout_layout`)
HOLDOUT_LAYOUTS = ("every_kth", "dithered")


def held_out_segments(M: int, every: int, layout: str = "every_kth") -> np.ndarray:
    """Which of ``M`` segments are held out of the parameter fit: one in each block of ``every`` consecutive
    segments (none when ``every`` is 0 or there are fewer segments than that; a last, incomplete block holds none).

    ``layout``: ``"every_kth"``, the block's last segment (every ``every``-th); ``"dithered"``, a place in the block
    drawn from a fixed seed (:data:`HOLDOUT_SEED`).  Every k-th hides the same phase of a test profile that repeats
    every multiple of ``every`` segments from the fit (measured: rig-sim's reversals under load repeat every 2.4 s,
    48 segments of 50 ms, and every third segment held out always hid the screw's breakaway after the reversal
    into the aiding quadrant: the drive-train damping fitted on the rest came out 0.42 N m s/rad, 1.73 dithered,
    rig-sim's 2); dithered, a phase is hidden in every repeat only by chance (``every**-repeats``)."""
    if layout not in HOLDOUT_LAYOUTS:
        raise ValueError(f"held-out segment layout {layout!r}: one of {', '.join(HOLDOUT_LAYOUTS)}")
    out = np.zeros(M, bool)
    if not every or M < every:
        return out
    blocks = M // every
    if layout == "every_kth":
        place = np.full(blocks, every - 1)
    else:
        place = np.random.default_rng(HOLDOUT_SEED).integers(0, every, size=blocks)
    out[np.arange(blocks) * every + place] = True
    return out


class RunProblem:
    """Residuals and Jacobian of one run: casadi map over segments of the current-driven map."""

    def __init__(self, run: RigRun, plant: Plant, mech: ca.Function, params: ParameterSet, free: Sequence[str],
                 settings: IdentificationSettings):
        self.run = run
        self.plant = plant
        t = np.asarray(run.time, float)
        self.time = t
        n = t.size
        channels = settings.channels or MECH_CHANNELS
        self.channels = tuple(c for c in channels if c in run.source_columns)
        if not self.channels:
            raise RigDataError(str(run.csv_path), [(None, None, f"no fitted channel measured; need one of {channels}")])
        dt = float(np.median(np.diff(t)))
        L, M, holdout = segment_layout(t, settings)
        self.L, self.M = L, M
        npad = L * M - n
        V = mech_inputs(run)
        H = sample_periods(run)
        V = np.hstack([V, np.repeat(V[:, -1:], npad, axis=1)])
        H = np.r_[H, np.repeat(H[-1], npad)]
        # measured data and noise weights
        Ymeas = np.vstack([np.asarray(run.signals[c], float) for c in self.channels])
        Ymeas = np.hstack([Ymeas, np.full((len(self.channels), npad), np.nan)])
        self.Ymeas = Ymeas
        noise = dict(settings.noise or {})
        self.sigma0 = np.array([float(noise[c]) if c in noise else estimate_noise(run.signals[c])
                                for c in self.channels])
        self.mask = np.isfinite(Ymeas)
        self.holdout_samples = holdout
        # channel-major residual rows: weight 0 on held-out samples in the parameter fit
        self.train_weight = np.tile((~self.holdout_samples).astype(float), len(self.channels))
        # states: which are free per segment, initial guesses
        states = plant.states
        tied = set(plant.quasi_static_states) if settings.quasi_static_starts else set()
        self.free_states = [i for i, s in enumerate(states) if s.kind in FREE_STATE_KINDS and s.name not in tied
                            and not (s.name == "nut_position" and "nut_position" not in run.source_columns)]
        self.x_guess = self._initial_states(params, L, M)
        self._track_custom_states(mech, params, V, H, L, M)
        # casadi: one segment = mapaccum of the map, a Function of the segment's own data (compiled to C once
        # per model structure, :class:`_SegmentFunctions`); all segments = that Function mapped over the segments
        n_p = len(plant.parameters)
        nx = len(states)
        nc = len(self.channels)
        y_idx = [plant.index("output", COMPARED_OUTPUT[c]) for c in self.channels]
        x = ca.SX.sym("x", nx)
        v = ca.SX.sym("v", V.shape[0])
        p = ca.SX.sym("p", n_p)
        h = ca.SX.sym("h")
        # speed sensors that read a difference quotient (the run's declaration): the reading at a sample is the
        # angle over the interval before it, computed in the previous sample period (the segment's first
        # sample keeps the instantaneous speed of its free start state)
        self.speed_sensors = speed_sensor_intervals(run, settings.speed_sensors)
        quot = {}
        for c in self.channels:
            iv = self.speed_sensors.get(c, {}).get("interval")
            if iv is not None:
                # plant steps the interval spans; a fraction of a step is read by interpolating the speed
                # (current_driven_map), not rounded to a whole step (1 ms at 500 Hz was read as 2 ms)
                m = (settings.substeps if iv == "sample"
                     else min(float(settings.substeps), iv / (dt / settings.substeps)))
                quot[c] = round(m) if abs(m - round(m)) < STEP_COUNT_TOL and round(m) >= 1 else m
        self.quotient_steps = quot
        if quot:
            from .replay import current_driven_map

            xn, y, q = current_driven_map(plant, settings.substeps, quot)(x, v, p, h)
            rows = []
            for c, i in zip(self.channels, y_idx):
                rows.append(q[list(quot).index(c)] if c in quot else y[i])
            step = ca.Function("step_sel", [x, v, p, h], [xn, y[y_idx], ca.vertcat(*rows)])
        else:
            xn, y = mech(x, v, p, h)
            step = ca.Function("step_sel", [x, v, p, h], [xn, y[y_idx]])
        self.V, self.H = V, H
        self.n_p = n_p
        # decision variables: free parameters (scaled deltas) and free segment states
        self.free_idx = [plant.parameters.index(nm) for nm in free]
        self.p0 = plant.p_vector(params)
        self.scale = None  # set by the Identifier
        self.n_dec_states = len(self.free_states) * M
        nf, nfs = len(free), len(self.free_states)
        # the segments' data, each segment a column block (the inputs of the mapped segment Functions)
        starts = np.minimum(np.arange(M) * L, n - 1)
        U0 = np.zeros((len(plant.inputs), M))
        if tied:  # fast internal modes start quasi-static, from the free states and the measured load
            U0[plant.index("input", "load_force")] = np.nan_to_num(np.asarray(run.signals["load_force"], float)[starts])
        first = np.zeros(M)
        first[:1] = 1.0
        self._seg_data = {"xg": np.array(self.x_guess, float), "first": first, "u0": U0, "V": V, "H": H[None, :],
                          "Y": np.nan_to_num(Ymeas), "W": np.where(self.mask, 1.0, 0.0)}
        seg = step.mapaccum("segment", L)
        step_all = ca.Function("step_all", [x, v, p, h], [xn, y])
        self._segment = _SegmentFunctions(plant, self.free_states, tied, seg, step_all.mapaccum("segment_all", L),
                                          quot, self.channels, L, nf, nx, V.shape[0])
        self._M, self._nc, self._nf, self._nfs = M, nc, nf, nfs
        self._compiled_request = bool(getattr(settings, "compiled", True))
        self._evaluators = None  # (res, jac, jac_states): made on first use (compiled, or the interpreter)
        self._layout = {}
        self.f_res = _AsCasadi(self, "res")
        self.f_jac = _AsCasadi(self, "jac")
        self.f_jac_states = _AsCasadi(self, "jac_states")
        self.f_pred = _Prediction(self, all_states=False)
        # every state (at each sample's start) and every output of the same segment predictions, for the
        # segmented open-loop residual (thsa_control.fit.segmented); not differentiated
        self.f_pred_all = _Prediction(self, all_states=True)

    # ------------------------------------------------------------------ evaluation of the segment Functions
    @property
    def compiled(self) -> bool:
        """True when the residual and its Jacobian are evaluated by the compiled library (else casadi's
        interpreter: no working C compiler, or ``IdentificationSettings.compiled = False``)."""
        return self._functions()[3]

    def _functions(self):
        if self._evaluators is None:
            fns, compiled = self._segment.evaluators(self._compiled_request)
            M = self._M
            mapped = [BufferedFunction(f.map(f"{f.name()}_segments", "serial", M, [4, 5, 6, 11], [])) for f in fns]
            self._evaluators = (*mapped, compiled)
        return self._evaluators

    def _directions(self, scale) -> np.ndarray:
        """``D`` (parameters x free parameters): the parameter vector is ``P + D dtheta``."""
        D = np.zeros((self.n_p, self._nf))
        scale = np.asarray(scale, float).ravel()
        for k, j in enumerate(self.free_idx):
            D[j, k] = scale[k]
        return D

    def _segment_args(self, dec, p0, scale, sigma=None):
        dec = np.asarray(dec, float).ravel()
        nf, d = self._nf, self._seg_data
        args = [dec[nf:], d["xg"], d["first"], d["u0"], np.asarray(p0, float), self._directions(scale), dec[:nf],
                d["V"], d["H"]]
        if sigma is not None:
            args += [d["Y"], d["W"], np.asarray(sigma, float)]
        return args

    def _jac_structure(self, states_only: bool):
        """Where each value of the mapped Jacobian blocks goes in the run's Jacobian (CSC): the blocks'
        buffer order (segment, column, row within the segment) mapped to the channel-major residual rows and
        the decision columns ``[dtheta; vec(S)]``, sorted once."""
        if states_only not in self._layout:
            nc, L, M, nf, nfs = self._nc, self.L, self._M, self._nf, self._nfs
            N = L * M
            q = np.arange(nc * L)
            row_q = (q % nc) * N + q // nc  # residual row of a segment row (channel-major over the run)
            rows, cols = [], []
            if not states_only:
                m, k = np.divmod(np.arange(M * nf), nf) if nf else (np.zeros(0, int), np.zeros(0, int))
                rows.append((row_q[None, :] + (m * L)[:, None]).ravel())
                cols.append(np.repeat(k, nc * L))
            m, j = np.divmod(np.arange(M * nfs), nfs) if nfs else (np.zeros(0, int), np.zeros(0, int))
            rows.append((row_q[None, :] + (m * L)[:, None]).ravel())
            cols.append(np.repeat((0 if states_only else nf) + m * nfs + j, nc * L))
            rows, cols = np.concatenate(rows), np.concatenate(cols)
            n_cols = (0 if states_only else nf) + M * nfs
            order = np.lexsort((rows, cols))
            indptr = np.r_[0, np.cumsum(np.bincount(cols, minlength=n_cols))].astype(np.int32)
            self._layout[states_only] = (order, rows[order].astype(np.int32), indptr, (nc * N, n_cols))
        return self._layout[states_only]

    def _evaluate(self, kind: str, dec, p0, scale, sigma):
        import scipy.sparse as sps

        f_res, f_jac, f_jst, _ = self._functions()
        args = self._segment_args(dec, p0, scale, sigma)
        if kind == "res":
            (R,) = f_res(*args)
            return R.ravel(order="C"), None
        out = (f_jst if kind == "jac_states" else f_jac)(*args)
        R = out[0]
        blocks = [b.ravel(order="F") for b in out[1:]]  # the dtheta block (full Jacobian), then the states block
        order, indices, indptr, shape = self._jac_structure(kind == "jac_states")
        data = np.concatenate(blocks)[order] if len(blocks) > 1 else blocks[0][order]
        return R.ravel(order="C"), sps.csc_matrix((data, indices, indptr), shape=shape)

    def _initial_states(self, params: ParameterSet, L: int, M: int) -> np.ndarray:
        """Segment initial states: measured where measured, else from a closed-loop replay or rest."""
        run, plant = self.run, self.plant
        starts = np.arange(M) * L
        n = self.time.size
        cl = None
        if run.controller is not None:
            try:
                cl = replay_closed_loop(run, plant, params, design=run_design(run))
            except ThsaError:
                cl = None
        X = np.zeros((len(plant.states), M))
        for m, k in enumerate(starts):
            k = min(k, n - 1)
            f0 = float(run.signals["load_force"][k])
            nut = self._measured_at("nut_position", k)
            x_rest = plant.initial_state(params, load_force=f0, nut_position=nut if nut is not None else 0.0)
            for i, s in enumerate(plant.states):
                if cl is not None and s.name in cl.simulated:
                    X[i, m] = cl.simulated[s.name][k]
                else:
                    X[i, m] = x_rest[i]
            w = motor_speed_from(lambda c: self._measured_at(c, k), run.gear_ratio)
            if w is not None:
                X[plant.index("state", "motor_speed"), m] = w
                if "surface_speed" in plant.state_names:  # the surface moves with the nut (the rest state has it still)
                    X[plant.index("state", "surface_speed"), m] = w * plant.kinematic_ratio(params)
            if nut is not None:  # the LVDT reads the surface; the nut sits the load-path deflection ahead
                i_nut = plant.index("state", "nut_position")
                if "surface_position" in plant.state_names:
                    i_srf = plant.index("state", "surface_position")
                    deflection = X[i_nut, m] - X[i_srf, m]
                    X[i_srf, m] = nut
                    X[i_nut, m] = nut + deflection
                else:
                    X[i_nut, m] = nut
        # a compliant drive train: rotors from the motor sensor, gear output from the screw sensor, twist quasi-static
        drivetrain_segment_guess(plant, params, run, starts, X, self._measured_at)
        return X

    def _track_custom_states(self, mech: ca.Function, params: ParameterSet, V: np.ndarray, H: np.ndarray, L: int,
                             M: int) -> None:
        """Custom states (pawl clearances) at the segment starts from the model's own map driven by the
        measured speeds at ``params`` (:func:`~thsa_control.fit.segment_states.custom_state_track`), so that
        they are consistent with the parameters being fitted; unchanged when the run measures no speed."""
        from .segment_states import custom_state_indices, custom_state_track, measured_state_matrix

        run, plant = self.run, self.plant
        idx = custom_state_indices(plant)
        Xm = measured_state_matrix(run, plant, params) if idx else None
        if Xm is None:
            return
        n = self.time.size
        Xm[idx, 0] = self.x_guess[idx, 0]
        track = custom_state_track(plant, mech, Xm, V[:, :n], H[:n], plant.p_vector(params))
        starts = np.minimum(np.arange(M) * L, n - 1)
        self.x_guess[idx, :] = track[:, starts]

    def _measured_at(self, name: str, k: int) -> float | None:
        if name not in self.run.source_columns:
            return None
        y = np.asarray(self.run.signals[name], float)
        window = y[max(0, k - 2):k + 3]
        window = window[np.isfinite(window)]
        return float(np.median(window)) if window.size else None

    def initial_decision(self) -> np.ndarray:
        return self.x_guess[self.free_states, :].ravel(order="F")

    def custom_starts(self) -> np.ndarray | None:
        """The custom states (pawl clearances) at every segment start (states x segments), None without any: not
        decision variables, they follow the model's map at the problem's initial parameters."""
        from .segment_states import custom_state_indices

        idx = custom_state_indices(self.plant)
        return np.array(self.x_guess[idx, :], float) if idx else None

    def use_custom_starts(self, starts) -> None:
        """Start the segments' custom states at ``starts`` (another problem's :meth:`custom_starts` over the same
        run and layout: a refit from that fit's optimum sees the same segments)."""
        from .segment_states import custom_state_indices

        idx = custom_state_indices(self.plant)
        given = np.asarray(starts, float)
        if not idx or given.shape != (len(idx), self.x_guess.shape[1]) or not np.all(np.isfinite(given)):
            raise ValueError(f"custom_states[{self.run.name!r}]: shape {given.shape}, the run's segment layout has "
                             f"{(len(idx), self.x_guess.shape[1])}{'' if np.all(np.isfinite(given)) else ' (not all finite)'}")
        self.x_guess[idx, :] = given
        self._seg_data["xg"] = np.array(self.x_guess, float)

    def residuals(self, dec, p0, scale, sigma) -> np.ndarray:
        """The channel-major residual rows (the measured channels minus the segment predictions, each divided by
        ``sigma`` of its channel; zero where a sample is not measured) as a flat array."""
        return self._evaluate("res", dec, p0, scale, sigma)[0]

    def jacobian(self, dec, p0, scale, sigma, states_only: bool = False):
        """Residual rows' exact Jacobian (scipy CSC) with respect to every decision variable, or to the segment
        states alone (``states_only``: the columns after the free parameters)."""
        return self._evaluate("jac_states" if states_only else "jac", dec, p0, scale, sigma)[1]


class _AsCasadi:
    """``f_res(dec, P, scale, sigma) -> r``, ``f_jac(...) -> (r, J)``, ``f_jac_states(...) -> (r, J_S)`` as casadi
    DMs: the problem's evaluation (compiled or interpreted, the same as :meth:`RunProblem.residuals` /
    :meth:`RunProblem.jacobian`) in the call form of a casadi Function."""

    def __init__(self, problem: "RunProblem", kind: str):
        self.problem, self.kind = problem, kind

    def __call__(self, dec, P, scale, sigma):
        r, J = self.problem._evaluate(self.kind, dec, P, scale, sigma)
        if J is None:
            return ca.DM(r)
        sp = ca.Sparsity(J.shape[0], J.shape[1], J.indptr.tolist(), J.indices.tolist())
        return ca.DM(r), ca.DM(sp, J.data)


class _Prediction:
    """``f_pred(dec, P, scale) -> Y`` (the fitted channels' predictions, channels x padded samples) and
    ``f_pred_all(dec, P, scale) -> (X, Y)`` (every state at each sample's start, every output) of the segments,
    evaluated by casadi's interpreter (a few calls per fit)."""

    def __init__(self, problem: "RunProblem", all_states: bool):
        self.problem, self.all_states = problem, all_states
        self._f = None

    def __call__(self, dec, P, scale):
        pb = self.problem
        if self._f is None:
            f = pb._segment.prediction(self.all_states)
            self._f = f.map(f"{f.name()}_segments", "serial", pb._M, [4, 5, 6], [])
        args = pb._segment_args(dec, P, scale)
        args[0] = args[0].reshape((pb._nfs, pb._M), order="F")
        args[2] = args[2][None, :]
        out = self._f(*args)
        return tuple(np.asarray(o) for o in out) if self.all_states else np.asarray(out)


#: Segment Functions compiled in this process, by the hash of their serialised form (a library is loaded once).
_COMPILED: dict[str, tuple] = {}


class _SegmentFunctions:
    """The casadi Functions of one segment, of the segment's own data: the same Functions serve every run and
    every segment of one model structure (plant, fitted channels, segment length, free states, number of free
    parameters), so one compiled library serves them all.

    Inputs (in this order): ``s`` the segment's free start states; ``xg`` the guess of every start state (the
    states not freed keep it); ``first`` 1 for a run's first segment (its pawl clearances come from the
    parameters); ``u0`` the plant inputs at the segment start (the quasi-static start of the fast modes);
    ``P`` the parameter vector; ``D`` the free parameters' directions (the parameters are ``P + D dtheta``);
    ``dtheta``; ``V`` (MECH_INPUTS x L) and ``H`` (1 x L) the measured current and load and the sample periods;
    ``Y`` and ``W`` (channels x L) the measured channels (0 where missing) and their masks; ``sigma`` the
    channels' weights.
    """

    def __init__(self, plant: Plant, free_states, tied, seg: ca.Function, seg_all: ca.Function, quot, channels,
                 L: int, nf: int, nx: int, nv: int):
        self.plant, self.seg, self.seg_all = plant, seg, seg_all
        n_p, nc = len(plant.parameters), len(channels)
        self.s = ca.MX.sym("s", len(free_states))
        self.xg = ca.MX.sym("xg", nx)
        self.first = ca.MX.sym("first")
        self.u0 = ca.MX.sym("u0", len(plant.inputs))
        self.P = ca.MX.sym("pbase", n_p)
        self.D = ca.MX.sym("D", n_p, nf)
        self.dth = ca.MX.sym("dtheta", nf)
        self.V = ca.MX.sym("V", nv, L)
        self.H = ca.MX.sym("H", 1, L)
        self.Y = ca.MX.sym("Y", nc, L)
        self.W = ca.MX.sym("W", nc, L)
        self.sig = ca.MX.sym("sigma", nc)
        self.pv = self.P + ca.mtimes(self.D, self.dth)
        # the segment's start state
        states = plant.states
        pawl = {"pawl_clearance_comp", "pawl_clearance_tens"}
        rows, k_free = [], 0
        for i in range(nx):
            if i in free_states:
                rows.append(self.s[k_free])
                k_free += 1
            elif states[i].name in pawl:
                # the run starts with the ratchets where they stopped: the clearance of the first segment is a
                # parameter (noback.pawl_initial_clearance, a fraction of the pitch); later segments take it
                # from the model's map driven by the measured speed at the initial parameters (no gradient:
                # a pitch is profiled, thsa_control.fit.profile, each value with its own segment clearances)
                ip = plant.parameters.index("noback.pawl_pitch")
                ic = plant.parameters.index("noback.pawl_initial_clearance")
                rows.append(ca.if_else(self.first, self.pv[ic] * self.pv[ip], self.xg[i]))
            else:
                rows.append(self.xg[i])
        x0 = ca.vertcat(*rows)
        if tied:
            x0 = plant.quasi_static(x0, self.u0, self.pv)
        self.x0 = x0
        if quot:
            _, Y0seg, Qseg = seg(x0, self.V, self.pv, self.H)
            qrow = np.array([c in quot for c in channels])
            # reading at sample j of the segment: the quotient ending there (computed by step j - 1)
            shifted = ca.horzcat(Y0seg[:, 0], Qseg[:, :L - 1])
            sel = ca.DM(np.diag(qrow.astype(float)))
            Yseg = sel @ shifted + (ca.DM.eye(nc) - sel) @ Y0seg
        else:
            _, Yseg = seg(x0, self.V, self.pv, self.H)
        self.Yseg = Yseg
        self.ins = [self.s, self.xg, self.first, self.u0, self.P, self.D, self.dth, self.V, self.H, self.Y, self.W,
                    self.sig]
        R = (self.Y - Yseg) * self.W / ca.repmat(self.sig, 1, L)
        r = ca.vec(R)  # sample-major inside the segment: the run's rows are put channel-major when assembled
        self.functions = [
            ca.Function("thsa_fit_res", self.ins, [R]),
            ca.Function("thsa_fit_jac", self.ins, [R, ca.densify(ca.jacobian(r, self.dth)),
                                                   ca.densify(ca.jacobian(r, self.s))]),
            # the segment states alone (parameters held: the "before" fit and the held-out segments)
            ca.Function("thsa_fit_jac_states", self.ins, [R, ca.densify(ca.jacobian(r, self.s))]),
        ]

    def evaluators(self, compiled: bool):
        """``((res, jac, jac_states), compiled)``: the library's Functions, or the interpreted ones (no C
        compiler, a failed build, or ``compiled`` False)."""
        if not compiled:
            return self.functions, False
        import hashlib

        from ..sim.codegen import FLAGS, compile_functions

        key = hashlib.sha256("".join(f.serialize() for f in self.functions).encode()).hexdigest()
        if key not in _COMPILED:
            # -O1: the build takes a third of -O3's processor time (0.8 s against 2.3 s for level A) for a
            # Jacobian 1.4x slower; a fit evaluates a few dozen, and a trace builds one library per candidate
            fns, _info = compile_functions(self.functions, "thsa_fit", flags=("-O1",) + FLAGS[1:])
            _COMPILED[key] = (tuple(fns), True) if fns is not None else (tuple(self.functions), False)
        return _COMPILED[key]

    def prediction(self, all_states: bool) -> ca.Function:
        ins = self.ins[:9]
        if not all_states:
            return ca.Function("pred", ins, [self.Yseg])
        Xs, Ys = self.seg_all(self.x0, self.V, self.pv, self.H)
        return ca.Function("pred_all", ins, [ca.horzcat(self.x0, Xs[:, :-1]), Ys])


class BufferedFunction:
    """A casadi Function evaluated into numpy buffers (no conversion of its outputs through Python lists): a
    dense column comes back flat, a dense matrix as (rows, columns), a sparse output as a scipy CSC matrix of
    its structural non-zeros."""

    def __init__(self, f: ca.Function):
        import scipy.sparse as sps

        self._sps = sps
        self.f = f
        self.n_in = [f.nnz_in(i) for i in range(f.n_in())]
        self.sparse = []
        for i in range(f.n_out()):
            sp = f.sparsity_out(i)
            colind, row = sp.get_ccs()
            self.sparse.append((sp.size1(), sp.size2()) if sp.is_dense() else
                               (np.asarray(row, np.int32), np.asarray(colind, np.int32), (sp.size1(), sp.size2())))
        self.buf = None

    def __call__(self, *args):
        if self.buf is None:  # made on first use (a buffer does not survive pickling or fork)
            self.buf = self.f.buffer()
        fb, call = self.buf
        keep = []
        for i, (a, n) in enumerate(zip(args, self.n_in)):
            a = np.ascontiguousarray(np.asarray(a, float).ravel(order="F"))
            if a.size != n:
                raise ValueError(f"{self.f.name()}: input {i} has {a.size} values, expected {n}")
            keep.append(a)
            fb.set_arg(i, memoryview(a))
        outs = [np.empty(self.f.nnz_out(i)) for i in range(self.f.n_out())]
        for i, o in enumerate(outs):
            fb.set_res(i, memoryview(o))
        call()
        res = []
        for o, sp in zip(outs, self.sparse):
            if len(sp) == 2:  # dense: a column vector flat, a matrix (rows, columns)
                res.append(o if sp[1] == 1 else o.reshape(sp, order="F"))
            else:
                row, colind, shape = sp
                res.append(self._sps.csc_matrix((o, row, colind), shape=shape))
        return res
