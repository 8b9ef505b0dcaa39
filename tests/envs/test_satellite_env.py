"""The per-satellite environments (GnssIns/SatelliteR-v0, GnssIns/SatelliteSageHusa-v0): layout, channel symmetry,
the mapping of channel actions onto satellites, agreement with the scalar env, recorded worlds, bad input.

(The checkers and seeded determinism run for every id in test_envs.py, vector = single there too.)"""
import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)
from envs.channel_features import (CHANNEL_FEATURES, CHANNEL_HISTORY, N_CHANNEL_FEATURES, N_LAGGED, N_STATIC,
                                   commit_epoch_parallel, commit_epoch_serial, commit_serial,
                                   snapshot_deleted_residuals)
from envs.core import OBS_FEATURES
from envs.datasets.errors import shared_data_dir
from envs.gnss_ins_env import SAGE_HUSA_PARAMS
from envs.satellite_env import SatelliteCore, SatelliteEnvConfig
from nav_filters.measurements import gnss_innovations

IDS = ("GnssIns/SatelliteR-v0", "GnssIns/SatelliteSageHusa-v0")
DATA = shared_data_dir()
LAG0 = N_STATIC  # first lagged feature (z_pr of the last update)


def _core(knob, B=1, **kw):
    cfg = SatelliteEnvConfig(**{"method": "kf" if knob == "inflation" else "sage-husa", "episode_length_s": 12.0,
                                **kw})
    return SatelliteCore(cfg, knob, B)


@pytest.mark.parametrize("env_id", IDS)
def test_spaces_and_layout(env_id):
    env = gym.make(env_id, episode_length_s=6.0, history=2)
    C = env.unwrapped.core.n_channels
    assert C == 16  # the simulated receiver's channels
    assert env.action_space.shape == (C,) and env.action_space.low.min() == -1 and env.action_space.high.max() == 1
    G = 2 * len(OBS_FEATURES)
    assert env.observation_space.shape == (G + C * N_CHANNEL_FEATURES + C,)
    assert N_CHANNEL_FEATURES == N_STATIC + CHANNEL_HISTORY * N_LAGGED == len(CHANNEL_FEATURES)
    obs, _ = env.reset(seed=3)
    g, ch, m = env.unwrapped.core.channel_view(obs)
    assert g.shape == (G,) and ch.shape == (C, N_CHANNEL_FEATURES) and set(np.unique(m)) <= {0.0, 1.0}
    assert m.sum() >= 4 and np.all(ch[m == 0] == 0)
    assert np.all(ch[m > 0, 2:7].sum(1) == 1)  # one system each
    assert np.all(ch[m > 0, LAG0:] == 0) and np.all(ch[m > 0, 7] == 0)  # nothing tracked before the first update
    for t in range(5):
        obs, r, te, tr, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs) and np.isfinite(r) and "mean_action" in info
    g, ch, m = env.unwrapped.core.channel_view(obs)
    assert np.any(ch[m > 0, LAG0] != 0) and np.any(ch[m > 0, LAG0 + 2] != 0)  # innovations, deleted residuals
    assert np.all(ch[m > 0, 7] > 0)  # tracked (no satellite rose in 6 s of this world)


def test_history_follows_the_satellite_across_channels():
    """The lag-1 features of a satellite at step t + 1 are its lag-0 features at step t, whichever channels it
    occupied (the simulated receiver orders its channels by elevation)."""
    core = _core("inflation", B=2, scenario="urban", episode_length_s=40.0)
    obs = core.reset_rows(np.arange(2), [11, 12])
    rng = np.random.default_rng(0)
    moved = 0
    prev = None
    for t in range(30):
        e = np.minimum(core.t, core.M - 1)
        keys = core.sat_keys[np.arange(2), e]  # the channels the observation describes
        _, ch, m = core.channel_view(obs)
        if prev is not None:
            pkeys, pch, pm = prev
            for b in range(2):
                for i in np.flatnonzero(m[b] > 0):
                    j = np.flatnonzero((pkeys[b] == keys[b, i]) & (pm[b] > 0))
                    if j.size and ch[b, i, 7] > 0:  # seen at both updates
                        lag1 = ch[b, i, LAG0 + N_LAGGED:LAG0 + 2 * N_LAGGED]
                        np.testing.assert_array_equal(lag1, pch[b, j[0], LAG0:LAG0 + N_LAGGED])
                        moved += int(j[0] != i)
        prev = (keys, ch, m)
        obs = core.step(rng.uniform(-1, 1, (2, core.n_channels))).obs
    assert moved > 0  # the test saw satellites change channels


