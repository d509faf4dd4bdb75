"""Batched numerics of discrete SISO loops (private to :mod:`thsa_control.loops.analysis`).

State-space blocks stacked over N operating points (point index first):
series connection, closing a loop around a plant, zero-order-hold
discretisation, frequency responses on a grid and at per-point frequencies,
stability margins from arrays with crossings refined by vectorised bisection
on the exact response, step responses by batched time stepping, and the
``step_info`` metrics of python-control on arrays.  No Python loop over
operating points in the numerics.  Imports numpy and scipy only.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import NDArray

__all__ = ["MarginSet", "StepMetrics", "loop_margins", "step_metrics"]

_CHUNK = 400_000  # largest number of complex matrix entries per batched solve


# ----------------------------------------------------------------------------------------------------------------
# batched discrete state space
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _SS:
    """Batched discrete state space: A (N,n,n), B (N,n,m), C (N,p,n), D (N,p,m)."""

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    @property
    def n(self) -> int:
        return self.A.shape[1]

    def sub(self, outputs: Sequence[int], inputs: Sequence[int]) -> "_SS":
        o, i = list(outputs), list(inputs)
        return _SS(self.A, self.B[:, :, i], self.C[:, o, :], self.D[:, o][:, :, i])

    def take(self, idx) -> "_SS":
        return _SS(self.A[idx], self.B[idx], self.C[idx], self.D[idx])


def _const(N: int, A, B, C, D) -> _SS:
    """A controller with the same matrices at all N points."""
    mats = [np.broadcast_to(np.atleast_2d(np.asarray(M, float)), (N,) + np.atleast_2d(np.asarray(M, float)).shape)
            for M in (A, B, C, D)]
    return _SS(*(np.array(m) for m in mats))


def _pi(N: int, kp: float, ki_h: float) -> _SS:
    """Discrete PI ``kp + ki_h / (z - 1)`` (integrator state before its update)."""
    return _const(N, [[1.0]], [[1.0]], [[ki_h]], [[kp]])


def _gain_delay(N: int, k: float, delay: int) -> _SS:
    """``k z^-delay`` (delay 0 or 1)."""
    if delay == 0:
        return _SS(np.zeros((N, 0, 0)), np.zeros((N, 0, 1)), np.zeros((N, 1, 0)), np.full((N, 1, 1), k))
    return _const(N, [[0.0]], [[1.0]], [[k]], [[0.0]])


def _series(first: _SS, second: _SS) -> _SS:
    """``second(first(u))`` for SISO blocks."""
    N, n1, n2 = first.A.shape[0], first.n, second.n
    A = np.zeros((N, n1 + n2, n1 + n2))
    A[:, :n1, :n1] = first.A
    A[:, n1:, :n1] = second.B @ first.C
    A[:, n1:, n1:] = second.A
    B = np.concatenate([first.B, second.B @ first.D], axis=1)
    C = np.concatenate([second.D @ first.C, second.C], axis=2)
    return _SS(A, B, C, second.D @ first.D)


def _close(plant: _SS, ctrl: _SS, fb: int, u: int) -> _SS:
    """Close ``u = K (r - y_fb)`` around ``plant``; the reference replaces input ``u``.

    Inputs of the result: the plant's, with input ``u`` now the reference
    ``r``; outputs: the plant's.  Needs no feedthrough from ``u`` to ``y_fb``.
    """
    if np.any(np.abs(plant.D[:, fb, u]) > 0):
        raise ValueError("algebraic loop: the fed-back output has feedthrough from the control input")
    N, n, nk = plant.A.shape[0], plant.n, ctrl.n
    bu = plant.B[:, :, u]  # (N, n)
    cf = plant.C[:, fb, :]  # (N, n)
    Ak, Bk, Ck, Dk = ctrl.A, ctrl.B[:, :, 0], ctrl.C[:, 0, :], ctrl.D[:, 0, 0]
    A = np.zeros((N, n + nk, n + nk))
    A[:, :n, :n] = plant.A - Dk[:, None, None] * bu[:, :, None] * cf[:, None, :]
    A[:, :n, n:] = bu[:, :, None] * Ck[:, None, :]
    A[:, n:, :n] = -Bk[:, :, None] * cf[:, None, :]
    A[:, n:, n:] = Ak
    B = np.concatenate([plant.B, np.zeros((N, nk, plant.B.shape[2]))], axis=1)
    B[:, :n, u] = bu * Dk[:, None]
    B[:, n:, u] = Bk
    C = np.concatenate([plant.C, np.zeros((N, plant.C.shape[1], nk))], axis=2)
    return _SS(A, B, C, plant.D.copy())


def _zoh(A: np.ndarray, B: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    """Batched zero-order-hold discretisation (``ct.c2d(..., 'zoh')``)."""
    N, n, m = B.shape
    M = np.zeros((N, n + m, n + m))
    M[:, :n, :n] = A * h
    M[:, :n, n:] = B * h
    E = scipy.linalg.expm(M)
    return E[:, :n, :n], E[:, :n, n:]


def freq_response(sys: _SS, z: np.ndarray, idx: np.ndarray | None = None) -> np.ndarray:
    """SISO response ``C (zI - A)^-1 B + D`` of every point at ``z``.

    ``z`` of shape (W,) is used for every point (result (N, W)); with ``idx``
    (shape (K,)), ``z`` has shape (K,) and point ``idx[k]`` is evaluated at
    ``z[k]`` (result (K,)).
    """
    A, b, c, d = sys.A, sys.B[:, :, 0], sys.C[:, 0, :], sys.D[:, 0, 0]
    n = sys.n
    if idx is not None:
        if n == 0:
            return d[idx].astype(complex)
        M = z[:, None, None] * np.eye(n) - A[idx]
        sol = np.linalg.solve(M, b[idx][:, :, None].astype(complex))[..., 0]
        return np.einsum("kn,kn->k", c[idx], sol) + d[idx]
    N, W = A.shape[0], z.size
    out = np.empty((N, W), dtype=complex)
    if n == 0:
        out[:] = d[:, None]
        return out
    step = max(1, _CHUNK // max(1, N * n * n))
    eye = np.eye(n)
    for s in range(0, W, step):
        zs = z[s:s + step]
        M = zs[None, :, None, None] * eye - A[:, None]
        rhs = np.broadcast_to(b[:, None, :, None], M.shape[:-1] + (1,)).astype(complex)
        sol = np.linalg.solve(M, rhs)[..., 0]
        out[:, s:s + zs.size] = np.einsum("kn,kwn->kw", c, sol) + d[:, None]
    return out


class _Response:
    """Exact SISO responses of N systems at any ``z``, fast.

    Where the eigenvectors of ``A`` are well conditioned (``cond(V) <
    cond_max``) the response is the modal sum ``sum_i r_i / (z - p_i) + d``
    (one batched eigendecomposition, then O(n) per frequency; at most about
    ``eps cond(V)`` = 1e-7 relative round-off); elsewhere
    (near-defective ``A``) it falls back to a batched linear solve.
    """

    def __init__(self, sys: _SS, cond_max: float = 1e9):
        self.sys = sys
        N, n = sys.A.shape[0], sys.n
        self.d = sys.D[:, 0, 0].astype(complex)
        self.lam = np.zeros((N, n), complex)
        self.res = np.zeros((N, n), complex)
        self.ok = np.ones(N, bool)
        if n == 0:
            return
        with np.errstate(all="ignore"):
            lam, V = np.linalg.eig(sys.A)
            cond = np.linalg.cond(V)
        ok = np.isfinite(cond) & (cond < cond_max)
        if ok.any():
            Vi = np.linalg.inv(V[ok])
            cv = np.einsum("kn,knm->km", sys.C[ok][:, 0, :], V[ok])
            wb = np.einsum("kmn,kn->km", Vi, sys.B[ok][:, :, 0])
            self.res[ok] = cv * wb
        self.lam, self.ok = lam, ok

    def grid(self, z: np.ndarray) -> np.ndarray:
        """Response of every point at every ``z`` (W,): shape (N, W)."""
        ok = self.ok
        out = np.empty((self.sys.A.shape[0], z.size), complex)
        if ok.any():
            out[ok] = np.einsum("kwn->kw", self.res[ok][:, None, :] / (z[None, :, None] - self.lam[ok][:, None, :])) \
                + self.d[ok][:, None]
        if (~ok).any():
            out[~ok] = freq_response(self.sys.take(np.flatnonzero(~ok)), z)
        return out

    def at(self, idx: np.ndarray, z: np.ndarray) -> np.ndarray:
        """Point ``idx[k]`` at ``z[k]``: shape (K,)."""
        idx = np.asarray(idx)
        out = np.empty(idx.size, complex)
        ok = self.ok[idx]
        if ok.any():
            i = idx[ok]
            out[ok] = np.sum(self.res[i] / (z[ok][:, None] - self.lam[i]), axis=1) + self.d[i]
        if (~ok).any():
            out[~ok] = freq_response(self.sys, z[~ok], idx[~ok])
        return out


def _dcgain(sys: _SS, out: int, inp: int) -> np.ndarray:
    """``C (I - A)^-1 B + D`` of one channel (nan where A has an eigenvalue at 1)."""
    n = sys.n
    res = np.full(sys.A.shape[0], np.nan)
    M = np.eye(n) - sys.A
    ok = np.abs(np.linalg.det(M)) > 1e-300 if n else np.ones(sys.A.shape[0], bool)
    if n == 0:
        return sys.D[:, out, inp].copy()
    sol = np.linalg.solve(M[ok], sys.B[ok][:, :, inp][:, :, None])[..., 0]
    res[ok] = np.einsum("kn,kn->k", sys.C[ok][:, out, :], sol) + sys.D[ok][:, out, inp]
    return res


# ----------------------------------------------------------------------------------------------------------------
# margins from arrays
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MarginSet:
    """Stability margins of N discrete SISO loops (arrays of shape (N,)).

    Attributes
    ----------
    omega : numpy.ndarray, shape (W,)
        Frequency grid [rad/s] (last point: Nyquist).
    L : numpy.ndarray, shape (N, W)
        Loop frequency response.
    crossover_hz : gain crossover of the phase margin kept [Hz] (nan: none).
    phase_margin_deg : [deg] (inf: no gain crossover).
    gain_margin_db : [dB], signed: the phase crossing closest to 0 dB (inf: no phase crossover).
    phase_crossover_hz : [Hz] of that crossing (nan: none).
    gain_margin_lower_db : [dB], <= 0: how far the gain may fall before a phase crossing where
        ``|L| > 1`` reaches -1 (a conditionally stable loop); -inf: no such crossing.
    gain_margin_upper_db : [dB], >= 0: how far the gain may rise before a crossing where
        ``|L| < 1`` reaches -1; inf: no such crossing.
    delay_margin_s : [s] (inf: no gain crossover; 0 when a crossover has no phase margin).
    ms : sensitivity peak ``max |1 / (1 + L)|`` [-].
    ms_hz : frequency of the peak [Hz].
    bandwidth_hz : closed-loop ``|L / (1 + L)|`` -3 dB below its DC value [Hz] (inf: no drop).
    """

    omega: NDArray[np.float64]
    L: NDArray[np.complex128]
    crossover_hz: NDArray[np.float64]
    phase_margin_deg: NDArray[np.float64]
    gain_margin_db: NDArray[np.float64]
    phase_crossover_hz: NDArray[np.float64]
    delay_margin_s: NDArray[np.float64]
    ms: NDArray[np.float64]
    ms_hz: NDArray[np.float64]
    bandwidth_hz: NDArray[np.float64]
    gain_margin_lower_db: NDArray[np.float64]
    gain_margin_upper_db: NDArray[np.float64]


def _bisect(f, idx: np.ndarray, lo: np.ndarray, hi: np.ndarray, iters: int = 48) -> np.ndarray:
    """Vectorised bisection in log frequency of ``f(idx, w)`` (real), sign change assumed."""
    flo = f(idx, lo)
    a, b = np.log(lo), np.log(hi)
    for _ in range(iters):
        m = 0.5 * (a + b)
        fm = f(idx, np.exp(m))
        left = np.sign(fm) == np.sign(flo)
        a = np.where(left, m, a)
        flo = np.where(left, fm, flo)
        b = np.where(left, b, m)
    return np.exp(0.5 * (a + b))


def _margins(evaluate, omega: np.ndarray, L: np.ndarray, dc_T: np.ndarray) -> MarginSet:
    """Margins of N loops given their response ``L`` on ``omega`` and an exact evaluator."""
    N, W = L.shape
    two_pi = 2 * np.pi
    with np.errstate(divide="ignore", invalid="ignore"):
        logmag = np.log(np.abs(L))
    # --- gain crossovers
    sc = np.signbit(logmag[:, :-1]) != np.signbit(logmag[:, 1:])
    k_g, j_g = np.nonzero(sc & np.isfinite(logmag[:, :-1]) & np.isfinite(logmag[:, 1:]))
    if k_g.size:
        wg = _bisect(lambda i, w: np.log(np.abs(evaluate(i, w))), k_g, omega[j_g], omega[j_g + 1])
        Lg = evaluate(k_g, wg)
        pm = np.remainder(np.angle(Lg, deg=True), 360.0) - 180.0
        dm = np.where(pm > 0, np.deg2rad(pm), np.deg2rad(np.remainder(pm, 360.0))) / wg
        dm = np.where(pm == 0, 0.0, dm)
    else:
        wg = pm = dm = np.zeros(0)
    pm_out = np.full(N, np.inf)
    wc_out = np.full(N, np.nan)
    dm_out = np.full(N, np.inf)
    order = np.lexsort((np.abs(pm), k_g))  # per point, smallest |PM| first
    seen = np.zeros(N, bool)
    for q in order:
        k = k_g[q]
        dm_out[k] = min(dm_out[k], dm[q])
        if not seen[k]:
            seen[k] = True
            pm_out[k], wc_out[k] = pm[q], wg[q]
    # --- phase crossovers (negative real axis), Nyquist included
    im = L.imag[:, :-1]
    sp = (np.signbit(im[:, :-1]) != np.signbit(im[:, 1:])) & ((L.real[:, :-2] < 0) | (L.real[:, 1:-1] < 0))
    k_p, j_p = np.nonzero(sp)
    if k_p.size:
        wp = _bisect(lambda i, w: evaluate(i, w).imag, k_p, omega[j_p], omega[j_p + 1])
        Lp = evaluate(k_p, wp)
        keep = Lp.real < 0
        k_p, wp, Lp = k_p[keep], wp[keep], Lp[keep]
    else:
        wp, Lp = np.zeros(0), np.zeros(0, complex)
    nyq = L[:, -1].real < 0
    k_p = np.concatenate([k_p, np.flatnonzero(nyq)])
    wp = np.concatenate([wp, np.full(int(nyq.sum()), omega[-1])])
    Lp = np.concatenate([Lp, L[nyq, -1]])
    with np.errstate(divide="ignore"):
        gm_db = -20 * np.log10(np.abs(Lp))
    gm_out = np.full(N, np.inf)
    wpc_out = np.full(N, np.nan)
    for q in np.lexsort((np.abs(gm_db), k_p)):
        k = k_p[q]
        if not np.isfinite(wpc_out[k]):
            gm_out[k], wpc_out[k] = gm_db[q], wp[q]
    lower = np.full(N, -np.inf)
    upper = np.full(N, np.inf)
    neg = gm_db < 0
    np.maximum.at(lower, k_p[neg], gm_db[neg])
    np.minimum.at(upper, k_p[~neg], gm_db[~neg])
    # --- sensitivity peak, refined by golden-section search around the grid maximum
    with np.errstate(divide="ignore", invalid="ignore"):
        S = np.abs(1.0 / (1.0 + L))
    S = np.where(np.isfinite(S), S, np.inf)
    jm = np.argmax(S, axis=1)
    allk = np.arange(N)
    a = np.log(omega[np.maximum(jm - 1, 0)])
    b = np.log(omega[np.minimum(jm + 1, W - 1)])
    g = (math.sqrt(5) - 1) / 2

    def s_of(x):
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.abs(1.0 / (1.0 + evaluate(allk, np.exp(x))))

    c1, c2 = b - g * (b - a), a + g * (b - a)
    f1, f2 = s_of(c1), s_of(c2)
    for _ in range(40):
        left = f1 > f2
        b = np.where(left, c2, b)
        a = np.where(left, a, c1)
        c2n = np.where(left, c1, a + g * (b - a))
        c1n = np.where(left, b - g * (b - a), c2)
        c1, c2 = c1n, c2n
        f1 = s_of(c1)
        f2 = s_of(c2)
    ms_ref = np.maximum(f1, f2)
    ms = np.maximum(S[allk, jm], np.where(np.isfinite(ms_ref), ms_ref, 0))
    ms_w = np.where(ms_ref > S[allk, jm], np.exp(np.where(f1 > f2, c1, c2)), omega[jm])
    # --- closed-loop bandwidth
    with np.errstate(divide="ignore", invalid="ignore"):
        T = np.abs(L / (1.0 + L))
    dc = np.abs(dc_T)
    below = T < dc[:, None] / math.sqrt(2)
    first = np.where(below.any(axis=1), np.argmax(below, axis=1), -1)
    bw = np.full(N, np.inf)
    bw[~np.isfinite(dc)] = np.nan
    kb = np.flatnonzero((first > 0) & np.isfinite(dc))
    bw[(first == 0)] = np.nan
    if kb.size:
        def t_excess(i, w):
            Li = evaluate(i, w)
            return np.abs(Li / (1 + Li)) - dc[i] / math.sqrt(2)

        bw[kb] = _bisect(t_excess, kb, omega[first[kb] - 1], omega[first[kb]])
    return MarginSet(omega=omega, L=L, crossover_hz=wc_out / two_pi, phase_margin_deg=pm_out, gain_margin_db=gm_out,
                     phase_crossover_hz=wpc_out / two_pi, delay_margin_s=dm_out, ms=ms, ms_hz=ms_w / two_pi,
                     bandwidth_hz=bw / two_pi, gain_margin_lower_db=lower, gain_margin_upper_db=upper)


def frequency_grid(h: float, f_min: float, n: int) -> np.ndarray:
    w_nyq = math.pi / h
    w0 = 2 * math.pi * f_min
    if not w0 < w_nyq:
        raise ValueError(f"f_min = {f_min:g} Hz is not below the Nyquist frequency {w_nyq / (2 * math.pi):g} Hz")
    return np.geomspace(w0, w_nyq, n)


def loop_margins(A, B, C, D, dt: float, omega=None, *, n_frequencies: int = 500, f_min: float = 0.1) -> MarginSet:
    """Margins of discrete SISO loops given in state space, batched.

    Parameters
    ----------
    A, B, C, D : array_like
        Loop transfer function ``L(z)`` [-], shapes (n, n), (n, 1), (1, n),
        (1, 1), or stacked (N, ...) for N loops.
    dt : float
        Sampling period [s].
    omega : array_like, optional
        Frequency grid [rad/s], increasing, ending at or below Nyquist
        ``pi / dt``; default ``n_frequencies`` log-spaced points from
        ``f_min`` [Hz] to Nyquist.

    Returns
    -------
    MarginSet
        The closed-loop bandwidth is that of ``L / (1 + L)``.

    Examples
    --------
    A discrete integrator loop ``L = K h / (z - 1)`` crosses over where
    ``2 sin(w h / 2) = K h``:

    >>> import math
    >>> h, K = 1e-3, 100.0
    >>> m = loop_margins([[1.0]], [[1.0]], [[K * h]], [[0.0]], h)
    >>> wc = 2 / h * math.asin(K * h / 2)
    >>> bool(abs(m.crossover_hz[0] - wc / (2 * math.pi)) < 1e-9 * wc)
    True
    >>> round(float(m.phase_margin_deg[0]), 6) == round(90 - math.degrees(wc * h / 2), 6)
    True
    """
    A = np.asarray(A, float)
    sys = _SS(*(np.asarray(M, float)[None] if A.ndim == 2 else np.asarray(M, float) for M in (A, B, C, D)))
    omega = frequency_grid(dt, f_min, n_frequencies) if omega is None else np.asarray(omega, float)
    resp = _Response(sys)
    L = resp.grid(np.exp(1j * omega * dt))
    dc = _dcgain(_cl_from_loop(sys), 0, 0)
    return _margins(lambda i, w: resp.at(i, np.exp(1j * w * dt)), omega, L, dc)


def _cl_from_loop(L: _SS) -> _SS:
    """``L / (1 + L)`` in state space (unity negative feedback, SISO)."""
    if np.any(L.D):
        return _cl_feedthrough(L)
    return _close(L, _gain_delay(L.A.shape[0], 1.0, 0), 0, 0)


def _cl_feedthrough(L: _SS) -> _SS:
    d = L.D[:, 0, 0]
    k = 1.0 / (1.0 + d)
    b, c = L.B[:, :, 0], L.C[:, 0, :]
    A = L.A - (k[:, None, None] * b[:, :, None] * c[:, None, :])
    return _SS(A, (k[:, None] * b)[:, :, None], (k[:, None] * c)[:, None, :], (k * d)[:, None, None])


# ----------------------------------------------------------------------------------------------------------------
# step responses
# ----------------------------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class StepMetrics:
    """python-control ``step_info`` metrics of N responses (arrays (N,); inf: not settled, nan: undefined).

    Attributes
    ----------
    rise_time_s, settling_time_s, overshoot_percent, peak, peak_time_s, steady_state
    """

    rise_time_s: NDArray[np.float64]
    settling_time_s: NDArray[np.float64]
    overshoot_percent: NDArray[np.float64]
    peak: NDArray[np.float64]
    peak_time_s: NDArray[np.float64]
    steady_state: NDArray[np.float64]


def step_metrics(t, y, final) -> StepMetrics:
    """Step metrics of responses ``y`` (N, K) at times ``t`` (K,) with final values ``final`` (N,).

    Definitions of python-control's ``step_info``: rise 10 % -> 90 % of the
    final value, settling into +-2 % (``inf`` when the response is still
    outside at the last sample), overshoot above the final value [%].

    Examples
    --------
    >>> import numpy as np
    >>> t = np.linspace(0, 10, 10001)
    >>> m = step_metrics(t, (1 - np.exp(-t))[None, :], np.array([1.0]))
    >>> round(float(m.rise_time_s[0]), 2), round(float(m.settling_time_s[0]), 2)
    (2.2, 3.91)
    """
    t = np.asarray(t, float)
    y = np.atleast_2d(np.asarray(y, float))
    final = np.asarray(final, float).reshape(-1)
    N, K = y.shape
    ok = np.isfinite(final) & (final != 0) & np.all(np.isfinite(y), axis=1)
    sgn = np.sign(final)
    rise = np.full(N, np.nan)
    settle = np.full(N, np.nan)
    over = np.full(N, np.nan)
    peak = np.full(N, np.nan)
    tpeak = np.full(N, np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        lo = sgn[:, None] * (y - 0.1 * final[:, None]) >= 0
        hi = sgn[:, None] * (y - 0.9 * final[:, None]) >= 0
        has = ok & lo.any(axis=1) & hi.any(axis=1)
        rise[has] = t[np.argmax(hi[has], axis=1)] - t[np.argmax(lo[has], axis=1)]
        outside = np.abs(y / final[:, None] - 1) >= 0.02
    last = K - 1 - np.argmax(outside[:, ::-1], axis=1)
    any_out = outside.any(axis=1)
    settled_idx = np.where(any_out, last + 1, 0)
    settle[ok] = np.where(settled_idx[ok] < K, t[np.minimum(settled_idx[ok], K - 1)], np.inf)
    yos = np.max(sgn[:, None] * y, axis=1)
    dy = np.abs(yos) - np.abs(final)
    over[ok] = np.where(dy[ok] > 1e-9 * np.abs(final[ok]), np.abs(100 * dy[ok] / final[ok]), 0.0)
    ip = np.argmax(np.abs(y), axis=1)
    peak[ok] = np.abs(y[ok, ip[ok]])
    tpeak[ok] = t[ip[ok]]
    return StepMetrics(rise, settle, over, peak, tpeak, np.where(ok, final, np.nan))


def _step(sys: _SS, out: int, inp: int, h: float, horizon: float, decimation: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit-step responses of one channel, batched; samples every ``decimation`` periods."""
    N, n = sys.A.shape[0], sys.n
    K = int(round(horizon / (h * decimation))) + 1
    c, d = sys.C[:, out, :], sys.D[:, out, inp]
    Ad = np.repeat(np.eye(n)[None], N, axis=0)
    Bd = np.zeros((N, n))
    b = sys.B[:, :, inp]
    for _ in range(decimation):  # x_{k+m} = A^m x_k + sum_{j<m} A^j b
        Bd = Bd + np.einsum("kij,kj->ki", Ad, b)
        Ad = Ad @ sys.A
    y = np.empty((N, K))
    x = np.zeros((N, n))
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(K):
            y[:, k] = np.einsum("kn,kn->k", c, x) + d
            x = np.einsum("kij,kj->ki", Ad, x) + Bd
    y[~np.isfinite(y)] = np.nan
    return np.arange(K) * h * decimation, y


def _load_metrics(t: np.ndarray, y: np.ndarray, fraction: float) -> tuple[np.ndarray, np.ndarray]:
    """Signed peak of a load-step response and the time it stays within ``fraction`` of it afterwards."""
    N = y.shape[0]
    ip = np.nanargmax(np.where(np.isfinite(y), np.abs(y), -1), axis=1)
    peak = y[np.arange(N), ip]
    band = fraction * np.abs(peak)
    outside = np.abs(y) > band[:, None]
    last = y.shape[1] - 1 - np.argmax(outside[:, ::-1], axis=1)
    rec = np.where(last + 1 < y.shape[1], t[np.minimum(last + 1, y.shape[1] - 1)], np.inf)
    bad = ~np.all(np.isfinite(y), axis=1)
    peak[bad], rec[bad] = np.nan, np.nan
    return peak, rec
