"""Simulated odometer of a wheeled vehicle (seed paper 003's SINS/GNSS/ODO sensor set).

A scenario with ``Scenario.odometer`` set (``seed003-sim``) gives its worlds a forward-speed reading at every
GNSS epoch, also during GNSS outages; the filter side fuses it with the two non-holonomic constraints
(:func:`envs.aiding.odometer_rows`: :func:`nav_filters.constraints.odometer` and
:func:`nav_filters.constraints.nhc`). Units: speeds in m/s, the scale error dimensionless.

Reading model (seed paper 003 Table 1: odometer scale-factor error 0.05 %)::

    speed_odo = |v_true| (1 + scale_error) + noise_mps * n,   n ~ N(0, 1) white, per epoch

Row i draws its noise only from ``seeds[i]`` (stream ``'odometer'`` of :data:`envs.sim.rng.STREAMS`), so a
world's odometer does not depend on the batch. The reading is the unsigned speed: the simulated drives never
reverse.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .rng import row_generators


@dataclass(frozen=True)
class OdometerModel:
    """Simulated odometer and the NHC / odometer noise the filter assumes.

    Attributes
    ----------
    scale_error : true odometer scale-factor error (seed 003 Table 1: 0.05 % -> 5e-4); simulated odometers only.
    noise_mps : true white noise of a speed reading [m/s]; simulated odometers only.
    sigma_mps : odometer standard deviation the filter assumes [m/s] (covers noise and scale error).
    nhc_sigma_mps : lateral / vertical NHC standard deviation the filter assumes [m/s].
    yaw_rate_sigma_rps : standard deviation [rad/s] the filter assumes for a yaw-rate reading
        (:func:`nav_filters.constraints.yaw_rate`; the gyro's white noise over the interval is added), or None:
        no yaw-rate row. Only recorded odometry reads a yaw rate (``World.odometer_yaw_rate``; a replay world
        of a dataset spec with ``[odometry]``); a simulated odometer reads the forward speed only.
    """

    scale_error: float = 5e-4
    noise_mps: float = 0.05
    sigma_mps: float = 0.1
    nhc_sigma_mps: float = 0.1
    yaw_rate_sigma_rps: float | None = None

    def __post_init__(self):
        for name in ("scale_error", "noise_mps", "sigma_mps", "nhc_sigma_mps", "yaw_rate_sigma_rps"):
            v = getattr(self, name)
            if name == "yaw_rate_sigma_rps" and v is None:
                continue
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"OdometerModel.{name} must be a finite number, got {v!r}")
        if self.noise_mps < 0:
            raise ValueError(f"OdometerModel.noise_mps must be >= 0, got {self.noise_mps!r}")
        for name in ("sigma_mps", "nhc_sigma_mps", "yaw_rate_sigma_rps"):
            v = getattr(self, name)
            if v is not None and v <= 0:
                raise ValueError(f"OdometerModel.{name} must be > 0, got {v!r}")


SEED003_ODOMETER = OdometerModel()
"""Odometer of seed paper 003's SINS/GNSS/ODO sensor set (speed and NHC rows at every 1 Hz epoch, also in
outages); the sensor set of ``seed003-sim``."""


def simulate_odometer(speed: np.ndarray, seeds, model: OdometerModel = SEED003_ODOMETER) -> np.ndarray:
    """Odometer forward-speed readings.

    Parameters
    ----------
    speed : (B, M) true speed at the GNSS epochs [m/s].
    seeds : B world seeds (row i's noise depends on ``seeds[i]`` only).
    model : the odometer.

    Returns
    -------
    (B, M) readings [m/s]: ``speed (1 + scale_error) + noise_mps * N(0, 1)``.
    """
    speed = np.asarray(speed, np.float64)
    if speed.ndim != 2:
        raise ValueError(f"simulate_odometer: speed must be (B, M), got shape {speed.shape}")
    rngs = row_generators(seeds, "odometer")
    if len(rngs) != speed.shape[0]:
        raise ValueError(f"simulate_odometer: {len(rngs)} seeds for {speed.shape[0]} rows of speed")
    noise = np.stack([g.normal(0.0, 1.0, speed.shape[1]) for g in rngs])
    return speed * (1.0 + model.scale_error) + model.noise_mps * noise


__all__ = ["OdometerModel", "SEED003_ODOMETER", "simulate_odometer"]
