"""The batched episode core behind every GNSS/INS tuning environment.

:class:`TuningCore` runs B episodes in one batched navigator. The single
environment is a core with B = 1 and the native vector environment a core with
B = num_envs, so row i of a vector env seeded ``s`` equals the single env seeded
``s + i`` by construction (and by test). Rows are reset independently
(:meth:`TuningCore.reset_rows`): a new world is drawn for those rows only and
spliced into the running batch (:meth:`nav_filters.navigator.Navigator.replace_rows`).

One step = one GNSS epoch: the action sets the filter parameters, the IMU
samples since the previous epoch are integrated (compiled kernel), then the
epoch's tightly coupled update runs. The observation is built from quantities
the filter has, never from the truth; the truth only scores it.
"""
from __future__ import annotations

import copy
import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from nav_filters.kernels import row_kernel, serial_and_parallel
from nav_filters.rows import check_row_pairs, copied_array, copy_dataclass_rows, copy_rows_generic

from .config import EnvConfig, ParamSpec
from .episodes import navigator_for
from .aiding import odometer_rows, with_rows
from .prepared import WORLD_ARRAY_NAMES, PreparedWorld, prepared_from
from .worlds_ahead import WorldsAhead
from .sim.buffers import WorldBuffers
from .zupt_source import STILL_SPEED_MPS, ZuptSource  # noqa: F401  (STILL_SPEED_MPS re-exported)

#: World seeds the environments draw at reset, ``[low, high)``: kept apart from the small seeds that
#: eval.py (``seed * 1_000_003 + k`` < 2**30) and ``train.py tune`` use, so that episodes seen in training
#: can never be evaluation episodes.
TRAINING_WORLD_SEEDS = (2**30, 2**31 - 1)


MAX_BATCH = 16384
"""Most rows of one env core (a vector env's ``num_envs``): every row holds its episode's world, about
:data:`envs.config.WORLD_BYTES_PER_IMU_SAMPLE` per IMU sample (16384 rows of 120 s at 100 Hz: ~80 GB)."""


def check_batch_size(n, name: str = "num_envs") -> int:
    """``n`` as an int in [1, :data:`MAX_BATCH`]; ``ValueError`` naming ``name`` otherwise (a bool, a float
    such as 2.7, a string such as '3', or too many rows)."""
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_BATCH:
        raise ValueError(f"{name} must be an int in [1, {MAX_BATCH}], got {n!r}")
    return int(n)


def check_method_has_params(method: str, specs, env_method: str | None = None) -> None:
    """``ValueError`` at construction when the filter ``method`` cannot take the parameters ``specs`` the env's
    action sets (``kf`` in the Sage-Husa env, ``stkf`` in the MA-STKF env, ...), naming the methods that can;
    with ``env_method`` (the env's own method, its ``DEFAULTS``) also when ``method`` runs another adaptive law
    (:func:`check_method_law`)."""
    from nav_filters.registry import FORMS, law_class, law_params
    need = {s.name for s in specs}

    def params(name):
        return {p.name for p in law_params(name)}

    if not need <= params(method):
        fits = [m for m in sorted(FORMS) if need <= params(m)
                and (env_method is None or law_class(m) is law_class(env_method))]
        have = sorted(params(method))
        raise ValueError(f"method {method!r} does not take the parameter(s) {', '.join(sorted(need))} this env sets "
                         f"({'its parameters: ' + ', '.join(have) if have else 'it has no adjustable parameters'}); "
                         f"methods that do: {', '.join(fits)} (optionally with '+onestep')")
    if env_method is not None:
        check_method_law(method, env_method)


def check_method_law(method: str, env_method: str) -> None:
    """``ValueError`` when ``method`` runs another adaptive law than ``env_method``, the env's own method.

    A parameter of the same name means another thing in another law: ``GnssIns/STKF-v1`` sets the strong-tracking
    softening of ``stkf``; ``ma-stkf`` takes a ``softening`` too, but there it scales the fading factor beside its
    own ``b`` and ``fading_scale``, which the env would leave at their defaults while calling the result
    tuned. The methods of the env's law (its forms, ``+fde``, ``+onestep``) are accepted."""
    from nav_filters.registry import FORMS, law_class
    own, law = law_class(env_method), law_class(method)
    if own is None or law is own:
        return
    import envs
    from . import vector_env
    home = [i for i, (_, vector) in envs.ENV_IDS.items()
            if law is not None and law_class(getattr(vector_env, vector).DEFAULTS["method"]) is law]
    fits = [m for m in sorted(FORMS) if law_class(m) is own]
    raise ValueError(f"method {method!r} runs another adaptive law ({getattr(law, '__name__', 'none')}) than this "
                     f"env's {env_method!r} ({own.__name__}), whose parameters its action sets; methods of this env: "
                     f"{', '.join(fits)} (optionally with '+fde' and/or '+onestep')"
                     + (f"; {method!r} has its own env: {', '.join(home)}" if home else ""))


def draw_world_seed(rng: np.random.Generator) -> int:
    """One training world seed from ``rng`` (in :data:`TRAINING_WORLD_SEEDS`)."""
    return int(rng.integers(*TRAINING_WORLD_SEEDS))

