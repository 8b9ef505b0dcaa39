"""Compiled per-row arithmetic of the strong-tracking laws (``stkf``, ``ma-stkf``) on the fused path.

An epoch of :class:`~.strong_tracking.StrongTracking` or :class:`~.strong_tracking.MeasurementAdaptiveSTKF`
is a few compiled passes (the innovation traces, the snapshot fit split) followed by some forty numpy
operations on (B,) arrays: the smoothing of the innovation ratio, the fault test, the measurement factors,
the fading factors and their per-state caps, the scaled R. At B = 1 each of those operations costs its call
overhead (~1 us), not its arithmetic: together they were the largest part of an MA-STKF step. The kernels
here do that arithmetic in one pass per row.

The numpy lines of the laws (``_plan_reference``) stay the specification. The kernels repeat their
operations in the same order on the same types, so the results are the same bits, float32 and float64
(``tests/nav_filters/test_strong_tracking_rows.py``):

* numpy's ``np.clip``, ``np.maximum`` and ``np.minimum`` propagate NaN (:func:`_clip`, :func:`_max_nan`,
  :func:`_min_nan` do too);
* a row sum (over the measurement rows, or the types) is numpy's pairwise summation
  (:func:`~nav_filters.kernels.pairwise_sum`);
* the measurement factors reach R in R's dtype, rounded as ``astype`` rounds them.

:func:`st_epoch` and :func:`ma_epoch` run a whole fused update of each law as one compiled call: the
innovation traces and the fit split (:mod:`.innovation`'s kernels), the plan kernel here, the fused time and
measurement update (:func:`~nav_filters.forms.kf._fused_rows`) and the commit arithmetic, in the order of the
Python sequence (``AdaptiveLaw._update``) and on the same arrays, so the same bits
(``tests/nav_filters/test_compiled_epochs.py``). At B = 1 the Python between those kernels took longer than
their arithmetic.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels import pairwise_sum, scale_symmetric_row, serial_and_parallel
from .compiled_epoch import fused_law_update
from .innovation import _fit_split_parallel, _fit_split_serial, _traces_parallel, _traces_serial
from .satellite_r import _row_group

SPLIT_STATS = 5
"""Columns of the smoothed statistics of :func:`~.strong_tracking.split_fading`: ``n``, ``d``, ``s``,
``e_res``, ``dof``."""


@nb.njit(cache=True)
def _clip(v, lo, hi):
    """``np.clip`` of a scalar: NaN stays NaN."""
    if v != v:
        return v
    if v < lo:
        return lo
    if v > hi:
        return hi
    return v


@nb.njit(cache=True)
def _max_nan(a, b):
    """``np.maximum`` of two scalars (NaN if either is)."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


