"""Gymnasium environments: an agent sets the adaptive parameter of a running tightly coupled GNSS/INS filter.

## Description

A simulated vehicle (IMU + GNSS receiver, see :mod:`envs.sim`) is navigated by
a batched tightly coupled error-state Kalman filter (:mod:`nav_filters`). The
filter is an *adaptive* one of the literature (Sage-Husa, STKF, MA-STKF) whose
hand-tuned constant is now the agent's action, chosen anew at every GNSS epoch
from the filter's own health signals. The reward is the negative position error
against the simulated truth.

| id | action sets | default method |
|---|---|---|
| ``GnssIns/SageHusa-v1`` | the Sage-Husa forgetting factor ``b`` | ``sage-husa`` (any Sage-Husa form: ``svd-akf``, ``svd-asrkf``) |
| ``GnssIns/STKF-v1`` | the strong-tracking softening factor | ``stkf`` |
| ``GnssIns/MASTKF-v1`` | MA-STKF ``b`` and its fading-factor scaling | ``ma-stkf`` |

## Action Space

``Box(-1, 1, shape=(k,), float32)``, one component per parameter, mapped to the
parameter's range (:class:`envs.config.ParamSpec`; the table of each env class
lists them). Values outside [-1, 1] are clipped; NaN or inf raise ``ValueError``.
The action is applied before the epoch's measurement update.

## Observation Space

``Box(low, high, shape=(history * (k + 19),), float32)``, finite bounds, values
clipped to them. Each frame (newest last when ``history > 1``) holds the current
parameter actions (k values in [-1, 1]) followed by (:data:`envs.core.OBS_FEATURES`):

| idx | name | range | meaning |
|---|---|---|---|
| k+0 | nis_pr | 0-100 | pseudorange NIS per measurement: sum(dz^2/S_ii)/n |
| k+1 | nis_prr | 0-100 | pseudorange-rate NIS per measurement |
| k+2 | nis_pr_ema | 0-100 | moving average (alpha 0.1) of nis_pr |
| k+3 | nis_prr_ema | 0-100 | moving average of nis_prr |
| k+4 | log_innov_pr | 0-4 | log10(1 + RMS pseudorange innovation [m]) |
| k+5 | log_innov_prr | 0-4 | log10(1 + RMS pseudorange-rate innovation [m/s]) |
| k+6 | sats_frac | 0-1 | satellites used / channels |
| k+7 | gdop | 0-5 | GDOP / 10 (5: no fix) |
| k+8 | log_pos_var | -4-8 | log10 trace of the position covariance [m^2] |
| k+9 | time_since_update | 0-10 | seconds since the last epoch with satellites / 60 |
| k+10 | outage | 0-1 | 1 if no satellite at this epoch |
| k+11 | zupt | 0-1 | 1 if a zero-velocity update was applied |
| k+12 | speed | 0-10 | INS speed [m/s] / 10 |
| k+13 | nis_pr_sat_max | 0-100 | largest per-satellite pseudorange dz_i^2/S_ii |
| k+14 | nis_pr_sat_p90 | 0-100 | its 90th percentile over the satellites |
| k+15 | gate_frac | 0-1 | fraction of satellites with dz_i^2/S_ii > 9 |
| k+16 | sats_rose | 0-1 | satellites whose R scale more than doubled this epoch / channels (per-satellite laws) |
| k+17 | log_sat_scale_max | -2-4 | log10 of the largest per-satellite R scale (per-satellite laws) |
| k+18 | dsats | -1-1 | change of the satellite count since the previous epoch / channels |

Only quantities the filter has enter the observation, never the truth.

## Rewards

``reward='horizontal'`` (default): ``-horizontal error [m]`` at the epoch.
``'log'``: ``-ln(error + 0.1 m)``. ``'3d'``: ``-3D error [m]``. ``'advantage'``:
the horizontal error of a reference filter (same method, default parameters,
same data) minus the agent's. A diverged epoch gets the penalty
``-divergence_bound_m`` (``-ln(bound + 0.1)`` for ``'log'``).

## Starting State

A new world (trajectory, IMU errors, satellites, receiver errors, initial
estimate errors) drawn from the scenario with the episode's world seed; parameters at
their defaults. ``reset(seed=s)`` seeds the generator that draws the world seeds, which lie in
:data:`envs.core.TRAINING_WORLD_SEEDS` (>= 2**30), apart from eval.py's and ``train.py tune``'s seeds.
Once ``reset()`` has gone on without a seed twice, the worlds of the coming resets are drawn in batches of up to
16 (:class:`envs.worlds_ahead.WorldsAhead`; a world costs less per row in a batch): the same episodes.

## Episode End

* Termination: the filter diverged (non-finite state, a failed filter update, a covariance that is not
  positive definite, or horizontal error above ``divergence_bound_m``, default 1000 m); ``info["diverged"]``
  with the reason in ``info["diverged_reason"]`` ('' while the row is fine). A failure in one row of a
  vector env ends that row's episode only (:mod:`nav_filters.navigator`); the others go on.
* Truncation: the last GNSS epoch of the episode (``episode_length_s``, default 120 s).

At the end, ``info["episode_metrics"]`` holds the episode's horizontal RMSE and maximum.

## Arguments

:class:`envs.config.EnvConfig` fields as keyword arguments: ``scenario``,
``method``, ``imu_grade``, ``episode_length_s``, ``gnss_rate_hz``, ``reward``,
``history``, ``zupt`` (``'none'``, ``'truth'``, or a detector: ``'shoe'``, ``'are'``, ``'mag'``, ``'mv'``,
``'mlp'``, ``'lstm'``; ``zupt_weights`` overrides the learned detector's shipped weights), ``dtype``,
``exact_transition`` (default ``False``: the filter's transition formed once per epoch from the averaged
error dynamics, several times faster; ``True``: composed per IMU sample, the reference that eval.py runs),
``fused_update`` (default ``True``: the fused compiled predict + Joseph update of ``kf`` and the adaptive laws'
fast kernels, same equations with a different rounding; ``False``: the navigator's default computation),
``divergence_bound_m``; plus
``render_mode`` (``'ansi'``, ``'rgb_array'``). The vector env (``gym.make_vec(..., vectorization_mode=
"vector_entry_point")``) also takes ``prefetch_worlds`` (default 0): draw the worlds of that many coming automatic
resets ahead in a background process at the lowest CPU priority (the same episodes; :mod:`envs.vector_env`), and
``parallel_kernels`` (default ``'auto'``): how the filter's row kernels run at ``num_envs`` >= 64
(:data:`nav_filters.kernels.PARALLEL_MIN_BATCH`), ``'auto'`` parallel or serial, whichever its measurements of both
found faster (where numba has more than one thread; :class:`nav_filters.parallel_governor.ParallelGovernor`: a
core busy with another process makes the parallel kernels several times slower), ``'always'`` parallel,
``'never'`` serial; the same bits in every mode, only the wall time differs.
Limits (a ``ValueError`` naming the argument at construction): ``episode_length_s`` at most
:data:`envs.config.MAX_EPISODE_S` (3600 s: the world is generated whole at reset), ``history`` at most
:data:`envs.config.MAX_HISTORY` (64), the vector env's ``num_envs`` an int in [1, :data:`envs.core.MAX_BATCH`]
(16384), ``prefetch_worlds`` an int >= 0, ``parallel_kernels`` one of ``'auto'``, ``'always'``, ``'never'``,
``divergence_bound_m`` at least :data:`envs.config.MIN_DIVERGENCE_BOUND_M` (50 m); numbers must not be bools;
``method`` must run this env's adaptive law (its forms, ``+fde``, ``+onestep``:
``ma-stkf`` takes a ``softening`` too, but it is not the STKF env's; :func:`envs.core.check_method_law`). Actions must be real numbers
(complex, string, bool or object arrays are refused); a NaN or inf action names the first rows and the count.

## Version History

* v1 (``GnssIns/SageHusa-v1``, ``GnssIns/STKF-v1``, ``GnssIns/MASTKF-v1``; the current ids): the laws and
  ranges of today, the first version bump since v0. Against v0 as first published (the revisions listed
  under v0, made while the id stayed v0): the Sage-Husa methods adapt R per satellite with the consensus
  sample, a floor of 1 on each scale and the epoch's median guard, and their Q law never goes below the
  nominal Q; ``b`` of ``GnssIns/SageHusa-v1`` spans [0.30, 0.9999] (was [0.90, 0.9999]); ``stkf`` and
  ``ma-stkf`` fade on state events only, MA-STKF's measurement factor is per measurement type; the STKF
  softening spans [0.2, 1000] (was [0.2, 5]) and the MA-STKF fading scale [0.01, 5] (was [0.2, 5]); the
  observation has the six per-satellite health features k+13 to k+18. The same seed and actions give other
  episodes than any v0: policies trained on v0 load (the observation and action spaces are those of the last
  v0) but act on other laws; retrain them.
* v0: initial version. The ``-v0`` ids stay makeable: they build the v1 environment, and ``gym.make`` warns
  that the id is out of date and names v1 (Gymnasium's ``DeprecationWarning``). The v0 laws are not kept:
  figures published with v0 (``docs/headroom.md`` and ``docs/results.md`` were generated with it) cannot be
  reproduced bit for bit by this release. v0 changed meaning four times without a version bump:

  * v0, revised with issue 16 (the ids are a public contract and were kept): the Sage-Husa methods adapt R
    per satellite (``sage-husa-group`` is the earlier law), and six per-satellite health features (k+13 to
    k+18) were appended to the observation. Policies trained before do not fit the new observation size.
  * v0, revised again with issue 16: the per-satellite law takes the *consensus* sample (the smaller of the
    deleted residual and the snapshot-fit residual; :class:`nav_filters.adaptive.SageHusa`) with a floor of 1
    on each satellite's scale, and the ``b`` range of ``GnssIns/SageHusa-v0`` widened from [0.90, 0.9999] to
    [0.30, 0.9999] (the optimum of the canyon scenarios lay at or below the old lower edge; on the 32
    tuning episodes of ``train.py tune`` b = 0.1 gives 3.10 m on urban-transition against 2.64 m at 0.3, and
    is 3.5% better on regime-switch, so the range stops at 0.3). The same
    action now means another b: policies trained before must be retrained. The STKF softening range widened
    from [0.2, 5] to [0.2, 1000] and the MA-STKF fading-scale range from [0.2, 5] to [0.01, 5]: measured on
    8 development episodes x 300 s, the best STKF softening is 100 on noise-burst (1.48 m against 3.83 at
    5) and outage (4.3 m against 4.7), and the best MA-STKF fading scale 0.01 on noise-burst,
    urban-transition and regime-switch (5.1 m against 7.3 at 0.2 on urban-transition): both optima lay
    beyond the old edges, where fading is all but off.
  * v0, revised a third time with issue 16: ``stkf`` and ``ma-stkf`` fade on state events only (the lower
    confidence bound of the innovation excess a state error can explain, withheld while the measurements are
    noisier than reported) and MA-STKF's measurement factor is per measurement type, from the snapshot-fit
    residuals (:mod:`nav_filters.adaptive.strong_tracking`). The actions keep their ranges and meanings
    (softening scales the noise term, fading_scale the ratio); policies trained before see another law.
  * v0, revised with the issue "adaptive laws that never lose badly" (a version bump is due: the same seed and
    actions give other episodes): the Sage-Husa Q law of ``sage-husa`` / ``svd-akf`` / ``svd-asrkf`` keeps the
    applied Q at or above the nominal one (``q_lower='nominal'``, :class:`nav_filters.adaptive.SageHusa`), so
    ``GnssIns/SageHusa-v0``'s ``q_scale`` feature no longer falls below ~1; the per-satellite R law of those and
    ``sage-husa-r`` divides each deleted-residual sample by its epoch's median (``median_guard``), which changes
    the per-satellite health features. Action ranges and meanings unchanged.
"""
from __future__ import annotations