# --------------------------------------------------------------------------- observation layout
OBS_FEATURES = (
    # name, low, high, description
    ("nis_pr", 0.0, 100.0, "pseudorange NIS per measurement, sum(dz^2 / S_ii) / n (0 without satellites)"),
    ("nis_prr", 0.0, 100.0, "pseudorange-rate NIS per measurement (0 without satellites or Doppler)"),
    ("nis_pr_ema", 0.0, 100.0, "exponential moving average (alpha 0.1) of nis_pr over epochs with satellites"),
    ("nis_prr_ema", 0.0, 100.0, "exponential moving average (alpha 0.1) of nis_prr"),
    ("log_innov_pr", 0.0, 4.0, "log10(1 + RMS pseudorange innovation [m])"),
    ("log_innov_prr", 0.0, 4.0, "log10(1 + RMS pseudorange-rate innovation [m/s])"),
    ("sats_frac", 0.0, 1.0, "satellites used / receiver channels"),
    ("gdop", 0.0, 5.0, "GDOP / 10 (5 = no fix: fewer than 4 satellites)"),
    ("log_pos_var", -4.0, 8.0, "log10 of the trace of the position covariance [m^2]"),
    ("time_since_update", 0.0, 10.0, "seconds since the last epoch with satellites / 60"),
    ("outage", 0.0, 1.0, "1 if this epoch had no satellite"),
    ("zupt", 0.0, 1.0, "1 if a zero-velocity update was applied at this epoch"),
    ("speed", 0.0, 10.0, "INS speed [m/s] / 10"),
    # per-satellite health (issue 16): where the error sits on individual satellites
    ("nis_pr_sat_max", 0.0, 100.0, "largest pseudorange normalized innovation dz_i^2 / S_ii over the satellites"),
    ("nis_pr_sat_p90", 0.0, 100.0, "90th percentile (linear interpolation) of dz_i^2 / S_ii over the satellites"),
    ("gate_frac", 0.0, 1.0, "fraction of satellites whose pseudorange dz_i^2 / S_ii exceeds 9 (a 3-sigma gate)"),
    ("sats_rose", 0.0, 1.0, "satellites whose R scale more than doubled at this epoch / channels (per-satellite "
                            "laws; 0 otherwise)"),
    ("log_sat_scale_max", -2.0, 4.0, "log10 of the largest per-satellite pseudorange R scale (per-satellite laws; "
                                     "0 otherwise)"),
    ("dsats", -1.0, 1.0, "change of the number of satellites since the previous epoch / channels"),
)
"""Per-frame observation features after the parameter values (all float32, clipped to [low, high])."""

EMA_ALPHA = 0.1
LOG_REWARD_OFFSET_M = 0.1


@nb.njit(cache=True, inline="always")
def _frame_row(b, action, dz, S, mask, groups, ema, gdop, P, tsu, zflag, v, rose, smax, prev_n, lo, hi, out,
               f, xv, nis, rms):
    """Row ``b`` of :func:`_frame_rows`, in the scratch ``f``, ``xv``, ``nis``, ``rms``."""
    k = action.shape[1]
    C = mask.shape[1]
    n = 0
    for j in range(C):
        if mask[b, j]:
            n += 1
    nn = max(n, 1)
    nis[0] = nis[1] = 0.0
    rms[0] = rms[1] = 0.0
    xmax = 0.0
    p90 = 0.0
    gate = 0.0
    if n > 0:
        q = 0
        for j in range(C):
            if mask[b, j]:
                xv[q] = np.float64(dz[b, j]) ** 2 / np.float64(S[b, j])
                q += 1
        xs = xv[:q]
        xs.sort()  # in place (np.sort's order)
        xmax = xs[q - 1]
        pos = 0.9 * (q - 1)
        lo_i = int(np.floor(pos))
        hi_i = min(lo_i + 1, q - 1)
        p90 = xs[lo_i] + (pos - lo_i) * (xs[hi_i] - xs[lo_i])
        for j in range(q):
            if xs[j] > 9.0:
                gate += 1.0
        gate /= q
        for g in range(groups):
            sn = 0.0
            sr = 0.0
            for j in range(C):
                if mask[b, j]:
                    d2 = np.float64(dz[b, g * C + j]) ** 2
                    sn += d2 / np.float64(S[b, g * C + j])
                    sr += d2
            nis[g] = sn / nn
            rms[g] = np.sqrt(sr / nn)
        for g in range(2):
            ema[b, g] = (1 - EMA_ALPHA) * ema[b, g] + EMA_ALPHA * nis[g]
    for i in range(k):
        f[i] = action[b, i]
    tr = np.float64(P[b, 6, 6]) + np.float64(P[b, 7, 7]) + np.float64(P[b, 8, 8])
    f[k + 0] = nis[0]
    f[k + 1] = nis[1]
    f[k + 2] = ema[b, 0]
    f[k + 3] = ema[b, 1]
    f[k + 4] = np.log10(1.0 + rms[0])
    f[k + 5] = np.log10(1.0 + rms[1])
    f[k + 6] = n / C
    f[k + 7] = min(gdop[b], 50.0) / 10.0
    f[k + 8] = np.log10(max(tr, 1e-12))
    f[k + 9] = tsu[b] / 60.0
    f[k + 10] = 1.0 if n == 0 else 0.0
    f[k + 11] = 1.0 if zflag[b] else 0.0
    f[k + 12] = np.sqrt(v[b, 0] * v[b, 0] + v[b, 1] * v[b, 1] + v[b, 2] * v[b, 2]) / 10.0
    f[k + 13] = xmax
    f[k + 14] = p90
    f[k + 15] = gate
    f[k + 16] = rose[b] / C
    f[k + 17] = np.log10(max(smax[b], 1e-12))
    f[k + 18] = (n - prev_n[b]) / C if prev_n[b] >= 0 else 0.0
    prev_n[b] = n
    for i in range(f.shape[0]):
        x = f[i]
        if np.isnan(x):
            x = 0.0
        elif x == np.inf:
            x = 1e30
        elif x == -np.inf:
            x = -1e30
        x = min(max(x, np.float64(lo[i])), np.float64(hi[i]))
        out[b, i] = x


