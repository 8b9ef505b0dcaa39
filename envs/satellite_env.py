"""Per-satellite environments: the action holds one value per receiver channel.

## Description

The world, the filter and the episode are those of :mod:`envs.gnss_ins_env`; here the agent acts on every
satellite of the coming GNSS epoch on its own, one action component per receiver channel:

| id | a channel's action sets | default method |
|---|---|---|
| ``GnssIns/SatelliteR-v0`` | the base-10 log of the inflation of the channel's reported pseudorange and pseudorange-rate variances, in [0, 4] (x1 to x10^4), applied before the epoch's update | ``kf`` (any method: form, adaptive law, robust screen, ``+fde``, ``+onestep``) |
| ``GnssIns/SatelliteSageHusa-v0`` | the forgetting factor ``b_i`` of the satellite's own Sage-Husa R recursion, in [0.30, 0.9999] (``GnssIns/SageHusa-v1``'s range and map) | ``sage-husa`` (any per-satellite Sage-Husa method: ``svd-akf``, ``svd-asrkf``, ``sage-husa-r``, with ``+fde`` / ``+onestep``) |

SatelliteR inflates the variance the receiver reports before the filter sees it (the filter then runs unchanged,
whatever its method): the action space in which ``oracle-r`` (the simulator's true variance per satellite and
epoch) is the floor. SatelliteSageHusa writes each channel's ``b`` to its satellite's pseudorange and rate keys
(:meth:`nav_filters.adaptive.SageHusa.set_satellite_params`); the row's own ``b`` (the Q law, the group scales)
stays at 0.98, ``GnssIns/SageHusa-v1``'s default.

Channels are a set: the receiver orders them as it likes (the simulated one by elevation, so a satellite moves
between channels), satellites rise and set. Channel i of an action is channel i of the epoch the observation
describes and the update uses; the env maps it to that channel's satellite key, and every per-channel history in
the observation follows the satellite, not the channel. The same world with its channels permuted, given the
correspondingly permuted actions, gives the same trajectory (to rounding; test).

## Action Space

``Box(-1, 1, shape=(C,), float32)``, ``C = channels`` (default: the scenario's receiver channels, 16 for the
simulated ones; a recording's own channel count). A channel's action maps linearly to ``log10_inflation`` in
[0, 4] (-1: x1, the default; 1: x10^4) in SatelliteR, and as ``GnssIns/SageHusa-v1``'s ``b`` (``log(1 - b)``
linear, -1: 0.30, 1: 0.9999, default 0.98 <-> 0.06) in SatelliteSageHusa. Values outside [-1, 1] are clipped,
NaN or inf raise ``ValueError``. The components of channels without a satellite (mask 0) are ignored.

## Observation Space

``Box(low, high, shape=(history * 19 + C * 27 + C,), float32)``, finite bounds, values clipped, in three blocks:

| block | size | content |
|---|---|---|
| global | ``history * 19`` | the frames of the scalar envs (:data:`envs.core.OBS_FEATURES`: NIS, innovations, satellites, GDOP, covariance, outage, ZUPT, speed, per-satellite health) without parameter values, newest last |
| channels | ``C * 27`` | channel i's 27 features at ``[G + 27 i, G + 27 (i + 1))`` (:data:`envs.channel_features.CHANNEL_FEATURES`), G the global block's size |
| mask | ``C`` | 1 where channel i carries a satellite at the coming epoch, 0 where it is empty (its features are 0) |

The 27 features of a channel (:mod:`envs.channel_features`):

| idx | name | range | meaning |
|---|---|---|---|
| 0 | cn0 | 0-1.5 | C/N0 [dB-Hz] / 50 at the coming epoch (0 where the data set has none) |
| 1 | elevation | 0-1 | elevation / 90 deg at the coming epoch |
| 2-6 | sys_gps ... sys_other | 0-1 | one-hot system: GPS, GLONASS, Galileo, BeiDou, other (QZSS, SBAS) |
| 7 | tracked | 0-5 | log10(1 + consecutive epochs the satellite was used up to the last update); 0: new or reacquired |
| 8 | last_action | -1-1 | the action applied to this satellite at its last update (the default action for a new one) |
| 9 + 6 l + 0 | z_pr_l | -10-10 | asinh(dz_i / sqrt(S_ii)), the pseudorange's normalized innovation l updates ago (l = 0, 1, 2; 0 where the method excluded the row) |
| 9 + 6 l + 1 | z_prr_l | -10-10 | the same for the pseudorange rate (0 without Doppler) |
| 9 + 6 l + 2 | w_pr_l | -10-10 | asinh of the pseudorange's normalized deleted residual of that epoch's snapshot fit (0 below 5 satellites) |
| 9 + 6 l + 3 | w_prr_l | -10-10 | the same for the rate |
| 9 + 6 l + 4 | log_scale_l | -2-6 | log10 of the law's pseudorange variance scale of the satellite (per-satellite laws; 0 otherwise) |
| 9 + 6 l + 5 | cn0_then_l | 0-1.5 | C/N0 / 50 at that update |

The observation describes the channels of the *coming* epoch (the one the next action applies to): what the
receiver reports there, and what the filter made of each satellite at its last three updates. Only quantities
the receiver and the filter have enter it, never the truth. The features are scaled to about unit size, so the
policies of :mod:`agents.set_policy` take them without running normalization (``train.py rl`` does not normalize
these observations; a per-slot normalization would also break the channels' symmetry).

## Rewards

As the scalar envs (``reward``): ``'horizontal'`` (default) ``-horizontal error [m]`` after the epoch's update,
``'log'``, ``'3d'``, ``'advantage'`` (a reference filter with no inflation / every satellite at the row's ``b``,
minus the agent's), the divergence penalty ``-divergence_bound_m``. No reward uses per-satellite truth.

## Starting State, Episode End

As :mod:`envs.gnss_ins_env` (world seeds, divergence, truncation at ``episode_length_s``,
``info["episode_metrics"]``). ``info`` adds ``mean_action`` (mean action over the used channels).

## Arguments

Those of the scalar envs (:class:`envs.config.EnvConfig`) plus ``channels`` (int or None): the action's and the
observation's channel count; a world with fewer channels is padded with empty ones, one with more raises
``ValueError`` at reset. The vector env (``gym.make_vec(..., vectorization_mode="vector_entry_point")``) takes
``num_envs``, ``prefetch_worlds`` and ``parallel_kernels``; row i of a vector env seeded s is the single env seeded
s + i.

## Version History

* v0: initial version.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from nav_filters.measurements import N_SAT_KEYS
from nav_filters.kernels import row_kernel

from .channel_features import (CHANNEL_FEATURES, CHANNEL_HISTORY, N_CHANNEL_FEATURES, N_LAGGED, commit_epoch_parallel,
                               commit_epoch_serial, observation_parallel, observation_serial)
from .config import EnvConfig, ParamSpec
from .core import TuningCore
from .gnss_ins_env import SAGE_HUSA_PARAMS, GnssInsTuningEnv
from .prepared import CHANNEL_ARRAY_NAMES, WORLD_ARRAY_NAMES, PreparedWorld

INFLATION_SPEC = ParamSpec("log10_inflation", 0.0, 4.0, "linear", 0.0,
                           "base-10 log of the inflation of a channel's reported variances (x1 to x10^4)")
"""SatelliteR's channel action: ``log10`` of the factor on the reported pseudorange and rate variances."""
SATELLITE_B_SPEC = dataclasses.replace(SAGE_HUSA_PARAMS[0], description="a satellite's Sage-Husa forgetting factor")
"""SatelliteSageHusa's channel action: the b of ``GnssIns/SageHusa-v1``, per satellite."""
MAX_CHANNELS = 128
"""Most channels of a per-satellite env (``channels``)."""


