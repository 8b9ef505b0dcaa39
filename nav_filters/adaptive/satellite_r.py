"""Measurement noise per satellite and measurement type: the tables, the compiled law and its numpy
specification, shared by the laws that adapt R per satellite (:class:`~.sage_husa.SageHusa` in
``r_mode='satellite'``, :class:`~.strong_tracking.MeasurementAdaptiveSTKF` in ``r_mode='satellite'``).

The law (:func:`_r_sat_kernel`; the choices are documented in :mod:`nav_filters.adaptive.sage_husa`):
one variance scale ``s`` per measurement key (satellite and type), the recursion
``s <- (1 - d) s + d x`` with the satellite's own count in ``d = (1 - b) / (1 - b^(j+1))`` (seed 000
eqs 21-23; the same sequence as seed 003's asymptotic weights ``beta_k = beta_(k-1) / (beta_(k-1) + b)``
counted per satellite), aged towards the reported variance over short gaps and forgotten after long
ones, with the per-satellite sample ``x`` of ``r_sample``.

A law using :class:`SatelliteNoise` provides ``self.config`` with the fields ``r_sample``,
``min_redundancy``, ``prior_inflation``, ``sample_iterations``, ``common_scale``, ``median_guard``,
``sat_scale_min`` and ``forget_after_epochs`` (checked by :func:`check_satellite_options`), per-row group scales
``self._r_scale`` (B, 3) for rows without a key, and the hooks :meth:`SatelliteNoise._sat_b`,
:meth:`SatelliteNoise._sat_jcap`, :meth:`SatelliteNoise._sat_bounds` and
:meth:`SatelliteNoise._sat_enabled`.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..error_model import CLK, DRIFT, N_STATES
from ..kernels import padded_width, row_chunks, row_kernel, serial_and_parallel
from ..measurements import N_SAT_KEYS
from .base import EpochContext, UpdatePlan
from .innovation import (GROUP_NAMES, _geometry_residual_row, _geometry_work, _nonzeros_work, _posterior_residual_row,
                         _posterior_work, _quad_nz, _rows_nonzeros, measurement_groups, quadratic_diag)
from .params import check_option

_SAMPLE_CODE = {"geometry": 1, "residual": 2, "innovation": 0, "loo": 3, "consensus": 4}
"""Kernel code of each per-satellite variance sample."""
R_SAMPLES = tuple(_SAMPLE_CODE)
"""Per-satellite variance samples (``r_sample``)."""
ROSE_FACTOR = 2.0
"""A satellite's R scale 'rose' at an epoch when it grew by more than this factor (adaptive state)."""
SUMMARY_NAMES = ("sat_scale_max", "sat_scale_median", "sats_rose", "sats_used")
"""Adaptive-state entries summarizing the pseudorange scales of the last epoch (:meth:`SatelliteNoise._satellite_state`)."""

_MAX_COL, _ROSE_COL = SUMMARY_NAMES.index("sat_scale_max"), SUMMARY_NAMES.index("sats_rose")
_CLK0, _DRIFT0 = CLK.start, DRIFT.start
_NK = N_SAT_KEYS


def check_satellite_options(owner: str, cfg) -> None:
    """Check the per-satellite options of a law's config (``ValueError`` naming ``owner.field``)."""
    if cfg.r_sample not in R_SAMPLES:
        raise ValueError(f"{owner}.r_sample must be one of {R_SAMPLES}, got {cfg.r_sample!r}")
    check_option(owner, "min_redundancy", cfg.min_redundancy, low=0.0, high=1.0, high_closed=False)
    check_option(owner, "prior_inflation", cfg.prior_inflation, low=1.0)
    check_option(owner, "sat_scale_min", cfg.sat_scale_min, low=0.0, low_closed=False)
    it = cfg.sample_iterations
    if isinstance(it, bool) or not isinstance(it, (int, np.integer)) or it < 1:
        raise ValueError(f"{owner}.sample_iterations must be an int >= 1, got {it!r}")
    f = cfg.forget_after_epochs
    if isinstance(f, bool) or not isinstance(f, (int, np.integer)) or f < 1:
        raise ValueError(f"{owner}.forget_after_epochs must be an int >= 1, got {f!r}")
    for name in ("common_scale", "median_guard"):
        if not isinstance(getattr(cfg, name), (bool, np.bool_)):
            raise ValueError(f"{owner}.{name} must be a bool, got {getattr(cfg, name)!r}")


@nb.njit(cache=True)
def _set_key_b(keys, b, table):
    """``table[r, keys[r, i]] = b[r, i]`` for every ``keys[r, i] >= 0``, in row-major order (a key given twice
    in a row keeps its last value), if every key lies in ``-1 .. K - 1`` (K = ``table.shape[1]``) and every
    ``b`` of a key is NaN or in (0, 1]; else nothing is written. Returns whether it wrote (keys (B, n) int64, b
    (B, n) float64, table (B, K))."""
    B, n = keys.shape
    K = table.shape[1]
    for r in range(B):
        for i in range(n):
            k = keys[r, i]
            if k < -1 or k >= K:
                return False
            v = b[r, i]
            if k >= 0 and not (v != v or (v > 0.0 and v <= 1.0)):
                return False
    for r in range(B):
        for i in range(n):
            if keys[r, i] >= 0:
                table[r, keys[r, i]] = b[r, i]
    return True


