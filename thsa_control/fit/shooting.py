"""The multiple-shooting problem of one rig run, and the noise estimate that weights it.

Owns :class:`RunProblem` (the residuals and exact Jacobian of one run: the
plant's current-driven map, :func:`thsa_control.fit.replay.current_driven_map`,
as a casadi ``mapaccum`` over each segment, mapped over the segments, each
segment starting from its own free initial speed and position), the guesses of
the segments' initial states, :func:`estimate_noise` (the channel weights) and
the fitted channels :data:`MECH_CHANNELS`.  :class:`thsa_control.fit.identify.Identifier`
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
from .replay import COMPARED_OUTPUT, mech_inputs, replay_closed_loop, run_design, sample_periods
from .segment_states import drivetrain_segment_guess

if TYPE_CHECKING:
    from .identify import IdentificationSettings

__all__ = ["MECH_CHANNELS", "FREE_STATE_KINDS", "RunProblem", "estimate_noise"]

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
        L = max(2, int(round(settings.segment_duration / dt)))
        M = int(math.ceil(n / L))
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
        k_hold = settings.holdout_every
        seg_of = np.arange(L * M) // L
        self.holdout_samples = (seg_of % k_hold == k_hold - 1) if k_hold and M >= k_hold else np.zeros(L * M, bool)
        # channel-major residual rows: weight 0 on held-out samples in the parameter fit
        self.train_weight = np.tile((~self.holdout_samples).astype(float), len(self.channels))
        # states: which are free per segment, initial guesses
        states = plant.states
        tied = set(plant.quasi_static_states) if settings.quasi_static_starts else set()
        self.free_states = [i for i, s in enumerate(states) if s.kind in FREE_STATE_KINDS and s.name not in tied
                            and not (s.name == "nut_position" and "nut_position" not in run.source_columns)]
        self.x_guess = self._initial_states(params, L, M)
        self._track_custom_states(mech, params, V, H, L, M)
        # casadi: one segment = mapaccum of the map; all segments = map
        n_p = len(plant.parameters)
        y_idx = [plant.index("output", COMPARED_OUTPUT[c]) for c in self.channels]
        x = ca.SX.sym("x", len(states))
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
                quot[c] = settings.substeps if iv == "sample" else int(min(settings.substeps, max(
                    1, round(iv / (dt / settings.substeps)))))
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
        seg = step.mapaccum("segment", L)
        xs0 = ca.MX.sym("x0", len(states))
        Vs = ca.MX.sym("V", V.shape[0], L)
        ps = ca.MX.sym("p", n_p)
        Hs = ca.MX.sym("H", 1, L)
        if quot:
            _, Y0seg, Qseg = seg(xs0, Vs, ps, Hs)
            qrow = np.array([c in quot for c in self.channels])
            # reading at sample j of the segment: the quotient ending there (computed by step j - 1)
            shifted = ca.horzcat(Y0seg[:, 0], Qseg[:, :L - 1])
            sel = ca.DM(np.diag(qrow.astype(float)))
            Yseg = sel @ shifted + (ca.DM.eye(len(self.channels)) - sel) @ Y0seg
        else:
            _, Yseg = seg(xs0, Vs, ps, Hs)
        segY = ca.Function("segY", [xs0, Vs, ps, Hs], [Yseg])
        allY = segY.map("segments", "serial", M, [2], [])
        self.V, self.H = V, H
        self.n_p = n_p
        # decision variables: free parameters (scaled deltas) and free segment states
        self.free_idx = [plant.parameters.index(nm) for nm in free]
        d_theta = ca.MX.sym("dtheta", len(free))
        S = ca.MX.sym("S", len(self.free_states), M)
        self.p0 = plant.p_vector(params)
        self.scale = None  # set by the Identifier
        P = ca.MX.sym("pbase", n_p)
        scale = ca.MX.sym("scale", len(free))
        pv = P
        for k, j in enumerate(self.free_idx):
            pv = pv + ca.DM.eye(n_p)[:, j] * (d_theta[k] * scale[k])
        X0 = ca.MX(ca.DM(self.x_guess))
        rows = []
        k_free = 0
        pawl = {"pawl_clearance_comp", "pawl_clearance_tens"}
        for i in range(len(states)):
            if i in self.free_states:
                rows.append(S[k_free, :])
                k_free += 1
            elif states[i].name in pawl and M > 0:
                # the run starts with the ratchets where they stopped: the clearance of the first segment is a
                # parameter (noback.pawl_initial_clearance, a fraction of the pitch); later segments take it
                # from the model's map driven by the measured speed at the initial parameters (no gradient:
                # a pitch is profiled, thsa_control.fit.profile, each value with its own segment clearances)
                ip, ic = plant.parameters.index("noback.pawl_pitch"), plant.parameters.index("noback.pawl_initial_clearance")
                first = pv[ic] * pv[ip]
                rows.append(ca.horzcat(first, X0[i, 1:]) if M > 1 else first)
            else:
                rows.append(X0[i, :])
        X0full = ca.vertcat(*rows)
        if tied and M > 0:  # fast internal modes start quasi-static, from the free states and the measured load
            U0 = np.zeros((len(plant.inputs), M))
            starts = np.minimum(np.arange(M) * L, n - 1)
            U0[plant.index("input", "load_force")] = np.nan_to_num(np.asarray(run.signals["load_force"], float)[starts])
            X0full = plant.quasi_static.map(M)(X0full, ca.DM(U0), pv)
        Y = allY(X0full, ca.DM(V), pv, ca.DM(H).T)  # (ny, L*M)
        W = ca.DM(np.where(self.mask, 1.0, 0.0))
        Ymeas0 = ca.DM(np.nan_to_num(Ymeas))
        sig = ca.MX.sym("sigma", len(self.channels))
        r = (Ymeas0 - Y) * W / ca.repmat(sig, 1, L * M)
        r = ca.vec(r.T)  # channel-major: all samples of channel 0, then 1 ...
        dec = ca.vertcat(d_theta, ca.vec(S))
        self.n_dec_states = len(self.free_states) * M
        self.f_res = ca.Function("res", [dec, P, scale, sig], [r])
        self.f_jac = ca.Function("res_jac", [dec, P, scale, sig], [r, ca.jacobian(r, dec)])
        # the segment states alone (parameters held: the "before" fit and the held-out segments): casadi colours
        # the block-diagonal columns with one direction per free state instead of one more per parameter
        self.f_jac_states = ca.Function("res_jac_states", [dec, P, scale, sig], [r, ca.jacobian(r, ca.vec(S))])
        self._res = BufferedFunction(self.f_res)
        self._jac = BufferedFunction(self.f_jac)
        self._jac_states = BufferedFunction(self.f_jac_states)
        self.f_pred = ca.Function("pred", [dec, P, scale], [Y])
        # every state (at each sample's start) and every output of the same segment predictions, for the
        # segmented open-loop residual (thsa_control.fit.segmented); not differentiated
        step_all = ca.Function("step_all", [x, v, p, h], [xn, y])
        Xs, Ys = step_all.mapaccum("segment_all", L)(xs0, Vs, ps, Hs)
        seg_all = ca.Function("seg_all", [xs0, Vs, ps, Hs], [ca.horzcat(xs0, Xs[:, :L - 1]), Ys])
        Xall, Yall = seg_all.map("segments_all", "serial", M, [2], [])(X0full, ca.DM(V), pv, ca.DM(H).T)
        self.f_pred_all = ca.Function("pred_all", [dec, P, scale], [Xall, Yall])

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

    def residuals(self, dec, p0, scale, sigma) -> np.ndarray:
        """``f_res`` as a flat array (the channel-major residual rows)."""
        r = self._res(dec, p0, scale, sigma)[0]
        return r if isinstance(r, np.ndarray) else r.toarray().ravel(order="F")

    def jacobian(self, dec, p0, scale, sigma, states_only: bool = False):
        """Residual rows' exact Jacobian (scipy CSC) with respect to every decision variable, or to the segment
        states alone (``states_only``: the columns after the free parameters)."""
        return (self._jac_states if states_only else self._jac)(dec, p0, scale, sigma)[1]


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
