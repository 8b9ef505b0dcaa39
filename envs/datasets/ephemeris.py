"""Broadcast Keplerian ephemerides: satellite position, velocity and clock (GPS, Galileo, BeiDou MEO/IGSO).

Implements the user algorithm of IS-GPS-200 (rev. N, sec 20.3.3.4.3, Table
20-IV "Elements of Coordinate Systems", with the SV velocity equations of the
same table) and its equivalents in the Galileo OS SIS ICD (issue 2.0, sec
5.1.1, Table 60) and the BeiDou ICD B1I (v3.0, sec 5.2.4.12, MEO/IGSO case),
which differ only in their constants ``mu`` and ``Omega_e_dot``. Vectorized
over K (satellite, time) pairs.

Orbit (IS-GPS-200 Table 20-IV)::

    A = sqrtA^2,  n = sqrt(mu / A^3) + dn,  tk = t - toe
    M = M0 + n tk,   M = E - e sin E              (Kepler, Newton iterations)
    nu = atan2(sqrt(1 - e^2) sin E, cos E - e),   Phi = nu + omega
    du = Cus sin 2Phi + Cuc cos 2Phi,   dr = Crs sin 2Phi + Crc cos 2Phi,   di = Cis sin 2Phi + Cic cos 2Phi
    u = Phi + du,   r = A (1 - e cos E) + dr,   i = i0 + di + IDOT tk
    x' = r cos u,   y' = r sin u
    Omega = Omega0 + (Omega_dot - We) tk - We toe
    x = x' cos Omega - y' cos i sin Omega,  y = x' sin Omega + y' cos i cos Omega,  z = y' sin i

and its time derivative (same table, "SV velocity"): ``E_dot = n / (1 - e
cos E)``, ``nu_dot = E_dot sqrt(1 - e^2) / (1 - e cos E)``, ``u_dot, r_dot,
i_dot`` from the harmonic corrections, ``Omega_dot_k = Omega_dot - We``. The
result is ECEF at time ``t`` in the ECEF frame *of that time* (the Sagnac
rotation during the signal flight is applied later, by
:func:`earth.ranging.range_and_rate`).

Clock (IS-GPS-200 20.3.3.3.3.1-2; Galileo ICD 5.1.4-5; BeiDou ICD 5.2.4.10)::

    dt_sv = af0 + af1 (t - toc) + af2 (t - toc)^2 + dt_r,    dt_r = F e sqrtA sin E,   F = -2 sqrt(mu) / c^2

and, for a single-frequency user, minus the group delay of the signal used
(GPS L1 C/A: ``TGD``; Galileo E1 with I/NAV clocks: ``BGD(E1, E5b)``, with
F/NAV: ``BGD(E1, E5a)``; BeiDou B1I: ``TGD1``). The time ``t`` is in the
system's own time scale (GPST, GST, BDT); :func:`satellite_states` takes GPS
time and converts (BDT = GPST - 14 s; GST is GPST to within tens of ns).

BeiDou GEO satellites (PRN 1-5 and 59-63) use a different rotation (BeiDou
ICD 5.2.4.12, GEO case) and are rejected with a clear error; GLONASS
broadcasts state vectors, not Keplerian elements, and is not handled here.
"""
from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from earth.wgs84 import C_LIGHT

from .epochs import SYS_BEIDOU, SYS_GALILEO, SYS_GPS, SYSTEM_NAMES

__all__ = ["MU", "OMEGA_E", "BDT_MINUS_GPST_S", "BEIDOU_GEO_PRNS", "KeplerEphemeris", "satellite_states",
           "select_ephemeris"]

MU = {SYS_GPS: 3.986005e14, SYS_GALILEO: 3.986004418e14, SYS_BEIDOU: 3.986004418e14}
"""Gravitational constant of each system's user algorithm [m^3/s^2] (IS-GPS-200, Galileo OS ICD, BeiDou ICD)."""
OMEGA_E = {SYS_GPS: 7.2921151467e-5, SYS_GALILEO: 7.2921151467e-5, SYS_BEIDOU: 7.292115e-5}
"""Earth rotation rate of each system's user algorithm [rad/s]."""
BDT_MINUS_GPST_S = -14.0
"""BeiDou time minus GPS time [s] (BeiDou ICD 4.2: BDT started 2006-01-01 00:00:00 UTC, GPST - UTC was 14 s)."""
BEIDOU_GEO_PRNS = (1, 2, 3, 4, 5, 59, 60, 61, 62, 63)
WEEK_S = 604_800.0