@dataclass(frozen=True)
class SatelliteEnvConfig(EnvConfig):
    """:class:`~envs.config.EnvConfig` plus ``channels``: the action's and observation's channel count (None:
    the scenario's receiver channels; a recording's own count), an int in [1, :data:`MAX_CHANNELS`]."""

    channels: int | None = None

    def __post_init__(self):
        super().__post_init__()
        c = self.channels
        if c is not None and (isinstance(c, bool) or not isinstance(c, (int, np.integer))
                              or not 1 <= c <= MAX_CHANNELS):
            raise ValueError(f"SatelliteEnvConfig.channels must be None or an int in [1, {MAX_CHANNELS}], got {c!r}")


_RECORDED_CHANNELS: dict = {}


def default_channels(config: EnvConfig) -> int:
    """The channel count of ``config``'s worlds: the simulated receiver's, or a recording's (read once)."""
    from .datasets.spec import ReplayScenario
    scen = config.resolve_scenario()
    if not isinstance(scen, ReplayScenario):
        return int(scen.receiver.n_channels)
    key = (repr(scen), config.imu_grade, float(config.episode_length_s))
    if key not in _RECORDED_CHANNELS:
        _RECORDED_CHANNELS[key] = int(config.make_world([0]).gnss.pr.shape[2])
    return _RECORDED_CHANNELS[key]


