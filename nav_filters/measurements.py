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

Speed: the navigator calls the compiled :func:`gnss_innovations` and :func:`dop`
(one numba call each instead of ~40 numpy calls; the innovation kernel also
builds only the non-zeros of H). The numpy functions
:func:`gnss_innovations_reference` and :func:`dop_reference` are the readable
specification, and ``tests/nav_filters/test_measurements.py`` asserts that the
compiled ones agree with them.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from earth.ranging import range_and_rate, range_rate_pair

from .error_model import CLK, DRIFT, N_STATES, POS, VEL
from .kernels import row_kernel, serial_and_parallel

# ----------------------------------------------------------------------------- satellite identity
SYSTEMS = ("G", "R", "E", "C", "J", "S")
"""GNSS system letters (RINEX 3) in the order of their index in a satellite key: GPS, GLONASS, Galileo,
BeiDou, QZSS, SBAS. A simulated constellation is system 0 (GPS-like)."""
MAX_PRN = 64
"""PRNs (slot numbers) 1..MAX_PRN per system."""
N_SAT_KEYS = len(SYSTEMS) * MAX_PRN
"""Number of distinct satellite keys: ``0 <= key < N_SAT_KEYS``."""


def satellite_key(system_index, prn):
    """Satellite key ``system_index * MAX_PRN + (prn - 1)``: one integer per satellite, unique across systems.

    Keys identify a satellite (system + PRN) independently of the receiver channel that tracks it, so
    that per-satellite state (the measurement-noise estimates of the adaptive laws) survives channel
    reordering, rising and setting satellites.

    Parameters
    ----------
    system_index : (...) int, index into :data:`SYSTEMS`.
    prn : (...) int in 1..MAX_PRN; a PRN < 1 (an empty channel, e.g. -1) gives key -1.

    Returns
    -------
    (...) int64 keys, -1 where ``prn < 1``.

    Raises
    ------
    ValueError
        a system index outside ``0..len(SYSTEMS)-1`` or a PRN above MAX_PRN on a valid entry.
    """
    sysi = np.asarray(system_index, np.int64)
    prn = np.asarray(prn, np.int64)
    valid = prn >= 1
    if np.any(valid & ((sysi < 0) | (sysi >= len(SYSTEMS)))):
        raise ValueError(f"system_index must lie in 0..{len(SYSTEMS) - 1}, got {np.unique(sysi[valid]).tolist()}")
    if np.any(valid & (prn > MAX_PRN)):
        raise ValueError(f"prn must lie in 1..{MAX_PRN}, got {int(prn[valid].max())}")
    return np.where(valid, sysi * MAX_PRN + prn - 1, -1).astype(np.int64)


@nb.njit(cache=True)
def _measurement_keys_kernel(k, mask, with_rate, n_extra, out):
    """Fill ``out`` (B, m) with the row identities of :func:`measurement_keys` (channels outside ``mask``: -1);
    returns False where a used key lies outside ``-1 .. N_SAT_KEYS - 1``."""
    B, C = k.shape
    valid = True
    for b in range(B):
        for i in range(C):
            v = k[b, i] if mask[b, i] else -1
            if v >= N_SAT_KEYS or v < -1:
                valid = False
            out[b, i] = v
            if with_rate:
                out[b, C + i] = v + N_SAT_KEYS if v >= 0 else -1
        for e in range(C * (1 + with_rate), C * (1 + with_rate) + n_extra):
            out[b, e] = -1
    return valid


