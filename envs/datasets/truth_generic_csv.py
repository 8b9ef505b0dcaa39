"""The generic truth CSV: any delimited text with a header line, read through a column map (issue 12).

Spec keys (``[truth]`` with ``format = "csv"``)::

    file = "reference.csv"
    delimiter = ","            # default ","
    comment = "#"              # lines starting with it are skipped (default "#")
    angles = "deg"             # unit of lat / lon / roll / pitch / yaw columns: "deg" (default) or "rad"
    [truth.columns]            # role -> column name of the header line
    week = "GpsWeek"           # time, either GPS week + time of week ...
    cycle = "GpsCycle"         #   optional: the 1024-week rollover count of a 10-bit week
    tow = "GpsTow [s]"
    # utc = "utc"              # ... or UTC date-time ("2023-06-29T11:12:42.5" or "2023-06-29 11:12:42.5")
    lat = "lat"                # position, either geodetic WGS84 (lat, lon, height [m]) ...
    lon = "lon"
    height = "h"
    # x = "x"; y = "y"; z = "z"  ... or ECEF [m]
    vn = "vn"; ve = "ve"; vd = "vd"          # optional velocity: NED [m/s] ... or vx, vy, vz ECEF [m/s]
    roll = "roll"; pitch = "pitch"; yaw = "yaw"   # optional attitude of the body in NED

Time (GPS time of the observation file's week):

* GPS week + TOW: a week below 1024 is a 10-bit week (GPS ICD, 1024-week
  rollover: 1999-08-22 and 2019-04-07). With a ``cycle`` column the full week
  is ``cycle * 1024 + week``; without one, the rollover count is the one that
  puts the week nearest the observation file's week (the recording and its
  truth are from the same days), and the resolved week must be within one
  week of it. A full week (>= 1024) is used as it is.
* UTC: GPS = UTC + the leap seconds in force (:data:`LEAP_SECONDS`, GPS - UTC
  = 18 s since 2017-01-01).

Like the other loaders it is all or nothing: a bad cell raises
:class:`~envs.datasets.errors.DatasetFormatError` naming the file, the line
and the column.
"""
from __future__ import annotations

import math

import numpy as np

from earth import C_en, geodetic_to_ecef

from .errors import DatasetFormatError, require_file
from .rinex import GPS_EPOCH

__all__ = ["CSV_OPTIONS", "COLUMN_ROLES", "LEAP_SECONDS", "check_csv_options", "read_csv_truth",
           "resolve_gps_week", "utc_to_gps_seconds", "read_columns", "column_gps_times"]

CSV_OPTIONS = ("columns", "delimiter", "comment", "angles")
_GROUPS = {"time": (("week", "tow"), ("utc",)), "position": (("x", "y", "z"), ("lat", "lon", "height")),
           "velocity": (("vx", "vy", "vz"), ("vn", "ve", "vd")), "attitude": (("roll", "pitch", "yaw"),)}
COLUMN_ROLES = ("week", "cycle", "tow", "utc", "x", "y", "z", "lat", "lon", "height", "vx", "vy", "vz", "vn", "ve",
                "vd", "roll", "pitch", "yaw")
LEAP_SECONDS = (("1981-07-01", 1), ("1982-07-01", 2), ("1983-07-01", 3), ("1985-07-01", 4), ("1988-01-01", 5),
                ("1990-01-01", 6), ("1991-01-01", 7), ("1992-07-01", 8), ("1993-07-01", 9), ("1994-07-01", 10),
                ("1996-01-01", 11), ("1997-07-01", 12), ("1999-01-01", 13), ("2006-01-01", 14),
                ("2009-01-01", 15), ("2012-07-01", 16), ("2015-07-01", 17), ("2017-01-01", 18))
"""(UTC date from which it holds, GPS - UTC [s]) (IERS Bulletin C; none announced after 2017-01-01)."""
WEEK_NS = 604_800 * 10**9


def _group(cols: dict, name: str, required: bool):
    """The one complete role set of group ``name`` present in ``cols`` (ValueError '<key>: msg' otherwise)."""
    sets = _GROUPS[name]
    present = [s for s in sets if any(r in cols for r in s)]
    if not present:
        if required:
            alts = " or ".join("(" + ", ".join(s) + ")" for s in sets)
            raise ValueError(f"columns: the {name} columns are missing: give {alts}")
        return None
    if len(present) > 1:
        raise ValueError(f"columns: give one {name} set, not both {present[0]} and {present[1]}")
    missing = [r for r in present[0] if r not in cols]
    if missing:
        raise ValueError(f"columns.{missing[0]}: missing (the {name} set {present[0]} is incomplete)")
    return present[0]


