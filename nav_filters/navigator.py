"""The batched tightly coupled GNSS/INS navigator (closed-loop error-state filter).

One :class:`Navigator` runs B independent navigation solutions in lock step:

* ``propagate_epoch(f_raw, w_raw, dt)`` (or ``propagate`` for one sample) for
  the IMU samples between two GNSS epochs: bias compensation, the ECEF
  strapdown mechanization and the 17-state transition, in one compiled call
  (:mod:`nav_filters.kernels`, checked against the numpy reference
  :func:`nav_filters.ins.mechanize` and
  :func:`nav_filters.error_model.system_matrix`). The per-sample transitions
  are composed over the epoch and handed to the filter form's ``predict`` once,
  just before the update: exactly (``Phi_acc = Phi_n...Phi_1``, ``Q_acc``
  propagated through every ``Phi_i``, identical to predicting at every sample)
  or, with the ``+onestep`` suffix, as seed paper 001's one-step prediction of
  P (eqs 19-20: the product of transitions and the summed process noise).
  With ``NavigatorConfig(exact_transition=False)`` nothing is composed per sample:
  the kernel integrates F and the process noise over the epoch and the transition
  and process noise are formed once, from the averaged dynamics
  (:mod:`nav_filters.averaged_transition`: ``Phi = exp(int F dt)``, ``Q`` its
  Van Loan integral, as short series), several times cheaper.
* ``update_gnss(...)`` once per GNSS epoch: pseudorange / pseudorange-rate
  innovations (:mod:`nav_filters.measurements`), the form's measurement update,
  and closed-loop feedback of the estimated errors into the INS, the IMU bias
  estimates and the receiver clock.

Precision: the navigation state (position, velocity, attitude, biases, clock)
is float64 always (float32 cannot hold an ECEF position finer than 0.5 m); the
``dtype`` of the config is the arithmetic of the *filter form* (covariance or
its factors, gains), which is what the float32 comparisons of seed paper 000
are about.

Failure isolation: a failure in one batch row stays in that row. A row is flagged in
:attr:`Navigator.diverged` (with its reason in :attr:`Navigator.divergence_code`,
:data:`DIVERGENCE_REASONS`) and parked (frozen at a neutral state, its measurement
updates skipped) when

* its nominal state (position, velocity, attitude, clock) becomes non-finite;
* its filter update or time update fails (``numpy.linalg.LinAlgError``: a matrix the
  form factorizes is not positive definite, or an SVD does not converge). A batched
  call fails as a whole, so the rows that fail are found by running *the same
  operation* (the form's own ``update`` / ``predict``, in its dtype, with the
  measurement covariance the adaptive law actually uses) on copies of the form in
  which the other rows are neutral (:meth:`Navigator._failing_rows`, bisection);
  the flagged rows are parked and the operation is run again for the others;
* its covariance after an update is not positive definite (or has NaN, or a
  non-positive variance): a Cholesky factorization in float64 of the values the
  form holds, over the states with finite variance (an information form's ``+inf``
  variance is an unobserved direction, not a divergence).
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from .error_model import ATT, BA, BG, CLK, DRIFT, N_STATES, POS, VEL, ProcessNoise
from .forms import UpdateResult
from .registry import make_form, parse_method
from .forms.base import check_dtype
from .ins import _earth_rate_matrices_np, apply_correction
from .averaged_transition import SERIES_ORDER, averaged_transition_into, _serial as _averaged_serial
from .forms.base import _prepare_serial
from .forms.kf import _prior_serial
from .kernels import (F_NONZERO, PARALLEL_MIN_BATCH, cholesky_inplace, row_kernel,
                      serial_and_parallel)
from .propagation import propagate_epoch
from .measurements import (_dop_kernel, _innovations_serial, _measurement_keys_kernel, dop, gnss_innovations,
                           measurement_keys)
from .rows import check_row_pairs, copy_rows_generic


DIVERGENCE_REASONS = (
    "",
    "navigation state not finite",
    "filter update failed (a matrix the form factorizes was not positive definite or did not converge)",
    "covariance not positive definite",
)
"""Why a row diverged, indexed by :attr:`Navigator.divergence_code` (0: not diverged)."""
REASON_STATE, REASON_UPDATE, REASON_COVARIANCE = 1, 2, 3


@dataclass(frozen=True)
class NavigatorConfig:
    """Configuration of the navigator.

    Attributes
    ----------
    noise : continuous-time process-noise densities (SI) the filter assumes (required: a filter with
        no process noise is never what a user meant).
    method : filter method name of DESIGN.md section 4 (e.g. ``'kf'``, ``'kf+onestep'``).
    use_pseudorange_rate : fuse pseudorange rates (Doppler) as well as pseudoranges.
    dtype : ``'float64'`` (default) or ``'float32'``: the filter form's arithmetic.
    exact_transition : how the covariance is carried over the IMU samples between two predicts.
        ``True`` (default): the per-sample transitions ``Phi_i = I + F_i dt`` and noises
        ``Q_i = G Q_c G^T dt`` are composed at every sample (``Phi = Phi_n ... Phi_1``,
        ``Q = Phi_n (... (Phi_1 0 Phi_1^T + Q_1) ...) Phi_n^T + Q_n``), identical to a predict per sample.
        ``False``: the averaged dynamics (:mod:`nav_filters.averaged_transition`): the kernel only sums
        ``A = sum_i F_i dt`` and ``S = sum_i Q_i``, and the predict gets ``Phi = exp(A)`` and
        ``Q = sum_k N_k / (k+1)!`` (``N_0 = S``, ``N_k = A N_{k-1} + N_{k-1} A^T``), the exact transition
        and noise of the constant system with the epoch's mean F and mean ``G Q_c G^T``. With ``+onestep``
        the ``Phi`` is the same and ``Q = S`` (seed 001's summed noise).

    fused_update : ``False`` (default): the filter form computes as it always did (numpy recursion, the
        compiled Joseph update). ``True``: the fast path of the forms that have one (``kf``, ``svd-kf``,
        ``svd-srkf``, and the adaptive laws around them: ``sage-husa``, ``stkf``, ``ma-stkf``, ``svd-akf``,
        ``svd-asrkf``, ...; :meth:`~nav_filters.forms.base.FilterForm.set_fused`): an adaptive law's deferred
        prediction and the inner form's update run as one compiled kernel per epoch
        (:func:`nav_filters.forms.kf.fused_update`: masked rows left out, no allocation per row, the law's
        prior ``Phi P Phi^T`` reused; :func:`nav_filters.forms.svd_rows.svd_fused_update` for the SVD forms) and
        the laws' row kernels run parallel over rows. The same equations with a different rounding (checked
        against the numpy recursion in ``tests/nav_filters/test_fused_update.py`` and
        ``tests/nav_filters/test_svd_fused.py``); forms without a fused path ignore it. Independent of
        ``exact_transition``.

    The transition of one IMU sample is ``Phi = I + F dt`` with the first-order process noise
    ``Q = G Q_c G^T dt`` (Groves eq 3.46 truncated; the trapezoidal form differs by O(F dt) ~ 1e-4
    relative at 100 Hz).
    """

    noise: ProcessNoise
    method: str = "kf"
    use_pseudorange_rate: bool = True
    dtype: str = "float64"
    exact_transition: bool = True
    fused_update: bool = False

    def __post_init__(self):
        parse_method(self.method)
        if not isinstance(self.exact_transition, (bool, np.bool_)):
            raise ValueError(f"exact_transition must be a bool, got {self.exact_transition!r}")
        if not isinstance(self.fused_update, (bool, np.bool_)):
            raise ValueError(f"fused_update must be a bool, got {self.fused_update!r}")
        if not isinstance(self.noise, ProcessNoise):
            raise ValueError(f"noise must be a ProcessNoise, got {type(self.noise).__name__}")
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
        f8 = np.float64
        self.r = np.array(r_e, dtype=f8)
        B = self.r.shape[0] if self.r.ndim == 2 else -1
        if self.r.shape != (B, 3):
            raise ValueError(f"r_e must have shape (B, 3), got {self.r.shape}")
        self.v = np.array(v_e, dtype=f8).reshape(B, 3)
        self.C = np.array(C_eb, dtype=f8).reshape(B, 3, 3)
        self.clk = np.array(clock_bias_m, dtype=f8).reshape(B)
        self.drift = np.array(clock_drift_mps, dtype=f8).reshape(B)
        self.bg = np.zeros((B, 3)) if gyro_bias is None else np.array(gyro_bias, f8).reshape(B, 3)
        self.ba = np.zeros((B, 3)) if accel_bias is None else np.array(accel_bias, f8).reshape(B, 3)
        P0 = np.asarray(P0)
        if P0.shape != (B, N_STATES, N_STATES):
            raise ValueError(f"P0 must have shape ({B}, {N_STATES}, {N_STATES}), got {P0.shape}")
        self.form = make_form(config.method, P0, dtype=self.dtype)
        if config.fused_update:
            self.form.set_fused(True)
        self.batch_size = B
        self.diverged = np.zeros(B, bool)
        self.divergence_code = np.zeros(B, np.int8)
        """(B,) why each row diverged: an index into :data:`DIVERGENCE_REASONS` (0: it has not)."""
        self.time_since_update = np.zeros(B)
        """(B,) seconds since each row's last GNSS update with at least one satellite."""
        noise = config.noise
        q = noise.diagonal()
        self._qg = np.ascontiguousarray(q[0:3])
        self._qa = np.ascontiguousarray(q[3:6])
        self._qdiag = np.ascontiguousarray(q)
        self._kg = 0.0 if noise.gyro_bias_tau_s is None else -1.0 / noise.gyro_bias_tau_s
        self._ka = 0.0 if noise.accel_bias_tau_s is None else -1.0 / noise.accel_bias_tau_s
        self._earth = {}
        self.exact_transition = bool(config.exact_transition)
        if self.exact_transition:
            self._Phi_acc = np.zeros((B, N_STATES, N_STATES))
            """(B, 17, 17) the composed transition of the pending samples."""
            self._Q_acc = np.zeros((B, N_STATES, N_STATES))
            """(B, 17, 17) the composed (or, ``+onestep``, summed) process noise of the pending samples."""
        else:
            self._F_int = np.zeros((B, N_STATES, N_STATES))
            """(B, 17, 17) ``sum_i F_i dt`` over the pending samples (averaged-dynamics mode)."""
            self._Qc_int = np.zeros((B, N_STATES, N_STATES))
            """(B, 17, 17) ``sum_i G Q_c G^T dt`` over the pending samples (averaged-dynamics mode)."""
        self._pending = 0
        """IMU samples integrated since the last flush; at 0 the propagation kernel starts the accumulators
        afresh (``I`` / 0), so a flush need not clear them."""

    # ------------------------------------------------------------------ time

    def propagate_epoch(self, f_raw, w_raw, dt: float):
        """Advance all rows by n IMU samples.

        Parameters
        ----------
        f_raw, w_raw : (B, n, 3) measured mean specific force [m/s^2] and angular rate [rad/s] over
            each sample interval (raw: the navigator subtracts its bias estimates).
        dt : sample interval [s] (> 0).
        """
        # a strided view (an epoch's slice of a (B, samples, 3) recording) is read in place, not copied
        f = np.asarray(f_raw, dtype=np.float64)
        w = np.asarray(w_raw, dtype=np.float64)
        B = self.batch_size
        if f.ndim != 3 or f.shape[0] != B or f.shape[2] != 3 or w.shape != f.shape:
            raise ValueError(f"f_raw and w_raw must both have shape ({B}, n, 3), got {f.shape} and {w.shape}")
        dt = float(dt)
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be a positive finite number of seconds, got {dt!r}")
        mats = self._earth.get(dt)
        if mats is None:
            Cz, Pm, QH, Qh = _earth_rate_matrices_np(dt)
            mats = self._earth[dt] = tuple(np.ascontiguousarray(m) for m in (Pm, QH, Qh, Cz))
        if self.exact_transition:
            propagate_epoch(self.r, self.v, self.C, self.bg, self.ba, self.clk, self.drift, f, w, dt, *mats,
                            self._qg, self._qa, self._qdiag, self._kg, self._ka, self._Phi_acc, self._Q_acc,
                            not self.onestep, False, F_NONZERO, False, self._pending == 0)
        else:
            propagate_epoch(self.r, self.v, self.C, self.bg, self.ba, self.clk, self.drift, f, w, dt, *mats,
                            self._qg, self._qa, self._qdiag, self._kg, self._ka, self._F_int, self._Qc_int,
                            False, False, F_NONZERO, True, self._pending == 0)
        self._pending += f.shape[1]
        self.time_since_update += dt * f.shape[1]

    def propagate(self, f_raw, w_raw, dt: float):
        """Advance all rows by one IMU sample: ``f_raw``, ``w_raw`` of shape (B, 3)."""
        self.propagate_epoch(np.asarray(f_raw)[:, None, :], np.asarray(w_raw)[:, None, :], dt)

    def flush_prediction(self):
        """Hand the accumulated transition of the pending samples to the form's ``predict``.

        The accumulators themselves are handed over (no copy in float64) and fresh ones are started, so a
        form may keep what it was given. In the averaged-dynamics mode (``exact_transition=False``) the
        transition and process noise are formed here from the integrals
        (:func:`~nav_filters.averaged_transition.averaged_transition_into`; with ``+onestep`` the process
        noise is the summed one)."""
        if not self._pending:
            return
        if self.exact_transition:
            Phi64, Q64 = self._Phi_acc, self._Q_acc
        else:
            B = self.batch_size
            Phi64, Q64 = np.empty((B, N_STATES, N_STATES)), np.empty((B, N_STATES, N_STATES))
            averaged_transition_into(self._F_int, self._Qc_int, Phi64, Q64)
            if self.onestep:
                Q64 = self._Qc_int
                self._Qc_int = np.empty_like(Q64)
        Phi, Q = Phi64.astype(self.dtype, copy=False), Q64.astype(self.dtype, copy=False)

        def predict(form, keep):
            if keep is None:  # fresh arrays, not used here again: a form may keep them
                return form.take_prediction(Phi, Q)
            k = keep[:, None, None]
            return form.predict(np.where(k, Phi, np.eye(N_STATES, dtype=self.dtype)), np.where(k, Q, 0))

        self._isolated(predict)
        if self.exact_transition:
            self._Phi_acc, self._Q_acc = np.empty_like(self._Phi_acc), np.empty_like(self._Q_acc)
        self._pending = 0  # the next propagation starts the accumulators afresh

    # ----------------------------------------------------------- measurement
    def update(self, dz, H, R, mask, keys=None) -> UpdateResult:
        """Closed-loop update with any stacked measurement (GNSS rows, constraints, or both).

        Flushes the pending prediction, runs the form's update on the rows that have not
        diverged, and feeds the estimated errors back into the nominal state.

        Parameters
        ----------
        dz : (B, m) innovations; H : (B, m, 17); R : (B, m) variances or (B, m, m); mask : (B, m) bool.
        keys : (B, m) int measurement identities (:func:`~nav_filters.measurements.measurement_keys`;
            -1 none), or None.
        """
        self.flush_prediction()
        self._check_state()
        return self._update_checked(dz, H, R, mask, keys)

    def _update_checked(self, dz, H, R, mask, keys=None) -> UpdateResult:
        """:meth:`update` after the prediction was flushed and the state checked."""
        mask = np.asarray(mask, bool)

        def update(form, keep):
            m = mask & ~self.diverged[:, None]
            return form.update(dz, H, R, m if keep is None else m & keep[:, None], keys=keys)

        res = self._isolated(update)
        self._feedback(self.form.take_correction())
        return res

    def update_gnss(self, sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, mask,
                    extra=None, sat_keys=None) -> tuple[UpdateResult, np.ndarray]:
        """Tightly coupled update with one GNSS epoch and closed-loop feedback.

        Parameters
        ----------
        sat_pos, sat_vel : (B, C, 3) satellite ECEF position/velocity at transmission time.
        pr, prr : (B, C) pseudorange [m], pseudorange rate [m/s] (``prr`` may be None).
        pr_sigma, prr_sigma : (B, C) measurement standard deviations [m], [m/s].
        mask : (B, C) bool valid channels.
        extra : optional ``(dz, H, R, mask)`` block (e.g. ZUPT/NHC from
            :mod:`nav_filters.constraints`) fused into the same update.
        sat_keys : (B, C) int satellite keys of the channels (:func:`~nav_filters.measurements.satellite_key`,
            -1 on empty channels), optional: they let per-satellite adaptive laws follow a satellite across
            channels (:func:`~nav_filters.measurements.measurement_keys` gives each row's identity).

        Returns
        -------
        result : :class:`~nav_filters.forms.UpdateResult` (rows ``[pr..., prr..., extra...]``)
        gdop : (B,) geometric DOP of the used satellites (inf below 4).
        """
        if sat_keys is not None:
            direct = self._direct_gnss_epoch(sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, mask, sat_keys, extra)
            if direct is not None:
                return direct
        self._check_state()
        mask = np.asarray(mask, bool) & ~self.diverged[:, None]
        pr_var = np.square(np.asarray(pr_sigma, np.float64))
        prr_var = None if prr_sigma is None else np.square(np.asarray(prr_sigma, np.float64))
        dz, H, R, row_mask, u = gnss_innovations(
            self.r, self.v, self.clk, self.drift, sat_pos, sat_vel, pr, prr, pr_var, prr_var, mask,
            use_rate=self.config.use_pseudorange_rate, dtype=self.dtype)
        n_gnss = dz.shape[1]
        if extra is not None:
            from .constraints import stack_measurements
            dz, H, R, row_mask = stack_measurements((dz, H, R, row_mask), extra, dtype=self.dtype)
        keys = None
        if sat_keys is not None:
            sk = np.asarray(sat_keys)
            if sk.shape != mask.shape:
                raise ValueError(f"sat_keys must have shape {mask.shape} (one per channel), got {sk.shape}")
            keys = measurement_keys(sk, n_gnss > mask.shape[1], dz.shape[1] - n_gnss, mask=mask)
        self.flush_prediction()  # the state was checked above and the prediction does not change it
        res = self._update_checked(dz, H, R, row_mask, keys)
        _clear_where_any(mask, self.time_since_update)
        return res, dop(u, mask)

    def _direct_gnss_epoch(self, sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, mask, sat_keys, extra=None):
        """:meth:`update_gnss` as one compiled call for the inputs and one for the law, or None where the general
        sequence must run.

        :func:`_gnss_epoch_inputs` runs the kernels of the general sequence on the same arrays (the state check,
        the innovations, the ``extra`` rows stacked after them as :func:`~nav_filters.constraints.
        stack_measurements` stacks them, the keys, the averaged transition of the pending samples, the
        measurement's preparation and the law's prior ``Phi P Phi^T``) and the law's :meth:`~nav_filters.adaptive.base.
        AdaptiveLaw.direct_epoch` its compiled epoch, so the results are the same bits (test:
        ``tests/nav_filters/test_direct_epoch.py``) without the Python of the layers in between, which took
        most of a single env's step. It runs where every precondition holds: a fused law with a compiled epoch
        ready for it (:meth:`~nav_filters.adaptive.base.AdaptiveLaw.direct_epoch_ready`) or the fused ``kf``
        itself (:meth:`~nav_filters.forms.kf.KalmanFilter.direct_epoch`: its time update, then its fused update),
        the averaged transition with samples pending, float64, fewer rows than
        :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` (the kernels run serially here) and inputs of the
        expected shapes (an ``extra`` block: a tuple of float64 arrays with (B, m_e) variances). Anything else,
        and a row whose state is not finite or an input the general sequence rejects (it raises the error naming
        it), leaves the work to the general sequence, before any state changed. Where some row's ``S`` is not
        positive definite the law keeps the epoch open and the general update finds, flags and parks the failing
        rows (:meth:`_isolated`)."""
        B = self.batch_size
        form = self.form
        ready = getattr(form, "direct_epoch_ready", None)
        if (self.exact_transition or not self._pending or B >= PARALLEL_MIN_BATCH or self.dtype != np.float64
                or ready is None or not ready()):
            return None
        f8, c = np.float64, np.ascontiguousarray  # (contiguous: one compiled specialization; no copy at B = 1)
        mask_in = c(mask, bool)
        sp, sv, pr, ps = c(sat_pos, f8), c(sat_vel, f8), c(pr, f8), c(pr_sigma, f8)
        sk = c(sat_keys)
        with_rate = bool(self.config.use_pseudorange_rate and prr is not None)
        if with_rate:
            if prr_sigma is None:
                return None
            prr, prs = c(prr, f8), c(prr_sigma, f8)
        else:
            prr, prs = pr, ps
        C = mask_in.shape[-1]
        if (mask_in.shape != (B, C) or sp.shape != (B, C, 3) or sv.shape != (B, C, 3) or sk.shape != (B, C)
                or sk.dtype.kind not in "iu" or not pr.shape == ps.shape == prr.shape == prs.shape == (B, C)):
            return None
        mg = 2 * C if with_rate else C
        n = N_STATES
        me = 0
        if extra is not None:  # (dz (B, m_e), H (B, m_e, n), R (B, m_e) variances, row_mask (B, m_e)), float64
            if not (type(extra) is tuple and len(extra) == 4 and all(type(a) is np.ndarray for a in extra)):
                return None
            e_dz, e_H, e_R, e_mask = (c(a) for a in extra)
            me = e_dz.shape[1] if e_dz.ndim == 2 else -1
            if (me < 1 or e_dz.dtype != f8 or e_H.dtype != f8 or e_R.dtype != f8 or e_mask.dtype != bool
                    or e_dz.shape != (B, me) or e_H.shape != (B, me, n) or e_R.shape != (B, me)
                    or e_mask.shape != (B, me)):
                return None
        m = mg + me
        key = (B, C, with_rate, me)
        # arrays read within this call only (the law keeps none of its inputs; a context left open by a failed
        # row holds Phi, Q and prior until the general update below closes it, within the same call)
        scratch = self.__dict__.get("_direct_scratch")
        if scratch is None or scratch[0] != key:
            e = np.empty
            gnss = (e((B, mg)), e((B, mg, n)), e((B, mg)), e((B, mg), bool))
            scratch = self._direct_scratch = (key, (
                e(B, bool), e((B, C), bool), e((B, C)), e((B, C)), *gnss, e((B, C, 3)), e(1, bool),
                *((e((B, m)), e((B, m, n)), e((B, m)), e((B, m), bool)) if me else gnss),
                e((B, m), np.int64), e((B, n, n)), e((B, n, n)), e((B, n, n)), e((B, m)), e((B, m, n)), e((B, m, m)),
                e((B, 0)), e((B, 0, n)), e((B, 0)), e((B, 0), bool)))
        (bad, mask, pr_var, prr_var, dz, H, R, gnss_mask, u, ok, dz_s, H_s, R_s, row_mask, keys, Phi, Q, prior, dz_o,
         H_o, R_o, *no_extra) = scratch[1]
        if not me:
            e_dz, e_H, e_R, e_mask = no_extra
        with_prior = hasattr(form, "inner")  # a law reads the prior of its inner kf; the plain kf predicts itself
        inner_P = np.ascontiguousarray(getattr(form, "inner", form).P, f8)
        if _gnss_epoch_inputs(self.r, self.v, self.C, self.clk, self.drift, self.diverged, sp, sv, pr, prr, ps, prs,
                              mask_in, sk.astype(np.int64, copy=False), with_rate, self._F_int, self._Qc_int, inner_P,
                              with_prior, SERIES_ORDER, F_NONZERO, e_dz, e_H, e_R, e_mask, bad, mask, pr_var, prr_var,
                              dz, H, R, gnss_mask, u, dz_s, H_s, R_s, row_mask, keys, Phi, Q, prior, dz_o, H_o, R_o,
                              ok):
            return None
        if self.onestep:  # seed 001's summed noise (flush_prediction)
            Q = self._Qc_int
            self._Qc_int = np.empty_like(Q)
        self._pending = 0
        try:
            res = form.direct_epoch(Phi, Q, prior, dz_o, H_o, R_o, row_mask, keys)
        except np.linalg.LinAlgError:  # the epoch stays open in the law: the general update isolates the rows
            res = self._update_checked(dz_o, H_o, R_o, row_mask, keys)
        else:
            return res, self._feedback(form.take_correction(), mask, u)
        _clear_where_any(mask, self.time_since_update)
        return res, dop(u, mask)

    def _isolated(self, op):
        """``op(self.form, None)`` with failure isolation: where it raises ``LinAlgError``, the rows whose own
        operation fails (:meth:`_failing_rows`) are flagged (:data:`REASON_UPDATE`) and parked, and ``op`` runs
        again for the others. The forms commit nothing from a failed call (an adaptive law keeps its pending
        epoch, already predicted, for the retry).

        ``op(form, keep)`` runs the operation on ``form``; ``keep`` (B,) bool (trial runs) says which rows must
        carry their real inputs, the others getting neutral ones (no measurement, identity transition);
        ``keep=None`` is the real call."""
        for _ in range(self.batch_size + 1):
            try:
                return op(self.form, None)
            except np.linalg.LinAlgError:
                bad = self._failing_rows(op)
                if not bad.any():
                    raise
                self._flag(bad, REASON_UPDATE)
        raise AssertionError("unreachable: every retry flags at least one more row")

    def _neutral_form(self, n):
        """A fresh form of ``n`` rows at unit covariance (what parked rows hold)."""
        eye = np.broadcast_to(np.eye(N_STATES), (n, N_STATES, N_STATES)).copy()
        form = make_form(self.config.method, eye, dtype=self.dtype)
        if self.config.fused_update:
            form.set_fused(True)
        return form

    def _failing_rows(self, op) -> np.ndarray:
        """(B,) bool: the live rows whose operation ``op`` raises ``LinAlgError`` when run on their own.

        Each trial runs ``op`` on a copy of the form in its current state (same dtype, same inputs, the
        adaptive law's own R and fading) with every row outside the tried set replaced by a neutral row and
        given neutral inputs, so what fails there is exactly what failed in the batch. The rows are found by
        bisection (about 2 log2(B) trials per failing row); a set that fails while neither half does is
        flagged whole."""
        B = self.batch_size

        def fails(rows):
            trial = copy.deepcopy(self.form)
            keep = np.zeros(B, bool)
            keep[rows] = True
            others = np.flatnonzero(~keep)
            if others.size:
                trial.replace_rows(others, self._neutral_form(others.size))
            try:
                op(trial, keep)
            except np.linalg.LinAlgError:
                return True
            return False

        def search(rows):
            if rows.size == 1:
                return rows
            found = [search(h) for h in np.array_split(rows, 2) if fails(h)]
            return np.concatenate(found) if found else rows

        bad = np.zeros(B, bool)
        live = np.flatnonzero(~self.diverged)
        if live.size and fails(live):
            bad[search(live)] = True
        return bad

    def _feedback(self, dx, mask=None, u=None):
        """Closed-loop correction: add the error-state estimate to the nominal state (B, 17).

        Compiled (:func:`_feedback_rows`); :meth:`_feedback_reference` is the numpy specification
        (agreement test in ``tests/nav_filters/test_kernels.py``). With ``mask`` (B, C) and ``u`` (B, C, 3), the
        used channels and lines of sight of a GNSS epoch on fewer than
        :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows (:meth:`_direct_gnss_epoch`), the same call also
        restarts :attr:`time_since_update` and returns the GDOP (:func:`_feedback_clear_dop`)."""
        dx = np.ascontiguousarray(dx, np.float64)
        P = self.form.covariance
        B = self.batch_size
        r, v, bg, ba = np.empty((B, 3)), np.empty((B, 3)), np.empty((B, 3)), np.empty((B, 3))
        C = np.empty((B, 3, 3))
        clk, drift = np.empty(B), np.empty(B)
        code = np.empty(B, np.int8)
        state = (self.r, self.v, self.C, self.bg, self.ba, self.clk, self.drift, dx, self.diverged,
                 P, r, v, C, bg, ba, clk, drift, code)
        gdop = None
        if mask is None:
            kern, nchunk = row_kernel(_feedback_serial, _feedback_parallel, B)
            kern(*state, nchunk)
            flagged = np.count_nonzero(code)  # (cheaper than .any() on a few rows)
        else:
            gdop = np.empty(B)
            flagged = _feedback_clear_dop(*state, mask, self.time_since_update, u, gdop)
        self.r, self.v, self.C, self.bg, self.ba, self.clk, self.drift = r, v, C, bg, ba, clk, drift
        if flagged:
            for c in (REASON_STATE, REASON_COVARIANCE):
                self._flag(code == c, c)
        return gdop

    def _feedback_reference(self, dx):
        """Numpy reference of :meth:`_feedback` (Groves sec 14.1 closed-loop correction through
        :func:`nav_filters.ins.apply_correction`)."""
        dx = np.where(self.diverged[:, None], 0, np.asarray(dx, np.float64))
        r, v, C = apply_correction(self.r, self.v, self.C, np.asarray(dx, np.float64))
        self.r, self.v, self.C = (np.ascontiguousarray(a, np.float64) for a in (r, v, C))
        self.bg = self.bg + dx[:, BG]
        self.ba = self.ba + dx[:, BA]
        self.clk = self.clk + dx[:, CLK.start].astype(np.float64)
        self.drift = self.drift + dx[:, DRIFT.start]
        finite = np.isfinite(self.r).all(1) & np.isfinite(self.v).all(1) & np.isfinite(self.C).all((1, 2))
        self._flag(~finite, REASON_STATE)
        self._flag(~covariance_is_pd(self.form.covariance), REASON_COVARIANCE)

    def _flag(self, bad, code):
        """Flag rows ``bad`` (B,) bool that have not diverged yet with reason ``code`` and park them."""
        bad = np.asarray(bad, bool)
        if not np.count_nonzero(bad):  # the common case: nothing to flag (count_nonzero: cheaper than .any())
            return
        newly = bad & ~self.diverged
        if newly.any():
            self.diverged |= newly
            self.divergence_code[newly] = code
            self._park(np.flatnonzero(newly))

    def divergence_reasons(self) -> np.ndarray:
        """(B,) str: why each row diverged (:data:`DIVERGENCE_REASONS`; '' where it has not)."""
        return np.asarray(DIVERGENCE_REASONS)[self.divergence_code]

    def _check_state(self):
        """Flag and park rows whose nominal state became non-finite (before any innovation is formed)."""
        bad = np.empty(self.batch_size, bool)
        if _nonfinite_rows(self.r, self.v, self.C, self.clk, self.drift, self.diverged, bad):
            self._flag(bad, REASON_STATE)

    def _park(self, rows):
        """Freeze diverged rows at a neutral finite state (flagged in :attr:`diverged`, never updated again)
        so that the batched LAPACK calls of every form never see a NaN: one diverged row must not stop
        the others."""
        from earth.wgs84 import A as _A
        self.r[rows] = (_A, 0.0, 0.0)
        self.v[rows] = 0.0
        self.C[rows] = np.eye(3)
        self.bg[rows] = 0.0
        self.ba[rows] = 0.0
        self.clk[rows] = 0.0
        self.drift[rows] = 0.0
        self.form.replace_rows(rows, self._neutral_form(rows.size))

    def replace_rows(self, rows, other: "Navigator") -> None:
        """Overwrite batch rows ``rows`` with the state of ``other`` (a navigator of len(rows) rows, same
        config): the nominal state, the filter form (:meth:`FilterForm.replace_rows`), the pending
        transition and the divergence flags. Used to reset single rows of a running batch."""
        rows = np.asarray(rows, dtype=np.intp)
        if other.config != self.config:
            raise ValueError("replace_rows needs a navigator with the same config")
        self.flush_prediction()
        other.flush_prediction()
        for name in ("r", "v", "C", "clk", "drift", "bg", "ba", "diverged", "divergence_code", "time_since_update"):
            getattr(self, name)[rows] = getattr(other, name)
        self.form.replace_rows(rows, other.form)

    _ROW_COPY_SKIP = frozenset({"config", "_qg", "_qa", "_qdiag", "_earth"})
    """Attributes shared by all rows (process-noise diagonals, earth-rate matrices): never copied row-wise."""

    def copy_rows(self, dst, src) -> None:
        """Copy the state of rows ``src`` to rows ``dst`` of this batch (exact branching; overlap allowed).

        Generic (:func:`nav_filters.rows.copy_rows_generic`): the nominal state (r, v, C, clock, biases),
        ``diverged``, ``time_since_update``, the pending transition accumulators and the filter form
        (:meth:`FilterForm.copy_rows`), and any per-row array added later; the shared attributes of
        :attr:`_ROW_COPY_SKIP` stay. Row ``dst[i]`` then continues exactly like row ``src[i]`` on the same
        IMU samples and measurements.

        Parameters
        ----------
        dst, src : (n,) int row indices (equal lengths; ``ValueError`` otherwise).
        """
        dst, src = check_row_pairs(dst, src, self.batch_size)
        copy_rows_generic(self, dst, src, self.batch_size, skip=self._ROW_COPY_SKIP)

    # ----------------------------------------------------------------- views
    @property
    def covariance(self) -> np.ndarray:
        """(B, 17, 17) current error covariance (after flushing nothing: the last form state)."""
        return self.form.covariance

    def position_sigma(self) -> np.ndarray:
        """(B, 3) one-sigma ECEF position uncertainty [m]."""
        return np.sqrt(np.maximum(np.diagonal(self.form.covariance, axis1=1, axis2=2)[:, POS], 0))


