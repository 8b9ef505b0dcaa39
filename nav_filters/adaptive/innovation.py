"""Innovation statistics shared by the adaptive laws.

The laws compare what the innovations *are* with what the filter *predicts*
they should be. Two helpers:

:func:`innovation_traces`
    the traces, over the used rows of one epoch, of the pieces of the predicted
    innovation covariance ``S = H Phi P Phi^T H^T + H Q H^T + R`` and the
    innovation energy ``||dz||^2`` (all that the trace-based fading and
    measurement factors of seed paper 003 eqs 16 and 19-21 need);
:func:`measurement_groups`
    which rows of a tightly coupled epoch are pseudoranges and which are
    pseudorange rates (for the per-group measurement-noise scale of the
    Sage-Husa law);
:func:`geometry_residuals`, :func:`posterior_residuals`, :func:`deleted_residuals`
    per-satellite residuals for the per-satellite Sage-Husa samples;
:func:`fit_split`
    each type's innovation energy split into what a state error can explain
    and what it cannot (the strong-tracking laws' state-event test).
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from ..error_model import CLK, DRIFT, N_STATES
from ..kernels import (cholesky_inplace as _cholesky_inplace, cholesky_solve as _cholesky_solve,
                       row_kernel, row_nonzeros as _row_nonzeros, serial_and_parallel)

_CLK0, _DRIFT0 = CLK.start, DRIFT.start

GROUP_NAMES = ("pseudorange", "rate", "other")
"""Measurement groups of :func:`measurement_groups`, in id order."""


def quadratic_diag(H, X, fast: bool = False):
    """``diag(H X H^T)`` for batched ``H`` (B, m, n) and ``X`` (B, n, n): shape (B, m).

    ``fast`` (the fused path): compiled over the structural non-zeros of each H row
    (:func:`_quadratic_diag_kernel`; float64, same values to round-off)."""
    if fast:
        out = np.empty(np.shape(H)[:2])
        _quadratic_diag_kernel(np.ascontiguousarray(H, np.float64), np.ascontiguousarray(X, np.float64), out)
        return out
    return np.sum((H @ X) * H, axis=-1)


@nb.njit(cache=True)
def _quadratic_diag_kernel(H, X, out):
    """``out[b, i] = h^T X[b] h`` with ``h = H[b, i]``, over the non-zeros of h only (:func:`_quad_nz`)."""
    B, m, n = H.shape
    every = np.ones(m, np.bool_)
    nzc, nzv, cnt = _nonzeros_work(m, n, H.dtype)
    for b in range(B):
        _rows_nonzeros(H[b], every, nzc, nzv, cnt)
        for i in range(m):
            out[b, i] = _quad_nz(nzc, nzv, cnt, i, X, X, False, b)


@nb.njit(cache=True)
def _quad_nz(nzc, nzv, cnt, i, prior, Q, add_q, b):
    """``(H P- H^T)_ii`` of batch row b, ``P- = prior[b] (+ Q[b])``, from the non-zeros of row i of H (columns
    ``nzc[i]``, values ``nzv[i]``, count ``cnt[i]``; :func:`_rows_nonzeros`): the same sums, in the
    same order, as over all n columns with the zeros skipped. Indices, not row views: a view per call costs
    more than these few products."""
    q = 0.0
    for p in range(cnt[i]):
        k = nzc[i, p]
        hp = 0.0
        for t in range(cnt[i]):
            l = nzc[i, t]
            pm = prior[b, l, k] + Q[b, l, k] if add_q else prior[b, l, k]
            hp += nzv[i, t] * pm
        q += hp * nzv[i, p]
    return q



@dataclass(frozen=True)
class InnovationTraces:
    """Traces over the used rows of one epoch (all (B,) arrays, in the form's dtype).

    Attributes
    ----------
    energy : ``||dz||^2 = tr(dz dz^T)``.
    tr_m : ``tr(H Phi P Phi^T H^T)`` (seed 003 eq 21, the unfaded propagated covariance seen by H).
    tr_q : ``tr(H Q H^T)``.
    tr_r : ``tr(R)`` (the measurement variances handed to the update).
    n_used : number of used rows (int).
    """

    energy: np.ndarray
    tr_m: np.ndarray
    tr_q: np.ndarray
    tr_r: np.ndarray
    n_used: np.ndarray

    @property
    def tr_s(self) -> np.ndarray:
        """``tr(S)`` of the nominal predicted innovation covariance ``S = M + H Q H^T + R``."""
        return self.tr_m + self.tr_q + self.tr_r


def innovation_traces(dz, H, prior, Q, R, mask) -> InnovationTraces:
    """Innovation energy and the traces of the predicted innovation covariance (seed 003 eqs 12, 21).

    Compiled (:func:`_traces_rows`, structural zeros of H skipped); the parameters, returns and
    equations are documented on its numpy specification :func:`innovation_traces_reference` (agreement
    test in tests/nav_filters/test_compiled_update.py).
    """
    B = dz.shape[0]
    c = np.ascontiguousarray
    out = np.empty((4, B))
    kern, nchunk = row_kernel(_traces_serial, _traces_parallel, B)
    kern(c(dz), c(H), c(prior), c(prior if Q is None else Q), Q is not None, c(R), c(mask, bool), out, nchunk)
    dt = np.result_type(dz.dtype, H.dtype, prior.dtype)
    tr_m, tr_q, tr_r, energy = (a.astype(dt) for a in out)
    return InnovationTraces(energy=energy, tr_m=tr_m, tr_q=tr_q, tr_r=tr_r, n_used=mask.sum(-1))


def _traces_rows(dz, H, prior, Q, with_q, R, mask, out, nchunk):
    """Rows of ``out`` (4, B): tr(H prior H^T), tr(H Q H^T), tr(R), ||dz||^2 over the used rows."""
    B, m, n = H.shape
    for c in nb.prange(nchunk):  # rows in chunks (parallel in the parallel variant), scratch per chunk
        nzc = np.empty(n, np.int64)
        nzv = np.empty(n, H.dtype)
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            tm = 0.0
            tq = 0.0
            tr = 0.0
            en = 0.0
            for i in range(m):
                if not mask[b, i]:
                    continue
                cnt = _row_nonzeros(H[b, i], nzc, nzv)  # the sums below over these, in column order
                for p in range(cnt):
                    k = nzc[p]
                    sm = 0.0
                    sq = 0.0
                    for t in range(cnt):
                        h = nzv[t]
                        sm += h * prior[b, nzc[t], k]
                        if with_q:
                            sq += h * Q[b, nzc[t], k]
                    hk = nzv[p]
                    tm += sm * hk
                    tq += sq * hk
                tr += R[b, i, i]
                en += dz[b, i] * dz[b, i]
            out[0, b] = tm
            out[1, b] = tq
            out[2, b] = tr
            out[3, b] = en


_traces_serial, _traces_parallel = serial_and_parallel(_traces_rows)


def innovation_traces_reference(dz, H, prior, Q, R, mask) -> InnovationTraces:
    """Numpy specification of :func:`innovation_traces` (seed 003 eqs 12, 21).

    Parameters
    ----------
    dz : (B, m) innovations ``z - H x_pred`` (masked rows 0).
    H : (B, m, n) measurement matrix (masked rows 0).
    prior : (B, n, n) ``Phi P Phi^T``, the propagated covariance before process noise.
    Q : (B, n, n) process noise of the epoch, or None (no transition: ``tr(H Q H^T) = 0``).
    R : (B, m, m) measurement covariance (masked rows identity).
    mask : (B, m) bool used rows.

    Returns
    -------
    InnovationTraces
    """
    w = mask.astype(dz.dtype)
    tr_m = np.sum(quadratic_diag(H, prior) * w, -1)
    tr_q = np.zeros_like(tr_m) if Q is None else np.sum(quadratic_diag(H, Q) * w, -1)
    tr_r = np.sum(np.diagonal(R, axis1=1, axis2=2) * w, -1)
    energy = np.sum(dz * dz * w, -1)
    return InnovationTraces(energy=energy, tr_m=tr_m, tr_q=tr_q, tr_r=tr_r, n_used=mask.sum(-1))


def measurement_groups(H, mask) -> np.ndarray:
    """Group id of every measurement row of a tightly coupled epoch.

    A row whose ``H`` has a non-zero receiver-clock column (``CLK``) is a
    pseudorange (group 0), one with a non-zero clock-drift column (``DRIFT``) a
    pseudorange rate (group 1) (see :mod:`nav_filters.measurements`); any other
    row (e.g. a future ZUPT / non-holonomic row, or any row of a filter that is
    not the 17-state model) is group 2. Masked rows get -1.

    Parameters
    ----------
    H : (B, m, n); mask : (B, m) bool.

    Returns
    -------
    (B, m) int array of ids into :data:`GROUP_NAMES` (-1 on masked rows).
    """
    B, m, n = H.shape
    groups = np.full((B, m), 2, dtype=np.int64)
    if n == N_STATES:
        groups[H[:, :, DRIFT.start] != 0] = 1
        groups[H[:, :, CLK.start] != 0] = 0
    groups[~mask] = -1
    return groups


# ----------------------------------------------------------------------------- geometry residuals
@nb.njit(cache=True)
def _rows_nonzeros(H, rows, nzc, nzv, cnt):
    """The non-zeros of the rows of one batch row's ``H`` (m, n) flagged in ``rows`` (m,) bool
    (:func:`~nav_filters.kernels.row_nonzeros`): columns ``nzc`` (m, n), values ``nzv`` (m, n, H's dtype) and
    counts ``cnt`` (m,) (0 on the other rows)."""
    for i in range(H.shape[0]):
        cnt[i] = _row_nonzeros(H[i], nzc[i], nzv[i]) if rows[i] else 0


@nb.njit(cache=True)
def _nonzeros_work(m, n, dtype):
    """Scratch of :func:`_rows_nonzeros` for ``m`` rows of ``n`` columns: ``(nzc, nzv, cnt)``."""
    return np.empty((m, n), np.int64), np.empty((m, n), dtype), np.zeros(m, np.int64)


@nb.njit(cache=True)
def _geometry_work(n):
    """Scratch of :func:`_geometry_residual_row` (allocated once per kernel call, not per row):
    ``(cols, mark, A, rhs, beta, y)``."""
    return (np.empty(n, np.int64), np.zeros(n, np.bool_), np.empty((n, n)), np.empty(n), np.empty(n),
            np.empty(n))


@nb.njit(cache=True)
def _geometry_residual_row(dz, H, nzc, cnt, var, use, v_out, red_out, work):
    """Weighted least-squares residuals of one batch row's used measurements (see :func:`geometry_residuals`).

    ``dz`` (m,), ``H`` (m, n), ``nzc`` / ``cnt`` the non-zero columns of the used rows of H
    (:func:`_rows_nonzeros`), ``var`` (m,) > 0, ``use`` (m,) bool, ``work`` :func:`_geometry_work`; writes
    ``v_out`` and ``red_out`` on the used rows (0 where there is no redundancy: no more used rows than fitted
    columns, or a singular geometry).
    """
    m, n = H.shape
    cols, mark, Aw, rhs_w, beta_w, y = work
    # the fitted columns: those where some used row of H is non-zero, in increasing order
    for i in range(m):
        if use[i]:
            for t in range(cnt[i]):
                mark[nzc[i, t]] = True
    p = 0
    for k in range(n):
        if mark[k]:
            cols[p] = k
            p += 1
            mark[k] = False
    k_used = 0
    for i in range(m):
        if use[i]:
            k_used += 1
            v_out[i] = 0.0
            red_out[i] = 0.0
    if k_used <= p or p == 0:
        return
    A = Aw[:p, :p]
    rhs = rhs_w[:p]
    A[:, :] = 0.0
    rhs[:] = 0.0
    for i in range(m):
        if not use[i]:
            continue
        w = 1.0 / var[i]
        for a in range(p):
            ga = np.float64(H[i, cols[a]])
            rhs[a] += w * ga * np.float64(dz[i])
            for c in range(p):
                A[a, c] += w * ga * np.float64(H[i, cols[c]])
    # Cholesky A = L L^T in place (lower triangle); a singular geometry gives no residuals
    if not _cholesky_inplace(A, 1e-12):
        return
    beta = beta_w[:p]
    beta[:] = rhs
    _cholesky_solve(A, beta)
    for i in range(m):
        if not use[i]:
            continue
        fit = 0.0
        for a in range(p):
            fit += np.float64(H[i, cols[a]]) * beta[a]
        v_out[i] = np.float64(dz[i]) - fit
        for a in range(p):  # h_ii = w g^T A^-1 g = w |L^-1 g|^2
            s = np.float64(H[i, cols[a]])
            for q in range(a):
                s -= A[a, q] * y[q]
            y[a] = s / A[a, a]
        h = 0.0
        for a in range(p):
            h += y[a] * y[a]
        red_out[i] = max(1.0 - h / var[i], 0.0)


@nb.njit(cache=True)
def _geometry_residuals_kernel(dz, H, var, types, n_types, v_out, red_out):
    B, m, n = H.shape
    use = np.zeros(m, np.bool_)
    typed = np.zeros(m, np.bool_)
    nzc, nzv, cnt = _nonzeros_work(m, n, H.dtype)
    work = _geometry_work(n)
    for b in range(B):
        for i in range(m):
            v_out[b, i] = 0.0
            red_out[b, i] = 0.0
            typed[i] = types[b, i] >= 0 and types[b, i] < n_types
        _rows_nonzeros(H[b], typed, nzc, nzv, cnt)
        for t in range(n_types):
            for i in range(m):
                use[i] = types[b, i] == t
            _geometry_residual_row(dz[b], H[b], nzc, cnt, var[b], use, v_out[b], red_out[b], work)


def geometry_residuals(dz, H, var, types, n_types: int = 2):
    """Snapshot least-squares residuals of each measurement type: what no common state error can explain.

    For each batch row and each type ``t`` (e.g. 0 pseudoranges, 1 pseudorange rates), the rows of that type
    are fitted by weighted least squares (weights ``1/var``) on the state columns their ``H`` rows touch
    (position and clock for pseudoranges, velocity and drift for rates), with no prior::

        beta = (G^T W G)^-1 G^T W dz,   v = dz - G beta,   h_ii = w_i g_i^T (G^T W G)^-1 g_i

    ``v`` is free of any error that a state correction explains (an INS drift, an overconfident P), so it
    measures the measurement errors alone; ``E[v_i^2] = (1 - h_ii) var_i`` when ``var`` are the true
    variances (the redundancy number ``1 - h_ii``, Baarda's reliability theory). This is the residual form of
    covariance matching (Mohamed & Schwarz 1999, cited as seed 000 ref [27]) taken on a snapshot fit.

    Parameters
    ----------
    dz : (B, m) innovations; H : (B, m, n); var : (B, m) variances (> 0 on typed rows);
    types : (B, m) int type of each row in ``[0, n_types)``, -1 for rows not fitted.

    Returns
    -------
    v : (B, m) residuals (0 on untyped rows and where a type has no redundancy);
    redundancy : (B, m) ``1 - h_ii`` in [0, 1] (0 where there is none: no more rows than fitted columns).

    Compiled (:func:`_geometry_residuals_kernel`); :func:`geometry_residuals_reference` is the numpy
    specification (agreement test).
    """
    c = np.ascontiguousarray
    B, m = np.shape(dz)
    v = np.empty((B, m))
    red = np.empty((B, m))
    _geometry_residuals_kernel(c(dz, np.float64), c(H, np.float64), c(var, np.float64), c(types, np.int64),
                               int(n_types), v, red)
    return v, red


def geometry_residuals_reference(dz, H, var, types, n_types: int = 2):
    """Numpy specification of :func:`geometry_residuals` (same parameters and returns)."""
    dz, H, var = (np.asarray(a, np.float64) for a in (dz, H, var))
    B, m, n = H.shape
    v, red = np.zeros((B, m)), np.zeros((B, m))
    for b in range(B):
        for t in range(n_types):
            rows = np.flatnonzero(types[b] == t)
            if rows.size == 0:
                continue
            G = H[b][rows]
            cols = np.flatnonzero((G != 0).any(0))
            G = G[:, cols]
            if rows.size <= cols.size or cols.size == 0:
                continue
            W = np.diag(1.0 / var[b, rows])
            A = G.T @ W @ G
            if np.linalg.matrix_rank(A) < cols.size:
                continue
            Ai = np.linalg.inv(A)
            v[b, rows] = dz[b, rows] - G @ (Ai @ G.T @ W @ dz[b, rows])
            red[b, rows] = np.maximum(1.0 - np.einsum("ij,jk,ik->i", G, Ai, G) / var[b, rows], 0.0)
    return v, red


@nb.njit(cache=True)
def _posterior_work(m, n):
    """Scratch of :func:`_posterior_residual_row` for ``P`` of ``n`` columns (allocated once per kernel call, not
    per row): ``(idx, S, HP, y, Linv)``, Linv with a spare row."""
    return np.empty(m, np.int64), np.empty((m, m)), np.empty((m, n)), np.empty(m), np.empty((m + 1, m))


@nb.njit(cache=True)
def _posterior_residual_row(dz, nzc, nzv, cnt, P, Q, add_q, k_prior, var, use, v_out, red_out, work):
    """Post-fit residuals of one batch row's used rows against the prior ``k_prior P-`` (see
    :func:`posterior_residuals`), ``P- = P (+ Q with add_q)`` (n, w): columns beyond the state count may be zero
    padding (the rows of ``H P-`` then run over all w, vectorized); writes ``v_out``, ``red_out`` on the used
    rows. ``nzc`` / ``nzv`` / ``cnt``: the non-zeros of the used rows of H (:func:`_rows_nonzeros`): ``H P-``
    and ``H P- H^T`` run over them (in increasing column order: the same sums as over all n columns with the
    zeros skipped). ``work``: :func:`_posterior_work` for w columns."""
    n = P.shape[1]
    m = use.shape[0]
    idx, Sw, HPw, yw, Lw = work
    q = 0
    for i in range(m):
        if use[i]:
            idx[q] = i
            q += 1
            v_out[i] = 0.0
            red_out[i] = 0.0
    if q == 0:
        return
    S = Sw[:q, :q]
    HP = HPw[:q]
    for a in range(q):
        ia = idx[a]
        for c in range(n):
            HP[a, c] = 0.0
        for t in range(cnt[ia]):
            l = nzc[ia, t]
            h = np.float64(nzv[ia, t])
            for c in range(n):
                pm = P[l, c] + Q[l, c] if add_q else P[l, c]
                HP[a, c] += h * np.float64(pm)
    for a in range(q):
        for c in range(a + 1):
            acc = 0.0
            ic = idx[c]
            for t in range(cnt[ic]):
                acc += HP[a, nzc[ic, t]] * np.float64(nzv[ic, t])
            S[a, c] = k_prior * acc
            S[c, a] = S[a, c]
        S[a, a] += var[idx[a]]
    if not _cholesky_inplace(S, 0.0):
        return
    y = yw[:q]  # S^-1 dz
    for i in range(q):
        y[i] = np.float64(dz[idx[i]])
    _cholesky_solve(S, y)
    # (S^-1)_aa = |L^-1 e_a|^2, the column sums of squares of L^-1 (lower triangle): L^-1 by rows, row i from the
    # rows above it (contiguous row operations), the sums accumulated row by row (the same sums in the same order)
    Linv = Lw[:q, :q]
    dg = Lw[q]
    for a in range(q):
        dg[a] = 0.0
    for i in range(q):
        for c in range(q):
            Linv[i, c] = 0.0
        Linv[i, i] = 1.0
        for p_ in range(i):
            sip = S[i, p_]
            for c in range(p_ + 1):
                Linv[i, c] -= sip * Linv[p_, c]
        d = S[i, i]
        for c in range(i + 1):
            Linv[i, c] = Linv[i, c] / d
            dg[c] += Linv[i, c] * Linv[i, c]
    for a in range(q):
        ia = idx[a]
        v_out[ia] = var[ia] * y[a]
        red_out[ia] = min(max(var[ia] * dg[a], 0.0), 1.0)


@nb.njit(cache=True)
def _posterior_residuals_kernel(dz, H, P, k_prior, var, use, v_out, red_out):
    B, m, n = H.shape
    nzc, nzv, cnt = _nonzeros_work(m, n, H.dtype)
    work = _posterior_work(m, n)
    for b in range(B):
        _rows_nonzeros(H[b], use[b], nzc, nzv, cnt)
        _posterior_residual_row(dz[b], nzc, nzv, cnt, P[b], P[b], False, k_prior, var[b], use[b], v_out[b],
                                red_out[b], work)


def posterior_residuals(dz, H, P, var, use, prior_inflation: float = 1.0):
    """Post-fit residuals of a measurement update against a (possibly inflated) prior: the residual form of
    covariance matching (Mohamed & Schwarz 1999, seed 000 ref [27]).

    With ``S = k H P H^T + diag(var)`` over the used rows (``k = prior_inflation``)::

        v = diag(var) S^-1 dz,     redundancy_i = var_i (S^-1)_ii,     E[v_i^2] = redundancy_i var_i

    (the Kalman post-fit residual ``dz - H dx+`` for ``k = 1``; ``k > 1`` trusts the prediction less, so
    that an overconfident P does not make a state error look like measurement noise; ``k -> inf`` tends
    to the snapshot fit of :func:`geometry_residuals`).

    Parameters
    ----------
    dz : (B, m); H : (B, m, n); P : (B, n, n) prior covariance; var : (B, m) variances; use : (B, m) bool;
    prior_inflation : k >= 1.

    Returns
    -------
    v, redundancy : (B, m) (0 on unused rows, or on a row whose S is not positive definite).
    """
    c = np.ascontiguousarray
    B, m = np.shape(dz)
    v, red = np.zeros((B, m)), np.zeros((B, m))
    _posterior_residuals_kernel(c(dz, np.float64), c(H, np.float64), c(P, np.float64), float(prior_inflation),
                                c(var, np.float64), c(use, np.bool_), v, red)
    return v, red


def posterior_residuals_reference(dz, H, P, var, use, prior_inflation: float = 1.0):
    """Numpy specification of :func:`posterior_residuals`."""
    B, m = np.shape(dz)
    v, red = np.zeros((B, m)), np.zeros((B, m))
    for b in range(B):
        rows = np.flatnonzero(use[b])
        if rows.size == 0:
            continue
        Hb = np.asarray(H[b][rows], np.float64)
        S = prior_inflation * Hb @ np.asarray(P[b], np.float64) @ Hb.T + np.diag(var[b, rows])
        Si = np.linalg.inv(S)
        v[b, rows] = var[b, rows] * (Si @ np.asarray(dz[b, rows], np.float64))
        red[b, rows] = np.clip(var[b, rows] * np.diag(Si), 0.0, 1.0)
    return v, red


def deleted_residuals(dz, H, P, var, use):
    """Leave-one-out (deleted) residuals of a measurement update: each used row predicted from the prior and
    every *other* used row.

    With ``S = H P H^T + diag(var)`` over the used rows and ``a = S^-1 dz``, the prediction of row i from the
    prior and the other rows misses it by (the leave-one-out identity of the Gaussian linear model)::

        e_i = a_i / (S^-1)_ii,        Var(e_i) = 1 / (S^-1)_ii = c_i + var_i

    where ``c_i`` is the variance of the prediction itself. ``e_i`` contains none of row i's own error in the
    estimate it is compared with (the post-fit residual of :func:`posterior_residuals` does: the update
    pulls the state towards an outlier and hides it), and, unlike the snapshot fit of
    :func:`geometry_residuals`, it uses the prior, so it separates one bad satellite of five. It is the
    studentized deleted residual of outlier diagnostics, here the covariance-matching sample of
    :class:`~nav_filters.adaptive.SageHusa` (``r_sample='loo'``):
    ``E[e_i^2 - c_i] = true variance of row i`` when P and the other rows' variances are right.

    Parameters
    ----------
    dz : (B, m) innovations; H : (B, m, n); P : (B, n, n) prior covariance; var : (B, m) variances of the rows
    (> 0 on used rows); use : (B, m) bool.

    Returns
    -------
    e : (B, m) deleted residuals; c : (B, m) variances of their predictions (``Var(e) - var``); both 0 on
    unused rows and on a row whose S is not positive definite.
    """
    v, red = posterior_residuals(dz, H, P, var, use, 1.0)
    ok = np.asarray(use, bool) & (red > 0)
    rs = np.where(ok, red, 1.0)
    var = np.asarray(var, np.float64)
    return np.where(ok, v / rs, 0.0), np.where(ok, var / rs - var, 0.0)



@dataclass(frozen=True)
class FitSplit:
    """The weighted innovation energy of each measurement type split by a snapshot least-squares fit.

    All (B, T) float64 arrays (T measurement types: 0 pseudoranges, 1 pseudorange rates), sums over the
    used rows of the type with weights ``1/R_ii``.

    Attributes
    ----------
    e_fit : ``||dz_fit||_W^2``, the energy of the part a state error can explain (the fit).
    e_res : ``||v||_W^2``, the energy of the residual no state error explains.
    dof : ``sum (1 - h_ii) = m_t - p_t``, the residual degrees of freedom (0: no redundancy, no split).
    p : ``p_t``, the number of fitted columns (0 where there is no split).
    tr_m : ``sum (H M H^T)_ii / R_ii`` with ``M`` the (unfaded) propagated covariance.
    tr_q : ``sum (H Q H^T)_ii / R_ii``.
    n : used rows of the type (also where there is no split).
    n_other : (B,) used rows of the 17-state model outside the fitted types (aiding rows: odometer, NHC, ZUPT);
        0 for a model other than the 17-state one.
    All but ``n`` and ``n_other`` are 0 where the type has no split.
    """

    e_fit: np.ndarray
    e_res: np.ndarray
    dof: np.ndarray
    p: np.ndarray
    tr_m: np.ndarray
    tr_q: np.ndarray
    n: np.ndarray
    n_other: np.ndarray

    @property
    def noise_scale(self) -> np.ndarray:
        """(B, T) ``g_t = e_res / dof``: the common variance factor of the type's noise that the residuals
        estimate (``E[v_i^2] = (1 - h_ii) g_t R_ii``); 1 where there is no redundancy."""
        ok = self.dof > 0
        return np.where(ok, self.e_res / np.where(ok, self.dof, 1.0), 1.0)

    def scaled(self, factors) -> "FitSplit":
        """The same split against the noise model ``factors_t R`` (B, T): every weighted sum divided by the
        type's factor (a common factor of a type leaves its fit, dof and fitted columns unchanged)."""
        return FitSplit(e_fit=self.e_fit / factors, e_res=self.e_res / factors, dof=self.dof, p=self.p,
                        tr_m=self.tr_m / factors, tr_q=self.tr_q / factors, n=self.n, n_other=self.n_other)

    @property
    def pooled_noise_scale(self) -> np.ndarray:
        """(B,) ``sum_t e_res / sum_t dof`` over the types with a split; 0 where no type has one."""
        dof = self.dof.sum(1)
        return np.where(dof > 0, self.e_res.sum(1) / np.where(dof > 0, dof, 1.0), 0.0)


def fit_split(dz, H, R, mask, prior, Q, n_types: int = 2, fast: bool = False) -> FitSplit:
    """Split each measurement type's innovations into what a state error can explain and what it cannot.

    Per batch row and type ``t`` (:func:`measurement_groups`), the weighted least-squares fit of
    :func:`geometry_residuals` (weights ``W = R^-1``, the type's ``H`` columns) gives residuals ``v`` and the
    fit ``dz_fit = dz - v``; ``W``-orthogonality splits the energy ``dz^T W dz = e_fit + e_res``. With
    ``dz = H dx + eps``, ``Cov(dx) = M + Q`` and ``Cov(eps) = g R`` (the column space of ``H`` is the fitted
    one, so the fit keeps all of ``H dx``)::

        E[e_res] = g (m_t - p_t),        E[e_fit] = tr(W H (M + Q) H^T) + g p_t

    so a state error shows in ``e_fit`` alone and a change of the noise level in both, in the ratio
    ``p_t : m_t - p_t`` (the residual form of covariance matching, Mohamed & Schwarz 1999; Baarda's
    redundancy numbers). The strong-tracking laws use it to fade on state events only
    (:class:`~nav_filters.adaptive.StrongTracking`).

    Parameters
    ----------
    dz : (B, m) innovations; H : (B, m, n); R : (B, m, m) measurement covariances (diagonals used);
    mask : (B, m) bool used rows; prior : (B, n, n) ``M = Phi P Phi^T``; Q : (B, n, n) or None;
    n_types : number of types fitted (rows of group >= n_types are left out).
    fast : the fused path: one compiled pass (:func:`_fit_split_rows`; the same quantities to round-off).

    Returns
    -------
    :class:`FitSplit` of (B, n_types) arrays.
    """
    mask = np.asarray(mask, bool)
    if fast:
        return _fit_split_fast(dz, H, R, mask, prior, Q, n_types)
    var = np.where(mask, np.diagonal(R, axis1=1, axis2=2).astype(np.float64), 1.0)
    groups = measurement_groups(H, mask)
    types = np.where(groups < n_types, groups, -1)
    v, red = geometry_residuals(dz, H, var, types, n_types)
    onehot = (types[..., None] == np.arange(n_types)).astype(np.float64)  # (B, m, T)
    dof = np.einsum("bm,bmt->bt", red, onehot)
    ok = dof > 1e-9
    w = np.where(types >= 0, 1.0 / var, 0.0)
    dz64 = np.asarray(dz, np.float64)
    H64 = np.asarray(H, np.float64)

    def wsum(x):
        return np.einsum("bm,bmt->bt", w * x, onehot)

    e_tot, e_res = wsum(dz64 ** 2), wsum(v ** 2)
    tr_m = wsum(quadratic_diag(H64, np.asarray(prior, np.float64)))
    tr_q = wsum(quadratic_diag(H64, np.asarray(Q, np.float64))) if Q is not None else np.zeros_like(tr_m)
    n_t = onehot.sum(1)
    n_other = ((groups >= n_types).sum(1) if H64.shape[2] == N_STATES else np.zeros(groups.shape[0], np.int64))
    z = np.zeros_like(dof)
    return FitSplit(e_fit=np.where(ok, e_tot - e_res, z), e_res=np.where(ok, e_res, z), dof=np.where(ok, dof, z),
                    p=np.where(ok, n_t - dof, z), tr_m=np.where(ok, tr_m, z), tr_q=np.where(ok, tr_q, z), n=n_t,
                    n_other=n_other)


def _fit_split_rows(dz, H, var, mask, prior, Q, has_q, n_types, model17, out, n_other, nchunk):
    """Compiled :func:`fit_split` (the fused path): per batch row, the groups of :func:`measurement_groups`,
    the per-type fits of :func:`_geometry_residual_row` and the weighted sums over H's non-zeros.

    ``var`` (B, m) the diagonal of R (1 on masked rows); ``model17``: H is the 17-state model's (the CLK /
    DRIFT columns name the groups; otherwise every row is 'other'). Writes ``out`` (7, B, T): e_fit, e_res,
    dof, p, tr_m, tr_q, n (0 where a type has no split, as :class:`FitSplit` says) and ``n_other`` (B,)."""
    B, m, n = H.shape
    T = n_types
    for c in nb.prange(nchunk):  # rows in chunks (parallel in the parallel variant), scratch per chunk
        types = np.empty(m, np.int64)
        use = np.zeros(m, np.bool_)
        typed = np.zeros(m, np.bool_)
        v = np.zeros(m)
        red = np.zeros(m)
        nzc, nzv, cnt = _nonzeros_work(m, n, H.dtype)
        work = _geometry_work(n)
        e_tot = np.empty(T)
        e_res = np.empty(T)
        dof = np.empty(T)
        trm = np.empty(T)
        trq = np.empty(T)
        nt = np.empty(T)
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            other = 0
            for i in range(m):
                g = -1
                if mask[b, i]:
                    g = 2
                    if model17:
                        if H[b, i, _CLK0] != 0:
                            g = 0
                        elif H[b, i, _DRIFT0] != 0:
                            g = 1
                    if g >= T:
                        other += 1
                types[i] = g if g < T else -1
                typed[i] = types[i] >= 0
                v[i] = 0.0
                red[i] = 0.0
            n_other[b] = other if model17 else 0
            _rows_nonzeros(H[b], typed, nzc, nzv, cnt)
            for t in range(T):
                for i in range(m):
                    use[i] = types[i] == t
                _geometry_residual_row(dz[b], H[b], nzc, cnt, var[b], use, v, red, work)
                e_tot[t] = 0.0
                e_res[t] = 0.0
                dof[t] = 0.0
                trm[t] = 0.0
                trq[t] = 0.0
                nt[t] = 0.0
            for i in range(m):
                t = types[i]
                if t < 0:
                    continue
                w = 1.0 / var[b, i]
                d = np.float64(dz[b, i])
                e_tot[t] += w * d * d
                e_res[t] += w * v[i] * v[i]
                dof[t] += red[i]
                nt[t] += 1.0
                trm[t] += w * _quad_nz(nzc, nzv, cnt, i, prior, prior, False, b)
                if has_q:
                    trq[t] += w * _quad_nz(nzc, nzv, cnt, i, Q, Q, False, b)
            for t in range(T):
                ok = dof[t] > 1e-9
                out[0, b, t] = e_tot[t] - e_res[t] if ok else 0.0
                out[1, b, t] = e_res[t] if ok else 0.0
                out[2, b, t] = dof[t] if ok else 0.0
                out[3, b, t] = nt[t] - dof[t] if ok else 0.0
                out[4, b, t] = trm[t] if ok else 0.0
                out[5, b, t] = trq[t] if ok else 0.0
                out[6, b, t] = nt[t]


_fit_split_serial, _fit_split_parallel = serial_and_parallel(_fit_split_rows)


def _fit_split_fast(dz, H, R, mask, prior, Q, n_types):
    """:func:`fit_split` through :func:`_fit_split_rows` (float64 inputs, one compiled pass)."""
    c = np.ascontiguousarray
    B, m, n = np.shape(H)
    var = c(np.where(mask, np.diagonal(R, axis1=1, axis2=2), 1.0), np.float64)
    out = np.empty((7, B, n_types))
    n_other = np.empty(B, np.int64)
    has_q = Q is not None
    P = c(prior, np.float64)
    kern, nchunk = row_kernel(_fit_split_serial, _fit_split_parallel, B)
    kern(c(dz, np.float64), c(H, np.float64), var, c(mask, np.bool_), P,
         c(Q, np.float64) if has_q else P, has_q, int(n_types), n == N_STATES, out, n_other, nchunk)
    return FitSplit(e_fit=out[0], e_res=out[1], dof=out[2], p=out[3], tr_m=out[4], tr_q=out[5], n=out[6],
                    n_other=n_other)
