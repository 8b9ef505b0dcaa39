"""Unit conversions used only at the edges (scenario presets, printed tables).

Inside navgym everything is SI with angles in radians. These named helpers turn
the units of data sheets into SI so that a preset reads like its data sheet::

    gyro_bias = dph(8.0)        # 8 deg/h      -> rad/s
    arw = dpsh(0.2)             # 0.2 deg/sqrt(h) -> rad/sqrt(s)
    accel_bias = mg(0.05)       # 0.05 mg      -> m/s^2
    vrw = ugpsh(700.0)          # 700 ug/sqrt(h)-> m/s/sqrt(s)
"""
from __future__ import annotations

import numpy as np

G0 = 9.80665
"""Standard gravity [m/s^2], the 'g' of mg and ug."""

DEG = np.pi / 180.0
"""One degree in radians."""


def deg(x):
    """Degrees -> radians."""
    return np.asarray(x, dtype=float) * DEG if np.ndim(x) else float(x) * DEG


def to_deg(x):
    """Radians -> degrees."""
    return np.asarray(x, dtype=float) / DEG if np.ndim(x) else float(x) / DEG


def dph(x):
    """deg/h -> rad/s (gyro bias, bias instability)."""
    return deg(x) / 3600.0


def dpsh(x):
    """deg/sqrt(h) -> rad/sqrt(s) (gyro angle random walk)."""
    return deg(x) / 60.0


def mg(x):
    """milli-g -> m/s^2 (accelerometer bias)."""
    return np.asarray(x, dtype=float) * 1e-3 * G0 if np.ndim(x) else float(x) * 1e-3 * G0


def ug(x):
    """micro-g -> m/s^2."""
    return np.asarray(x, dtype=float) * 1e-6 * G0 if np.ndim(x) else float(x) * 1e-6 * G0


def ugpsh(x):
    """micro-g/sqrt(h) -> m/s/sqrt(s) (velocity random walk as ug/sqrt(h))."""
    return ug(x) / 60.0


def ugpshz(x):
    """micro-g/sqrt(Hz) -> m/s/sqrt(s) (velocity random walk as a noise density)."""
    return ug(x)


def mpsph(x):
    """m/s/sqrt(h) -> m/s/sqrt(s) (velocity random walk)."""
    return np.asarray(x, dtype=float) / 60.0 if np.ndim(x) else float(x) / 60.0


def ppm(x):
    """parts per million -> dimensionless fraction (scale factor)."""
    return np.asarray(x, dtype=float) * 1e-6 if np.ndim(x) else float(x) * 1e-6