def check_csv_options(opts: dict) -> None:
    """Validate the generic CSV keys (module docstring); ``ValueError('<key>: <message>')``."""
    bad = sorted(set(opts) - set(CSV_OPTIONS))
    if bad:
        raise ValueError(f"{bad[0]}: unknown key for the csv truth; known: {', '.join(CSV_OPTIONS)}")
    cols = opts.get("columns")
    if not isinstance(cols, (dict, tuple)):
        raise ValueError("columns: missing: a [truth.columns] table mapping roles to header names")
    cols = dict(cols)
    for k, v in cols.items():
        if k not in COLUMN_ROLES:
            raise ValueError(f"columns.{k}: unknown role; known: {', '.join(COLUMN_ROLES)}")
        if not isinstance(v, str) or not v.strip():
            raise ValueError(f"columns.{k}: must be a column name, got {v!r}")
    for g in ("time", "position"):
        _group(cols, g, True)
    _group(cols, "velocity", False)
    _group(cols, "attitude", False)
    if "cycle" in cols and "week" not in cols:
        raise ValueError("columns.cycle: goes with a week column")
    for k in ("delimiter", "comment"):
        if k in opts and not (isinstance(opts[k], str) and len(opts[k]) == 1):
            raise ValueError(f"{k}: must be one character, got {opts[k]!r}")
    if opts.get("angles", "deg") not in ("deg", "rad"):
        raise ValueError(f"angles: must be 'deg' or 'rad', got {opts['angles']!r}")


def resolve_gps_week(week, cycle, week_ref: int, path=None) -> np.ndarray:
    """Full GPS weeks of (G,) ``week`` (module docstring: 10-bit weeks with or without a rollover ``cycle``).

    Raises
    ------
    DatasetFormatError : a 10-bit week that no rollover puts within one week of ``week_ref``.
    """
    week = np.asarray(week, np.int64)
    if cycle is not None:
        full = np.asarray(cycle, np.int64) * 1024 + np.where(week < 1024, week, week % 1024)
    else:
        ten = week < 1024
        k = np.rint((week_ref - week) / 1024.0).astype(np.int64)
        full = np.where(ten, week + 1024 * np.maximum(k, 0), week)
    off = np.abs(full - week_ref) > 1
    if off.any():
        i = int(np.argmax(off))
        raise DatasetFormatError(path, None, f"GPS week {int(week[i])} resolves to {int(full[i])}, more than one "
                                             f"week from the observation file's week {week_ref}")
    return full


def utc_to_gps_seconds(utc, week_ref: int) -> np.ndarray:
    """UTC datetime64 values -> GPS seconds since the start of GPS week ``week_ref`` (leap seconds applied)."""
    ns = (np.asarray(utc).astype("datetime64[ns]") - GPS_EPOCH).astype(np.int64)
    dates = np.array([np.datetime64(d, "ns") for d, _ in LEAP_SECONDS])
    steps = np.array([s for _, s in LEAP_SECONDS], np.int64)
    idx = np.searchsorted(dates, np.asarray(utc).astype("datetime64[ns]"), side="right")
    leap = np.where(idx > 0, steps[np.maximum(idx - 1, 0)], 0)
    return (ns + leap * 10**9 - np.int64(week_ref) * WEEK_NS).astype(np.float64) * 1e-9


def read_columns(path, cols: dict, delim: str = ",", comment: str = "#", key: str = "truth.columns",
                 min_rows: int = 5):
    """The mapped columns of a delimited text file with a header line, all or nothing.

    Parameters
    ----------
    path : the file; cols : {role: header name}; delim, comment : one character each;
    key : the spec key of the column map (named in errors); min_rows : fewest data rows accepted.

    Returns
    -------
    num : {role: (G,) float64} every role but ``'utc'`` (finite numbers).
    utc : (G,) datetime64[ns] or None, the ``'utc'`` role parsed as ISO 8601.
    where : (G,) int, the 1-based line number of each row.

    Raises
    ------
    DatasetFormatError : naming the file, the line and the column.
    """
    path = require_file(path)
    lines = path.read_text(encoding="utf-8", errors="replace").split("\n")
    if lines[-1].strip():
        raise DatasetFormatError(path, len(lines), "last line has no line end: the file is truncated")
    header, idx, rows, where = None, {}, [], []
    for i, ln in enumerate(lines[:-1], start=1):
        s = ln.strip()
        if not s or s.startswith(comment):
            continue
        tok = [x.strip() for x in s.split(delim)]
        if header is None:
            header = tok
            for role, name in cols.items():
                if name.strip() not in header:
                    raise DatasetFormatError(path, i, f"column {name!r} ({key}.{role}) is not in the "
                                                      f"header {header[:8]}{' ...' if len(header) > 8 else ''}")
                idx[role] = header.index(name.strip())
            continue
        if len(tok) < len(header):
            raise DatasetFormatError(path, i, f"row has {len(tok)} fields, the header {len(header)}")
        rows.append([tok[j] for j in idx.values()])
        where.append(i)
    if header is None:
        raise DatasetFormatError(path, None, "no header line")
    if len(rows) < min_rows:
        raise DatasetFormatError(path, None, f"{len(rows)} rows; at least {min_rows} are needed")
    roles = list(idx)
    text = np.array(rows, dtype=object)
    num, utc = {}, None
    for j, role in enumerate(roles):
        if role == "utc":
            continue
        vals = np.empty(len(rows))
        for k, x in enumerate(text[:, j]):
            try:
                vals[k] = float(x)
            except ValueError:
                raise DatasetFormatError(path, where[k], f"{cols[role]!r}: {x[:40]!r} is not a number") from None
            if not math.isfinite(vals[k]):
                raise DatasetFormatError(path, where[k], f"{cols[role]!r}: non-finite number")
        num[role] = vals
    if "utc" in idx:
        utc = np.empty(len(rows), "datetime64[ns]")
        for k, x in enumerate(text[:, roles.index("utc")]):
            try:
                utc[k] = np.datetime64(x.replace(" ", "T").rstrip("Z"), "ns")
            except ValueError:
                raise DatasetFormatError(path, where[k], f"{cols['utc']!r}: {x[:40]!r} is not an ISO 8601 "
                                                         f"UTC date-time") from None
    return num, utc, np.asarray(where, np.int64)


