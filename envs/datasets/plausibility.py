"""Physical plausibility of recorded data, checked at load: an impossible value is a
:class:`~envs.datasets.errors.DatasetFormatError` naming the file, the line and the value, never a silent
input to the filter (a pseudorange of 2.35e14 m replayed to an RMSE of 3e13 m with exit status 0 before).

What is checked, and against what:

* **Pseudoranges** (smartLoc rows, RINEX code observations of the signals used): a pseudorange is the range
  from a receiver on or near the Earth's surface to a satellite in its orbit, plus the receiver clock bias,
  which can be large (milliseconds, hundreds of km) but is *common to the epoch*. With the receiver at radius
  :data:`RECEIVER_RADIUS_M` and the satellite at radius ``r`` (smartLoc: its recorded position; RINEX: the
  system's orbit radii, :data:`ORBIT_RADIUS_M`), seen at an elevation of at least
  :data:`MIN_ELEVATION_DEG`, the range lies in :func:`range_window` (GPS: about 19,300-27,300 km); each
  pseudorange then allows the clock an interval, and the intervals of an epoch must share a point (within
  :data:`INTER_SYSTEM_MARGIN_M` for biases between systems): :func:`common_offset_outliers` names the
  pseudoranges outside the clock most of the epoch agrees on. The clock itself is at most
  :data:`CLOCK_MAX_M`.
* **Pseudorange rates** (RINEX Doppler of the codes used): the range rate of a satellite seen from a
  receiver at most :data:`RECEIVER_SPEED_MAX_MPS` fast is within :data:`RANGE_RATE_MAX_MPS`, plus the clock
  drift, common to the epoch and at most :data:`CLOCK_DRIFT_MAX_MPS`.
* **Broadcast ephemerides** (RINEX navigation records of GPS, Galileo, BeiDou): every parameter within the
  range its ICD's message field can hold (:data:`ICD_RANGES`; e.g. ``Crs`` 16 bits of 2^-5 m: +-1024 m for GPS
  and Galileo, 18 bits of 2^-6 m for BeiDou) -- a ``Crs`` of 1e7 m made the single-point solution's matrix
  singular before, with no file named.
* **Tracks**: satellite positions of one satellite move at most :data:`SAT_SPEED_MAX_MPS`; the truth at most
  :data:`TRUTH_SPEED_MAX_MPS` between rows (:func:`check_track_speed`).
* **The truth against the recording's own single-point solution** (:func:`check_truth_near_spp`): the median
  distance over the epochs at most :data:`TRUTH_SPP_MAX_M` (a static truth 3,400 km from the receiver replayed
  to an RMSE of 3.3e6 m before).

The bounds are generous (a real recording is far inside them: the shipped ones load unchanged); they catch
what no receiver on Earth can record, not a poor measurement.
"""
from __future__ import annotations

import math

import numpy as np

from earth.wgs84 import C_LIGHT

from .errors import DatasetFormatError

__all__ = ["RECEIVER_RADIUS_M", "MIN_ELEVATION_DEG", "ORBIT_RADIUS_M", "INTER_SYSTEM_MARGIN_M", "CLOCK_MAX_M",
           "RANGE_RATE_MAX_MPS", "RECEIVER_SPEED_MAX_MPS", "CARRIER_HZ", "check_rinex_epochs", "CLOCK_DRIFT_MAX_MPS", "SAT_SPEED_MAX_MPS",
           "TRUTH_SPEED_MAX_MPS", "TRUTH_SPP_MAX_M", "CN0_MAX_DBHZ", "ICD_RANGES", "NAV_FIELDS", "range_window",
           "common_offset_outliers", "icd_violation", "check_track_speed", "check_truth_near_spp"]

RECEIVER_RADIUS_M = (6.35e6, 6.42e6)
"""Distance of a receiver from the Earth's centre [m]: the polar radius (6357 km) less a few km, to the
equatorial radius (6378 km) plus 40 km of altitude."""
MIN_ELEVATION_DEG = -5.0
"""Lowest elevation a satellite is tracked at [deg] (below 0 only from a height)."""
ORBIT_RADIUS_M = {"G": (25.7e6, 27.4e6), "R": (25.2e6, 25.9e6), "E": (23.4e6, 32.6e6), "C": (27.3e6, 42.7e6),
                  "J": (38.9e6, 45.4e6), "S": (41.5e6, 42.8e6), "I": (41.5e6, 42.8e6)}