@nb.njit(cache=True)
def _min_nan(a, b):
    """``np.minimum`` of two scalars (NaN if either is)."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


@nb.njit(cache=True)
def split_fading_row(e_fit, e_res, dof, p, tr_m, tr_q, n_typed, n_other, stats_prev, weight, softening,
                     confidence, lambda_max, noise_gate, printed, scale, stats, x, xk):
    """One row of :func:`~.strong_tracking.split_fading` (its numpy lines are the specification).

    Parameters
    ----------
    e_fit, e_res, dof, p, tr_m, tr_q, n_typed : (T,) the row's :class:`~.innovation.FitSplit`;
    n_other : its aiding rows; stats_prev : (SPLIT_STATS,) smoothed statistics; weight, softening,
    confidence, lambda_max, noise_gate, printed, scale : floats as in ``split_fading``.
    stats : (SPLIT_STATS,) output, the new statistics; x (T,), xk (SPLIT_STATS,) : scratch.

    Returns
    -------
    The fading factor (float).
    """
    T = e_fit.shape[0]
    has = False
    typed = n_other > 0
    for t in range(T):
        has = has or dof[t] > 0
        typed = typed or n_typed[t] > 0
    for t in range(T):  # n_k terms
        if dof[t] > 0:
            g = e_res[t] / dof[t]
            x[t] = e_fit[t] - softening * g * p[t] - tr_q[t]
        else:
            x[t] = 0.0
    xk[0] = pairwise_sum(x, 0, T)
    xk[1] = pairwise_sum(tr_m, 0, T)
    for t in range(T):  # s_k terms
        if dof[t] > 0:
            g = e_res[t] / dof[t]
            pp = p[t]
            u = g * pp + tr_m[t] + tr_q[t]
            x[t] = 2.0 * (u * u) / (pp if pp > 0 else 1.0) + 2.0 * (g * g) * (pp * pp) / dof[t]
        else:
            x[t] = 0.0
    xk[2] = pairwise_sum(x, 0, T)
    xk[3] = pairwise_sum(e_res, 0, T)
    xk[4] = pairwise_sum(dof, 0, T)
    w = weight
    keep = 1.0 - w
    for c in range(SPLIT_STATS):
        if not has:
            stats[c] = stats_prev[c]
        elif c == 2:  # the variance of a weighted sum
            stats[c] = (keep * keep) * stats_prev[c] + (w * w) * xk[c]
        else:
            stats[c] = keep * stats_prev[c] + w * xk[c]
    n, d, var, er, ds = stats[0], stats[1], stats[2], stats[3], stats[4]
    if d > 0:
        if var < 0.0:  # np.maximum(var, 0): NaN stays NaN
            var = 0.0
        v = scale * (n - confidence * np.sqrt(var)) / d
    else:
        v = 1.0
    v = _clip(v, 1.0, lambda_max)
    noise = er / ds if ds > 0 else 1.0
    if noise > noise_gate:
        v = 1.0
    return v if has else (1.0 if typed else printed)


@nb.njit(cache=True)
def split_fading_kernel(e_fit, e_res, dof, p, tr_m, tr_q, n_typed, n_other, stats_prev, weight, softening,
                        confidence, lambda_max, noise_gate, printed, scale, lam, stats):
    """:func:`split_fading_row` for every row: ``lam`` (B,) and ``stats`` (B, SPLIT_STATS) out."""
    B, T = e_fit.shape
    x = np.empty(T)
    xk = np.empty(SPLIT_STATS)
    for b in range(B):
        lam[b] = split_fading_row(e_fit[b], e_res[b], dof[b], p[b], tr_m[b], tr_q[b], n_typed[b], n_other[b],
                                  stats_prev[b], weight[b], softening[b], confidence, lambda_max, noise_gate,
                                  printed[b], scale[b], stats[b], x, xk)


@nb.njit(cache=True)
def _type_factor(t, alpha_t, alpha):
    """The measurement factor of a row of type ``t``: ``alpha_t[0]`` (pseudoranges), ``alpha_t[1]`` (rates),
    else the scalar ``alpha`` (one row of :meth:`~.strong_tracking.MeasurementAdaptiveSTKF._row_factors`)."""
    return alpha_t[0] if t == 0 else (alpha_t[1] if t == 1 else alpha)


@nb.njit(cache=True)
def _fading_factor(tr_c, tr_m, tr_q, tr_r, softening, lambda_max, scale):
    """One row of :func:`~.strong_tracking.fading_factor` (seed 003 eqs 19-21)."""
    tr_n = tr_c - tr_q - softening * tr_r  # eq 20
    lam = scale * tr_n / tr_m if tr_m > 0 else 1.0  # eq 19
    return _clip(lam, 1.0, lambda_max)


@nb.njit(cache=True)
def _capped_fading(lam, prior, b, p0_diag, cap, fade):
    """One row of :meth:`~.base.AdaptiveLaw.capped_fading` (finite ``cap``) into ``fade`` (n,)."""
    for k in range(fade.shape[0]):
        d = np.float64(prior[b, k, k])
        room = cap * p0_diag[b, k] / d if d > 0 else np.inf
        fade[k] = _min_nan(lam, _max_nan(1.0, room))


def _st_plan_rows(energy, tr_m, tr_q, tr_r, mask, prior, pending, s_fit, s_res, s_dof, s_p, s_m, s_q, s_n, s_other,
                  count, v_prev, fs_prev, rho, softening, p0_diag, lambda_max, fading_cap, geometry, confidence,
                  noise_gate, v_out, has_out, lam_out, fs_out, fade, nchunk):
    """:meth:`~.strong_tracking.StrongTracking._plan_reference` after its traces and fit split, per row.

    Parameters
    ----------
    energy, tr_m, tr_q, tr_r : (B,) the :class:`~.innovation.InnovationTraces` (in the law's dtype);
    mask : (B, m) bool; prior : (B, n, n) ``Phi P Phi^T``; pending : a transition is pending;
    s_fit, s_res, s_dof, s_p, s_m, s_q, s_n : (B, T) and s_other (B,): the :class:`~.innovation.FitSplit`'s
    ``e_fit, e_res, dof, p, tr_m, tr_q, n, n_other`` (read with ``geometry`` only);
    count, v_prev, fs_prev : the law's state; rho, softening : (B,) parameters; p0_diag : (B, n) float64;
    lambda_max, fading_cap (inf: one factor per row), geometry, confidence, noise_gate : the config.
    v_out, lam_out : (B,) float64, has_out : (B,) bool, fs_out : (B, SPLIT_STATS), fade : (B, n) (only
    where ``fading_cap`` is finite) outputs; nchunk : row chunks (:func:`~nav_filters.kernels.row_kernel`).
    """
    B, m = mask.shape
    T = s_fit.shape[1]
    capped = fading_cap != np.inf
    for c in nb.prange(nchunk):
        x = np.empty(T)
        xk = np.empty(SPLIT_STATS)
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            has = False
            for i in range(m):
                has = has or mask[b, i]
            trr = np.float64(tr_r[b])
            ratio = np.float64(energy[b]) / (trr if has else 1.0)
            r = rho[b]
            v = ratio if count[b] == 0 else (r * v_prev[b] + ratio) / (1.0 + r)
            if not has:
                v = v_prev[b]
            lam = _fading_factor(v * trr, np.float64(tr_m[b]), np.float64(tr_q[b]), trr, softening[b],
                                 lambda_max, 1.0)
            if geometry:
                weight = 1.0 if count[b] == 0 else 1.0 / (1.0 + r)
                lam = split_fading_row(s_fit[b], s_res[b], s_dof[b], s_p[b], s_m[b], s_q[b], s_n[b], s_other[b],
                                       fs_prev[b], weight, softening[b], confidence, lambda_max, noise_gate, lam,
                                       1.0, fs_out[b], x, xk)
            else:
                for k in range(SPLIT_STATS):
                    fs_out[b, k] = fs_prev[b, k]
            if not (has and pending):
                lam = 1.0
            v_out[b] = v
            has_out[b] = has
            lam_out[b] = lam
            if capped:
                _capped_fading(lam, prior, b, p0_diag, fading_cap, fade[b])


_st_plan_serial, _st_plan_parallel = serial_and_parallel(_st_plan_rows)


def _ma_plan_rows(energy, tr_m, tr_q, tr_r, H, R, mask, prior, pending, s_fit, s_res, s_dof, s_p, s_m, s_q, s_n,
                  s_other, count, c_prev, beta_prev, alpha_prev, alpha_t_prev, fs_prev, streak, b_par, softening,
                  fading_scale, fault_threshold, p0_diag, warmup, max_rejections, alpha_min, alpha_max, lambda_max,
                  fading_cap, uses_alpha, confidence, noise_gate, c_out, beta_out, alpha_out, accept_out, fault_out,
                  lam_out, alpha_t_out, fs_out, fade, R_out, mask_out, nchunk):
    """:meth:`~.strong_tracking.MeasurementAdaptiveSTKF._plan_reference` after its traces and fit split, per
    row, in the default configuration (``fading_noise='geometry'``, ``r_mode='type'``): seed 003 eqs 10-11
    (``beta``, ``c``), the fault test (eq 13 on the residual noise scale where a type has redundancy), eq 16
    (``alpha``) and the per-type factors, eqs 19-21 and :func:`split_fading_row` (``lambda``), the per-state
    caps, and ``R_out = D R D`` with ``D = diag(sqrt(factor))`` (unit variance on masked rows).

    Parameters
    ----------
    energy, tr_m, tr_q, tr_r : (B,) the :class:`~.innovation.InnovationTraces` (in the law's dtype);
    H : (B, m, n); R : (B, m, m); mask : (B, m) bool; prior : (B, n, n); pending : a transition is pending;
    s_fit ... s_other : the :class:`~.innovation.FitSplit` against the reported R (as in :func:`_st_plan_rows`);
    count, c_prev, beta_prev, alpha_prev, alpha_t_prev (B, 2), fs_prev (B, SPLIT_STATS), streak : the law's
    state; b_par, softening, fading_scale, fault_threshold : (B,) parameters; p0_diag : (B, n) float64;
    warmup ... noise_gate : the config (``uses_alpha``: ``fading_uses_alpha``).
    c_out, beta_out, alpha_out, lam_out (B,), accept_out, fault_out (B,) bool, alpha_t_out (B, 2), fs_out
    (B, SPLIT_STATS), fade (B, n) (finite ``fading_cap`` only), R_out (B, m, m) in R's dtype, mask_out (B, m)
    bool: outputs; nchunk : row chunks.
    """
    B, m, n = H.shape
    T = s_fit.shape[1]
    capped = fading_cap != np.inf
    for c in nb.prange(nchunk):
        work = np.empty(m)
        types = np.empty(m, np.int64)
        sq = np.empty(m, R.dtype)
        x = np.empty(T)
        xk = np.empty(SPLIT_STATS)
        model = np.empty((4, T))
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            has = False
            for i in range(m):
                has = has or mask[b, i]
            trm, trq, trr = np.float64(tr_m[b]), np.float64(tr_q[b]), np.float64(tr_r[b])
            ratio = np.float64(energy[b]) / (trr if has else 1.0)
            # eqs 10-11 (beta = 1 at the first epoch)
            beta = 1.0 if count[b] == 0 else beta_prev[b] / (beta_prev[b] + b_par[b])
            cc = (1.0 - beta) * c_prev[b] + beta * ratio
            tr_c = cc * trr
            acting = has and count[b] >= warmup
            # eq 13 against the current noise model: each row's factor on its reported variance
            a_prev = alpha_prev[b]
            for i in range(m):
                t = _row_group(H, b, i, n) if mask[b, i] else -1
                types[i] = t
                work[i] = _type_factor(t, alpha_t_prev[b], a_prev) * (np.float64(R[b, i, i]) if mask[b, i] else 0.0)
            predicted = trm + trq + pairwise_sum(work, 0, m)
            thr = fault_threshold[b]
            fault = acting and tr_c > thr * predicted
            # the split against alpha_(k-1) R: every weighted sum over the type's factor
            for t in range(T):
                f = alpha_t_prev[b, t]
                model[0, t] = s_fit[b, t] / f
                model[1, t] = s_res[b, t] / f
                model[2, t] = s_m[b, t] / f
                model[3, t] = s_q[b, t] / f
            dof_sum = pairwise_sum(s_dof[b], 0, T)
            if dof_sum > 0:  # a fault is a jump of the measurement errors (residual noise scale vs the model)
                fault = acting and pairwise_sum(model[1], 0, T) / dof_sum > thr
            fault = fault and streak[b] < max_rejections
            accept = has and not fault
            # eq 16: measurement factor
            safe_r = trr if trr > 0 else 1.0
            alpha = _clip((tr_c - trm - trq) / safe_r, alpha_min, alpha_max) if accept and acting else a_prev
            # eqs 19-21: fading factor (N_k with the current noise model alpha_(k-1) R_k, or the reported R_k)
            soft = softening[b] * (a_prev if uses_alpha else 1.0)
            lam = _fading_factor(tr_c, trm, trq, trr, soft, lambda_max, fading_scale[b])
            for t in range(T):  # per-type factors (a rejected epoch's residuals still measure the noise)
                a = alpha_t_prev[b, t]
                if s_dof[b, t] > 0 and acting:
                    a = _clip((1.0 - beta) * a + beta * (s_res[b, t] / s_dof[b, t]), alpha_min, alpha_max)
                alpha_t_out[b, t] = a
            lam = split_fading_row(model[0], model[1], s_dof[b], s_p[b], model[2], model[3], s_n[b], s_other[b],
                                   fs_prev[b], beta, softening[b], confidence, lambda_max, noise_gate, lam,
                                   fading_scale[b], fs_out[b], x, xk)
            if not accept:
                for k in range(SPLIT_STATS):
                    fs_out[b, k] = fs_prev[b, k]
            if not (accept and acting and pending):
                lam = 1.0
            c_out[b] = cc if accept else c_prev[b]
            beta_out[b] = beta if accept else beta_prev[b]
            alpha_out[b] = alpha
            accept_out[b] = accept
            fault_out[b] = fault
            lam_out[b] = lam
            # eq 24: alpha R, as D R D in R's dtype (masked rows keep unit variance)
            for i in range(m):
                sq[i] = _type_factor(types[i], alpha_t_out[b], alpha) if accept else 1.0  # rounded to R's dtype
                sq[i] = np.sqrt(sq[i])
            scale_symmetric_row(R[b], sq, mask[b], R_out[b])
            for i in range(m):
                mask_out[b, i] = mask[b, i] and not fault
            if capped:
                _capped_fading(lam, prior, b, p0_diag, fading_cap, fade[b])


_ma_plan_serial, _ma_plan_parallel = serial_and_parallel(_ma_plan_rows)


@nb.njit(cache=True)
def _traces_and_split(r, H, R, mask, prior, Q, dz64, H64, prior64, Q64, geometry, model17, nchunk, tr_out, energy,
                      tr_m, tr_q, tr_r, var, split_out, n_other):
    """What ``strong_tracking._fused_plan_inputs`` forms: the innovation traces (``_traces_rows`` into ``tr_out``
    (4, B) float64, then cast to the law's dtype as ``astype``: ``energy``, ``tr_m``, ``tr_q``, ``tr_r``) and,
    with ``geometry``, the fit split of two types (``_fit_split_rows`` on the float64 copies ``dz64`` ...
    ``Q64``, the variances ``var`` (B, m) = diag R, 1 on masked rows; into ``split_out`` (7, B, 2),
    ``n_other`` (B,))."""
    if nchunk > 1:
        _traces_parallel(r, H, prior, Q, True, R, mask, tr_out, nchunk)
    else:
        _traces_serial(r, H, prior, Q, True, R, mask, tr_out, 1)
    B, m = mask.shape
    for b in range(B):
        tr_m[b] = tr_out[0, b]
        tr_q[b] = tr_out[1, b]
        tr_r[b] = tr_out[2, b]
        energy[b] = tr_out[3, b]
    if geometry:
        for b in range(B):
            for i in range(m):
                var[b, i] = np.float64(R[b, i, i]) if mask[b, i] else 1.0
        if nchunk > 1:
            _fit_split_parallel(dz64, H64, var, mask, prior64, Q64, True, 2, model17, split_out, n_other, nchunk)
        else:
            _fit_split_serial(dz64, H64, var, mask, prior64, Q64, True, 2, model17, split_out, n_other, 1)


@nb.njit(cache=True)
def st_epoch(r, H, R, mask, prior, Q, Phi, P, x_inner, x_law, dz64, H64, prior64, Q64, model17, count, v_prev,
             fs_prev, rho, softening, p0_diag, lambda_max, fading_cap, geometry, confidence, noise_gate, nchunk,
             tr_out, energy, tr_m, tr_q, tr_r, var, split_out, n_other, v, has, lam, fs, fade, s, Pn, xn, r_out, Sd,
             nis, ok, x_new, n_used, count_new):
    """One fused update of :class:`~.strong_tracking.StrongTracking` on an epoch with a pending transition (the
    inner form a fused ``kf``): :func:`_traces_and_split`, :func:`_st_plan_rows`,
    :func:`.compiled_epoch.fused_law_update`, then the commit's count ``count_new = count + has`` (``v``, ``lam``,
    ``fs`` are the law's new state). Returns False, committing nothing, where some row's ``S`` is not positive
    definite."""
    _traces_and_split(r, H, R, mask, prior, Q, dz64, H64, prior64, Q64, geometry, model17, nchunk, tr_out, energy,
                      tr_m, tr_q, tr_r, var, split_out, n_other)
    plan = (energy, tr_m, tr_q, tr_r, mask, prior, True, split_out[0], split_out[1], split_out[2], split_out[3],
            split_out[4], split_out[5], split_out[6], n_other, count, v_prev, fs_prev, rho, softening, p0_diag,
            lambda_max, fading_cap, geometry, confidence, noise_gate, v, has, lam, fs, fade)
    if nchunk > 1:
        _st_plan_parallel(*plan, nchunk)
    else:
        _st_plan_serial(*plan, 1)
    if not fused_law_update(P, x_inner, Phi, Q, prior, H, R, r, mask, fade, lam, s, Pn, xn, r_out, Sd, nis, ok, x_law,
                         x_new, n_used, nchunk):
        return False
    for b in range(count.shape[0]):
        count_new[b] = count[b] + has[b]
    return True


@nb.njit(cache=True)
def ma_epoch(r, H, R, mask, prior, Q, Phi, P, x_inner, x_law, dz64, H64, prior64, Q64, model17, count, c_prev,
             beta_prev, alpha_prev, alpha_t_prev, fs_prev, streak, b_par, softening, fading_scale, fault_threshold,
             p0_diag, warmup, max_rejections, alpha_min, alpha_max, lambda_max, fading_cap, uses_alpha, confidence,
             noise_gate, nchunk, tr_out, energy, tr_m, tr_q, tr_r, var, split_out, n_other, c_out, beta_out,
             alpha_out, accept, fault, lam, alpha_t, fs, fade, R_used, mask_used, s, Pn, xn, r_out, Sd, nis, ok,
             x_new, n_used, count_new, streak_new):
    """One fused update of :class:`~.strong_tracking.MeasurementAdaptiveSTKF` in its default configuration on an
    epoch with a pending transition (the inner form a fused ``kf``): :func:`_traces_and_split`,
    :func:`_ma_plan_rows`, :func:`.compiled_epoch.fused_law_update` with the planned ``R_used`` and ``mask_used``,
    then the commit's counts: ``count_new = count + accept`` and the rejection streak (one more on a fault, 0 on a
    row with a measurement, else kept). Returns False, committing nothing, where some row's ``S`` is not positive
    definite."""
    _traces_and_split(r, H, R, mask, prior, Q, dz64, H64, prior64, Q64, True, model17, nchunk, tr_out, energy,
                      tr_m, tr_q, tr_r, var, split_out, n_other)
    plan = (energy, tr_m, tr_q, tr_r, H, R, mask, prior, True, split_out[0], split_out[1], split_out[2],
            split_out[3], split_out[4], split_out[5], split_out[6], n_other, count, c_prev, beta_prev, alpha_prev,
            alpha_t_prev, fs_prev, streak, b_par, softening, fading_scale, fault_threshold, p0_diag, warmup,
            max_rejections, alpha_min, alpha_max, lambda_max, fading_cap, uses_alpha, confidence, noise_gate, c_out,
            beta_out, alpha_out, accept, fault, lam, alpha_t, fs, fade, R_used, mask_used)
    if nchunk > 1:
        _ma_plan_parallel(*plan, nchunk)
    else:
        _ma_plan_serial(*plan, 1)
    if not fused_law_update(P, x_inner, Phi, Q, prior, H, R_used, r, mask_used, fade, lam, s, Pn, xn, r_out, Sd, nis,
                         ok, x_law, x_new, n_used, nchunk):
        return False
    B, m = mask.shape
    for b in range(B):
        count_new[b] = count[b] + accept[b]
        has = False
        for i in range(m):
            has = has or mask[b, i]
        streak_new[b] = streak[b] + 1 if fault[b] else (0 if has else streak[b])
    return True
