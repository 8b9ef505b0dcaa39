"""The smartLoc data set (TU Chemnitz, CC BY-SA 4.0): loader for its ``*_Input.txt`` / ``*_GT.txt`` files.

P. Reisdorf, T. Pfeifer, J. Bressler, S. Bauer, P. Weissig, S. Lange, P. Protzel,
G. Wanielik, "The Problem of Comparable GNSS Results - An Approach for a
Uniform Dataset with Low-Cost and Reference Data", Proc. VEHICULAR 2016.

Each line is one measurement, whitespace separated, its first token the row
type (the readme of the data folder defines the columns):

================  =============  ===========================================================================
row type          file           numeric columns (after the type)
================  =============  ===========================================================================
``pseudorange3``  ``*_Input``    t [s], pseudorange [m], its variance [m^2], satellite ECEF x, y, z [m],
                                 satellite id, system (1 GPS, 2 SBAS, 4 GLONASS, 8 Galileo, 16 QZSS,
                                 32 BeiDou), elevation [deg], C/N0 [dB-Hz]  (10 numbers)
``odom3``         ``*_Input``    t [s], velocity x, y, z [m/s], turn rate x, y, z [rad/s], their six
                                 variances [(m/s)^2, (rad/s)^2]  (13 numbers)
``point3``        ``*_GT``       t [s], ego ECEF x, y, z [m], 3x3 covariance row-major (zeros)  (13 numbers)
================  =============  ===========================================================================

Units and frames as loaded (checked against the ground truth, see
``tests/envs/test_datasets.py``):

* pseudoranges have the atmospheric delays and the satellite clock removed;
  the receiver clock (a common bias per epoch, drifting at about -50 m/s in
  Potsdamer Platz) remains;
* satellite positions are ECEF at the transmission time, in the ECEF frame
  of that time (the Sagnac rotation is *not* applied: residuals against the
  ground truth are smaller with :func:`earth.ranging.range_and_rate` than with
  a plain distance);
* odometry is in the vehicle frame: x forward [m/s]; the turn rate z is
  about the *up* axis (positive = left turn, counter-clockwise seen from
  above: it has the opposite sign of the NED heading rate of the ground
  truth); only x velocity and z turn rate are non-zero in the recording;
* the ground truth (NovAtel SPAN) is the ECEF position at the same time
  stamps as the pseudorange epochs; its covariance columns are zeros.

Loading is all or nothing: any problem raises before anything is returned.
A missing file raises ``FileNotFoundError`` naming it; a truncated file (last
line without its line end), a corrupted line (wrong column count, a token that
is not a finite number, a value out of its range, time going backwards) or an
unknown row type raise :class:`~envs.datasets.errors.DatasetFormatError`
naming the file and the line. So does a physically impossible value
(:mod:`envs.datasets.plausibility`): a pseudorange no receiver clock common to
its epoch explains, a satellite or the ground truth jumping faster than it can
move, an odometry speed no vehicle reaches, a C/N0 above 80 dB-Hz, or a ground
truth more than 1 km from the recording's own single-point solution.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .epochs import SYS_BEIDOU, SYS_GALILEO, SYS_GLONASS, SYS_GPS, SYS_QZSS, SYS_SBAS, GnssEpochs, pack_epochs, \
    satellite_velocities
from .errors import DatasetFormatError, require_file, shared_data_dir
from .plausibility import (CLOCK_MAX_M, CN0_MAX_DBHZ, INTER_SYSTEM_MARGIN_M, RECEIVER_SPEED_MAX_MPS, SAT_SPEED_MAX_MPS,
                           TRUTH_SPEED_MAX_MPS, check_track_speed, check_truth_near_spp, common_offset_outliers,
                           range_window)
from .validate import check_smartloc

__all__ = ["SmartLocPseudoranges", "SmartLocOdometry", "SmartLocGroundTruth", "SmartLocData", "load_smartloc",
           "smartloc_dir", "POTSDAMER_PLATZ"]

POTSDAMER_PLATZ = "Berlin_Potsdamer_Platz"
"""File stem of the Berlin Potsdamer Platz recording."""

_N_NUMBERS = {"pseudorange3": 10, "odom3": 13, "point3": 13}
_INPUT_TYPES = ("pseudorange3", "odom3")
_GT_TYPES = ("point3",)
_SYSTEMS = (SYS_GPS, SYS_SBAS, SYS_GLONASS, SYS_GALILEO, SYS_QZSS, SYS_BEIDOU)
ODOMETRY_TURN_RATE_MAX_RPS = 10.0
"""Largest recorded turn rate of the vehicle [rad/s] (a car turns below 1 rad/s)."""


@dataclass(frozen=True)
class SmartLocPseudoranges:
    """``pseudorange3`` rows (K of them), in file order.

    Attributes
    ----------
    t : (K,) time stamp [s]; pr : (K,) pseudorange [m]; pr_var : (K,) its variance [m^2];
    sat_pos : (K, 3) satellite ECEF position [m]; sat_id : (K,) int64; system : (K,) int64 code;
    elevation_deg : (K,) [deg]; cn0_dbhz : (K,) [dB-Hz]; line : (K,) int64 1-based source line.
    """

    t: np.ndarray
    pr: np.ndarray
    pr_var: np.ndarray
    sat_pos: np.ndarray
    sat_id: np.ndarray
    system: np.ndarray
    elevation_deg: np.ndarray
    cn0_dbhz: np.ndarray
    line: np.ndarray


@dataclass(frozen=True)
class SmartLocOdometry:
    """``odom3`` rows (L of them), vehicle frame (x forward, z up; see the module docstring).

    Attributes
    ----------
    t : (L,) [s]; velocity : (L, 3) [m/s]; turn_rate : (L, 3) [rad/s];
    velocity_var : (L, 3) [m^2/s^2]; turn_rate_var : (L, 3) [rad^2/s^2]; line : (L,) int64.
    """

    t: np.ndarray
    velocity: np.ndarray
    turn_rate: np.ndarray
    velocity_var: np.ndarray
    turn_rate_var: np.ndarray
    line: np.ndarray

    def frd_at(self, t):
        """Forward speed and yaw rate in the body FRD convention at times ``t``, for an odometer update.

        Linear interpolation between the recorded samples (held beyond the ends); the yaw rate is
        returned about the body z axis pointing *down* (FRD, positive = right turn): the recorded z
        turn rate (about up) with its sign flipped.

        Parameters
        ----------
        t : (n,) times [s] (the recording's time stamps).

        Returns
        -------
        speed : (n,) [m/s]; yaw_rate : (n,) [rad/s]; speed_var : (n,) [m^2/s^2]; yaw_rate_var : (n,) [rad^2/s^2].
        """
        t = np.asarray(t, np.float64)
        if self.t.size == 0:
            raise ValueError("no odometry rows")
        return (np.interp(t, self.t, self.velocity[:, 0]), -np.interp(t, self.t, self.turn_rate[:, 2]),
                np.interp(t, self.t, self.velocity_var[:, 0]), np.interp(t, self.t, self.turn_rate_var[:, 2]))


@dataclass(frozen=True)
class SmartLocGroundTruth:
    """``point3`` rows (G of them): t (G,) [s], r_e (G, 3) ECEF [m], line (G,) int64."""

    t: np.ndarray
    r_e: np.ndarray
    line: np.ndarray


@dataclass(frozen=True)
class SmartLocData:
    """One smartLoc recording, fully loaded and validated.

    Attributes
    ----------
    name : file stem (e.g. ``'Berlin_Potsdamer_Platz'``).
    input_path, gt_path : the two files.
    pseudoranges, odometry, ground_truth : the rows.
    """

    name: str
    input_path: Path
    gt_path: Path
    pseudoranges: SmartLocPseudoranges
    odometry: SmartLocOdometry
    ground_truth: SmartLocGroundTruth

    @property
    def duration_s(self) -> float:
        """Time span of the ground truth [s]."""
        return float(self.ground_truth.t[-1] - self.ground_truth.t[0])

    def epochs(self, systems=(SYS_GPS, SYS_GLONASS), min_elevation_deg: float = 0.0,
               min_cn0_dbhz: float = 0.0) -> GnssEpochs:
        """The pseudoranges grouped into epochs (rows with equal time stamps), as :class:`GnssEpochs`.

        Satellite velocities are derived from the recorded positions
        (:func:`~envs.datasets.epochs.satellite_velocities`); ``pr_sigma`` is
        the square root of the recorded variance; the recorded elevation is
        kept (converted to radians).

        Parameters
        ----------
        systems : system codes to keep (default GPS and GLONASS, all this recording has).
        min_elevation_deg : drop measurements below this recorded elevation [deg].
        min_cn0_dbhz : drop measurements below this C/N0 [dB-Hz].
        """
        p = self.pseudoranges
        systems = tuple(int(s) for s in systems)
        bad = [s for s in systems if s not in _SYSTEMS]
        if bad:
            raise ValueError(f"systems: unknown system code(s) {bad}; known {list(_SYSTEMS)}")
        for name, v in (("min_elevation_deg", min_elevation_deg), ("min_cn0_dbhz", min_cn0_dbhz)):
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not math.isfinite(v):
                raise ValueError(f"{name} must be a finite number, got {v!r}")
        t, _, c = pack_epochs(p.t, p.system, p.sat_id, {
            "sat_pos": p.sat_pos, "pr": p.pr, "pr_var": p.pr_var, "sat_id": p.sat_id, "system": p.system,
            "elevation": np.radians(p.elevation_deg), "cn0": p.cn0_dbhz, "valid": np.ones(p.t.size, bool)},
            what=str(self.input_path))
        mask = c["valid"]
        key = c["system"] * 100_000 + c["sat_id"]
        sat_vel = satellite_velocities(t, c["sat_pos"], key, mask)
        sat_id = np.where(mask, c["sat_id"], -1)
        ep = GnssEpochs(t=t, sat_pos=c["sat_pos"], sat_vel=sat_vel, pr=c["pr"], pr_sigma=np.sqrt(c["pr_var"]),
                        mask=mask, sat_id=sat_id, system=c["system"], elevation=c["elevation"], cn0=c["cn0"],
                        t0_gps=None, source=f"smartLoc {self.name}")
        keep = (np.isin(c["system"], systems) & (c["elevation"] >= math.radians(min_elevation_deg))
                & (c["cn0"] >= min_cn0_dbhz))
        return ep.keep(keep)


def smartloc_dir() -> Path:
    """``<shared data>/smartloc`` (may not exist; see :func:`~envs.datasets.errors.shared_data_dir`)."""
    return shared_data_dir() / "smartloc"


def _read_rows(path: Path, types: tuple) -> dict:
    """Parse one smartLoc text file strictly; return type -> (numbers (n, k) float64, lines (n,) int64)."""
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError as exc:
        line = path.read_bytes()[:exc.start].count(b"\n") + 1
        raise DatasetFormatError(path, line, "non-ASCII byte: corrupted file") from None
    lines = text.split("\n")
    if lines[-1].strip():
        raise DatasetFormatError(path, len(lines), "last line has no line end: the file is truncated")
    rows = {k: [] for k in types}
    nums = {k: [] for k in types}
    for i, ln in enumerate(lines[:-1], start=1):
        tok = ln.split()
        if not tok:
            continue
        kind = tok[0]
        if kind not in rows:
            known = ", ".join(types)
            other = "" if kind not in _N_NUMBERS else f" (a {kind} row belongs in another file)"
            raise DatasetFormatError(path, i, f"unknown row type {kind[:40]!r}{other}; expected one of {known}")
        n = _N_NUMBERS[kind]
        if len(tok) != n + 1:
            raise DatasetFormatError(path, i, f"{kind} row has {len(tok) - 1} numbers, expected {n}")
        rows[kind].append(i)
        nums[kind].append(tok[1:])
    if not any(rows.values()):
        raise DatasetFormatError(path, None, "no data rows")
    out = {}
    for kind in types:
        ln = np.asarray(rows[kind], np.int64)
        try:
            a = np.fromiter((float(x) for row in nums[kind] for x in row), np.float64,
                            count=len(ln) * _N_NUMBERS[kind]).reshape(len(ln), _N_NUMBERS[kind])
        except ValueError:
            for j, toks in enumerate(nums[kind]):  # find the culprit only on failure
                for tk in toks:
                    try:
                        float(tk)
                    except ValueError:
                        raise DatasetFormatError(path, ln[j], f"{kind} row: {tk[:40]!r} is not a number") from None
            raise
        bad = ~np.isfinite(a)
        if bad.any():
            j = int(np.argmax(bad.any(1)))
            raise DatasetFormatError(path, ln[j], f"{kind} row holds a non-finite number")
        if a.shape[0] > 1:
            back = np.diff(a[:, 0]) < 0
            if back.any():
                j = int(np.argmax(back)) + 1
                raise DatasetFormatError(path, ln[j], f"{kind} time stamp {a[j, 0]!r} goes back in time "
                                                      f"(previous {a[j - 1, 0]!r})")
        out[kind] = (a, ln)
    return out


def _check(path, a, ln, cond, what, col=None):
    """``DatasetFormatError`` at the first row where ``cond`` is False (with ``col``: naming its value)."""
    if not np.all(cond):
        j = int(np.argmin(cond))
        raise DatasetFormatError(path, ln[j], what if col is None else f"{what}, got {float(a[j, col])!r}")


def _plausible_pseudoranges(path, a, ln, rs) -> None:
    """Each epoch's pseudoranges against what the orbits and one common receiver clock allow
    (:mod:`envs.datasets.plausibility`): the first row that no clock of its epoch explains is named."""
    lo, hi = range_window(rs)
    b_lo, b_hi = a[:, 1] - hi, a[:, 1] - lo                     # the receiver clock bias each row allows [m]
    bad, clock = common_offset_outliers(a[:, 0], b_lo - INTER_SYSTEM_MARGIN_M, b_hi + INTER_SYSTEM_MARGIN_M)
    far = (b_lo > CLOCK_MAX_M) | (b_hi < -CLOCK_MAX_M)
    if not (bad | far).any():
        return
    j = int(np.argmax(bad | far))
    why = (f"a receiver clock bias beyond {CLOCK_MAX_M / 1e3:.0f} km (1 s)" if far[j] else
           f"a receiver clock bias of {b_lo[j] / 1e3:.6g} to {b_hi[j] / 1e3:.6g} km, but the other pseudoranges of "
           f"its epoch agree on {clock[j] / 1e3:.6g} km")
    raise DatasetFormatError(path, ln[j], f"pseudorange3: pseudorange {float(a[j, 1])!r} m of satellite {int(a[j, 6])} "
                                          f"(system {int(a[j, 7])}) is impossible: its satellite, {rs[j] / 1e3:.0f} km "
                                          f"from the Earth's centre, lies {lo[j] / 1e3:.0f}-{hi[j] / 1e3:.0f} km from "
                                          f"any receiver on the Earth, which leaves {why}")


def _plausible_satellite_tracks(path, a, ln) -> None:
    """Each satellite's recorded positions move at most :data:`SAT_SPEED_MAX_MPS` between its rows."""
    key = a[:, 7] * 1000 + a[:, 6]
    for k in np.unique(key):
        rows = np.flatnonzero(key == k)
        check_track_speed(path, a[rows, 0], a[rows, 3:6], ln[rows],
                          f"pseudorange3: satellite {int(a[rows[0], 6])} (system {int(a[rows[0], 7])})",
                          SAT_SPEED_MAX_MPS)


def _pseudoranges(path, a, ln) -> SmartLocPseudoranges:
    _check(path, a, ln, a[:, 1] > 0, "pseudorange3: pseudorange must be > 0")
    _check(path, a, ln, a[:, 2] > 0, "pseudorange3: pseudorange variance must be > 0")
    rs = np.linalg.norm(a[:, 3:6], axis=1)
    _check(path, a, ln, (rs > 1.0e7) & (rs < 5.0e7), "pseudorange3: satellite position is not a GNSS orbit "
                                                     "(|r| outside 1e4..5e4 km)")
    _check(path, a, ln, (a[:, 6] == np.round(a[:, 6])) & (a[:, 6] > 0), "pseudorange3: satellite id must be a "
                                                                        "positive integer")
    _check(path, a, ln, np.isin(a[:, 7], _SYSTEMS), f"pseudorange3: system must be one of {list(_SYSTEMS)}")
    _check(path, a, ln, np.abs(a[:, 8]) <= 90.0, "pseudorange3: elevation must be within [-90, 90] deg")
    _check(path, a, ln, a[:, 9] >= 0, "pseudorange3: C/N0 must be >= 0")
    _check(path, a, ln, a[:, 9] <= CN0_MAX_DBHZ, f"pseudorange3: C/N0 must be <= {CN0_MAX_DBHZ:g} dB-Hz (GNSS signals "
                                                f"arrive below 55 dB-Hz)", col=9)
    _plausible_pseudoranges(path, a, ln, rs)
    _plausible_satellite_tracks(path, a, ln)
    return SmartLocPseudoranges(t=a[:, 0].copy(), pr=a[:, 1].copy(), pr_var=a[:, 2].copy(), sat_pos=a[:, 3:6].copy(),
                                sat_id=a[:, 6].astype(np.int64), system=a[:, 7].astype(np.int64),
                                elevation_deg=a[:, 8].copy(), cn0_dbhz=a[:, 9].copy(), line=ln)


def _odometry(path, a, ln) -> SmartLocOdometry:
    _check(path, a, ln, np.all(a[:, 7:13] >= 0, axis=1), "odom3: variances must be >= 0")
    speed = np.linalg.norm(a[:, 1:4], axis=1)
    _check(path, a, ln, speed <= RECEIVER_SPEED_MAX_MPS, f"odom3: velocity must be at most {RECEIVER_SPEED_MAX_MPS:g} "
                                                         f"m/s (a vehicle)", col=1)
    _check(path, a, ln, np.linalg.norm(a[:, 4:7], axis=1) <= ODOMETRY_TURN_RATE_MAX_RPS,
           f"odom3: turn rate must be at most {ODOMETRY_TURN_RATE_MAX_RPS:g} rad/s (a vehicle)", col=6)
    return SmartLocOdometry(t=a[:, 0].copy(), velocity=a[:, 1:4].copy(), turn_rate=a[:, 4:7].copy(),
                            velocity_var=a[:, 7:10].copy(), turn_rate_var=a[:, 10:13].copy(), line=ln)


def _ground_truth(path, a, ln) -> SmartLocGroundTruth:
    rr = np.linalg.norm(a[:, 1:4], axis=1)
    _check(path, a, ln, (rr > 6.2e6) & (rr < 6.5e6), "point3: position is not near the Earth's surface")
    if a.shape[0] > 1:
        _check(path, a[1:], ln[1:], np.diff(a[:, 0]) > 0, "point3: time stamps must be strictly increasing")
    check_track_speed(path, a[:, 0], a[:, 1:4], ln, "point3: the ground truth", TRUTH_SPEED_MAX_MPS)
    return SmartLocGroundTruth(t=a[:, 0].copy(), r_e=a[:, 1:4].copy(), line=ln)


def load_smartloc(folder=None, name: str = POTSDAMER_PLATZ) -> SmartLocData:
    """Load and validate ``<folder>/<name>_Input.txt`` and ``<folder>/<name>_GT.txt``.

    Parameters
    ----------
    folder : the smartLoc folder (default :func:`smartloc_dir`).
    name : the recording's file stem.

    Returns
    -------
    SmartLocData

    Raises
    ------
    FileNotFoundError : a file is missing (the message names it).
    DatasetFormatError : a truncated or corrupted file, an unknown row type (the message names file and line).
    """
    folder = smartloc_dir() if folder is None else Path(folder)
    inp = require_file(folder / f"{name}_Input.txt")
    gtp = require_file(folder / f"{name}_GT.txt")
    rows = _read_rows(inp, _INPUT_TYPES)
    gt_rows = _read_rows(gtp, _GT_TYPES)
    if rows["pseudorange3"][0].shape[0] == 0:
        raise DatasetFormatError(inp, None, "no pseudorange3 rows")
    pr = _pseudoranges(inp, *rows["pseudorange3"])
    od = _odometry(inp, *rows["odom3"])
    gt = _ground_truth(gtp, *gt_rows["point3"])
    check_smartloc(inp, gtp, pr, od, gt)  # spans both ways (file and line), repeated rows (issue 13)
    if pr.t[0] < gt.t[0] or pr.t[-1] > gt.t[-1]:
        raise DatasetFormatError(gtp, None, f"ground truth spans [{gt.t[0]}, {gt.t[-1]}] s but the pseudoranges "
                                            f"span [{pr.t[0]}, {pr.t[-1]}] s: truncated ground truth")
    data = SmartLocData(name=name, input_path=inp, gt_path=gtp, pseudoranges=pr, odometry=od, ground_truth=gt)
    check_truth_near_spp(data.epochs(systems=tuple(int(s) for s in np.unique(pr.system))), gt.t, gt.r_e, gtp,
                         int(gt.line[0]), f"point3 rows from ({', '.join(f'{x:.3f}' for x in gt.r_e[0])}) m")
    return data
