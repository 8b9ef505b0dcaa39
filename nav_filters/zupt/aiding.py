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

The numpy composition (:func:`~nav_filters.constraints.zupt`, :func:`~nav_filters.constraints.zero_heading_rate`,
:func:`~nav_filters.constraints.stack_measurements`) is the specification; :func:`stationary_block` forms the same
block with two compiled passes around its three matrix products, which stay numpy's (their bits are BLAS's), so the
block is the same bits (test: ``tests/nav_filters/test_zupt_compiled.py``). With the composition, cProfile put 21% of
a single ``urban`` env's steps with ``zupt="shoe"`` in it (62 of the 300 epochs were stationary).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from earth.wgs84 import E2 as _E2
from earth.wgs84 import OMEGA_IE

from ..constraints import stack_measurements, zero_heading_rate, zupt
from ..error_model import ATT, BG, N_STATES, VEL

_W_IE = np.array([0.0, 0.0, OMEGA_IE])

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


def stationary_block(nav, w_raw, stationary, dt: float, config: ZuptAidingConfig = ZuptAidingConfig(), *,
                     compiled: bool = True):
    """Measurement block for the rows declared stationary at this epoch.

    Parameters
    ----------
    nav : :class:`nav_filters.navigator.Navigator` after propagating to the epoch (before its update);
        its ``v``, ``C``, ``r``, ``bg`` and the gyro PSD of its process noise are read.
    w_raw : (B, n, 3) raw gyro samples of the epoch [rad/s] (n >= 1).
    stationary : (B, n) bool detector decisions for those samples.
    dt : IMU sample interval [s].
    config : ZuptAidingConfig.
    compiled : form the block by the compiled passes (the same bits) where the inputs allow (a live stationary
        row with a state or gyro mean that is not finite runs the composition, which raises the error naming it);
        False: always the numpy composition.

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
    arw = math.sqrt(float(np.max(nav.config.noise.gyro_psd)))
    if compiled:
        block = _compiled_block(nav, w, st, active, float(dt), arw, config)
        if block is not None:
            return block, active
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
        sigma = np.sqrt(arw ** 2 / T + (config.vibration_angle_rad / T) ** 2)
        sigma = np.maximum(sigma, 1e-12)  # the navigator floors its ARW (episodes.process_noise_for); never 0
        blocks.append(zero_heading_rate(nav.C, np.where(active[:, None], w_mean, 0.0), nav.r, sigma, active))
    return stack_measurements(*blocks, dtype=nav.dtype), active


def _compiled_block(nav, w, st, active, dt, arw, config):
    """The block of :func:`stationary_block` by :func:`_heading_inputs` and :func:`_block_rows` around the
    numpy products of :func:`~nav_filters.constraints.zero_heading_rate` (the same expressions on arrays of the
    same layout), or None where a live stationary row's state or gyro mean is not finite."""
    B = w.shape[0]
    f8 = np.float64
    v, C, r, bg = (np.asarray(a, f8) for a in (nav.v, nav.C, nav.r, nav.bg))  # (as the composition reads them)
    heading = bool(config.heading_rate)
    wm, d_e, var_h = np.empty((B, 3)), np.empty((B, 3)), np.empty(B)
    if not _heading_inputs(w, st, active, v, C, r, bg, dt, arw ** 2, float(config.vibration_angle_rad),
                           1.0 / (1.0 - _E2), heading, wm, d_e, var_h):
        return None
    if heading:
        with np.errstate(invalid="ignore"):
            w_e = (C @ wm[..., None])[..., 0] - _W_IE
            dz_h = np.einsum("bi,bi->b", d_e, w_e)
            h_bg = (np.swapaxes(C, -1, -2) @ d_e[..., None])[..., 0]
    else:
        dz_h, h_bg = var_h, wm  # (unread)
    m = 4 if heading else 3
    dt_out = nav.dtype
    dz, H, R, mask = np.empty((B, m), dt_out), np.empty((B, m, N_STATES), dt_out), np.empty((B, m), dt_out), \
        np.empty((B, m), bool)
    s = float(config.zupt_sigma_mps)
    _block_rows(active, v, dz_h, h_bg, d_e, s * s, var_h, heading, OMEGA_IE, VEL.start, ATT.start, BG.start,
                dz, H, R, mask)
    return dz, H, R, mask


