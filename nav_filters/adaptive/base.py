"""Adaptive laws as filter forms that *compose* an inner filter form.

An adaptive law (Sage-Husa, strong tracking, MA-STKF) is itself a
:class:`~nav_filters.forms.base.FilterForm` that wraps an *inner* form (any
registered form: ``kf``, ``svd-kf``, ``svd-srkf``, ``if``, ``svd-if``,
``srif``) and talks to it only through the public interface: ``predict``,
``update``, ``covariance`` and ``take_correction``. The same law therefore
adapts every form (``svd-akf`` is Sage-Husa around ``svd-kf``), and no filter
recursion is copied. The laws read the inner covariance, so it must be finite
(an information form started from zero information has infinite variances
until its first updates; wrap it only with a finite ``P0``).

Deferred prediction
-------------------
The laws need the measurement of an epoch *before* the epoch's time update is
applied (the strong-tracking fading factor scales ``Phi P Phi^T`` by a factor
computed from the innovations; the Sage-Husa law replaces the epoch's process
noise by its adapted estimate). So :meth:`AdaptiveLaw.predict` does not touch
the inner form; it composes the transitions of the epoch exactly::

    Phi_acc <- Phi Phi_acc,     Q_acc <- Phi Q_acc Phi^T + Q,

(the composition of the per-call predictions, so with neutral adaptation the
wrapper reproduces the inner form to rounding) and propagates the wrapper's own
error state ``x <- Phi x`` at once. At the next :meth:`update` the law chooses
the epoch's fading factor ``lambda`` and process noise ``Q_k`` and hands the
inner form one prediction::

    inner.predict(sqrt(lambda) Phi_acc, Q_k)   # P <- lambda Phi P Phi^T + Q_k

which any form can apply through its own ``predict``.

Error state
-----------
The wrapper owns the error-state estimate ``x``; the inner form's ``x`` is kept
at zero (the innovation handed to it is ``dz - H x`` and its correction
``K (dz - H x)`` is taken back with ``take_correction`` after each update), so
scaling ``Phi`` by ``sqrt(lambda)`` never scales the state, and the change of
the inner state across an update is exactly the correction ``K dz`` that the
Sage-Husa estimator needs (seed 000 eq 18).

Per-row parameters
------------------
Each law declares its adaptive parameters (:class:`~.params.ParamSpec`); their
values are (B,) arrays, one per batch row, initialized from the law's config
and settable between steps with :meth:`AdaptiveLaw.set_params` (a scalar or a
(B,) array; validated). :meth:`AdaptiveLaw.params` returns them and
:meth:`AdaptiveLaw.adaptive_state` the current adaptive quantities (fading
factor, weights, noise scales) as (B,) arrays for observations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..forms.base import FilterForm, UpdateResult, check_keys, symmetrize
from ..forms.kf import KalmanFilter, transition_prior
from ..rows import check_row_pairs, copy_dataclass_rows
from .params import ParamSpec


def resolve_inner(inner):
    """The inner-form factory: a callable ``(P0, x0=None, dtype=None) -> FilterForm`` (a form class such as
    :class:`~nav_filters.forms.kf.KalmanFilter`, or a factory of :data:`nav_filters.registry.FORMS`).

    The laws know nothing of method names: the registry, which sits above them, resolves a name and hands the
    law its factory. Anything else raises ``ValueError`` naming ``inner``.
    """
    if isinstance(inner, type) and issubclass(inner, FilterForm):
        return inner
    if isinstance(inner, str) or not callable(inner):
        raise ValueError(f"inner must be a form class or a callable (P0, x0=None, dtype=None) -> FilterForm, "
                         f"got {inner!r} (a method name is resolved by nav_filters.registry.make_form)")
    return inner


@dataclass
class EpochContext:
    """What the pending time update of an epoch is, before it is applied to the inner form.

    Attributes
    ----------
    pending : whether a transition was accumulated since the last update (else Phi = I, Q = 0).
    Phi : (B, n, n) accumulated transition, or None.
    Q : (B, n, n) process noise the law will apply this epoch (nominal or adapted), or None.
    prior : (B, n, n) ``Phi P_(k-1) Phi^T`` with ``P_(k-1)`` the inner covariance after the last update.
    applied : whether the prediction has been handed to the inner form (an update that raised is
        retried without applying it twice).
    """

    pending: bool
    Phi: np.ndarray | None
    Q: np.ndarray | None
    prior: np.ndarray
    applied: bool = False


@dataclass
class UpdatePlan:
    """A law's decisions for one update (before the inner form is called).

    Attributes
    ----------
    fade : (B,) fading factor ``lambda >= 1`` applied to ``Phi P Phi^T`` (1 where not fading).
    R : (B, m, m) measurement covariance handed to the inner update.
    mask : (B, m) rows handed to the inner update (a law may drop a row's whole epoch).
    pending : law-specific values to commit once the inner update succeeded.
    """

    fade: np.ndarray
    R: np.ndarray
    mask: np.ndarray
    pending: dict = field(default_factory=dict)


class AdaptiveLaw(FilterForm):
    """Base of the adaptive laws: a :class:`FilterForm` around an inner form (see the module docstring).

    Parameters
    ----------
    P0 : (B, n, n) initial covariance.
    x0 : (B, n) initial error state (default zeros).
    dtype : float32 or float64 (default: P0's).
    inner : the inner form: a form class (default :class:`~nav_filters.forms.kf.KalmanFilter`) or a callable
        ``(P0, x0=None, dtype=None) -> FilterForm`` (:data:`nav_filters.registry.FORMS` holds one per method name).
    config : the law's frozen configuration dataclass (default: its defaults).

    Subclasses set :attr:`PARAMS` (the per-row parameters, initialized from the config fields of the
    same names), :attr:`config_class`, and implement :meth:`_plan` / :meth:`_commit` (and optionally
    :meth:`_epoch_q`, :meth:`_init_state`, :meth:`_state`).
    """

    name = "adaptive"
    PARAMS: tuple[ParamSpec, ...] = ()
    config_class: type = type(None)

    def __init__(self, P0, x0=None, dtype=None, *, inner=KalmanFilter, config=None):
        if config is None:
            config = self.config_class()
        if not isinstance(config, self.config_class):
            raise ValueError(f"config must be a {self.config_class.__name__}, got {type(config).__name__}")
        self.config = config
        self._inner_factory = resolve_inner(inner)
        super().__init__(P0, x0=x0, dtype=dtype)
        B = self.batch_size
        self._params = {p.name: p.check(getattr(config, p.name), B) for p in self.PARAMS}
        self._Phi_acc = None
        self._Q_acc = None
        self._ctx: EpochContext | None = None
        self._keys = None
        self._init_state()

    # ----------------------------------------------------------- inner form
    def _init_uncertainty(self, P0):
        self._p0_diag = np.diagonal(P0, axis1=1, axis2=2).astype(np.float64).copy()
        self.inner = self._inner_factory(P0, dtype=self.dtype)
        if not isinstance(self.inner, FilterForm):
            raise ValueError(f"inner must build a FilterForm, got {type(self.inner).__name__}")
        if self.inner.batch_size != P0.shape[0] or self.inner.n != P0.shape[1]:
            raise ValueError("inner form does not match P0's shape")

    def set_fused(self, on: bool = True) -> bool:
        """The fused fast path (:meth:`FilterForm.set_fused`): the law's own fast kernels (row kernels on
        parallel chunks, compiled replacements of numpy steps; same decisions to round-off) and, where the
        inner form has a fused path (``kf``), the epoch's deferred prediction and update as one compiled
        call (:meth:`FilterForm.predicted_update`, given the prior ``Phi P Phi^T`` the law already formed).
        Returns True when on (whatever the inner form)."""
        self.inner.set_fused(on)
        self.fused = bool(on)
        return self.fused

    @property
    def covariance(self) -> np.ndarray:
        """(B, n, n) current covariance: the inner form's, with a pending (unfaded) time update applied."""
        P = self.inner.covariance
        if self._Phi_acc is None:
            return P
        Phi = self._Phi_acc
        return symmetrize(Phi @ P @ Phi.mT + self._epoch_q(self._Q_acc))

    # ------------------------------------------------------------ time update
    def predict(self, Phi, Q):
        """Accumulate a time update (applied to the inner form at the next :meth:`update`).

        ``x <- Phi x`` at once; ``Phi_acc <- Phi Phi_acc``, ``Q_acc <- Phi Q_acc Phi^T + Q`` (exact
        composition of successive predictions; seed 000 eqs 5-6 applied per call).

        Parameters
        ----------
        Phi : (B, n, n) transition; Q : (B, n, n) process noise (anything broadcastable to it).
        """
        self._accumulate(Phi, Q, given=False)

    def take_prediction(self, Phi, Q):
        """:meth:`predict`, keeping ``Phi`` and ``Q`` themselves (no copy) where they are (B, n, n) arrays of the
        law's dtype: the caller hands them over (:meth:`FilterForm.take_prediction`)."""
        self._accumulate(Phi, Q, given=True)

    def _accumulate(self, Phi, Q, given):
        B, n = self.batch_size, self.n
        Phi = np.asarray(Phi, self.dtype)
        if Phi.shape != (B, n, n):
            raise ValueError(f"Phi must have shape ({B}, {n}, {n}), got {Phi.shape}")
        Q = np.asarray(Q, self.dtype)
        try:
            Q = Q if Q.shape == (B, n, n) else np.broadcast_to(Q, (B, n, n))
        except ValueError:
            raise ValueError(f"Q must broadcast to ({B}, {n}, {n}), got {Q.shape}") from None
        self._ctx = None
        if np.count_nonzero(self.x):  # (the error state is zero after each closed-loop feedback: Phi 0 = 0)
            self.x = (Phi @ self.x[..., None])[..., 0]
        if self._Phi_acc is None:
            self._Phi_acc = Phi if given else Phi.copy()
            self._Q_acc = Q if given and Q.flags.writeable else np.array(Q)  # (a broadcast view is read-only)
        else:
            self._Phi_acc = Phi @ self._Phi_acc
            self._Q_acc = Phi @ self._Q_acc @ Phi.mT + Q

    def _open_epoch(self) -> EpochContext:
        """Consume the accumulated transition into an :class:`EpochContext` (nothing applied yet)."""
        P = self.inner.covariance
        if self._Phi_acc is None:
            return EpochContext(pending=False, Phi=None, Q=None, prior=P)
        Phi, Q_acc = self._Phi_acc, self._Q_acc
        self._Phi_acc = self._Q_acc = None
        return EpochContext(pending=True, Phi=Phi, Q=self._epoch_q(Q_acc), prior=transition_prior(Phi, P))

    def _apply_prediction(self, ctx: EpochContext, fade):
        """``inner.predict(D Phi, Q)`` with ``D = diag(sqrt(fade))``: ``P <- D Phi P Phi^T D + Q``.

        ``fade`` (B,) is one fading factor per row (seed 003 eq 23: ``lambda Phi P Phi^T``), or (B, n)
        one per state (multiple fading factors; the congruence keeps P positive definite).
        """
        if ctx.pending and not ctx.applied:
            f = np.asarray(fade, np.float64)
            s = np.sqrt(f if f.ndim == 2 else f[:, None]).astype(self.dtype)
            if np.all(s == 1):
                self.inner.predict(ctx.Phi, ctx.Q)
            else:
                self.inner.predict(s[:, :, None] * ctx.Phi, ctx.Q)
        ctx.applied = True

    def capped_fading(self, lam, prior, cap):
        """Per-state fading factors ``lambda_i = min(lambda, max(1, cap P0_ii / (Phi P Phi^T)_ii))``.

        A safeguard (not in seed 003): a single fading factor inflates every state alike, also those
        the measurements barely observe (attitude, biases), which then grow without bound while the
        innovations stay large (NLOS); capping each state's faded variance at ``cap`` times its
        initial variance keeps the linearized error model valid.

        Parameters
        ----------
        lam : (B,) fading factors >= 1; prior : (B, n, n) ``Phi P Phi^T``; cap : float (> 0, inf: no cap).

        Returns
        -------
        (B,) ``lam`` itself when ``cap`` is inf, else (B, n).
        """
        lam = np.asarray(lam, np.float64)
        if math.isinf(cap):
            return lam
        d = np.diagonal(prior, axis1=1, axis2=2).astype(np.float64)
        room = np.where(d > 0, cap * self._p0_diag / np.where(d > 0, d, 1.0), np.inf)
        return np.minimum(lam[:, None], np.maximum(1.0, room))

    # ------------------------------------------------------ measurement update
    def update(self, dz, H, R, mask=None, keys=None) -> UpdateResult:
        """Measurement update (:meth:`FilterForm.update`); ``keys`` (B, m) are the measurement rows'
        identities (satellite and type, -1 none) that per-satellite laws key their estimates by; a law
        given none treats every row as having no identity."""
        self._keys = check_keys(keys, np.shape(dz))
        try:
            return super().update(dz, H, R, mask)
        finally:
            self._keys = None

    def _residual(self, dz, H):
        """``r = dz - H x`` (B, m) of the law's state; ``dz`` itself (a copy) where x is zero, as after every
        closed-loop feedback (no product to form)."""
        if not np.count_nonzero(self.x):
            return dz.copy()
        return dz - (H @ self.x[..., None])[..., 0]

    def _update(self, dz, H, R, mask) -> UpdateResult:
        start = self._compiled_epoch_start(dz, H) if self._has_compiled_epoch() else None
        if start is not None:
            return self._compiled_epoch(start[0], start[1], H, R, mask)
        r = self._residual(dz, H)
        if self._ctx is None:
            self._ctx = self._open_epoch()
        ctx = self._ctx
        plan = self._plan(r, H, R, mask, ctx)
        if isinstance(self.inner, AdaptiveLaw):
            # a law around a law (``sage-husa+fde``): the inner law defers the prediction to its own update and
            # keys its estimates by the measurement rows' identities
            self._apply_prediction(ctx, plan.fade)
            res = self.inner.update(r, H, plan.R, plan.mask, keys=self._keys)
        elif self.inner.fused:
            # one compiled call (commits nothing when it raises, so ctx.applied stays False for a retry)
            if ctx.pending and not ctx.applied:
                res = self.inner._predicted_update(ctx.Phi, ctx.Q, r, H, plan.R, plan.mask, fade=plan.fade,
                                                   prior=ctx.prior)
                ctx.applied = True
            else:
                res = self.inner._update(r, H, plan.R, plan.mask)
        else:
            self._apply_prediction(ctx, plan.fade)
            res = self.inner.update(r, H, plan.R, plan.mask)
        dx = self.inner.take_correction()
        self.x = self.x + dx
        self._ctx = None
        self._commit(plan, ctx, r, H, mask, dx)
        return res

    # --------------------------------------------------------- compiled epochs
    # A law may run a fused update (plan, inner update, commit) as one compiled call that calls the same kernels
    # as _update's Python sequence in the same order (the same bits): SageHusa, StrongTracking, MA-STKF. Such a
    # law says so in _has_compiled_epoch and runs it in _compiled_epoch.
    def _has_compiled_epoch(self) -> bool:
        """Whether this law's configuration has a compiled epoch (:meth:`_compiled_epoch`); none here."""
        return False

    def _compiled_epoch(self, r, ctx: EpochContext, H, R, mask) -> UpdateResult:
        """The fused update of a prepared measurement as one compiled call: ``r = dz - H x`` (B, m) of the law's
        state, ``ctx`` the opened epoch (pending, not applied), ``H`` (B, m, n), ``R`` (B, m, m), ``mask``
        (B, m); the measurement keys in ``self._keys``. Commits through :meth:`_compiled_epoch_end`."""
        raise NotImplementedError(f"{type(self).__name__} has no compiled epoch")

    def direct_epoch_ready(self) -> bool:
        """Whether :meth:`direct_epoch` can run the next update: a compiled epoch on the fused ``kf``, no
        transition accumulated or epoch opened yet, and the law's state zero (as after every closed-loop
        feedback)."""
        return (self.fused and self._Phi_acc is None and self._ctx is None and type(self.inner) is KalmanFilter
                and self._has_compiled_epoch() and not np.count_nonzero(self.x))

    def direct_epoch(self, Phi, Q, prior, dz, H, R, mask, keys) -> UpdateResult:
        """:meth:`take_prediction` ``(Phi, Q)`` then :meth:`update` ``(dz, H, R, mask, keys)``, for a caller that
        formed the epoch's inputs itself (the navigator's compiled GNSS epoch): the same compiled epoch on the
        same arrays, without the generic layers in between, where :meth:`direct_epoch_ready` holds.

        ``Phi``, ``Q`` (B, n, n) the epoch's transition and process noise, handed over; ``prior`` (B, n, n)
        ``transition_prior(Phi, inner P)``; ``dz``, ``H``, ``R`` (B, m, m), ``mask`` a measurement as
        :func:`~nav_filters.forms.base.prepare_measurement` returns it (checked, masked rows neutral), in the
        law's dtype; ``keys`` (B, m) int64 valid measurement keys. Where some row's ``S`` is not positive
        definite it raises ``LinAlgError`` having committed nothing, with the epoch left open as
        :meth:`update` leaves it (so that an ``update`` of the same measurement retries it)."""
        ctx = EpochContext(pending=True, Phi=Phi, Q=self._epoch_q(Q), prior=prior)
        self._keys = keys
        try:
            return self._compiled_epoch(dz, ctx, H, R, mask)
        except np.linalg.LinAlgError:
            self._ctx = ctx
            raise
        finally:
            self._keys = None

    def _compiled_epoch_start(self, dz, H):
        """``(r, ctx)`` for a compiled epoch: ``r = dz - H x`` of the law's state (as :meth:`_update` forms it)
        and the epoch context; None where :meth:`_update`'s sequence must run instead: no fused ``kf`` inside,
        no pending transition, or one already applied (a retried update)."""
        if not (self.fused and type(self.inner) is KalmanFilter):
            return None
        if self._ctx is None:
            self._ctx = self._open_epoch()
        ctx = self._ctx
        if not ctx.pending or ctx.applied:
            return None
        return self._residual(dz, H), ctx

    def _compiled_epoch_end(self, ok, P, x, nis, n_used, r, Sd) -> UpdateResult:
        """Commit a compiled epoch's update: the inner form's posterior ``P`` (its state reset to zero, the
        correction taken), the law's state ``x`` (B, n); or, where ``ok`` is False (some row's ``S`` not positive
        definite), raise ``LinAlgError`` as the fused update does, committing nothing (the context kept for the
        retry). Returns the :class:`UpdateResult` of the update (``r`` the innovations, ``Sd`` diag S)."""
        if not ok:
            raise np.linalg.LinAlgError("Matrix is not positive definite")
        self.inner.P, self.inner.x = P, np.zeros(x.shape, x.dtype)
        self.x, self._ctx = x, None
        return UpdateResult(nis=nis, n_used=n_used, innovation=r, innovation_var=Sd, applied=n_used > 0)

    def _compiled_epoch_scratch(self, key, make):
        """Arrays a compiled epoch uses within one call, kept from call to call while ``key`` (the shapes and
        dtype) is unchanged: ``make()`` builds them. Held in a tuple, which the row copies leave alone."""
        scratch = self.__dict__.get("_scratch")
        if scratch is None or scratch[0] != key:
            scratch = self._scratch = (key, make())
        return scratch[1]

    def _config_settings(self, make):
        """The settings a compiled epoch takes from the (frozen) config, ``make()`` of them, formed once per
        config object instead of at every epoch."""
        cached = self.__dict__.get("_settings")
        if cached is None or cached[0] is not self.config:
            cached = self._settings = (self.config, make())
        return cached[1]

    # ------------------------------------------------------------- row reset
    def replace_rows(self, rows, other: "AdaptiveLaw") -> None:
        """Overwrite batch rows ``rows`` with the rows of ``other`` (same law, ``len(rows)`` rows).

        The generic copy of :meth:`FilterForm.replace_rows` (per-row arrays, the inner form) plus what
        it cannot see: the per-row parameters, and a pending (deferred) transition present on only one
        side (a row without one gets ``Phi = I``, ``Q = 0``).
        """
        rows = np.asarray(rows, dtype=np.intp)
        super().replace_rows(rows, other)
        if self._Phi_acc is not None or other._Phi_acc is not None:
            if self._Phi_acc is None:
                self._Phi_acc = np.broadcast_to(np.eye(self.n, dtype=self.dtype), (self.batch_size, self.n, self.n)).copy()
                self._Q_acc = np.zeros((self.batch_size, self.n, self.n), self.dtype)
            if other._Phi_acc is None:
                self._Phi_acc[rows] = np.eye(self.n, dtype=self.dtype)
                self._Q_acc[rows] = 0
            else:
                self._Phi_acc[rows] = other._Phi_acc
                self._Q_acc[rows] = other._Q_acc
        for name, value in other._params.items():
            self._params[name][rows] = value

    _ROW_COPY_SKIP = frozenset({"_ctx"})

    def copy_rows(self, dst, src) -> None:
        """Copy the state of rows ``src`` to rows ``dst`` (exact branching inside the batch).

        The generic copy of :meth:`FilterForm.copy_rows` covers the inner form, the law's per-row arrays,
        the per-row parameters (``_params``, a dict of (B,) arrays) and any other dict of per-row arrays,
        and the deferred transition ``_Phi_acc`` / ``_Q_acc`` (None or (B, n, n) for every row alike). A
        pending epoch context (left by an update that failed for every row) is copied field by field;
        one with a field that is not a per-row array raises ``ValueError``. At step boundaries there is
        none.
        """
        dst, src = check_row_pairs(dst, src, self.batch_size)
        super().copy_rows(dst, src)
        if self._ctx is not None:
            self._ctx = copy_dataclass_rows(self._ctx, dst, src, self.batch_size,
                                            f"the pending epoch context of {type(self).__name__}")

    # --------------------------------------------------------------- params
    def params(self) -> dict:
        """The per-row adaptive parameters: ``{name: (B,) float64 array}`` (copies)."""
        return {k: v.copy() for k, v in self._params.items()}

    def set_params(self, **values):
        """Set adaptive parameters between steps, per batch row.

        Parameters
        ----------
        **values : ``name=value`` with a scalar (all rows) or a (B,) array; names from :attr:`PARAMS`.

        Raises
        ------
        ValueError
            unknown name, wrong shape, NaN or out-of-range value (names the parameter). Nothing is
            changed if any value is invalid.
        """
        checked = []
        for k, v in values.items():
            for spec in self.PARAMS:  # a scan of one to four specs: cheaper than a name -> spec dict per call
                if spec.name == k:
                    break
            else:
                known = sorted(p.name for p in self.PARAMS)
                raise ValueError(f"unknown adaptive parameter {k!r} for {type(self).__name__}; known: {known}")
            checked.append((k, spec.check(v, self.batch_size)))
        for k, v in checked:
            changed = v != self._params[k]
            self._params[k] = v
            self._on_param_change(k, changed)

    def adaptive_state(self) -> dict:
        """Current adaptive quantities for observations: ``{name: (B,) float64 array}`` (copies)."""
        return {k: np.array(v, np.float64) for k, v in self._state().items()}

    def satellite_summary(self) -> dict:
        """The per-satellite summary entries of :meth:`adaptive_state` alone (``sat_scale_max``,
        ``sat_scale_median``, ``sats_rose``, ``sats_used``: (B,) float64 copies; ``{}`` for a law without
        per-satellite R): what an env's observation reads every epoch, without forming the rest of the state."""
        return {k: np.array(v, np.float64) for k, v in self._satellite_state().items()}

    def satellite_health(self):
        """``(sats_rose, sat_scale_max)`` of :meth:`satellite_summary`, (B,) float64 copies, or None for a law
        without per-satellite R: the two entries an env's observation frame reads, without the dict."""
        return None

    def excluded(self):
        """(B,) int measurement rows the law excluded from its last update (fault exclusion, a zero robust
        weight), or None for a law that never excludes."""
        return None

    # -------------------------------------------------------------- hooks
    def _init_state(self):
        """Allocate the law's per-row state."""

    def _epoch_q(self, Q_acc) -> np.ndarray:
        """Process noise to apply this epoch given the accumulated nominal one (default: nominal). No side effects."""
        return Q_acc

    def _plan(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        """Decide fading, measurement covariance and rows for this update (no state change)."""
        return UpdatePlan(fade=np.ones(self.batch_size), R=R, mask=mask)

    def _commit(self, plan: UpdatePlan, ctx: EpochContext, r, H, mask, dx):
        """Commit the law's state after a successful inner update (``dx`` the correction ``K dz``)."""

    def _on_param_change(self, name: str, changed_rows: np.ndarray):
        """Called after ``set_params`` changed ``name`` on ``changed_rows`` (B,) bool."""

    def _state(self) -> dict:
        return {}

    def _satellite_state(self) -> dict:
        """The per-satellite summary (:class:`~.satellite_r.SatelliteNoise` overrides it)."""
        return {}
