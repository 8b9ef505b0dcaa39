"""Per-channel observation features of the per-satellite environments (:mod:`envs.satellite_env`), compiled.

Each receiver channel of the *coming* epoch (the one the next action applies to) is described by what the
receiver reports for it there (C/N0, elevation, the satellite's system) and by what the filter made of the same
satellite at its last updates, found by satellite key (:func:`nav_filters.measurements.satellite_key`), not by
channel: the receiver reorders its channels (the simulated one by elevation) and satellites rise and set, so a
channel's history is its satellite's. A satellite not used at the previous update is new (its history zero, its
tracked count 0).

Two compiled row kernels (serial below :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows, else parallel
chunks) do the work of a step: ``commit_epoch_serial`` / ``_parallel`` after the update (each used channel's
statistics of the epoch, pushed onto its satellite's history, read straight from the world's arrays at each row's
epoch; ``commit_serial`` / ``_parallel`` do the same from inputs gathered beforehand) and ``observation_serial`` /
``_parallel`` (the features of the coming epoch's channels). :func:`snapshot_deleted_residuals` is the numpy
specification of the deleted residuals (agreement tests in ``tests/envs/test_satellite_env.py``).

Features of channel i (the rows of :data:`CHANNEL_FEATURES`, in this order, float32, clipped to [low, high];
zero on a channel without a satellite):

* static: ``cn0``, ``elevation``, ``sys_gps`` ... ``sys_other`` (one-hot), ``tracked``, ``last_action``;
* for lag l = 0 .. :data:`CHANNEL_HISTORY` - 1 (l = 0 the satellite's last update, 1 the one before, ...):
  ``z_pr``, ``z_prr``, ``w_pr``, ``w_prr``, ``log_scale``, ``cn0`` of that update (:data:`LAGGED_FEATURES`).

Normalized innovation ``z = asinh(dz_i / sqrt(S_ii))``: the filter's innovation of the row against its own
prior and the variance it used (``S = H P- H^T + R``; 0 on a row the method excluded, as the update reports it).
Deleted residual ``w = asinh(v_i / sqrt(var_i red_i))``
of the epoch's snapshot weighted least-squares fit of the measurement type alone (4 unknowns: position and clock,
or velocity and drift; weights the receiver's reported variances ``var_i``; redundancy ``red_i = 1 - h_ii``;
Baarda's w-test statistic without the prior), computed on the filter's post-update residuals (a snapshot fit's
residuals do not depend on the linearization point to first order); 0 with fewer than 5 satellites of the type.
``asinh`` keeps the sign and compresses the outliers of NLOS satellites (100 sigma -> 5.3).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from nav_filters.kernels import serial_and_parallel
from nav_filters.measurements import MAX_PRN, channel_residuals

CHANNEL_HISTORY = 3
"""Updates of a satellite in its channel's features (the last and the two before)."""

STATIC_FEATURES = (
    # name, low, high, description
    ("cn0", 0.0, 1.5, "C/N0 [dB-Hz] / 50 the receiver reports at the coming epoch (0 where the data set has none)"),
    ("elevation", 0.0, 1.0, "elevation [rad] / (pi / 2) at the coming epoch"),
    ("sys_gps", 0.0, 1.0, "1 for a GPS satellite"),
    ("sys_glonass", 0.0, 1.0, "1 for a GLONASS satellite"),
    ("sys_galileo", 0.0, 1.0, "1 for a Galileo satellite"),
    ("sys_beidou", 0.0, 1.0, "1 for a BeiDou satellite"),
    ("sys_other", 0.0, 1.0, "1 for a QZSS or SBAS satellite"),
    ("tracked", 0.0, 5.0, "log10(1 + consecutive epochs the satellite was used, up to the last update); 0: new or "
                          "reacquired"),
    ("last_action", -1.0, 1.0, "the action applied to the satellite at its last update (the default action for a "
                               "new one)"),
)
LAGGED_FEATURES = (
    ("z_pr", -10.0, 10.0, "asinh of the pseudorange's normalized innovation dz_i / sqrt(S_ii) at that update (0 "
                          "where the method excluded the row, kf-fde / +fde: its deleted residual still shows it)"),
    ("z_prr", -10.0, 10.0, "the same for the pseudorange rate (0 without Doppler)"),
    ("w_pr", -10.0, 10.0, "asinh of the pseudorange's normalized deleted residual of the epoch's snapshot fit "
                          "(0 with fewer than 5 satellites)"),
    ("w_prr", -10.0, 10.0, "the same for the pseudorange rate (0 without Doppler)"),
    ("log_scale", -2.0, 6.0, "log10 of the law's variance scale of the satellite's pseudorange after that update "
                             "(per-satellite laws; 0 otherwise)"),
    ("cn0_then", 0.0, 1.5, "C/N0 [dB-Hz] / 50 at that update"),
)
N_STATIC = len(STATIC_FEATURES)
N_LAGGED = len(LAGGED_FEATURES)