def _permuted_core(knob, perm, seeds, **kw):
    """A core whose world has its channels permuted by ``perm`` at every epoch (the same satellites)."""
    core = _core(knob, B=len(seeds), **kw)
    core.reset_rows(np.arange(len(seeds)), seeds)
    for name in ("sat_pos", "sat_vel", "pr", "prr", "pr_sigma", "prr_sigma", "gmask", "sat_keys", "sat_el",
                 "sat_cn0"):
        setattr(core, name, getattr(core, name)[:, :, perm].copy())
    return core, core._observation()


@pytest.mark.parametrize("knob,method", [("inflation", "kf"), ("inflation", "sage-husa+fde"), ("b", "sage-husa")])
def test_channel_order_carries_no_meaning(knob, method):
    """The same world with its channels permuted, given the correspondingly permuted actions, gives the same
    trajectory (to rounding) and the correspondingly permuted observations."""
    seeds = [5, 6]
    kw = dict(scenario="urban", episode_length_s=30.0, method=method)
    C = 16
    perm = np.random.default_rng(1).permutation(C)
    a, obs_a = _permuted_core(knob, np.arange(C), seeds, **kw)
    b, obs_b = _permuted_core(knob, perm, seeds, **kw)
    rng = np.random.default_rng(2)
    for t in range(25):
        _, ch_a, m_a = a.channel_view(obs_a)
        _, ch_b, m_b = b.channel_view(obs_b)
        np.testing.assert_array_equal(m_b, m_a[:, perm])
        np.testing.assert_allclose(ch_b, ch_a[:, perm], rtol=1e-4, atol=2e-4)
        act = rng.uniform(-1, 1, (2, C))
        ra, rb = a.step(act), b.step(act[:, perm])
        np.testing.assert_allclose(rb.info["horizontal_error_m"], ra.info["horizontal_error_m"], rtol=1e-6,
                                   atol=1e-6)
        obs_a, obs_b = ra.obs, rb.obs
    np.testing.assert_allclose(b.nav.r, a.nav.r, rtol=0, atol=1e-5)


def test_actions_of_empty_channels_are_ignored():
    core_a, core_b = _core("inflation", B=2), _core("inflation", B=2)
    for c in (core_a, core_b):
        c.reset_rows(np.arange(2), [7, 8])
    rng = np.random.default_rng(3)
    for t in range(10):
        act = rng.uniform(-1, 1, (2, 16))
        e = np.minimum(core_a.t, core_a.M - 1)
        empty = ~core_a.gmask[np.arange(2), e]
        assert empty.any()
        other = np.where(empty, rng.uniform(-1, 1, (2, 16)), act)
        ra, rb = core_a.step(act), core_b.step(other)
        np.testing.assert_array_equal(ra.info["horizontal_error_m"], rb.info["horizontal_error_m"])
        np.testing.assert_array_equal(ra.obs, rb.obs)


