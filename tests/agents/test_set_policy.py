"""The permutation-equivariant set policies of agents/set_policy.py: channel permutations permute the actions, an
empty channel changes no other action, the heads keep one distribution per channel, and train.py rl trains them."""
import numpy as np
import pytest
import torch as th

from agents.set_policy import ChannelSetPolicy, ChannelSetRecurrentPolicy, ChannelSetSACPolicy
from envs.satellite_env import SatelliteCore, SatelliteEnvConfig, channel_layout


def _spaces(history=1, channels=None):
    from gymnasium import spaces
    core = SatelliteCore(SatelliteEnvConfig(method="kf", history=history, channels=channels), "inflation", 1)
    obs = spaces.Box(core.obs_low, core.obs_high, dtype=np.float32)
    act = spaces.Box(-1.0, 1.0, shape=(core.action_dim,), dtype=np.float32)
    return obs, act, channel_layout(obs)


def _observations(obs_space, layout, n, rng, empty=(3, 7)):
    """``n`` random observations inside the bounds, channels ``empty`` (and a few random ones) without satellites."""
    lo, hi = obs_space.low, obs_space.high
    o = rng.uniform(np.maximum(lo, -3), np.minimum(hi, 3), (n,) + lo.shape).astype(np.float32)
    G, C, F = layout.global_dim, layout.channels, layout.features
    mask = rng.uniform(size=(n, C)) < 0.8
    mask[:, list(empty)] = False
    ch = o[:, G:G + C * F].reshape(n, C, F)
    ch[~mask] = 0.0
    o[:, G + C * F:] = mask
    return o, mask


def _permute(o, layout, perm):
    G, C, F = layout.global_dim, layout.channels, layout.features
    p = o.copy()
    p[:, G:G + C * F] = o[:, G:G + C * F].reshape(-1, C, F)[:, perm].reshape(-1, C * F)
    p[:, G + C * F:] = o[:, G + C * F:][:, perm]
    return p


def _lr(_):
    return 3e-4


def _ppo_parts(policy, o):
    with th.no_grad():
        dist = policy.get_distribution(th.as_tensor(o))
        return dist.distribution.mean.numpy(), dist.distribution.stddev.numpy(), policy.predict_values(
            th.as_tensor(o)).numpy()


def _sac_parts(policy, o, a):
    with th.no_grad():
        mean, log_std, _ = policy.actor.get_action_dist_params(th.as_tensor(o))
        q = th.cat(policy.critic(th.as_tensor(o), th.as_tensor(a)), 1)
        return mean.numpy(), log_std.numpy(), q.numpy()


def _recurrent_parts(policy, o, steps=3):
    """Means and values after ``steps`` recurrent steps on the same observations (the LSTM state carried)."""
    n = o.shape[0]
    shape = (policy.lstm_hidden_state_shape[0], n, policy.lstm_hidden_state_shape[2])
    state = (th.zeros(shape), th.zeros(shape))
    starts = th.zeros(n)
    with th.no_grad():
        for _ in range(steps):
            dist, state = policy.get_distribution(th.as_tensor(o), state, starts)
        vals = policy.predict_values(th.as_tensor(o), state, starts)
    return dist.distribution.mean.numpy(), dist.distribution.stddev.numpy(), vals.numpy()


def _make(kind, obs_space, act_space):
    th.manual_seed(0)
    if kind == "ppo":
        return ChannelSetPolicy(obs_space, act_space, _lr)
    if kind == "recurrentppo":
        return ChannelSetRecurrentPolicy(obs_space, act_space, _lr, lstm_hidden_size=16)
    return ChannelSetSACPolicy(obs_space, act_space, _lr)


def _parts(kind, policy, o, a):
    if kind == "ppo":
        return _ppo_parts(policy, o)
    if kind == "recurrentppo":
        return _recurrent_parts(policy, o)
    return _sac_parts(policy, o, a)


