"""Conventional error-state Kalman filter with the Joseph-form update (``kf``).

The reference form: every other form of the family must reproduce its state and
covariance in float64 (seed paper 000, eqs 5-8 for the standard recursion).
"""
from __future__ import annotations

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