@pytest.mark.parametrize("b", [0.5, 0.98])
def test_one_b_on_every_satellite_is_the_scalar_sage_husa_env(b):
    """Every channel at b gives GnssIns/SageHusa-v1 at b (the per-key b replaces the row's in the satellites'
    recursions; the row's b is the scalar env's default, so at 0.98 the two laws are the same): to 1e-9, not bit
    for bit, since the scalar env's row b is the float32 action's 0.98 (0.98 + 4.8e-10) where the per-satellite env
    keeps the default 0.98 for the Q law, which never applies less than the nominal Q and so uses it."""
    a_b = float(SAGE_HUSA_PARAMS[0].to_action(b))
    kw = dict(episode_length_s=20.0, scenario="urban")
    sat = gym.make("GnssIns/SatelliteSageHusa-v0", **kw)
    ref = gym.make("GnssIns/SageHusa-v1", **kw)
    o_s, _ = sat.reset(seed=4)
    o_r, _ = ref.reset(seed=4)
    for t in range(20):
        o_s, r_s, *_ = sat.step(np.full(16, a_b, np.float32))
        o_r, r_r, *_ = ref.step(np.array([a_b], np.float32))
        if b == 0.98:
            assert r_s == pytest.approx(r_r, rel=1e-9)
            np.testing.assert_allclose(o_s[:len(OBS_FEATURES)], o_r[1:], rtol=1e-6, atol=1e-6)
    if b != 0.98:  # the row's b (0.98) still drives the Q law: close, not equal
        assert r_s != r_r and abs(r_s - r_r) < 1.0


def test_satellite_r_without_inflation_is_the_method_itself():
    kw = dict(episode_length_s=15.0, scenario="noise-burst")
    sat = gym.make("GnssIns/SatelliteR-v0", method="sage-husa", **kw)
    ref = gym.make("GnssIns/SageHusa-v1", **kw)
    sat.reset(seed=9)
    ref.reset(seed=9)
    for t in range(15):
        _, r_s, *_ = sat.step(-np.ones(16, np.float32))  # x1 on every channel
        _, r_r, *_ = ref.step(np.array([SAGE_HUSA_PARAMS[0].to_action(0.98)]))  # float64: b = 0.98 exactly
        assert r_s == r_r


def test_inflating_a_channel_is_a_larger_reported_sigma():
    """SatelliteR's action v on a channel is the world's reported sigma times 10^(v/2) (pseudorange and rate)."""
    core, twin = _core("inflation", B=1, scenario="urban"), _core("inflation", B=1, scenario="urban")
    core.reset_rows(np.arange(1), [21])
    twin.reset_rows(np.arange(1), [21])
    act = np.full((1, 16), -1.0)
    act[0, 2] = 0.5  # log10 inflation 3: sigma x 10^1.5
    for t in range(8):
        twin.pr_sigma[0, t, 2] *= 10 ** 1.5
        twin.prr_sigma[0, t, 2] *= 10 ** 1.5
        ra, rb = core.step(act), twin.step(-np.ones((1, 16)))
        np.testing.assert_array_equal(ra.info["horizontal_error_m"], rb.info["horizontal_error_m"])


def test_the_deleted_residual_kernel_matches_its_numpy_specification():
    rng = np.random.default_rng(5)
    B, C = 3, 9
    az, el = rng.uniform(0, 2 * np.pi, (B, C)), rng.uniform(0.2, 1.4, (B, C))
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    mask = rng.uniform(size=(B, C)) < 0.8
    mask[0] = True
    mask[2, :5] = False  # a row with at most 4 satellites: no statistic
    keys = np.where(mask, np.arange(C), -1).astype(np.int64)
    resid = rng.normal(size=(B, 2 * C)) * 3
    resid[0, 1] += 40  # an outlier
    pr_var, prr_var = rng.uniform(1, 9, (B, C)), rng.uniform(0.01, 0.1, (B, C))
    st = dict(ch_keys=np.full((B, C), -1, np.int64), ch_hist=np.zeros((B, C, CHANNEL_HISTORY, N_LAGGED)),
              ch_count=np.zeros((B, C), np.int64), ch_act=np.zeros((B, C)))
    commit_serial(mask, keys, np.full((B, C), 45.0), resid, np.ones((B, 2 * C)), resid, u, pr_var, prr_var, True,
                  np.ones((B, C)), np.zeros((B, C)), st["ch_keys"], st["ch_hist"], st["ch_count"], st["ch_act"], 1)
    for b in range(B):
        w_pr = snapshot_deleted_residuals(resid[b, :C], u[b], pr_var[b], mask[b])
        w_prr = snapshot_deleted_residuals(resid[b, C:], u[b], prr_var[b], mask[b])
        np.testing.assert_allclose(st["ch_hist"][b, :, 0, 2], np.where(mask[b], np.arcsinh(w_pr), 0), atol=1e-9)
        np.testing.assert_allclose(st["ch_hist"][b, :, 0, 3], np.where(mask[b], np.arcsinh(w_prr), 0), atol=1e-9)
    assert np.argmax(np.abs(st["ch_hist"][0, :, 0, 2])) == 1  # the outlier has the largest statistic
    assert np.all(st["ch_hist"][2, :, 0, 2] == 0)