_ATT0, _VEL0, _POS0, _BG0, _BA0, _CLK0, _DRIFT0 = (s.start for s in (ATT, VEL, POS, BG, BA, CLK, DRIFT))


@nb.njit(cache=True)
def _nonfinite_rows(r, v, C, clk, drift, diverged, bad):
    """``bad[b]``: row b has not diverged yet and its nominal state (r, v, C, clock) is not finite. Returns
    whether any row is bad."""
    any_bad = False
    for b in range(r.shape[0]):
        ok = np.isfinite(clk[b]) and np.isfinite(drift[b])
        for i in range(3):
            ok = ok and np.isfinite(r[b, i]) and np.isfinite(v[b, i])
            for j in range(3):
                ok = ok and np.isfinite(C[b, i, j])
        bad[b] = not ok and not diverged[b]
        any_bad = any_bad or bad[b]
    return any_bad


@nb.njit(cache=True)
def _gnss_epoch_inputs(r, v, C, clk, drift, diverged, sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, mask_in, sat_keys,
                       with_rate, F_int, Qc_int, P, with_prior, order, nz, e_dz, e_H, e_R, e_mask, bad, mask, pr_var,
                       prr_var, dz, H, R, gnss_mask, u, dz_s, H_s, R_s, row_mask, keys, Phi, Q, prior, dz_o, H_o, R_o,
                       ok):
    """The inputs of a GNSS epoch's update (:meth:`Navigator._direct_gnss_epoch`), by the kernels the general
    sequence of :meth:`Navigator.update_gnss` runs, serially, in one call: :func:`_nonfinite_rows` (``bad``),
    ``mask = mask_in & ~diverged``, the variances ``pr_var = pr_sigma^2``, ``prr_var = prr_sigma^2``, the
    innovations (:func:`~nav_filters.measurements._innovations_rows`: ``dz``, ``H``, ``R`` (B, m_g),
    ``gnss_mask``, ``u``), the ``m_e`` extra rows ``e_dz``, ``e_H``, ``e_R`` (variances), ``e_mask`` stacked
    after them (:func:`_stack_extra`: ``dz_s``, ``H_s``, ``R_s``, ``row_mask`` (B, m_g + m_e); with
    ``m_e = 0`` the caller passes the innovations' arrays themselves), the measurement keys (``keys``), the
    averaged transition of the pending samples
    (:func:`~nav_filters.averaged_transition._averaged_transition_into`: ``Phi``, ``Q`` from ``F_int``,
    ``Qc_int``), the prepared measurement (:func:`~nav_filters.forms.base._prepare_rows`: ``dz_o``, ``H_o``,
    ``R_o`` (B, m, m)) and, with ``with_prior`` (an adaptive law, which reads it), the law's prior
    ``sym(Phi P Phi^T)`` of the inner covariance ``P`` (:func:`~nav_filters.forms.kf._prior_rows`; the plain ``kf``
    forms its own in its predict).

    Returns 0, or where the general sequence must run instead (no state was changed): 1 a live row's nominal
    state is not finite, 2 a satellite key out of range, 3 a used measurement row not finite or a variance not
    positive (the general sequence flags the rows, or raises the error naming the input).
    """
    if _nonfinite_rows(r, v, C, clk, drift, diverged, bad):
        return 1
    B, n_ch = mask_in.shape
    for b in range(B):
        for j in range(n_ch):
            mask[b, j] = mask_in[b, j] and not diverged[b]
            s = pr_sigma[b, j]
            pr_var[b, j] = s * s
            s = prr_sigma[b, j]
            prr_var[b, j] = s * s
    _innovations_serial(r, v, clk, drift, sat_pos, sat_vel, pr, prr, pr_var, prr_var, mask, with_rate, dz, H, R,
                        gnss_mask, u, 1)
    m_e = e_dz.shape[1]
    if m_e:
        _stack_extra(dz, H, R, gnss_mask, e_dz, e_H, e_R, e_mask, diverged, dz_s, H_s, R_s, row_mask)
    if not _measurement_keys_kernel(sat_keys, mask, with_rate, m_e, keys):
        return 2
    _prepare_serial(dz_s, H_s, R_s.reshape((B, R_s.shape[1], 1)), False, row_mask, dz_o, H_o, R_o, ok)
    if not ok[0]:
        return 3
    _averaged_serial(F_int, Qc_int, Phi, Q, order, nz, 1)
    if with_prior:
        _prior_serial(Phi, P, prior, 1)
    return 0


