"""Broadcast ionosphere (Klobuchar) and troposphere (Saastamoinen) delay models for single-point positioning.

Klobuchar (IS-GPS-200 rev. N, sec 20.3.3.5.2.5, Figure 20-4; J. A. Klobuchar,
"Ionospheric time-delay algorithm for single-frequency GPS users", IEEE
Trans. AES 23(3), 1987). With the user's geodetic latitude ``phi_u`` and
longitude ``lambda_u``, the satellite elevation ``E`` and azimuth ``A`` (all
in semicircles except ``A``), and GPS time of week ``t_gps``::

    psi     = 0.0137 / (E + 0.11) - 0.022                    (Earth-centred angle)
    phi_i   = clip(phi_u + psi cos A, -0.416, 0.416)          (pierce-point latitude)
    lam_i   = lambda_u + psi sin A / cos(phi_i pi)
    phi_m   = phi_i + 0.064 cos((lam_i - 1.617) pi)          (geomagnetic latitude)
    t       = (4.32e4 lam_i + t_gps) mod 86400               (local time)
    F       = 1 + 16 (0.53 - E)^3                            (obliquity)
    AMP     = max(0, sum_n alpha_n phi_m^n),  PER = max(72000, sum_n beta_n phi_m^n)
    x       = 2 pi (t - 50400) / PER
    T_iono  = F [5e-9 + AMP (1 - x^2/2 + x^4/24)]  if |x| < 1.57,  else F 5e-9       [s, on L1]

scaled to another carrier ``f`` by ``(f_L1 / f)^2`` (first-order ionosphere).

Saastamoinen (J. Saastamoinen, "Atmospheric correction for the troposphere
and stratosphere in radio ranging of satellites", Geophys. Monogr. 15, AGU
1972; the zenith hydrostatic term with the gravity factor of Davis et al.,
Radio Sci. 20(6), 1985)::

    T_trop = 0.002277 / cos z * [ P / f(phi, h) + (1255 / T + 0.05) e ]               [m]
    f(phi, h) = 1 - 0.00266 cos 2 phi - 0.00028 h_km

(``z`` the zenith angle, ``P`` total pressure [hPa], ``T`` temperature [K],
``e`` water-vapour pressure [hPa]), with the surface meteorology of a standard
atmosphere at the user's height ``h`` (Berg 1948 as in the IERS conventions:
``P = 1013.25 (1 - 2.2557e-5 h)^5.2568``, ``T = 288.15 - 6.5e-3 h``, 50 %
relative humidity at 15 C and sea level decaying as ``exp(-6.396e-4 h)``,
``e = RH 6.11 * 10^(7.5 (T - 273.15) / (T - 35.85))`` (Magnus-Tetens)). The
``1/cos z`` mapping grows too fast near the horizon (3.5 % too large at 10
deg): apply an elevation mask of 10 deg or more.
"""
from __future__ import annotations

import numpy as np

from earth.wgs84 import C_LIGHT

__all__ = ["F_L1", "klobuchar_delay", "saastamoinen_delay", "standard_atmosphere"]

F_L1 = 1575.42e6
"""GPS L1 / Galileo E1 carrier [Hz]."""


def klobuchar_delay(alpha, beta, lat, lon, elevation, azimuth, t_gps, frequency_hz=F_L1) -> np.ndarray:
    """Klobuchar ionospheric group delay [m] (module docstring; IS-GPS-200 20.3.3.5.2.5).

    Parameters
    ----------
    alpha, beta : (4,) broadcast coefficients (alpha [s, s/sc, s/sc^2, s/sc^3], beta [s, ...]).
    lat, lon : (...) user geodetic latitude / longitude [rad].
    elevation, azimuth : (...) [rad].
    t_gps : (...) GPS time [s] (only its value modulo 86400 s matters).
    frequency_hz : (...) carrier [Hz].

    Returns
    -------
    (...) delay [m], > 0.
    """
    alpha = np.asarray(alpha, np.float64)
    beta = np.asarray(beta, np.float64)
    if alpha.shape != (4,) or beta.shape != (4,):
        raise ValueError(f"alpha and beta must have shape (4,), got {alpha.shape}, {beta.shape}")
    E = np.asarray(elevation, np.float64) / np.pi
    A = np.asarray(azimuth, np.float64)
    phi_u = np.asarray(lat, np.float64) / np.pi
    lam_u = np.asarray(lon, np.float64) / np.pi
    psi = 0.0137 / (E + 0.11) - 0.022
    phi_i = np.clip(phi_u + psi * np.cos(A), -0.416, 0.416)
    lam_i = lam_u + psi * np.sin(A) / np.cos(phi_i * np.pi)
    phi_m = phi_i + 0.064 * np.cos((lam_i - 1.617) * np.pi)
    t = np.mod(4.32e4 * lam_i + np.asarray(t_gps, np.float64), 86400.0)
    F = 1.0 + 16.0 * (0.53 - E) ** 3
    pw = np.stack([np.ones_like(phi_m), phi_m, phi_m ** 2, phi_m ** 3], -1)
    amp = np.maximum(pw @ alpha, 0.0)
    per = np.maximum(pw @ beta, 72000.0)
    x = 2.0 * np.pi * (t - 50400.0) / per
    T = np.where(np.abs(x) < 1.57, F * (5e-9 + amp * (1.0 - x * x / 2.0 + x ** 4 / 24.0)), F * 5e-9)
    return C_LIGHT * T * (F_L1 / np.asarray(frequency_hz, np.float64)) ** 2


def standard_atmosphere(h_m):
    """Surface pressure [hPa], temperature [K] and water-vapour pressure [hPa] at height ``h_m`` [m]."""
    h = np.clip(np.asarray(h_m, np.float64), -500.0, 9000.0)
    P = 1013.25 * (1.0 - 2.2557e-5 * h) ** 5.2568
    T = 288.15 - 6.5e-3 * h
    rh = 0.5 * np.exp(-6.396e-4 * h)
    e = rh * 6.11 * 10.0 ** (7.5 * (T - 273.15) / (T - 35.85))
    return P, T, e


def saastamoinen_delay(lat, h_m, elevation) -> np.ndarray:
    """Saastamoinen slant tropospheric delay [m] with a standard atmosphere (module docstring).

    Parameters
    ----------
    lat : (...) geodetic latitude [rad]; h_m : (...) ellipsoidal height [m]; elevation : (...) [rad], > 0.

    Returns
    -------
    (...) delay [m] (0 where the elevation is <= 0).
    """
    el = np.asarray(elevation, np.float64)
    P, T, e = standard_atmosphere(h_m)
    f = 1.0 - 0.00266 * np.cos(2.0 * np.asarray(lat, np.float64)) - 0.00028 * np.asarray(h_m, np.float64) / 1e3
    zen = 0.002277 * (P / f + (1255.0 / T + 0.05) * e)
    up = el > 0
    return np.where(up, zen / np.sin(np.where(up, el, 1.0)), 0.0)