"""Satellite distance from the Earth's centre per RINEX system letter [m]: GPS a = 26,560 km with e <= 0.03,
GLONASS 25,510 km, Galileo 29,600 km and the two eccentric E14/E18 orbits (23,500-32,500 km), BeiDou MEO
27,900 km to IGSO/GEO 42,164 km, QZSS QZO (e 0.075) and GEO, SBAS and NavIC GEO/IGSO."""
INTER_SYSTEM_MARGIN_M = 1e-3 * C_LIGHT
"""Room for the receiver clock differing between systems in one epoch [m] (1 ms; real biases are metres)."""
CLOCK_MAX_M = 1.0 * C_LIGHT
"""Largest receiver clock bias [m] (1 s; receivers steer theirs to within milliseconds)."""
RECEIVER_SPEED_MAX_MPS = 1000.0
"""Fastest receiver [m/s] (faster than any aircraft a navigation recording comes from)."""
RANGE_RATE_MAX_MPS = 1000.0 + RECEIVER_SPEED_MAX_MPS
"""Largest range rate [m/s]: a satellite's line-of-sight rate seen from the Earth (below 1 km/s for MEO, about 0
for GEO) plus the receiver's speed."""
CLOCK_DRIFT_MAX_MPS = 1e-4 * C_LIGHT
"""Largest receiver clock drift [m/s] (100 ppm; a TCXO is within a few ppm)."""
SAT_SPEED_MAX_MPS = 6000.0
"""Fastest a GNSS satellite moves in ECEF [m/s] (MEO about 3.9 km/s)."""
TRUTH_SPEED_MAX_MPS = RECEIVER_SPEED_MAX_MPS
"""Fastest the truth moves between its rows [m/s]."""
TRUTH_SPP_MAX_M = 1000.0
"""Largest median distance between the truth and the recording's own single-point solution [m] (urban smartLoc:
71 m median, 135 m at worst; the static Reach recording: about 7 m)."""
CN0_MAX_DBHZ = 80.0
"""Largest carrier-to-noise density [dB-Hz] (GNSS signals arrive below 55 dB-Hz on the ground)."""

_SC = math.pi  # one semicircle [rad]; the ICDs give the angles in semicircles, RINEX in radians
ICD_RANGES = {
    "G": {"af0": 2.0 ** -10, "af1": 2.0 ** -28, "af2": 2.0 ** -48, "tgd": 2.0 ** -24, "crs": 2.0 ** 10,
          "crc": 2.0 ** 10, "dn": 2.0 ** -28 * _SC, "m0": _SC, "omega0": _SC, "omega": _SC, "i0": _SC,
          "cuc": 2.0 ** -14, "cus": 2.0 ** -14, "cic": 2.0 ** -14, "cis": 2.0 ** -14, "e": (0.0, 0.03),
          "sqrtA": (2530.0, 8192.0), "toe": (0.0, 604784.0), "omega_dot": 2.0 ** -20 * _SC, "idot": 2.0 ** -30 * _SC},
    "E": {"af0": 2.0 ** -4, "af1": 2.0 ** -26, "af2": 2.0 ** -54, "tgd": 2.0 ** -23, "crs": 2.0 ** 10,
          "crc": 2.0 ** 10, "dn": 2.0 ** -28 * _SC, "m0": _SC, "omega0": _SC, "omega": _SC, "i0": _SC,
          "cuc": 2.0 ** -14, "cus": 2.0 ** -14, "cic": 2.0 ** -14, "cis": 2.0 ** -14, "e": (0.0, 0.5),
          "sqrtA": (2530.0, 8192.0), "toe": (0.0, 604740.0), "omega_dot": 2.0 ** -20 * _SC, "idot": 2.0 ** -30 * _SC},
    "C": {"af0": 2.0 ** -10, "af1": 2.0 ** -29, "af2": 2.0 ** -56, "tgd": 5.12e-8, "crs": 2.0 ** 11,
          "crc": 2.0 ** 11, "dn": 2.0 ** -28 * _SC, "m0": _SC, "omega0": _SC, "omega": _SC, "i0": _SC,
          "cuc": 2.0 ** -14, "cus": 2.0 ** -14, "cic": 2.0 ** -14, "cis": 2.0 ** -14, "e": (0.0, 0.5),
          "sqrtA": (2530.0, 8192.0), "toe": (0.0, 604792.0), "omega_dot": 2.0 ** -20 * _SC, "idot": 2.0 ** -30 * _SC},
}
"""Broadcast ephemeris parameters per system: the range the ICD's message field holds (a number x: [-x, x]; a pair:
[low, high]), in RINEX units (s, s/s, s/s^2, m, rad, rad/s). GPS: IS-GPS-200 Tables 20-I and 20-III (``e`` and
``sqrtA`` at their "effective range"; angles +-1 semicircle); Galileo: OS SIS ICD 2.0 Tables 57 and 60; BeiDou: B1I
ICD 3.0 sec 5.2.4 (``tgd`` 10 bits of 0.1 ns; ``crs``/``crc`` 18 bits of 2^-6 m; ``cuc``... 18 bits of 2^-31 rad)."""
NAV_FIELDS = {(0, 0): "af0", (0, 1): "af1", (0, 2): "af2", (1, 1): "crs", (1, 2): "dn", (1, 3): "m0",
              (2, 0): "cuc", (2, 1): "e", (2, 2): "cus", (2, 3): "sqrtA", (3, 0): "toe", (3, 1): "cic",
              (3, 2): "omega0", (3, 3): "cis", (4, 0): "i0", (4, 1): "crc", (4, 2): "omega", (4, 3): "omega_dot",
              (5, 0): "idot", (6, 2): "tgd"}