@dataclass(frozen=True)
class KeplerEphemeris:
    """K broadcast ephemeris records (arrays of shape (K,)).

    Times are seconds since the start of a reference GPS week (``week_ref``
    of the loader), each in its system's own time scale: ``toe`` and ``toc``
    for BeiDou are BDT. Angles in rad, rates in rad/s, distances in m,
    clock terms in s, s/s, s/s^2.

    Attributes
    ----------
    system, prn : int64; toe, toc : [s]; sqrtA [m^0.5]; e; i0, omega0, omega, m0 [rad];
    dn, omega_dot, idot [rad/s]; cuc, cus, cic, cis [rad]; crc, crs [m];
    af0 [s], af1 [s/s], af2 [s/s^2]; tgd [s], the group delay of the single-frequency signal used;
    health : int64 (0 = healthy).
    """

    system: np.ndarray
    prn: np.ndarray
    toe: np.ndarray
    toc: np.ndarray
    sqrtA: np.ndarray
    e: np.ndarray
    i0: np.ndarray
    omega0: np.ndarray
    omega: np.ndarray
    m0: np.ndarray
    dn: np.ndarray
    omega_dot: np.ndarray
    idot: np.ndarray
    cuc: np.ndarray
    cus: np.ndarray
    cic: np.ndarray
    cis: np.ndarray
    crc: np.ndarray
    crs: np.ndarray
    af0: np.ndarray
    af1: np.ndarray
    af2: np.ndarray
    tgd: np.ndarray
    health: np.ndarray

    def __post_init__(self):
        K = np.shape(self.system)[0] if np.ndim(self.system) == 1 else -1
        for f in fields(self):
            a = np.asarray(getattr(self, f.name))
            if a.shape != (K,):
                raise ValueError(f"KeplerEphemeris.{f.name} must have shape ({K},), got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"KeplerEphemeris.{f.name} must be finite")
        bad = ~np.isin(self.system, list(MU))
        if bad.any():
            raise ValueError(f"KeplerEphemeris.system: {SYSTEM_NAMES.get(int(self.system[bad][0]), '?')} has no "
                             f"Keplerian broadcast ephemeris here (GPS, Galileo, BeiDou only)")
        geo = (self.system == SYS_BEIDOU) & np.isin(self.prn, BEIDOU_GEO_PRNS)
        if geo.any():
            raise ValueError(f"BeiDou GEO satellite C{int(self.prn[geo][0]):02d}: the GEO orbit algorithm "
                             f"(BeiDou ICD 5.2.4.12) is not implemented; drop GEO satellites")

    @property
    def size(self) -> int:
        return int(np.shape(self.system)[0])

    def take(self, idx) -> "KeplerEphemeris":
        """The records ``idx`` (int array)."""
        return KeplerEphemeris(**{f.name: np.asarray(getattr(self, f.name))[idx] for f in fields(self)})


def _consts(system):
    mu = np.select([system == SYS_GPS, system == SYS_GALILEO], [MU[SYS_GPS], MU[SYS_GALILEO]], MU[SYS_BEIDOU])
    we = np.select([system == SYS_GPS, system == SYS_GALILEO], [OMEGA_E[SYS_GPS], OMEGA_E[SYS_GALILEO]],
                   OMEGA_E[SYS_BEIDOU])
    return mu, we


def _system_time(system, t_gps):
    """The system's own time of GPS time ``t_gps`` (BeiDou: BDT = GPST - 14 s)."""
    return np.where(system == SYS_BEIDOU, t_gps + BDT_MINUS_GPST_S, t_gps)


def satellite_states(eph: KeplerEphemeris, t_gps, kepler_iterations: int = 10):
    """Satellite ECEF position, velocity and clock correction at GPS times (module docstring).

    Parameters
    ----------
    eph : K records (one per evaluation; use :meth:`KeplerEphemeris.take` to pair records with times).
    t_gps : (K,) GPS time [s since the start of the reference week].
    kepler_iterations : Newton iterations on Kepler's equation (converged to < 1e-15 rad in 4 for e < 0.03).

    Returns
    -------
    pos : (K, 3) ECEF position at ``t`` [m]; vel : (K, 3) ECEF velocity [m/s];
    dt_sv : (K,) satellite clock correction incl. relativity and group delay [s]
        (the corrected pseudorange is ``pr + c dt_sv``);
    ddt_sv : (K,) its rate [s/s].
    """
    t_gps = np.asarray(t_gps, np.float64)
    if t_gps.shape != (eph.size,):
        raise ValueError(f"t_gps must have shape ({eph.size},), got {t_gps.shape}")
    s = eph.system
    mu, we = _consts(s)
    t = _system_time(s, t_gps)
    A = eph.sqrtA ** 2
    n = np.sqrt(mu / A ** 3) + eph.dn
    tk = t - eph.toe
    M = eph.m0 + n * tk
    e = eph.e
    E = M.copy()
    for _ in range(kepler_iterations):                      # Newton on E - e sin E - M = 0
        E = E - (E - e * np.sin(E) - M) / (1.0 - e * np.cos(E))
    sE, cE = np.sin(E), np.cos(E)
    one_ecE = 1.0 - e * cE
    sq = np.sqrt(1.0 - e * e)
    nu = np.arctan2(sq * sE, cE - e)
    phi = nu + eph.omega
    s2, c2 = np.sin(2 * phi), np.cos(2 * phi)
    u = phi + eph.cus * s2 + eph.cuc * c2
    r = A * one_ecE + eph.crs * s2 + eph.crc * c2
    inc = eph.i0 + eph.cis * s2 + eph.cic * c2 + eph.idot * tk
    xp, yp = r * np.cos(u), r * np.sin(u)
    Om = eph.omega0 + (eph.omega_dot - we) * tk - we * eph.toe
    cO, sO, ci, si = np.cos(Om), np.sin(Om), np.cos(inc), np.sin(inc)
    pos = np.stack([xp * cO - yp * ci * sO, xp * sO + yp * ci * cO, yp * si], -1)
    # velocity (IS-GPS-200 Table 20-IV, SV velocity)
    Ed = n / one_ecE
    nud = Ed * sq / one_ecE
    did = eph.idot + 2.0 * nud * (eph.cis * c2 - eph.cic * s2)
    ud = nud + 2.0 * nud * (eph.cus * c2 - eph.cuc * s2)
    rd = e * A * Ed * sE + 2.0 * nud * (eph.crs * c2 - eph.crc * s2)
    Omd = eph.omega_dot - we
    xpd = rd * np.cos(u) - r * ud * np.sin(u)
    ypd = rd * np.sin(u) + r * ud * np.cos(u)
    vx = -xp * Omd * sO + xpd * cO - ypd * sO * ci - yp * (Omd * cO * ci - did * sO * si)
    vy = xp * Omd * cO + xpd * sO + ypd * cO * ci - yp * (Omd * sO * ci + did * cO * si)
    vz = ypd * si + yp * did * ci
    vel = np.stack([vx, vy, vz], -1)
    # clock (IS-GPS-200 20.3.3.3.3.1 with the relativistic term; minus the single-frequency group delay)
    F = -2.0 * np.sqrt(mu) / C_LIGHT ** 2
    dtc = t - eph.toc
    dt_sv = eph.af0 + eph.af1 * dtc + eph.af2 * dtc ** 2 + F * e * eph.sqrtA * sE - eph.tgd
    ddt_sv = eph.af1 + 2.0 * eph.af2 * dtc + F * e * eph.sqrtA * cE * Ed
    return pos, vel, dt_sv, ddt_sv


def select_ephemeris(eph: KeplerEphemeris, system, prn, t_gps, max_age_s: float = 4 * 3600.0) -> np.ndarray:
    """Index of the healthy record of each satellite nearest in ``toe`` to ``t_gps``, -1 where none.

    Parameters
    ----------
    system, prn, t_gps : (...) arrays of equal shape (GPS time [s since the reference week start]).
    max_age_s : largest ``|t - toe|`` accepted [s] (GPS fit interval 4 h: +-2 h; Galileo and BeiDou
        ephemerides are refreshed every 10 min / 1 h, so the nearest is far inside it).

    Returns
    -------
    (...) int64 record index.
    """
    system, prn, t_gps = np.broadcast_arrays(np.asarray(system), np.asarray(prn), np.asarray(t_gps, np.float64))
    out = np.full(system.shape, -1, np.int64)
    healthy = eph.health == 0
    for s_, p_ in {(int(a), int(b)) for a, b in zip(system.ravel(), prn.ravel())}:
        recs = np.nonzero((eph.system == s_) & (eph.prn == p_) & healthy)[0]
        sel = (system == s_) & (prn == p_)
        if recs.size == 0:
            continue
        t_sys = _system_time(s_, t_gps[sel])
        age = np.abs(t_sys[:, None] - eph.toe[recs][None, :])
        j = np.argmin(age, axis=1)
        out[sel] = np.where(age[np.arange(j.size), j] <= max_age_s, recs[j], -1)
    return out