def _frame_rows(action, dz, S, mask, groups, ema, gdop, P, tsu, zflag, v, rose, smax, prev_n, lo, hi, out, nchunk):
    """Observation frames (B, k + len(OBS_FEATURES)) float32, same quantities as ``TuningCore._frame_reference``.

    Updates the NIS moving averages ``ema`` (B, 2) in place on rows with satellites and ``prev_n`` (B,) to the
    satellite counts of ``mask``; non-finite values map
    as ``np.nan_to_num`` (NaN -> 0, +-inf -> +-1e30) and every component is clipped to [lo, hi].
    Batch rows in ``nchunk`` chunks (parallel in the parallel variant), each allocating its scratch once.
    """
    B = action.shape[0]
    C = mask.shape[1]
    for ch in nb.prange(nchunk):
        f = np.empty(lo.shape[0])
        xv = np.empty(C)
        nis = np.empty(2)
        rms = np.empty(2)
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            _frame_row(b, action, dz, S, mask, groups, ema, gdop, P, tsu, zflag, v, rose, smax, prev_n, lo, hi, out,
                       f, xv, nis, rms)


_frame_serial, _frame_parallel = serial_and_parallel(_frame_rows)


@nb.njit(cache=True)
def _clip_if_finite(a):
    """Clip the (B, k) actions ``a`` to [-1, 1] in place and return True when every entry is finite (the values
    of ``np.minimum(np.maximum(a, -1), 1)``); return False, ``a`` untouched, when one is NaN or inf."""
    B, k = a.shape
    for b in range(B):
        for i in range(k):
            if not np.isfinite(a[b, i]):
                return False
    for b in range(B):
        for i in range(k):
            x = a[b, i]
            if x < -1.0:
                a[b, i] = -1.0
            elif x > 1.0:
                a[b, i] = 1.0
    return True


@nb.njit(cache=True, fastmath={"contract"})
def _rotate(C, b, k, x0, x1, x2):
    """``C[b, k] @ (x0, x1, x2)``, each row's dot product contracted to fused multiply-adds where the CPU has them,
    as numpy's ``matmul`` of a stacked 3 x 3 by 3 x 1 (BLAS) forms it: the same bits as the numpy specification
    on this machine."""
    return (C[b, k, 0, 0] * x0 + C[b, k, 0, 1] * x1 + C[b, k, 0, 2] * x2,
            C[b, k, 1, 0] * x0 + C[b, k, 1, 1] * x1 + C[b, k, 1, 2] * x2,
            C[b, k, 2, 0] * x0 + C[b, k, 2, 1] * x1 + C[b, k, 2, 2] * x2)


@nb.njit(cache=True)
def _errors_kernel(r, truth_r, truth_Cne, j, last, h, e3):
    """Horizontal and 3D position errors [m] of every row at its epoch ``j[b]`` (compiled; the numpy
    specification is :func:`_errors_reference`, agreement test in ``tests/envs/test_core_compiled.py``).

    ``r`` (B, 3) estimated ECEF position; ``truth_r`` (B, M, 3) true ECEF positions and ``truth_Cne``
    (B, M, 3, 3) the ECEF-to-NED rotations at the epochs; ``j`` (B,) int epoch of each row, taken at most ``last``
    (the final epoch). The error ``r - truth`` is rotated to NED; ``h = hypot(north, east)`` and
    ``e3 = |NED error|`` go into ``h``, ``e3`` (B,).
    """
    for b in range(r.shape[0]):
        k = min(j[b], last)
        x0 = r[b, 0] - truth_r[b, k, 0]
        x1 = r[b, 1] - truth_r[b, k, 1]
        x2 = r[b, 2] - truth_r[b, k, 2]
        n0, n1, n2 = _rotate(truth_Cne, b, k, x0, x1, x2)
        h[b] = math.hypot(n0, n1)
        e3[b] = math.sqrt((n0 * n0 + n1 * n1) + n2 * n2)  # numpy's sum of three: in order, not fused


def _errors_reference(r, truth_r, truth_Cne, j, last):
    """Numpy specification of :func:`_errors_kernel`: ``(h, e3)`` (B,) of the rows at epochs ``min(j, last)``."""
    rows, j = np.arange(r.shape[0]), np.minimum(j, last)
    ned = (truth_Cne[rows, j] @ (r - truth_r[rows, j])[..., None])[..., 0]
    return np.hypot(ned[:, 0], ned[:, 1]), np.linalg.norm(ned, axis=1)


@nb.njit(cache=True)
def _score_kernel(h, src, advantage, nav_diverged, bound, penalty, t, M, sq_err_sum, max_err, diverged, reward,
                  truncated):
    """Score one step of every row (compiled :func:`_score_reference`, same values bit for bit: agreement test
    in ``tests/envs/test_core_compiled.py``).

    A row diverged where its navigator did, or its horizontal error ``h`` [m] is not finite or above ``bound``;
    it gets the reward ``penalty``, the others ``-src`` (``src``: the horizontal or 3D error or the log of the
    error plus its offset) or, with ``advantage``, the reference's horizontal error ``src`` (``bound`` where not
    finite, at most ``bound``) minus ``h``. The bounded error (``bound`` where not finite) goes into
    ``sq_err_sum`` (squared) and ``max_err``; ``t`` counts the step; ``truncated`` rows reached epoch ``M``
    without diverging. Writes ``diverged``, ``reward``, ``truncated`` (B,) and returns the number diverged.
    """
    n = 0
    for b in range(h.shape[0]):
        x = h[b]
        finite = np.isfinite(x)
        d = nav_diverged[b] or not finite or x > bound
        if d:
            reward[b] = penalty
            n += 1
        elif advantage:
            s = src[b]
            reward[b] = (min(s, bound) if np.isfinite(s) else bound) - x
        else:
            reward[b] = -src[b]
        hf = min(x, bound) if finite else bound
        sq_err_sum[b] += hf * hf
        if hf > max_err[b]:
            max_err[b] = hf
        t[b] += 1
        diverged[b] = d
        truncated[b] = t[b] >= M and not d
    return n