def pad_channels(prepared: PreparedWorld, C: int) -> PreparedWorld:
    """``prepared`` with its channel axis padded to ``C`` empty channels (mask False, key -1, unit sigmas)."""
    a = prepared.arrays
    Cw = a["pr"].shape[2]
    if Cw == C:
        return prepared
    if Cw > C:
        raise ValueError(f"the world has {Cw} receiver channels, the env {C}: pass channels={Cw} (or more)")
    fill = {"gmask": False, "sat_keys": -1, "pr_sigma": 1.0, "prr_sigma": 1.0}
    out = dict(a)
    for name in ("sat_pos", "sat_vel", "pr", "prr", "pr_sigma", "prr_sigma", "gmask", "sat_keys") + CHANNEL_ARRAY_NAMES:
        x = a[name]
        pad = [(0, 0)] * x.ndim
        pad[2] = (0, C - Cw)
        out[name] = np.pad(x, pad, constant_values=fill.get(name, 0))
    return dataclasses.replace(prepared, arrays=out)


class SatelliteCore(TuningCore):
    """B episodes of a per-satellite env in one batched navigator (:class:`~envs.core.TuningCore` with one action
    component per channel and the channel block of the observation; module docstring).

    Parameters
    ----------
    config : :class:`SatelliteEnvConfig` (or an :class:`~envs.config.EnvConfig`: the default channels).
    knob : ``'inflation'`` (SatelliteR) or ``'b'`` (SatelliteSageHusa).
    batch_size : B.
    """

    WORLD_ARRAYS = WORLD_ARRAY_NAMES + CHANNEL_ARRAY_NAMES
    SHARED_ATTRS = TuningCore.SHARED_ATTRS | {"spec", "ch_low", "ch_high", "knob"}

    def __init__(self, config: EnvConfig, knob: str, batch_size: int):
        if knob not in ("inflation", "b"):
            raise ValueError(f"knob must be 'inflation' or 'b', got {knob!r}")
        super().__init__(config, (), batch_size)
        self.knob = knob
        self.spec = INFLATION_SPEC if knob == "inflation" else SATELLITE_B_SPEC
        if knob == "b":
            check_satellite_b_method(config.method)
        C = getattr(config, "channels", None) or default_channels(config)
        self.n_channels = self.action_dim = int(C)
        self.default_channel_action = float(self.spec.to_action(self.spec.default))
        lo = np.array([f[1] for f in CHANNEL_FEATURES], np.float32)
        hi = np.array([f[2] for f in CHANNEL_FEATURES], np.float32)
        self.ch_low, self.ch_high = lo, hi
        self.global_dim = self.obs_dim
        self.obs_low = np.concatenate([self.obs_low, np.tile(lo, C), np.zeros(C, np.float32)])
        self.obs_high = np.concatenate([self.obs_high, np.tile(hi, C), np.ones(C, np.float32)])
        self.obs_dim = self.obs_low.size

    # ------------------------------------------------------------------ reset
    def _make_nav(self, world, method):
        from .episodes import navigator_for
        return navigator_for(world, method, dtype=self.config.dtype, exact_transition=self.config.exact_transition,
                             fused_update=self.config.fused_update)

    def _set_params(self, nav, action=None):
        """The row parameters stay at the method's defaults (SatelliteSageHusa: ``b`` = 0.98 on every row)."""
        if self.knob == "b":
            nav.form.set_params(b=self.spec.default)
        return {}

    def reset_rows(self, rows, seeds, prepared: PreparedWorld | None = None, coming=None) -> np.ndarray:
        if prepared is None and coming is not None:
            prepared = self.worlds_ahead.take([int(s) for s in seeds], coming)
        if prepared is None:
            from .prepared import prepare_world
            prepared = prepare_world(self.config, seeds, buffers=self.world_buffers)
        return super().reset_rows(rows, seeds, pad_channels(prepared, self.n_channels))

    def _alloc(self, prepared: PreparedWorld):
        super()._alloc(prepared)
        B, M, C = self.B, self.M, self.C
        self.sat_el = np.zeros((B, M, C))
        self.sat_cn0 = np.zeros((B, M, C))
        self.ch_keys = np.full((B, C), -1, np.int64)
        self.ch_hist = np.zeros((B, C, CHANNEL_HISTORY, N_LAGGED))
        self.ch_count = np.zeros((B, C), np.int64)
        self.ch_act = np.zeros((B, C))
        self.ch_action = np.zeros((B, C))  # the step's actions (clipped)
        self.sigma_scale = np.ones((B, C))
        self.upd_epoch = np.zeros(B, np.int64)

    def _reset_extra(self, rows) -> None:
        self.ch_keys[rows] = -1
        self.ch_hist[rows] = 0.0
        self.ch_count[rows] = 0
        self.ch_act[rows] = 0.0
        self.ch_action[rows] = self.default_channel_action
        self.sigma_scale[rows] = 1.0

    # ------------------------------------------------------------------- step
    def _apply_action(self, a) -> dict:
        """Map the (B, C) channel actions onto this epoch's channels: SatelliteR scales the reported sigmas by
        ``10^(v / 2)``, SatelliteSageHusa writes each satellite's b to its pseudorange and rate keys."""
        self.ch_action[:] = a
        B = self.B
        self.upd_epoch[:] = np.minimum(self.t, self.M - 1)
        v = self.spec.to_value(a)
        if self.knob == "inflation":
            self.sigma_scale = 10.0 ** (0.5 * v)
        else:
            keys = self.sat_keys[np.arange(B), self.upd_epoch]
            mkeys = np.concatenate([keys, np.where(keys >= 0, keys + N_SAT_KEYS, -1)], 1)
            self.nav.form.set_satellite_params(mkeys, np.concatenate([v, v], 1))
        return {}

    def _gnss_inputs(self, nav, rows, jj) -> tuple:
        g = super()._gnss_inputs(nav, rows, jj)
        if self.knob != "inflation" or nav is not self.nav:
            return g
        s = self.sigma_scale
        return g[:4] + (g[4] * s, None if g[5] is None else g[5] * s, g[6])

    def _frame(self, res, zflag):
        out = super()._frame(res, zflag)
        self._commit_channels(res)
        return out

    def _commit_channels(self, res) -> None:
        """The statistics of the epoch just updated onto each used channel's satellite history (one compiled call,
        :func:`~envs.channel_features.commit_epoch_serial`, on the world's arrays at each row's updated epoch)."""
        nav = self.nav
        with_rate = bool(nav.config.use_pseudorange_rate and self.has_rate)
        mask = np.ascontiguousarray(self._last_mask, bool)
        kern, nchunk = row_kernel(commit_epoch_serial, commit_epoch_parallel, self.B)
        c = np.ascontiguousarray
        kern(self.upd_epoch, self.sat_keys, self.sat_cn0, self.sat_pos, self.sat_vel, self.pr, self.prr, self.pr_sigma,
             self.prr_sigma, c(nav.r), c(nav.v), c(nav.clk), c(nav.drift), mask, with_rate, c(res.innovation),
             c(res.innovation_var), self._law_scales(mask), self.ch_action, self.ch_keys, self.ch_hist, self.ch_count,
             self.ch_act, nchunk)

    def _law_scales(self, mask) -> np.ndarray:
        """(B, C) the per-satellite law's pseudorange variance scales after the update (1 without such a law) of
        the channels ``mask`` used at the updated epoch."""
        get = getattr(self.nav.form, "satellite_scales", None)
        if get is None:
            return np.ones(mask.shape)
        keys = self.sat_keys[np.arange(self.B), self.upd_epoch]
        try:
            return np.ascontiguousarray(get(np.where(mask, keys, -1)), np.float64)
        except ValueError:  # a law whose per-satellite mode is off
            return np.ones(mask.shape)

    def _observation(self, rows=None) -> np.ndarray:
        rows = np.arange(self.B) if rows is None else np.asarray(rows, np.intp)
        n = rows.size
        out = np.empty((n, self.obs_dim), np.float32)
        G = self.global_dim
        out[:, :G] = self.frames[rows].reshape(n, G)
        epoch = np.minimum(self.t[rows], self.M - 1)
        kern, nchunk = row_kernel(observation_serial, observation_parallel, n)
        kern(rows.astype(np.int64), epoch, self.gmask, self.sat_keys, self.sat_cn0, self.sat_el, self.ch_keys,
             self.ch_hist, self.ch_count, self.ch_act, self.default_channel_action, self.ch_low, self.ch_high,
             out[:, G:], nchunk)
        return out

    def step(self, actions):
        res = super().step(actions)
        m = self._last_mask
        n = np.maximum(m.sum(1), 1)
        res.info["mean_action"] = np.where(m, self.ch_action, 0.0).sum(1) / n
        return res

    def channel_view(self, obs) -> tuple:
        """Split observations (..., obs_dim) into ``(global (..., G), channels (..., C, F), mask (..., C))``."""
        obs = np.asarray(obs)
        G, C, F = self.global_dim, self.n_channels, N_CHANNEL_FEATURES
        lead = obs.shape[:-1]
        return obs[..., :G], obs[..., G:G + C * F].reshape(lead + (C, F)), obs[..., G + C * F:]


