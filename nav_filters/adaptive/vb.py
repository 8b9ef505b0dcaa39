"""Variational-Bayes adaptive measurement noise (``vb-akf``): Särkkä & Nummenmaa (2009), "Recursive noise
adaptive Kalman filtering by variational Bayesian approximations", IEEE TAC 54(3):596-600, per satellite.

The paper models each diagonal element of R as an inverse-gamma variable ``sigma_i^2 ~ Inv-Gamma(alpha_i,
beta_i)`` and approximates the joint posterior of the state and the variances by a product of a Gaussian and
inverse gammas. Per epoch (its Algorithm 1):

* prediction of the variances (the heuristic dynamics, forgetting factor ``rho`` in (0, 1]):
  ``alpha_i^- = rho alpha_i``, ``beta_i^- = rho beta_i``;
* update: ``alpha_i = alpha_i^- + 1/2``; ``beta_i = beta_i^-``; then ``n_iter`` fixed-point iterations of

      Sigma = diag(beta_i / alpha_i)
      (m, P) = the Kalman update of the prediction with R = Sigma
      beta_i = beta_i^- + 1/2 (y - H m)_i^2 + 1/2 (H P H^T)_ii

Choices (navgym's; the paper's model has one fixed measurement vector):

* **Per satellite and type.** The variables are kept per measurement key (satellite and pseudorange / rate,
  :func:`nav_filters.measurements.measurement_keys`), like the per-satellite Sage-Husa law: a satellite keeps
  its estimate across channels; one unseen for ``u`` epochs is predicted ``u`` times (``rho^u``), and one
  unseen for more than ``forget_after_epochs`` starts again from the prior. Rows without a key (constraints,
  or an update given no keys) keep their reported variance.
* **Relative to the reported variance.** The inverse gamma is that of the *scale* ``s_i`` of the variance the
  receiver reports (``R_ii`` changes with elevation and C/N0 from epoch to epoch): ``Sigma_ii = (beta_i /
  alpha_i) R_ii``, and the residual terms enter ``beta`` divided by ``R_ii``. The prior of a new satellite is
  ``alpha = beta = alpha0`` (scale 1: the reported variance).
* **Early stop.** The fixed-point iterations stop once no satellite's scale changes by more than ``tol``
  (1e-3) of itself, at most ``n_iter``: a clean epoch needs two or three.
* **Bounds.** The scale handed to the update is clipped to ``[scale_min, scale_max]``; ``scale_min = 1`` (the
  default) trusts no satellite more than its reported variance, as the registered Sage-Husa laws do.

``rho`` is a per-row parameter (``set_params(rho=...)``): an adaptive-noise knob like Sage-Husa's ``b``, for
the environments. The fixed-point iterations need the post-fit residuals and ``diag(H P H^T) = var (1 -
red)`` of each fit, which :func:`~.robust_rows.fit_row` gives. Compiled per row (:func:`_vb_rows`);
:meth:`VariationalR._vb_reference` is the numpy specification.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from ..kernels import row_kernel, serial_and_parallel
from ..measurements import N_SAT_KEYS
from .base import AdaptiveLaw, EpochContext, UpdatePlan
from .innovation import _rows_nonzeros
from .params import ParamSpec, check_option
from .robust_rows import fit_reference, fit_row, fit_work, groups_reference, load_prior, row_group

RHO_SPEC = ParamSpec("rho", 0.0, 1.0, low_closed=False, high_closed=True,
                     doc="VB-AKF forgetting factor of the variance estimates")


@dataclass(frozen=True)
class VbConfig:
    """Configuration of :class:`VariationalR`.

    Attributes
    ----------
    rho : initial forgetting factor (per-row settable), (0, 1] (default 0.95: a memory of ~20 epochs).
    n_iter : fixed-point iterations per epoch at most (>= 1; default 5).
    tol : the iterations stop once no scale changes by more than this fraction (>= 0; default 1e-3; 0 runs all
        ``n_iter``).
    alpha0 : prior shape of a new satellite's scale (> 0; its prior scale is 1).
    scale_min, scale_max : bounds of the scale handed to the update (0 < min <= 1 <= max).
    forget_after_epochs : epochs unseen after which a satellite restarts from the prior (>= 1).
    """

    rho: float = 0.95
    n_iter: int = 5
    tol: float = 1e-3
    alpha0: float = 1.0
    scale_min: float = 1.0
    scale_max: float = 1e4
    forget_after_epochs: int = 50

    def __post_init__(self):
        o = type(self).__name__
        RHO_SPEC.check(self.rho, owner=o)
        check_option(o, "alpha0", self.alpha0, low=0.0, low_closed=False)
        check_option(o, "tol", self.tol, low=0.0)
        check_option(o, "scale_min", self.scale_min, low=0.0, high=1.0, low_closed=False)
        check_option(o, "scale_max", self.scale_max, low=1.0)
        for name in ("n_iter", "forget_after_epochs"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"{o}.{name} must be an int >= 1, got {v!r}")


@nb.njit(cache=True)
def _vb_row(r, H, Rd, mask, keys, Pm, work, var, ad, bm, rho, epoch, a_tab, b_tab, last_tab, forget, alpha0, smin,
            smax, n_iter, tol, scale, a_rows, b_rows):
    """The update of one batch row (module docstring): ``scale`` (m,) the variance scales handed to the update
    (1 on rows not adapted), ``a_rows`` / ``b_rows`` (m,) the alpha and beta to commit (0 on rows not adapted).
    ``ad`` (m,) bool and ``bm`` (m,) scratch."""
    nzc, nzv, cnt, _, post, v, red = work
    m, n = H.shape
    _rows_nonzeros(H, mask, nzc, nzv, cnt)
    for i in range(m):
        key = keys[i]
        ad[i] = mask[i] and key >= 0 and row_group(H, i, n) < 2
        scale[i] = 1.0
        a_rows[i] = 0.0
        b_rows[i] = 0.0
        var[i] = np.float64(Rd[i])
        if ad[i]:
            last = last_tab[key]
            u = epoch - last
            if last < 0 or u > forget:
                am, bmi = alpha0, alpha0
            else:
                f = rho ** u
                am, bmi = f * a_tab[key], f * b_tab[key]
            a_rows[i] = am + 0.5
            bm[i] = bmi
            b_rows[i] = bmi
    for it in range(n_iter):
        for i in range(m):
            if ad[i]:
                scale[i] = min(max(b_rows[i] / a_rows[i], smin), smax)
                var[i] = scale[i] * np.float64(Rd[i])
        fit_row(r, nzc, nzv, cnt, Pm, var, mask, post, v, red)
        change = 0.0
        for i in range(m):
            if ad[i] and red[i] > 0:
                hph = var[i] * (1.0 - red[i])
                b_rows[i] = bm[i] + 0.5 * (v[i] * v[i] + hph) / np.float64(Rd[i])
                change = max(change, abs(min(max(b_rows[i] / a_rows[i], smin), smax) / scale[i] - 1.0))
        if change < tol:
            break


def _vb_rows(r, H, prior, Q, add_q, Rd, mask, keys, rho, epoch, a_tab, b_tab, last_tab, forget, alpha0, smin, smax,
             n_iter, tol, scale, a_rows, b_rows, nchunk):
    """:func:`_vb_row` over every batch row in ``nchunk`` chunks (parallel in the parallel variant)."""
    B, m, n = H.shape
    for ch in nb.prange(nchunk):
        work = fit_work(m, n, H.dtype)
        Pm = work[3]
        var = np.ones(m)
        ad = np.zeros(m, np.bool_)
        bm = np.zeros(m)
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            load_prior(prior, Q, add_q, b, Pm)
            _vb_row(r[b], H[b], Rd[b], mask[b], keys[b], Pm, work, var, ad, bm, rho[b], epoch[b], a_tab[b], b_tab[b],
                    last_tab[b], forget, alpha0, smin, smax, n_iter, tol, scale[b], a_rows[b], b_rows[b])


_vb_serial, _vb_parallel = serial_and_parallel(_vb_rows)


class VariationalR(AdaptiveLaw):
    """Variational-Bayes adaptive R per satellite around any form (module docstring; ``vb-akf``).

    Parameters
    ----------
    P0, x0, dtype, inner, config : as :class:`~.base.AdaptiveLaw` (``config``: :class:`VbConfig`).
    """

    name = "vb-akf"
    PARAMS = (RHO_SPEC,)
    config_class = VbConfig

    def _init_state(self):
        B, K = self.batch_size, 2 * N_SAT_KEYS
        self._epoch = np.zeros(B, np.int64)
        self._alpha = np.zeros((B, K))
        self._beta = np.zeros((B, K))
        self._last = np.full((B, K), -1, np.int64)
        self._scale_max = np.ones(B)

    def _inputs(self, mask):
        B, m = mask.shape
        keys = self._keys if self._keys is not None else np.full((B, m), -1, np.int64)
        return np.ascontiguousarray(keys, np.int64)

    def _plan(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        cfg = self.config
        B, m = mask.shape
        keys = self._inputs(mask)
        epoch = self._epoch + bool(ctx.pending)  # (a second update of one epoch predicts nothing)
        scale, a_rows, b_rows = np.ones((B, m)), np.zeros((B, m)), np.zeros((B, m))
        c = np.ascontiguousarray
        kern, nchunk = row_kernel(_vb_serial, _vb_parallel, B)
        P = c(ctx.prior)
        kern(c(r), c(H), P, c(ctx.Q) if ctx.pending else P, bool(ctx.pending),
             c(np.diagonal(R, axis1=1, axis2=2), np.float64), c(mask, bool), keys, self._params["rho"], epoch,
             self._alpha, self._beta, self._last, int(cfg.forget_after_epochs), float(cfg.alpha0),
             float(cfg.scale_min), float(cfg.scale_max), int(cfg.n_iter), float(cfg.tol), scale, a_rows, b_rows,
             nchunk)
        s = np.sqrt(scale).astype(self.dtype)
        return UpdatePlan(fade=np.ones(B), R=R * s[:, :, None] * s[:, None, :], mask=mask,
                          pending=dict(keys=keys, epoch=epoch, scale=scale, alpha=a_rows, beta=b_rows))

    def _commit(self, plan: UpdatePlan, ctx: EpochContext, r, H, mask, dx):
        p = plan.pending
        used = p["alpha"] > 0
        b_idx, i_idx = np.nonzero(used)
        k = p["keys"][b_idx, i_idx]
        self._alpha[b_idx, k] = p["alpha"][b_idx, i_idx]
        self._beta[b_idx, k] = p["beta"][b_idx, i_idx]
        self._last[b_idx, k] = p["epoch"][b_idx]
        self._epoch = p["epoch"]
        self._scale_max = np.where(used.any(1), np.max(np.where(used, p["scale"], 1.0), 1), 1.0)

    def _state(self) -> dict:
        return {"vb_scale_max": self._scale_max}

    def satellite_scales(self, keys) -> np.ndarray:
        """The current (unclipped) scale ``beta / alpha`` of the measurement keys ``keys`` (B, k); 1 for keys
        never seen."""
        keys = np.asarray(keys, np.int64)
        kk = np.maximum(keys, 0)
        a = np.take_along_axis(self._alpha, kk, 1)
        seen = (keys >= 0) & (np.take_along_axis(self._last, kk, 1) >= 0)
        return np.where(seen, np.take_along_axis(self._beta, kk, 1) / np.where(seen, a, 1.0), 1.0)

    def _vb_reference(self, r, H, R, mask, ctx: EpochContext):
        """Numpy specification of the plan's kernel: ``(scale, alpha, beta)`` (B, m) as :func:`_vb_rows` writes."""
        cfg = self.config
        B, m = mask.shape
        keys = self._inputs(mask)
        P_minus = ctx.prior + ctx.Q if ctx.pending else ctx.prior
        Rd = np.diagonal(R, axis1=1, axis2=2).astype(np.float64)
        scale, a_rows, b_rows = np.ones((B, m)), np.zeros((B, m)), np.zeros((B, m))
        epoch = self._epoch + bool(ctx.pending)
        for b in range(B):
            ad = mask[b] & (keys[b] >= 0) & (groups_reference(np.asarray(H[b])) < 2)
            kk = np.maximum(keys[b], 0)
            last = self._last[b, kk]
            u = epoch[b] - last
            fresh = (last < 0) | (u > cfg.forget_after_epochs)
            f = self._params["rho"][b] ** np.where(fresh, 0, u)
            am = np.where(fresh, cfg.alpha0, f * self._alpha[b, kk])
            bm = np.where(fresh, cfg.alpha0, f * self._beta[b, kk])
            alpha, beta = am + 0.5, bm.copy()
            for _ in range(cfg.n_iter):
                s = np.where(ad, np.clip(beta / alpha, cfg.scale_min, cfg.scale_max), 1.0)
                var = s * Rd[b]
                _, v, red, _ = fit_reference(r[b], H[b], P_minus[b], var, mask[b])
                upd = ad & (red > 0)
                beta = np.where(upd, bm + 0.5 * (v ** 2 + var * (1 - red)) / Rd[b], beta)
                new = np.clip(beta / alpha, cfg.scale_min, cfg.scale_max)
                if not np.any(upd) or np.max(np.abs(new[upd] / s[upd] - 1.0)) < cfg.tol:
                    break
            scale[b] = s
            a_rows[b] = np.where(ad, alpha, 0.0)
            b_rows[b] = np.where(ad, beta, 0.0)
        return scale, a_rows, b_rows


__all__ = ["VbConfig", "VariationalR", "RHO_SPEC"]