def column_gps_times(path, cols: dict, num: dict, utc, where, week_ref: int) -> np.ndarray:
    """GPS seconds since the start of week ``week_ref`` of rows read by :func:`read_columns`, from the
    ``utc`` role or the ``week`` (+ ``cycle``) and ``tow`` roles (module docstring); errors name the line."""
    if utc is not None:
        return utc_to_gps_seconds(utc, week_ref)
    for k, w in enumerate(num["week"]):
        if w != round(w) or w < 0:
            raise DatasetFormatError(path, where[k], f"{cols['week']!r}: GPS week must be a non-negative "
                                                     f"integer, got {w!r}")
        if not 0.0 <= num["tow"][k] < 604800.0:
            raise DatasetFormatError(path, where[k], f"{cols['tow']!r}: time of week must be in "
                                                     f"[0, 604800) s, got {num['tow'][k]!r}")
    week = resolve_gps_week(num["week"], num.get("cycle"), week_ref, path)
    return (week - week_ref) * 604800.0 + num["tow"]


def read_csv_truth(spec, week_ref: int, span):
    """Read the generic truth CSV of ``spec`` (a :class:`~envs.datasets.spec.TruthSpec`; module docstring)."""
    from .truth_readers import TruthTrack
    opts = dict(spec.options)
    cols = dict(opts["columns"])
    ang = math.pi / 180.0 if opts.get("angles", "deg") == "deg" else 1.0
    path = require_file(spec.file)
    num, utc, where = read_columns(path, cols, opts.get("delimiter", ","), opts.get("comment", "#"))
    t = column_gps_times(path, cols, num, utc, where, week_ref)
    back = np.diff(t) <= 0
    if back.any():
        raise DatasetFormatError(path, where[int(np.argmax(back)) + 1], "time does not increase")
    if "x" in num:
        r = np.stack([num["x"], num["y"], num["z"]], -1)
        from earth import ecef_to_geodetic
        lat, lon, _ = ecef_to_geodetic(r)
    else:
        lat, lon = num["lat"] * ang, num["lon"] * ang
        bad = np.abs(lat) > math.pi / 2
        if bad.any():
            raise DatasetFormatError(path, where[int(np.argmax(bad))], f"{cols['lat']!r}: latitude beyond 90 deg "
                                                                       f"(angles = {opts.get('angles', 'deg')!r})")
        r = geodetic_to_ecef(lat, lon, num["height"])
    far = ~((6.2e6 < np.linalg.norm(r, axis=-1)) & (np.linalg.norm(r, axis=-1) < 6.5e6))
    if far.any():
        raise DatasetFormatError(path, where[int(np.argmax(far))], "position is not near the Earth's surface")
    v = None
    if "vx" in num:
        v = np.stack([num["vx"], num["vy"], num["vz"]], -1)
    elif "vn" in num:
        v_n = np.stack([num["vn"], num["ve"], num["vd"]], -1)
        v = (C_en(lat, lon) @ v_n[..., None])[..., 0]
    rpy = np.stack([num["roll"], num["pitch"], num["yaw"]], -1) * ang if "roll" in num else None
    return TruthTrack(t=t, r_e=np.asarray(r, np.float64), v_e=v, rpy=rpy, source=str(path), lines=where)
