"""Compiled row kernels of the GNSS geometry stages (:func:`envs.sim.gnss_stages.sky_geometry` and
:func:`~envs.sim.gnss_stages.channel_ranging`).

Each kernel runs rows ``r0 .. r1-1`` in one pass without the GIL, so the stages run row ranges on threads
(:func:`envs.sim.row_threads.run_row_ranges`). They evaluate the same formulas in the same order as the numpy
chain they replace (:meth:`~envs.sim.constellation.Constellation.positions_velocities`, the line of sight of
Groves eq 8.36, :func:`earth.ranging.range_and_rate`), so the worlds stay the same bit for bit
(``tests/envs/test_geometry_kernels.py`` compares them with that chain).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from earth.ranging import range_rate_pair
from earth.wgs84 import C_LIGHT, OMEGA_IE

from .constellation import walker_point

_TWO_PI = 2.0 * np.pi


BELOW_HORIZON_EL = -0.5 * np.pi
"""The elevation :func:`sky_rows` reports for a satellite below the local horizon (its azimuth: 0) [rad]."""

_BELOW_MARGIN_M = 1.0e4
"""How far below the horizon plane [m] the line of sight computed without the Earth-rotation correction must point
for :func:`sky_rows` to skip that correction: the correction turns the satellite position about the z axis by
``OMEGA_IE tau``, which moves the vertical component by at most ``OMEGA_IE tau |r_s|``: 0.2 km for GPS (flight time
< 0.12 s, orbit radius 26 600 km), under 1 km for any orbit radius below 60 000 km."""


@nb.njit(cache=True, nogil=True)
def sky_rows(r0, r1, t_rx, r_e, sl, cl, so, co, cu0, su0, cr, sr, a, ci, si, n, t_tx, el, az):
    """Transmission time, elevation and azimuth of all satellites at every epoch of rows ``r0 .. r1-1``.

    Per satellite-epoch: the Walker orbit at the reception time (:func:`~envs.sim.constellation.walker_point`),
    the flight time ``tau = |r_s - r_r| / c`` (one light-time pass: < 0.5 us, < 2 mm of satellite motion),
    ``t_tx = t_rx - tau``, and the line of sight to ``C_z(OMEGA_IE tau) (r_s - v_s tau) - r_r`` (Groves eq 8.36
    with a first-order satellite back propagation) resolved in NED: ``h = cos(lon) d_x + sin(lon) d_y``,
    ``n = -sin(lat) h + cos(lat) d_z``, ``e = -sin(lon) d_x + cos(lon) d_y``, ``up = cos(lat) h + sin(lat) d_z``;
    ``el = atan2(up, hypot(n, e))``, ``az = atan2(e, n)`` wrapped to [0, 2 pi).

    A satellite below the horizon (``up < 0``, about 60% of them: never visible, the elevation mask is >= 0 deg)
    gets :data:`BELOW_HORIZON_EL` and azimuth 0 instead of its angles (lazily: no stage reads them but as
    "not visible", and every channel array of the world is the same bit for bit; ``t_tx`` is exact for all).
    One whose uncorrected line of sight points more than :data:`_BELOW_MARGIN_M` below the horizon plane skips
    the Earth-rotation correction too.

    Parameters
    ----------
    r0, r1 : the rows to evaluate.
    t_rx : (B, M) GPS reception time [s]; r_e : (B, M, 3) receiver ECEF position [m].
    sl, cl, so, co : (B, M) sin / cos of the receiver's latitude and longitude.
    cu0 .. n : :meth:`~envs.sim.constellation.Constellation.kernel_constants` (S satellites).
    t_tx, el, az : (B, M, S) outputs [s, rad, rad]; only rows ``r0 .. r1-1`` are written.
    """
    M = t_rx.shape[1]
    S = cu0.shape[0]
    for b in range(r0, r1):
        for j in range(M):
            t = t_rx[b, j]
            cnt, snt = np.cos(n * t), np.sin(n * t)
            cwt, swt = np.cos(OMEGA_IE * t), np.sin(OMEGA_IE * t)
            rx, ry, rz = r_e[b, j, 0], r_e[b, j, 1], r_e[b, j, 2]
            for k in range(S):
                x, y, z, vx, vy, vz = walker_point(cnt, snt, cwt, swt, cu0[k], su0[k], cr[k], sr[k], a, ci, si, n)
                dx, dy, dz = x - rx, y - ry, z - rz
                # (x^2 + z^2) + y^2: the order in which numpy's einsum("...i,...i") summed the squares in the
                # numpy chain this kernel replaced (its two-lane inner loop), so the worlds keep their bits
                tau = math.sqrt((dx * dx + dz * dz) + dy * dy) / C_LIGHT
                t_tx[b, j, k] = t - tau
                px, py, pz = x - vx * tau, y - vy * tau, z - vz * tau
                ez = pz - rz
                if cl[b, j] * (co[b, j] * (px - rx) + so[b, j] * (py - ry)) + sl[b, j] * ez < -_BELOW_MARGIN_M:
                    el[b, j, k] = BELOW_HORIZON_EL
                    az[b, j, k] = 0.0
                    continue
                th = OMEGA_IE * tau
                c, s = np.cos(th), np.sin(th)
                ex = c * px + s * py - rx
                ey = -s * px + c * py - ry
                h1 = co[b, j] * ex + so[b, j] * ey
                up = cl[b, j] * h1 + sl[b, j] * ez
                if up < 0.0:
                    el[b, j, k] = BELOW_HORIZON_EL
                    az[b, j, k] = 0.0
                    continue
                nn = -sl[b, j] * h1 + cl[b, j] * ez
                ee = -so[b, j] * ex + co[b, j] * ey
                el[b, j, k] = math.atan2(up, math.hypot(nn, ee))
                w = math.atan2(ee, nn)
                az[b, j, k] = w + _TWO_PI if w < 0.0 else w + 0.0


@nb.njit(cache=True, nogil=True)
def ranging_rows(r0, r1, t_tx, sel, mask, r_e, v_e, cu0, su0, cr, sr, a, ci, si, n, sat_pos, sat_vel, rho,
                 rho_dot):
    """Ephemeris at transmission time and true range / rate on the tracked channels of rows ``r0 .. r1-1``.

    Per tracked channel: the Walker orbit of satellite ``sel`` at its transmission time ``t_tx``
    (:func:`~envs.sim.constellation.walker_point`), then range and rate with the Sagnac correction
    (Groves eqs 8.36, 8.46; :func:`earth.ranging.range_rate_pair`, 3 light-time iterations). Channels not
    tracked get zeros.

    Parameters
    ----------
    r0, r1 : the rows to evaluate.
    t_tx : (B, M, C) transmission time of each channel's satellite [s]; sel : (B, M, C) its index (0 .. T-1);
    mask : (B, M, C) bool, tracked.
    r_e, v_e : (B, M, 3) receiver ECEF position [m] / velocity [m/s].
    cu0 .. n : :meth:`~envs.sim.constellation.Constellation.kernel_constants`.
    sat_pos, sat_vel : (B, M, C, 3) outputs [m, m/s]; rho, rho_dot : (B, M, C) outputs [m, m/s].
    """
    M, C = mask.shape[1], mask.shape[2]
    u = np.empty(3)
    for b in range(r0, r1):
        for j in range(M):
            for k in range(C):
                if not mask[b, j, k]:
                    for c in range(3):
                        sat_pos[b, j, k, c] = 0.0
                        sat_vel[b, j, k, c] = 0.0
                    rho[b, j, k] = 0.0
                    rho_dot[b, j, k] = 0.0
                    continue
                t = t_tx[b, j, k]
                i = sel[b, j, k]
                x, y, z, vx, vy, vz = walker_point(np.cos(n * t), np.sin(n * t), np.cos(OMEGA_IE * t),
                                                   np.sin(OMEGA_IE * t), cu0[i], su0[i], cr[i], sr[i], a, ci, si, n)
                sat_pos[b, j, k, 0], sat_pos[b, j, k, 1], sat_pos[b, j, k, 2] = x, y, z
                sat_vel[b, j, k, 0], sat_vel[b, j, k, 1], sat_vel[b, j, k, 2] = vx, vy, vz
                rho[b, j, k], rho_dot[b, j, k] = range_rate_pair(
                    x, y, z, vx, vy, vz, r_e[b, j, 0], r_e[b, j, 1], r_e[b, j, 2], v_e[b, j, 0], v_e[b, j, 1],
                    v_e[b, j, 2], 3, u)


@nb.njit(cache=True, nogil=True)
def channel_order_rows(r0, r1, visible, el, sel):
    """The satellites on the C channels of rows ``r0 .. r1-1`` (:func:`envs.sim.gnss_stages.allocate_channels`):
    per epoch the visible satellites by elevation, descending, then the others, each group in index order where
    it ties, the first C of them (index 0 on the channels beyond S). The permutation of numpy's
    ``argsort(-where(visible, el, -inf), kind="stable")`` (one insertion sort of at most S entries per epoch,
    without numpy's per-epoch call).

    Parameters
    ----------
    r0, r1 : the rows to evaluate; visible : (B, M, S) bool; el : (B, M, S) elevation [rad];
    sel : (B, M, C) int output (only rows ``r0 .. r1-1`` are written).
    """
    M, S = el.shape[1], el.shape[2]
    C = sel.shape[2]
    idx = np.empty(S, np.int64)
    for b in range(r0, r1):
        for j in range(M):
            nv = 0
            for k in range(S):
                if visible[b, j, k]:
                    e = el[b, j, k]
                    p = nv
                    while p > 0 and el[b, j, idx[p - 1]] < e:   # strictly lower: a tie keeps the index order
                        idx[p] = idx[p - 1]
                        p -= 1
                    idx[p] = k
                    nv += 1
            q = nv
            for k in range(S):
                if not visible[b, j, k]:
                    idx[q] = k
                    q += 1
            for c in range(C):
                sel[b, j, c] = idx[c] if c < S else 0