def _channel_state(B, C):
    return dict(ch_keys=np.full((B, C), -1, np.int64), ch_hist=np.zeros((B, C, CHANNEL_HISTORY, N_LAGGED)),
                ch_count=np.zeros((B, C), np.int64), ch_act=np.zeros((B, C)))


@pytest.mark.parametrize("with_rate", [True, False])
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_commit_at_the_epochs_equals_the_gathered_chain(with_rate, dtype):
    """The env's commit (one kernel on the world arrays at each row's epoch) gives the bits of the chain it replaced:
    the epoch gathered per row, ``gnss_innovations`` at the corrected state and ``commit_serial``; serial and in
    parallel chunks, over three updates (the histories shift), with and without rate rows, in both filter dtypes."""
    rng = np.random.default_rng(11)
    B, M, C = 5, 4, 9
    r = rng.normal(size=(B, 3)) * 10 + np.array([4.0e6, 3.0e5, 4.9e6])
    los = rng.normal(size=(B, M, C, 3))
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    sat_pos = r[:, None, None] + 2.2e7 * los
    sat_vel = rng.normal(size=(B, M, C, 3)) * 3e3
    pr = np.linalg.norm(sat_pos - r[:, None, None], axis=-1) + rng.normal(size=(B, M, C)) * 5
    prr, pr_sigma, prr_sigma = rng.normal(size=(B, M, C)) * 300, rng.uniform(1, 9, (B, M, C)), \
        rng.uniform(0.05, 0.3, (B, M, C))
    sat_keys = rng.integers(-1, 12, (B, M, C))
    sat_cn0 = rng.uniform(25, 50, (B, M, C))
    m = 2 * C if with_rate else C
    got = [_channel_state(B, C) for _ in range(3)]
    for t in range(3):
        epoch = rng.integers(0, M, B)
        mask = rng.uniform(size=(B, C)) < 0.85
        mask[0, :5] = False  # at most 4 satellites of a type: no deleted residual
        nav = [(rng.normal(size=(B, 3)) + r).astype(dtype), rng.normal(size=(B, 3)).astype(dtype),
               rng.normal(size=B).astype(dtype) * 30, rng.normal(size=B).astype(dtype)]
        innov, S = rng.normal(size=(B, m)).astype(dtype), rng.uniform(1, 4, (B, m)).astype(dtype)
        scale, act = rng.uniform(0.5, 20, (B, C)), rng.uniform(-1, 1, (B, C))
        rows = np.arange(B)
        pr_var, prr_var = np.square(pr_sigma[rows, epoch]), np.square(prr_sigma[rows, epoch])
        resid, _, _, _, u = gnss_innovations(*nav, sat_pos[rows, epoch], sat_vel[rows, epoch], pr[rows, epoch],
                                             prr[rows, epoch] if with_rate else None, pr_var,
                                             prr_var if with_rate else None, mask, use_rate=with_rate)
        ref = got[0]
        commit_serial(mask, sat_keys[rows, epoch], sat_cn0[rows, epoch], innov, S, resid, u, pr_var,
                      prr_var if with_rate else pr_var, with_rate, scale, act, ref["ch_keys"], ref["ch_hist"],
                      ref["ch_count"], ref["ch_act"], 1)
        for st, kern, nchunk in ((got[1], commit_epoch_serial, 1), (got[2], commit_epoch_parallel, 2)):
            kern(epoch, sat_keys, sat_cn0, sat_pos, sat_vel, pr, prr, pr_sigma, prr_sigma, *nav, mask, with_rate,
                 innov, S, scale, act, st["ch_keys"], st["ch_hist"], st["ch_count"], st["ch_act"], nchunk)
        for st in got[1:]:
            for k in ref:
                np.testing.assert_array_equal(st[k], ref[k], err_msg=k)
    assert np.count_nonzero(got[0]["ch_hist"][:, :, 0, 2]) > 10  # deleted residuals were formed
    assert np.count_nonzero(got[0]["ch_count"] > 1) > 0  # and histories carried over


