"""Failure isolation of the navigator (issue 13): a failure in one batch row stays in that row.

A row whose filter update fails, or whose covariance stops being positive definite, is flagged
(``diverged`` with its reason) and parked; the other rows give exactly what they give in a batch without it.
"""
import copy

import numpy as np
import pytest

from envs.episodes import navigator_for
from envs.sim.world import generate_world
from nav_filters.error_model import BG, N_STATES
from nav_filters.navigator import (DIVERGENCE_REASONS, REASON_COVARIANCE, REASON_UPDATE, _row_is_pd,
                                   covariance_is_pd)


def _run(nav, w, epochs, poison=None):
    g, k = w.gnss, 0
    for j, kk in enumerate(w.epoch_idx[:epochs]):
        nav.propagate_epoch(w.imu.f_b[:, k + 1:kk + 1], w.imu.w_b[:, k + 1:kk + 1], 0.01)
        k = kk
        if poison is not None and j == 3:
            poison(nav)
        nav.update_gnss(g.sat_pos[:, j], g.sat_vel[:, j], g.pr[:, j], g.prr[:, j], g.pr_sigma[:, j],
                        g.prr_sigma[:, j], g.mask[:, j], sat_keys=None)
    return nav


def _set_inner_P(nav, row, P):
    form = nav.form
    while hasattr(form, "inner"):
        form = form.inner
    form.P = form.P.copy()
    form.P[row] = P


@pytest.mark.parametrize("method", ["kf", "sage-husa", "stkf", "ma-stkf"])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_a_row_whose_update_fails_is_flagged_and_the_others_are_untouched(method, dtype):
    """Row 1's covariance is made negative definite in the observed states: its innovation covariance is not
    positive definite, so the batched update raises; row 1 alone is flagged (reason: the update failed) and
    rows 0 and 2 end bit for bit where a run without the poison ends."""
    w = generate_world("seed000-sim", [0, 1, 2])
    clean = _run(navigator_for(w, method, dtype=dtype), w, 8)

    def poison(nav):
        nav.flush_prediction()
        _set_inner_P(nav, 1, -1e6 * np.eye(N_STATES))

    nav = _run(navigator_for(w, method, dtype=dtype), w, 8, poison)
    assert nav.diverged.tolist() == [False, True, False]
    assert nav.divergence_code.tolist() == [0, REASON_UPDATE, 0]
    assert nav.divergence_reasons()[1] == DIVERGENCE_REASONS[REASON_UPDATE]
    for name in ("r", "v", "C", "clk", "drift", "bg", "ba"):
        np.testing.assert_array_equal(getattr(nav, name)[[0, 2]], getattr(clean, name)[[0, 2]], err_msg=name)
    np.testing.assert_array_equal(nav.covariance[[0, 2]], clean.covariance[[0, 2]])
    assert covariance_is_pd(nav.covariance).all()  # the parked row holds a valid (unit) covariance


@pytest.mark.parametrize("method", ["kf", "stkf"])
def test_a_covariance_that_is_not_positive_definite_counts_as_divergence(method):
    """An indefinite block in states no measurement sees (gyro biases): every update succeeds, but the row's
    covariance is not positive definite any more; it is flagged with that reason, the others go on."""
    w = generate_world("seed000-sim", [0, 1, 2])
    clean = _run(navigator_for(w, method), w, 6)

    def poison(nav):
        nav.flush_prediction()
        P = np.asarray(nav.covariance[1], np.float64).copy()
        i, j = BG.start, BG.start + 1
        P[i, j] = P[j, i] = 3.0 * np.sqrt(P[i, i] * P[j, j])  # |correlation| > 1: indefinite, positive diagonal
        _set_inner_P(nav, 1, P)

    nav = _run(navigator_for(w, method), w, 6, poison)
    assert nav.diverged.tolist() == [False, True, False]
    assert nav.divergence_code[1] == REASON_COVARIANCE
    np.testing.assert_array_equal(nav.r[[0, 2]], clean.r[[0, 2]])


def test_compiled_pd_check_matches_numpy_cholesky():
    """_row_is_pd (compiled, in the feedback kernel) against covariance_is_pd (numpy): random SPD, indefinite,
    NaN, negative-diagonal, +inf-variance (unobserved) and nearly singular float32 matrices."""
    rng = np.random.default_rng(3)
    n = 6
    mats = []
    for _ in range(40):
        A = rng.normal(size=(n, n))
        mats.append(A @ A.T + 1e-3 * np.eye(n))
    for _ in range(20):
        A = rng.normal(size=(n, n))
        mats.append(0.5 * (A + A.T))  # indefinite (almost surely)
    bad = mats[0].copy()
    bad[2, 3] = bad[3, 2] = np.nan
    mats.append(bad)
    neg = mats[1].copy()
    neg[4, 4] = -1.0
    mats.append(neg)
    unobserved = mats[2].copy()
    unobserved[5, :] = unobserved[:, 5] = 0.0
    unobserved[5, 5] = np.inf
    mats.append(unobserved)
    v = rng.normal(size=n)
    mats.append((np.outer(v, v) - 1e-7 * np.eye(n)).astype(np.float32).astype(np.float64))  # rank one minus a bit
    P = np.array(mats)
    L, idx = np.empty((n, n)), np.empty(n, np.int64)
    compiled = np.array([_row_is_pd(P, b, L, idx) for b in range(len(P))])
    np.testing.assert_array_equal(compiled, covariance_is_pd(P))
    assert compiled[:40].all() and not compiled[40:60].any() and compiled.tolist()[-4:] == [False, False, True, False]


def test_feedback_flags_a_non_pd_covariance_like_its_reference():
    w = generate_world("open-sky", [0, 1, 2])
    nav = navigator_for(w, "kf")
    P = nav.form.P.copy()
    i, j = BG.start, BG.start + 2
    P[2, i, j] = P[2, j, i] = 2.0 * np.sqrt(P[2, i, i] * P[2, j, j])
    nav.form.P = P
    ref = copy.deepcopy(nav)
    dx = np.zeros((3, N_STATES))
    nav._feedback(dx)
    ref._feedback_reference(dx)
    assert nav.divergence_code.tolist() == ref.divergence_code.tolist() == [0, 0, REASON_COVARIANCE]


def test_time_since_update_restarts_on_rows_with_a_used_satellite_only():
    """``time_since_update`` [s] grows with every propagated sample and restarts at a GNSS update on the rows that
    used a satellite; a row in an outage (every channel masked) keeps counting."""
    w = generate_world("seed000-sim", [0, 1, 2])
    nav = _run(navigator_for(w, "kf"), w, 2)
    np.testing.assert_array_equal(nav.time_since_update, 0.0)
    g, a, b = w.gnss, w.epoch_idx[1], w.epoch_idx[2]
    nav.propagate_epoch(w.imu.f_b[:, a + 1:b + 1], w.imu.w_b[:, a + 1:b + 1], 0.01)
    np.testing.assert_allclose(nav.time_since_update, (b - a) * 0.01)
    mask = g.mask[:, 2].copy()
    mask[1] = False  # row 1: an outage
    assert mask[[0, 2]].any(1).all()
    nav.update_gnss(g.sat_pos[:, 2], g.sat_vel[:, 2], g.pr[:, 2], g.prr[:, 2], g.pr_sigma[:, 2], g.prr_sigma[:, 2],
                    mask)
    np.testing.assert_allclose(nav.time_since_update, [0.0, (b - a) * 0.01, 0.0])