@nb.njit(cache=True)
def _key_scales(keys, scale, last):
    """(B, k) ``scale[r, keys[r, i]]`` where the key is >= 0 and was used (``last >= 0``), else 1 (keys (B, k)
    int64 below K, checked by the caller; scale (B, K) float64; last (B, K) int64)."""
    out = np.ones(keys.shape)
    for r in range(keys.shape[0]):
        for i in range(keys.shape[1]):
            k = keys[r, i]
            if k >= 0 and last[r, k] >= 0:
                out[r, i] = scale[r, k]
    return out


@nb.njit(cache=True)
def _group_step(num, den, cnt, active, d, scale, smin, smax, out):
    """One group-scale recursion of one batch row: ``out_g = clip((1 - d) scale_g + d num_g / den_g)`` on the
    groups with rows when the row adapts, else ``scale_g``."""
    for g in range(out.shape[0]):
        if cnt[g] > 0 and active:
            sg = (1.0 - d) * scale[g] + d * (num[g] / den[g])
            out[g] = min(max(sg, smin), smax)
        else:
            out[g] = scale[g]


@nb.njit(cache=True)
def _row_group(H, b, i, n):
    """Measurement group of row i (0 pseudorange: CLK column, 1 rate: DRIFT column, 2 other)."""
    if n == N_STATES:
        if H[b, i, _CLK0] != 0:
            return 0
        if H[b, i, _DRIFT0] != 0:
            return 1
    return 2


@nb.njit(cache=True, inline="always")
def _sat_priors_row(b, r, H, R, mask, keys, bf, b_key, epoch, s_tab, n_tab, last_tab, forget, sample, nzc, nzv, cnt,
                    Pm3, s_rows, n_rows, s_prev, work):
    """Step 1 of :func:`_r_sat_kernel` on row ``b``: per used row i its group ``gi``, the innovation excess
    ``ex = r_i^2 - (H P- H^T)_ii``, and for a keyed row its key's forgetting factor ``bks``, prior scale ``s0``
    (aged, or 1 when reacquired) into ``s_prev[b]``, count ``n0s`` and variance ``var = s0 R_ii`` (with the
    innovation sample, ``xs``); the outputs of the unused rows set to their neutral values. ``work = (xs, bks, ex,
    has_x, var, gi, n0s)`` (m,) each; ``Pm3`` (1, n, >= n) holds P-."""
    xs, bks, ex, has_x, var, gi, n0s = work
    m, n = H.shape[1], H.shape[2]
    for i in range(m):
        s_rows[b, i] = 1.0
        n_rows[b, i] = 0
        s_prev[b, i] = 1.0
        has_x[i] = False
        var[i] = 1.0
        gi[i] = -1
        if not mask[b, i]:
            continue
        gi[i] = _row_group(H, b, i, n)
        q = _quad_nz(nzc, nzv, cnt, i, Pm3, Pm3, False, 0)
        rr = np.float64(r[b, i])
        ex[i] = rr * rr - q
        key = keys[b, i]
        if key >= 0:
            bk = b_key[b, key]
            if bk != bk:  # NaN: the row's b
                bk = bf[b]
            bks[i] = bk
            last = last_tab[b, key]
            u = epoch[b] - last
            if last < 0 or u > forget:
                s0 = 1.0
                n0 = 0
            else:
                s0 = s_tab[b, key]
                n0 = n_tab[b, key]
                if u > 1:
                    s0 = 1.0 + (s0 - 1.0) * bk ** (u - 1)
            s_prev[b, i] = s0
            n0s[i] = n0
            var[i] = s0 * np.float64(R[b, i, i])
            if sample == 0:
                xs[i] = ex[i] / np.float64(R[b, i, i])
                has_x[i] = True


