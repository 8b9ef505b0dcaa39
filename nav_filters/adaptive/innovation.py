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
    Sage-Husa law).
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from ..error_model import CLK, DRIFT, N_STATES

GROUP_NAMES = ("pseudorange", "rate", "other")
"""Measurement groups of :func:`measurement_groups`, in id order."""


def quadratic_diag(H, X):
    """``diag(H X H^T)`` for batched ``H`` (B, m, n) and ``X`` (B, n, n): shape (B, m)."""
    return np.sum((H @ X) * H, axis=-1)


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

    Compiled (:func:`_traces_kernel`, structural zeros of H skipped); the parameters, returns and
    equations are documented on its numpy specification :func:`innovation_traces_reference` (agreement
    test in tests/nav_filters/test_compiled_update.py).
    """
    B = dz.shape[0]
    c = np.ascontiguousarray
    out = np.empty((4, B))
    _traces_kernel(c(dz), c(H), c(prior), c(prior if Q is None else Q), Q is not None, c(R), c(mask, bool), out)
    dt = np.result_type(dz.dtype, H.dtype, prior.dtype)
    tr_m, tr_q, tr_r, energy = (a.astype(dt) for a in out)
    return InnovationTraces(energy=energy, tr_m=tr_m, tr_q=tr_q, tr_r=tr_r, n_used=mask.sum(-1))


@nb.njit(cache=True)
def _traces_kernel(dz, H, prior, Q, with_q, R, mask, out):
    """Rows of ``out`` (4, B): tr(H prior H^T), tr(H Q H^T), tr(R), ||dz||^2 over the used rows."""
    B, m, n = H.shape
    for b in range(B):
        tm = 0.0
        tq = 0.0
        tr = 0.0
        en = 0.0
        for i in range(m):
            if not mask[b, i]:
                continue
            for k in range(n):
                hk = H[b, i, k]
                if hk == 0:
                    continue
                sm = 0.0
                sq = 0.0
                for l in range(n):
                    h = H[b, i, l]
                    if h != 0:
                        sm += h * prior[b, l, k]
                        if with_q:
                            sq += h * Q[b, l, k]
                tm += sm * hk
                tq += sq * hk
            tr += R[b, i, i]
            en += dz[b, i] * dz[b, i]
        out[0, b] = tm
        out[1, b] = tq
        out[2, b] = tr
        out[3, b] = en


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