import copy

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .config import EnvConfig, ParamSpec
from .core import TuningCore, draw_world_seed

SAGE_HUSA_PARAMS = (ParamSpec("b", 0.30, 0.9999, "log1m", 0.98,
                              "Sage-Husa forgetting factor; log(1 - b) linear in the action"),)
STKF_PARAMS = (ParamSpec("softening", 0.2, 1000.0, "log", 1.0,
                         "strong-tracking softening factor beta (scales R in N_k); log-uniform"),)
MASTKF_PARAMS = (ParamSpec("b", 0.90, 0.9999, "log1m", 0.987, "MA-STKF asymptotic forgetting factor b"),
                 ParamSpec("fading_scale", 0.01, 5.0, "log", 1.0, "scaling of the MA-STKF fading factor"))


def make_config(defaults: dict, kwargs: dict, config_class: type = EnvConfig) -> EnvConfig:
    """A ``config_class`` (an :class:`EnvConfig` or a subclass, an env class's ``CONFIG``) from an env's defaults
    and the user's kwargs (unknown kwargs -> ValueError naming them)."""
    fields = set(config_class.__dataclass_fields__)
    bad = set(kwargs) - fields
    if bad:
        raise ValueError(f"unknown environment argument(s) {sorted(bad)}; known: {sorted(fields)}")
    return config_class(**{**defaults, **kwargs})