@nb.njit(cache=True, inline="always")
def _sat_scales_row(b, r, H, R, mask, keys, active, jcap, n_iter, sample, min_red, k_prior, guard, sat_min, smax, nzc,
                    nzv, cnt, Pm, s_rows, n_rows, s_prev, work, geo_work, post_work):
    """Step 2 of :func:`_r_sat_kernel` on row ``b``: ``n_iter`` rounds of the samples (geometry, residual,
    loo, consensus; a later round refits with each row weighted by the larger of its tentative scale and its
    sample) and the recursion of each keyed row's scale and count into ``s_rows[b]``, ``n_rows[b]``.
    ``work = (xs, bks, has_x, var, n0s, use, v, red, xl, hl, srt)`` (m,) each, as step 1 left them; ``Pm``
    (n, >= n) holds P-."""
    xs, bks, has_x, var, n0s, use, v, red, xl, hl, srt = work
    m = mask.shape[1]
    j_last = -1  # the last count and b whose weight was computed for this row (most satellites share them)
    b_last = np.nan
    d_last = 0.0
    for it in range(n_iter):
        if it > 0 and sample > 0:  # refit with each row weighted by max(tentative scale, its sample)
            for i in range(m):
                if mask[b, i] and keys[b, i] >= 0:
                    w = max(s_rows[b, i], xs[i]) if has_x[i] else s_rows[b, i]
                    var[i] = w * np.float64(R[b, i, i])
                    has_x[i] = False
        if sample == 1 or sample == 4:
            for t in range(2):
                for i in range(m):
                    k = keys[b, i]
                    use[i] = mask[b, i] and k >= 0 and ((k >= _NK) == (t == 1))
                _geometry_residual_row(r[b], H[b], nzc, cnt, var, use, v, red, geo_work)
                for i in range(m):
                    if use[i] and red[i] >= min_red:
                        xs[i] = v[i] * v[i] / (red[i] * np.float64(R[b, i, i]))
                        has_x[i] = True
        if sample >= 2:
            for i in range(m):
                use[i] = mask[b, i] and keys[b, i] >= 0
            _posterior_residual_row(r[b], nzc, nzv, cnt, Pm, Pm, False, k_prior, var, use, v, red, post_work)
            for i in range(m):
                hl[i] = use[i] and red[i] >= min_red
                if hl[i] and sample != 2:  # deleted residual e = v / red, its prediction's variance var/red - var
                    e = v[i] / red[i]
                    xl[i] = (e * e - (var[i] / red[i] - var[i])) / np.float64(R[b, i, i])
            if guard and sample != 2:
                _median_guard(xl, hl, keys[b], srt)
            for i in range(m):
                if hl[i]:
                    if sample == 2:
                        xs[i] = v[i] * v[i] / (red[i] * np.float64(R[b, i, i]))
                    else:
                        xs[i] = min(xs[i], xl[i]) if (sample == 4 and has_x[i]) else xl[i]
                    has_x[i] = True
        for i in range(m):
            if not mask[b, i] or keys[b, i] < 0:
                continue
            s0 = s_prev[b, i]
            n0 = n0s[i]
            if active[b] and has_x[i]:
                j = min(n0 + 1, jcap[b])
                if j != j_last or bks[i] != b_last:
                    d_last = _weight_one(bks[i], j)
                    j_last = j
                    b_last = bks[i]
                d = d_last
                s1 = (1.0 - d) * s0 + d * xs[i]
                s_rows[b, i] = min(max(s1, sat_min), smax)
                n_rows[b, i] = n0 + 1
            else:
                s_rows[b, i] = s0
                n_rows[b, i] = n0


@nb.njit(cache=True, inline="always")
def _sat_group_row(b, R, mask, keys, gi, ex, s_rows, common, active, d_row, r_scale, smin, smax, s_group, work,
                   R_out):
    """Step 3 of :func:`_r_sat_kernel` on row ``b``: the group scales (over the rows without a key, or with
    ``common`` over every row) into ``s_group[b]`` and ``R_out[b] = D^(1/2) R D^(1/2)``. ``work = (num, den,
    cnt_g, sq)``: (G,), (G,), (G,) int and (m,) scratch."""
    num, den, cnt_g, sq = work
    m = mask.shape[1]
    for g in range(num.shape[0]):
        num[g] = 0.0
        den[g] = 0.0
        cnt_g[g] = 0
    for i in range(m):
        if gi[i] < 0 or (keys[b, i] >= 0 and not common):
            continue
        num[gi[i]] += ex[i]
        den[gi[i]] += s_rows[b, i] * np.float64(R[b, i, i])
        cnt_g[gi[i]] += 1
    _group_step(num, den, cnt_g, active[b], d_row[b], r_scale[b], smin, smax, s_group[b])
    for i in range(m):
        if not mask[b, i]:
            sq[i] = 1.0
        elif keys[b, i] >= 0:
            sq[i] = np.sqrt(s_rows[b, i] * (s_group[b, gi[i]] if common else 1.0))
        else:
            sq[i] = np.sqrt(s_group[b, gi[i]])
    for i in range(m):
        for j in range(m):
            R_out[b, i, j] = R[b, i, j] * sq[i] * sq[j]