"""(line of the record, field of the line) -> parameter, in a RINEX 3 GPS / Galileo / BeiDou navigation record
(RINEX 3.04 Tables A6, A8, A14: the same places in all three)."""
_NAV_NAMES = {"af0": "SV clock bias af0 [s]", "af1": "SV clock drift af1 [s/s]", "af2": "SV clock drift rate af2 "
              "[s/s^2]", "crs": "Crs [m]", "dn": "Delta n [rad/s]", "m0": "M0 [rad]", "cuc": "Cuc [rad]",
              "e": "eccentricity e", "cus": "Cus [rad]", "sqrtA": "sqrt(A) [sqrt(m)]", "toe": "Toe [s of week]",
              "cic": "Cic [rad]", "omega0": "OMEGA0 [rad]", "cis": "Cis [rad]", "i0": "i0 [rad]", "crc": "Crc [m]",
              "omega": "omega [rad]", "omega_dot": "OMEGA DOT [rad/s]", "idot": "IDOT [rad/s]",
              "tgd": "group delay TGD / BGD [s]"}


CARRIER_HZ = {"G": {"1": 1575.42e6, "2": 1227.60e6, "5": 1176.45e6},
              "R": {"1": 1602.0e6, "2": 1246.0e6, "3": 1202.025e6, "4": 1600.995e6, "6": 1248.06e6},
              "E": {"1": 1575.42e6, "5": 1176.45e6, "6": 1278.75e6, "7": 1207.14e6, "8": 1191.795e6},
              "C": {"1": 1575.42e6, "2": 1561.098e6, "5": 1176.45e6, "6": 1268.52e6, "7": 1207.14e6,
                    "8": 1191.795e6},
              "J": {"1": 1575.42e6, "2": 1227.60e6, "5": 1176.45e6, "6": 1278.75e6},
              "S": {"1": 1575.42e6, "5": 1176.45e6}, "I": {"5": 1176.45e6, "9": 2492.028e6, "1": 1575.42e6}}
"""Carrier frequency [Hz] per RINEX system letter and band digit, for a Doppler [Hz] as a range rate (GLONASS FDMA
bands at their centre: the channels are within 0.3 %)."""


