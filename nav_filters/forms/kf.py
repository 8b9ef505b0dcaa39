"""Conventional error-state Kalman filter with the Joseph-form update (``kf``).

The reference form: every other form of the family must reproduce its state and
covariance in float64 (seed paper 000, eqs 5-8 for the standard recursion).

Speed: :meth:`KalmanFilter._update` runs the Joseph update in one compiled
(numba) call per batch, :func:`joseph_update` (Cholesky of S, two triangular
solves for the gain, structural zeros of H and R skipped; parallel over rows for
B >= 64). :meth:`KalmanFilter._update_reference` is the same recursion in numpy
(the readable specification); ``tests/nav_filters/test_kf_form.py`` asserts
their agreement.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from .base import FilterForm, UpdateResult, symmetrize


def innovation_covariance(P, H, R):
    """``S = H P H^T + R`` and ``P H^T``; shapes (B, m, m), (B, n, m)."""
    PHt = P @ H.mT
    return H @ PHt + R, PHt


def nis_and_gain(S, PHt, dz):
    """Gain ``K = P H^T S^-1`` and NIS ``dz^T S^-1 dz`` by one Cholesky factorization of S.

    Returns
    -------
    K : (B, n, m); nis : (B,)
    """
    L = np.linalg.cholesky(S)
    # S^-1 = L^-T L^-1; solve with the (small) batched triangular factor.
    Linv = np.linalg.inv(L)
    Sinv = Linv.mT @ Linv
    K = PHt @ Sinv
    w = Linv @ dz[..., None]
    nis = np.sum(w[..., 0] ** 2, axis=-1)
    return K, nis


def _joseph_rows(P, x, H, R, dz, Pn, xn, r, Sd, nis, ok):
    """Joseph-form update of every batch row (seed 000 eqs 7-8 with the Joseph covariance of eq 17).

    Per row b (P symmetric, as every form keeps it)::

        r  = dz - H x                       HP = H P           S = HP H^T + R   (lower triangle)
        S  = L L^T (Cholesky)               w = L^-1 r         nis = w^T w
        K^T = L^-T L^-1 HP                  x+ = x + K r
        A  = I - K H                        P+ = sym(A P A^T + K R K^T)

    Products skip the structural zeros of H and R (a GNSS row of H has 4 non-zeros of 17).

    Parameters
    ----------
    P : (B, n, n); x : (B, n); H : (B, m, n); R : (B, m, m); dz : (B, m) (prepared: masked rows neutral).
    Pn, xn : outputs (B, n, n), (B, n); r : (B, m) residual ``dz - H x``; Sd : (B, m) diag(S);
    nis : (B,); ok : (B,) bool, False where S is not positive definite (that row's outputs are undefined).
    """
    B, m, n = H.shape
    for b in nb.prange(B):
        dt = P.dtype
        HP = np.zeros((m, n), dt)
        L = np.zeros((m, m), dt)
        Y = np.empty((m, n), dt)
        w = np.empty(m, dt)
        At = np.zeros((n, n), dt)
        AP = np.zeros((n, n), dt)
        X = np.zeros((n, n), dt)
        KRt = np.zeros((m, n), dt)
        # column indices / values of the non-zeros of each row of H
        nzc = np.empty((m, n), np.int64)
        nzv = np.empty((m, n), dt)
        cnt = np.zeros(m, np.int64)
        for i in range(m):
            c = 0
            for l in range(n):
                h = H[b, i, l]
                if h != 0:
                    nzc[i, c] = l
                    nzv[i, c] = h
                    c += 1
            cnt[i] = c
        for i in range(m):
            s = dz[b, i]
            for t in range(cnt[i]):
                l = nzc[i, t]
                h = nzv[i, t]
                s -= h * x[b, l]
                for k in range(n):
                    HP[i, k] += h * P[b, l, k]
            r[b, i] = s
        # S = HP H^T + R (lower triangle) and its Cholesky factor, in place in L
        for i in range(m):
            for j in range(i + 1):
                s = R[b, i, j]
                for t in range(cnt[j]):
                    s += HP[i, nzc[j, t]] * nzv[j, t]
                L[i, j] = s
            Sd[b, i] = L[i, i]
        good = True
        for j in range(m):
            d = L[j, j]
            for p in range(j):
                d -= L[j, p] * L[j, p]
            if not d > 0:
                good = False
                break
            d = np.sqrt(d)
            L[j, j] = d
            for i in range(j + 1, m):
                s = L[i, j]
                for p in range(j):
                    s -= L[i, p] * L[j, p]
                L[i, j] = s / d
        ok[b] = good
        if not good:
            continue
        # w = L^-1 r, Y = L^-1 HP (forward), K^T = L^-T Y (backward, in place in Y)
        q = 0.0
        for i in range(m):
            s = r[b, i]
            for p in range(i):
                s -= L[i, p] * w[p]
            w[i] = s / L[i, i]
            q += w[i] * w[i]
            for k in range(n):
                Y[i, k] = HP[i, k]
            for p in range(i):
                lip = L[i, p]
                if lip != 0:
                    for k in range(n):
                        Y[i, k] -= lip * Y[p, k]
            for k in range(n):
                Y[i, k] /= L[i, i]
        nis[b] = q
        for i in range(m - 1, -1, -1):
            for p in range(i + 1, m):
                lpi = L[p, i]
                if lpi != 0:
                    for k in range(n):
                        Y[i, k] -= lpi * Y[p, k]
            for k in range(n):
                Y[i, k] /= L[i, i]
        # x+ = x + K r
        for k in range(n):
            xn[b, k] = x[b, k]
        for i in range(m):
            ri = r[b, i]
            for k in range(n):
                xn[b, k] += Y[i, k] * ri
        # A^T = I - H^T K^T
        for k in range(n):
            At[k, k] = 1.0
        for i in range(m):
            for t in range(cnt[i]):
                l = nzc[i, t]
                h = nzv[i, t]
                for k in range(n):
                    At[l, k] -= h * Y[i, k]
        # AP = A P, X = AP A^T
        for k in range(n):
            for l in range(n):
                a = At[l, k]
                if a != 0:
                    for j in range(n):
                        AP[k, j] += a * P[b, l, j]
        for k in range(n):
            for l in range(n):
                a = AP[k, l]
                for j in range(n):
                    X[k, j] += a * At[l, j]
        # X += K R K^T  (KRt = (K R)^T = R^T K^T)
        for j in range(m):
            for i in range(m):
                rij = R[b, i, j]
                if rij != 0:
                    for k in range(n):
                        KRt[j, k] += rij * Y[i, k]
        for k in range(n):
            for j in range(m):
                a = KRt[j, k]
                for l in range(n):
                    X[k, l] += a * Y[j, l]
        for k in range(n):
            for l in range(n):
                Pn[b, k, l] = 0.5 * (X[k, l] + X[l, k])


_joseph_serial = nb.njit(cache=True)(_joseph_rows)
_joseph_parallel = nb.njit(cache=True, parallel=True)(_joseph_rows)

PARALLEL_MIN_BATCH = 64
"""Below this batch size the serial kernel runs (a parallel launch costs more than it saves)."""


def joseph_update(P, x, H, R, dz):
    """Compiled Joseph-form update of a batch (see :func:`_joseph_rows`; seed 000 eqs 7-8, 17).

    Parameters
    ----------
    P : (B, n, n) symmetric covariance; x : (B, n); H : (B, m, n); R : (B, m, m); dz : (B, m), all prepared
        (masked rows neutral) and of one float dtype.

    Returns
    -------
    P_new, x_new, r (= dz - H x), diag(S), nis : new arrays in the dtype of P.

    Raises
    ------
    numpy.linalg.LinAlgError
        ``S`` is not positive definite on some row (as ``np.linalg.cholesky`` does); nothing is returned.
    """
    B, m, n = H.shape
    dt = P.dtype
    args = [np.ascontiguousarray(a, dt) for a in (P, x, H, R, dz)]
    Pn = np.empty((B, n, n), dt)
    xn = np.empty((B, n), dt)
    r = np.empty((B, m), dt)
    Sd = np.empty((B, m), dt)
    nis = np.zeros(B, dt)
    ok = np.empty(B, bool)
    kern = _joseph_parallel if B >= PARALLEL_MIN_BATCH else _joseph_serial
    kern(*args, Pn, xn, r, Sd, nis, ok)
    if not ok.all():
        raise np.linalg.LinAlgError("Matrix is not positive definite")
    return Pn, xn, r, Sd, nis


class KalmanFilter(FilterForm):
    """``kf``: covariance form, Joseph update ``P = (I-KH) P (I-KH)^T + K R K^T``.

    Time update (seed 000 eqs 5-6): ``x = Phi x``, ``P = Phi P Phi^T + Q``.
    Measurement update (eqs 7-8 with the Joseph form of eq 17):
    ``K = P H^T (H P H^T + R)^-1``, ``x = x + K (dz - H x)``.
    """

    name = "kf"

    def _init_uncertainty(self, P0):
        self.P = P0

    @property
    def covariance(self):
        return self.P

    def predict(self, Phi, Q):
        Phi = np.asarray(Phi, self.dtype)
        self.x = (Phi @ self.x[..., None])[..., 0]
        self.P = symmetrize(Phi @ self.P @ Phi.mT + np.asarray(Q, self.dtype))

    def _update(self, dz, H, R, mask):
        P, x, r, Sd, nis = joseph_update(self.P, self.x, H, R, dz)
        self.P, self.x = P, x
        n_used = mask.sum(-1)
        return UpdateResult(nis=nis, n_used=n_used, innovation=r, innovation_var=Sd, applied=n_used > 0)

    def _update_reference(self, dz, H, R, mask):
        """Numpy specification of :meth:`_update` (same equations; agreement test)."""
        P = self.P
        S, PHt = innovation_covariance(P, H, R)
        r = dz - (H @ self.x[..., None])[..., 0]
        K, nis = nis_and_gain(S, PHt, r)
        self.x = self.x + (K @ r[..., None])[..., 0]
        I_KH = np.eye(self.n, dtype=self.dtype) - K @ H
        self.P = symmetrize(I_KH @ P @ I_KH.mT + K @ R @ K.mT)
        n_used = mask.sum(-1)
        return UpdateResult(nis=nis, n_used=n_used, innovation=r,
                            innovation_var=np.diagonal(S, axis1=1, axis2=2).copy(), applied=n_used > 0)
