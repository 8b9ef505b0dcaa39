"""Innovation-based fault detection and exclusion (``kf-fde``, and the ``+fde`` suffix of any method).

Each epoch, before the update of the form (or law) it wraps, the law screens the measurement rows against the
prediction (the prior ``P- = Phi P Phi^T + Q`` of the nominal time update and the reported variances ``R``):

1. **Gate** (per row): a pseudorange or rate row whose normalized innovation squared
   ``r_i^2 / (h_i P- h_i^T + R_ii)`` exceeds the chi-square (1 dof) quantile of ``p_gate`` is excluded, the
   largest first, while its measurement type keeps more rows than the unknowns it serves.
2. **Detection** (per epoch): the NIS ``r^T S^-1 r`` of the rows left is tested against the chi-square quantile
   with ``n_used`` degrees of freedom at the false-alarm probability ``p_fa`` (Teunissen 1990's local overall
   model test; Brown & Chin 1997's innovation-based receiver autonomous integrity monitoring).
3. **Identification and exclusion**: while the test fails and redundancy remains (a type's rows outnumber the
   unknowns they serve, :data:`~.robust_rows.UNKNOWNS_PER_GROUP`: position and clock, or velocity and drift),
   the row with the largest normalized deleted residual ``|w_i|`` (:mod:`.robust_rows`: Baarda's w-test
   statistic, the row predicted from the prior and every other row) is excluded, and the test repeated.

Constraint rows (odometer, NHC, ZUPT: neither CLK nor DRIFT in H) count in the test but are never excluded.
The wrapped form then updates with the rows kept (an excluded row is masked: the update equals the form's
without it). Exclusions per epoch are reported (:meth:`FaultExclusion.excluded`, ``adaptive_state()``).

Around an adaptive law (``sage-husa+fde``) the screen runs before the law's own plan, so the law adapts on the
rows kept (exclusion before adaptation); the law's parameters are set and read through the wrapper.

Compiled per row (:func:`_fde_rows`, serial / parallel over rows); :func:`fde_screen_reference` is the numpy
specification (agreement test in ``tests/nav_filters/test_robust.py``).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import numba as nb
import numpy as np
from scipy.stats import chi2

from ..kernels import row_kernel, serial_and_parallel
from .base import AdaptiveLaw, EpochContext, UpdatePlan
from .innovation import _rows_nonzeros
from .params import check_option
from .robust_rows import (UNKNOWNS_PER_GROUP, deleted_stat, fit_reference, fit_row, fit_work, groups_reference,
                          innovation_stat, load_prior, row_group)


@dataclass(frozen=True)
class FdeConfig:
    """Configuration of :class:`FaultExclusion`.

    Attributes
    ----------
    p_fa : false-alarm probability of the epoch's chi-square test, (0, 0.5] (default 1e-3).
    p_gate : probability that the per-row gate rejects a clean row, [0, 0.5] (default 1e-4: the gate at 3.9
        sigma; 0 disables the gate).
    min_rows : rows of a measurement type always kept, >= 1 (default 4, the unknowns a type serves).
    """

    p_fa: float = 1e-3
    p_gate: float = 1e-4
    min_rows: int = UNKNOWNS_PER_GROUP

    def __post_init__(self):
        o = type(self).__name__
        check_option(o, "p_fa", self.p_fa, low=0.0, high=0.5, low_closed=False)
        check_option(o, "p_gate", self.p_gate, low=0.0, high=0.5)
        if isinstance(self.min_rows, bool) or not isinstance(self.min_rows, (int, np.integer)) or self.min_rows < 1:
            raise ValueError(f"{o}.min_rows must be an int >= 1, got {self.min_rows!r}")


@functools.lru_cache(maxsize=64)
def chi_square_thresholds(p: float, m: int) -> np.ndarray:
    """(m + 1,) the chi-square quantiles ``chi2.isf(p, dof)`` for dof 0..m (inf at dof 0: nothing to test)."""
    out = np.full(m + 1, np.inf)
    out[1:] = chi2.isf(p, np.arange(1, m + 1))
    out.setflags(write=False)
    return out


def gate_threshold(p_gate: float) -> float:
    """The per-row gate on the normalized innovation squared: ``chi2.isf(p_gate, 1)`` (inf when 0)."""
    return float(chi2.isf(p_gate, 1)) if p_gate > 0 else np.inf


@nb.njit(cache=True)
def _fde_row(r, H, Rd, mask, Pm, work, var, g, chi, gate, min_rows, keep):
    """The screen of one batch row (module docstring): ``keep`` (m,) written; returns ``(excluded, alarm, nis)``.
    ``g`` (m,) and ``var`` (m,) are scratch; ``work``: :func:`~.robust_rows.fit_work`."""
    nzc, nzv, cnt, _, post, v, red = work
    m, n = H.shape
    count = np.zeros(3, np.int64)
    for i in range(m):
        keep[i] = mask[i]
        var[i] = np.float64(Rd[i])
        g[i] = row_group(H, i, n) if mask[i] else -1
        if mask[i]:
            count[g[i]] += 1
    _rows_nonzeros(H, mask, nzc, nzv, cnt)
    excluded = 0
    if gate < np.inf:
        u = np.full(m, -1.0)
        for i in range(m):
            if keep[i] and g[i] < 2:
                u[i] = innovation_stat(r, nzc, nzv, cnt, Pm, var, i)
        while True:
            best = -1
            top = gate
            for i in range(m):
                if u[i] > top and count[g[i]] > min_rows:
                    best, top = i, u[i]
            if best < 0:
                break
            keep[best] = False
            u[best] = -1.0
            count[g[best]] -= 1
            excluded += 1
    alarm = False
    nis = 0.0
    while True:
        nis = fit_row(r, nzc, nzv, cnt, Pm, var, keep, post, v, red)
        dof = 0
        for i in range(m):
            dof += keep[i]
        if nis <= chi[dof]:
            break
        alarm = True
        best = -1
        top = 0.0
        for i in range(m):
            if keep[i] and g[i] < 2 and count[g[i]] > min_rows and red[i] > 0:
                w = abs(deleted_stat(v, red, var, i))
                if w > top:
                    best, top = i, w
        if best < 0:
            break
        keep[best] = False
        count[g[best]] -= 1
        excluded += 1
    return excluded, alarm, nis


def _fde_rows(r, H, prior, Q, add_q, Rd, mask, chi, gate, min_rows, keep, n_excl, alarm, nis, nchunk):
    """:func:`_fde_row` over every batch row, in ``nchunk`` chunks (parallel in the parallel variant): ``keep``
    (B, m), ``n_excl`` (B,) int64, ``alarm`` (B,) bool (the first test failed), ``nis`` (B,) of the rows kept."""
    B, m, n = H.shape
    for c in nb.prange(nchunk):
        work = fit_work(m, n, H.dtype)
        Pm = work[3]
        var = np.empty(m)
        g = np.empty(m, np.int64)
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            load_prior(prior, Q, add_q, b, Pm)
            e, a, s = _fde_row(r[b], H[b], Rd[b], mask[b], Pm, work, var, g, chi, gate, min_rows, keep[b])
            n_excl[b] = e
            alarm[b] = a
            nis[b] = s


_fde_serial, _fde_parallel = serial_and_parallel(_fde_rows)


def fde_screen(r, H, P_minus, Rd, mask, config: FdeConfig, Q=None):
    """The screen of :class:`FaultExclusion` (module docstring), compiled.

    Parameters
    ----------
    r : (B, m) innovations; H : (B, m, n); P_minus : (B, n, n) the prior (``+ Q`` (B, n, n) when given);
    Rd : (B, m) reported variances; mask : (B, m) bool rows used; config : FdeConfig.

    Returns
    -------
    keep : (B, m) bool rows kept; n_excluded : (B,) int; alarm : (B,) bool, the epoch's first test failed;
    nis : (B,) the NIS of the rows kept.
    """
    c = np.ascontiguousarray
    B, m = np.shape(r)
    keep = np.zeros((B, m), bool)
    n_excl = np.zeros(B, np.int64)
    alarm = np.zeros(B, bool)
    nis = np.zeros(B)
    kern, nchunk = row_kernel(_fde_serial, _fde_parallel, B)
    P = c(P_minus)
    kern(c(r), c(H), P, P if Q is None else c(Q), Q is not None, c(Rd, np.float64), c(mask, bool),
         chi_square_thresholds(float(config.p_fa), m), gate_threshold(config.p_gate), int(config.min_rows), keep,
         n_excl, alarm, nis, nchunk)
    return keep, n_excl, alarm, nis


def fde_screen_reference(r, H, P_minus, Rd, mask, config: FdeConfig):
    """Numpy specification of :func:`fde_screen` (same returns), row by row."""
    B, m = np.shape(r)
    chi = chi_square_thresholds(float(config.p_fa), m)
    gate = gate_threshold(config.p_gate)
    keep = np.array(mask, bool)
    n_excl, alarm, nis_out = np.zeros(B, np.int64), np.zeros(B, bool), np.zeros(B)
    for b in range(B):
        Hb, P = np.asarray(H[b], np.float64), np.asarray(P_minus[b], np.float64)
        var = np.asarray(Rd[b], np.float64)
        g = np.where(keep[b], groups_reference(Hb), -1)
        count = np.array([np.sum(g == k) for k in range(3)])
        u = np.where(keep[b] & (g < 2), np.asarray(r[b], np.float64) ** 2 / (np.einsum("ij,jk,ik->i", Hb, P, Hb)
                                                                            + var), -1.0)
        while np.isfinite(gate):
            cand = np.flatnonzero((u > gate) & (g >= 0) & (count[np.maximum(g, 0)] > config.min_rows))
            if cand.size == 0:
                break
            i = cand[np.argmax(u[cand])]
            keep[b, i], u[i] = False, -1.0
            count[g[i]] -= 1
            n_excl[b] += 1
        while True:
            nis, v, red, w = fit_reference(r[b], Hb, P, var, keep[b])
            nis_out[b] = nis
            if nis <= chi[keep[b].sum()]:
                break
            alarm[b] = True
            cand = np.flatnonzero(keep[b] & (g < 2) & (g >= 0) & (count[np.maximum(g, 0)] > config.min_rows)
                                  & (red > 0))
            if cand.size == 0:
                break
            i = cand[np.argmax(np.abs(w[cand]))]
            keep[b, i] = False
            count[g[i]] -= 1
            n_excl[b] += 1
    return keep, n_excl, alarm, nis_out


class FaultExclusion(AdaptiveLaw):
    """Fault detection and exclusion around any form or adaptive law (module docstring; ``kf-fde``, ``+fde``).

    Parameters
    ----------
    P0, x0, dtype, inner, config : as :class:`~.base.AdaptiveLaw` (``config``: :class:`FdeConfig`; ``inner``: a
        form class or factory, plain or adaptive).

    The wrapped law's parameters are the wrapper's: :meth:`set_params`, :meth:`params`,
    :meth:`adaptive_state`, :meth:`satellite_health`, :meth:`set_satellite_params`, :meth:`satellite_params` and
    :meth:`satellite_scales` reach it.
    """

    name = "fde"
    config_class = FdeConfig

    def _init_state(self):
        B = self.batch_size
        self._excluded = np.zeros(B, np.int64)
        self._alarm = np.zeros(B, bool)

    def _plan(self, r, H, R, mask, ctx: EpochContext) -> UpdatePlan:
        Rd = np.diagonal(R, axis1=1, axis2=2)
        keep, n_excl, alarm, _ = fde_screen(r, H, ctx.prior, Rd, mask, self.config,
                                            Q=ctx.Q if ctx.pending else None)
        return UpdatePlan(fade=np.ones(self.batch_size), R=R, mask=keep,
                          pending=dict(excluded=n_excl, alarm=alarm))

    def _commit(self, plan: UpdatePlan, ctx: EpochContext, r, H, mask, dx):
        self._excluded = plan.pending["excluded"]
        self._alarm = plan.pending["alarm"]

    def excluded(self) -> np.ndarray:
        """(B,) int: measurement rows excluded at the last update (with those of a wrapped law)."""
        inner = self.inner.excluded() if isinstance(self.inner, AdaptiveLaw) else None
        return self._excluded.copy() if inner is None else self._excluded + inner

    # ------------------------------------------------- the wrapped law's parameters
    def _inner_law(self):
        return self.inner if isinstance(self.inner, AdaptiveLaw) else None

    def params(self) -> dict:
        law = self._inner_law()
        return {} if law is None else law.params()

    def set_params(self, **values):
        law = self._inner_law()
        if law is None:
            return super().set_params(**values)  # no parameters: the base names the culprit
        return law.set_params(**values)

    def adaptive_state(self) -> dict:
        law = self._inner_law()
        out = {} if law is None else law.adaptive_state()
        out.update(excluded=self._excluded.astype(np.float64), fde_alarm=self._alarm.astype(np.float64))
        return out

    def satellite_summary(self) -> dict:
        law = self._inner_law()
        return {} if law is None else law.satellite_summary()

    def satellite_health(self):
        law = self._inner_law()
        return None if law is None else law.satellite_health()

    def set_satellite_params(self, keys, b) -> None:
        """The wrapped law's per-satellite forgetting factors (:meth:`~.satellite_r.SatelliteNoise.
        set_satellite_params`); ``ValueError`` when it takes none."""
        law = self._inner_law()
        if law is None or not hasattr(law, "set_satellite_params"):
            raise ValueError(f"{type(self).__name__} around {type(self.inner).__name__} takes no per-satellite "
                             "forgetting factor")
        law.set_satellite_params(keys, b)

    def satellite_params(self, keys) -> dict:
        law = self._inner_law()
        if law is None or not hasattr(law, "satellite_params"):
            raise ValueError(f"{type(self).__name__} around {type(self.inner).__name__} takes no per-satellite "
                             "forgetting factor")
        return law.satellite_params(keys)

    def satellite_scales(self, keys):
        """The wrapped law's per-satellite R scales (``ValueError`` when it has none)."""
        law = self._inner_law()
        if law is None or not hasattr(law, "satellite_scales"):
            raise ValueError(f"{type(self).__name__} around {type(self.inner).__name__} has no per-satellite R")
        return law.satellite_scales(keys)


__all__ = ["FdeConfig", "FaultExclusion", "fde_screen", "fde_screen_reference", "chi_square_thresholds",
           "gate_threshold"]