@pytest.mark.parametrize("env_id", IDS)
def test_float32(env_id):
    env = gym.make(env_id, episode_length_s=12.0, dtype="float32", scenario="urban")
    env.reset(seed=1)
    for t in range(12):
        obs, r, te, tr, _ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs) and np.isfinite(r) and not te
    assert tr


def test_copy_rows_branches_exactly():
    core = _core("b", B=3, scenario="urban")
    core.reset_rows(np.arange(3), [1, 2, 3])
    rng = np.random.default_rng(4)
    for t in range(4):
        core.step(rng.uniform(-1, 1, (3, 16)))
    core.copy_rows([2], [0])
    act = rng.uniform(-1, 1, (1, 16))
    for t in range(4):
        res = core.step(np.concatenate([act, rng.uniform(-1, 1, (1, 16)), act]))
        np.testing.assert_array_equal(res.obs[2], res.obs[0])
        assert res.reward[2] == res.reward[0]


@pytest.mark.parametrize("spec", ["smartloc-potsdamer-platz", "instinct-reach-static"])
@pytest.mark.parametrize("env_id", IDS)
def test_recorded_worlds(env_id, spec):
    folder = "smartloc" if spec.startswith("smartloc") else "instinct_tckf_static"
    if not (DATA / folder).is_dir():
        pytest.skip(f"recorded data set {folder} not in {DATA}")
    env = gym.make(env_id, scenario=spec, episode_length_s=8.0)
    C = env.unwrapped.core.n_channels
    assert C == env.action_space.shape[0] and C >= 5  # the recording's channel count
    obs, _ = env.reset(seed=0)
    for t in range(10):
        obs, r, te, tr, _ = env.step(env.action_space.sample())
        assert env.observation_space.contains(obs) and np.isfinite(r)
    _, ch, m = env.unwrapped.core.channel_view(obs)
    assert m.sum() >= 4 and np.all(ch[m > 0, 0] > 0.4)  # the recording's C/N0
    wide = gym.make(env_id, scenario=spec, episode_length_s=8.0, channels=C + 5)  # padded with empty channels
    obs, _ = wide.reset(seed=0)
    assert wide.action_space.shape == (C + 5,) and wide.unwrapped.core.channel_view(obs)[2][C:].sum() == 0
    wide.step(wide.action_space.sample())


def test_bad_input_is_a_clear_error():
    env = gym.make("GnssIns/SatelliteR-v0", episode_length_s=4.0)
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(16,\)"):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="NaN or inf"):
        env.step(np.full(16, np.nan, np.float32))
    with pytest.raises(ValueError, match="channels must be None or an int"):
        gym.make("GnssIns/SatelliteR-v0", channels=0)
    with pytest.raises(ValueError, match="takes no per-satellite forgetting factor; methods that do: .*sage-husa"):
        gym.make("GnssIns/SatelliteSageHusa-v0", method="kf")
    few = gym.make("GnssIns/SatelliteR-v0", episode_length_s=4.0, channels=8)
    with pytest.raises(ValueError, match="pass channels=16"):
        few.reset(seed=0)
    with pytest.raises(ValueError, match="unknown environment argument"):
        gym.make("GnssIns/SatelliteR-v0", channel=3)