def check_rinex_epochs(path, rows) -> None:
    """Pseudoranges and Doppler of a RINEX observation file against one receiver clock per epoch (module
    docstring); ``DatasetFormatError`` at the first line no clock explains.

    Parameters
    ----------
    rows : list of ``(epoch index, line, satellite, observable, value)`` of the code (``C..``) and Doppler
        (``D..``) observations to check.
    """
    if not rows:
        return
    ep = np.array([r[0] for r in rows])
    val = np.array([r[4] for r in rows], np.float64)
    sat = [r[2] for r in rows]
    obs = [r[3] for r in rows]
    code = np.array([o[0] == "C" for o in obs])
    big = np.full(val.size, np.inf)
    lo, hi = np.zeros(val.size), big.copy()
    for i in np.flatnonzero(code):
        lo[i], hi[i] = range_window(*ORBIT_RADIUS_M.get(sat[i][0], (23.4e6, 45.4e6)))
    lam = np.array([C_LIGHT / CARRIER_HZ.get(s[0], {}).get(o[1], np.nan) if o[0] == "D" else np.nan
                    for s, o in zip(sat, obs)])
    prr = -lam * val
    dop = ~code & np.isfinite(prr)
    b_lo = np.where(code, val - hi - INTER_SYSTEM_MARGIN_M, prr - RANGE_RATE_MAX_MPS - 0.005 * np.abs(prr) - 1.0)
    b_hi = np.where(code, val - lo + INTER_SYSTEM_MARGIN_M, prr + RANGE_RATE_MAX_MPS + 0.005 * np.abs(prr) + 1.0)
    use = code | dop
    bad, point = common_offset_outliers(np.where(code, 2 * ep, 2 * ep + 1)[use], b_lo[use], b_hi[use])
    limit = np.where(code, CLOCK_MAX_M, CLOCK_DRIFT_MAX_MPS)[use]
    far = (b_lo[use] > limit) | (b_hi[use] < -limit)
    if not (bad | far).any():
        return
    k = int(np.argmax(bad | far))
    i = int(np.flatnonzero(use)[k])
    what, unit = ("pseudorange", "m") if code[i] else ("Doppler", "Hz")
    if code[i]:
        why = (f"the range of a {sat[i][0]} satellite from the Earth is {lo[i] / 1e3:.0f}-{hi[i] / 1e3:.0f} km, which "
               + (f"leaves a receiver clock bias beyond {CLOCK_MAX_M / 1e3:.0f} km (1 s)" if far[k] else
                  f"leaves a receiver clock bias of {(val[i] - hi[i]) / 1e3:.6g} to {(val[i] - lo[i]) / 1e3:.6g} km, "
                  f"but the other pseudoranges of the epoch agree on {point[k] / 1e3:.6g} km"))
    else:
        why = (f"a range rate of {prr[i]:.6g} m/s, which " +
               (f"leaves a receiver clock drift beyond {CLOCK_DRIFT_MAX_MPS:.0f} m/s" if far[k] else
                f"the epoch's other Dopplers and one receiver clock drift cannot explain (the range rate of a "
                f"satellite seen from a receiver at most {RECEIVER_SPEED_MAX_MPS:g} m/s fast is within "
                f"{RANGE_RATE_MAX_MPS:g} m/s)"))
    raise DatasetFormatError(path, rows[i][1], f"{sat[i]} {obs[i]} {what} {float(val[i])!r} {unit} is impossible: {why}")


def range_window(r_sat_lo, r_sat_hi=None):
    """``(lo, hi)`` [m]: the ranges a receiver at :data:`RECEIVER_RADIUS_M` sees a satellite at radius in
    ``[r_sat_lo, r_sat_hi]`` at, at elevations from :data:`MIN_ELEVATION_DEG` up (zenith: ``r - R``; low:
    ``-R sin(el) + sqrt(r^2 - R^2 cos^2(el))``, largest for the smallest ``R``). Arrays broadcast."""
    r_lo = np.asarray(r_sat_lo, np.float64)
    r_hi = r_lo if r_sat_hi is None else np.asarray(r_sat_hi, np.float64)
    R_min, R_max = RECEIVER_RADIUS_M
    el = math.radians(MIN_ELEVATION_DEG)
    lo = r_lo - R_max
    hi = -R_min * math.sin(el) + np.sqrt(r_hi ** 2 - (R_min * math.cos(el)) ** 2)
    return lo, hi


def common_offset_outliers(group, lo, hi):
    """Rows whose interval ``[lo, hi]`` misses the point most intervals of their group share.

    Parameters
    ----------
    group : (K,) group key per row (an epoch); lo, hi : (K,) each row's interval of the group's common offset
        (a receiver clock bias or drift).

    Returns
    -------
    bad : (K,) bool, rows outside their group's best point; point : (K,) that point per row (NaN where the
    group's intervals share one: nothing to report).
    """
    group = np.asarray(group)
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    keys, inv = np.unique(group, return_inverse=True)
    top = np.full(keys.size, -np.inf)
    low = np.full(keys.size, np.inf)
    np.maximum.at(top, inv, lo)
    np.minimum.at(low, inv, hi)
    bad = np.zeros(group.shape, bool)
    point = np.full(group.shape, np.nan)
    for g in np.flatnonzero(top > low):                       # only the groups without a common point
        rows = np.flatnonzero(inv == g)
        cover = (lo[rows][None, :] <= lo[rows][:, None]) & (lo[rows][:, None] <= hi[rows][None, :])
        best = lo[rows][int(np.argmax(cover.sum(1)))]          # the lower end covered by the most intervals
        bad[rows] = (best < lo[rows]) | (best > hi[rows])
        point[rows] = best
    return bad, point


