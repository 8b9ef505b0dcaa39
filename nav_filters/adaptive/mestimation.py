"""Robust M-estimation of the measurement update: IGG-III equivalent weights (``kf-igg3``) and Huber weights
(``kf-huber``), iteratively reweighted within the epoch.

The update of the form the law wraps is the weighted least-squares fit of the prediction and the epoch's rows;
an M-estimator replaces each row's weight ``1 / R_ii`` by the equivalent weight ``gamma_i / R_ii``, i.e. hands
the form the equivalent variance ``R_ii / gamma_i`` (Yang, Song & Xu 2002, J. Geodesy 76:353-358: the
equivalent-weight form of robust estimation; for a Kalman filter, Yang, He & Xu 2001, J. Geodesy 75:109-116).
The factor ``gamma_i`` is a function of the row's standardized residual ``t_i`` and is found by iteration
(iteratively reweighted least squares)::

    gamma^(0) = 1
    repeat:  fit the prior and the rows with variances R_ii / gamma_i  (:mod:`.robust_rows`)
             t_i = e_i / sqrt(c_i + R_ii)          e_i the deleted residual of row i, c_i the variance of its
                                                   prediction from the prior and the other rows (as weighted)
             gamma_i = weight(t_i)                 IGG-III (:func:`~.robust_rows.igg3_weight`, k0, k1) or
                                                   Huber (:func:`~.robust_rows.huber_weight`, c)
    until max |gamma_new - gamma| < tol or max_iter fits.

Standardizing by the deleted residual (the w-test statistic at the first iteration) makes ``t_i`` independent
of row i's own weight, so a down-weighted outlier cannot hide by pulling the fit towards itself, and the
iteration does not oscillate. A row whose IGG-III weight is 0 (``|t| > k1``) is excluded (masked) from the
update; inside the iteration it stays in the fit with a negligible weight (:data:`MIN_WEIGHT`) so that its
standardized residual keeps being evaluated. Only pseudorange and rate rows are reweighted; constraint rows
(odometer, NHC, ZUPT) keep their variance.

Defaults: IGG-III ``k0 = 1.5``, ``k1 = 3.0`` (the values usual in GNSS applications of the scheme; Yang et al.
give k0 in 1.0-1.5 and k1 in 2.5-8.0); Huber ``c = 1.345`` (95% asymptotic efficiency at the normal
distribution, Huber & Ronchetti 2009).

Compiled per row (:func:`_mest_rows`); :func:`robust_weights_reference` is the numpy specification (agreement
test in ``tests/nav_filters/test_robust.py``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..kernels import row_kernel, serial_and_parallel
from .base import AdaptiveLaw, EpochContext, UpdatePlan
from .innovation import _rows_nonzeros
from .params import check_option
from .robust_rows import (fit_reference, fit_row, fit_work, groups_reference, huber_weight, igg3_weight,
                          load_prior, row_group)

WEIGHT_FUNCTIONS = ("igg3", "huber")
"""The equivalent-weight functions of :class:`RobustConfig`."""
MIN_WEIGHT = 1e-10
"""The weight a rejected row keeps inside the iteration (its variance times 1e10; it is masked in the update)."""


@dataclass(frozen=True)
class RobustConfig:
    """Configuration of :class:`RobustUpdate`.

    Attributes
    ----------
    weight : ``'igg3'`` or ``'huber'``.
    k0, k1 : IGG-III thresholds on ``|t|`` (0 < k0 < k1): weight 1 up to k0, 0 beyond k1.
    c : Huber threshold (> 0).
    max_iter : fits per epoch at most (>= 1).
    tol : convergence of the weights (max absolute change, > 0).
    min_rows : rows of a measurement type kept with a non-zero weight at least (>= 0; default 4, the unknowns
        a type serves): where IGG-III rejects more, the rejected rows with the smallest ``|t|`` come back with the
        weight ``k0 / |t|`` (a safeguard, not in the paper: a filter whose state has drifted sees every row as an
        outlier and would otherwise never update again).
    """

    weight: str = "igg3"
    k0: float = 1.5
    k1: float = 3.0
    c: float = 1.345
    max_iter: int = 10
    tol: float = 1e-2
    min_rows: int = 4

    def __post_init__(self):
        o = type(self).__name__
        if self.weight not in WEIGHT_FUNCTIONS:
            raise ValueError(f"{o}.weight must be one of {WEIGHT_FUNCTIONS}, got {self.weight!r}")
        check_option(o, "k0", self.k0, low=0.0, low_closed=False)
        check_option(o, "k1", self.k1, low=self.k0, low_closed=False)
        check_option(o, "c", self.c, low=0.0, low_closed=False)
        check_option(o, "tol", self.tol, low=0.0, low_closed=False)
        for name, low in (("max_iter", 1), ("min_rows", 0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < low:
                raise ValueError(f"{o}.{name} must be an int >= {low}, got {v!r}")


@nb.njit(cache=True)
def _weight(t, kind, k0, k1, c):
    return igg3_weight(t, k0, k1) if kind == 0 else huber_weight(t, c)


@nb.njit(cache=True)
def _mest_row(r, H, Rd, mask, Pm, work, var, gam, kind, k0, k1, c, max_iter, tol, min_rows, t_out):
    """The iteration of one batch row (module docstring): writes the weights ``gam`` (m,) (1 on rows not
    reweighted, 0 on masked rows) and the final standardized residuals ``t_out``; returns the fits run."""
    nzc, nzv, cnt, _, post, v, red = work
    m, n = H.shape
    _rows_nonzeros(H, mask, nzc, nzv, cnt)
    for i in range(m):
        gam[i] = 1.0 if mask[i] else 0.0
        t_out[i] = 0.0
    fits = 0
    for it in range(max_iter):
        for i in range(m):
            if mask[i]:
                var[i] = np.float64(Rd[i]) / max(gam[i], MIN_WEIGHT)
        fit_row(r, nzc, nzv, cnt, Pm, var, mask, post, v, red)
        fits += 1
        change = 0.0
        for i in range(m):
            if not mask[i] or red[i] <= 0 or row_group(H, i, n) == 2:
                continue
            e = v[i] / red[i]
            ce = var[i] / red[i] - var[i]
            t = e / math.sqrt(max(ce, 0.0) + np.float64(Rd[i]))
            t_out[i] = t
            g = _weight(t, kind, k0, k1, c)
            change = max(change, abs(g - gam[i]))
            gam[i] = g
        if change < tol:
            break
    _keep_redundancy(H, mask, gam, t_out, k0, min_rows)
    return fits


@nb.njit(cache=True)
def _keep_redundancy(H, mask, gam, t, k0, min_rows):
    """The safeguard against losing lock: while a measurement type keeps fewer than ``min_rows`` rows of non-zero
    weight, its rejected row with the smallest ``|t|`` comes back with the weight ``k0 / |t|``."""
    m, n = H.shape
    for grp in range(2):
        kept = 0
        for i in range(m):
            if mask[i] and gam[i] > 0 and row_group(H, i, n) == grp:
                kept += 1
        while kept < min_rows:
            best = -1
            for i in range(m):
                if mask[i] and gam[i] == 0 and row_group(H, i, n) == grp and (best < 0 or abs(t[i]) < abs(t[best])):
                    best = i
            if best < 0:
                break
            gam[best] = k0 / max(abs(t[best]), k0)
            kept += 1


def _mest_rows(r, H, prior, Q, add_q, Rd, mask, kind, k0, k1, c, max_iter, tol, min_rows, gam, t_out, fits, nchunk):
    """:func:`_mest_row` over every batch row in ``nchunk`` chunks (parallel in the parallel variant)."""
    B, m, n = H.shape
    for ch in nb.prange(nchunk):
        work = fit_work(m, n, H.dtype)
        Pm = work[3]
        var = np.ones(m)
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            load_prior(prior, Q, add_q, b, Pm)
            fits[b] = _mest_row(r[b], H[b], Rd[b], mask[b], Pm, work, var, gam[b], kind, k0, k1, c, max_iter, tol,
                                min_rows, t_out[b])


_mest_serial, _mest_parallel = serial_and_parallel(_mest_rows)


def robust_weights(r, H, P_minus, Rd, mask, config: RobustConfig, Q=None):
    """The equivalent-weight factors of one epoch (module docstring), compiled.

    Parameters
    ----------
    r : (B, m) innovations; H : (B, m, n); P_minus : (B, n, n) the prior (``+ Q`` when given);
    Rd : (B, m) reported variances; mask : (B, m) bool; config : RobustConfig.

    Returns
    -------
    gamma : (B, m) weight factors in [0, 1] (0 on masked rows); t : (B, m) standardized residuals of the
    last fit; fits : (B,) int fits run.
    """
    cc = np.ascontiguousarray
    B, m = np.shape(r)
    gam, t, fits = np.zeros((B, m)), np.zeros((B, m)), np.zeros(B, np.int64)
    kern, nchunk = row_kernel(_mest_serial, _mest_parallel, B)
    P = cc(P_minus)
    kern(cc(r), cc(H), P, P if Q is None else cc(Q), Q is not None, cc(Rd, np.float64), cc(mask, bool),
         WEIGHT_FUNCTIONS.index(config.weight), float(config.k0), float(config.k1), float(config.c),
         int(config.max_iter), float(config.tol), int(config.min_rows), gam, t, fits, nchunk)
    return gam, t, fits


def robust_weights_reference(r, H, P_minus, Rd, mask, config: RobustConfig):
    """Numpy specification of :func:`robust_weights` (same returns), row by row."""
    B, m = np.shape(r)
    w = np.vectorize(lambda t: (igg3_weight(t, config.k0, config.k1) if config.weight == "igg3"
                                else huber_weight(t, config.c)))
    gam, t_out, fits = np.where(mask, 1.0, 0.0), np.zeros((B, m)), np.zeros(B, np.int64)
    for b in range(B):
        Hb, P, R = np.asarray(H[b], np.float64), np.asarray(P_minus[b], np.float64), np.asarray(Rd[b], np.float64)
        robust = np.asarray(mask[b], bool) & (groups_reference(Hb) < 2)
        for it in range(config.max_iter):
            var = np.where(mask[b], R / np.maximum(gam[b], MIN_WEIGHT), 1.0)
            _, v, red, _ = fit_reference(r[b], Hb, P, var, mask[b])
            fits[b] += 1
            ok = robust & (red > 0)
            rs = np.where(ok, red, 1.0)
            t = np.where(ok, (v / rs) / np.sqrt(np.maximum(var / rs - var, 0.0) + R), 0.0)
            t_out[b] = np.where(ok, t, t_out[b])
            new = np.where(ok, w(t), gam[b])
            change = np.max(np.abs(new - gam[b])) if m else 0.0
            gam[b] = new
            if change < config.tol:
                break
        g = groups_reference(Hb)
        for grp in range(2):
            while np.sum(mask[b] & (gam[b] > 0) & (g == grp)) < config.min_rows:
                cand = np.flatnonzero(mask[b] & (gam[b] == 0) & (g == grp))
                if cand.size == 0:
                    break
                i = cand[np.argmin(np.abs(t_out[b, cand]))]
                gam[b, i] = config.k0 / max(abs(t_out[b, i]), config.k0)
    return gam, t_out, fits


class RobustUpdate(AdaptiveLaw):
    """IGG-III or Huber M-estimation of the update of any form (module docstring; ``kf-igg3``, ``kf-huber``).

    Parameters
    ----------
    P0, x0, dtype, inner, config : as :class:`~.base.AdaptiveLaw` (``config``: :class:`RobustConfig`).
    """

    name = "robust"
    config_class = RobustConfig

    def _init_state(self):
        B = self.batch_size
        self._excluded = np.zeros(B, np.int64)
        self._downweighted = np.zeros(B, np.int64)
        self._fits = np.zeros(B, np.int64)

    def _plan(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        Rd = np.diagonal(R, axis1=1, axis2=2)
        gam, _, fits = robust_weights(r, H, ctx.prior, Rd, mask, self.config, Q=ctx.Q if ctx.pending else None)
        keep = mask & (gam > 0)
        s = np.sqrt(np.where(keep, 1.0 / np.where(keep, gam, 1.0), 1.0)).astype(self.dtype)
        pending = dict(excluded=np.count_nonzero(mask & ~keep, axis=1),
                       downweighted=np.count_nonzero(keep & (gam < 1), axis=1), fits=fits)
        return UpdatePlan(fade=np.ones(self.batch_size), R=R * s[:, :, None] * s[:, None, :], mask=keep,
                          pending=pending)

    def _commit(self, plan: UpdatePlan, ctx: EpochContext, r, H, mask, dx):
        self._excluded = plan.pending["excluded"]
        self._downweighted = plan.pending["downweighted"]
        self._fits = plan.pending["fits"]

    def excluded(self) -> np.ndarray:
        """(B,) int rows with weight 0 at the last update (IGG-III's rejection zone)."""
        return self._excluded.copy()

    def _state(self) -> dict:
        return {"excluded": self._excluded, "downweighted": self._downweighted, "fits": self._fits}


__all__ = ["RobustConfig", "RobustUpdate", "robust_weights", "robust_weights_reference", "WEIGHT_FUNCTIONS",
           "MIN_WEIGHT"]