def measurement_keys(sat_keys, with_rate: bool, n_extra: int = 0, mask=None):
    """Per measurement row identity of a tightly coupled epoch, rows ``[pr_1..pr_C, prr_1..prr_C, extra...]``.

    A pseudorange row of satellite key ``s`` gets ``s``, its pseudorange-rate row ``N_SAT_KEYS + s``
    (one identity per satellite *and* measurement type); rows without a satellite (empty channels,
    constraint rows) get -1.

    Parameters
    ----------
    sat_keys : (B, C) int satellite keys of the channels (:func:`satellite_key`), -1 on empty channels.
    with_rate : whether the epoch has pseudorange-rate rows.
    n_extra : number of extra (constraint) rows stacked after the GNSS rows.
    mask : (B, C) bool channels in use, or None (all): the others get -1 (their keys are not checked).

    Returns
    -------
    (B, m) int64 with ``m = C (1 + with_rate) + n_extra``, values in ``[-1, 2 N_SAT_KEYS)``.
    """
    k = np.ascontiguousarray(sat_keys, np.int64)
    if k.ndim != 2:
        raise ValueError(f"sat_keys must have shape (B, C), got {k.shape}")
    mask = np.ones(k.shape, bool) if mask is None else np.ascontiguousarray(mask, bool)
    if mask.shape != k.shape:
        raise ValueError(f"mask must have the shape of sat_keys {k.shape}, got {mask.shape}")
    out = np.empty((k.shape[0], k.shape[1] * (1 + bool(with_rate)) + int(n_extra)), np.int64)
    if not _measurement_keys_kernel(k, mask, bool(with_rate), int(n_extra), out):
        raise ValueError(f"sat_keys must lie in -1..{N_SAT_KEYS - 1}")
    return out


def gnss_innovations_reference(r_e, v_e, clk_m, drift_mps, sat_pos, sat_vel, pr, prr, pr_var, prr_var, mask,
                               use_rate: bool = True, dtype=np.float64):
    """Innovations, measurement matrix and variances of one tightly coupled epoch (numpy reference).

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


def dop_reference(u, mask):
    """Geometric dilution of precision from lines of sight (numpy reference of :func:`dop`).

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


# ----------------------------------------------------------------------------- compiled versions
_POS0, _VEL0, _CLK0, _DRIFT0 = POS.start, VEL.start, CLK.start, DRIFT.start


@nb.njit(cache=True, inline="always")
def channel_residuals(sx, sy, sz, svx, svy, svz, rx, ry, rz, rvx, rvy, rvz, clk, drift, pr, prr, u):
    """One channel's pseudorange and rate residuals at a receiver state: ``(pr - (rho + clk), prr - (rho_dot +
    drift))`` [m, m/s], the range and rate by :func:`earth.ranging.range_rate_pair` (Groves eqs 8.36, 8.46; 3
    light-time iterations), ``u`` (3,) the unit line of sight it leaves. The compiled innovations
    (:func:`_innovations_rows`) and the per-satellite envs' post-update residuals
    (:mod:`envs.channel_features`) both form them here. Scalars in, so that the row loops pass no array views."""
    rho, rho_dot = range_rate_pair(sx, sy, sz, svx, svy, svz, rx, ry, rz, rvx, rvy, rvz, 3, u)
    return pr - (rho + clk), prr - (rho_dot + drift)


def _innovations_rows(r, v, clk, drift, sat_pos, sat_vel, pr, prr, pr_var, prr_var, mask, with_rate,
                      dz, H, R, row_mask, u, nchunk):
    """Fill dz, H, R, row_mask, u for every row and channel (see the reference; H zeroed here, row by row, in
    the row's chunk); rows in ``nchunk`` chunks (parallel in the parallel variant), each row's arithmetic the same."""
    B, C = mask.shape
    for c in nb.prange(nchunk):
        uu = np.empty(3)
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            H[b] = 0.0
            for j in range(C):
                e_pr, e_prr = channel_residuals(sat_pos[b, j, 0], sat_pos[b, j, 1], sat_pos[b, j, 2],
                                                sat_vel[b, j, 0], sat_vel[b, j, 1], sat_vel[b, j, 2],
                                                r[b, 0], r[b, 1], r[b, 2], v[b, 0], v[b, 1], v[b, 2], clk[b],
                                                drift[b], pr[b, j], prr[b, j], uu)
                m = mask[b, j]
                for i in range(3):
                    u[b, j, i] = uu[i]
                    H[b, j, _POS0 + i] = -uu[i]
                H[b, j, _CLK0] = 1.0
                dz[b, j] = e_pr if m else 0.0
                R[b, j] = pr_var[b, j] if m else 1.0
                row_mask[b, j] = m
                if with_rate:
                    k = C + j
                    for i in range(3):
                        H[b, k, _VEL0 + i] = -uu[i]
                    H[b, k, _DRIFT0] = 1.0
                    dz[b, k] = e_prr if m else 0.0
                    R[b, k] = prr_var[b, j] if m else 1.0
                    row_mask[b, k] = m