@nb.njit(cache=True)
def _stack_extra(dz, H, R, gnss_mask, e_dz, e_H, e_R, e_mask, diverged, dz_s, H_s, R_s, row_mask):
    """The GNSS rows ``dz``, ``H``, ``R`` (variances), ``gnss_mask`` (B, m_g) and the extra rows ``e_*`` (B, m_e)
    stacked into ``dz_s``, ``H_s``, ``R_s``, ``row_mask`` (B, m_g + m_e) as the general sequence stacks them
    (:func:`~nav_filters.constraints.stack_measurements`: each masked row ``dz = 0``, ``H = 0``, unit variance),
    and ``row_mask`` the rows its update uses (an extra row of a diverged batch row is not)."""
    B, mg = gnss_mask.shape
    me = e_mask.shape[1]
    n = H.shape[2]
    for b in range(B):
        for i in range(mg + me):
            g = i < mg
            keep = gnss_mask[b, i] if g else e_mask[b, i - mg]
            if keep:
                dz_s[b, i] = dz[b, i] if g else e_dz[b, i - mg]
                R_s[b, i] = R[b, i] if g else e_R[b, i - mg]
                for j in range(n):
                    H_s[b, i, j] = H[b, i, j] if g else e_H[b, i - mg, j]
            else:
                dz_s[b, i] = 0.0
                R_s[b, i] = 1.0
                for j in range(n):
                    H_s[b, i, j] = 0.0
            row_mask[b, i] = keep and not diverged[b]