def channel_feature_table() -> tuple:
    """``(name, low, high, description)`` of every per-channel feature in observation order."""
    out = list(STATIC_FEATURES)
    for lag in range(CHANNEL_HISTORY):
        out += [(f"{n}_l{lag}", lo, hi, d) for n, lo, hi, d in LAGGED_FEATURES]
    return tuple(out)


CHANNEL_FEATURES = channel_feature_table()
"""Per-channel features in observation order (module docstring)."""
N_CHANNEL_FEATURES = len(CHANNEL_FEATURES)

_SYSTEM_COLUMN = (2, 3, 4, 5, 6, 6)
"""One-hot column of each system index of :data:`nav_filters.measurements.SYSTEMS` (G R E C J S)."""
_SYS_COL = np.array(_SYSTEM_COLUMN, np.int64)


@nb.njit(cache=True, inline="always")
def _snapshot_fit(resid, u, var, use, off, C, w, A, g):
    """Normalized deleted residuals ``w`` (C,) of rows ``off .. off + C - 1`` of one batch row: the weighted
    least-squares fit of ``resid`` on ``[-u_i, 1]`` (4 unknowns) over the channels ``use`` with variances ``var``
    (scratch ``A`` (4, 4), ``g`` (4,)); 0 on unused channels, everywhere with fewer than 5 of them, and where a
    redundancy is not positive."""
    n = 0
    for i in range(C):
        w[i] = 0.0
        if use[i]:
            n += 1
    if n < 5:
        return
    for p in range(4):
        g[p] = 0.0
        for q in range(4):
            A[p, q] = 0.0
    for i in range(C):
        if use[i]:
            a0, a1, a2 = -u[i, 0], -u[i, 1], -u[i, 2]
            wi = 1.0 / var[i]
            r = resid[off + i]
            av = (a0, a1, a2, 1.0)
            for p in range(4):
                g[p] += wi * av[p] * r
                for q in range(4):
                    A[p, q] += wi * av[p] * av[q]
    # Cholesky A = L L^T in place (lower triangle); a degenerate geometry gives no statistic
    for p in range(4):
        s = A[p, p]
        for k in range(p):
            s -= A[p, k] * A[p, k]
        if not s > 0.0:
            return
        A[p, p] = math.sqrt(s)
        for q in range(p + 1, 4):
            t = A[q, p]
            for k in range(p):
                t -= A[q, k] * A[p, k]
            A[q, p] = t / A[p, p]
    # x = A^-1 g: forward then back substitution
    for p in range(4):
        t = g[p]
        for k in range(p):
            t -= A[p, k] * g[k]
        g[p] = t / A[p, p]
    for p in range(3, -1, -1):
        t = g[p]
        for k in range(p + 1, 4):
            t -= A[k, p] * g[k]
        g[p] = t / A[p, p]
    for i in range(C):
        if not use[i]:
            continue
        av = (-u[i, 0], -u[i, 1], -u[i, 2], 1.0)
        v = resid[off + i] - (av[0] * g[0] + av[1] * g[1] + av[2] * g[2] + av[3] * g[3])
        # h = a^T A^-1 a / var = |L^-1 a|^2 / var
        y0 = av[0] / A[0, 0]
        y1 = (av[1] - A[1, 0] * y0) / A[1, 1]
        y2 = (av[2] - A[2, 0] * y0 - A[2, 1] * y1) / A[2, 2]
        y3 = (av[3] - A[3, 0] * y0 - A[3, 1] * y1 - A[3, 2] * y2) / A[3, 3]
        red = 1.0 - (y0 * y0 + y1 * y1 + y2 * y2 + y3 * y3) / var[i]
        if red > 1e-9:
            w[i] = v / math.sqrt(var[i] * red)


