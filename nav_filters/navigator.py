"""The batched tightly coupled GNSS/INS navigator (closed-loop error-state filter).

One :class:`Navigator` runs B independent navigation solutions in lock step:

* ``propagate(f_raw, w_raw, dt)`` once per IMU sample: bias compensation, the
  ECEF strapdown mechanization (:mod:`nav_filters.ins`), the 17-state
  transition and process noise (:mod:`nav_filters.error_model`), and the
  filter form's time update (every sample, or once per epoch with the
  ``+onestep`` suffix: the product of the per-sample transitions is
  accumulated, seed paper 001 eqs 19-20);
* ``update_gnss(...)`` once per GNSS epoch: pseudorange / pseudorange-rate
  innovations (:mod:`nav_filters.measurements`), the form's measurement update,
  and closed-loop feedback of the estimated errors into the INS, the IMU bias
  estimates and the receiver clock.

Rows whose solution becomes non-finite are flagged in :attr:`Navigator.diverged`
and frozen (their measurement updates are skipped), so one diverged row never
poisons the batch.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .error_model import ATT, BA, BG, CLK, DRIFT, N_STATES, POS, VEL, ProcessNoise, discretize, system_matrix
from .forms import UpdateResult, make_form, parse_method
from .forms.base import check_dtype
from .ins import apply_correction, mechanize
from .measurements import dop, gnss_innovations


@dataclass(frozen=True)
class NavigatorConfig:
    """Configuration of the navigator.

    Attributes
    ----------
    noise : continuous-time process-noise densities (SI) the filter assumes (required: a filter with
        no process noise is never what a user meant).
    method : filter method name of DESIGN.md section 4 (e.g. ``'kf'``, ``'kf+onestep'``).
    use_pseudorange_rate : fuse pseudorange rates (Doppler) as well as pseudoranges.
    phi_order : 1 or 2, order of the Taylor series of the transition matrix. With 1 and isotropic IMU
        noise densities the navigator takes its fast path: ``Phi = I + F dt`` built in place and the
        first-order ``Q = G Q_c G^T dt`` (a constant diagonal; Groves eq 3.46 truncated), which differs
        from the trapezoidal ``Q`` of :func:`~nav_filters.error_model.discretize` by O(F dt) ~ 1e-4
        relative at 100 Hz.
    dtype : ``'float64'`` (default) or ``'float32'``: the filter's arithmetic.
    """

    noise: ProcessNoise
    method: str = "kf"
    use_pseudorange_rate: bool = True
    phi_order: int = 1
    dtype: str = "float64"

    def __post_init__(self):
        parse_method(self.method)
        if not isinstance(self.noise, ProcessNoise):
            raise ValueError(f"noise must be a ProcessNoise, got {type(self.noise).__name__}")
        if self.phi_order not in (1, 2):
            raise ValueError(f"phi_order must be 1 or 2, got {self.phi_order!r}")
        check_dtype(self.dtype)


class Navigator:
    """Batched closed-loop tightly coupled GNSS/INS navigator.

    Parameters
    ----------
    config : NavigatorConfig
    r_e, v_e : (B, 3) initial ECEF position [m] and velocity [m/s].
    C_eb : (B, 3, 3) initial attitude (body FRD -> ECEF).
    P0 : (B, 17, 17) initial error covariance (state order of :mod:`nav_filters.error_model`).
    clock_bias_m, clock_drift_mps : (B,) initial receiver clock estimates.
    gyro_bias, accel_bias : (B, 3) initial IMU bias estimates (default zero).
    """

    def __init__(self, config: NavigatorConfig, r_e, v_e, C_eb, P0, clock_bias_m, clock_drift_mps,
                 gyro_bias=None, accel_bias=None):
        self.config = config
        self.dtype = check_dtype(config.dtype)
        _, self.onestep = parse_method(config.method)
        dt_ = self.dtype
        self.r = np.array(r_e, dtype=np.float64)  # positions stay float64: 6e6 m in float32 loses 0.5 m
        B = self.r.shape[0]
        if self.r.shape != (B, 3):
            raise ValueError(f"r_e must have shape (B, 3), got {self.r.shape}")
        self.v = np.array(v_e, dtype=dt_).reshape(B, 3)
        self.C = np.array(C_eb, dtype=dt_).reshape(B, 3, 3)
        self.clk = np.array(clock_bias_m, dtype=np.float64).reshape(B)
        self.drift = np.array(clock_drift_mps, dtype=dt_).reshape(B)
        self.bg = np.zeros((B, 3), dt_) if gyro_bias is None else np.array(gyro_bias, dt_).reshape(B, 3)
        self.ba = np.zeros((B, 3), dt_) if accel_bias is None else np.array(accel_bias, dt_).reshape(B, 3)
        P0 = np.asarray(P0)
        if P0.shape != (B, N_STATES, N_STATES):
            raise ValueError(f"P0 must have shape ({B}, {N_STATES}, {N_STATES}), got {P0.shape}")
        self.form = make_form(config.method, P0, dtype=dt_)
        self.batch_size = B
        self.diverged = np.zeros(B, bool)
        self.time_since_update = 0.0
        self._F = np.zeros((B, N_STATES, N_STATES), dt_)
        self._fast = config.phi_order == 1 and config.noise.isotropic
        self._q = config.noise.diagonal().astype(dt_)
        self._Q_cache = {}
        self._reset_accumulator()

    # ------------------------------------------------------------------ time
    def _reset_accumulator(self):
        self._Phi_acc = None
        self._Q_acc = None

    def propagate(self, f_raw, w_raw, dt: float):
        """Advance all rows by one IMU sample.

        Parameters
        ----------
        f_raw, w_raw : (B, 3) measured mean specific force [m/s^2] and angular rate [rad/s]
            over the sample interval.
        dt : sample interval [s].
        """
        f = np.asarray(f_raw, self.dtype) - self.ba
        w = np.asarray(w_raw, self.dtype) - self.bg
        Phi, Q = self._transition(f, dt)
        if self.onestep:
            # seed 001 multiplication method: Phi_(k+n,k) = Phi_n ... Phi_1; Q accumulated alongside.
            if self._Phi_acc is None:
                self._Phi_acc, self._Q_acc = Phi.copy(), np.array(Q)
            else:
                self._Phi_acc = Phi @ self._Phi_acc
                self._Q_acc = Phi @ self._Q_acc @ Phi.mT + Q
        else:
            self.form.predict(Phi, Q)
        r, v, C = mechanize(self.r, self.v, self.C, f, w, dt)
        self.r = np.asarray(r, np.float64)
        self.v, self.C = v.astype(self.dtype, copy=False), C.astype(self.dtype, copy=False)
        self.clk = self.clk + self.drift.astype(np.float64) * dt
        self.time_since_update += dt

    def _transition(self, f, dt):
        """Per-sample ``(Phi, Q)`` of the error model (fast path: see :class:`NavigatorConfig`)."""
        noise = self.config.noise
        F = system_matrix(self.C, f, self.r.astype(self.dtype), noise.gyro_bias_tau_s, noise.accel_bias_tau_s,
                          out=self._F)
        if not self._fast:
            return discretize(F, self.C, noise, dt, order=self.config.phi_order)
        F *= self.dtype.type(dt)
        idx = np.arange(N_STATES)
        F[:, idx, idx] += 1
        Q = self._Q_cache.get(dt)
        if Q is None:
            Q = np.broadcast_to(np.diag(self._q * dt).astype(self.dtype), F.shape)
            self._Q_cache[dt] = Q
        return F, Q

    def flush_prediction(self):
        """Apply the accumulated one-step transition (``+onestep``) to the form; no-op otherwise."""
        if self.onestep and self._Phi_acc is not None:
            self.form.predict(self._Phi_acc, self._Q_acc)
            self._reset_accumulator()

    # ----------------------------------------------------------- measurement
    def update_gnss(self, sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, mask) -> tuple[UpdateResult, np.ndarray]:
        """Tightly coupled update with one GNSS epoch and closed-loop feedback.

        Parameters
        ----------
        sat_pos, sat_vel : (B, C, 3) satellite ECEF position/velocity at transmission time.
        pr, prr : (B, C) pseudorange [m], pseudorange rate [m/s] (``prr`` may be None).
        pr_sigma, prr_sigma : (B, C) measurement standard deviations [m], [m/s].
        mask : (B, C) bool valid channels.

        Returns
        -------
        result : :class:`~nav_filters.forms.UpdateResult`
        gdop : (B,) geometric DOP of the used satellites (inf below 4).
        """
        self.flush_prediction()
        mask = np.asarray(mask, bool) & ~self.diverged[:, None]
        pr_var = np.square(np.asarray(pr_sigma, np.float64))
        prr_var = None if prr_sigma is None else np.square(np.asarray(prr_sigma, np.float64))
        dz, H, R, row_mask, u = gnss_innovations(
            self.r, self.v, self.clk, self.drift, sat_pos, sat_vel, pr, prr, pr_var, prr_var, mask,
            use_rate=self.config.use_pseudorange_rate, dtype=self.dtype)
        try:
            res = self.form.update(dz, H, R, row_mask)
        except np.linalg.LinAlgError:
            res = self._update_isolating_failures(dz, H, R, row_mask)
        self._feedback(self.form.take_correction())
        if np.any(mask.any(-1)):
            self.time_since_update = 0.0
        return res, dop(u, mask)

    def _update_isolating_failures(self, dz, H, R, row_mask):
        """Retry an update after flagging rows whose covariance is no longer positive definite."""
        P = self.form.covariance
        bad = ~np.all(np.isfinite(P), axis=(1, 2))
        ok = ~bad
        try:
            np.linalg.cholesky(H[ok] @ P[ok] @ H[ok].mT + (np.eye(R.shape[1]) * R[ok][:, None, :]))
        except np.linalg.LinAlgError:
            bad[:] = True
            for b in range(self.batch_size):
                try:
                    S = H[b] @ P[b] @ H[b].T + np.diag(R[b])
                    np.linalg.cholesky(S)
                    bad[b] = not np.all(np.isfinite(S))
                except np.linalg.LinAlgError:
                    bad[b] = True
        self.diverged |= bad
        row_mask = row_mask & ~bad[:, None]
        if bad.all():
            B, m = row_mask.shape
            z = np.zeros(B)
            return UpdateResult(nis=z, n_used=np.zeros(B, int), innovation=np.zeros((B, m)),
                                innovation_var=np.ones((B, m)), applied=np.zeros(B, bool))
        return self.form.update(dz, H, R, row_mask)

    def _feedback(self, dx):
        """Closed-loop correction: add the error-state estimate to the nominal state (B, 17)."""
        dx = np.where(self.diverged[:, None], 0, dx)
        r, v, C = apply_correction(self.r, self.v, self.C, dx)
        self.r = np.asarray(r, np.float64)
        self.v, self.C = v.astype(self.dtype, copy=False), C.astype(self.dtype, copy=False)
        self.bg = self.bg + dx[:, BG]
        self.ba = self.ba + dx[:, BA]
        self.clk = self.clk + dx[:, CLK.start].astype(np.float64)
        self.drift = self.drift + dx[:, DRIFT.start]
        finite = np.isfinite(self.r).all(1) & np.isfinite(self.v).all(1) & np.isfinite(self.C).all((1, 2))
        P = self.form.covariance
        finite &= np.isfinite(np.diagonal(P, axis1=1, axis2=2)).all(1) & (np.diagonal(P, axis1=1, axis2=2) > 0).all(1)
        self.diverged |= ~finite

    # ----------------------------------------------------------------- views
    @property
    def covariance(self) -> np.ndarray:
        """(B, 17, 17) current error covariance (after flushing nothing: the last form state)."""
        return self.form.covariance

    def position_sigma(self) -> np.ndarray:
        """(B, 3) one-sigma ECEF position uncertainty [m]."""
        return np.sqrt(np.maximum(np.diagonal(self.form.covariance, axis1=1, axis2=2)[:, POS], 0))


__all__ = ["Navigator", "NavigatorConfig", "ATT", "VEL", "POS"]
