"""A recorded IMU replayed from a CSV file (issue 12): ``[imu]`` with ``source = "recorded"``.

Spec keys::

    [imu]
    source = "recorded"
    file = "imu.csv"                 # relative to the spec's folder; ${NAVGYM_DATA_DIR} expands
    grade = "industrial"             # the data-sheet grade: the filter's process noise (envs.sim.imu.IMU_GRADES)
    rate_hz = 100.0                  # the world's IMU grid
    accel_unit = "m/s^2"             # "m/s^2" (default) or "g" (standard gravity, 9.80665 m/s^2)
    gyro_unit = "rad/s"              # "rad/s" (default) or "deg/s"
    mounting = [0.0, 0.0, 90.0]      # roll, pitch, yaw [deg] of the sensor axes in the vehicle body (default 0s)
    max_gap_s = 0.1                  # a larger step between two samples is an error (default 0.1 s)
    delimiter = ","                  # default ","
    comment = "#"                    # default "#"
    [imu.columns]                    # role -> column name of the header line
    week = "GpsWeek"; tow = "GpsTow" # time as for the generic truth CSV (envs.datasets.truth_generic_csv):
    # cycle = "GpsCycle"             #   GPS week (+ 10-bit rollover cycle) + time of week, or
    # utc = "utc"                    #   UTC ISO 8601 date-time (leap seconds applied)
    fx = "ax"; fy = "ay"; fz = "az"  # specific force along the sensor axes
    wx = "gx"; wy = "gy"; wz = "gz"  # angular rate w_ib along the sensor axes

Frames (``nav_filters`` package docstring): the navigator's body frame is the vehicle's FRD. ``mounting`` is
the attitude of the sensor axes in it, ``C_bs = dcm_from_euler(roll, pitch, yaw)`` (Z-Y-X, as every
attitude in navgym), so ``f_b = C_bs f_s`` and ``w_b = C_bs w_s``. A sensor whose axes are the body's has
``mounting = [0, 0, 0]``.

Samples: each row is taken as the mean rate over the interval that ends at its time stamp (the
convention of :class:`envs.sim.imu.ImuData`; increment-integrating IMUs such as the VN-310 output this).
Onto the world's grid (:func:`resample_rates`): the recorded rates, piecewise constant over their
intervals, are integrated to a cumulative velocity / angle increment, which is interpolated linearly at
the grid times; a grid sample is its interval's increment over ``dt``. When the recorded stamps *are* the
grid the samples come out as recorded (to rounding); otherwise the increments are conserved. Rows must have
strictly increasing times, steps of at most ``max_gap_s``, and cover the replayed span (the replay is cut
to the part of the truth inside the recording: :mod:`envs.datasets.dataset_world`).

What a recorded sensor cannot know is not invented: the resulting :class:`~envs.sim.imu.ImuData` has
``gyro_bias``, ``accel_bias``, ``gyro_scale_misalignment``, ``accel_scale_misalignment``, ``bias_steps``
and ``rough`` set to ``None`` (unknown); ``grade`` is the spec's data-sheet grade.
"""
from __future__ import annotations

import math

import numpy as np

from earth import dcm_from_euler

from ..sim.imu import IMU_GRADES, ImuData
from .errors import DatasetFormatError, require_file
from .truth_generic_csv import _group, column_gps_times, read_columns

__all__ = ["IMU_OPTIONS", "IMU_COLUMN_ROLES", "ACCEL_UNITS", "GYRO_UNITS", "check_imu_options",
           "read_imu_csv", "resample_rates", "recorded_imu_data"]

IMU_OPTIONS = ("file", "columns", "accel_unit", "gyro_unit", "mounting", "max_gap_s", "delimiter", "comment")
"""The ``[imu]`` keys of a recorded IMU besides ``source``, ``grade`` and ``rate_hz``."""
IMU_COLUMN_ROLES = ("week", "cycle", "tow", "utc", "fx", "fy", "fz", "wx", "wy", "wz")
ACCEL_UNITS = {"m/s^2": 1.0, "g": 9.80665}
"""Accelerometer unit -> its size [m/s^2]."""
GYRO_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180.0}
"""Gyro unit -> its size [rad/s]."""


ACCEL_MAX_MPS2 = 50 * 9.80665
"""Largest specific force a recorded IMU sample may hold [m/s^2] (50 g; navigation IMUs measure up to 16-30 g)."""
GYRO_MAX_RPS = 35.0
"""Largest angular rate a recorded IMU sample may hold [rad/s] (2000 deg/s, the widest MEMS gyro range)."""