def check_satellite_b_method(method: str) -> None:
    """``ValueError`` unless ``method`` takes a per-satellite forgetting factor (a per-satellite Sage-Husa law)."""
    from nav_filters.registry import ADAPTIVE_METHODS, make_form
    P0 = np.eye(17)[None]
    try:
        make_form(method, P0).set_satellite_params(np.zeros((1, 1), np.int64), np.full((1, 1), 0.98))
    except (ValueError, AttributeError):
        fits = [m for m in sorted(ADAPTIVE_METHODS) if _takes_satellite_b(m)]
        raise ValueError(f"method {method!r} takes no per-satellite forgetting factor; methods that do: "
                         f"{', '.join(fits)} (optionally with '+fde' and/or '+onestep')") from None


def _takes_satellite_b(method: str) -> bool:
    from nav_filters.registry import make_form
    try:
        make_form(method, np.eye(17)[None]).set_satellite_params(np.zeros((1, 1), np.int64), np.ones((1, 1)))
    except (ValueError, AttributeError):
        return False
    return True


class SatelliteEnv(GnssInsTuningEnv):
    """Base class of the per-satellite environments (module docstring)."""

    CONFIG = SatelliteEnvConfig
    PARAMS = ()  # no scalar parameter: the action is per channel
    KNOB = "inflation"

    @classmethod
    def core_for(cls, config, batch_size: int) -> SatelliteCore:
        return SatelliteCore(config, cls.KNOB, batch_size)


