"""The stationary-vehicle measurement block: ZUPT + zero heading rate from a detector's decisions.

Seed paper 000 sec 2: "If the system is in a zero-velocity state at this
moment, velocity and heading constraints are applied". Per GNSS epoch, given
the detector's per-sample decisions over the epoch's IMU samples, a row is
*stationary at the epoch* when the detector declares its last sample (the
update instant) stationary; for those rows the block stacks

* the ZUPT rows (:func:`nav_filters.constraints.zupt`, true velocity = 0), and
* the zero-heading-rate row (:func:`nav_filters.constraints.zero_heading_rate`)
  with the mean bias-corrected gyro sample over the trailing run of stationary
  samples of the epoch (length ``T`` seconds), standard deviation
  ``sqrt(ARW^2 / T + (vibration_angle_rad / T)^2)``: the white gyro noise
  averaged over ``T`` plus the residual of an oscillation of angular amplitude
  ``vibration_angle_rad`` (engine idle rocking; the mean rate of a periodic
  rotation over ``T`` is bounded by its angle amplitude over ``T``).

The block is fused into the epoch's GNSS update through
``Navigator.update_gnss(..., extra=block)`` (one stacked update).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..constraints import stack_measurements, zero_heading_rate, zupt

__all__ = ["ZuptAidingConfig", "stationary_block"]


@dataclass(frozen=True)
class ZuptAidingConfig:
    """Constraint settings (validated; errors name the field).

    Attributes
    ----------
    zupt_sigma_mps : ZUPT standard deviation per axis [m/s] (residual motion at rest), > 0.
    heading_rate : also apply the zero-heading-rate row.
    vibration_angle_rad : angular amplitude of residual rocking at rest [rad], >= 0 (heading-rate sigma).
    """

    zupt_sigma_mps: float = 0.02
    heading_rate: bool = True
    vibration_angle_rad: float = 1e-4

    def __post_init__(self):
        s = self.zupt_sigma_mps
        if isinstance(s, bool) or not isinstance(s, (int, float)) or not math.isfinite(s) or s <= 0:
            raise ValueError(f"ZuptAidingConfig.zupt_sigma_mps must be a positive finite number, got {s!r}")
        v = self.vibration_angle_rad
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v < 0:
            raise ValueError(f"ZuptAidingConfig.vibration_angle_rad must be a finite number >= 0, got {v!r}")
        if not isinstance(self.heading_rate, bool):
            raise ValueError(f"ZuptAidingConfig.heading_rate must be a bool, got {self.heading_rate!r}")


def stationary_block(nav, w_raw, stationary, dt: float, config: ZuptAidingConfig = ZuptAidingConfig()):
    """Measurement block for the rows declared stationary at this epoch.

    Parameters
    ----------
    nav : :class:`nav_filters.navigator.Navigator` after propagating to the epoch (before its update);
        its ``v``, ``C``, ``r``, ``bg`` and the gyro PSD of its process noise are read.
    w_raw : (B, n, 3) raw gyro samples of the epoch [rad/s] (n >= 1).
    stationary : (B, n) bool detector decisions for those samples.
    dt : IMU sample interval [s].
    config : ZuptAidingConfig.

    Returns
    -------
    block : ``(dz, H, R, row_mask)`` with 3 ZUPT rows (+ 1 heading-rate row), neutral on moving rows;
        or None when no row is stationary.
    active : (B,) bool, rows constrained at this epoch.
    """
    w = np.asarray(w_raw, np.float64)
    st = np.asarray(stationary)
    B = nav.batch_size
    if w.ndim != 3 or w.shape[0] != B or w.shape[2] != 3 or w.shape[1] < 1:
        raise ValueError(f"w_raw must have shape ({B}, n >= 1, 3), got {w.shape}")
    if st.shape != w.shape[:2] or st.dtype != bool:
        raise ValueError(f"stationary must be a bool array of shape {w.shape[:2]}, got {st.dtype} {st.shape}")
    if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
    active = st[:, -1] & ~nav.diverged
    if not active.any():
        return None, active
    blocks = [zupt(nav.v, nav.C, config.zupt_sigma_mps, active)]
    if config.heading_rate:
        # trailing run of stationary samples (>= 1 on active rows)
        n = st.shape[1]
        moving_idx = np.where(~st, np.arange(n)[None, :], -1).max(1)        # last moving sample, -1 if none
        run = n - 1 - moving_idx
        in_run = np.arange(n)[None, :] > moving_idx[:, None]
        cnt = np.maximum(run, 1)
        w_mean = np.where(in_run[..., None], w, 0.0).sum(1) / cnt[:, None] - nav.bg
        T = cnt * dt
        arw = math.sqrt(float(np.max(nav.config.noise.gyro_psd)))
        sigma = np.sqrt(arw ** 2 / T + (config.vibration_angle_rad / T) ** 2)
        sigma = np.maximum(sigma, 1e-12)  # the navigator floors its ARW (episodes.process_noise_for); never 0
        blocks.append(zero_heading_rate(nav.C, np.where(active[:, None], w_mean, 0.0), nav.r, sigma, active))
    return stack_measurements(*blocks, dtype=nav.dtype), active
