"""GNSS ranging geometry with the Earth-rotation (Sagnac) correction, batched.

The simulated receiver uses it to make true ranges and the tightly coupled
filter uses it to predict them from the INS; one function for both.

Satellite positions/velocities are given as a broadcast ephemeris would give
them: ECEF at the *transmission* time. The signal flies for ``tau = rho / c``
during which the ECEF frame turns by ``OMEGA_IE * tau``; the satellite
position resolved in the ECEF frame at the *reception* time is
``C_z(OMEGA_IE tau) r_s`` (Groves eq 8.36)::

    rho     = | C_z(w tau) r_s - r_r |                                   (Groves 8.36)
    rho_dot = u^T [C_z(w tau) (v_s + Omega r_s) - (v_r + Omega r_r)]      (Groves 8.46)

with ``u`` the unit line of sight from receiver to satellite and ``Omega`` the
skew matrix of the Earth rate. The light-time equation is solved by fixed-point
iteration (3 passes: error < 1e-9 m for GNSS orbits).
"""
from __future__ import annotations

import numba as nb
import numpy as np

from .wgs84 import C_LIGHT, OMEGA_IE


def range_and_rate(sat_pos, sat_vel, rx_pos, rx_vel, iterations: int = 3):
    """Geometric range, range rate and line of sight with the Sagnac correction.

    Parameters
    ----------
    sat_pos, sat_vel : (..., S, 3) satellite ECEF position [m] / velocity [m/s] at transmission time.
    rx_pos, rx_vel : (..., 3) receiver ECEF position [m] / velocity [m/s] at reception time
        (broadcast against the satellite axis S).
    iterations : light-time iterations.

    Returns
    -------
    rho : (..., S) geometric range [m]
    rho_dot : (..., S) range rate [m/s]
    u : (..., S, 3) unit line of sight receiver -> satellite, ECEF at reception time.
    """
    sat_pos = np.asarray(sat_pos)
    sat_vel = np.asarray(sat_vel)
    rp = np.asarray(rx_pos)[..., None, :]
    rv = np.asarray(rx_vel)[..., None, :]
    # the light-time iterations run on the components (no stacked temporaries); the sum of squares
    # is added in np.sum's order, so rho equals np.sqrt(np.sum(d * d, -1)) bit for bit
    sx, sy = sat_pos[..., 0], sat_pos[..., 1]
    rx, ry = rp[..., 0], rp[..., 1]
    dx, dy, dz = sx - rx, sy - ry, sat_pos[..., 2] - rp[..., 2]
    dz2 = dz * dz
    rho = np.sqrt(dx * dx + dy * dy + dz2)
    for _ in range(iterations):
        theta = OMEGA_IE * rho / C_LIGHT
        c, s = np.cos(theta), np.sin(theta)
        dx = c * sx + s * sy - rx                       # C_z(theta) r_s - r_r (the z row is unchanged)
        dy = -s * sx + c * sy - ry
        rho = np.sqrt(dx * dx + dy * dy + dz2)
    theta = OMEGA_IE * rho / C_LIGHT
    c, s = np.cos(theta), np.sin(theta)
    u = np.stack([dx, dy, dz], -1) / rho[..., None]
    # C_z(theta) (v_s + Omega x r_s) - (v_r + Omega x r_r), per component; Omega x r has a zero z
    # component (added as a zero of r's dtype, as the full vector sum would)
    wx = sat_vel[..., 0] + -OMEGA_IE * sy
    wy = sat_vel[..., 1] + OMEGA_IE * sx
    wz = sat_vel[..., 2] + np.zeros((), sat_pos.dtype)
    dvx = (c * wx + s * wy) - (rv[..., 0] + -OMEGA_IE * ry)
    dvy = (-s * wx + c * wy) - (rv[..., 1] + OMEGA_IE * rx)
    dvz = wz - (rv[..., 2] + np.zeros((), rp.dtype))
    # u^T dv summed in np.sum's order (it starts from +0.0)
    rho_dot = u[..., 0] * dvx + 0.0 + u[..., 1] * dvy + u[..., 2] * dvz
    return rho, rho_dot, u


@nb.njit(cache=True)
def range_rate_pair(sx, sy, sz, svx, svy, svz, rx, ry, rz, rvx, rvy, rvz, iterations, u):
    """Compiled :func:`range_and_rate` for one receiver / satellite pair (same equations, same order).

    The scalar form that compiled measurement kernels call per channel (Groves eqs 8.36, 8.46); the
    numpy :func:`range_and_rate` stays the reference (agreement test in ``tests/earth``).

    Parameters
    ----------
    sx, sy, sz, svx, svy, svz : satellite ECEF position [m] / velocity [m/s] at transmission time.
    rx, ry, rz, rvx, rvy, rvz : receiver ECEF position [m] / velocity [m/s] at reception time.
    iterations : light-time iterations (3 in the navigator).
    u : (3,) output, unit line of sight receiver -> satellite (ECEF at reception time).

    Returns
    -------
    rho : geometric range [m]; rho_dot : range rate [m/s].
    """
    dx = sx - rx
    dy = sy - ry
    dz = sz - rz
    rho = np.sqrt(dx * dx + dy * dy + dz * dz)
    for _ in range(iterations):
        theta = OMEGA_IE * rho / C_LIGHT
        c = np.cos(theta)
        s = np.sin(theta)
        dx = (c * sx + s * sy) - rx
        dy = (-s * sx + c * sy) - ry
        dz = sz - rz
        rho = np.sqrt(dx * dx + dy * dy + dz * dz)
    theta = OMEGA_IE * rho / C_LIGHT
    c = np.cos(theta)
    s = np.sin(theta)
    u[0] = dx / rho
    u[1] = dy / rho
    u[2] = dz / rho
    # v_s + Omega x r_s, rotated by C_z(theta); v_r + Omega x r_r
    wx = svx + -OMEGA_IE * sy
    wy = svy + OMEGA_IE * sx
    wz = svz + 0.0
    vsx = c * wx + s * wy
    vsy = -s * wx + c * wy
    vrx = rvx + -OMEGA_IE * ry
    vry = rvy + OMEGA_IE * rx
    vrz = rvz + 0.0
    rho_dot = u[0] * (vsx - vrx) + u[1] * (vsy - vry) + u[2] * (wz - vrz)
    return rho, rho_dot