_innovations_serial, _innovations_parallel = serial_and_parallel(_innovations_rows)


def _f64(a):
    """``a`` as float64, strided views read in place (an epoch's slice of a world's (B, epochs, ...) arrays)."""
    return np.asarray(a, dtype=np.float64)


def gnss_innovations(r_e, v_e, clk_m, drift_mps, sat_pos, sat_vel, pr, prr, pr_var, prr_var, mask,
                     use_rate: bool = True, dtype=np.float64):
    """Innovations, measurement matrix and variances of one tightly coupled epoch (compiled).

    Same arguments, returns and equations as :func:`gnss_innovations_reference` (seed paper 000 eqs 2-3
    linearized; ranging by Groves eqs 8.36, 8.46 through :func:`earth.ranging.range_rate_pair`); agrees
    with it to rounding (test).
    """
    mask = np.ascontiguousarray(mask, dtype=bool)
    B, C = mask.shape
    with_rate = bool(use_rate and prr is not None)
    m = 2 * C if with_rate else C
    dt = np.dtype(dtype)
    dz = np.empty((B, m), dt)
    H = np.empty((B, m, N_STATES), dt)  # zeroed by the kernel, row by row
    R = np.empty((B, m), dt)
    row_mask = np.empty((B, m), bool)
    u = np.empty((B, C, 3))
    pr64 = _f64(pr)
    if with_rate:
        prr64, prr_var64 = _f64(prr), _f64(prr_var)
    else:
        prr64 = prr_var64 = pr64
    kern, nchunk = row_kernel(_innovations_serial, _innovations_parallel, B)
    kern(_f64(r_e), _f64(v_e), _f64(clk_m), _f64(drift_mps), _f64(sat_pos), _f64(sat_vel),
         pr64, prr64, _f64(pr_var), prr_var64, mask, with_rate, dz, H, R, row_mask, u, nchunk)
    return dz, H, R, row_mask, u


@nb.njit(cache=True)
def _dop_kernel(u, mask, out):
    """GDOP per row: trace((G^T G)^-1) = ||L^-1||_F^2 with G^T G = L L^T (Cholesky); inf below 4 satellites
    or for a degenerate geometry (G^T G not positive definite)."""
    B, C = mask.shape
    A = np.empty((4, 4))
    g = np.empty(4)
    for b in range(B):
        n = 0
        A[:, :] = 0.0
        for j in range(C):
            if mask[b, j]:
                n += 1
                g[0] = -u[b, j, 0]
                g[1] = -u[b, j, 1]
                g[2] = -u[b, j, 2]
                g[3] = 1.0
                for i in range(4):
                    for k in range(4):
                        A[i, k] += g[i] * g[k]
        if n < 4:
            out[b] = np.inf
            continue
        ok = True
        for k in range(4):  # in-place Cholesky, lower triangle
            d = A[k, k]
            for p in range(k):
                d -= A[k, p] * A[k, p]
            if not d > 0.0:
                ok = False
                break
            A[k, k] = np.sqrt(d)
            for i in range(k + 1, 4):
                s = A[i, k]
                for p in range(k):
                    s -= A[i, p] * A[k, p]
                A[i, k] = s / A[k, k]
        if not ok:
            out[b] = np.inf
            continue
        tr = 0.0
        for c in range(4):  # column c of L^-1 by forward substitution
            for i in range(4):
                g[i] = 0.0
            for i in range(c, 4):
                s = 1.0 if i == c else 0.0
                for p in range(c, i):
                    s -= A[i, p] * g[p]
                g[i] = s / A[i, i]
                tr += g[i] * g[i]
        out[b] = np.sqrt(tr)


def dop(u, mask):
    """Geometric dilution of precision (compiled; same definition as :func:`dop_reference`).

    Parameters
    ----------
    u : (B, C, 3) unit lines of sight; mask : (B, C) bool.

    Returns
    -------
    gdop : (B,) sqrt(trace((G^T G)^-1)) with G = [-u, 1] over the used satellites (Langley's GDOP);
        ``inf`` with fewer than 4 satellites or a degenerate geometry.
    """
    mask = np.ascontiguousarray(mask, dtype=bool)
    out = np.empty(mask.shape[0])
    _dop_kernel(_f64(u), mask, out)
    return out
