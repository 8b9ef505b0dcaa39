"""WGS84 ellipsoid, Earth rotation, gravity and frame conversions (batched).

Frames: ``e`` = ECEF (WGS84), ``n`` = local NED (north, east, down) at a
geodetic latitude/longitude. Geodetic latitude ``lat`` and longitude ``lon``
in radians, ellipsoidal height ``h`` in metres.

References: NIMA TR8350.2 (WGS84 constants); P. D. Groves, *Principles of
GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed.,
eqs 2.95-2.96 (radii), 2.112-2.113 (geodetic <-> ECEF), 2.142 (J2 gravitation).
"""
from __future__ import annotations

import numba as nb
import numpy as np

A = 6378137.0
"""Semi-major axis [m]."""
F = 1.0 / 298.257223563
"""Flattening."""
E2 = F * (2.0 - F)
"""First eccentricity squared."""
B_AXIS = A * (1.0 - F)
"""Semi-minor axis [m]."""
OMEGA_IE = 7.292115e-5
"""Earth rotation rate [rad/s] (also Table 1 of seed paper 000)."""
GM = 3.986004418e14
"""Earth gravitational constant [m^3/s^2]."""
J2 = 1.082627e-3
"""Second zonal harmonic."""
C_LIGHT = 299792458.0
"""Speed of light [m/s]."""

OMEGA_IE_E = np.array([0.0, 0.0, OMEGA_IE])
"""Earth rotation vector in ECEF [rad/s], shape (3,)."""


def radii(lat):
    """Meridian and transverse radii of curvature (Groves eqs 2.105-2.106).

    Parameters
    ----------
    lat : (...) geodetic latitude [rad]

    Returns
    -------
    R_M, R_N : (...) [m]
    """
    s2 = np.sin(lat) ** 2
    den = 1.0 - E2 * s2
    return A * (1.0 - E2) / den**1.5, A / np.sqrt(den)


def _transverse_radius(lat):
    """R_N of :func:`radii` alone (Groves eq 2.106), by the same operations: the conversions need no R_M (whose
    power ``den**1.5`` costs as much as the rest)."""
    return A / np.sqrt(1.0 - E2 * np.sin(lat) ** 2)


def geodetic_to_ecef(lat, lon, h):
    """Geodetic -> ECEF position (Groves eq 2.112).

    Parameters
    ----------
    lat, lon : (...) [rad]
    h : (...) ellipsoidal height [m]

    Returns
    -------
    r_e : (..., 3) [m]
    """
    lat, lon, h = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float), np.asarray(h, float))
    RN = _transverse_radius(lat)
    cl = np.cos(lat)
    return np.stack([(RN + h) * cl * np.cos(lon), (RN + h) * cl * np.sin(lon), ((1.0 - E2) * RN + h) * np.sin(lat)], -1)


def ecef_to_geodetic(r_e):
    """ECEF -> geodetic (Bowring's iteration, 4 passes: < 1e-9 m on Earth's surface).

    Parameters
    ----------
    r_e : (..., 3) [m]

    Returns
    -------
    lat, lon, h : (...) [rad, rad, m]
    """
    r_e = np.asarray(r_e, dtype=float)
    x, y, z = r_e[..., 0], r_e[..., 1], r_e[..., 2]
    p = np.hypot(x, y)
    lon = np.arctan2(y, x)
    lat = np.arctan2(z, p * (1.0 - E2))
    for _ in range(4):
        RN = _transverse_radius(lat)
        cl = np.cos(lat)
        h = np.where(np.abs(cl) > 1e-9, p / cl - RN, np.abs(z) - B_AXIS)
        lat = np.arctan2(z, p * (1.0 - E2 * RN / (RN + h)))
    RN = _transverse_radius(lat)
    cl, sl = np.cos(lat), np.sin(lat)
    h = p * cl + z * sl - A * A / RN
    return lat, lon, h


def C_en(lat, lon):
    """Rotation NED -> ECEF at (lat, lon) [rad], shape (..., 3, 3) (Groves eq 2.150 transposed)."""
    lat, lon = np.broadcast_arrays(np.asarray(lat, float), np.asarray(lon, float))
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    z = np.zeros_like(lat)
    C_ne = np.stack([
        np.stack([-sl * co, -sl * so, cl], -1),
        np.stack([-so, co, z], -1),
        np.stack([-cl * co, -cl * so, -sl], -1),
    ], -2)
    return np.swapaxes(C_ne, -1, -2)