def snapshot_deleted_residuals(resid, u, var, use):
    """Numpy specification of the deleted residuals of :func:`commit_channels` for one type of one batch row.

    Parameters
    ----------
    resid : (C,) residuals [m or m/s]; u : (C, 3) unit lines of sight; var : (C,) variances; use : (C,) bool.

    Returns
    -------
    (C,) normalized deleted residuals ``v_i / sqrt(var_i (1 - h_ii))`` of the fit on ``[-u_i, 1]`` (0 on unused
    channels and everywhere with fewer than 5 used).
    """
    out = np.zeros(resid.shape)
    idx = np.flatnonzero(use)
    if idx.size < 5:
        return out
    A = np.concatenate([-u[idx], np.ones((idx.size, 1))], 1)
    W = np.diag(1.0 / var[idx])
    N = A.T @ W @ A
    Ni = np.linalg.inv(N)
    v = resid[idx] - A @ (Ni @ (A.T @ W @ resid[idx]))
    red = 1.0 - np.einsum("ij,jk,ik->i", A, Ni, A) / var[idx]
    out[idx] = np.where(red > 1e-9, v / np.sqrt(var[idx] * np.maximum(red, 1e-300)), 0.0)
    return out


def _commit_rows(mask, keys, cn0, innov, S, resid, u, pr_var, prr_var, with_rate, scale, act, ch_keys, ch_hist,
                 ch_count, ch_act, nchunk):
    """Push every used channel's statistics of the epoch just updated onto its satellite's history (in place).

    Parameters
    ----------
    mask : (B, C) bool channels used in the update; keys : (B, C) int64 satellite keys; cn0 : (B, C) [dB-Hz].
    innov, S : (B, m) the update's innovations and their variances ``S_ii`` (rows ``[pr..., prr..., extra...]``).
    resid : (B, m_r) post-update residuals of the same rows (``gnss_innovations`` at the corrected state); u :
        (B, C, 3) lines of sight; pr_var, prr_var : (B, C) reported variances. with_rate : rate rows present.
    scale : (B, C) the law's pseudorange variance scale of each channel's satellite (1 without one).
    act : (B, C) the actions applied to the channels at this update.
    ch_keys (B, C) int64, ch_hist (B, C, L, 6), ch_count (B, C) int64, ch_act (B, C): the channel state, rewritten:
        channel i now holds its satellite (found by key among the previous state's channels, or new).
    """
    B, C = mask.shape
    for ch in nb.prange(nchunk):
        work = _commit_work(C, ch_hist.shape[2], ch_hist.shape[3])
        use = np.empty(C, np.bool_)
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            for i in range(C):
                use[i] = mask[b, i] and keys[b, i] >= 0
            _commit_row(b, use, keys[b], cn0[b], innov, S, resid[b], u[b], pr_var[b], prr_var[b], with_rate, scale,
                        act, ch_keys, ch_hist, ch_count, ch_act, work)


@nb.njit(cache=True, inline="always")
def _commit_work(C, L, D):
    """The scratch of :func:`_commit_row` (one per chunk of rows)."""
    return (np.empty(C, np.int64), np.empty((C, L, D)), np.empty(C, np.int64), np.empty(C), np.empty(C),
            np.empty((4, 4)), np.empty(4))