@nb.njit(cache=True)
def _r_sat_kernel(r, H, prior, Q, add_q, R, mask, keys, bf, b_key, jcap, d_row, active, epoch, s_tab, n_tab,
                  last_tab, forget, smin, smax, sat_min, sample, min_red, k_prior, n_iter, common, guard, r_scale,
                  s_rows, n_rows, s_prev, s_group, R_out):
    """The Sage-Husa measurement-noise law per satellite and measurement type (``r_mode='satellite'``).

    Per batch row b and used measurement row i with key k = keys[b, i] >= 0 (numpy specification:
    :meth:`SageHusa._r_sat_reference`)::

        bk = b_key[b, k], or bf[b] where b_key[b, k] is NaN (the key's own forgetting factor, default the row's)
        u  = epoch[b] - last_tab[b, k]                    (epochs since the satellite was last used)
        s0 = 1, n0 = 0                                    if never seen or u > forget (reacquired)
        s0 = 1 + (s_tab[b, k] - 1) bk^(u - 1), n0 = n_tab  otherwise (aged over the u - 1 missed epochs)
        x  = v_i^2 / (red_i R_ii)                          geometry (sample 1): snapshot LS residual of the
                                                          type (variances s0 R_ii), if red_i >= min_red;
                                                          residual (sample 2): post-fit residual against
                                                          the prior inflated k_prior times
        x  = (e_i^2 - c_i) / R_ii                         loo (sample 3): deleted residual e_i = v_i / red_i
                                                          of the posterior fit, c_i = var_i / red_i - var_i;
                                                          with ``guard`` divided by max(1, its median over the
                                                          epoch's rows of the type, :func:`_median_guard`)
        x  = min(geometry x, loo x)                       consensus (sample 4; either alone where the other
                                                          has no sample)
        x  = (dz_i^2 - (H P- H^T)_ii) / R_ii              innovation form (sample 0)
        d  = (1 - bk) / (1 - bk^(min(n0 + 1, jcap) + 1))  (seed 000 eqs 21-23, the satellite's own count)
        s1 = clip((1 - d) s0 + d x, smin, smax), n1 = n0 + 1   on active rows with a sample (else s0, n0)

    Group scales (``d_row``, the row's own count): over the rows without a key, or with ``common`` over every
    row with its per-satellite scale in the base variance (the common factor of a whole measurement type,
    e.g. all signals attenuated under trees; the classic innovation law)::

        g <- clip((1 - d_row) g + d_row sum(dz_i^2 - (H P- H^T)_ii) / sum(s_i R_ii), smin, smax)

    The row's variance is ``g s_i R_ii`` (``s_i = 1`` without a key; ``g = 1`` for keyed rows without
    ``common``). Outputs: ``s_rows``/``n_rows``/``s_prev`` (B, m) the new and the prior scale and the count of
    each keyed row (1/0/1 elsewhere), ``s_group`` (B, G) and ``R_out = D^(1/2) R D^(1/2)``.
    """
    B, m, n = H.shape
    G = s_group.shape[1]
    xs = np.empty(m)
    bks = np.empty(m)
    ex = np.empty(m)
    has_x = np.zeros(m, np.bool_)
    var = np.empty(m)
    use = np.zeros(m, np.bool_)
    v = np.zeros(m)
    red = np.zeros(m)
    n0s = np.zeros(m, np.int64)
    gi = np.full(m, -1, np.int64)
    xl = np.zeros(m)  # the loo samples of a row, and which rows have one
    hl = np.zeros(m, np.bool_)
    srt = np.empty(m)
    group_work = (np.empty(G), np.empty(G), np.empty(G, np.int64), np.empty(m, R.dtype))
    # scratch of the row helpers, allocated once per call (not per batch row)
    nzc, nzv, cnt = _nonzeros_work(m, n, H.dtype)
    geo_work = _geometry_work(n)
    # the row's P- = prior (+ Q), formed once for both helpers (the sums they formed entry by entry, the same bits),
    # its rows padded with zeros (kernels.padded_width: the posterior fit's row operations vectorize)
    wp = padded_width(n)
    Pm3 = np.zeros((1, n, wp), prior.dtype)
    Pm = Pm3[0]
    post_work = _posterior_work(m, wp)
    for b in range(B):
        _rows_nonzeros(H[b], mask[b], nzc, nzv, cnt)
        for i in range(n):
            for j in range(n):
                Pm[i, j] = prior[b, i, j] + Q[b, i, j] if add_q else prior[b, i, j]
        _sat_priors_row(b, r, H, R, mask, keys, bf, b_key, epoch, s_tab, n_tab, last_tab, forget, sample, nzc, nzv,
                        cnt, Pm3, s_rows, n_rows, s_prev, (xs, bks, ex, has_x, var, gi, n0s))
        _sat_scales_row(b, r, H, R, mask, keys, active, jcap, n_iter, sample, min_red, k_prior, guard, sat_min, smax,
                        nzc, nzv, cnt, Pm, s_rows, n_rows, s_prev, (xs, bks, has_x, var, n0s, use, v, red, xl, hl, srt),
                        geo_work, post_work)
        _sat_group_row(b, R, mask, keys, gi, ex, s_rows, common, active, d_row, r_scale, smin, smax, s_group,
                       group_work, R_out)


