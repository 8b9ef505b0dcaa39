"""Strong tracking (``stkf``) and measurement-adaptive strong tracking (``ma-stkf``) around any filter form.

Both scale the propagated covariance of an epoch by a suboptimal fading factor
(seed paper 003 eqs 17-23)::

    P_k|k-1 = lambda_k Phi P_(k-1) Phi^T + Q,    lambda_k = max(1, tr(N_k) / tr(M_k)),
    N_k = C_k - H Q H^T - beta R,                 M_k = H Phi P_(k-1) Phi^T H^T,

with ``C_k`` an estimate of the innovation covariance and ``beta`` a softening
(weakening) factor. ``lambda`` is applied to the epoch's ``Phi P Phi^T``
(``Phi`` the composed transition of the epoch, ``Q`` its composed process
noise, which is not faded), through the inner form's own ``predict`` with
``sqrt(lambda) Phi`` (:mod:`nav_filters.adaptive.base`).

Innovation covariance across changing satellite sets
----------------------------------------------------
Only traces of ``C_k`` enter the laws, but a channel of the navigator carries
different satellites from one epoch to the next and the number of used rows
changes, so ``tr(C_k)`` cannot be smoothed as it stands (losing half the
satellites would look like a drop of the innovation energy). Both laws
therefore smooth the innovation energy *per unit of reported measurement
variance*, ``c_k ~ ||dz_k||^2 / tr(R_k)``, and use ``tr(C_k) = c_k tr(R_k)``.
For a fixed measurement set with fixed reported variances this is exactly the
paper's recursion on ``tr(C_k)``. (Normalizing by ``tr(S_k)`` instead would
feed the fading back into itself: a faded, larger P raises ``tr(S_k)`` and so
the whole smoothed history.)

Safeguards (not in the paper)
-----------------------------
A single fading factor inflates every error state alike, also those the
measurements barely observe (attitude, IMU biases): while the innovations stay
large (NLOS in a street canyon) those variances grow geometrically, epoch after
epoch, until the linearized error model breaks (measured on ``urban``, 8
episodes: the uncapped STKF reached attitude sigmas of 100+ degrees and km
position errors, one episode diverged). Hence ``lambda <= lambda_max`` and a
per-state cap, ``fading_cap`` times the state's initial variance ``P0_ii``
(default 1: fading never makes a state more uncertain than it was at the
start), applied as per-state factors ``D = diag(sqrt(lambda_i))``,
``P <- D Phi P Phi^T D + Q`` (:meth:`~.base.AdaptiveLaw.capped_fading`).
``fading_cap=inf`` gives the paper's single factor.

Updates with no transition since the previous update (a second measurement in
the same epoch) update the statistics but apply no fading.

State events and measurement events (``fading_noise='geometry'``, the default)
------------------------------------------------------------------------------
The laws were designed for sudden changes of the vehicle/sensor state (fading)
and of the measurement statistics (MA-STKF's alpha) (seed 003). As printed,
both read the same innovation excess: a noise burst or an NLOS satellite fades P
(measured, issue 16: STKF fades in a third of the noise-burst epochs; a larger P
then trusts the noisier measurements more), and a converged filter fades on
noise alone, because eq 19 divides a noisy difference of energies by the small
``tr(M_k)`` and ``max(1, .)`` keeps only the upward noise. The default mode
splits each epoch's pseudoranges and rates by a snapshot least-squares fit
(:func:`~.innovation.fit_split`): a state error moves only the fitted part, a
change of the noise level both parts. The fading is the lower
``fading_confidence``-sigma bound of the state-attributable excess over
``tr(M_k)`` (:func:`split_fading`), withheld while the residual noise scale
exceeds ``noise_gate`` (a measurement event); MA-STKF's measurement factor is
per type and from the residuals. Measured on 8 development episodes x 300 s
(seeds outside every evaluation set), horizontal RMSE, printed -> geometry
(``kf``): STKF noise-burst 3.84 -> 1.72 m (1.66), urban-transition 18.97 ->
5.54 (5.41), urban 28.07 -> 14.80 (12.23), noise-mismatch 1.04 -> 0.61 (0.63),
open-sky 1.40 -> 1.40 (1.36). MA-STKF, with its fault test on the residuals too
(:class:`MeasurementAdaptiveSTKF`), 16 development episodes, printed -> geometry
(``kf``): urban 13.25 -> 8.47 (11.46), urban-transition 6.49 -> 3.48 (5.57),
regime-switch 10.02 -> 7.42 (8.30), noise-mismatch 0.65 -> 0.62 (0.84),
noise-burst 2.17 -> 1.71 (1.72), open-sky 1.37 -> 1.37 (1.38), outage 6.95 ->
6.26 (5.56). STKF has no R adaptation, so a measurement event can only be left
alone; MA-STKF answers it with its factor.

MA-STKF's factor per satellite (``r_mode='satellite'``: the per-satellite law of
the registered ``sage-husa``, :mod:`~.satellite_r`, with MA-STKF's ``b``) was
measured against the factor per type on 16 development episodes x 300 s:
urban 10.78 against 8.47 m, urban-transition 3.81 / 3.48, regime-switch 6.93 /
7.42, noise-mismatch 0.71 / 0.62, noise-burst 2.18 / 1.71, open-sky 1.38 / 1.37
(``kf`` 11.46, 5.57, 8.30, 0.84, 1.72, 1.38). Per satellite wins only on
regime-switch, so ``ma-stkf`` keeps the factor per type; the per-satellite mode
is there to be chosen (``law_factory(MeasurementAdaptiveSTKF, 'kf',
r_mode='satellite')``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..error_model import N_STATES
from ..kernels import row_chunks, row_kernel, scale_symmetric, scale_symmetric_reference, unit_diagonal
from .base import AdaptiveLaw, EpochContext, UpdatePlan
from .innovation import fit_split, innovation_traces, measurement_groups
from .params import ParamSpec, check_option
from .satellite_r import SatelliteNoise, check_satellite_options
from .strong_tracking_rows import (SPLIT_STATS, _ma_plan_parallel, _ma_plan_serial, _st_plan_parallel,
                                   _st_plan_serial, ma_epoch, split_fading_kernel, st_epoch)

SOFTENING_SPEC = ParamSpec("softening", 0.0, 1e6, low_closed=False, high_closed=True,
                           doc="softening factor beta of N_k = C_k - H Q H^T - beta R")
RHO_SPEC = ParamSpec("rho", 0.0, 1.0, low_closed=False, high_closed=True,
                     doc="STKF forgetting factor of the innovation covariance")
MA_B_SPEC = ParamSpec("b", 0.0, 1.0, low_closed=False, high_closed=True,
                      doc="MA-STKF asymptotic fading factor b of beta_k = beta_(k-1)/(beta_(k-1) + b)")
FADING_SCALE_SPEC = ParamSpec("fading_scale", 0.0, 1e6, low_closed=False, high_closed=True,
                              doc="MA-STKF scaling of the fading factor, lambda = max(1, s tr(N_k)/tr(M_k))")
MA_R_MODES = ("type", "satellite")
"""Measurement factors of :class:`MeasurementAdaptiveSTKF` in the geometry mode (``r_mode``)."""
FADING_NOISE = ("geometry", "reported")
"""Measurement-noise models subtracted in ``N_k`` (eq 20) by the strong-tracking laws (``fading_noise``)."""
FAULT_SPEC = ParamSpec("fault_threshold", 1.0, np.inf, low_closed=False, high_closed=True,
                       doc="MA-STKF fault test ratio tr(C_k) > threshold * tr(predicted); inf disables")


def check_fading_noise(owner, value):
    """Raise a ValueError naming ``owner.fading_noise`` unless ``value`` is one of :data:`FADING_NOISE`."""
    if value not in FADING_NOISE:
        raise ValueError(f"{owner}.fading_noise must be one of {FADING_NOISE}, got {value!r}")


def split_fading(split, stats_prev, weight, softening, confidence, lambda_max, noise_gate, printed, scale=1.0,
                 fast: bool = False):
    """Fading factor from the part of the innovations a state error can explain (``fading_noise='geometry'``).

    Per epoch, over the measurement types with redundancy (:class:`~.innovation.FitSplit`, weights
    ``W = R^-1``; ``g_t`` the noise scale its residuals estimate, ``p_t`` its fitted columns)::

        n_k = sum_t (e_fit,t - beta g_t p_t - tr(W H Q H^T)_t)     state-attributable excess (eq 20's N_k)
        d_k = sum_t tr(W H M H^T)_t                                 (eq 21's M_k)
        s_k = sum_t 2 (g_t p_t + tr(W H (M + Q) H^T)_t)^2 / p_t     its variance under no model error:
              + 2 g_t^2 p_t^2 / dof_t                              e_fit and g_t p_t (chi-square sums)

    smoothed ``x <- (1 - w) x + w x_k`` (``s`` with ``w^2``, so that it stays the variance of the smoothed
    ``n``), and ``lambda = clip(scale (n - kappa sqrt(s)) / d, 1, lambda_max)``: the lower ``kappa``-sigma
    bound of the paper's ratio ``tr(N_k)/tr(M_k)`` (eq 19). Why not the ratio itself: ``M_k`` is small once a
    filter has converged, so the ratio divides the noise of a difference of two energy estimates by a small
    number, and ``max(1, .)`` rectifies that noise into fading (a constant-velocity snapshot test: mean
    lambda 1.8 with no event at all, and 2.9 m position error against kf's 0.95; the bound with kappa = 2:
    1.3 and 1.7 m, a 60 m jump still faded ~40-fold). The residual energy and its degrees of freedom are
    smoothed alike: ``g = e_res / dof`` is the noise scale of the recent epochs.

    No fading while ``g = e_res / dof`` (smoothed) exceeds ``noise_gate`` (a measurement event); an epoch
    with pseudoranges, rates or aiding rows of the 17-state model (odometer, NHC, ZUPT: ``split.n_other``) but
    no split does not fade (it cannot tell a state error from noise; on seed003-sim's odometer-only outage
    epochs the printed form faded on noise: MA-STKF 3.49 -> 2.97 m, kf 2.81, 16 development episodes); an
    epoch with none of them (rows of another model) takes ``printed`` (eqs 19-21 as written).

    Parameters
    ----------
    split : :class:`~.innovation.FitSplit` (B, T); stats_prev : (B, SPLIT_STATS) smoothed statistics (zeros
    at the start); weight : (B,) smoothing weight in (0, 1]; softening : (B,) beta; confidence : kappa
    (>= 0); lambda_max : float; noise_gate : float (>= 1, inf: no gate); printed : (B,) the printed law's
    lambda; scale : (B,) or scalar multiplier of the ratio; fast : the compiled form
    (:func:`~.strong_tracking_rows.split_fading_kernel`, the fused path's: the same values bit for bit for the
    laws' 2 types, tested with 1-3 in ``tests/nav_filters/test_fused_update.py``; the numpy lines here are its
    specification).

    Returns
    -------
    lam : (B,) fading factors;
    stats : (B, SPLIT_STATS) the new smoothed statistics (unchanged where no type has redundancy).
    """
    if fast:
        B = split.e_fit.shape[0]

        def f64(a):  # (B,) float64, contiguous (a scalar broadcast)
            a = np.asarray(a, np.float64)
            return np.ascontiguousarray(a) if a.shape == (B,) else np.full(B, a)
        lam, stats = np.empty(B), np.empty((B, SPLIT_STATS))
        split_fading_kernel(*(np.ascontiguousarray(a, np.float64) for a in (
            split.e_fit, split.e_res, split.dof, split.p, split.tr_m, split.tr_q, split.n)),
            np.ascontiguousarray(split.n_other, np.float64), np.ascontiguousarray(stats_prev, np.float64),
            f64(weight), f64(softening), float(confidence), float(lambda_max), float(noise_gate), f64(printed),
            f64(scale), lam, stats)
        return lam, stats
    g = split.noise_scale
    ok = split.dof > 0
    beta = np.asarray(softening, np.float64)[:, None]
    p, dof = split.p, np.where(ok, split.dof, 1.0)
    x_k = np.stack([np.where(ok, split.e_fit - beta * g * p - split.tr_q, 0.0).sum(1),
                    split.tr_m.sum(1),
                    np.where(ok, 2.0 * (g * p + split.tr_m + split.tr_q) ** 2 / np.where(p > 0, p, 1.0)
                             + 2.0 * g ** 2 * p ** 2 / dof, 0.0).sum(1),
                    split.e_res.sum(1),
                    split.dof.sum(1)], 1)
    has = ok.any(1)
    w = np.repeat(np.asarray(weight, np.float64)[:, None], SPLIT_STATS, 1)
    keep = 1.0 - w
    w[:, 2] **= 2  # the variance of a weighted sum
    keep[:, 2] **= 2
    stats = np.where(has[:, None], keep * stats_prev + w * x_k, stats_prev)
    n, d, var, e_res, dof_s = stats.T
    pos = d > 0
    lam = np.where(pos, scale * (n - confidence * np.sqrt(np.maximum(var, 0.0))) / np.where(pos, d, 1.0), 1.0)
    lam = np.clip(lam, 1.0, lambda_max)
    noise = np.where(dof_s > 0, e_res / np.where(dof_s > 0, dof_s, 1.0), 1.0)
    lam = np.where(noise > noise_gate, 1.0, lam)
    typed = (split.n > 0).any(1) | (split.n_other > 0)
    return np.where(has, lam, np.where(typed, 1.0, printed)), stats


def _fused_plan_inputs(law, r, H, R, mask, ctx, geometry):
    """What the compiled plans of the fused path read besides the law's state: the epoch's
    :class:`~.innovation.InnovationTraces`, the :class:`~.innovation.FitSplit`'s fields ``(e_fit, e_res, dof, p,
    tr_m, tr_q, n, n_other)`` ((B, 0) arrays without ``geometry``) and the output array of the per-state fading
    factors, (B, n), or (B, 0) where ``fading_cap`` is inf (the one factor per row is lambda itself)."""
    B = law.batch_size
    tr = innovation_traces(r, H, ctx.prior, ctx.Q, R, mask)
    if geometry:
        s = fit_split(r, H, R, mask, ctx.prior, ctx.Q if ctx.pending else None, fast=True)
        c = np.ascontiguousarray
        sp = (c(s.e_fit), c(s.e_res), c(s.dof), c(s.p), c(s.tr_m), c(s.tr_q), c(s.n), c(s.n_other))
    else:
        z = np.empty((B, 0))
        sp = (z, z, z, z, z, z, z, np.zeros(B, np.int64))
    return tr, sp, _fade_out(law)


def _fade_out(law):
    """The plan's output of per-state fading factors: (B, n), or (B, 0) where ``fading_cap`` is inf."""
    return np.empty((law.batch_size, 0 if math.isinf(law.config.fading_cap) else law.n))


def _compiled_epoch_io(law, r, H, R, mask, ctx, geometry):
    """The arrays of a compiled strong-tracking epoch (:func:`~.strong_tracking_rows.st_epoch`,
    :func:`~.strong_tracking_rows.ma_epoch`) that both laws share: the inputs, in the types the Python sequence
    hands its kernels (float64 copies for the fit split); the traces' and fit split's arrays (kept from call to
    call); the update's outputs; the plan's fading output (:func:`_fade_out`) and ``nchunk``."""
    B, m = mask.shape
    n, dt = law.n, law.dtype
    c, e = np.ascontiguousarray, np.empty
    inner = law.inner
    prior, Q = c(ctx.prior, dt), c(ctx.Q, dt)
    f64 = np.float64
    inputs = (c(r), c(H), c(R), c(mask, bool), prior, Q, c(ctx.Phi, dt), c(inner.P, dt), c(inner.x, dt), law.x,
              c(r, f64), c(H, f64), c(prior, f64), c(Q, f64), n == N_STATES)
    split = law._compiled_epoch_scratch((B, m, dt), lambda: (
        e((4, B)), e(B, dt), e(B, dt), e(B, dt), e(B, dt), e((B, m)), e((7, B, 2 if geometry else 0)),
        np.zeros(B, np.int64), e((B, n), dt), e((B, n), dt), e(B, bool)))
    s, xn, ok = split[8:]
    outputs = (s, e((B, n, n), dt), xn, e((B, m), dt), e((B, m), dt), np.zeros(B, dt), ok, e((B, n), dt),
               e(B, np.int64))
    return inputs, split[:8], outputs, _fade_out(law), row_chunks(B)


def fading_factor(tr_c, traces, softening, lambda_max, scale=1.0):
    """Suboptimal fading factor (seed 003 eqs 19-21; Zhou's STF).

    Parameters
    ----------
    tr_c : (B,) trace of the innovation-covariance estimate ``C_k``.
    traces : :class:`~.innovation.InnovationTraces` of the epoch (``tr M``, ``tr H Q H^T``, ``tr R``).
    softening : (B,) softening factor beta (``N_k = C_k - H Q H^T - beta R``).
    lambda_max : upper bound of lambda (a safeguard; the paper has none).
    scale : (B,) or scalar multiplier of the ratio (1 as written).

    Returns
    -------
    (B,) float64 ``lambda_k = clip(scale tr(N_k) / tr(M_k), 1, lambda_max)``; 1 where ``tr(M_k) <= 0``.
    """
    tr_m = traces.tr_m.astype(np.float64)
    tr_n = tr_c - traces.tr_q.astype(np.float64) - softening * traces.tr_r.astype(np.float64)  # eq 20
    ok = tr_m > 0
    lam = np.where(ok, scale * tr_n / np.where(ok, tr_m, 1.0), 1.0)  # eq 19
    return np.clip(lam, 1.0, lambda_max)


@dataclass(frozen=True)
class StrongTrackingConfig:
    """Configuration of :class:`StrongTracking`.

    Attributes
    ----------
    softening : initial softening factor beta (> 0; 1 = no softening; per-row settable).
    rho : initial forgetting factor of the innovation covariance, (0, 1] (0.95; per-row settable).
    lambda_max : upper bound of the fading factor (>= 1; 1 disables fading).
    fading_cap : per-state cap of the faded variance, in units of the initial variance ``P0_ii``
        (:meth:`~nav_filters.adaptive.base.AdaptiveLaw.capped_fading`; ``inf`` applies the single
        factor of the paper uncapped).
    fading_noise : ``'geometry'`` (default): the fading factor from the part of the innovations a state
        error can explain, with the noise level its snapshot-fit residuals estimate, as a lower confidence
        bound (:func:`split_fading`), so that the law fades on state events and not on measurement-noise
        events; ``'reported'``: eqs 19-21 as printed (``N_k = C_k - H Q H^T - beta R_k``). An epoch with
        pseudoranges, rates or aiding rows of the 17-state model (odometer, NHC, ZUPT) but no redundancy does
        not fade (it cannot tell a state error from noise); one with none of them (another model's rows) uses
        the printed form.
    fading_confidence : kappa of :func:`split_fading` (the fading is the lower kappa-sigma bound; 0: the
        point estimate).
    noise_gate : ``fading_noise='geometry'``: no fading while the smoothed residual noise scale exceeds this
        (the measurements are noisier than reported: a measurement event, which inflating P only makes
        worse, and which a law without R adaptation cannot answer; ``inf`` disables).
    """

    softening: float = 1.0
    rho: float = 0.95
    lambda_max: float = 1e3
    fading_cap: float = 1.0
    fading_noise: str = "geometry"
    fading_confidence: float = 3.0
    noise_gate: float = 2.0

    def __post_init__(self):
        o = type(self).__name__
        check_fading_noise(o, self.fading_noise)
        check_option(o, "fading_confidence", self.fading_confidence, low=0.0)
        check_option(o, "noise_gate", self.noise_gate, low=1.0, allow_inf=True)
        SOFTENING_SPEC.check(self.softening, owner=o)
        RHO_SPEC.check(self.rho, owner=o)
        check_option(o, "lambda_max", self.lambda_max, low=1.0)
        check_option(o, "fading_cap", self.fading_cap, low=0.0, low_closed=False, allow_inf=True)


class StrongTracking(AdaptiveLaw):
    """``stkf``: strong tracking filter with a single suboptimal fading factor around an inner form.

    Innovation covariance (Zhou's STF, seed 003 ref [17]): ``V_1 = dz dz^T``,
    ``V_k = (rho V_(k-1) + dz dz^T) / (1 + rho)`` (on the normalized ratio, see the module docstring);
    ``lambda_k`` of :func:`fading_factor` with ``C_k = V_k`` (``fading_noise='reported'``), or by default
    :func:`split_fading` of the epoch's snapshot split smoothed with the same weights ``1/(1 + rho)``,
    gated by ``noise_gate`` (module docstring).

    Per-row parameters: ``softening`` (beta > 0), ``rho`` ((0, 1]).
    Adaptive state: ``lambda`` (the last fading factor), ``innovation_ratio`` (``tr V_k / tr R_k``).
    """

    name = "stkf"
    PARAMS = (SOFTENING_SPEC, RHO_SPEC)
    config_class = StrongTrackingConfig

    def _init_state(self):
        B = self.batch_size
        self._v = np.ones(B)
        self._count = np.zeros(B, np.int64)
        self._lambda = np.ones(B)
        self._fs = np.zeros((B, SPLIT_STATS))

    def _has_compiled_epoch(self) -> bool:
        """Every configuration has a compiled epoch."""
        return True

    def _compiled_epoch(self, r, ctx, H, R, mask):
        """:meth:`AdaptiveLaw._compiled_epoch`: the plan, the inner update and the commit of the fused path as one
        compiled call (:func:`~.strong_tracking_rows.st_epoch`: the same kernels as :meth:`AdaptiveLaw._update`'s
        sequence in the same order, the same bits)."""
        cfg = self.config
        geo = cfg.fading_noise == "geometry"
        inputs, split, out, fade, nchunk = _compiled_epoch_io(self, r, H, R, mask, ctx, geo)
        B, e = self.batch_size, np.empty
        v, has, lam, fs, count = e(B), e(B, bool), e(B), e((B, SPLIT_STATS)), e(B, np.int64)
        settings = self._config_settings(self._plan_settings)
        ok = st_epoch(*inputs, self._count, self._v, self._fs, self._params["rho"], self._params["softening"],
                      self._p0_diag, *settings, nchunk, *split, v, has, lam, fs, fade, *out, count)
        _, Pn, _, r_out, Sd, nis, _, x_new, n_used = out
        res = self._compiled_epoch_end(ok, Pn, x_new, nis, n_used, r_out, Sd)
        self._v, self._count, self._lambda, self._fs = v, count, lam, fs
        return res

    def _plan_settings(self) -> tuple:
        """The settings in the order :func:`~.strong_tracking_rows._st_plan_rows` takes them (``lambda_max`` ...
        ``noise_gate``)."""
        cfg = self.config
        return (float(cfg.lambda_max), float(cfg.fading_cap), cfg.fading_noise == "geometry",
                float(cfg.fading_confidence), float(cfg.noise_gate))

    def _plan(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        if not self.fused:
            return self._plan_reference(r, H, R, mask, ctx)
        # the fused path: the row arithmetic of _plan_reference in one compiled pass (the same bits)
        cfg = self.config
        geo = cfg.fading_noise == "geometry"
        B = self.batch_size
        tr, sp, fade = _fused_plan_inputs(self, r, H, R, mask, ctx, geo)
        v, has, lam = np.empty(B), np.empty(B, bool), np.empty(B)
        fs = np.empty((B, SPLIT_STATS))
        kern, nchunk = row_kernel(_st_plan_serial, _st_plan_parallel, B)
        kern(tr.energy, tr.tr_m, tr.tr_q, tr.tr_r, np.ascontiguousarray(mask, bool), np.ascontiguousarray(ctx.prior),
             bool(ctx.pending), *sp, self._count, self._v, self._fs, self._params["rho"], self._params["softening"],
             self._p0_diag, *self._plan_settings(), v, has, lam, fs, fade, nchunk)
        return UpdatePlan(fade=fade if fade.shape[1] else lam, R=R, mask=mask,
                          pending={"v": v, "has": has, "lambda": lam, "fs": fs})

    def _plan_reference(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        """Numpy specification of :meth:`_plan` (the compiled :func:`~.strong_tracking_rows._st_plan_rows` on
        the fused path; agreement test in tests/nav_filters/test_strong_tracking_rows.py)."""
        has = mask.any(-1)
        tr = innovation_traces(r, H, ctx.prior, ctx.Q, R, mask)
        tr_r = tr.tr_r.astype(np.float64)
        ratio = tr.energy.astype(np.float64) / np.where(has, tr_r, 1.0)
        rho = self._params["rho"]
        v = np.where(self._count == 0, ratio, (rho * self._v + ratio) / (1.0 + rho))
        v = np.where(has, v, self._v)
        cfg = self.config
        lam = fading_factor(v * tr_r, tr, self._params["softening"], cfg.lambda_max)
        fs = self._fs
        if cfg.fading_noise == "geometry":
            split = fit_split(r, H, R, mask, ctx.prior, ctx.Q if ctx.pending else None, fast=self.fused)
            lam, fs = split_fading(split, self._fs, np.where(self._count == 0, 1.0, 1.0 / (1.0 + rho)),
                                   self._params["softening"], cfg.fading_confidence, cfg.lambda_max, cfg.noise_gate, lam,
                                   fast=self.fused)
        lam = np.where(has & ctx.pending, lam, 1.0)
        fade = self.capped_fading(lam, ctx.prior, cfg.fading_cap)
        return UpdatePlan(fade=fade, R=R, mask=mask, pending={"v": v, "has": has, "lambda": lam, "fs": fs})

    def _commit(self, plan, ctx, r, H, mask, dx):
        self._v = plan.pending["v"]
        self._count = self._count + plan.pending["has"]
        self._lambda = plan.pending["lambda"]
        self._fs = plan.pending["fs"]

    def _state(self):
        return {"lambda": self._lambda, "innovation_ratio": self._v}


@dataclass(frozen=True)
class MeasurementAdaptiveSTKFConfig:
    """Configuration of :class:`MeasurementAdaptiveSTKF`.

    Attributes
    ----------
    b : initial asymptotic fading factor b of eq 11, (0, 1] (paper: 0.987; per-row settable).
    softening : initial softening factor beta on R in ``N_k`` (1 = eq 20 as written; per-row settable).
    fading_scale : initial multiplier s of the fading ratio, ``lambda = max(1, s tr(N_k)/tr(M_k))``
        (1 = eq 19 as written; per-row settable).
    fault_threshold : initial ratio of the eq 13 fault test (> 1, ``inf`` disables; per-row settable).
    alpha_min, alpha_max : bounds of the measurement factor alpha_k of eq 16.
    lambda_max : upper bound of the fading factor (>= 1; 1 disables fading).
    max_consecutive_rejections : after this many consecutive rejected epochs a row's next epoch is
        accepted (so a lasting change is tracked instead of being rejected for ever).
    fading_cap : per-state cap of the faded variance in units of ``P0_ii`` (see
        :class:`StrongTrackingConfig`; ``inf``: the paper's single uncapped factor).
    fading_uses_alpha : the measurement noise subtracted in ``N_k`` (eq 20) is the current noise
        model ``alpha_(k-1) R_k`` (True, default) or the reported ``R_k`` as printed (False); see
        :class:`MeasurementAdaptiveSTKF`.
    fading_noise : ``'geometry'`` (default): pseudoranges and rates get one measurement factor per type
        from their snapshot-fit residuals (:class:`~.innovation.FitSplit`: what no state error explains)
        instead of eq 16's innovation excess, and the fading is the lower confidence bound of
        :func:`split_fading` with the current noise model, gated by ``noise_gate``; other measurement
        rows keep eq 16. ``'reported'``: eqs 16 and 19-21 as printed (with ``fading_uses_alpha``).
    fading_confidence, noise_gate : as in :class:`StrongTrackingConfig`, the noise scale measured against
        the current noise model ``alpha_(k-1) R_k``.
    r_mode : geometry mode: ``'type'`` (default) one factor per measurement type, or ``'satellite'`` one
        per satellite and type (:mod:`~.satellite_r`, the law of the registered ``sage-husa`` with this
        law's ``b`` in every satellite's eq 11 weights, bounds ``[sat_scale_min, alpha_max]``; rows without
        a satellite key get a per-group factor).
    r_sample, min_redundancy, prior_inflation, sample_iterations, common_scale, sat_scale_min,
    forget_after_epochs, median_guard : ``r_mode='satellite'``: as in :class:`~.sage_husa.SageHusaConfig` (defaults:
        the registered ``sage-husa``'s).
    warmup_epochs : measurement epochs of a row that only feed ``C_k`` (eqs 10-11) before alpha,
        lambda and the fault test act (``alpha = lambda = 1``): the first ``C_k`` rest on one or two
        innovations, and innovations far below a conservative ``P0`` would drive alpha to its floor
        and then flag the next ordinary epochs as faults. 0: act from the first epoch.
    """

    b: float = 0.987
    softening: float = 1.0
    fading_scale: float = 1.0
    fault_threshold: float = 3.0
    alpha_min: float = 0.1
    alpha_max: float = 1e4
    lambda_max: float = 1e3
    max_consecutive_rejections: int = 5
    fading_cap: float = 1.0
    fading_uses_alpha: bool = True
    warmup_epochs: int = 10
    fading_noise: str = "geometry"
    fading_confidence: float = 3.0
    noise_gate: float = 2.0
    r_mode: str = "type"
    r_sample: str = "consensus"
    min_redundancy: float = 0.05
    prior_inflation: float = 1.0
    sample_iterations: int = 1
    common_scale: bool = False
    sat_scale_min: float = 1.0
    forget_after_epochs: int = 30
    median_guard: bool = False

    def __post_init__(self):
        o = type(self).__name__
        if self.r_mode not in MA_R_MODES:
            raise ValueError(f"{o}.r_mode must be one of {MA_R_MODES}, got {self.r_mode!r}")
        if self.r_mode == "satellite" and self.fading_noise != "geometry":
            raise ValueError(f"{o}.r_mode='satellite' needs fading_noise='geometry', got {self.fading_noise!r}")
        check_satellite_options(o, self)
        if not isinstance(self.fading_uses_alpha, (bool, np.bool_)):
            raise ValueError(f"{o}.fading_uses_alpha must be a bool, got {self.fading_uses_alpha!r}")
        check_fading_noise(o, self.fading_noise)
        check_option(o, "fading_confidence", self.fading_confidence, low=0.0)
        check_option(o, "noise_gate", self.noise_gate, low=1.0, allow_inf=True)
        MA_B_SPEC.check(self.b, owner=o)
        SOFTENING_SPEC.check(self.softening, owner=o)
        FADING_SCALE_SPEC.check(self.fading_scale, owner=o)
        FAULT_SPEC.check(self.fault_threshold, owner=o)
        check_option(o, "alpha_min", self.alpha_min, low=0.0, low_closed=False)
        check_option(o, "alpha_max", self.alpha_max, low=self.alpha_min)
        check_option(o, "lambda_max", self.lambda_max, low=1.0)
        check_option(o, "fading_cap", self.fading_cap, low=0.0, low_closed=False, allow_inf=True)
        for name in ("max_consecutive_rejections", "warmup_epochs"):
            m = getattr(self, name)
            if isinstance(m, bool) or not isinstance(m, (int, np.integer)) or m < 0:
                raise ValueError(f"{o}.{name} must be an int >= 0, got {m!r}")


class MeasurementAdaptiveSTKF(SatelliteNoise, AdaptiveLaw):
    """``ma-stkf``: measurement-adaptive strong tracking Kalman filter (seed paper 003, eqs 10-26).

    At each measurement epoch, per row:

    1. innovation covariance by asymptotic weighting (eqs 10-11)::

           C_k = (1 - beta_k) C_(k-1) + beta_k dz dz^T,   beta_k = beta_(k-1) / (beta_(k-1) + b),

       with ``beta = 1`` at a row's first measurement epoch (``C = dz dz^T``; the paper's initial
       value 1) and ``beta_k -> 1 - b``; smoothed as the ratio ``c_k = tr C_k / tr R_k`` (module
       docstring);
    2. fault test (eq 13): the epoch is rejected (no measurement update, ``applied`` False) when
       ``tr(C_k) > fault_threshold * tr(H (Phi P Phi^T + Q) H^T + alpha_(k-1) R)``. Choices: the
       prediction uses the current measurement factor ``alpha_(k-1)`` (so a slow change of the
       noise level, which alpha tracks, is not a fault; only a jump of C is), and a rejected
       epoch is isolated: its innovation does not enter ``C`` (eq 10 is not committed), up to
       ``max_consecutive_rejections`` in a row;
    3. measurement factor (eq 16)
       ``alpha_k = tr(C_k - H (Phi P Phi^T + Q) H^T) / tr(R_k)`` clipped to
       ``[alpha_min, alpha_max]``; the update uses ``alpha_k R_k`` (eq 24);
    4. fading factor (eqs 19-21) ``lambda_k = max(1, tr(N_k)/tr(M_k))``,
       ``N_k = C_k - H Q H^T - beta alpha_(k-1) R_k`` with ``beta`` the softening factor (1 as
       written), the ratio multiplied by ``fading_scale`` (1 as written), capped at ``lambda_max``
       and per state by ``fading_cap``;
       ``P_k|k-1 = lambda_k Phi P Phi^T + Q`` (eq 23). Choice: eq 20 prints the reported ``R_k``,
       but once eq 24 uses ``alpha_k R_k`` that counts the same innovation excess twice, as
       measurement noise (alpha) *and* as model mismatch (lambda), so a lasting rise of the noise
       level fades P for ever (and ``alpha_k R_k`` itself would make lambda identically 1 by eq 16);
       the noise model the epoch starts with, ``alpha_(k-1) R_k``, makes lambda react to a *jump*
       of the innovations relative to the adapted noise. ``fading_uses_alpha=False`` gives the
       printed form;
    5. the inner form's update with ``alpha_k R_k`` (eqs 24-25; the inner form's own covariance
       update, Joseph for ``kf``, stands for eq 26).

    With ``fading_noise='geometry'`` (the default; module docstring) steps 3 and 4 change for the
    pseudoranges and pseudorange rates: each type gets its own factor,
    ``alpha_t <- clip((1 - beta_k) alpha_t + beta_k g_t)`` with ``g_t`` the noise scale of the type's
    snapshot-fit residuals (:class:`~.innovation.FitSplit`; a common factor of a type leaves its fit
    unchanged, so one fit serves every alpha), and the fading is :func:`split_fading` of the same split
    against the current noise model ``alpha_(k-1) R`` (smoothed with ``beta_k``), gated by
    ``noise_gate``. Other rows keep eq 16's scalar alpha. The fault test (step 2) compares this epoch's
    residual noise scale (against the current noise model) with ``fault_threshold``: a fault is a jump of
    the measurement errors, and a state error, which the fit absorbs, is left to the fading (the printed
    test, against ``tr(H (Phi P Phi^T + Q) H^T + alpha R)``, rejected the first epochs of every IMU bias
    step of ``noise-mismatch`` once alpha had found a too large reported variance: 1.67 m against the
    printed law's 0.66 on the 32 episodes of docs/headroom.md). The per-type factors learn from rejected
    epochs too (their residuals still measure the noise level; otherwise a lasting burst is rejected in
    cycles of ``max_consecutive_rejections`` while the factor stays low: noise-burst 2.16 m against 1.71).
    Epochs without redundancy use the printed test.

    Per-row parameters: ``b`` ((0, 1]), ``softening`` (> 0), ``fading_scale`` (> 0, multiplies the
    ratio of eq 19), ``fault_threshold`` ((1, inf]).
    Adaptive state: ``lambda``, ``alpha`` (eq 16), ``alpha_pseudorange``, ``alpha_rate`` (geometry mode; 1
    otherwise), ``beta``, ``innovation_ratio`` (``c_k``), ``rejected`` (0/1, the last epoch),
    ``rejections`` (consecutive rejected epochs).
    """

    name = "ma-stkf"
    PARAMS = (MA_B_SPEC, SOFTENING_SPEC, FADING_SCALE_SPEC, FAULT_SPEC)
    config_class = MeasurementAdaptiveSTKFConfig

    def _init_state(self):
        B = self.batch_size
        self._c = np.ones(B)
        self._beta = np.ones(B)
        self._count = np.zeros(B, np.int64)
        self._alpha = np.ones(B)
        self._lambda = np.ones(B)
        self._rejected = np.zeros(B, bool)
        self._streak = np.zeros(B, np.int64)
        self._alpha_t = np.ones((B, 2))
        self._fs = np.zeros((B, SPLIT_STATS))
        self._r_scale = np.ones((B, 3))  # satellite mode: group factors of rows without a satellite key
        self._init_satellite_tables()

    def _sat_enabled(self):
        return self.config.r_mode == "satellite" and self.config.fading_noise == "geometry"

    def _sat_bounds(self):
        return self.config.alpha_min, self.config.alpha_max

    def _current_factors(self, types):
        """(B, m) the noise model the epoch starts with: each row's factor on its reported variance."""
        a = self._row_factors(self._alpha, self._alpha_t, types)
        if not self._sat_enabled():
            return a
        keys = self._keys if self._keys is not None else np.full(types.shape, -1, np.int64)
        g = np.take_along_axis(self._r_scale, np.clip(types, 0, 2), 1)
        return np.where(types >= 0, np.where(keys >= 0, self.satellite_scales(keys), g), a)

    def _row_factors(self, alpha, alpha_t, types):
        """(B, m) measurement factor of each row: its type's ``alpha_t`` (pseudoranges 0, rates 1) in the
        geometry mode, else the scalar ``alpha``."""
        if self.config.fading_noise != "geometry":
            return np.broadcast_to(alpha[:, None], types.shape)
        return np.where(types == 0, alpha_t[:, :1], np.where(types == 1, alpha_t[:, 1:2], alpha[:, None]))

    def _has_compiled_epoch(self) -> bool:
        """The default configuration (geometry noise, no per-satellite R) has a compiled epoch."""
        return self.config.fading_noise == "geometry" and not self._sat_enabled()

    def _compiled_epoch(self, r, ctx, H, R, mask):
        """:meth:`AdaptiveLaw._compiled_epoch`: the plan, the inner update and the commit of the fused path of the
        default configuration as one compiled call (:func:`~.strong_tracking_rows.ma_epoch`: the same kernels as
        :meth:`AdaptiveLaw._update`'s sequence in the same order, the same bits)."""
        inputs, split, out, fade, nchunk = _compiled_epoch_io(self, r, H, R, mask, ctx, True)
        B, m = mask.shape
        e = np.empty
        c_new, beta, alpha, lam = e(B), e(B), e(B), e(B)
        accept, fault, alpha_t, fs = e(B, bool), e(B, bool), e((B, 2)), e((B, SPLIT_STATS))
        R_used, mask_used, count, streak = e((B, m, m), self.dtype), e((B, m), bool), e(B, np.int64), e(B, np.int64)
        p = self._params
        settings = self._config_settings(self._plan_settings)
        ok = ma_epoch(*inputs, self._count, self._c, self._beta, self._alpha, self._alpha_t, self._fs, self._streak,
                      p["b"], p["softening"], p["fading_scale"], p["fault_threshold"], self._p0_diag,
                      *settings, nchunk, *split, c_new, beta, alpha, accept, fault, lam, alpha_t, fs,
                      fade, R_used, mask_used, *out, count, streak)
        _, Pn, _, r_out, Sd, nis, _, x_new, n_used = out
        res = self._compiled_epoch_end(ok, Pn, x_new, nis, n_used, r_out, Sd)
        self._c, self._beta, self._alpha, self._alpha_t, self._fs = c_new, beta, alpha, alpha_t, fs
        self._count, self._streak, self._rejected, self._lambda = count, streak, fault, lam
        return res

    def _plan_settings(self) -> tuple:
        """The default configuration's settings in the order :func:`~.strong_tracking_rows._ma_plan_rows` takes
        them (``warmup`` ... ``noise_gate``)."""
        cfg = self.config
        return (int(cfg.warmup_epochs), int(cfg.max_consecutive_rejections), float(cfg.alpha_min),
                float(cfg.alpha_max), float(cfg.lambda_max), float(cfg.fading_cap), bool(cfg.fading_uses_alpha),
                float(cfg.fading_confidence), float(cfg.noise_gate))

    def _plan(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        cfg = self.config
        if not (self.fused and cfg.fading_noise == "geometry" and not self._sat_enabled()):
            return self._plan_reference(r, H, R, mask, ctx)
        # the fused path of the default configuration: the row arithmetic of _plan_reference in one compiled
        # pass (the same bits)
        B, m = mask.shape
        tr, sp, fade = _fused_plan_inputs(self, r, H, R, mask, ctx, True)
        c, beta, alpha, lam = np.empty(B), np.empty(B), np.empty(B), np.empty(B)
        accept, fault = np.empty(B, bool), np.empty(B, bool)
        alpha_t, fs = np.empty((B, 2)), np.empty((B, SPLIT_STATS))
        R = np.ascontiguousarray(R)
        R_used, mask_used = np.empty(R.shape, R.dtype), np.empty((B, m), bool)
        p = self._params
        kern, nchunk = row_kernel(_ma_plan_serial, _ma_plan_parallel, B)
        kern(tr.energy, tr.tr_m, tr.tr_q, tr.tr_r, np.ascontiguousarray(H), R, np.ascontiguousarray(mask, bool),
             np.ascontiguousarray(ctx.prior), bool(ctx.pending), *sp, self._count, self._c, self._beta, self._alpha,
             self._alpha_t, self._fs, self._streak, p["b"], p["softening"], p["fading_scale"], p["fault_threshold"],
             self._p0_diag, *self._plan_settings(), c, beta, alpha, accept, fault, lam, alpha_t, fs, fade, R_used,
             mask_used, nchunk)
        pending = {"c": c, "beta": beta, "alpha": alpha, "accept": accept, "fault": fault, "lambda": lam,
                   "alpha_t": alpha_t, "fs": fs}
        return UpdatePlan(fade=fade if fade.shape[1] else lam, R=R_used, mask=mask_used, pending=pending)

    def _plan_reference(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        """Numpy specification of :meth:`_plan` (every configuration; the compiled
        :func:`~.strong_tracking_rows._ma_plan_rows` on the fused path of the default one, agreement test in
        tests/nav_filters/test_strong_tracking_rows.py)."""
        cfg = self.config
        geo = cfg.fading_noise == "geometry"
        scale = scale_symmetric if self.fused else scale_symmetric_reference  # D R D: the same bits
        has = mask.any(-1)
        tr = innovation_traces(r, H, ctx.prior, ctx.Q, R, mask)
        tr_m, tr_q, tr_r = (a.astype(np.float64) for a in (tr.tr_m, tr.tr_q, tr.tr_r))
        ratio = tr.energy.astype(np.float64) / np.where(has, tr_r, 1.0)
        types = np.where(mask, measurement_groups(H, mask), -1)
        Rdiag = np.where(mask, np.diagonal(R, axis1=1, axis2=2).astype(np.float64), 0.0)
        # eqs 10-11 (beta = 1 at the first epoch)
        beta = np.where(self._count == 0, 1.0, self._beta / (self._beta + self._params["b"]))
        c = (1.0 - beta) * self._c + beta * ratio
        tr_c = c * tr_r
        # eq 13: fault test against the predicted innovation trace with the current noise model
        acting = has & (self._count >= cfg.warmup_epochs)
        a_model = self._current_factors(types)
        tr_model = (a_model * Rdiag).sum(1)
        predicted = tr_m + tr_q + tr_model
        fault = acting & (tr_c > self._params["fault_threshold"] * predicted)
        if geo:
            # the snapshot split with the reported R (a common factor per type leaves the fit unchanged)
            split = fit_split(r, H, R, mask, ctx.prior, ctx.Q if ctx.pending else None, fast=self.fused)
            if self._sat_enabled():  # the split against the current per-satellite noise model
                model = fit_split(r, H, scale(R, np.sqrt(a_model)), mask, ctx.prior,
                                  ctx.Q if ctx.pending else None, fast=self.fused)
            else:  # the same split against alpha_(k-1) R
                model = split.scaled(self._alpha_t)
            # a fault is a jump of the measurement errors: this epoch's residual noise scale against the model
            # (a state error, which the fit absorbs, is the fading's business, not a fault)
            fault = np.where(model.dof.sum(1) > 0, acting & (model.pooled_noise_scale > self._params["fault_threshold"]),
                             fault)
        fault = fault & (self._streak < cfg.max_consecutive_rejections)
        accept = has & ~fault
        # eq 16: measurement factor
        safe_r = np.where(tr_r > 0, tr_r, 1.0)
        alpha = np.clip((tr_c - tr_m - tr_q) / safe_r, cfg.alpha_min, cfg.alpha_max)
        alpha = np.where(accept & acting, alpha, self._alpha)
        # eqs 19-21: fading factor (N_k with the current noise model alpha_(k-1) R_k, or the reported R_k)
        soft = self._params["softening"] * (self._alpha if cfg.fading_uses_alpha else 1.0)
        lam = fading_factor(tr_c, tr, soft, cfg.lambda_max, scale=self._params["fading_scale"])
        alpha_t, fs = self._alpha_t, self._fs
        if geo:
            ok = split.dof > 0
            upd = ok & acting[:, None]  # a rejected epoch's residuals still measure the noise level
            alpha_t = np.where(upd, np.clip((1.0 - beta[:, None]) * self._alpha_t + beta[:, None] * split.noise_scale,
                                            cfg.alpha_min, cfg.alpha_max), self._alpha_t)
            lam, fs_new = split_fading(model, self._fs, beta, self._params["softening"], cfg.fading_confidence,
                                       cfg.lambda_max, cfg.noise_gate, lam, scale=self._params["fading_scale"],
                                       fast=self.fused)
            fs = np.where(accept[:, None], fs_new, self._fs)
        lam = np.where(accept & acting & ctx.pending, lam, 1.0)
        pending = {"c": np.where(accept, c, self._c), "beta": np.where(accept, beta, self._beta),
                   "alpha": alpha, "accept": accept, "fault": fault, "lambda": lam, "alpha_t": alpha_t, "fs": fs}
        # masked rows keep unit variance (they change nothing, but stay the documented neutral rows)
        if self._sat_enabled():  # per satellite and type (seed 000's law with this law's b and eq 11 weights)
            R_used = unit_diagonal(self._plan_satellite(r, H, R, mask, ctx, beta, accept & acting, pending).R.copy(),
                                   mask)
        else:
            a = np.where(accept[:, None], self._row_factors(alpha, alpha_t, types), 1.0).astype(R.dtype)
            R_used = scale(R, np.sqrt(a), keep=mask)
        fade = self.capped_fading(lam, ctx.prior, cfg.fading_cap)
        return UpdatePlan(fade=fade, R=R_used, mask=mask & ~fault[:, None], pending=pending)

    def _commit(self, plan, ctx, r, H, mask, dx):
        p = plan.pending
        self._c, self._beta, self._alpha = p["c"], p["beta"], p["alpha"]
        self._alpha_t, self._fs = p["alpha_t"], p["fs"]
        if "sat" in p:
            self._r_scale = p["r_scale"]
            self._commit_satellites(mask, *p["sat"], p["epoch"])
        self._count = self._count + p["accept"]
        has = mask.any(-1)
        self._streak = np.where(p["fault"], self._streak + 1, np.where(has, 0, self._streak))
        self._rejected = p["fault"]
        self._lambda = p["lambda"]

    def _state(self):
        return {"lambda": self._lambda, "alpha": self._alpha, "alpha_pseudorange": self._alpha_t[:, 0],
                "alpha_rate": self._alpha_t[:, 1], "beta": self._beta, "innovation_ratio": self._c,
                "rejected": self._rejected.astype(np.float64), "rejections": self._streak.astype(np.float64),
                **self._satellite_state()}