@nb.njit(cache=True, inline="always")
def _commit_row(b, use, keys, cn0, innov, S, resid, u, pr_var, prr_var, with_rate, scale, act, ch_keys, ch_hist,
                ch_count, ch_act, work):
    """Row ``b`` of :func:`_commit_rows`: ``use`` (C,) the channels used with a key, ``keys``, ``cn0`` (C,), ``resid``
    (m_r,), ``u`` (C, 3), ``pr_var``, ``prr_var`` (C,) that row's; the rest as there; ``work``
    (:func:`_commit_work`)."""
    old_keys, old_hist, old_count, w_pr, w_prr, A, g = work
    C = use.shape[0]
    L = ch_hist.shape[2]
    D = ch_hist.shape[3]
    for i in range(C):
        old_keys[i] = ch_keys[b, i]
        old_count[i] = ch_count[b, i]
        for lag in range(L):
            for f in range(D):
                old_hist[i, lag, f] = ch_hist[b, i, lag, f]
    _snapshot_fit(resid, u, pr_var, use, 0, C, w_pr, A, g)
    if with_rate:
        _snapshot_fit(resid, u, prr_var, use, C, C, w_prr, A, g)
    for i in range(C):
        key = keys[i] if use[i] else -1
        ch_keys[b, i] = key
        if key < 0:
            ch_count[b, i] = 0
            ch_act[b, i] = 0.0
            for lag in range(L):
                for f in range(D):
                    ch_hist[b, i, lag, f] = 0.0
            continue
        j = -1
        for q in range(C):
            if old_keys[q] == key:
                j = q
                break
        ch_count[b, i] = old_count[j] + 1 if j >= 0 else 1
        for lag in range(L - 1, 0, -1):
            for f in range(D):
                ch_hist[b, i, lag, f] = old_hist[j, lag - 1, f] if j >= 0 else 0.0
        z_pr = np.float64(innov[b, i]) / math.sqrt(np.float64(S[b, i]))
        z_prr = np.float64(innov[b, C + i]) / math.sqrt(np.float64(S[b, C + i])) if with_rate else 0.0
        ch_hist[b, i, 0, 0] = math.asinh(z_pr)
        ch_hist[b, i, 0, 1] = math.asinh(z_prr)
        ch_hist[b, i, 0, 2] = math.asinh(w_pr[i])
        ch_hist[b, i, 0, 3] = math.asinh(w_prr[i]) if with_rate else 0.0
        ch_hist[b, i, 0, 4] = math.log10(max(scale[b, i], 1e-12))
        ch_hist[b, i, 0, 5] = cn0[i] / 50.0
        ch_act[b, i] = act[b, i]


def _commit_epoch_rows(epoch, sat_keys, sat_cn0, sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, r, v, clk, drift,
                       mask, with_rate, innov, S, scale, act, ch_keys, ch_hist, ch_count, ch_act, nchunk):
    """:func:`_commit_rows` on an env core's world arrays at each row's updated epoch, forming that row's inputs
    itself with the arithmetic of the gathered inputs (the same bits, test): the epoch's keys, C/N0 and reported
    variances ``sigma^2``, and the post-update residuals and lines of sight that
    :func:`nav_filters.measurements.gnss_innovations` gives at the corrected state (its
    :func:`~nav_filters.measurements.channel_residuals`; residual 0 on unused channels). One call per
    step: no (B, C, ...) gathers, and no measurement matrix formed for nothing.

    Parameters
    ----------
    epoch : (B,) int64 the updated epoch of each row; sat_keys (B, M, C) int64, sat_cn0, pr, prr, pr_sigma,
    prr_sigma (B, M, C), sat_pos, sat_vel (B, M, C, 3): the world's epochs [m, m/s, dB-Hz]; r, v (B, 3), clk, drift
    (B,): the navigator's corrected position, velocity [m, m/s], clock bias and drift [m, m/s]; mask (B, C) bool
    the channels used; the rest as :func:`_commit_rows`.
    """
    B, C = mask.shape
    for ch in nb.prange(nchunk):
        work = _commit_work(C, ch_hist.shape[2], ch_hist.shape[3])
        use = np.empty(C, np.bool_)
        keys = np.empty(C, np.int64)
        resid = np.empty(2 * C if with_rate else C)
        u = np.empty((C, 3))
        uu = np.empty(3)
        pr_var = np.empty(C)
        prr_var = np.empty(C)
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            e = epoch[b]
            for i in range(C):
                e_pr, e_prr = channel_residuals(
                    sat_pos[b, e, i, 0], sat_pos[b, e, i, 1], sat_pos[b, e, i, 2], sat_vel[b, e, i, 0],
                    sat_vel[b, e, i, 1], sat_vel[b, e, i, 2], np.float64(r[b, 0]), np.float64(r[b, 1]),
                    np.float64(r[b, 2]), np.float64(v[b, 0]), np.float64(v[b, 1]), np.float64(v[b, 2]),
                    np.float64(clk[b]), np.float64(drift[b]), pr[b, e, i], prr[b, e, i], uu)
                m = mask[b, i]
                for k in range(3):
                    u[i, k] = uu[k]
                resid[i] = e_pr if m else 0.0
                sg = pr_sigma[b, e, i]
                pr_var[i] = sg * sg
                if with_rate:
                    resid[C + i] = e_prr if m else 0.0
                    sg = prr_sigma[b, e, i]
                    prr_var[i] = sg * sg
                else:
                    prr_var[i] = pr_var[i]
                keys[i] = sat_keys[b, e, i]
                use[i] = m and keys[i] >= 0
            _commit_row(b, use, keys, sat_cn0[b, e], innov, S, resid, u, pr_var, prr_var, with_rate, scale, act,
                        ch_keys, ch_hist, ch_count, ch_act, work)