class SatelliteREnv(SatelliteEnv):
    """``GnssIns/SatelliteR-v0``: per channel, log10 of the inflation of the reported variances in [0, 4]."""

    KNOB = "inflation"
    DEFAULTS = {"method": "kf"}


class SatelliteSageHusaEnv(SatelliteEnv):
    """``GnssIns/SatelliteSageHusa-v0``: per channel, the forgetting factor of its satellite's Sage-Husa R
    recursion in [0.30, 0.9999]."""

    KNOB = "b"
    DEFAULTS = {"method": "sage-husa"}


@dataclass(frozen=True)
class ChannelLayout:
    """Where the blocks of a per-satellite observation lie (module docstring): ``global_dim`` values of the
    global frames, then ``channels`` x ``features`` channel features (channel-major), then ``channels`` mask values."""

    global_dim: int
    channels: int
    features: int

    @property
    def size(self) -> int:
        return self.global_dim + self.channels * (self.features + 1)


def channel_layout(space, channels: int | None = None) -> ChannelLayout:
    """The :class:`ChannelLayout` of a per-satellite env's observation space (a flat ``Box``), found from its size
    and bounds (``channels`` pins the channel count; ``ValueError`` when the space is not such an observation or,
    without ``channels``, fits more than one layout)."""
    from .core import OBS_FEATURES
    from .config import MAX_HISTORY
    shape = getattr(space, "shape", None)
    if shape is None or len(shape) != 1:
        raise ValueError(f"a per-satellite observation is a flat Box, got {space!r}")
    D, F, f = int(shape[0]), N_CHANNEL_FEATURES, len(OBS_FEATURES)
    lo, hi = np.asarray(space.low, np.float32), np.asarray(space.high, np.float32)
    frame_lo = np.array([x[1] for x in OBS_FEATURES], np.float32)
    ch_lo = np.array([x[1] for x in CHANNEL_FEATURES], np.float32)
    fits = []
    for C in ([channels] if channels else range(1, MAX_CHANNELS + 1)):
        G = D - C * (F + 1)
        if G <= 0 or G % f or G // f > MAX_HISTORY:
            continue
        if (np.array_equal(lo[:G], np.tile(frame_lo, G // f)) and np.array_equal(lo[G:G + C * F], np.tile(ch_lo, C))
                and np.all(lo[G + C * F:] == 0) and np.all(hi[G + C * F:] == 1)):
            fits.append(ChannelLayout(G, C, F))
    if len(fits) != 1:
        raise ValueError(f"observation space of size {D} is {'ambiguous' if fits else 'not'} a per-satellite "
                         f"observation{' (pass channels=)' if fits else ''}")
    return fits[0]
