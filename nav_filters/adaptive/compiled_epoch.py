"""The part of the adaptive laws' compiled epochs (:func:`.sage_husa_rows.satellite_epoch`,
:func:`.strong_tracking_rows.st_epoch`, :func:`.strong_tracking_rows.ma_epoch`) that every law shares: the inner
``kf``'s fused time and measurement update of the law's plan and the law's state after it."""
from __future__ import annotations

import numba as nb
import numpy as np

from ..forms.kf import _fused_parallel, _fused_serial


@nb.njit(cache=True)
def fused_law_update(P, x_inner, Phi, Q, prior, H, R, r, mask, fade, lam, s, Pn, xn, r_out, Sd, nis, ok, x_law,
                     x_new, n_used, nchunk):
    """The fused update of a law's plan (``KalmanFilter._predicted_update`` in mode 2, the prior given, as
    ``AdaptiveLaw._update`` calls it): ``s`` (B, n) the square roots of the fading factors ``fade`` (B, n), or
    of ``lam`` (B,) where ``fade`` has no columns, in the filter dtype (``fused_update``'s ``s``); then, if every
    row's ``S`` is positive definite, the law's new state ``x_new = x_law + xn`` (its correction taken back) and
    ``n_used`` the rows of ``mask`` per batch row. Returns whether every ``S`` was positive definite (else
    nothing but the outputs was written)."""
    B, n = s.shape
    per_state = fade.shape[1] > 0
    for b in range(B):
        for i in range(n):
            s[b, i] = np.sqrt(fade[b, i]) if per_state else np.sqrt(lam[b])
    if nchunk > 1:
        _fused_parallel(P, x_inner, Phi, s, Q, prior, 2, H, R, r, mask, Pn, xn, r_out, Sd, nis, ok, nchunk)
    else:
        _fused_serial(P, x_inner, Phi, s, Q, prior, 2, H, R, r, mask, Pn, xn, r_out, Sd, nis, ok, 1)
    for b in range(B):
        if not ok[b]:
            return False
    m = mask.shape[1]
    for b in range(B):
        c = 0
        for i in range(m):
            c += mask[b, i]
        n_used[b] = c
        for k in range(n):
            x_new[b, k] = x_law[b, k] + xn[b, k]
    return True