@nb.njit(cache=True)
def _heading_inputs(w, st, active, v, C, r, bg, dt, arw2, vib, down_k, heading, wm, d_e, var_h):
    """Per live stationary row (``active``) of :func:`stationary_block`, as its numpy lines: the bias-corrected
    mean gyro sample ``wm`` over the trailing stationary run (samples summed in order, over the count), the
    variance ``var_h`` of the heading-rate row (``max(sqrt(arw2 / T + (vib / T)^2), 1e-12)^2``) and the local
    down ``d_e`` (:func:`~nav_filters.constraints._local_down`, ``down_k = 1 / (1 - e^2)``); zeros elsewhere.
    Returns False where such a row's ``v``, ``C``, ``r`` or ``wm`` is not finite (the composition raises)."""
    B, n = st.shape
    for b in range(B):
        for c in range(3):
            wm[b, c] = 0.0
            d_e[b, c] = 0.0
        var_h[b] = 1.0
        if not active[b]:
            continue
        for c in range(3):
            if not np.isfinite(v[b, c]):
                return False
        if not heading:
            continue
        for i in range(3):
            if not (np.isfinite(r[b, i]) and np.isfinite(C[b, i, 0]) and np.isfinite(C[b, i, 1])
                    and np.isfinite(C[b, i, 2])):
                return False
        last_moving = -1
        for i in range(n):
            if not st[b, i]:
                last_moving = i
        cnt = max(n - 1 - last_moving, 1)
        for c in range(3):
            s = 0.0
            for i in range(last_moving + 1, n):
                s += w[b, i, c]
            wm[b, c] = s / cnt - bg[b, c]
            if not np.isfinite(wm[b, c]):
                return False
        T = cnt * dt
        q = vib / T
        sig = max(np.sqrt(arw2 / T + q * q), 1e-12)
        var_h[b] = sig * sig
        n0, n1, n2 = r[b, 0] * 1.0, r[b, 1] * 1.0, r[b, 2] * down_k
        nn = -np.sqrt((n0 * n0 + n1 * n1) + n2 * n2)
        d_e[b, 0], d_e[b, 1], d_e[b, 2] = n0 / nn, n1 / nn, n2 / nn
    return True


@nb.njit(cache=True)
def _block_rows(active, v, dz_h, h_bg, d_e, var_z, var_h, heading, omega, vel0, att0, bg0, dz, H, R, mask):
    """The rows of :func:`stationary_block` into ``dz``, ``H``, ``R``, ``mask`` (B, m) of the navigator's dtype:
    the three ZUPT rows (``dz = -v``, ``H[VEL] = I``, variance ``var_z``) and, with ``heading``, the heading-rate
    row (``dz_h``, ``H[BG] = h_bg``, ``H[ATT] = (d_e x w_ie)^T``, ``var_h``); neutral (0, 0, variance 1) on the
    other batch rows."""
    B, m, n = H.shape
    for b in range(B):
        a = active[b]
        for k in range(m):
            for j in range(n):
                H[b, k, j] = 0.0
            mask[b, k] = a
            dz[b, k] = 0.0
            R[b, k] = 1.0
        if not a:
            continue
        for k in range(3):
            dz[b, k] = -v[b, k]
            H[b, k, vel0 + k] = 1.0
            R[b, k] = var_z
        if heading:
            dz[b, 3] = dz_h[b]
            for j in range(3):
                H[b, 3, bg0 + j] = h_bg[b, j]
            H[b, 3, att0] = omega * d_e[b, 1]
            H[b, 3, att0 + 1] = -omega * d_e[b, 0]
            R[b, 3] = var_h[b]