def _score_reference(h, src, advantage, nav_diverged, bound, penalty, t, M, sq_err_sum, max_err):
    """The numpy specification of :func:`_score_kernel`: returns (diverged, reward, truncated) and updates
    ``t``, ``sq_err_sum`` and ``max_err`` in place."""
    diverged = nav_diverged | ~np.isfinite(h) | (h > bound)
    if advantage:
        reward = np.where(np.isfinite(src), np.minimum(src, bound), bound) - h
    else:
        reward = -src
    reward = np.where(diverged, penalty, reward)
    hf = np.where(np.isfinite(h), np.minimum(h, bound), bound)
    sq_err_sum += hf ** 2
    max_err[:] = np.maximum(max_err, hf)
    t += 1
    return diverged, reward, (t >= M) & ~diverged


@dataclass
class StepResult:
    """Batched result of one core step (arrays of length B)."""

    obs: np.ndarray
    reward: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray
    info: dict


class TuningCore:
    """B episodes of adaptive-parameter tuning in one batched navigator.

    Parameters
    ----------
    config : EnvConfig
    specs : the filter parameters the action sets (one action component each).
    batch_size : B.
    env_method : the env's own method (its ``DEFAULTS``): ``config.method`` must run the same adaptive law
        (:func:`check_method_law`); None: any method that takes ``specs``.
    """

    def __init__(self, config: EnvConfig, specs: tuple[ParamSpec, ...], batch_size: int,
                 env_method: str | None = None):
        check_batch_size(batch_size, "batch_size")
        self.config = config
        self.specs = tuple(specs)
        self.B = int(batch_size)
        self.scenario = config.resolve_scenario()
        check_method_has_params(config.method, self.specs, env_method)
        self.k = len(self.specs)
        self.action_dim = self.k  # components of one row's action (a subclass may act per channel)
        self.frame_dim = self.k + len(OBS_FEATURES)
        self.obs_dim = self.frame_dim * config.history
        lo = np.r_[-np.ones(self.k), [f[1] for f in OBS_FEATURES]]
        hi = np.r_[np.ones(self.k), [f[2] for f in OBS_FEATURES]]
        self.frame_low, self.frame_high = lo.astype(np.float32), hi.astype(np.float32)
        self.obs_low = np.tile(self.frame_low, config.history)
        self.obs_high = np.tile(self.frame_high, config.history)
        self.default_action = np.array([s.to_action(s.default) for s in self.specs], np.float64)
        # the default parameter values of every row (the values of to_value on the default actions)
        self._default_values = {s.name: s.to_value(np.full(self.B, self.default_action[i]))
                                for i, s in enumerate(self.specs)}
        bound = config.divergence_bound_m
        self._bound = float(bound)
        self._penalty = float(-math.log(bound + LOG_REWARD_OFFSET_M) if config.reward == "log" else -bound)
        self.nav = None
        self.ref = None
        self.seeds = [None] * self.B
        # zero-velocity decisions on the IMU samples of every epoch (EnvConfig.zupt)
        self._zupt = ZuptSource(config.zupt, self.scenario.imu_rate_hz, config.zupt_weights)
        self._zflags = None
        # the bulk arrays of the worlds drawn at the resets, reused from one reset to the next (envs.sim.buffers)
        self.world_buffers = WorldBuffers()
        # the worlds of coming resets of few rows, drawn in batches where the env passes their seeds (envs.worlds_ahead)
        self.worlds_ahead = WorldsAhead(config)

    # ------------------------------------------------------------------ reset
    def _make_nav(self, world, method):
        nav = navigator_for(world, method, dtype=self.config.dtype, exact_transition=self.config.exact_transition,
                            fused_update=self.config.fused_update)
        if not hasattr(nav.form, "set_params"):
            raise ValueError(f"method {method!r} has no adjustable parameters "
                             f"({', '.join(s.name for s in self.specs)}); choose an adaptive method")
        return nav

    def _set_params(self, nav, action=None):
        """Set the filter parameters of every row of ``nav`` from the (B, k) actions (None: the defaults, the
        reference navigator's parameters at every step of ``reward='advantage'``); returns them."""
        if action is None:  # copies: a form may keep (and a row reset write into) the arrays it is given
            vals = {name: v.copy() for name, v in self._default_values.items()}
        else:
            vals = {s.name: s.to_value(action[:, i]) for i, s in enumerate(self.specs)}
        nav.form.set_params(**vals)
        return vals

    def reset_rows(self, rows, seeds, prepared: PreparedWorld | None = None, coming=None) -> np.ndarray:
        """Start new episodes on ``rows`` with world ``seeds``; returns their observations (len(rows), obs_dim).

        ``prepared``: the rows' world drawn ahead (:func:`envs.prepared.prepare_world` of this core's config and
        these seeds, e.g. by :class:`envs.prefetch.WorldPrefetcher`); None draws it here. ``coming(k)``: the seeds
        of these rows' next ``k`` resets (``k`` lists like ``seeds``), where the env knows them: then the worlds of
        a few rows are drawn in batches with those of their coming resets (:class:`envs.worlds_ahead.WorldsAhead`,
        ``self.worlds_ahead``). Either way the same bits: the world is a function of the config and the seeds."""
        rows = np.asarray(rows, np.intp)
        seeds = [int(s) for s in seeds]
        if prepared is None and coming is not None:
            prepared = self.worlds_ahead.take(seeds, coming)
        whole = None
        if prepared is None:
            # the whole world stays referenced until its arrays are copied, as before envs.prepared: freeing its
            # bulk (truth at the IMU rate, IMU error records) earlier made the reset of 1024 rows ~1 s shorter
            # but gave 2-3 of the 15 steps after it +30 ms of wall time (no minor page faults, no GC run; cause
            # not pinned down), 0.74-0.82x in bench_envs' 8 timed steps at B = 1024
            whole = self.config.make_world(seeds, buffers=self.world_buffers, for_reset=True)
            prepared = prepared_from(whole)
        elif list(prepared.seeds) != seeds:
            raise ValueError(f"reset_rows: the prepared world holds seeds {list(prepared.seeds)[:4]}..., not the "
                             f"rows' seeds {seeds[:4]}...")
        world = prepared.world
        nav = self._make_nav(world, self.config.method)
        act = np.broadcast_to(self.default_action, (rows.size, self.k)).copy()
        self._set_params(nav, act)
        ref = None
        if self.config.reward == "advantage":
            ref = self._make_nav(world, self.config.method)
            self._set_params(ref, act)
        if self.nav is None:
            if rows.size != self.B or not np.array_equal(rows, np.arange(self.B)):
                raise ValueError("the first reset must cover every row")
            self._alloc(prepared)
            self.nav, self.ref = nav, ref
        else:
            self.nav.replace_rows(rows, nav)
            if ref is not None:
                self.ref.replace_rows(rows, ref)
        for name in self.WORLD_ARRAYS:
            getattr(self, name)[rows] = prepared.arrays[name]
        del whole  # the world drawn here is freed after the copies (see above)
        self._zupt.reset(None if rows.size == self.B else rows)  # new streams on the reset rows
        for i, s in zip(rows, seeds):
            self.seeds[i] = s
        self.t[rows] = 0
        self.action[rows] = act
        self.ema[rows] = 1.0
        self.prev_nsat[rows] = -1
        self.sq_err_sum[rows] = 0.0
        self.max_err[rows] = 0.0
        self.excluded_sum[rows] = 0
        self.est_track[rows] = np.nan
        frame = self._initial_frame(rows)
        self.frames[rows] = frame[:, None, :]
        self._reset_extra(rows)
        return self._observation(rows)

    def _reset_extra(self, rows) -> None:
        """Reset a subclass's own per-row state on ``rows`` (called by :meth:`reset_rows` before the observation)."""

    def _observation(self, rows=None) -> np.ndarray:
        """The observations (len(rows), obs_dim) float32 of ``rows`` (None: every row, (B, obs_dim)), new arrays:
        the stacked frames."""
        if rows is None:
            return self.frames.reshape(self.B, -1).copy()
        return self.frames[rows].reshape(len(rows), -1).copy()

    def _alloc(self, prepared: PreparedWorld):
        B = self.B
        a = prepared.arrays
        N = a["f"].shape[1]
        M, C = a["pr"].shape[1], a["pr"].shape[2]
        self.epoch_idx = prepared.world.epoch_idx
        self.has_rate = prepared.has_rate  # recorded data sets may have no Doppler
        self.M, self.C = M, C
        self.dt = 1.0 / self.scenario.imu_rate_hz
        self.f = np.zeros((B, N, 3))
        self.w = np.zeros((B, N, 3))
        self.sat_pos = np.zeros((B, M, C, 3))
        self.sat_vel = np.zeros((B, M, C, 3))
        self.pr, self.prr, self.pr_sigma, self.prr_sigma = (np.zeros((B, M, C)) for _ in range(4))
        self.gmask = np.zeros((B, M, C), bool)
        self.odo = np.full((B, M), np.nan)  # odometer readings [m/s] (scenarios with an odometer)
        self.odo_yaw = np.full((B, M), np.nan)  # yaw-rate readings [rad/s] (recorded odometry)
        self.sat_keys = np.full((B, M, C), -1, np.int64)
        self.truth_r = np.zeros((B, M, 3))
        self.truth_Cne = np.zeros((B, M, 3, 3))
        self.truth_still = np.zeros((B, M), bool)
        self.truth_still_n = np.zeros((B, N), bool)  # per IMU sample (zupt='truth')
        self.origin = np.zeros((B, 3))
        self.origin_Cne = np.zeros((B, 3, 3))
        self.t = np.zeros(B, np.int64)
        self.action = np.zeros((B, self.k))
        self.ema = np.ones((B, 2))
        self.prev_nsat = np.full(B, -1, np.int64)
        self.sq_err_sum = np.zeros(B)
        self.max_err = np.zeros(B)
        self.excluded_sum = np.zeros(B, np.int64)  # measurement rows the filter excluded (fault exclusion)
        self.frames = np.zeros((B, self.config.history, self.frame_dim), np.float32)
        self.est_track = np.full((B, M, 3), np.nan)

    def _initial_frame(self, rows):
        n = rows.size
        feat = np.zeros((n, len(OBS_FEATURES)))
        P = np.asarray(self.nav.covariance, np.float64)[rows]
        feat[:, 2:4] = 1.0
        feat[:, 7] = 5.0
        feat[:, 8] = np.log10(np.trace(P[:, 6:9, 6:9], axis1=1, axis2=2))
        feat[:, 12] = np.linalg.norm(self.nav.v[rows], axis=1) / 10.0
        return self._clip_frame(np.concatenate([self.action[rows], feat], 1))

    def _clip_frame(self, frame):
        frame = np.nan_to_num(frame, nan=0.0, posinf=1e30, neginf=-1e30)
        return np.clip(frame, self.frame_low, self.frame_high).astype(np.float32)

    # ------------------------------------------------------------------- step
    def check_actions(self, actions) -> np.ndarray:
        """(B, k) float64 array of real, finite numbers; ``ValueError`` naming the problem otherwise (a complex,
        string, boolean or object array; the wrong shape; NaN/inf, naming the first rows and how many).
        Out-of-range values are clipped to [-1, 1] (documented behaviour)."""
        raw = np.asarray(actions)
        if raw.dtype.kind not in "fiu":
            raise ValueError(f"action must be an array of real numbers, got dtype {raw.dtype}"
                             + (" (complex: the imaginary part would be dropped)" if raw.dtype.kind == "c" else ""))
        a = raw.astype(np.float64)
        k = self.action_dim
        if a.shape == (k,) and self.B == 1:
            a = a[None]
        if a.shape != (self.B, k):
            raise ValueError(f"action must have shape ({k},) per env (batch {self.B}), got {np.shape(actions)}")
        if not _clip_if_finite(a):  # one compiled pass instead of isfinite / all / maximum / minimum
            bad = np.flatnonzero(~np.isfinite(a).all(1))
            first = ", ".join(str(int(r)) for r in bad[:5]) + (", ..." if bad.size > 5 else "")
            raise ValueError(f"action contains NaN or inf in {bad.size} of {self.B} rows (rows {first}; "
                             f"row {int(bad[0])}: {a[bad[0]].tolist()})")
        return a

    def step(self, actions) -> StepResult:
        """Apply the actions, integrate to the next GNSS epoch, update, and score every row."""
        a = self.check_actions(actions)
        if self.nav is None:
            raise RuntimeError("reset() must be called before step()")
        if (self.t[0] if self.B == 1 else self.t.max()) >= self.M:  # (a single row: no reduction call)
            raise RuntimeError("step() on a finished episode: reset those rows first")
        vals = self._apply_action(a)
        j = self.t  # per-row epoch index (rows may be at different epochs after partial resets)
        h_err, e3, res, zflag = self._advance(self.nav, j)
        if self.ref is not None:
            self._set_params(self.ref)
            ref_h, ref_3d, _, _ = self._advance(self.ref, j)
        if self.B == 1:
            self.est_track[0, j[0]] = self.nav.r[0]
        else:
            self.est_track[np.arange(self.B), j] = self.nav.r
        mode = self.config.reward
        if mode == "horizontal":
            src = h_err
        elif mode == "3d":
            src = e3
        elif mode == "log":
            src = np.log(h_err + LOG_REWARD_OFFSET_M)
        else:
            src = ref_h
        diverged, reward, truncated = np.empty(self.B, bool), np.empty(self.B), np.empty(self.B, bool)
        n_diverged = _score_kernel(h_err, src, mode == "advantage", self.nav.diverged, self._bound, self._penalty,
                                   self.t, self.M, self.sq_err_sum, self.max_err, diverged, reward, truncated)
        if n_diverged:
            bound = self.config.divergence_bound_m
            reason = np.where(self.nav.diverged, self.nav.divergence_reasons(),
                              np.where(~np.isfinite(h_err), "horizontal error not finite",
                                       np.where(h_err > bound,
                                                f"horizontal error above divergence_bound_m ({bound:g} m)", "")))
        else:  # the common case: no strings to form
            reason = np.zeros(self.B, "<U1")  # = np.full(B, ""), cheaper
        terminated = diverged
        if self.config.history > 1:
            self.frames[:, :-1] = self.frames[:, 1:]
        frame = self._frame(res, zflag)  # written into self.frames[:, -1]
        info = {
            "horizontal_error_m": h_err, "error_3d_m": e3, "diverged": diverged, "diverged_reason": reason,
            "nis_pr": frame[:, self.k + 0].astype(np.float64), "nis_prr": frame[:, self.k + 1].astype(np.float64),
            "n_sats": self.prev_nsat.copy(), "zupt": zflag,  # _frame set prev_nsat to this epoch's counts
        }
        for s in self.specs:
            info[s.name] = vals[s.name].copy()
        excluded = getattr(self.nav.form, "excluded", None)
        excluded = None if excluded is None else excluded()
        if excluded is not None:  # a method that screens its measurements (kf-fde, +fde, kf-igg3)
            info["n_excluded"] = excluded
            self.excluded_sum += excluded
        if self.ref is not None:
            info["reference_horizontal_error_m"] = ref_h
        return StepResult(obs=self._observation(), reward=reward, terminated=terminated, truncated=truncated,
                          info=info)

    def _apply_action(self, a) -> dict:
        """Apply the checked (B, action_dim) actions ``a`` for the coming update; returns the parameter values set
        (``{name: (B,)}``, reported in the step's info)."""
        self.action[:] = a
        return self._set_params(self.nav, a)

    def episode_metrics(self, rows) -> list[dict]:
        """Metrics of the episodes of ``rows`` so far (call at the end of an episode)."""
        out = []
        for i in np.atleast_1d(rows):
            n = max(int(self.t[i]), 1)
            out.append({"rmse_h_m": float(np.sqrt(self.sq_err_sum[i] / n)), "max_h_m": float(self.max_err[i]),
                        "epochs": int(self.t[i]), "seed": self.seeds[i],
                        "excluded_per_epoch": float(self.excluded_sum[i] / n)})
        return out

    def _advance(self, nav, j):
        """Integrate each row to its epoch j[row] and run the update; rows share the IMU rate."""
        B = self.B
        ep = self.epoch_idx
        j0 = int(j[0])
        if B == 1 or bool((j == j0).all()):  # common case: every row at the same epoch (basic slices)
            a0, b0 = (int(ep[j0 - 1]) if j0 > 0 else 0) + 1, int(ep[min(j0, self.M - 1)]) + 1
            sel = (slice(None), slice(a0, b0))
            nav.propagate_epoch(self.f[sel], self.w[sel], self.dt)
            rows = slice(None)
            jj = min(j0, self.M - 1)
        else:  # rows at different epochs (after partial resets): gather each row's samples
            rows = np.arange(B)
            start = np.where(j > 0, ep[np.maximum(j - 1, 0)], 0)
            stop = ep[np.minimum(j, self.M - 1)]
            n = int((stop - start).max())
            idx = start[:, None] + 1 + np.arange(n)[None, :]
            sel = (rows[:, None], idx)
            nav.propagate_epoch(self.f[sel], self.w[sel], self.dt)
            jj = np.minimum(j, self.M - 1)
        g = self._gnss_inputs(nav, rows, jj)
        zflag = np.zeros(B, bool)
        extra = None
        if self._zupt.enabled:
            if nav is self.nav:  # the detector runs once per step; a reference navigator reuses its decisions
                self._zflags = self._zupt.decide(self.f[sel], self.w[sel], self.truth_still_n[sel])
            extra, zflag = self._zupt.block(nav, self.w[sel], self._zflags, self.dt)
        odo_model = getattr(self.scenario, "odometer", None)  # simulated, or a recording's ([odometry] of its spec)
        if odo_model is not None:  # the scenario's wheel odometer + NHC (+ yaw rate) (envs.aiding)
            extra = with_rows(extra, odometer_rows(nav, self.odo[rows, jj], odo_model, self.odo_yaw[rows, jj],
                                                   self.w[sel], self.dt))
        res, gdop = nav.update_gnss(*g, extra=extra, sat_keys=self.sat_keys[rows, jj])
        h, e3 = np.empty(B), np.empty(B)
        _errors_kernel(nav.r, self.truth_r, self.truth_Cne, j, self.M - 1, h, e3)
        if nav is self.nav:
            self._last_res, self._last_gdop, self._last_mask = res, gdop, g[6] & ~nav.diverged[:, None]
        return h, e3, res, zflag

    def _gnss_inputs(self, nav, rows, jj) -> tuple:
        """The epoch's arguments of :meth:`~nav_filters.navigator.Navigator.update_gnss` for ``nav`` (the agent's
        navigator or the reference one): ``(sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, mask)`` of rows
        ``rows`` at their epochs ``jj`` (``prr`` and its sigma None without Doppler)."""
        rate = self.has_rate
        return (self.sat_pos[rows, jj], self.sat_vel[rows, jj], self.pr[rows, jj],
                self.prr[rows, jj] if rate else None, self.pr_sigma[rows, jj],
                self.prr_sigma[rows, jj] if rate else None, self.gmask[rows, jj])

    def _frame(self, res, zflag):
        """The observation frame of this epoch, written into ``self.frames[:, -1]`` and returned (compiled:
        :func:`_frame_rows`; :meth:`_frame_reference` is the numpy specification, agreement test in
        ``tests/envs/test_core_compiled.py``)."""
        groups = 2 if (self.nav.config.use_pseudorange_rate and self.has_rate) else 1
        out = self.frames[:, -1]  # the newest frame, in place
        rose, smax = self._satellite_health()
        kern, nchunk = row_kernel(_frame_serial, _frame_parallel, self.B)
        kern(self.action, np.ascontiguousarray(res.innovation), np.ascontiguousarray(res.innovation_var),
             self._last_mask, groups, self.ema, self._last_gdop, self.nav.covariance, self.nav.time_since_update,
             zflag, self.nav.v, rose, smax, self.prev_nsat, self.frame_low, self.frame_high, out, nchunk)
        return out

    def _satellite_health(self):
        """(B,) satellites whose R scale rose this epoch and (B,) the largest per-satellite R scale, from a
        per-satellite law's adaptive state (zeros and ones for other methods)."""
        health = getattr(self.nav.form, "satellite_health", None)
        h = health() if health is not None else None
        return (np.zeros(self.B), np.ones(self.B)) if h is None else h

    def _frame_reference(self, res, zflag):
        C = self.C
        mask = self._last_mask
        n = mask.sum(1)
        dz2 = np.asarray(res.innovation, np.float64) ** 2
        S = np.asarray(res.innovation_var, np.float64)
        nis = np.zeros((self.B, 2))
        rms = np.zeros((self.B, 2))
        groups = [slice(0, C)]
        if self.nav.config.use_pseudorange_rate and self.has_rate:
            groups.append(slice(C, 2 * C))
        for gi, sl in enumerate(groups):
            m = mask
            nn = np.maximum(n, 1)
            nis[:, gi] = np.where(n > 0, np.sum(np.where(m, dz2[:, sl] / S[:, sl], 0.0), 1) / nn, 0.0)
            rms[:, gi] = np.where(n > 0, np.sqrt(np.sum(np.where(m, dz2[:, sl], 0.0), 1) / nn), 0.0)
        has = n > 0
        self.ema[has] = (1 - EMA_ALPHA) * self.ema[has] + EMA_ALPHA * nis[has]
        P = np.asarray(self.nav.covariance, np.float64)
        feat = np.stack([
            nis[:, 0], nis[:, 1], self.ema[:, 0], self.ema[:, 1],
            np.log10(1.0 + rms[:, 0]), np.log10(1.0 + rms[:, 1]),
            n / C, np.minimum(self._last_gdop, 50.0) / 10.0,
            np.log10(np.maximum(np.trace(P[:, 6:9, 6:9], axis1=1, axis2=2), 1e-12)),
            self.nav.time_since_update / 60.0, (n == 0).astype(float), zflag.astype(float),
            np.linalg.norm(self.nav.v, axis=1) / 10.0,
        ], 1)
        x = np.where(mask, dz2[:, :C] / S[:, :C], np.nan)
        with np.errstate(all="ignore"):
            xmax = np.where(n > 0, np.nanmax(np.where(mask, x, -np.inf), 1), 0.0)
            p90 = np.array([np.percentile(r[np.isfinite(r)], 90) if np.isfinite(r).any() else 0.0 for r in x])
            gate = np.where(n > 0, np.sum(mask & (np.nan_to_num(x) > 9.0), 1) / np.maximum(n, 1), 0.0)
        rose, smax = self._satellite_health()
        dsats = np.where(self.prev_nsat >= 0, (n - self.prev_nsat) / C, 0.0)
        feat = np.concatenate([feat, np.stack([xmax, p90, gate, rose / C, np.log10(np.maximum(smax, 1e-12)),
                                               dsats], 1)], 1)
        self.prev_nsat = n.astype(np.int64)
        return self._clip_frame(np.concatenate([self.action, feat], 1))

    # -------------------------------------------------------------- branching
    WORLD_ARRAYS = WORLD_ARRAY_NAMES
    """Per-row world arrays (a function of the row's world seed: rows with equal seeds hold equal worlds)."""
    SHARED_ATTRS = frozenset({"config", "specs", "scenario", "epoch_idx", "default_action", "_default_values",
                              "frame_low", "frame_high", "obs_low", "obs_high", "nav", "ref", "seeds", "_zupt",
                              "_last_res"})
    """Attributes :meth:`copy_rows` does not copy generically: shared by all rows (their length may equal B by
    chance) or copied by their own rule. Every other ndarray with leading axis B is per-row state."""

    def copy_rows(self, dst, src) -> None:
        """Copy the episode state of rows ``src`` to rows ``dst`` (exact branching inside the batch).

        Copied: the navigator (:meth:`nav_filters.navigator.Navigator.copy_rows`), the reference
        navigator of ``reward='advantage'``, the world seed and world arrays (:data:`WORLD_ARRAYS`; skipped
        where both rows already hold the same seed's world), and every other per-row array of the core
        (epoch ``t``, ``action``, the NIS averages ``ema``, ``sq_err_sum``, ``max_err``, ``frames``,
        ``est_track``, the last step's diagnostics, and any added later). Afterwards row ``dst[i]``
        stepped with the same actions as row ``src[i]`` gives bit-identical results.

        Parameters
        ----------
        dst, src : (n,) int row indices, equal lengths; overlap allowed (sources are read first).

        Raises
        ------
        ValueError
            bad indices, or a zero-velocity detector with its own per-row stream state (``zupt`` other
            than ``'none'`` or ``'truth'``): branching needs ``zupt='none'`` (or ``'truth'``).
        RuntimeError
            before the first reset.
        """
        if self.nav is None:
            raise RuntimeError("copy_rows() needs a reset() first")
        dst, src = check_row_pairs(dst, src, self.B)
        if self._zupt.detector is not None:
            raise ValueError(f"copy_rows: the {self._zupt.choice!r} zero-velocity detector keeps per-row stream "
                             "state that is not copied; branching (the oracles) needs zupt='none' (or 'truth')")
        self.nav.copy_rows(dst, src)
        if self.ref is not None:
            self.ref.copy_rows(dst, src)
        differ = np.array([self.seeds[d] != self.seeds[s] for d, s in zip(dst, src)], bool)
        if differ.any():
            wd, ws = dst[differ], src[differ]
            for name in self.WORLD_ARRAYS:
                setattr(self, name, copied_array(getattr(self, name), wd, ws))
        seeds = list(self.seeds)
        for d, s in zip(dst, src):
            seeds[d] = self.seeds[s]
        self.seeds = seeds
        if getattr(self, "_last_res", None) is not None:
            self._last_res = copy_dataclass_rows(self._last_res, dst, src, self.B, "the last update result")
        copy_rows_generic(self, dst, src, self.B, skip=self.SHARED_ATTRS | set(self.WORLD_ARRAYS))

    def clone(self) -> "TuningCore":
        """An independent copy of the running batch (a snapshot to return to): every state is deep-copied,
        the world arrays and the other shared read-only attributes are shared with this core (nothing
        writes them in place; :meth:`copy_rows` replaces an array instead of writing into it). The caches of
        world draws (``world_buffers``, ``worlds_ahead``) start empty in the copy instead of being copied."""
        memo = {id(getattr(self, n)): getattr(self, n) for n in self.WORLD_ARRAYS if hasattr(self, n)}
        memo[id(self.world_buffers)] = WorldBuffers()
        memo[id(self.worlds_ahead)] = WorldsAhead(self.config)
        for n in ("config", "specs", "scenario", "epoch_idx", "default_action", "_default_values", "frame_low",
                  "frame_high", "obs_low", "obs_high"):
            if hasattr(self, n):
                memo[id(getattr(self, n))] = getattr(self, n)
        return copy.deepcopy(self, memo)

    # ------------------------------------------------------------------ views
    def track_ned(self, row: int):
        """(truth, estimate) horizontal tracks of ``row`` so far, NED metres from its start: (n, 2) each."""
        n = int(self.t[row])
        C0 = self.origin_Cne[row]
        tr = (C0 @ (self.truth_r[row, :n] - self.origin[row]).T).T
        es = (C0 @ (self.est_track[row, :n] - self.origin[row]).T).T
        return tr[:, :2], es[:, :2]
