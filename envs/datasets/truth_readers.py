"""Truth (reference trajectory) readers chosen by name in a dataset spec's ``[truth]`` section (issue 12).

=================  ========================================================================================
``format``         what it reads
=================  ========================================================================================
``navgym-csv``     navgym's own CSV (:mod:`envs.datasets.truth_csv`): ``gps_week,tow_s,x_m,y_m,z_m``
``csv``            any CSV through a column map (:mod:`envs.datasets.truth_generic_csv`): GPS week + TOW
                   (10-bit weeks resolved) or UTC; ECEF or lat/lon/height; optional velocity and attitude
``static``         no file: a fixed antenna position (``position_ecef = [x, y, z]`` [m] or
                   ``position_llh = [lat_deg, lon_deg, h_m]``) over the whole observation span, zero velocity
``smartloc``       smartLoc's ``<name>_GT.txt`` (NovAtel SPAN ground truth; only with ``gnss.format = "smartloc"``)
=================  ========================================================================================

Every reader returns a :class:`TruthTrack`: GPS time (seconds since the start
of the observation file's GPS week), ECEF positions and, where the format has
them, ECEF velocities and roll / pitch / yaw. The replay world's truth is the
smoothing spline of the positions (:mod:`envs.datasets.spline_truth`, with
the IMU synthesized consistently from it); recorded velocities and attitudes
are kept on the track for checks (the Doppler test, ``TruthTrack.v_e``).
Each reader's own keys are checked when the spec is loaded
(:func:`check_truth_options`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from earth import geodetic_to_ecef

__all__ = ["TruthTrack", "TruthReader", "TRUTH_FORMATS", "check_truth_options", "read_truth"]


@dataclass(frozen=True)
class TruthTrack:
    """A reference trajectory.

    Attributes
    ----------
    t : (G,) GPS time [s since the start of GPS week ``week_ref``] (smartLoc: its own time stamps).
    r_e : (G, 3) ECEF antenna position [m].
    v_e : (G, 3) ECEF velocity [m/s] or None.
    rpy : (G, 3) roll, pitch, yaw of the body in NED [rad] or None.
    source : str, the file or description.
    lines : (G,) int64 1-based line of each row in its file, or None (no file, or a reader that does not say).
    """

    t: np.ndarray
    r_e: np.ndarray
    v_e: np.ndarray | None = None
    rpy: np.ndarray | None = None
    source: str = ""
    lines: np.ndarray | None = None


@dataclass(frozen=True)
class TruthReader:
    """One truth format: ``read(truth_spec, week_ref, span) -> TruthTrack``; ``check(options)`` raises
    ``ValueError('<key>: <message>')``; ``options`` the keys it accepts besides ``format`` and ``file``."""

    name: str
    read: Callable
    check: Callable
    options: tuple = ()
    needs_file: bool = True


def _no_options(opts: dict) -> None:
    if opts:
        raise ValueError(f"{sorted(opts)[0]}: unknown key for this truth format")


def _read_navgym_csv(spec, week_ref: int, span) -> TruthTrack:
    from .truth_csv import read_truth_csv_rows
    t, r, lines = read_truth_csv_rows(spec.file, week_ref)
    return TruthTrack(t=t, r_e=r, source=str(spec.file), lines=lines)


def _static_attitude(opts: dict):
    """The optional ``attitude_rpy_deg = [roll, pitch, yaw]`` of a static truth [rad] (3,) or None."""
    v = opts.get("attitude_rpy_deg")
    if v is None:
        return None
    if not (isinstance(v, (list, tuple)) and len(v) == 3 and all(isinstance(x, (int, float)) and
                                                                   not isinstance(x, bool) and math.isfinite(x)
                                                                   for x in v)):
        raise ValueError(f"attitude_rpy_deg: must be [roll, pitch, yaw] in degrees (3 finite numbers), got {v!r}")
    return np.radians(np.asarray(v, np.float64))


def _check_static(opts: dict) -> None:
    _static_position(opts)
    _static_attitude(opts)


def _static_position(opts: dict) -> np.ndarray:
    if ("position_ecef" in opts) == ("position_llh" in opts):
        raise ValueError("position_ecef: give exactly one of position_ecef = [x, y, z] (m) or "
                         "position_llh = [lat_deg, lon_deg, h_m]")
    key = "position_ecef" if "position_ecef" in opts else "position_llh"
    v = opts[key]
    if not (isinstance(v, (list, tuple)) and len(v) == 3 and all(isinstance(x, (int, float)) and
                                                                   not isinstance(x, bool) and math.isfinite(x)
                                                                   for x in v)):
        raise ValueError(f"{key}: must be 3 finite numbers, got {v!r}")
    if key == "position_llh":
        if not (-90 <= v[0] <= 90 and -180 <= v[1] <= 360):
            raise ValueError(f"{key}: latitude must be in [-90, 90] and longitude in [-180, 360] deg, got {v!r}")
        return np.asarray(geodetic_to_ecef(math.radians(v[0]), math.radians(v[1]), float(v[2])), np.float64)
    r = np.asarray(v, np.float64)
    if not 6.2e6 < np.linalg.norm(r) < 6.5e6:
        raise ValueError(f"{key}: {v!r} is not near the Earth's surface (ECEF metres expected)")
    return r


def _read_static(spec, week_ref: int, span) -> TruthTrack:
    r = _static_position(dict(spec.options))
    t0, t1 = float(span[0]), float(span[1])
    t = np.linspace(t0, t1, max(5, int(math.ceil(t1 - t0)) + 1))
    G = t.size
    a = _static_attitude(dict(spec.options))
    return TruthTrack(t=t, r_e=np.repeat(r[None], G, 0), v_e=np.zeros((G, 3)),
                      rpy=None if a is None else np.repeat(a[None], G, 0), source="static position")


def _read_smartloc(spec, week_ref: int, span) -> TruthTrack:
    from .smartloc import load_smartloc
    folder, name = spec.file.parent, spec.file.name[:-len("_GT.txt")]
    gt = load_smartloc(folder, name).ground_truth
    return TruthTrack(t=gt.t, r_e=gt.r_e, source=str(spec.file), lines=gt.line)


def _read_csv(spec, week_ref: int, span) -> TruthTrack:
    from .truth_generic_csv import read_csv_truth
    return read_csv_truth(spec, week_ref, span)


def _check_csv(opts: dict) -> None:
    from .truth_generic_csv import check_csv_options
    check_csv_options(opts)


TRUTH_FORMATS: dict[str, TruthReader] = {
    "navgym-csv": TruthReader("navgym-csv", _read_navgym_csv, _no_options),
    "csv": TruthReader("csv", _read_csv, _check_csv, ("columns", "delimiter", "comment", "angles")),
    "static": TruthReader("static", _read_static, _check_static,
                          ("position_ecef", "position_llh", "attitude_rpy_deg"), False),
    "smartloc": TruthReader("smartloc", _read_smartloc, _no_options),
}
"""Truth format name -> reader (module table)."""


def check_truth_options(fmt: str, options: dict) -> None:
    """Validate the reader-specific keys of a ``[truth]`` section (``ValueError('<key>: <message>')``)."""
    TRUTH_FORMATS[fmt].check(dict(options))


def read_truth(spec, week_ref: int, span) -> TruthTrack:
    """Read the truth of a :class:`~envs.datasets.spec.TruthSpec`.

    Parameters
    ----------
    spec : TruthSpec. week_ref : GPS week the returned times count from.
    span : (t_first, t_last) GPS times of the observations [s since the start of ``week_ref``] (the static
        truth spans them; other readers use it to resolve a 10-bit GPS week).

    A truth read from a file moves at most :data:`~envs.datasets.plausibility.TRUTH_SPEED_MAX_MPS` between its
    rows (``DatasetFormatError`` naming the file and the line otherwise).
    """
    from .plausibility import TRUTH_SPEED_MAX_MPS, check_track_speed
    track = TRUTH_FORMATS[spec.format].read(spec, int(week_ref), span)
    if spec.file is not None:
        check_track_speed(spec.file, track.t, track.r_e, track.lines, "the truth", TRUTH_SPEED_MAX_MPS)
    return track