def icd_violation(system: str, name: str, value: float) -> str | None:
    """The message for a broadcast parameter outside :data:`ICD_RANGES` (None when inside or not listed)."""
    lim = ICD_RANGES.get(system, {}).get(name)
    if lim is None:
        return None
    lo, hi = (-lim, lim) if not isinstance(lim, tuple) else lim
    tol = 1e-9 * max(abs(lo), abs(hi))                           # RINEX rounds to 12 digits
    if lo - tol <= value <= hi + tol:
        return None
    return (f"{_NAV_NAMES[name]} = {value:.6g} is outside the range its ICD field holds [{lo:.6g}, {hi:.6g}]: not a "
            f"broadcast value")


def check_track_speed(path, t, r, lines, what: str, max_mps: float) -> None:
    """``DatasetFormatError`` at the first row of a track (``t`` (n,) [s] increasing, ``r`` (n, 3) [m], ``lines``
    (n,) 1-based, or None: rows counted from 1) reached faster than ``max_mps`` from the row before (the message
    names both rows)."""
    t, r = np.asarray(t, np.float64), np.asarray(r, np.float64)
    if t.size < 2:
        return
    dt = np.diff(t)
    step = np.linalg.norm(np.diff(r, axis=0), axis=1)
    fast = (dt > 0) & (step > max_mps * np.maximum(dt, 1e-9))
    if not fast.any():
        return
    i = int(np.argmax(fast))                                    # rows i -> i + 1
    j = i + 1
    v = step[i] / dt[i]
    kind, ia, ib = ("line", int(lines[i]), int(lines[j])) if lines is not None else ("row", i + 1, j + 1)
    raise DatasetFormatError(path, ib if lines is not None else None,
                             f"{what} moves {step[i] / 1e3:.6g} km in {dt[i]:.6g} s ({v:.4g} m/s, more than "
                             f"{max_mps:g} m/s) between {kind} {ia} and {kind} {ib}: position "
                             f"({', '.join(f'{x:.3f}' for x in r[j])}) m is impossible")


def check_truth_near_spp(epochs, t_truth, r_truth, path, line, value: str) -> None:
    """``DatasetFormatError`` naming ``path``:``line`` and ``value`` when the truth lies more than
    :data:`TRUTH_SPP_MAX_M` from the recording's own single-point solution (median over the epochs where both
    exist; nothing to say without such epochs).

    Parameters
    ----------
    epochs : GnssEpochs of the recording (its pseudoranges, satellite positions and sigmas).
    t_truth : (G,) truth times on the epochs' time base [s], increasing; r_truth : (G, 3) ECEF [m].
    path, line, value : what the message names (a truth file and its first row, or a spec file and its key).
    """
    from .spp import solve_spp
    ep = epochs
    t_truth, r_truth = np.asarray(t_truth, np.float64), np.asarray(r_truth, np.float64)
    sol = solve_spp(ep.sat_pos, ep.pr, ep.mask, ep.pr_sigma, ep.system)
    use = sol.valid & (ep.t >= t_truth[0]) & (ep.t <= t_truth[-1]) & np.all(np.isfinite(sol.r_e), -1)
    if not use.any():
        return
    r_at = np.stack([np.interp(ep.t[use], t_truth, r_truth[:, k]) for k in range(3)], -1)
    d = float(np.median(np.linalg.norm(sol.r_e[use] - r_at, axis=1)))
    if d > TRUTH_SPP_MAX_M:
        raise DatasetFormatError(path, line, f"{value}: the truth lies {d / 1e3:.6g} km from the recording's own "
                                             f"single-point solution (median over {int(use.sum())} epochs; more than "
                                             f"{TRUTH_SPP_MAX_M:g} m is not a truth of this recording)")
