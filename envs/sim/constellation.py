"""A GPS-like Walker constellation of circular orbits, ECEF positions and velocities.

The simulated sky: ``n_planes`` equally spaced orbital planes of
``sats_per_plane`` satellites each on circular orbits of the GPS nominal
semi-major axis (IS-GPS-200 nominal orbit: A = 26 559.7 km, i = 55 deg),
arranged as a Walker delta pattern ``i : T/P/F`` (J. G. Walker, "Satellite
constellations", J. Brit. Interplanetary Soc. 37, 1984): plane ``p`` has right
ascension of the ascending node ``Omega_p = Omega_0 + 2 pi p / P`` and its
``k``-th satellite the argument of latitude at ``t = 0``
``u_pk = u_0 + 2 pi k / S_p + 2 pi F p / T``.

The ECI and ECEF frames coincide at GPS time ``t = 0``; the ECEF position at
time ``t`` is the inertial one rotated by ``C_z(OMEGA_IE t)`` and the ECEF
velocity carries the transport term ``- Omega_ie x r_e`` (the IS-GPS-200
Table 20-IV user algorithm with e = 0 and no harmonic corrections, as in
Groves 2nd ed. ch. 8: eccentric anomaly = mean anomaly).

Satellites are identified by their index ``0 .. S-1`` (``prn = index + 1``),
plane-major: index ``p * sats_per_plane + k``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numba as nb
import numpy as np

from earth.wgs84 import A as EARTH_A
from earth.wgs84 import GM, OMEGA_IE


def _check_real(owner: str, name: str, value, *, lo=None, hi=None, lo_open=False) -> None:
    """Raise ``ValueError`` naming ``owner.name`` unless ``value`` is a finite real inside the bounds."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{owner}.{name} must be a real number, got {value!r}")
    if not math.isfinite(float(value)):
        raise ValueError(f"{owner}.{name} must be finite, got {value!r}")
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ValueError(f"{owner}.{name} must be {'>' if lo_open else '>='} {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ValueError(f"{owner}.{name} must be <= {hi}, got {value!r}")


def _check_pair(owner: str, name: str, value, *, lo=0.0, lo_open=False) -> None:
    """A (min, max) pair of finite reals with lo <= min <= max."""
    if not isinstance(value, tuple) or len(value) != 2:
        raise ValueError(f"{owner}.{name} must be a (min, max) tuple, got {value!r}")
    _check_real(owner, f"{name}[0]", value[0], lo=lo, lo_open=lo_open)
    _check_real(owner, f"{name}[1]", value[1], lo=lo, lo_open=lo_open)
    if value[1] < value[0]:
        raise ValueError(f"{owner}.{name}: max < min in {value!r}")


def _check_int(owner: str, name: str, value, *, lo=None, hi=None) -> None:
    """Raise ``ValueError`` naming ``owner.name`` unless ``value`` is an int inside the bounds."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{owner}.{name} must be an int, got {value!r}")
    if lo is not None and value < lo:
        raise ValueError(f"{owner}.{name} must be >= {lo}, got {value!r}")
    if hi is not None and value > hi:
        raise ValueError(f"{owner}.{name} must be <= {hi}, got {value!r}")


@dataclass(frozen=True)
class Constellation:
    """GPS-like Walker-delta constellation of circular orbits.

    Parameters
    ----------
    n_planes : int
        Number of orbital planes P (GPS: 6).
    sats_per_plane : int
        Satellites per plane; the total is ``T = n_planes * sats_per_plane``
        (default 5 -> 30 satellites, about today's operational GPS count).
    inclination_deg : float
        Orbit inclination [deg], in [0, 180] (GPS nominal 55).
    semi_major_axis_m : float
        Orbit radius [m] (circular orbits); must exceed the Earth's equatorial
        radius (IS-GPS-200 nominal 26 559 700 m).
    phasing : int
        Walker phasing factor F in ``0 .. n_planes-1``: the in-plane phase offset
        between adjacent planes is ``2 pi F / T``.
    raan0_deg : float
        Right ascension of the ascending node of plane 0 at t = 0 [deg].
    arg_lat0_deg : float
        Argument of latitude of satellite 0 at t = 0 [deg].

    Notes
    -----
    The gravitational constant is WGS84's ``earth.wgs84.GM`` (IS-GPS-200 uses
    3.986005e14 m^3/s^2; the difference moves a satellite by ~2 mm/s).
    """

    n_planes: int = 6
    sats_per_plane: int = 5
    inclination_deg: float = 55.0
    semi_major_axis_m: float = 26_559_700.0
    phasing: int = 1
    raan0_deg: float = 0.0
    arg_lat0_deg: float = 0.0

    def __post_init__(self):
        o = "Constellation"
        _check_int(o, "n_planes", self.n_planes, lo=1)
        _check_int(o, "sats_per_plane", self.sats_per_plane, lo=1)
        _check_real(o, "inclination_deg", self.inclination_deg, lo=0.0, hi=180.0)
        _check_real(o, "semi_major_axis_m", self.semi_major_axis_m, lo=EARTH_A, lo_open=True)
        _check_int(o, "phasing", self.phasing, lo=0, hi=self.n_planes - 1)
        _check_real(o, "raan0_deg", self.raan0_deg)
        _check_real(o, "arg_lat0_deg", self.arg_lat0_deg)

    # ------------------------------------------------------------------ derived
    @property
    def n_sats(self) -> int:
        """Total number of satellites T = n_planes * sats_per_plane."""
        return self.n_planes * self.sats_per_plane

    @property
    def mean_motion(self) -> float:
        """Mean motion ``n = sqrt(GM / a^3)`` [rad/s] (Kepler's third law)."""
        return math.sqrt(GM / self.semi_major_axis_m**3)

    @property
    def orbital_speed(self) -> float:
        """Inertial speed of a circular orbit ``sqrt(GM / a)`` [m/s] (~3874 m/s for GPS)."""
        return math.sqrt(GM / self.semi_major_axis_m)

    @property
    def period_s(self) -> float:
        """Orbital period ``2 pi / n`` [s] (~11 h 58 min for GPS)."""
        return 2.0 * math.pi / self.mean_motion

    @property
    def prn(self) -> np.ndarray:
        """PRN numbers ``1 .. T`` of the satellites, shape (T,)."""
        return np.arange(1, self.n_sats + 1)

    def _elements(self):
        """Per-satellite RAAN [rad] and argument of latitude at t = 0 [rad], shapes (T,) (Walker delta)."""
        P, Sp, T = self.n_planes, self.sats_per_plane, self.n_sats
        p = np.repeat(np.arange(P), Sp)
        k = np.tile(np.arange(Sp), P)
        raan = np.deg2rad(self.raan0_deg) + 2.0 * np.pi * p / P
        u0 = np.deg2rad(self.arg_lat0_deg) + 2.0 * np.pi * k / Sp + 2.0 * np.pi * self.phasing * p / T
        return raan, u0

    @cached_property
    def _satellite_trig(self) -> np.ndarray:
        """(4, T) read-only ``cos u0, sin u0, cos RAAN, sin RAAN`` of the satellites (computed once per instance)."""
        raan, u0 = self._elements()
        trig = np.stack([np.cos(u0), np.sin(u0), np.cos(raan), np.sin(raan)])
        trig.setflags(write=False)
        return trig

    def kernel_constants(self) -> tuple:
        """The satellite arrays and orbit constants of :func:`walker_point`: ``(cu0, su0, cr, sr, a, ci, si, n)``
        (the first four (T,) read-only, from :attr:`_satellite_trig`)."""
        inc = np.deg2rad(self.inclination_deg)
        return (*self._satellite_trig, self.semi_major_axis_m, math.cos(inc), math.sin(inc), self.mean_motion)

    # ---------------------------------------------------------------- positions
    def positions_velocities(self, t_gps, sat_index=None):
        """Satellite ECEF positions and velocities at GPS time ``t_gps``.

        Circular Keplerian orbit in the inertial frame rotated into ECEF
        (Groves 2nd ed. ch. 8 satellite orbit equations, circular case; IS-GPS-200 Table 20-IV
        with e = 0 and no harmonic corrections). With ``Omega_e = Omega_p -
        OMEGA_IE t`` the longitude of the ascending node in ECEF and
        ``u = u_0 + n t``::

            r_e = a [cos Om_e cos u - sin Om_e sin u cos i,
                     sin Om_e cos u + cos Om_e sin u cos i,
                     sin u sin i]
            v_e = C_z(OMEGA_IE t) v_i - Omega_ie x r_e

        Parameters
        ----------
        t_gps : (...,) array_like
            GPS time [s]; ECI and ECEF coincide at ``t_gps = 0``.
        sat_index : (..., K) int array_like, optional
            Satellite indices (``0 .. T-1``) to evaluate, broadcast against
            ``t_gps[..., None]``. Default: all ``T`` satellites.

        Returns
        -------
        pos : (..., S, 3) float64
            ECEF position [m] (``S = T`` or ``K``).
        vel : (..., S, 3) float64
            ECEF velocity [m/s] (includes ``-Omega_ie x r_e``).
        """
        t = np.asarray(t_gps, dtype=np.float64)
        if sat_index is None:
            idx = np.arange(self.n_sats)
        else:
            idx = np.asarray(sat_index)
            if idx.size and (idx.min() < 0 or idx.max() >= self.n_sats):
                raise ValueError(f"sat_index must lie in 0..{self.n_sats - 1}")
        shape = np.broadcast_shapes(t.shape + (1,), idx.shape)
        # angle-sum identities: the trigonometry runs on the time axes and the
        # satellite axis separately (u = u0 + n t, Om_e = Om_p - OMEGA_IE t)
        n = self.mean_motion
        nt, wt = n * t, OMEGA_IE * t
        time_terms = [(x if x.shape == shape[:-1] else np.broadcast_to(x, shape[:-1])).reshape(-1)
                      for x in (np.cos(nt), np.sin(nt), np.cos(wt), np.sin(wt))]
        pos = np.empty(shape + (3,))
        vel = np.empty(shape + (3,))
        _walker_kernel(*time_terms, np.broadcast_to(idx, shape).reshape(-1, shape[-1]), *self.kernel_constants(),
                       pos.reshape(-1, shape[-1], 3), vel.reshape(-1, shape[-1], 3))
        return pos, vel


@nb.njit(cache=True)
def _walker_kernel(cnt, snt, cwt, swt, idx, cu0, su0, cr, sr, a, ci, si, n, pos, vel):
    """The arithmetic of :meth:`Constellation.positions_velocities`, one pass over (time point, satellite).

    With ``u = u0 + n t`` and ``Om_e = Om_p - OMEGA_IE t`` expanded by the angle-sum identities::

        r_e = a [cos Om_e cos u - sin Om_e sin u cos i, sin Om_e cos u + cos Om_e sin u cos i, sin u sin i]
        v_e = C_z(OMEGA_IE t) v_i - Omega_ie x r_e

    Parameters
    ----------
    cnt, snt, cwt, swt : (N,) cos / sin of ``n t`` and of ``OMEGA_IE t`` at the N time points.
    idx : (N, K) int, satellite index of each output (0 .. T-1).
    cu0, su0, cr, sr : (T,) cos / sin of the argument of latitude at t = 0 and of the RAAN.
    a : orbit radius [m]; ci, si : cos / sin of the inclination; n : mean motion [rad/s].
    pos, vel : (N, K, 3) outputs, ECEF position [m] and velocity [m/s].
    """
    for j in range(idx.shape[0]):
        for k in range(idx.shape[1]):
            i = idx[j, k]
            (pos[j, k, 0], pos[j, k, 1], pos[j, k, 2], vel[j, k, 0], vel[j, k, 1],
             vel[j, k, 2]) = walker_point(cnt[j], snt[j], cwt[j], swt[j], cu0[i], su0[i], cr[i], sr[i], a, ci, si, n)


@nb.njit(cache=True, nogil=True)
def walker_point(cnt, snt, cwt, swt, cu0, su0, cr, sr, a, ci, si, n):
    """One satellite at one time: the arithmetic of :meth:`Constellation.positions_velocities` (the compiled
    geometry stages call it per satellite-epoch; one copy of the formulas, one order of operations).

    Parameters
    ----------
    cnt, snt, cwt, swt : cos / sin of ``n t`` and of ``OMEGA_IE t``.
    cu0, su0, cr, sr : cos / sin of the satellite's argument of latitude at t = 0 and of its RAAN.
    a : orbit radius [m]; ci, si : cos / sin of the inclination; n : mean motion [rad/s].

    Returns
    -------
    x, y, z : ECEF position [m]; vx, vy, vz : ECEF velocity [m/s].
    """
    cu = cu0 * cnt - su0 * snt
    su = su0 * cnt + cu0 * snt
    co = cr * cwt + sr * swt
    so = sr * cwt - cr * swt
    a_ci_su = a * ci * su
    a_cu = a * cu
    x = co * a_cu - so * a_ci_su
    y = so * a_cu + co * a_ci_su
    # inertial velocity rotated into ECEF (same rotation as the position) minus Omega_ie x r_e
    a_ci_cu = ci * a_cu
    a_su = a * su
    vx = (co * a_su + so * a_ci_cu) * -n + OMEGA_IE * y
    vy = (co * a_ci_cu - so * a_su) * n - OMEGA_IE * x
    return x, y, a * si * su, vx, vy, a * n * si * cu