@nb.njit(cache=True)
def _median_guard(x, has, keys, srt):
    """The epoch guard of the deleted-residual samples (``median_guard``): per measurement type (pseudoranges: keys
    below :data:`~nav_filters.measurements.N_SAT_KEYS`, rates: the others), the samples ``x`` (m,) of the rows
    flagged in ``has`` (used, keyed, with a sample) divided by ``max(1, c)``, ``c`` their median (``np.median``'s:
    the middle value, or the mean of the two). ``srt`` (m,) scratch."""
    m = x.shape[0]
    for t in range(2):
        k = 0
        for i in range(m):
            if has[i] and ((keys[i] >= _NK) == (t == 1)):
                srt[k] = x[i]
                k += 1
        if k == 0:
            continue
        v = srt[:k]
        v.sort()
        c = v[k // 2] if k % 2 == 1 else (v[k // 2 - 1] + v[k // 2]) / 2.0
        if c > 1.0:
            for i in range(m):
                if has[i] and ((keys[i] >= _NK) == (t == 1)):
                    x[i] = x[i] / c


@nb.njit(cache=True, parallel=True)
def _r_sat_parallel(nchunk, r, H, prior, Q, add_q, R, mask, keys, bf, b_key, jcap, d_row, active, epoch, s_tab,
                    n_tab, last_tab, forget, smin, smax, sat_min, sample, min_red, k_prior, n_iter, common, guard,
                    r_scale,
                    s_rows, n_rows, s_prev, s_group, R_out):
    """:func:`_r_sat_kernel` on ``nchunk`` chunks of rows in parallel (the fused fast path): each chunk runs the
    serial kernel itself on its slice of every per-row array, so every row gets the same bits."""
    B = r.shape[0]
    for c in nb.prange(nchunk):
        lo = c * B // nchunk
        hi = (c + 1) * B // nchunk
        _r_sat_kernel(r[lo:hi], H[lo:hi], prior[lo:hi], Q[lo:hi], add_q, R[lo:hi], mask[lo:hi], keys[lo:hi],
                      bf[lo:hi], b_key[lo:hi], jcap[lo:hi], d_row[lo:hi], active[lo:hi], epoch[lo:hi], s_tab[lo:hi],
                      n_tab[lo:hi], last_tab[lo:hi], forget, smin, smax, sat_min, sample, min_red, k_prior, n_iter, common,
                      guard,
                      r_scale[lo:hi], s_rows[lo:hi], n_rows[lo:hi], s_prev[lo:hi], s_group[lo:hi], R_out[lo:hi])


def _commit_rows(mask, keys, s_rows, n_rows, s_prev, epoch, n_pr_keys, rose_factor, sat_scale, sat_count, sat_last,
                 out, nchunk):
    """The fused path of :meth:`SatelliteNoise._commit_satellites` in one call: every used row ``(b, i)``
    (``mask`` and a key >= 0) writes its new scale, count and the epoch into the per-key tables at
    ``keys[b, i]`` (in row order, as numpy's fancy assignment), then the summary of the used pseudorange rows
    (keys below ``n_pr_keys``) into ``out`` (B, 4): ``(max scale, median scale, count risen above rose_factor x
    its prior, count)``, 1, 1, 0, 0 for a batch row without any; the median is ``np.nanmedian``'s (middle value,
    or the mean of the two). Batch rows in ``nchunk`` chunks (parallel in the parallel variant)."""
    B, m = mask.shape
    for ch in nb.prange(nchunk):
        vals = np.empty(m)
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            k = 0
            rose = 0
            mx = -np.inf
            for i in range(m):
                key = keys[b, i]
                if mask[b, i] and key >= 0:
                    v = s_rows[b, i]
                    sat_scale[b, key] = v
                    sat_count[b, key] = n_rows[b, i]
                    sat_last[b, key] = epoch[b]
                    if key < n_pr_keys:
                        vals[k] = v
                        k += 1
                        mx = max(mx, v)
                        if v > rose_factor * s_prev[b, i]:
                            rose += 1
            if k == 0:
                out[b, 0] = 1.0
                out[b, 1] = 1.0
            else:
                srt = vals[:k]
                srt.sort()  # in place (np.sort's order)
                out[b, 0] = mx
                out[b, 1] = srt[k // 2] if k % 2 == 1 else (srt[k // 2 - 1] + srt[k // 2]) / 2.0
            out[b, 2] = rose
            out[b, 3] = k


_commit_serial, _commit_parallel = serial_and_parallel(_commit_rows)


@nb.njit(cache=True)
def _weight_one(b, j):
    """Scalar :func:`sage_husa_weight` (seed 000 eqs 21-23)."""
    if b >= 1.0:
        return 1.0 / (j + 1.0)
    return (1.0 - b) / (1.0 - b ** (j + 1.0))


def sage_husa_weight(b, j):
    """Sage-Husa weight ``d = (1 - b) / (1 - b^(j+1))`` of the j-th adaptation (seed 000 eqs 21-23).

    Parameters
    ----------
    b : (B,) forgetting factors in (0, 1]; j : (B,) adaptation counts (>= 1).

    Returns
    -------
    (B,) float64 weights in (0, 1]; ``1/(j+1)`` where ``b == 1`` (the limit); ``-> 1 - b`` as j grows.
    """
    b = np.asarray(b, np.float64)
    j = np.asarray(j, np.float64)
    one = b >= 1.0
    bb = np.where(one, 0.5, b)
    d = (1.0 - bb) / (1.0 - bb ** (j + 1.0))
    return np.where(one, 1.0 / (j + 1.0), d)


def _median_guard_reference(x, has, keys):
    """Numpy specification of :func:`_median_guard`: ``x`` (B, m) divided, per batch row and measurement type, by
    ``max(1, median)`` of the entries flagged in ``has`` (B, m)."""
    x = np.array(x, np.float64)
    for t in range(2):
        sel = has & ((keys >= N_SAT_KEYS) == (t == 1))
        for b in np.flatnonzero(sel.any(1)):
            c = np.median(x[b, sel[b]])
            if c > 1.0:
                x[b, sel[b]] /= c
    return x


class SatelliteNoise:
    """Mixin of an :class:`~.base.AdaptiveLaw`: measurement noise per satellite and measurement type
    (module docstring). The law calls :meth:`_init_satellite_tables` from its ``_init_state``,
    :meth:`_plan_satellite` from its ``_plan`` and :meth:`_commit_satellites` from its ``_commit``.

    A law whose R recursion is :func:`_r_sat_kernel` (``SATELLITE_PARAMS = ('b',)``: :class:`~.sage_husa.SageHusa`)
    also takes a forgetting factor per measurement key (:meth:`set_satellite_params`), NaN by default: the
    row's ``b`` (so a law never given one computes as before, bit for bit).
    """

    SATELLITE_PARAMS: tuple = ()
    """Names of the per-key parameters :meth:`set_satellite_params` takes (none unless the law declares them)."""

    def _sat_enabled(self) -> bool:
        """Whether the law adapts R per satellite (tables allocated)."""
        return self.config.r_mode == "satellite"

    def _sat_b(self) -> np.ndarray:
        """(B,) forgetting factor b of every satellite's recursion."""
        return self._params["b"]

    def _sat_jcap(self) -> np.ndarray:
        """(B,) count at which each row's ``d`` freezes (no freezing: beyond any count)."""
        return np.full(self.batch_size, 1 << 62, np.int64)

    def _sat_bounds(self) -> tuple:
        """(low, high) bounds of the scales (the per-satellite floor is ``config.sat_scale_min``)."""
        return self.config.r_scale_min, self.config.r_scale_max

    def _sat_settings(self) -> tuple:
        """The R law's settings in the order :func:`_r_sat_kernel` takes them (``forget`` ... ``guard``)."""
        cfg = self.config
        smin, smax = self._sat_bounds()
        return (int(cfg.forget_after_epochs), float(smin), float(smax), float(cfg.sat_scale_min),
                _SAMPLE_CODE[cfg.r_sample], float(cfg.min_redundancy), float(cfg.prior_inflation),
                int(cfg.sample_iterations), bool(cfg.common_scale), bool(cfg.median_guard))

    def _init_satellite_tables(self):
        """Per (satellite key, type) scale, adaptation count and last epoch used (-1 never); the epoch
        counter; the summary of the last epoch (:data:`SUMMARY_NAMES`)."""
        B = self.batch_size
        K = 2 * N_SAT_KEYS if self._sat_enabled() else 0
        self._epoch = np.zeros(B, np.int64)
        self._sat_scale = np.ones((B, K))
        self._sat_count = np.zeros((B, K), np.int64)
        self._sat_last = np.full((B, K), -1, np.int64)
        self._sat_summary = np.zeros((B, 4))
        self._sat_b_key = np.full((B, K), np.nan)  # per-key forgetting factor, NaN: the row's b

    def set_satellite_params(self, keys, b) -> None:
        """Set the forgetting factor of individual satellites' recursions (per measurement key), per batch row.

        Parameters
        ----------
        keys : (B, n) int measurement keys (:func:`~nav_filters.measurements.measurement_keys`: a satellite's
            pseudorange key ``s``, its rate key ``N_SAT_KEYS + s``); -1 entries are skipped.
        b : (B, n) forgetting factors in (0, 1] for those keys, or NaN (the key follows the row's ``b`` again,
            the default). A key keeps its value until set again (or its row is reset).

        Raises
        ------
        ValueError
            the law takes no per-satellite parameter or does not adapt R per satellite, shapes that differ from
            (B, n), a key outside ``-1 .. 2 N_SAT_KEYS - 1``, or a ``b`` outside (0, 1] that is not NaN. Nothing
            is changed then.
        """
        name = type(self).__name__
        if "b" not in self.SATELLITE_PARAMS or not self._sat_enabled():
            raise ValueError(f"{name} takes no per-satellite forgetting factor (a Sage-Husa law with "
                             "r_mode='satellite' and adapt_r does)")
        if not getattr(self.config, "adapt_r", True):
            raise ValueError(f"{name} does not adapt R (adapt_r=False): a per-satellite b would change nothing")
        keys = np.asarray(keys)
        b = np.asarray(b, np.float64)
        B = self.batch_size
        if keys.ndim != 2 or keys.shape[0] != B or b.shape != keys.shape:
            raise ValueError(f"set_satellite_params: keys and b must have the same shape (B={B}, n), got "
                             f"{keys.shape} and {b.shape}")
        if keys.dtype.kind not in "iu":
            raise ValueError(f"set_satellite_params: keys must be integers, got dtype {keys.dtype}")
        K = self._sat_b_key.shape[1]
        wraps = keys.dtype.kind == "u" and keys.size and keys.max() >= K  # as int64 it could read as -1 (none)
        if not wraps and _set_key_b(np.ascontiguousarray(keys, np.int64), np.ascontiguousarray(b), self._sat_b_key):
            return
        # nothing was changed: name the culprit
        if keys.size and (keys.min() < -1 or keys.max() >= K):
            raise ValueError(f"set_satellite_params: keys must lie in -1..{K - 1}, got {keys.min()}..{keys.max()}")
        bad = (keys >= 0) & ~np.isnan(b) & ~((b > 0.0) & (b <= 1.0))
        raise ValueError(f"set_satellite_params: b must lie in (0, 1] (or be NaN: the row's b), got "
                         f"{b[bad][0]!r} at {np.argwhere(bad)[0].tolist()}")

    def satellite_params(self, keys) -> dict:
        """``{'b': (B, n)}``: the forgetting factor each measurement key of ``keys`` (B, n) uses (the row's ``b``
        where none was set; NaN for -1 keys)."""
        if "b" not in self.SATELLITE_PARAMS or not self._sat_enabled():
            raise ValueError(f"{type(self).__name__} takes no per-satellite forgetting factor")
        keys = np.asarray(keys, np.int64)
        own = np.take_along_axis(self._sat_b_key, np.maximum(keys, 0), 1)
        b = np.where(np.isnan(own), self._sat_b()[:, None], own)
        return {"b": np.where(keys >= 0, b, np.nan)}

    def _satellite_state(self) -> dict:
        """The summary entries of ``adaptive_state`` (empty when the law does not adapt per satellite)."""
        if not self._sat_enabled():
            return {}
        return {name: self._sat_summary[:, i] for i, name in enumerate(SUMMARY_NAMES)}

    def satellite_health(self):
        """:meth:`~.base.AdaptiveLaw.satellite_health` from the summary table (None when the law does not adapt
        per satellite)."""
        if not self._sat_enabled():
            return None
        s = self._sat_summary
        return s[:, _ROSE_COL].copy(), s[:, _MAX_COL].copy()

    def _plan_satellite(self, r, H, R, mask, ctx: EpochContext, d, active, pending) -> UpdatePlan:
        """The R law of ``r_mode='satellite'`` (compiled :func:`_r_sat_kernel`; numpy specification
        :meth:`_r_sat_reference`, agreement test)."""
        B, m = mask.shape
        keys = self._keys if self._keys is not None else np.full((B, m), -1, np.int64)
        epoch = self._epoch + bool(ctx.pending)
        c = np.ascontiguousarray
        s_rows, s_prev = np.empty((B, m)), np.empty((B, m))
        n_rows = np.empty((B, m), np.int64)
        s_group = np.empty((B, len(GROUP_NAMES)))
        R_used = np.empty(R.shape, R.dtype)
        args = (c(r), c(H), c(ctx.prior), c(ctx.Q if ctx.pending else ctx.prior), bool(ctx.pending), c(R),
                mask, c(keys, np.int64), self._sat_b(), self._sat_b_key, self._sat_jcap(), d, active, epoch,
                self._sat_scale,
                self._sat_count, self._sat_last, *self._sat_settings(), self._r_scale,
                s_rows, n_rows, s_prev, s_group, R_used)
        nchunk = row_chunks(B)
        if self.fused and nchunk > 1:  # same bits per row, rows in parallel chunks
            _r_sat_parallel(nchunk, *args)
        else:
            _r_sat_kernel(*args)
        pending.update(r_scale=s_group, sat=(keys, s_rows, n_rows, s_prev), epoch=epoch)
        return UpdatePlan(fade=np.ones(self.batch_size), R=R_used, mask=mask, pending=pending)

    def _r_sat_reference(self, r, H, R, mask, ctx: EpochContext, keys, d, active):
        """Numpy specification of the satellite-mode R law (:func:`_r_sat_kernel`).

        Returns
        -------
        s_rows (B, m) new scales of the keyed rows (1 elsewhere), n_rows (B, m) their counts, s_group (B, G)
        the group scales of the rows without a key, R_used (B, m, m).
        """
        from .innovation import geometry_residuals_reference, posterior_residuals_reference
        cfg = self.config
        B, m = mask.shape
        b = self._sat_b()
        smin, smax = self._sat_bounds()
        epoch = self._epoch + bool(ctx.pending)
        P_minus = ctx.prior + ctx.Q if ctx.pending else ctx.prior
        excess = r.astype(np.float64) ** 2 - quadratic_diag(H, P_minus).astype(np.float64)
        Rdiag = np.diagonal(R, axis1=1, axis2=2).astype(np.float64)
        keyed = mask & (keys >= 0)
        kk = np.maximum(keys, 0)
        bk = np.take_along_axis(self._sat_b_key, kk, 1)
        bk = np.where(np.isnan(bk), b[:, None], bk)  # each key's own b, the row's by default
        last = np.take_along_axis(self._sat_last, kk, 1)
        u = epoch[:, None] - last
        fresh = (last < 0) | (u > cfg.forget_after_epochs)
        aged = 1.0 + (np.take_along_axis(self._sat_scale, kk, 1) - 1.0) * bk ** np.maximum(u - 1, 0)
        s0 = np.where(fresh, 1.0, aged)
        n0 = np.where(fresh, 0, np.take_along_axis(self._sat_count, kk, 1))
        dk = sage_husa_weight(bk, np.minimum(n0 + 1, self._sat_jcap()[:, None]))
        act = active[:, None]
        scale_var = s0
        x, has = excess / Rdiag, keyed
        for it in range(1 if cfg.r_sample == "innovation" else cfg.sample_iterations):
            if cfg.r_sample != "innovation":
                var = np.where(keyed, scale_var * Rdiag, 1.0)
                if cfg.r_sample in ("geometry", "consensus"):
                    types = np.where(keyed, (keys >= N_SAT_KEYS).astype(np.int64), -1)
                    v, red = geometry_residuals_reference(r, H, var, types, 2)
                    has = keyed & (red >= cfg.min_redundancy) & (red > 0)
                    x = np.where(has, v ** 2 / np.where(has, red * Rdiag, 1.0), 0.0)
                if cfg.r_sample != "geometry":
                    has_g, x_g = (has, x) if cfg.r_sample == "consensus" else (np.zeros_like(keyed), 0.0)
                    v, red = posterior_residuals_reference(r, H, P_minus, var, keyed, cfg.prior_inflation)
                    has = keyed & (red >= cfg.min_redundancy) & (red > 0)
                    rs = np.where(has, red, 1.0)
                    if cfg.r_sample == "residual":
                        x = np.where(has, v ** 2 / (rs * Rdiag), 0.0)
                    else:  # deleted residual e = v / red, its prediction's variance var / red - var
                        x = np.where(has, ((v / rs) ** 2 - (var / rs - var)) / Rdiag, 0.0)
                        if cfg.median_guard:
                            x = _median_guard_reference(x, has, keys)
                        x = np.where(has & has_g, np.minimum(x, x_g), np.where(has, x, x_g))
                    has = has | has_g
            s1 = np.clip((1 - dk) * s0 + dk * x, cfg.sat_scale_min, smax)
            upd = has & act
            s_rows = np.where(keyed, np.where(upd, s1, s0), 1.0)
            n_rows = np.where(keyed, np.where(upd, n0 + 1, n0), 0)
            scale_var = np.where(has, np.maximum(s_rows, x), s_rows)
        all_groups = np.where(mask, measurement_groups(H, mask), -1)
        groups = all_groups if cfg.common_scale else np.where(keys < 0, all_groups, -1)
        G = len(GROUP_NAMES)
        onehot = (groups[..., None] == np.arange(G)).astype(np.float64)
        num = np.einsum("bm,bmg->bg", excess, onehot)
        den = np.einsum("bm,bmg->bg", Rdiag * s_rows, onehot)
        used = onehot.sum(1) > 0
        sg = np.clip((1 - d[:, None]) * self._r_scale + d[:, None] * num / np.where(used, den, 1.0),
                     smin, smax)
        s_group = np.where(used & active[:, None], sg, self._r_scale)
        g_row = np.take_along_axis(s_group, np.maximum(all_groups, 0), 1)
        row_s = np.where(keyed, s_rows * (g_row if cfg.common_scale else 1.0), np.where(all_groups >= 0, g_row, 1.0))
        sq = np.sqrt(row_s).astype(self.dtype)
        return s_rows, n_rows, s_group, R * sq[:, :, None] * sq[:, None, :]

    def _commit_satellites(self, mask, keys, s_rows, n_rows, s_prev, epoch):
        """Write the used satellites' new scales, counts and epoch into the per-key tables; summarize."""
        if self.fused:  # compiled, same values (the numpy lines below are its specification)
            self._epoch = epoch
            self._sat_summary = np.empty((mask.shape[0], 4))
            kern, nchunk = row_kernel(_commit_serial, _commit_parallel, mask.shape[0])
            kern(np.ascontiguousarray(mask), np.ascontiguousarray(keys, np.int64),
                 np.ascontiguousarray(s_rows, np.float64), np.ascontiguousarray(n_rows, np.int64),
                 np.ascontiguousarray(s_prev, np.float64), np.ascontiguousarray(epoch, np.int64),
                 N_SAT_KEYS, float(ROSE_FACTOR), self._sat_scale, self._sat_count, self._sat_last, self._sat_summary,
                 nchunk)
            return
        used = mask & (keys >= 0)
        b_idx, i_idx = np.nonzero(used)
        k = keys[b_idx, i_idx]
        self._sat_scale[b_idx, k] = s_rows[b_idx, i_idx]  # in place: committed only after a successful update
        self._sat_count[b_idx, k] = n_rows[b_idx, i_idx]
        self._sat_last[b_idx, k] = epoch[b_idx]
        self._epoch = epoch
        pr = used & (keys < N_SAT_KEYS)
        npr = pr.sum(1)
        mx = np.where(npr > 0, np.max(np.where(pr, s_rows, -np.inf), 1), 1.0)
        # median over the used pseudorange rows; a row without any is all ones (median 1)
        med = np.nanmedian(np.where(npr[:, None] > 0, np.where(pr, s_rows, np.nan), 1.0), 1)
        rose = (pr & (s_rows > ROSE_FACTOR * s_prev)).sum(1)
        self._sat_summary = np.stack([mx, med, rose, npr], 1).astype(np.float64)

    def satellite_scales(self, keys):
        """Current R scales of the satellites ``keys`` (B, k) measurement keys (satellite mode): (B, k), 1 for
        keys never seen or forgotten (aging not applied: the values of the last epoch each was used)."""
        if not self._sat_enabled():
            raise ValueError("satellite_scales needs r_mode='satellite'")
        keys = np.ascontiguousarray(keys, np.int64)
        B, K = self._sat_scale.shape
        if keys.ndim != 2 or keys.shape[0] != B:
            raise ValueError(f"satellite_scales: keys must have the shape (B={B}, k), got {keys.shape}")
        if keys.size and keys.max() >= K:
            raise ValueError(f"satellite_scales: keys must be below {K}, got {keys.max()}")
        return _key_scales(keys, self._sat_scale, self._sat_last)