def _scalar(x):
    """A batch entry of an info array as a Python scalar (float, bool, int or str)."""
    if isinstance(x, (np.floating, np.bool_, np.integer, np.str_)):  # what v[0] of an info array is
        return x.item()
    kind = np.asarray(x).dtype.kind
    if kind == "f":
        return float(x)
    if kind == "b":
        return bool(x)
    return str(x) if kind in "UO" else int(x)


class GnssInsTuningEnv(gym.Env):
    """Base class of the tuning environments (see the module docstring for the tables)."""

    metadata = {"render_modes": ["ansi", "rgb_array"], "render_fps": 4}
    PARAMS: tuple[ParamSpec, ...] = SAGE_HUSA_PARAMS
    DEFAULTS: dict = {"method": "sage-husa"}
    CONFIG: type = EnvConfig
    """The config class of the env's arguments (:func:`make_config`)."""

    def __init__(self, render_mode: str | None = None, **kwargs):
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None, got {render_mode!r}")
        self.config = make_config(self.DEFAULTS, kwargs, self.CONFIG)
        self.render_mode = render_mode
        self.core = self._make_core(1)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(self.core.action_dim,), dtype=np.float32)
        self.observation_space = spaces.Box(self.core.obs_low, self.core.obs_high, dtype=np.float32)
        self._last = None

    @classmethod
    def config_from(cls, kwargs: dict) -> EnvConfig:
        """This env's config from the user's ``kwargs`` (:func:`make_config` with the env's defaults and class)."""
        return make_config(cls.DEFAULTS, kwargs, cls.CONFIG)

    @classmethod
    def core_for(cls, config: EnvConfig, batch_size: int) -> TuningCore:
        """The batched core of this env for ``config`` and ``batch_size`` rows (a subclass may run another)."""
        return TuningCore(config, cls.PARAMS, batch_size, cls.DEFAULTS["method"])

    def _make_core(self, batch_size: int) -> TuningCore:
        return self.core_for(self.config, batch_size)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self.core.worlds_ahead.restart()
        world_seed = draw_world_seed(self.np_random)
        obs = self.core.reset_rows(np.array([0]), [world_seed], coming=self._coming_world_seeds)
        self._last = None
        return obs[0], {"seed": world_seed}

    def _coming_world_seeds(self, k: int) -> list:
        """The world seeds of the next ``k`` resets without a seed, from a copy of ``np_random`` (which goes on as
        if nothing was drawn ahead; a seed that differs at its reset only misses the world drawn for it)."""
        rng = copy.deepcopy(self.np_random)
        return [[draw_world_seed(rng)] for _ in range(k)]

    def step(self, action):
        res = self.core.step(np.asarray(action)[None] if np.ndim(action) == 1 else action)
        self._last = res
        info = {k: v.item(0) if type(v) is np.ndarray else _scalar(v[0]) for k, v in res.info.items()}
        terminated, truncated = bool(res.terminated[0]), bool(res.truncated[0])
        if terminated or truncated:
            info["episode_metrics"] = self.core.episode_metrics([0])[0]
        return res.obs[0], float(res.reward[0]), terminated, truncated, info

    def close(self):
        """Release the world buffers (the bulk arrays its resets reuse, :mod:`envs.sim.buffers`) and the worlds drawn
        ahead."""
        if getattr(self, "core", None) is not None:
            self.core.world_buffers.clear()
            self.core.worlds_ahead.clear()
        super().close()

    def render(self):
        if self.render_mode is None:
            gym.logger.warn("render() called without a render_mode")
            return None
        if self.render_mode == "ansi":
            return self._render_ansi()
        return self._render_rgb()

    def _render_ansi(self) -> str:
        c = self.core
        if self._last is None:
            return f"t=0 s  scenario={c.scenario.name}  method={self.config.method}\n"
        i = self._last.info
        params = "  ".join(f"{s.name}={i[s.name][0]:.5g}" for s in c.specs)
        return (f"epoch {int(c.t[0]):4d}/{c.M}  err_h={i['horizontal_error_m'][0]:7.2f} m  "
                f"nis_pr={i['nis_pr'][0]:6.2f}  sats={int(i['n_sats'][0]):2d}  {params}\n")

    def _render_rgb(self) -> np.ndarray:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        truth, est = self.core.track_ned(0)
        fig, (a1, a2) = plt.subplots(1, 2, figsize=(8, 3.6), dpi=80)
        a1.plot(truth[:, 1], truth[:, 0], "k-", lw=1.5, label="truth")
        a1.plot(est[:, 1], est[:, 0], "r.", ms=3, label="estimate")
        a1.set_xlabel("east [m]"), a1.set_ylabel("north [m]"), a1.axis("equal"), a1.legend(loc="best")
        err = np.hypot(*(est - truth).T) if len(truth) else np.zeros(0)
        a2.plot(np.arange(1, len(err) + 1) / self.core.scenario.gnss_rate_hz, err, "r-")
        a2.set_xlabel("time [s]"), a2.set_ylabel("horizontal error [m]"), a2.grid(alpha=0.3)
        fig.tight_layout()
        fig.canvas.draw()
        img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        plt.close(fig)
        return img