def gravitation_ecef(r_e):
    """Gravitational acceleration (mass attraction only) with J2, ECEF (Groves eq 2.142).

    Parameters
    ----------
    r_e : (..., 3) [m]

    Returns
    -------
    (..., 3) [m/s^2], same dtype as ``r_e``.
    """
    r_e = np.asarray(r_e)
    r2 = np.sum(r_e * r_e, axis=-1, keepdims=True)
    r = np.sqrt(r2)
    zr2 = (r_e[..., 2:3] ** 2) / r2
    k = 1.5 * J2 * (A * A) / r2
    fac = np.concatenate([1.0 + k * (1.0 - 5.0 * zr2), 1.0 + k * (1.0 - 5.0 * zr2), 1.0 + k * (3.0 - 5.0 * zr2)], -1)
    return (-GM / (r2 * r)) * r_e * fac


_K_J2 = 1.5 * J2 * (A * A)
"""``1.5 J2 a^2`` [m^2], the J2 factor's constant as :func:`gravitation_ecef` forms it."""


@nb.njit(cache=True, nogil=True)
def _gravity_rows(r, out):
    """:func:`gravity_ecef` of the points ``r`` (n, 3) float64 into ``out`` (n, 3), point by point in the order of
    operations of numpy's evaluation of :func:`gravitation_ecef` plus the centrifugal term (no fastmath: the
    same roundings, the same bits): ``r^2 = (x^2 + y^2) + z^2`` (numpy's sum of three), ``k = 1.5 J2 a^2 / r^2``,
    ``c = -GM / (r^2 r)``, ``g_x = (c x)(1 + k (1 - 5 z^2 / r^2)) + w^2 x``, ``g_z = (c z)(1 + k (3 - 5 z^2 /
    r^2)) + 0`` (Groves eqs 2.133, 2.142)."""
    w2 = OMEGA_IE * OMEGA_IE
    for i in range(r.shape[0]):
        x, y, z = r[i, 0], r[i, 1], r[i, 2]
        r2 = (x * x + y * y) + z * z
        zr2 = (z * z) / r2
        k = _K_J2 / r2
        c = -GM / (r2 * np.sqrt(r2))
        fxy = 1.0 + k * (1.0 - 5.0 * zr2)
        out[i, 0] = c * x * fxy + w2 * x
        out[i, 1] = c * y * fxy + w2 * y
        out[i, 2] = c * z * (1.0 + k * (3.0 - 5.0 * zr2)) + 0.0


def gravity_ecef(r_e):
    """Gravity = gravitation + centrifugal, ECEF (Groves eq 2.133): ``g = gamma - Omega Omega r``.

    This is the ``g`` of the ECEF mechanization ``a_e = C_eb f_b + g_e - 2 Omega_ie v_e``
    and of the truth generator; both use this one function. A float64 input is evaluated by the compiled
    :func:`_gravity_rows` (one pass, no temporaries, the GIL released): the same bits as the numpy form, which
    evaluates any other dtype.

    Parameters
    ----------
    r_e : (..., 3) [m]

    Returns
    -------
    (..., 3) [m/s^2]
    """
    r_e = np.asarray(r_e)
    if r_e.dtype == np.float64 and r_e.ndim >= 1 and r_e.shape[-1] == 3:
        flat = np.ascontiguousarray(r_e).reshape(-1, 3)
        out = np.empty_like(flat)
        _gravity_rows(flat, out)
        return out.reshape(r_e.shape)
    g = gravitation_ecef(r_e)
    w2 = OMEGA_IE * OMEGA_IE
    cent = np.zeros_like(g)
    cent[..., 0] = w2 * r_e[..., 0]
    cent[..., 1] = w2 * r_e[..., 1]
    return g + cent


def ned_to_ecef_vector(v_n, lat, lon):
    """Rotate NED vectors to ECEF: (..., 3) -> (..., 3)."""
    return (C_en(lat, lon) @ np.asarray(v_n)[..., None])[..., 0]


def ecef_to_ned_vector(v_e, lat, lon):
    """Rotate ECEF vectors to NED: (..., 3) -> (..., 3)."""
    return (np.swapaxes(C_en(lat, lon), -1, -2) @ np.asarray(v_e)[..., None])[..., 0]