@nb.njit(cache=True)
def _clear_where_any(mask, t):
    """``t[b] = 0`` on the rows b with any ``mask[b, :]`` (= ``t[mask.any(-1)] = 0``, without the temporaries)."""
    for b in range(mask.shape[0]):
        for i in range(mask.shape[1]):
            if mask[b, i]:
                t[b] = 0.0
                break


def _feedback_rows(r, v, C, bg, ba, clk, drift, dx, diverged, P, r2, v2, C2, bg2, ba2, clk2, drift2, code, nchunk):
    """Compiled closed-loop feedback (same operations, in the same order, as :meth:`Navigator._feedback_reference`).

    ``C2 = exp([phi x]) C`` (Rodrigues, :func:`earth.rotations.exp_so3`, Taylor series below 1e-4 rad),
    ``v2 = v + dv``, ``r2 = r + dr``, biases and clock plus their corrections (Groves sec 14.1, with the
    correction-to-add convention of :mod:`nav_filters.error_model`); rows flagged ``diverged`` are copied
    unchanged. ``code[b]``: 0, or :data:`REASON_STATE` where the new nominal state is not finite, or
    :data:`REASON_COVARIANCE` where a live row's covariance is not positive definite
    (:func:`_row_is_pd`).
    """
    B = r.shape[0]
    n = P.shape[1]
    for ch in nb.prange(nchunk):  # rows in chunks (parallel in the parallel variant), scratch per chunk
        L = np.empty((n, n))
        idx = np.empty(n, np.int64)
        S = np.empty((3, 3))
        E = np.empty((3, 3))
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            if diverged[b]:
                for i in range(3):
                    r2[b, i] = r[b, i]
                    v2[b, i] = v[b, i]
                    bg2[b, i] = bg[b, i]
                    ba2[b, i] = ba[b, i]
                    for j in range(3):
                        C2[b, i, j] = C[b, i, j]
                clk2[b] = clk[b]
                drift2[b] = drift[b]
            else:
                p0 = dx[b, _ATT0]
                p1 = dx[b, _ATT0 + 1]
                p2 = dx[b, _ATT0 + 2]
                th2 = p0 * p0 + p1 * p1 + p2 * p2
                th = np.sqrt(th2)
                if th < 1e-4:
                    a = 1.0 - th2 / 6.0 + th2 * th2 / 120.0
                    c = 0.5 - th2 / 24.0 + th2 * th2 / 720.0
                else:
                    a = np.sin(th) / th
                    c = (1.0 - np.cos(th)) / (th * th)
                S[0, 0] = 0.0
                S[0, 1] = -p2
                S[0, 2] = p1
                S[1, 0] = p2
                S[1, 1] = 0.0
                S[1, 2] = -p0
                S[2, 0] = -p1
                S[2, 1] = p0
                S[2, 2] = 0.0
                for i in range(3):
                    for j in range(3):
                        ss = S[i, 0] * S[0, j] + S[i, 1] * S[1, j] + S[i, 2] * S[2, j]
                        E[i, j] = ((1.0 if i == j else 0.0) + a * S[i, j]) + c * ss
                for i in range(3):
                    for j in range(3):
                        C2[b, i, j] = E[i, 0] * C[b, 0, j] + E[i, 1] * C[b, 1, j] + E[i, 2] * C[b, 2, j]
                    r2[b, i] = r[b, i] + dx[b, _POS0 + i]
                    v2[b, i] = v[b, i] + dx[b, _VEL0 + i]
                    bg2[b, i] = bg[b, i] + dx[b, _BG0 + i]
                    ba2[b, i] = ba[b, i] + dx[b, _BA0 + i]
                clk2[b] = clk[b] + dx[b, _CLK0]
                drift2[b] = drift[b] + dx[b, _DRIFT0]
            ok = True
            for i in range(3):
                ok = ok and np.isfinite(r2[b, i]) and np.isfinite(v2[b, i])
                for j in range(3):
                    ok = ok and np.isfinite(C2[b, i, j])
            if not ok:
                code[b] = REASON_STATE
            elif not diverged[b] and not _row_is_pd(P, b, L, idx):
                code[b] = REASON_COVARIANCE
            else:
                code[b] = 0