class SageHusaEnv(GnssInsTuningEnv):
    """``GnssIns/SageHusa-v1``: the action sets the Sage-Husa forgetting factor ``b`` in [0.30, 0.9999]
    (``log(1 - b)`` linear in the action; default b = 0.98 <-> action 0.06). Methods: ``sage-husa``,
    ``svd-akf``, ``svd-asrkf``, ``sage-husa-r``, ``sage-husa-group`` (``+onestep`` allowed).

    Per epoch, b weights every satellite's variance recursion (``d -> 1 - b``, no freezing): a small b
    follows a satellite into and out of NLOS within a few epochs and is noisy in open sky, a large b is
    calm and slow. Measured with the consensus law (12 episodes x 300 s, one b for the whole episode),
    the best constant b is 0.5-0.8 in the canyon scenarios (urban-transition, regime-switch) and 0.97-0.9999
    in open sky, the trade-off a policy can learn within an episode."""

    PARAMS = SAGE_HUSA_PARAMS
    DEFAULTS = {"method": "sage-husa"}


class StkfEnv(GnssInsTuningEnv):
    """``GnssIns/STKF-v1``: the action sets the strong-tracking softening factor in [0.2, 1000] (log-uniform,
    default 1)."""

    PARAMS = STKF_PARAMS
    DEFAULTS = {"method": "stkf"}


class MaStkfEnv(GnssInsTuningEnv):
    """``GnssIns/MASTKF-v1``: the action sets the MA-STKF forgetting factor ``b`` in [0.90, 0.9999] (default
    0.987) and the fading-factor scaling in [0.01, 5] (default 1)."""

    PARAMS = MASTKF_PARAMS
    DEFAULTS = {"method": "ma-stkf"}
