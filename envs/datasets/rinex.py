"""RINEX 3 observation and navigation files (read with georinex) reduced to corrected pseudorange epochs.

Reading is georinex's (M. Hirsch, https://github.com/geospace-code/georinex);
this module only maps its xarray datasets onto :class:`ObsData`,
:class:`~envs.datasets.ephemeris.KeplerEphemeris` and finally
:class:`~envs.datasets.epochs.GnssEpochs`:

1. per satellite, the first available code of the system's single-frequency
   signal (GPS ``C1C``, Galileo ``C1X``/``C1C``, BeiDou ``C2I`` (B1I));
2. transmission time in GPS time (IS-GPS-200 20.3.3.3.3.1):
   ``t_tx = t_rx - pr / c - dt_sv(t_tx)`` (two passes; the receiver clock
   error of ``t_rx`` cancels, ``t_rx - pr/c`` is the satellite's clock
   reading);
3. satellite position / velocity / clock from the healthy broadcast record
   nearest in ``toe`` (:func:`~envs.datasets.ephemeris.satellite_states`);
4. corrected pseudorange ``pr + c dt_sv - T_iono - T_trop`` with the
   Klobuchar (GPS broadcast coefficients for every system, scaled to the
   carrier) and Saastamoinen models (:mod:`envs.datasets.atmosphere`), at
   elevations / azimuths from an approximate receiver position: the RINEX
   header's ``APPROX POSITION XYZ`` or, without one, a first single-point
   solution without atmosphere;
5. ``pr_sigma`` from the elevation model ``sigma0 * sqrt(1 + 1/sin^2 el)``.

GLONASS (``R``) broadcasts PZ-90 state vectors to be integrated numerically,
not Keplerian elements: it is left out, and asking for it raises a clear
error. Satellites without a healthy ephemeris, and BeiDou GEOs, are skipped.

Time: GPS time in seconds since the start of the GPS week of the first
observation (``week_ref``); :attr:`GnssEpochs.t` is seconds since the first
epoch and :attr:`GnssEpochs.t0_gps` its GPS time of week. BeiDou ``toe`` and
``toc`` stay in BDT, counted from the same calendar origin (BDT week ``w``
starts at the calendar date of GPS week ``w + 1356``), and
:func:`~envs.datasets.ephemeris.satellite_states` converts GPST -> BDT.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from earth import ecef_to_geodetic
from earth.wgs84 import C_LIGHT, C_en

from .atmosphere import F_L1, klobuchar_delay, saastamoinen_delay
from .ephemeris import BEIDOU_GEO_PRNS, WEEK_S, KeplerEphemeris, satellite_states, select_ephemeris
from .epochs import SYSTEM_LETTERS, GnssEpochs
from .errors import DatasetFormatError, require_file
from .validate import check_nav_parsed, check_obs_parsed, scan_rinex_nav, scan_rinex_obs
from .spp import solve_spp

__all__ = ["ObsData", "NavData", "load_obs", "load_nav", "rinex_epochs", "SIGNALS", "GPS_EPOCH"]

GPS_EPOCH = np.datetime64("1980-01-06T00:00:00", "ns")
SIGNALS = {
    "G": (("C1C",), F_L1),
    "E": (("C1X", "C1C"), F_L1),
    "C": (("C2I", "C1I"), 1561.098e6),
}
"""System letter -> (code observables in order of preference, carrier [Hz]) of the single-frequency solution."""
_SYSTEM_NAME = {"G": "GPS", "E": "Galileo", "C": "BeiDou", "R": "GLONASS"}


def _georinex():
    try:
        import georinex
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError("reading RINEX needs the 'georinex' package (pip install georinex)") from exc
    return georinex


def _gps_seconds(times, week_ref: int) -> np.ndarray:
    """datetime64 GPS calendar times -> seconds since the start of GPS week ``week_ref`` (float64, ns exact)."""
    ns = (np.asarray(times).astype("datetime64[ns]") - GPS_EPOCH).astype(np.int64)
    return (ns - np.int64(week_ref) * np.int64(604_800_000_000_000)).astype(np.float64) * 1e-9


def _gps_week(time) -> int:
    ns = (np.datetime64(time, "ns") - GPS_EPOCH).astype(np.int64)
    return int(ns // 604_800_000_000_000)


@dataclass(frozen=True)
class ObsData:
    """Single-frequency code observations of one RINEX observation file.

    Attributes
    ----------
    t : (M,) reception times, GPS seconds since the start of week ``week_ref``.
    week_ref : int, GPS week.
    sv : (S,) str satellite names (``'G01'``...), system : (S,) int64 codes, prn : (S,) int64.
    pr : (M, S) pseudorange [m], NaN where not observed; code : (S,) str observable used.
    cn0 : (M, S) [dB-Hz], 0 where unknown.
    approx_position : (3,) ECEF from the header [m] or None.
    path : Path.
    doppler : (M, S) Doppler [Hz] of the code's signal (``D`` + the code's band and attribute), NaN where not
        observed; None when not read.
    """

    t: np.ndarray
    week_ref: int
    sv: np.ndarray
    system: np.ndarray
    prn: np.ndarray
    pr: np.ndarray
    code: np.ndarray
    cn0: np.ndarray
    approx_position: np.ndarray | None
    path: Path
    doppler: np.ndarray | None = None


@dataclass(frozen=True)
class NavData:
    """Broadcast navigation data of one RINEX navigation file.

    Attributes
    ----------
    ephemeris : KeplerEphemeris (GPS, Galileo, BeiDou MEO/IGSO; times relative to ``week_ref``).
    week_ref : int; iono_alpha, iono_beta : (4,) GPS Klobuchar coefficients (None if absent).
    skipped : tuple of str, what was not loaded and why (GLONASS, BeiDou GEO).
    path : Path.
    """

    ephemeris: KeplerEphemeris
    week_ref: int
    iono_alpha: np.ndarray | None
    iono_beta: np.ndarray | None
    skipped: tuple
    path: Path


def load_obs(path, systems=("G", "E", "C"), interval_s: float | None = None, tlim=None, signals=None,
             notes=None, doppler: bool = False) -> ObsData:
    """Read a RINEX 3 observation file (georinex) and keep one code per satellite (module docstring).

    Parameters
    ----------
    path : the observation file.
    systems : system letters to keep; ``'R'`` (GLONASS) raises: not supported.
    interval_s : keep one epoch every ``interval_s`` seconds (georinex ``interval``; faster); None: all.
    tlim : (start, stop) ISO time strings (georinex ``tlim``), or None.
    signals : {letter: (code, ...)} code observables in order of preference (default :data:`SIGNALS`).
    notes : callable taking one summary line, told of satellites dropped for want of a listed signal.
    doppler : also read the Doppler ``D`` observable of each satellite's code (:attr:`ObsData.doppler`).
    """
    path = require_file(path)
    systems = _check_systems(systems)
    sig = {s: tuple((signals or {}).get(s, SIGNALS[s][0])) for s in systems}
    # the file's structure, before a parser may skip damage (issue 13), and the plausibility of the codes used
    layout = scan_rinex_obs(path, codes=sig, doppler=doppler)
    gr = _georinex()
    meas = sorted({p + c[1:] for s in systems for c in sig[s] for p in ("CSD" if doppler else "CS")})
    kw = {}
    if interval_s is not None:
        kw["interval"] = float(interval_s)
    if tlim is not None:
        kw["tlim"] = tlim
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            # georinex averages the empty column of a requested signal the file does not have (numpy warns twice);
            # that case gets its own error below ("no <system> satellite with a <code> observation")
            for message in ("Mean of empty slice", "invalid value encountered in scalar divide"):
                warnings.filterwarnings("ignore", message, RuntimeWarning)
            obs = gr.load(path, meas=meas, use=set(systems), **kw)
    except Exception as exc:  # georinex raises many types on bad input
        raise DatasetFormatError(path, None, f"georinex could not read the observations: {exc}") from exc
    if obs.sizes.get("time", 0) == 0 or obs.sizes.get("sv", 0) == 0:
        raise DatasetFormatError(path, None, f"no observation of systems {systems} in the file")
    if interval_s is None and tlim is None:
        check_obs_parsed(path, layout, obs.sizes["time"], systems)
    times = obs.time.values
    week = _gps_week(times[0])
    t = _gps_seconds(times, week)
    svs = np.asarray(obs.sv.values).astype(str)
    pr = np.full((t.size, svs.size), np.nan)
    cn0 = np.zeros((t.size, svs.size))
    code = np.empty(svs.size, dtype=object)
    dop = np.full((t.size, svs.size), np.nan) if doppler else None
    for j, sv in enumerate(svs):
        for c in sig[sv[0]]:
            if c in obs and np.isfinite(obs[c].values[:, j]).any():
                pr[:, j] = obs[c].values[:, j]
                s_name = "S" + c[1:]
                if s_name in obs:
                    cn0[:, j] = np.nan_to_num(obs[s_name].values[:, j])
                if doppler and "D" + c[1:] in obs:
                    dop[:, j] = obs["D" + c[1:]].values[:, j]
                code[j] = c
                break
    keep = np.array([c is not None for c in code])
    if notes is not None:
        for s in systems:
            lost = [sv for sv, k in zip(svs, keep) if sv[0] == s and not k]
            if lost:
                notes(f"{_SYSTEM_NAME[s]}: {len(lost)} satellites observed without {'/'.join(sig[s])}: dropped "
                      f"({', '.join(lost)})")
    pos = obs.attrs.get("position")
    approx = None if pos is None or not np.any(pos) else np.asarray(pos, np.float64)
    sv_k = svs[keep]
    return ObsData(t=t, week_ref=week, sv=sv_k, system=np.array([SYSTEM_LETTERS[s[0]] for s in sv_k], np.int64),
                   prn=np.array([int(s[1:]) for s in sv_k], np.int64), pr=pr[:, keep], code=code[keep].astype(str),
                   cn0=cn0[:, keep], approx_position=approx, path=path,
                   doppler=None if dop is None else dop[:, keep])


def _check_systems(systems) -> tuple:
    systems = tuple(systems)
    if "R" in systems:
        raise ValueError("GLONASS ('R') is not supported: its broadcast ephemeris is a PZ-90 state vector to be "
                         "integrated (GLONASS ICD A.3.1.2), not Keplerian elements; leave 'R' out of systems")
    bad = [s for s in systems if s not in SIGNALS]
    if bad or not systems:
        raise ValueError(f"systems must be letters among {sorted(SIGNALS)}, got {systems!r}")
    return systems


def load_nav(path, week_ref: int | None = None) -> NavData:
    """Read a RINEX 3 navigation file (georinex) into Keplerian records (module docstring).

    Parameters
    ----------
    path : the navigation file.
    week_ref : GPS week the times are relative to (default: that of the first record).
    """
    path = require_file(path)
    layout = scan_rinex_nav(path)  # the file's structure, before a parser may skip damage (issue 13)
    gr = _georinex()
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FutureWarning)
            nav = gr.load(path)
    except Exception as exc:
        raise DatasetFormatError(path, None, f"georinex could not read the navigation data: {exc}") from exc
    if nav.sizes.get("time", 0) == 0:
        raise DatasetFormatError(path, None, "no navigation record")
    check_nav_parsed(path, layout, nav)
    if week_ref is None:
        week_ref = _gps_week(nav.time.values[0])
    cols = {k: [] for k in ("system", "prn", "toe", "toc", "sqrtA", "e", "i0", "omega0", "omega", "m0", "dn",
                            "omega_dot", "idot", "cuc", "cus", "cic", "cis", "crc", "crs", "af0", "af1", "af2",
                            "tgd", "health")}
    skipped = []
    names = {"sqrtA": "sqrtA", "e": "Eccentricity", "i0": "Io", "omega0": "Omega0", "omega": "omega", "m0": "M0",
             "dn": "DeltaN", "omega_dot": "OmegaDot", "idot": "IDOT", "cuc": "Cuc", "cus": "Cus", "cic": "Cic",
             "cis": "Cis", "crc": "Crc", "crs": "Crs", "af0": "SVclockBias", "af1": "SVclockDrift",
             "af2": "SVclockDriftRate"}
    toc_all = _gps_seconds(nav.time.values, week_ref)

    def var(name, j):
        return nav[name].values[:, j] if name in nav else np.full(nav.sizes["time"], np.nan)

    for j, sv in enumerate(np.asarray(nav.sv.values).astype(str)):
        letter, prn = sv[0], int(sv[1:])
        if letter == "R":
            if "GLONASS" not in " ".join(skipped):
                skipped.append("GLONASS: state-vector ephemerides are not supported")
            continue
        if letter not in ("G", "E", "C"):
            skipped.append(f"{sv}: system not supported")
            continue
        if letter == "C" and prn in BEIDOU_GEO_PRNS:
            skipped.append(f"{sv}: BeiDou GEO orbit algorithm not implemented")
            continue
        sqa = var("sqrtA", j)
        rows = np.nonzero(np.isfinite(sqa))[0]
        if rows.size == 0:
            continue
        system = SYSTEM_LETTERS[letter]
        if letter == "G":
            week, tgd, health = var("GPSWeek", j), var("TGD", j), var("health", j)
        elif letter == "E":
            week, health = var("GALWeek", j), var("health", j)
            src = np.nan_to_num(var("DataSrc", j)).astype(np.int64)
            # I/NAV clocks (bit 9) go with BGD(E1, E5b); F/NAV clocks (bit 8) with BGD(E1, E5a)
            tgd = np.where(src & 512, var("BGDe5b", j), var("BGDe5a", j))
        else:
            week, tgd, health = var("BDTWeek", j) + 1356.0, var("TGD1", j), var("SatH1", j)
        for i in rows:
            toe_week_s = (week[i] - week_ref) * WEEK_S
            toe = toe_week_s + var("Toe", j)[i]
            toc = toc_all[i]                               # BeiDou: BDT calendar, same origin (module doc)
            vals = {k: var(v, j)[i] for k, v in names.items()}
            if not (np.isfinite(toe) and all(np.isfinite(v) for v in vals.values()) and np.isfinite(tgd[i])):
                raise DatasetFormatError(path, None, f"{sv} record at {nav.time.values[i]}: incomplete ephemeris")
            cols["system"].append(system)
            cols["prn"].append(prn)
            cols["toe"].append(toe)
            cols["toc"].append(toc)
            for k, v in vals.items():
                cols[k].append(v)
            cols["tgd"].append(tgd[i])
            cols["health"].append(int(np.nan_to_num(health[i], nan=1.0)))
    eph = KeplerEphemeris(**{k: np.asarray(v, np.int64 if k in ("system", "prn", "health") else np.float64)
                             for k, v in cols.items()})
    iono = nav.attrs.get("ionospheric_corr_GPS")
    alpha = beta = None
    if iono is not None and len(iono) == 8:
        alpha, beta = np.asarray(iono[:4], np.float64), np.asarray(iono[4:], np.float64)
    return NavData(ephemeris=eph, week_ref=int(week_ref), iono_alpha=alpha, iono_beta=beta, skipped=tuple(skipped),
                   path=path)


def rinex_epochs(obs: ObsData, nav: NavData, elevation_mask_deg: float = 10.0, sigma0_m: float = 1.5,
                 approx_position="header", iono: bool = True, tropo: bool = True,
                 doppler_sigma0_mps: float | None = None) -> GnssEpochs:
    """Corrected single-frequency pseudorange epochs from RINEX observations and broadcast ephemerides.

    Parameters
    ----------
    obs, nav : from :func:`load_obs`, :func:`load_nav` (any ``week_ref``: ``nav`` is re-based).
    elevation_mask_deg : drop satellites below this elevation [deg] (at the approximate position).
    sigma0_m : zenith code sigma of the elevation model [m], > 0.
    approx_position : position for elevations and the atmosphere: an ECEF (3,) array [m]; ``'header'``
        the header's ``APPROX POSITION XYZ`` (falls back to ``'spp'`` without one); ``'spp'`` a first
        single-point solution per epoch without atmosphere (epochs where it fails are dropped).
    iono, tropo : apply the Klobuchar / Saastamoinen corrections.
    doppler_sigma0_mps : with ``obs.doppler``, the zenith pseudorange-rate sigma [m/s] of the elevation model;
        the epochs then carry pseudorange rates (:mod:`envs.datasets.doppler`). None: no rates.

    Returns
    -------
    GnssEpochs with ``t`` since the first epoch, ``t0_gps`` its GPS time of week [s].
    """
    if not (isinstance(sigma0_m, (int, float)) and math.isfinite(sigma0_m) and sigma0_m > 0):
        raise ValueError(f"sigma0_m must be a finite number > 0, got {sigma0_m!r}")
    if not (isinstance(elevation_mask_deg, (int, float)) and -90 <= elevation_mask_deg <= 90):
        raise ValueError(f"elevation_mask_deg must be in [-90, 90], got {elevation_mask_deg!r}")
    eph = nav.ephemeris
    if nav.week_ref != obs.week_ref:
        shift = (nav.week_ref - obs.week_ref) * WEEK_S
        eph = KeplerEphemeris(**{**{f: getattr(eph, f) for f in eph.__dataclass_fields__},
                                 "toe": eph.toe + shift, "toc": eph.toc + shift})
    M, S = obs.pr.shape
    t_rx = np.broadcast_to(obs.t[:, None], (M, S))
    system = np.broadcast_to(obs.system[None], (M, S))
    prn = np.broadcast_to(obs.prn[None], (M, S))
    rec = select_ephemeris(eph, system, prn, t_rx)
    ok = np.isfinite(obs.pr) & (rec >= 0)
    mi, si = np.nonzero(ok)
    e = eph.take(rec[mi, si])
    pr = obs.pr[mi, si]
    t_tx = t_rx[mi, si] - pr / C_LIGHT
    dt_sv = np.zeros_like(t_tx)
    for _ in range(2):                                      # t_tx = t_sv - dt_sv(t_tx)
        pos, vel, dt_sv, _ = satellite_states(e, t_tx - dt_sv)
    t_tx = t_tx - dt_sv
    pos, vel, dt_sv, ddt_sv = satellite_states(e, t_tx)
    sat_pos = np.zeros((M, S, 3))
    sat_vel = np.zeros((M, S, 3))
    pr_c = np.zeros((M, S))
    sat_pos[mi, si], sat_vel[mi, si] = pos, vel
    pr_c[mi, si] = pr + C_LIGHT * dt_sv
    # approximate receiver position for elevations and the atmosphere
    if isinstance(approx_position, str):
        if approx_position not in ("header", "spp"):
            raise ValueError(f"approx_position must be 'header', 'spp' or an ECEF (3,) array, got {approx_position!r}")
        approx_position = obs.approx_position if approx_position == "header" else None
    if approx_position is None:
        first = solve_spp(sat_pos, pr_c, ok, system=np.where(ok, system, 0))
        r_ap = first.r_e
        ok &= first.valid[:, None]
        r_ap = np.where(np.isfinite(r_ap), r_ap, 0.0)
    else:
        r_ap = np.broadcast_to(np.asarray(approx_position, np.float64), (M, 3))
    lat, lon, h = ecef_to_geodetic(r_ap)
    d = sat_pos - r_ap[:, None, :]
    u_n = (np.swapaxes(C_en(lat, lon), -1, -2)[:, None] @ d[..., None])[..., 0]
    el = np.arctan2(-u_n[..., 2], np.hypot(u_n[..., 0], u_n[..., 1]))
    az = np.mod(np.arctan2(u_n[..., 1], u_n[..., 0]), 2 * np.pi)
    ok &= el >= math.radians(elevation_mask_deg)
    if iono and nav.iono_alpha is not None:
        freq = np.array([SIGNALS[{v: k for k, v in SYSTEM_LETTERS.items()}[s]][1] for s in obs.system])
        pr_c -= np.where(ok, klobuchar_delay(nav.iono_alpha, nav.iono_beta, lat[:, None], lon[:, None], el, az,
                                             t_rx, freq[None, :]), 0.0)
    if tropo:
        pr_c -= np.where(ok, saastamoinen_delay(lat[:, None], h[:, None], np.maximum(el, 1e-3)), 0.0)
    s_el = np.sin(np.maximum(el, math.radians(1.0)))
    sigma = sigma0_m * np.sqrt(1.0 + 1.0 / s_el ** 2)
    cn0 = obs.cn0

    def z(a):
        a = np.array(a, np.float64 if a.dtype.kind == "f" else a.dtype)
        a[~ok] = 0
        return a

    sat_id = np.where(ok, prn, -1)
    prr = prr_sigma = None
    if doppler_sigma0_mps is not None and obs.doppler is not None:
        from .doppler import doppler_epochs
        prr, prr_sigma = doppler_epochs(obs, mi, si, ddt_sv, ok, s_el, doppler_sigma0_mps)
    return GnssEpochs(t=obs.t - obs.t[0], sat_pos=z(sat_pos), sat_vel=z(sat_vel), pr=z(pr_c), pr_sigma=z(sigma),
                      mask=ok, sat_id=sat_id.astype(np.int64), system=np.where(ok, system, 0).astype(np.int64),
                      elevation=z(el), cn0=z(cn0), t0_gps=float(obs.t[0]),
                      source=f"RINEX {Path(obs.path).name} + {Path(nav.path).name}", prr=prr, prr_sigma=prr_sigma)