def check_imu_options(opts: dict) -> None:
    """Validate the recorded-IMU keys (module docstring, without ``file``'s existence); ``ValueError('<key>:
    <message>')`` with the key relative to ``[imu]``."""
    bad = sorted(set(opts) - set(IMU_OPTIONS))
    if bad:
        raise ValueError(f"{bad[0]}: unknown key for a recorded IMU; known: {', '.join(IMU_OPTIONS)}")
    if "file" not in opts:
        raise ValueError("file: missing: the recorded IMU CSV")
    cols = opts.get("columns")
    if not isinstance(cols, (dict, tuple)):
        raise ValueError("columns: missing: an [imu.columns] table mapping roles to header names")
    cols = dict(cols)
    for k, v in cols.items():
        if k not in IMU_COLUMN_ROLES:
            raise ValueError(f"columns.{k}: unknown role; known: {', '.join(IMU_COLUMN_ROLES)}")
        if not isinstance(v, str) or not v.strip():
            raise ValueError(f"columns.{k}: must be a column name, got {v!r}")
    _group(cols, "time", True)
    if "cycle" in cols and "week" not in cols:
        raise ValueError("columns.cycle: goes with a week column")
    for r in ("fx", "fy", "fz", "wx", "wy", "wz"):
        if r not in cols:
            raise ValueError(f"columns.{r}: missing (a recorded IMU needs fx, fy, fz, wx, wy, wz)")
    for k, units in (("accel_unit", ACCEL_UNITS), ("gyro_unit", GYRO_UNITS)):
        if k in opts and opts[k] not in units:
            raise ValueError(f"{k}: must be one of {', '.join(units)}, got {opts[k]!r}")
    m = opts.get("mounting", (0.0, 0.0, 0.0))
    if not (isinstance(m, (list, tuple)) and len(m) == 3
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in m)):
        raise ValueError(f"mounting: must be [roll, pitch, yaw] in degrees (three finite numbers), got {m!r}")
    g = opts.get("max_gap_s", 0.1)
    if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(g) or g <= 0:
        raise ValueError(f"max_gap_s: must be a finite number > 0, got {g!r}")
    for k in ("delimiter", "comment"):
        if k in opts and not (isinstance(opts[k], str) and len(opts[k]) == 1):
            raise ValueError(f"{k}: must be one character, got {opts[k]!r}")


def mounting_dcm(opts: dict) -> np.ndarray:
    """``C_bs`` (3, 3) of the ``mounting`` key [deg] (identity without it)."""
    roll, pitch, yaw = np.radians(np.asarray(opts.get("mounting", (0.0, 0.0, 0.0)), np.float64))
    return dcm_from_euler(roll, pitch, yaw)


def read_imu_csv(spec, week_ref: int):
    """Read and check the recorded IMU of ``spec`` (an :class:`~envs.datasets.spec.ImuSpec`).

    Returns
    -------
    t : (M,) GPS seconds since the start of week ``week_ref``, strictly increasing.
    f_b : (M, 3) specific force in the vehicle body frame [m/s^2] (units converted, mounting applied).
    w_b : (M, 3) angular rate ``w_ib^b`` [rad/s].

    Raises
    ------
    DatasetFormatError : a bad cell, time that does not increase, a step above ``max_gap_s``
        (naming the file, the line and the column).
    """
    opts = dict(spec.options)
    cols = dict(opts["columns"])
    path = require_file(spec.file)
    num, utc, where = read_columns(path, cols, opts.get("delimiter", ","), opts.get("comment", "#"),
                                   key="imu.columns", min_rows=2)
    t = column_gps_times(path, cols, num, utc, where, week_ref)
    dt = np.diff(t)
    back = dt <= 0
    if back.any():
        i = int(np.argmax(back))
        raise DatasetFormatError(path, where[i + 1], f"time does not increase ({t[i + 1] - t[i]:+.6g} s after "
                                                     f"line {where[i]})")
    gap = float(opts.get("max_gap_s", 0.1))
    big = dt > gap
    if big.any():
        i = int(np.argmax(big))
        raise DatasetFormatError(path, where[i + 1], f"a gap of {dt[i]:.6g} s after line {where[i]}: above "
                                                     f"imu.max_gap_s = {gap:g} s")
    C_bs = mounting_dcm(opts)
    f_s = np.stack([num["fx"], num["fy"], num["fz"]], -1) * ACCEL_UNITS[opts.get("accel_unit", "m/s^2")]
    w_s = np.stack([num["wx"], num["wy"], num["wz"]], -1) * GYRO_UNITS[opts.get("gyro_unit", "rad/s")]
    for roles, x, limit, unit in ((("fx", "fy", "fz"), f_s, ACCEL_MAX_MPS2, "m/s^2"),
                                  (("wx", "wy", "wz"), w_s, GYRO_MAX_RPS, "rad/s")):
        over = np.abs(x) > limit
        if over.any():
            i, k = np.unravel_index(int(np.argmax(over)), over.shape)
            raise DatasetFormatError(path, where[i], f"{cols[roles[k]]!r}: {float(num[roles[k]][i])!r} ({x[i, k]:.6g} {unit}) is "
                                                     f"beyond any navigation IMU's range ({limit:g} {unit}): "
                                                     f"check {'accel_unit' if unit == 'm/s^2' else 'gyro_unit'} or "
                                                     f"the file")
    return t, f_s @ C_bs.T, w_s @ C_bs.T


