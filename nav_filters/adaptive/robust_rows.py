"""Compiled per-row pieces shared by the robust measurement screens (:mod:`.fde`, :mod:`.mestimation`,
:mod:`.vb`): the epoch's fit against the prior, its test statistics, and the equivalent-weight functions.

For one batch row with prior covariance ``P-`` (n, n), innovations ``r`` (m,) of the used rows, their
variances ``var`` (m,) and ``S = H P- H^T + diag(var)`` (:func:`~.innovation._posterior_residual_row`)::

    y = S^-1 r,  v_i = var_i y_i (post-fit residual),  red_i = var_i (S^-1)_ii (redundancy number)
    NIS = r^T S^-1 r = sum_i r_i y_i                   (chi-square with n_used dof under H0)
    e_i = v_i / red_i,  Var(e_i) = var_i / red_i       (deleted residual: row i predicted from the prior
                                                        and the other rows; independent of var_i itself)
    w_i = e_i / sqrt(Var e_i) = y_i / sqrt((S^-1)_ii)  (normalized deleted residual, Baarda's w-test
                                                        statistic of the outlier in row i alone)

(Teunissen 1990, recursive detection-identification-adaptation; Baarda 1968.)
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..error_model import CLK, DRIFT, N_STATES
from ..kernels import padded_width
from .innovation import _nonzeros_work, _posterior_residual_row, _posterior_work, _quad_nz, _rows_nonzeros

_CLK0, _DRIFT0 = CLK.start, DRIFT.start

UNKNOWNS_PER_GROUP = 4
"""The unknowns a measurement type serves in a snapshot fit: position and clock for the pseudoranges, velocity
and clock drift for the rates (:mod:`nav_filters.measurements`)."""


@nb.njit(cache=True)
def row_group(H, i, n):
    """Measurement group of row ``i`` of one batch row's ``H`` (m, n): 0 pseudorange (CLK column), 1 rate (DRIFT
    column), 2 any other row (constraints, or a filter that is not the 17-state model)."""
    if n == N_STATES:
        if H[i, _CLK0] != 0:
            return 0
        if H[i, _DRIFT0] != 0:
            return 1
    return 2


@nb.njit(cache=True)
def fit_work(m, n, dtype):
    """Scratch of :func:`fit_row` for m rows and n states, allocated once per kernel call (not per row):
    ``(nzc, nzv, cnt, Pm, post, v, red)`` with ``Pm`` the (n, padded) prior."""
    nzc, nzv, cnt = _nonzeros_work(m, n, dtype)
    Pm = np.zeros((n, padded_width(n)))
    return nzc, nzv, cnt, Pm, _posterior_work(m, padded_width(n)), np.zeros(m), np.zeros(m)


@nb.njit(cache=True)
def load_prior(prior, Q, add_q, b, Pm):
    """``Pm[:, :n] = prior[b] (+ Q[b])``: the row's ``P-`` in float64, its padding left zero."""
    n = prior.shape[1]
    for i in range(n):
        for j in range(n):
            Pm[i, j] = np.float64(prior[b, i, j]) + np.float64(Q[b, i, j]) if add_q else np.float64(prior[b, i, j])


@nb.njit(cache=True)
def fit_row(r, nzc, nzv, cnt, Pm, var, use, post, v, red):
    """The epoch's fit of one batch row against its prior ``Pm`` (module docstring) on the rows ``use``:
    writes ``v``, ``red`` (0 on the other rows) and returns the NIS. ``red`` 0 on a used row means ``S`` was
    not positive definite (the NIS is then 0: nothing can be tested)."""
    m = use.shape[0]
    for i in range(m):
        v[i] = 0.0
        red[i] = 0.0
    _posterior_residual_row(r, nzc, nzv, cnt, Pm, Pm, False, 1.0, var, use, v, red, post)
    nis = 0.0
    for i in range(m):
        if use[i] and red[i] > 0:
            nis += np.float64(r[i]) * v[i] / var[i]
    return nis


@nb.njit(cache=True)
def deleted_stat(v, red, var, i):
    """Normalized deleted residual ``w_i = v_i / sqrt(var_i red_i)`` of a fitted row (0 where ``red_i <= 0``)."""
    if red[i] <= 0:
        return 0.0
    return v[i] / math.sqrt(var[i] * red[i])


@nb.njit(cache=True)
def innovation_stat(r, nzc, nzv, cnt, Pm, var, i):
    """Normalized innovation squared of row i alone: ``r_i^2 / (h_i P- h_i^T + var_i)``."""
    q = _quad_nz(nzc, nzv, cnt, i, Pm.reshape((1,) + Pm.shape), Pm.reshape((1,) + Pm.shape), False, 0)
    return np.float64(r[i]) ** 2 / (q + var[i])


@nb.njit(cache=True)
def huber_weight(t, c):
    """Huber's weight ``psi(t) / t`` of a standardized residual ``t``: 1 for ``|t| <= c``, ``c / |t|`` beyond
    (Huber 1964, Ann. Math. Statist. 35:73-101, the psi function of the minimax M-estimator; Huber & Ronchetti
    2009, section 4.5)."""
    a = abs(t)
    return 1.0 if a <= c else c / a


@nb.njit(cache=True)
def igg3_weight(t, k0, k1):
    """The IGG-III equivalent-weight factor of a standardized residual ``t`` (the three-zone scheme of Yang 1994,
    used for the bifactor equivalent weights of Yang, Song & Xu 2002, J. Geodesy 76:353-358)::

        gamma = 1                                      |t| <= k0          (kept)
        gamma = k0 / |t| ((k1 - |t|) / (k1 - k0))^2    k0 < |t| <= k1     (down-weighted)
        gamma = 0                                      |t| > k1           (rejected)
    """
    a = abs(t)
    if a <= k0:
        return 1.0
    if a > k1:
        return 0.0
    return k0 / a * ((k1 - a) / (k1 - k0)) ** 2


def fit_reference(r, H, P, var, use):
    """Numpy specification of :func:`fit_row` + :func:`deleted_stat` for one batch row: ``(nis, v, red, w)``
    over the rows ``use`` (m,) (``v``, ``red``, ``w`` 0 elsewhere)."""
    m = r.shape[0]
    v, red, w = np.zeros(m), np.zeros(m), np.zeros(m)
    rows = np.flatnonzero(use)
    if rows.size == 0:
        return 0.0, v, red, w
    Hb = np.asarray(H[rows], np.float64)
    S = Hb @ np.asarray(P, np.float64) @ Hb.T + np.diag(var[rows])
    Si = np.linalg.inv(S)
    y = Si @ np.asarray(r[rows], np.float64)
    v[rows] = var[rows] * y
    red[rows] = var[rows] * np.diag(Si)
    w[rows] = y / np.sqrt(np.diag(Si))
    return float(np.asarray(r[rows], np.float64) @ y), v, red, w


def groups_reference(H) -> np.ndarray:
    """(m,) :func:`row_group` of every row of one batch row's ``H`` (m, n) (numpy)."""
    m, n = H.shape
    g = np.full(m, 2, np.int64)
    if n == N_STATES:
        g[H[:, _DRIFT0] != 0] = 1
        g[H[:, _CLK0] != 0] = 0
    return g


__all__ = ["UNKNOWNS_PER_GROUP", "row_group", "fit_work", "load_prior", "fit_row", "deleted_stat",
           "innovation_stat", "huber_weight", "igg3_weight", "fit_reference", "groups_reference"]
