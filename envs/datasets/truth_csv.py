"""The reference-trajectory CSV of a generic RINEX replay: GPS time and ECEF position per row.

Format (ASCII, comma separated, one header line; lines starting with ``#`` are
comments and may appear anywhere)::

    # any comment
    gps_week,tow_s,x_m,y_m,z_m
    2268,385962.0,4157190.12,671190.25,4774770.31
    ...

* ``gps_week`` : GPS week number (integer, continuous since 1980-01-06, no 1024 rollover);
* ``tow_s`` : GPS time of week [s], in [0, 604800);
* ``x_m, y_m, z_m`` : WGS84 ECEF position of the antenna [m].

At least 5 rows (the smoothing spline of :mod:`envs.datasets.spline_truth`
needs them), times strictly increasing. Like the smartLoc loader it is all or
nothing: a missing file raises ``FileNotFoundError``, anything else
:class:`~envs.datasets.errors.DatasetFormatError` naming the file and line.
"""
from __future__ import annotations

import math

import numpy as np

from .ephemeris import WEEK_S
from .errors import DatasetFormatError, require_file

__all__ = ["TRUTH_CSV_HEADER", "load_truth_csv", "read_truth_csv_rows", "write_truth_csv"]

TRUTH_CSV_HEADER = "gps_week,tow_s,x_m,y_m,z_m"


def load_truth_csv(path, week_ref: int):
    """Read a truth CSV (module docstring).

    Parameters
    ----------
    path : the file.
    week_ref : GPS week the returned times count from.

    Returns
    -------
    t : (G,) GPS seconds since the start of week ``week_ref``; r_e : (G, 3) ECEF [m].
    """
    t, r, _ = read_truth_csv_rows(path, week_ref)
    return t, r


def read_truth_csv_rows(path, week_ref: int):
    """:func:`load_truth_csv` and the 1-based line of each row: ``(t, r_e, lines (G,) int64)``."""
    path = require_file(path)
    text = path.read_text(encoding="ascii", errors="replace")
    lines = text.split("\n")
    if lines[-1].strip():
        raise DatasetFormatError(path, len(lines), "last line has no line end: the file is truncated")
    header_seen = False
    rows, where = [], []
    for i, ln in enumerate(lines[:-1], start=1):
        s = ln.strip()
        if not s or s.startswith("#"):
            continue
        if not header_seen:
            if s.replace(" ", "") != TRUTH_CSV_HEADER:
                raise DatasetFormatError(path, i, f"expected the header {TRUTH_CSV_HEADER!r}, got {s[:60]!r}")
            header_seen = True
            continue
        tok = s.split(",")
        if len(tok) != 5:
            raise DatasetFormatError(path, i, f"row has {len(tok)} fields, expected 5")
        try:
            vals = [float(x) for x in tok]
        except ValueError:
            bad = next(x for x in tok if not _is_float(x))
            raise DatasetFormatError(path, i, f"{bad.strip()[:40]!r} is not a number") from None
        if not all(math.isfinite(v) for v in vals):
            raise DatasetFormatError(path, i, "non-finite number")
        if vals[0] != round(vals[0]) or vals[0] < 0:
            raise DatasetFormatError(path, i, f"gps_week must be a non-negative integer, got {tok[0]!r}")
        if not 0.0 <= vals[1] < WEEK_S:
            raise DatasetFormatError(path, i, f"tow_s must be in [0, 604800), got {vals[1]!r}")
        if not 6.2e6 < math.sqrt(vals[2] ** 2 + vals[3] ** 2 + vals[4] ** 2) < 6.5e6:
            raise DatasetFormatError(path, i, "position is not near the Earth's surface (ECEF metres expected)")
        rows.append(vals)
        where.append(i)
    if not header_seen:
        raise DatasetFormatError(path, None, f"no header line {TRUTH_CSV_HEADER!r}")
    if len(rows) < 5:
        raise DatasetFormatError(path, None, f"{len(rows)} rows; at least 5 are needed")
    a = np.array(rows)
    t = (a[:, 0] - week_ref) * WEEK_S + a[:, 1]
    back = np.diff(t) <= 0
    if back.any():
        j = int(np.argmax(back)) + 1
        raise DatasetFormatError(path, where[j], "time does not increase")
    return t, a[:, 2:5].copy(), np.asarray(where, np.int64)


def _is_float(x: str) -> bool:
    try:
        float(x)
        return True
    except ValueError:
        return False


def write_truth_csv(path, gps_week, tow_s, r_e, comment: str | None = None) -> None:
    """Write a truth CSV (module docstring) from (G,) weeks, (G,) times of week [s] and (G, 3) ECEF [m]."""
    gps_week = np.broadcast_to(np.asarray(gps_week, np.int64), np.shape(tow_s))
    r_e = np.asarray(r_e, np.float64)
    out = [] if comment is None else [f"# {c}" for c in comment.splitlines()]
    out.append(TRUTH_CSV_HEADER)
    for w, t, r in zip(gps_week, np.asarray(tow_s, np.float64), r_e):
        out.append(f"{int(w)},{t:.6f},{r[0]:.4f},{r[1]:.4f},{r[2]:.4f}")
    from ..outputs import write_atomic
    write_atomic(path, ("\n".join(out) + "\n").encode("ascii"))