@pytest.mark.parametrize("kind", ["ppo", "recurrentppo", "sac"])
def test_permuting_the_channels_permutes_the_actions(kind):
    obs_space, act_space, layout = _spaces(history=2)
    policy = _make(kind, obs_space, act_space)
    rng = np.random.default_rng(0)
    o, mask = _observations(obs_space, layout, 6, rng)
    a = rng.uniform(-1, 1, (6, layout.channels)).astype(np.float32)
    perm = rng.permutation(layout.channels)
    mean, spread, value = _parts(kind, policy, o, a)
    mean_p, spread_p, value_p = _parts(kind, policy, _permute(o, layout, perm), a[:, perm])
    np.testing.assert_allclose(mean_p, mean[:, perm], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(spread_p, spread[:, perm], rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(value_p, value, rtol=1e-5, atol=1e-6)  # the value / Q: invariant
    assert np.all(mean[~mask] == 0)  # empty channels: action 0 (the env ignores it)
    assert np.ptp(mean[mask]) > 0  # and the others differ
    if kind != "sac":  # PPO's Gaussian has one log-std for every channel: the distribution is equivariant too
        assert np.all(spread == spread.flat[0])


@pytest.mark.parametrize("kind", ["ppo", "recurrentppo", "sac"])
def test_an_empty_channels_features_change_no_action(kind):
    obs_space, act_space, layout = _spaces()
    policy = _make(kind, obs_space, act_space)
    rng = np.random.default_rng(1)
    o, mask = _observations(obs_space, layout, 4, rng, empty=(2,))
    a = rng.uniform(-1, 1, (4, layout.channels)).astype(np.float32)
    noisy = o.copy()
    G, F = layout.global_dim, layout.features
    noisy[:, G + 2 * F:G + 3 * F] = rng.uniform(-1, 1, (4, F))  # garbage in the empty channel 2
    a2 = a.copy()
    a2[:, 2] = -a[:, 2]  # and another action there (SAC's critic)
    for x, y in zip(_parts(kind, policy, o, a), _parts(kind, policy, noisy, a2)):
        np.testing.assert_array_equal(x, y)


def test_layout_is_found_from_the_space_and_checked():
    obs_space, act_space, layout = _spaces(history=3, channels=11)
    assert (layout.channels, layout.features, layout.global_dim) == (11, 27, 3 * 19)
    from gymnasium import spaces
    with pytest.raises(ValueError, match="not a per-satellite observation"):
        channel_layout(spaces.Box(-1, 1, (20,)))
    with pytest.raises(ValueError, match="4 channels observed, 11 actions"):
        ChannelSetPolicy(_spaces(channels=4)[0], act_space, _lr)
    with pytest.raises(ValueError, match="net_arch is not taken"):
        ChannelSetPolicy(obs_space, act_space, _lr, net_arch=[64])
    with pytest.raises(ValueError, match="channel_net must be a non-empty list"):
        ChannelSetPolicy(obs_space, act_space, _lr, channel_net=[])


@pytest.mark.parametrize("algo", ["ppo", "sac", "recurrentppo"])
def test_train_rl_trains_the_set_policy_and_eval_loads_it(tmp_path, algo):
    """A tiny run through train.py rl's function (the plumbing only: no claim on the result): the set policy by
    default, rewards normalized and observations not, and the saved model acts per channel on the env's rows."""
    import json

    from agents.policies import Sb3Policy
    from agents.training import train_rl
    cfg = tmp_path / "c.yml"
    hyper = {"ppo": "  n_steps: 8\n  batch_size: 16\n  n_epochs: 1\n",
             "recurrentppo": "  n_steps: 8\n  batch_size: 16\n  n_epochs: 1\n",
             "sac": "  learning_starts: 8\n  batch_size: 8\n  buffer_size: 200\n"}[algo]
    cfg.write_text(f"GnssIns/SatelliteR-v0:\n  n_envs: 2\n  n_timesteps: 32\n{hyper}  eval_episodes: 1\n"
                   "  prefetch_worlds: 0\n  env_kwargs: {episode_length_s: 4.0, scenario: urban}\n")
    out = tmp_path / "run"
    config = train_rl("GnssIns/SatelliteR-v0", algo, out, config_file=cfg, seed=0, progress=False)
    assert config["policy"].startswith("agents.set_policy.") and config["normalize"] == {"norm_obs": False,
                                                                                          "norm_reward": True}
    assert json.loads((out / "config.json").read_text())["env"] == "GnssIns/SatelliteR-v0"
    pol = Sb3Policy.load(out / "model.zip", algo)
    assert pol.obs_rms is None  # observations were not normalized
    core = SatelliteCore(SatelliteEnvConfig(method="kf", episode_length_s=4.0, scenario="urban"), "inflation", 3)
    obs = core.reset_rows(np.arange(3), [1, 2, 3])
    pol.reset(3)
    act = pol.act(obs)
    assert act.shape == (3, core.n_channels) and np.all(np.abs(act) <= 1)
    core.step(act)
    if algo == "ppo":   # a receiver with more channels (a recording's): the same policy, rebuilt for them
        big = SatelliteCore(SatelliteEnvConfig(method="kf", episode_length_s=4.0, scenario="urban",
                                               channels=core.n_channels + 2), "inflation", 3)
        obs = big.reset_rows(np.arange(3), [1, 2, 3])
        pol.reset(3)
        act = pol.act(obs)
        assert act.shape == (3, core.n_channels + 2) and np.all(np.abs(act) <= 1)
        big.step(act)
        with pytest.raises(ValueError, match="not a channel count of its layout"):
            pol.act(obs[:, :-1])


def test_action_init_sets_the_initial_mean_action_and_survives_save_and_load(tmp_path):
    """action_init = -1 (x1 on GnssIns/SatelliteR-v0: the running method itself) is every valid channel's initial
    mean action (the head's weights start at gain 0.01, so to about 0.05); empty channels stay at 0; the value is
    saved with the policy; outside [-1, 1] it is refused."""
    obs_space, act_space, layout = _spaces()
    o, valid = _observations(obs_space, layout, 6, np.random.default_rng(1))
    th.manual_seed(0)
    pol = ChannelSetPolicy(obs_space, act_space, _lr, action_init=-1.0)
    mean, _, _ = _ppo_parts(pol, o)
    assert np.all(np.abs(mean[valid] + 1.0) < 0.05) and np.all(mean[~valid] == 0.0)
    assert np.all(np.abs(_ppo_parts(ChannelSetPolicy(obs_space, act_space, _lr), o)[0][valid]) < 0.05)
    pol.save(tmp_path / "p.pt")
    loaded = ChannelSetPolicy.load(tmp_path / "p.pt")
    assert loaded._set_kwargs["action_init"] == -1.0
    np.testing.assert_allclose(_ppo_parts(loaded, o)[0], mean, atol=1e-6)
    rec = ChannelSetRecurrentPolicy(obs_space, act_space, _lr, lstm_hidden_size=8, action_init=0.5)
    assert float(rec.action_net.linear.bias.detach()) == 0.5
    with pytest.raises(ValueError, match="action_init must be a number in"):
        ChannelSetPolicy(obs_space, act_space, _lr, action_init=-2.0)


@pytest.mark.parametrize("kind", ["ppo", "sac"])
def test_with_channels_acts_the_same_on_padded_channels(kind):
    """A set policy rebuilt for more channels (a recording's receiver has more than the simulated one) keeps its
    weights: on the same observation padded with empty channels, the original channels' actions are unchanged."""
    from agents.set_policy import with_channels
    obs_space, act_space, layout = _spaces()
    pol = _make(kind, obs_space, act_space)
    o, mask = _observations(obs_space, layout, 5, np.random.default_rng(2))
    G, C, F = layout.global_dim, layout.channels, layout.features
    big = with_channels(pol, C + 3)
    assert big.action_space.shape == (C + 3,) and big.observation_space.shape == (G + (C + 3) * (F + 1),)
    pad = np.zeros((5, G + (C + 3) * (F + 1)), np.float32)
    pad[:, :G + C * F] = o[:, :G + C * F]
    pad[:, G + (C + 3) * F:G + (C + 3) * F + C] = o[:, G + C * F:]
    with th.no_grad():
        a = pol.predict(o, deterministic=True)[0]
        b = big.predict(pad, deterministic=True)[0]
    np.testing.assert_allclose(b[:, :C], a, atol=1e-5)
    with pytest.raises(ValueError, match="channels must be an int >= 1"):
        with_channels(pol, 0)
