"""Earth model, frames, rotations and units shared by the truth and the estimator.

This is navgym's bottom layer: ``envs.sim`` (the simulated world) and
``nav_filters`` (the estimator) both import it, and it imports nothing of
navgym. Keeping the WGS84 ellipsoid and the gravity model in one place is what
makes the simulated IMU *consistent* with the INS mechanization.

Frames and units (fixed once for the whole project)
---------------------------------------------------
* ``i`` inertial, ``e`` ECEF (WGS84; the navigation frame of the filters),
  ``n`` local **NED** (north, east, down), ``b`` body **FRD** (x forward,
  y right, z down).
* ``v_e`` is a vector resolved in frame ``e``; ``C_eb`` rotates ``b`` -> ``e``.
* SI units everywhere, angles in radians. Data-sheet units (deg, deg/h,
  deg/sqrt(h), mg, ug) only at the edges via :mod:`earth.units`.
"""
from .numba_cache import invalidate_stale_caches

invalidate_stale_caches()  # before any kernel can load a cache compiled from older sources (see numba_cache)

from . import rotations, units, wgs84  # noqa: E402
from .rotations import dcm_from_euler, euler_from_dcm, exp_so3, log_so3, skew
from .wgs84 import (
    C_LIGHT,
    OMEGA_IE,
    OMEGA_IE_E,
    C_en,
    ecef_to_geodetic,
    geodetic_to_ecef,
    gravity_ecef,
    radii,
)

__all__ = [
    "rotations", "units", "wgs84", "skew", "exp_so3", "log_so3", "dcm_from_euler", "euler_from_dcm",
    "C_LIGHT", "OMEGA_IE", "OMEGA_IE_E", "C_en", "ecef_to_geodetic", "geodetic_to_ecef", "gravity_ecef", "radii",
]