def resample_rates(t_rec: np.ndarray, x: np.ndarray, t_grid: np.ndarray) -> np.ndarray:
    """Interval-mean rates ``x`` (M, 3) stamped at the ends of their intervals ``t_rec`` (M,), onto the
    grid ``t_grid`` (N,) by integrating them (module docstring).

    Sample ``k >= 1`` is the mean over ``(t_grid[k-1], t_grid[k]]``; sample 0 the recorded rate of the
    interval holding ``t_grid[0]``. The grid must lie in ``[t_rec[0], t_rec[-1]]`` (ValueError otherwise).
    """
    t_rec, x, t_grid = np.asarray(t_rec, np.float64), np.asarray(x, np.float64), np.asarray(t_grid, np.float64)
    tol = 1e-9 * max(1.0, abs(t_rec[-1]))
    if t_grid[0] < t_rec[0] - tol or t_grid[-1] > t_rec[-1] + tol:
        raise ValueError(f"the grid [{t_grid[0]:.6f}, {t_grid[-1]:.6f}] s is not inside the recorded samples "
                         f"[{t_rec[0]:.6f}, {t_rec[-1]:.6f}] s")
    t_grid = np.clip(t_grid, t_rec[0], t_rec[-1])
    # the cumulative integral from t_rec[0] is exact at the stamps and linear between them
    q = np.concatenate([np.zeros((1, x.shape[1])), np.cumsum(x[1:] * np.diff(t_rec)[:, None], axis=0)])
    Q = np.stack([np.interp(t_grid, t_rec, q[:, j]) for j in range(x.shape[1])], -1)
    out = np.empty((t_grid.size, x.shape[1]))
    out[1:] = np.diff(Q, axis=0) / np.diff(t_grid)[:, None]
    out[0] = x[min(max(int(np.searchsorted(t_rec, t_grid[0], side="left")), 1), t_rec.size - 1)]
    return out


def recorded_imu_data(spec, week_ref: int, t_grid: np.ndarray, batch_size: int = 1,
                      dtype=np.float64, samples=None) -> ImuData:
    """The :class:`~envs.sim.imu.ImuData` of the recorded IMU of ``spec`` on the grid ``t_grid``.

    Parameters
    ----------
    spec : ImuSpec with ``source = 'recorded'``.
    week_ref : GPS week of the times; t_grid : (N,) GPS seconds since its start, uniform at ``spec.rate_hz``.
    batch_size : B; the rows are read-only broadcast views of one recording (identical in every row).
    dtype : float32 or float64.
    samples : ``(t, f_b, w_b)`` already read by :func:`read_imu_csv` (to read the file once), or None.

    Returns
    -------
    ImuData with ``f_b``, ``w_b`` (B, N, 3); biases, scale factors, events ``None`` (module docstring).
    """
    if spec.source != "recorded":
        raise ValueError(f"imu.source is {spec.source!r}, not 'recorded'")
    dt = np.dtype(dtype)
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be np.float32 or np.float64, got {dtype!r}")
    t, f, w = read_imu_csv(spec, week_ref) if samples is None else samples
    try:
        f_g, w_g = resample_rates(t, f, t_grid), resample_rates(t, w, t_grid)
    except ValueError as exc:
        raise ValueError(f"{spec.file}: {exc}") from None
    B = int(batch_size)

    def bc(x):
        return np.broadcast_to(x.astype(dt)[None], (B,) + x.shape)

    return ImuData(f_b=bc(f_g), w_b=bc(w_g), gyro_bias=None, accel_bias=None, gyro_scale_misalignment=None,
                   accel_scale_misalignment=None, dt=1.0 / float(spec.rate_hz), grade=IMU_GRADES[spec.grade],
                   bias_steps=None, rough=None)
