"""Compiled per-row arithmetic of the Sage-Husa law (:class:`~.sage_husa.SageHusa`) on the fused path.

The law's numpy lines (``SageHusa._adapt_q_reference``, ``_epoch_rows_reference`` and the numpy branch of
``_commit``) are the specification; the kernels here do the same operations in the same order on the same
types (agreement tests in ``tests/nav_filters/test_compiled_update.py`` and
``tests/nav_filters/test_fused_update.py``).

:func:`satellite_epoch` runs a whole fused update of the law in its default mode (per-satellite R) as one compiled
call: the row flags, the R law, the fused time and measurement update and the commit, each the kernel that the
Python sequence (``AdaptiveLaw._update`` with ``SageHusa._plan`` and ``_commit``) calls, in that order on the same
arrays, so the same bits (test: ``tests/nav_filters/test_compiled_epochs.py``). At B = 1 the Python between those
kernels (argument tuples, plan and result objects, some twenty small allocations) took longer than their arithmetic.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels import padded_width, serial_and_parallel, sym_eig_inplace
from .compiled_epoch import fused_law_update
from .satellite_r import _commit_parallel, _commit_serial, _r_sat_kernel, _r_sat_parallel, _weight_one


def _adapt_q_rows(rows, d, dx, P_post, prior, Q_nom, b, step, e_prev, b_used, q_init, q_ref, Q_raw, Q, Q_base,
                  jump_ratio, b_min, b_jump_factor, diagonal, floor, ceiling, above, own_eig=False, nchunk=1):
    """Seed 000 eqs 18-22 and 24 (with the choices of :class:`SageHusa`) on the rows flagged in ``rows``.

    ``own_eig`` (the fused fast path): the projection's eigen-decomposition by
    :func:`~nav_filters.kernels.sym_eig_inplace` (no LAPACK call per row, about twice as fast; equal to
    ``np.linalg.eigh``'s result to round-off, which it falls back to if the QR iteration does not converge)
    instead of ``np.linalg.eigh``. The projection binds on every adapted row of the built-in scenarios (an
    eigenvalue below ``floor`` and one above ``ceiling``: measured), so no cheaper test can skip it.

    Per row: ``Q_hat = sym(dx dx^T + P_post - prior)`` (eq 18, sign of eq 20); ``e = sum Q_hat^2`` and the
    eq 24 jump test lowering b for this correction; on the first adaptation ``q_ref`` and ``Q_raw`` from
    the nominal epoch Q (and, with ``above``, ``Q_base``); ``Q_raw <- (1 - d) Q_raw + d Q_hat`` (eq 22; eq 21
    with ``diagonal``); ``Q`` the projection of ``Q_raw`` onto ``floor <= eig(W Q W) <= ceiling``
    (:func:`clip_relative_eigenvalues`), or with ``above`` (``q_lower='nominal'``, ``floor`` 0) ``Q_base`` plus
    that projection of ``Q_raw - Q_base``. Updates ``e_prev``, ``b_used``, ``q_init``, ``q_ref``, ``Q_raw``,
    ``Q_base``, ``Q`` in place. The rows run in
    ``nchunk`` chunks (parallel in the parallel variant), each allocating its scratch once.
    """
    B, n = dx.shape
    for ch in nb.prange(nchunk):
        X = np.empty((n, n), Q_raw.dtype)
        Qh = np.empty((n, n), Q_raw.dtype)
        w = np.empty(n)
        Qw = np.empty((n, n))
        W = padded_width(n)   # sym_eig_inplace's rows, padded with zero columns (it keeps them zero)
        A = np.zeros((n, W))
        vals = np.empty(n)
        Vt = np.zeros((n, W))
        sc = np.zeros((3, W))
        for r in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            if rows[r]:
                _adapt_q_row(r, d, dx, P_post, prior, Q_nom, b, step, e_prev, b_used, q_init, q_ref, Q_raw, Q,
                             Q_base, jump_ratio, b_min, b_jump_factor, diagonal, floor, ceiling, above, own_eig,
                             (X, Qh, w, Qw, A, vals, Vt, sc))


@nb.njit(cache=True, inline="always")
def _adapt_q_row(r, d, dx, P_post, prior, Q_nom, b, step, e_prev, b_used, q_init, q_ref, Q_raw, Q, Q_base,
                 jump_ratio, b_min, b_jump_factor, diagonal, floor, ceiling, above, own_eig, work):
    """Row ``r`` of :func:`_adapt_q_rows`, in the scratch ``work = (X, Qh, w, Qw, A, vals, Vt, sc)``: ``X``, ``Qh``,
    ``Qw`` (n, n), ``A``, ``Vt`` (n, W) (W the padded width of :func:`~nav_filters.kernels.sym_eig_inplace`, zero
    padding), ``w``, ``vals`` (n,), ``sc`` (3, W). (One tuple: a call of more than 30 arguments is compiled by
    CPython as ``f(*args)``, which numba cannot inline.)"""
    X, Qh, w, Qw, A, vals, Vt, sc = work
    n = dx.shape[1]
    for i in range(n):
        for j in range(n):
            X[i, j] = (dx[r, i] * dx[r, j] + P_post[r, i, j]) - prior[r, i, j]
    e = 0.0
    for i in range(n):
        for j in range(n):
            Qh[i, j] = 0.5 * (X[i, j] + X[j, i])
            e += np.float64(Qh[i, j]) ** 2
    dr = d[r]
    if e_prev[r] > 0 and e > jump_ratio * e_prev[r]:
        bb = b[r]
        b_low = min(bb, max(b_min, 1.0 - b_jump_factor * (1.0 - bb)))
        dr = max(dr, _weight_one(b_low, step[r] + 1.0))
        b_used[r] = b_low
    e_prev[r] = e
    if not q_init[r]:
        top = -np.inf
        for i in range(n):
            top = max(top, np.float64(Q_nom[r, i, i]))
        for i in range(n):
            q_ref[r, i] = max(np.float64(Q_nom[r, i, i]), 1e-12 * top) if top > 0 else 1.0
            for j in range(n):
                Q_raw[r, i, j] = Q_nom[r, i, j]
                if above:
                    Q_base[r, i, j] = Q_nom[r, i, j]
    for i in range(n):
        w[i] = 1.0 / np.sqrt(q_ref[r, i])
    dd = Q_raw.dtype.type(dr)
    for i in range(n):
        for j in range(n):
            c = Qh[i, j] if (not diagonal or i == j) else 0.0
            X[i, j] = (1 - dd) * Q_raw[r, i, j] + dd * c
            Q_raw[r, i, j] = X[i, j]
    if above:  # the excess over the nominal Q is projected (in the filter dtype, as the numpy lines)
        for i in range(n):
            for j in range(n):
                X[i, j] = X[i, j] - Q_base[r, i, j]
    for i in range(n):
        for j in range(n):
            Qw[i, j] = 0.5 * (np.float64(X[i, j]) * w[i] * w[j] + np.float64(X[j, i]) * w[j] * w[i])
    done = False
    if own_eig:
        for i in range(n):
            for j in range(n):
                A[i, j] = Qw[i, j]
        if sym_eig_inplace(A, vals, Vt, sc[0], sc[1], sc[2]):
            # Qw = Vt^T diag(clip(vals)) Vt = floor I + sum_k (clip(vals_k) - floor) v_k v_k^T (the rows v_k of Vt
            # are orthonormal, Vt^T Vt = I): only the eigenvalues above the floor add a term (the floor holds about
            # half of them on the built-in scenarios). Their scaled rows A[q] = (min(vals_k, ceiling) - floor) Vt[k]
            # and Vt[q] = Vt[k] are packed to the top (q <= k); then the upper triangle, mirrored.
            na = 0
            for k in range(n):
                c = min(vals[k], ceiling) - floor
                if c > 0:
                    for j in range(n):
                        A[na, j] = c * Vt[k, j]
                        Vt[na, j] = Vt[k, j]
                    na += 1
            for i in range(n):
                for j in range(i, n):
                    Qw[i, j] = 0.0
                Qw[i, i] = floor
                for k in range(na):
                    a = Vt[k, i]
                    for j in range(i, n):
                        Qw[i, j] += a * A[k, j]
                for j in range(i + 1, n):
                    Qw[j, i] = Qw[i, j]
            done = True
    if not done:
        lam, vecs = np.linalg.eigh(Qw)
        for k in range(n):
            lam[k] = min(max(lam[k], floor), ceiling)
        for i in range(n):
            for j in range(i, n):
                s = 0.0
                for k in range(n):
                    s += vecs[i, k] * lam[k] * vecs[j, k]
                Qw[i, j] = s
                Qw[j, i] = s
    for i in range(n):       # back from the weighted frame: Q = W^-1 Qw W^-1, upper triangle, mirrored
        w[i] = np.sqrt(q_ref[r, i])
    for i in range(n):
        for j in range(i, n):
            q = Qw[i, j] * w[i] * w[j]
            if above:
                q += np.float64(Q_base[r, i, j])
            Q[r, i, j] = q
            Q[r, j, i] = q
    q_init[r] = True


_adapt_q_serial, _adapt_q_parallel = serial_and_parallel(_adapt_q_rows)


@nb.njit(cache=True)
def _epoch_rows_kernel(mask, seen, warmup, step, jcap, b, d_prev, has, active, d):
    """The row flags and weights :meth:`SageHusa._plan` starts from (the fused path; numpy specification
    :meth:`SageHusa._epoch_rows_reference`): ``has`` (any used row), ``active`` (``has`` and past the warm-up)
    and ``d``, the weight of seed 000 eqs 21-23 at the count ``min(step + 1, jcap)`` on active rows (the last
    one elsewhere), into the (B,) outputs."""
    B, m = mask.shape
    for r in range(B):
        h = False
        for i in range(m):
            h = h or mask[r, i]
        a = h and seen[r] >= warmup
        has[r] = h
        active[r] = a
        d[r] = _weight_one(b[r], np.float64(min(step[r] + 1, jcap[r]))) if a else d_prev[r]


@nb.njit(cache=True)
def _count_rows_kernel(active, has, pending, adapt_q, b, b_used_prev, step_prev, seen_prev, rows, b_used, step, seen):
    """The bookkeeping of :meth:`SageHusa._commit` (the fused path; numpy specification in ``_commit``): the rows
    whose Q adapts (``active`` with a pending transition, if ``adapt_q``), ``b_used`` (b on active rows),
    the adaptation and epoch counts, into new (B,) arrays. Returns whether any row adapts Q."""
    any_rows = False
    for r in range(active.shape[0]):
        rows[r] = active[r] and pending and adapt_q
        any_rows = any_rows or rows[r]
        b_used[r] = b[r] if active[r] else b_used_prev[r]
        step[r] = step_prev[r] + active[r]
        seen[r] = seen_prev[r] + has[r]
    return any_rows


@nb.njit(cache=True)
def satellite_epoch(r, H, R, mask, keys, prior, Q, Phi, P, x_inner, x_law, seen, step, jcap, b, b_key, d_prev,
                    warmup, epoch, s_tab, n_tab, last_tab, forget, smin, smax, sat_min, sample, min_red, k_prior, n_iter,
                    common, guard, r_scale, adapt_q, b_used_prev, e_prev, q_init, q_ref, Q_raw, Q_law, Q_base,
                    jump_ratio, b_min, b_jump_factor, diagonal, floor, ceiling, above, n_pr_keys, rose_factor, nchunk,
                    has, active, d, s_rows, n_rows, s_prev, s_group, R_used, no_fade, unit, s, Pn, xn, r_out, Sd,
                    nis, ok, n_used, summary, rows, b_used, step_new, seen_new, x_new):
    """One fused update of :class:`~.sage_husa.SageHusa` with ``r_mode='satellite'`` on an epoch with a
    pending transition (the inner form a fused :class:`~nav_filters.forms.kf.KalmanFilter`).

    The kernels of the Python path, in its order: :func:`_epoch_rows_kernel` (``SageHusa._epoch_rows``), the
    per-satellite R law (:func:`~.satellite_r._r_sat_kernel`, ``_plan_satellite``), the fused time + Joseph
    update without fading (:func:`.compiled_epoch.fused_law_update`), then, if every row's ``S`` was positive
    definite, the commit: ``x_new = x_law + xn``, the per-satellite tables
    (:func:`~.satellite_r._commit_rows`), the counts (:func:`_count_rows_kernel`) and the Q law
    (:func:`_adapt_q_rows`, own eigen-decomposition) on the adapting rows. Row kernels run their parallel
    variant over ``nchunk`` chunks when ``nchunk > 1``.

    Parameters
    ----------
    r : (B, m) innovations ``dz - H x`` of the law's state; H : (B, m, n); R : (B, m, m); mask : (B, m) bool;
    keys : (B, m) int64 measurement keys (-1 none); prior : (B, n, n) ``sym(Phi P Phi^T)``; Q : (B, n, n) the
    epoch's process noise; Phi : (B, n, n); P, x_inner : the inner form's covariance and state; x_law : (B, n)
    the law's state. The law's row state (``seen``, ``step``, ``jcap``, ``b``, ``d_prev``, ``warmup``; ``b_key``
    (B, K) the per-key forgetting factors, NaN: the row's ``b``), its
    satellite tables (``epoch`` the epoch counter after this one; ``s_tab``, ``n_tab``, ``last_tab`` updated in
    place on success) and settings (``forget`` ... ``guard``, ``r_scale``), and its Q-law state (``b_used_prev``,
    ``e_prev``, ``q_init``, ``q_ref``, ``Q_raw``, ``Q_law``, ``Q_base`` updated in place on success) and settings.
    The rest are outputs (new arrays of the shapes of the Python path's); ``no_fade`` (B, 0) and ``unit`` (B,)
    ones are the plan's fading (none: ``lambda = 1``), ``s`` (B, n) scratch of the filter dtype.

    Returns
    -------
    bool, False where some row's ``S`` is not positive definite: then nothing was committed (the law's state
    and tables are as they were; the caller raises ``LinAlgError``).
    """
    _epoch_rows_kernel(mask, seen, warmup, step, jcap, b, d_prev, has, active, d)
    if nchunk > 1:
        _r_sat_parallel(nchunk, r, H, prior, Q, True, R, mask, keys, b, b_key, jcap, d, active, epoch, s_tab, n_tab,
                        last_tab, forget, smin, smax, sat_min, sample, min_red, k_prior, n_iter, common, guard, r_scale,
                        s_rows, n_rows, s_prev, s_group, R_used)
    else:
        _r_sat_kernel(r, H, prior, Q, True, R, mask, keys, b, b_key, jcap, d, active, epoch, s_tab, n_tab, last_tab,
                      forget, smin, smax, sat_min, sample, min_red, k_prior, n_iter, common, guard, r_scale, s_rows,
                      n_rows, s_prev, s_group, R_used)
    if not fused_law_update(P, x_inner, Phi, Q, prior, H, R_used, r, mask, no_fade, unit, s, Pn, xn, r_out, Sd, nis,
                            ok, x_law, x_new, n_used, nchunk):
        return False
    if nchunk > 1:
        _commit_parallel(mask, keys, s_rows, n_rows, s_prev, epoch, n_pr_keys, rose_factor, s_tab, n_tab, last_tab,
                         summary, nchunk)
    else:
        _commit_serial(mask, keys, s_rows, n_rows, s_prev, epoch, n_pr_keys, rose_factor, s_tab, n_tab, last_tab,
                       summary, 1)
    if _count_rows_kernel(active, has, True, adapt_q, b, b_used_prev, step, seen, rows, b_used, step_new,
                          seen_new):
        # the Q law reads the counts before this epoch's (step) and the b_used just formed
        if nchunk > 1:
            _adapt_q_parallel(rows, d, xn, Pn, prior, Q, b, step, e_prev, b_used, q_init, q_ref, Q_raw, Q_law,
                              Q_base, jump_ratio, b_min, b_jump_factor, diagonal, floor, ceiling, above, True, nchunk)
        else:
            _adapt_q_serial(rows, d, xn, Pn, prior, Q, b, step, e_prev, b_used, q_init, q_ref, Q_raw, Q_law,
                            Q_base, jump_ratio, b_min, b_jump_factor, diagonal, floor, ceiling, above, True, 1)
    return True
