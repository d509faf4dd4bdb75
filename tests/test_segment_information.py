"""Where a fit's values come from, segment by segment (thsa_control.fit.identify.segment_information): known linear
least-squares cases.

A multiple-shooting fit's Jacobian has the free parameters' columns over every row and each segment's start-state
columns over that segment's rows only.  For a linear problem of that shape the leave-one-segment-out estimate is
exact to compute, and with white noise the segment-clustered (sandwich) standard error is the information's.
"""

from __future__ import annotations

import numpy as np
import pytest

from thsa_control.fit.identify import segment_information

NC, L, M, NFS, NF = 2, 20, 60, 2, 2


def _problem(rng, structured: float = 0.0, prior: bool = False):
    """J (channel-major rows, nc x L x M; columns: NF parameters then NFS states per segment), y, the layout."""
    N = L * M
    J = np.zeros((NC * N, NF + M * NFS))
    J[:, :NF] = rng.normal(size=(NC * N, NF))
    for m in range(M):
        rows = (np.arange(NC)[:, None] * N + m * L + np.arange(L)[None, :]).ravel()
        J[np.ix_(rows, NF + m * NFS + np.arange(NFS))] = rng.normal(size=(rows.size, NFS))
    z_true = rng.normal(size=J.shape[1])
    y = J @ z_true + rng.normal(size=NC * N)
    if structured:  # an error shared by each segment's samples along the first parameter's column
        for m in range(M):
            rows = (np.arange(NC)[:, None] * N + m * L + np.arange(L)[None, :]).ravel()
            y[rows] += structured * rng.normal() * J[rows, 0]
    if prior:  # one prior row per parameter (regularising, weight 3)
        J = np.vstack([J, np.hstack([3.0 * np.eye(NF), np.zeros((NF, M * NFS))])])
        y = np.r_[y, 3.0 * z_true[:NF]]
    return J, y, [("run", NC, L, M, NFS)]


def _solve(J, y):
    z, *_ = np.linalg.lstsq(J, y, rcond=None)
    return z, J @ z - y  # r = J z - y: J is dr/dz, as in the fit


def _information_sd(J):
    return np.sqrt(np.diag(np.linalg.inv(J.T @ J))[:NF])


def test_the_first_order_influence_is_the_exact_leave_one_segment_out_change():
    """Each segment left out and the problem solved again without its rows and its start states: the parameters
    move by what ``influence`` says (in standard errors of the information), within 10 % for the segments that
    move them most (the first-order error is the segment's leverage, about 1/M)."""
    rng = np.random.default_rng(1)
    J, y, layout = _problem(rng, structured=0.5)
    z, r = _solve(J, y)
    shares, infl = segment_information(J, layout, NF, [NF], r)
    sd = _information_sd(J)
    N = L * M
    exact = np.zeros((M, NF))
    for m in range(M):
        rows = (np.arange(NC)[:, None] * N + m * L + np.arange(L)[None, :]).ravel()
        keep_r = np.setdiff1d(np.arange(J.shape[0]), rows)
        keep_c = np.setdiff1d(np.arange(J.shape[1]), NF + m * NFS + np.arange(NFS))
        zm, _ = _solve(J[np.ix_(keep_r, keep_c)], y[keep_r])
        exact[m] = (zm[:NF] - z[:NF]) / sd
    for k in range(NF):
        top = np.argsort(-np.abs(exact[:, k]))[:5]
        assert infl["run"][top, k] == pytest.approx(exact[top, k], rel=0.1), (k, infl["run"][top, k], exact[top, k])
    assert shares["run"].sum(axis=0) == pytest.approx(np.ones(NF))


def test_with_white_noise_the_segments_give_the_informations_standard_error():
    """Noise alone: the root sum of squares of the segments' influences (the clustered sandwich over the
    information's standard error) is about 1 for each parameter, over several seeds (0.75 .. 1.3 with 60
    segments); a shared error within each segment along a parameter's column makes it several times that."""
    for seed in range(2, 6):
        J, y, layout = _problem(np.random.default_rng(seed))
        _, r = _solve(J, y)
        _, infl = segment_information(J, layout, NF, [NF], r)
        ratio = np.sqrt((infl["run"] ** 2).sum(axis=0))
        assert np.all((ratio > 0.75) & (ratio < 1.3)), (seed, ratio)
    J, y, layout = _problem(np.random.default_rng(7), structured=1.0)
    _, r = _solve(J, y)
    _, infl = segment_information(J, layout, NF, [NF], r)
    ratio = np.sqrt((infl["run"] ** 2).sum(axis=0))
    assert ratio[0] > 2.5 and ratio[1] < 1.5, ratio


def test_the_priors_take_their_share_and_held_out_segments_none():
    """Prior rows after the runs' rows carry their part of the information (the shares sum below 1 by exactly
    that part); a segment whose rows weigh zero (held out) carries no share and no influence."""
    rng = np.random.default_rng(3)
    J, y, layout = _problem(rng, prior=True)
    N = L * M
    held = (np.arange(NC)[:, None] * N + 5 * L + np.arange(L)[None, :]).ravel()
    J[held] = 0.0
    y[held] = 0.0
    _, r = _solve(J, y)
    shares, infl = segment_information(J, layout, NF, [NF], r)
    A = J.T @ J  # the information on the parameters with every segment's states profiled out (Schur complement)
    total = np.diag(A[:NF, :NF] - A[:NF, NF:] @ np.linalg.pinv(A[NF:, NF:]) @ A[NF:, :NF])
    assert shares["run"].sum(axis=0) == pytest.approx(1.0 - 9.0 / total)
    assert not shares["run"][5].any() and not infl["run"][5].any()
    assert segment_information(J, layout, 0, [0], r) == ({}, {})
