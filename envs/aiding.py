"""Non-GNSS aiding rows of a world's sensor set, stacked with the GNSS update (DESIGN.md section 2).

A scenario with a wheel odometer (``Scenario.odometer``, :mod:`envs.sim.odometer`; ``seed003-sim``, or a replay
of recorded odometry) gives every GNSS epoch, also in outages, one odometer forward-speed row and the two
non-holonomic constraint rows (lateral and vertical body velocity zero) of :mod:`nav_filters.constraints`, and,
where the odometry reads a yaw rate (``World.odometer_yaw_rate``) and the model fuses it, one yaw-rate row
(:func:`nav_filters.constraints.yaw_rate`). :func:`odometer_rows` builds them
for a navigator; :func:`with_rows` stacks them after other extra rows (zero-velocity updates), giving the
``extra`` argument of ``Navigator.update_gnss``. The env core and :func:`envs.episodes.run_episodes` use the
same two functions, so every method, policy and oracle sees the same sensor set.
"""
from __future__ import annotations

import numpy as np

from nav_filters.constraints import odometer_nhc, stack_measurements, yaw_rate

from .sim.odometer import OdometerModel


def odometer_rows(nav, speed_mps: np.ndarray, model: OdometerModel, yaw_rate_rps=None, w_raw=None,
                  dt: float | None = None):
    """Odometer + NHC (+ yaw-rate) measurement block of one epoch.

    Parameters
    ----------
    nav : the navigator (its current velocity ``v`` (B, 3) [m/s], attitude ``C`` (B, 3, 3), gyro bias ``bg``
        (B, 3) and the gyro PSD of its process noise).
    speed_mps : (B,) odometer readings of the epoch [m/s] (NaN: no reading on that row).
    model : the odometer (its ``sigma_mps``, ``nhc_sigma_mps`` and ``yaw_rate_sigma_rps`` are the sigmas the
        filter assumes).
    yaw_rate_rps : (B,) yaw-rate readings about body z (FRD) [rad/s], the means over the epoch's IMU interval
        (NaN: none), or None; fused when ``model.yaw_rate_sigma_rps`` is set and ``w_raw`` holds samples.
    w_raw : (B, n, 3) raw gyro samples of that interval [rad/s] (what the navigator just integrated).
    dt : IMU sample interval [s].

    Returns
    -------
    ``(dz (B, m), H (B, m, 17), R (B, m), row_mask (B, m))``: the odometer row of
    :func:`nav_filters.constraints.odometer`, the two rows of :func:`nav_filters.constraints.nhc`
    (:func:`nav_filters.constraints.odometer_nhc`, one compiled pass), then the yaw-rate row (m = 4) with the
    variance ``yaw_rate_sigma_rps^2 + gyro_psd / (n dt)`` (the sensor and the mean gyro's white noise).
    """
    block = odometer_nhc(nav.v, nav.C, np.asarray(speed_mps, np.float64), model.sigma_mps, model.nhc_sigma_mps,
                         model.nhc_sigma_mps, dtype=nav.dtype)
    if model.yaw_rate_sigma_rps is None or yaw_rate_rps is None or w_raw is None or np.shape(w_raw)[1] == 0:
        return block
    w = np.asarray(w_raw, np.float64)
    z = np.asarray(yaw_rate_rps, np.float64)
    have = np.isfinite(z) & ~nav.diverged
    n = w.shape[1]
    var = model.yaw_rate_sigma_rps ** 2 + float(np.max(nav.config.noise.gyro_psd)) / (n * float(dt))
    w_mean = np.where(have[:, None], w.mean(axis=1) - nav.bg, 0.0)
    return stack_measurements(block, yaw_rate(np.where(have[:, None, None], nav.C, np.eye(3)), w_mean,
                                              np.where(have, z, 0.0), np.sqrt(var), have, dtype=nav.dtype))


def with_rows(extra, rows):
    """``extra`` (a measurement block or None) followed by ``rows`` (a block or None): one block or None."""
    if rows is None:
        return extra
    if extra is None:
        return rows
    return stack_measurements(extra, rows)


__all__ = ["odometer_rows", "with_rows"]