_feedback_serial, _feedback_parallel = serial_and_parallel(_feedback_rows)


@nb.njit(cache=True)
def _feedback_clear_dop(r, v, C, bg, ba, clk, drift, dx, diverged, P, r2, v2, C2, bg2, ba2, clk2, drift2, code, mask,
                        t, u, gdop):
    """The end of a GNSS epoch in one call (:meth:`Navigator._direct_gnss_epoch`): the feedback
    (:func:`_feedback_rows`, serially), ``t[b] = 0`` on the rows with a used channel (:func:`_clear_where_any`)
    and the GDOP of the used channels (:func:`~nav_filters.measurements._dop_kernel`) into ``gdop`` (B,).
    Returns the number of rows flagged (``code`` non-zero)."""
    _feedback_serial(r, v, C, bg, ba, clk, drift, dx, diverged, P, r2, v2, C2, bg2, ba2, clk2, drift2, code, 1)
    _clear_where_any(mask, t)
    _dop_kernel(u, mask, gdop)
    flagged = 0
    for b in range(code.shape[0]):
        flagged += code[b] != 0
    return flagged


@nb.njit(cache=True)
def _row_is_pd(P, b, L, idx):
    """Whether ``P[b]`` is a valid covariance: no NaN, a positive diagonal, and its block over the states of
    finite variance is finite and positive definite (Cholesky in float64 of the values held, lower triangle).
    ``+inf`` variances (an information form's unobserved directions) are left out. ``L`` (n, n) float64
    and ``idx`` (n,) int64 are scratch."""
    n = P.shape[1]
    m = 0
    for i in range(n):
        d = P[b, i, i]
        if np.isnan(d) or not d > 0:
            return False
        if d != np.inf:
            idx[m] = i
            m += 1
    for i in range(m):
        for j in range(i + 1):
            x = np.float64(P[b, idx[i], idx[j]])
            if not np.isfinite(x):
                return False
            L[i, j] = x
    return cholesky_inplace(L[:m, :m], 0.0)


def covariance_is_pd(P) -> np.ndarray:
    """(B,) bool: each ``P[b]`` (B, n, n) is a valid covariance (numpy specification of :func:`_row_is_pd`):
    no NaN, a positive diagonal, and ``np.linalg.cholesky`` (float64) succeeds on the block of the states of
    finite variance (``+inf``: an unobserved direction of an information form, left out)."""
    P = np.asarray(P, np.float64)
    out = np.zeros(P.shape[0], bool)
    for b in range(P.shape[0]):
        d = np.diagonal(P[b])
        if np.isnan(d).any() or not (d > 0).all():
            continue
        fin = np.isfinite(d)
        sub = P[b][np.ix_(fin, fin)]
        if not np.isfinite(sub).all():
            continue
        try:
            np.linalg.cholesky(sub)
        except np.linalg.LinAlgError:
            continue
        out[b] = True
    return out


__all__ = ["Navigator", "NavigatorConfig", "DIVERGENCE_REASONS", "covariance_is_pd", "ATT", "VEL", "POS"]