commit_serial, commit_parallel = serial_and_parallel(_commit_rows)
commit_epoch_serial, commit_epoch_parallel = serial_and_parallel(_commit_epoch_rows)


def _observation_rows(rows, epoch, gmask, keys, cn0, el, ch_keys, ch_hist, ch_count, ch_act, default_action, lo, hi,
                      out, nchunk):
    """The per-channel features and the validity mask of the coming epoch's channels of ``rows`` into ``out``.

    Parameters
    ----------
    rows : (n,) int64 batch rows; epoch : (n,) int64 their coming epochs.
    gmask (B, M, C) bool, keys (B, M, C) int64, cn0 (B, M, C) [dB-Hz], el (B, M, C) [rad]: the world's channels.
    ch_keys, ch_hist, ch_count, ch_act : the channel state of :func:`_commit_rows` (read only).
    default_action : the action reported for a satellite without a last update.
    lo, hi : (F,) feature bounds (clipping; NaN -> 0).
    out : (n, C * F + C) float32: channel i's F features at ``i * F``, then the C mask values (1 used, 0 not).
    """
    n = rows.shape[0]
    C = gmask.shape[2]
    F = lo.shape[0]
    L = ch_hist.shape[2]
    D = ch_hist.shape[3]
    for ch in nb.prange(nchunk):
        f = np.empty(F)
        for r in range(ch * n // nchunk, (ch + 1) * n // nchunk):
            b = rows[r]
            e = epoch[r]
            for i in range(C):
                key = keys[b, e, i]
                valid = gmask[b, e, i] and key >= 0
                out[r, C * F + i] = 1.0 if valid else 0.0
                if not valid:
                    for k in range(F):
                        out[r, i * F + k] = 0.0
                    continue
                j = -1
                for q in range(C):
                    if ch_keys[b, q] == key:
                        j = q
                        break
                f[0] = cn0[b, e, i] / 50.0
                f[1] = el[b, e, i] / (0.5 * math.pi)
                for k in range(2, 7):
                    f[k] = 0.0
                f[_SYS_COL[key // MAX_PRN]] = 1.0
                f[7] = math.log10(1.0 + ch_count[b, j]) if j >= 0 else 0.0
                f[8] = ch_act[b, j] if j >= 0 else default_action
                for lag in range(L):
                    for k in range(D):
                        f[N_STATIC + lag * D + k] = ch_hist[b, j, lag, k] if j >= 0 else 0.0
                for k in range(F):
                    x = f[k]
                    if x != x:
                        x = 0.0
                    out[r, i * F + k] = min(max(x, np.float64(lo[k])), np.float64(hi[k]))


observation_serial, observation_parallel = serial_and_parallel(_observation_rows)

__all__ = ["CHANNEL_HISTORY", "STATIC_FEATURES", "LAGGED_FEATURES", "CHANNEL_FEATURES", "N_CHANNEL_FEATURES",
           "channel_feature_table", "snapshot_deleted_residuals", "commit_serial", "commit_parallel",
           "commit_epoch_serial", "commit_epoch_parallel", "observation_serial", "observation_parallel"]
