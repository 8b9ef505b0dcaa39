"""Tightly coupled GNSS measurement model: pseudorange and pseudorange-rate innovations.

Error-state convention (see :mod:`nav_filters.error_model`): x is the
correction to add to the estimate, so the innovation is
``dz = z_measured - h(x_nominal) = H x + v`` with ``H`` the Jacobian of the
measurement with respect to the *true* state:

=====================  ==========================================  =========================
row                    innovation dz                               non-zero H entries
=====================  ==========================================  =========================
pseudorange, sat j     ``pr_j - (rho_j(r_ins) + clk)``             ``POS: -u_j^T``, ``CLK: 1``
pseudorange rate, j    ``prr_j - (rho_dot_j(r_ins, v_ins) + drift)`` ``VEL: -u_j^T``, ``DRIFT: 1``
=====================  ==========================================  =========================

``rho``, ``rho_dot`` and the line of sight ``u`` come from
:func:`earth.ranging.range_and_rate` (Sagnac-corrected, Groves eqs 8.36, 8.46):
the same function the simulated receiver uses for the truth. This is the
linearized measurement of seed paper 000 eqs 2-3. The antenna is taken at the
IMU (no lever arm).

Rows are stacked ``[pr_1..pr_C, prr_1..prr_C]`` (m = 2C), or pseudoranges only
(m = C) when rates are not used or not available. Padded channels are masked.
"""
from __future__ import annotations

import numpy as np

from earth.ranging import range_and_rate

from .error_model import CLK, DRIFT, N_STATES, POS, VEL


def gnss_innovations(r_e, v_e, clk_m, drift_mps, sat_pos, sat_vel, pr, prr, pr_var, prr_var, mask,
                     use_rate: bool = True, dtype=np.float64):
    """Innovations, measurement matrix and variances of one tightly coupled epoch.

    Parameters
    ----------
    r_e, v_e : (B, 3) INS position [m] and velocity [m/s], ECEF.
    clk_m, drift_mps : (B,) estimated receiver clock bias [m] and drift [m/s].
    sat_pos, sat_vel : (B, C, 3) satellite ECEF position/velocity at transmission time.
    pr, prr : (B, C) measured pseudorange [m] and pseudorange rate [m/s] (prr may be None).
    pr_var, prr_var : (B, C) measurement variances [m^2], [m^2/s^2].
    mask : (B, C) bool, valid channels.
    use_rate : include the pseudorange-rate rows (ignored if ``prr`` is None).

    Returns
    -------
    dz : (B, m); H : (B, m, 17); R : (B, m) variances; row_mask : (B, m) bool;
    u : (B, C, 3) line-of-sight unit vectors (for DOP).
    """
    r64 = np.asarray(r_e, np.float64)
    v64 = np.asarray(v_e, np.float64)
    rho, rho_dot, u = range_and_rate(np.asarray(sat_pos, np.float64), np.asarray(sat_vel, np.float64), r64, v64)
    mask = np.asarray(mask, bool)
    B, C = mask.shape
    dz_pr = np.asarray(pr, np.float64) - (rho + np.asarray(clk_m, np.float64)[:, None])
    H_pr = np.zeros((B, C, N_STATES))
    H_pr[:, :, POS] = -u
    H_pr[:, :, CLK] = 1.0
    with_rate = use_rate and prr is not None
    if with_rate:
        dz_prr = np.asarray(prr, np.float64) - (rho_dot + np.asarray(drift_mps, np.float64)[:, None])
        H_prr = np.zeros((B, C, N_STATES))
        H_prr[:, :, VEL] = -u
        H_prr[:, :, DRIFT] = 1.0
        dz = np.concatenate([dz_pr, dz_prr], 1)
        H = np.concatenate([H_pr, H_prr], 1)
        R = np.concatenate([np.asarray(pr_var), np.asarray(prr_var)], 1)
        row_mask = np.concatenate([mask, mask], 1)
    else:
        dz, H, R, row_mask = dz_pr, H_pr, np.asarray(pr_var), mask
    dz = np.where(row_mask, dz, 0.0)
    R = np.where(row_mask, R, 1.0)
    return dz.astype(dtype), H.astype(dtype), R.astype(dtype), row_mask, u


def dop(u, mask):
    """Geometric dilution of precision from lines of sight.

    Parameters
    ----------
    u : (B, C, 3) unit lines of sight; mask : (B, C) bool.

    Returns
    -------
    gdop : (B,) sqrt(trace((G^T G)^-1)) with G = [-u, 1]; ``inf`` with fewer than 4 satellites.
    """
    mask = np.asarray(mask, bool)
    G = np.concatenate([-np.asarray(u, np.float64), np.ones(u.shape[:2] + (1,))], -1) * mask[..., None]
    A = G.mT @ G
    ok = mask.sum(-1) >= 4
    A = np.where(ok[:, None, None], A, np.eye(4))
    tr = np.trace(np.linalg.inv(A), axis1=1, axis2=2)
    return np.where(ok, np.sqrt(np.abs(tr)), np.inf)
