"""Permutation-equivariant policies for the per-satellite environments (:mod:`envs.satellite_env`).

The receiver's channels are a set: their order carries no meaning, and some are empty. The networks here treat
them so (a Deep Sets / PointNet structure):

* a shared per-channel network ``phi`` maps each channel's features ``x_i`` (27) to ``h_i``;
* a pooled context over the *valid* channels (masked mean and max of ``h_i``) joined with an encoding of the
  global frames, ``ctx = rho([mean_i h_i, max_i h_i, gamma(g)])``, is the same for every order of the channels;
* a per-channel latent ``z_i = psi([h_i, ctx])`` feeds a per-channel action head (one shared linear unit) and the
  value / Q functions see only pooled quantities.

So permuting the channels permutes the actions (to float rounding: the pooled sums change order), and an empty
channel (mask 0) enters no pooled quantity: its features change no other channel's action, and its own action is
0 (the env ignores it). The validity is read as ``mask > 0``, which holds for the raw mask and for one
normalized by ``VecNormalize`` (a slot's running mean lies in (0, 1) once it has been both used and empty; a
slot never used has mean 0 and normalizes to 0, "empty"); the envs' features are scaled to about unit size and
``train.py rl`` does not normalize them (a per-slot normalization would break the symmetry).

SB3 classes (usable by ``train.py rl`` and RL Zoo by name, ``policy: agents.set_policy.ChannelSetPolicy``):

* :class:`ChannelSetExtractor` -- the features extractor: ``[z_1 .. z_C, ctx, mask]``.
* :class:`ChannelSetPolicy` -- PPO's actor-critic: Gaussian actions with one shared log-std (so that the
  distribution, not only its mean, is equivariant), the value from ``ctx``.
* :class:`ChannelSetRecurrentPolicy` -- RecurrentPPO: the LSTMs run on the pooled context; channel i's head sees
  ``[z_i, o]`` with ``o`` the LSTM's output.
* :class:`ChannelSetSACPolicy` -- SAC: a per-channel squashed-Gaussian actor (mean and log-std heads per channel)
  and twin critics ``Q = w^T [mean_i q([z_i, a_i]), ctx]`` pooling over the valid channels.

``policy_kwargs``: ``channel_net`` (hidden sizes of ``phi``, default [64, 64]), ``context_net`` (of ``gamma`` and
``rho``, [64]), ``latent_dim`` (``z_i`` and ``ctx``, 64), ``action_init`` (PPO / RecurrentPPO: the initial mean
action of every channel, the head's bias, in [-1, 1], default 0; -1 on ``GnssIns/SatelliteR-v0`` starts at x1,
the running method itself, and explores from there), ``channels`` (the channel count, default: found from the
observation space, :func:`envs.satellite_env.channel_layout`), ``activation_fn``; SAC also ``net_arch`` (the
per-channel hidden sizes of each Q, [64, 64]).

Reward shaping with truth is not used here; the policy never sees the truth (the observation has none).
"""
from __future__ import annotations

import numpy as np
import torch as th
from sb3_contrib.common.recurrent.policies import RecurrentActorCriticPolicy
from stable_baselines3.common.policies import ActorCriticPolicy, ContinuousCritic
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.sac.policies import LOG_STD_MAX, LOG_STD_MIN, Actor, SACPolicy
from torch import nn

from envs.satellite_env import channel_layout

DEFAULT_CHANNEL_NET = (64, 64)
DEFAULT_CONTEXT_NET = (64,)
DEFAULT_LATENT_DIM = 64


def _mlp(sizes, activation_fn, last_activation: bool = True) -> nn.Sequential:
    """Linear layers ``sizes[0] -> ... -> sizes[-1]`` with ``activation_fn`` between (and after the last one)."""
    layers = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if last_activation or i < len(sizes) - 2:
            layers.append(activation_fn())
    return nn.Sequential(*layers)


def _sizes(name: str, value) -> tuple:
    sizes = tuple(value)
    if not sizes or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 1 for s in sizes):
        raise ValueError(f"{name} must be a non-empty list of ints >= 1, got {value!r}")
    return sizes


def split_features(features: th.Tensor, channels: int, latent_dim: int):
    """``(z (N, C, d), ctx (N, d), valid (N, C) bool)`` of :class:`ChannelSetExtractor`'s output."""
    C, d = channels, latent_dim
    z = features[:, :C * d].reshape(features.shape[0], C, d)
    return z, features[:, C * d:C * d + d], features[:, C * d + d:] > 0.5


class ChannelSetExtractor(BaseFeaturesExtractor):
    """Shared per-channel network, pooled context over the valid channels, per-channel latents (module docstring).

    Parameters
    ----------
    observation_space : a per-satellite env's flat Box (:func:`envs.satellite_env.channel_layout`).
    channels : the channel count (None: from the space).
    channel_net, context_net : hidden sizes of ``phi`` and of ``gamma`` / ``rho``.
    latent_dim : size of ``z_i`` and of ``ctx``.
    activation_fn : activation class (``nn.Tanh``, SB3's default for PPO).

    Output: ``(N, C * latent_dim + latent_dim + C)``: ``z_1 .. z_C`` (zero on empty channels), ``ctx``, the mask
    (1.0 / 0.0).
    """

    def __init__(self, observation_space, channels: int | None = None, channel_net=DEFAULT_CHANNEL_NET,
                 context_net=DEFAULT_CONTEXT_NET, latent_dim: int = DEFAULT_LATENT_DIM,
                 activation_fn: type[nn.Module] = nn.Tanh):
        layout = channel_layout(observation_space, channels)
        channel_net, context_net = _sizes("channel_net", channel_net), _sizes("context_net", context_net)
        _sizes("latent_dim", [latent_dim])
        C, d = layout.channels, int(latent_dim)
        super().__init__(observation_space, C * d + d + C)
        self.layout, self.channels, self.latent_dim = layout, C, d
        self.phi = _mlp((layout.features,) + channel_net, activation_fn)
        h = channel_net[-1]
        self.gamma = _mlp((layout.global_dim,) + context_net, activation_fn)
        self.rho = _mlp((2 * h + context_net[-1],) + context_net + (d,), activation_fn)
        self.psi = _mlp((h + d, d), activation_fn)

    def forward(self, obs: th.Tensor) -> th.Tensor:
        G, C, F = self.layout.global_dim, self.channels, self.layout.features
        N = obs.shape[0]
        x = obs[:, G:G + C * F].reshape(N, C, F)
        valid = obs[:, G + C * F:G + C * F + C] > 0  # raw 1/0, or VecNormalize'd (module docstring)
        w = valid.unsqueeze(-1).to(obs.dtype)
        h = self.phi(x)
        n = w.sum(1).clamp(min=1.0)
        mean = (h * w).sum(1) / n
        mx = h.masked_fill(~valid.unsqueeze(-1), -1e9).amax(1)
        mx = th.where(valid.any(1, keepdim=True), mx, th.zeros_like(mx))
        ctx = self.rho(th.cat([mean, mx, self.gamma(obs[:, :G])], 1))
        z = self.psi(th.cat([h, ctx.unsqueeze(1).expand(N, C, ctx.shape[1])], 2)) * w
        return th.cat([z.reshape(N, C * self.latent_dim), ctx, valid.to(obs.dtype)], 1)


class _ActorCriticLatents(nn.Module):
    """PPO's ``mlp_extractor``: the actor's latent is the extractor's per-channel part (``z`` and the mask), the
    critic's the pooled context. ``head_dim``: the size of a channel's latent at the action head."""

    def __init__(self, channels: int, latent_dim: int):
        super().__init__()
        self.channels, self.d = channels, latent_dim
        self.head_dim = latent_dim
        self.latent_dim_pi = channels * latent_dim + channels
        self.latent_dim_vf = latent_dim

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        C, d = self.channels, self.d
        return th.cat([features[:, :C * d], features[:, C * d + d:]], 1)

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        C, d = self.channels, self.d
        return features[:, C * d:C * d + d]

    def forward(self, features: th.Tensor):
        return self.forward_actor(features), self.forward_critic(features)


class _ActorLatent(nn.Module):
    """SAC's actor latent: :meth:`_ActorCriticLatents.forward_actor` as a module."""

    def __init__(self, channels: int, latent_dim: int):
        super().__init__()
        self.split = _ActorCriticLatents(channels, latent_dim)

    def forward(self, features: th.Tensor) -> th.Tensor:
        return self.split.forward_actor(features)


class _RecurrentLatents(nn.Module):
    """RecurrentPPO's ``mlp_extractor``: its input is ``[z_1 .. z_C, mask, o]`` with ``o`` (H) the LSTM's output
    on the pooled context (:meth:`ChannelSetRecurrentPolicy._process_sequence`); channel i's latent at the head is
    ``[z_i, o]``, the critic's ``o``."""

    def __init__(self, channels: int, latent_dim: int, hidden: int):
        super().__init__()
        self.channels, self.d, self.hidden = channels, latent_dim, hidden
        self.head_dim = latent_dim + hidden
        self.latent_dim_pi = channels * self.head_dim + channels
        self.latent_dim_vf = hidden

    def forward_actor(self, latent: th.Tensor) -> th.Tensor:
        C, d, H = self.channels, self.d, self.hidden
        N = latent.shape[0]
        z = latent[:, :C * d].reshape(N, C, d)
        o = latent[:, -H:].unsqueeze(1).expand(N, C, H)
        return th.cat([th.cat([z, o], 2).reshape(N, C * (d + H)), latent[:, C * d:C * d + C]], 1)

    def forward_critic(self, latent: th.Tensor) -> th.Tensor:
        return latent[:, -self.hidden:]

    def forward(self, latent: th.Tensor):
        return self.forward_actor(latent), self.forward_critic(latent)


class ChannelHead(nn.Module):
    """One shared linear unit per channel: ``(N, C * d + C)`` (``z`` then the mask) -> ``(N, C)``, ``fill`` on
    empty channels."""

    def __init__(self, channels: int, latent_dim: int, fill: float = 0.0):
        super().__init__()
        self.channels, self.d, self.fill = channels, latent_dim, float(fill)
        self.linear = nn.Linear(latent_dim, 1)

    def forward(self, latent: th.Tensor) -> th.Tensor:
        C, d = self.channels, self.d
        z = latent[:, :C * d].reshape(latent.shape[0], C, d)
        out = self.linear(z).squeeze(-1)
        return th.where(latent[:, C * d:] > 0.5, out, th.full_like(out, self.fill))


def _set_policy_kwargs(owner: str, kwargs: dict, channels, channel_net, context_net, latent_dim,
                       activation_default, action_init: float = 0.0) -> dict:
    """Check an actor-critic set policy's ``kwargs`` and put the extractor's arguments in (in place); returns the
    set arguments to save with the policy."""
    if not (isinstance(action_init, (int, float)) and not isinstance(action_init, bool)
            and -1.0 <= float(action_init) <= 1.0):
        raise ValueError(f"{owner}: action_init must be a number in [-1, 1] (the action space), got {action_init!r}")
    if kwargs.get("use_sde"):
        raise ValueError(f"{owner}: use_sde is not supported (a Gaussian with one shared log-std)")
    if kwargs.get("net_arch"):
        raise ValueError(f"{owner}: net_arch is not taken; set channel_net, context_net, latent_dim")
    kwargs.pop("net_arch", None)
    fe = dict(channels=channels, channel_net=channel_net, context_net=context_net, latent_dim=latent_dim,
              activation_fn=kwargs.get("activation_fn", activation_default))
    fe.update(kwargs.pop("features_extractor_kwargs", None) or {})
    kwargs["features_extractor_kwargs"] = fe
    kwargs.setdefault("features_extractor_class", ChannelSetExtractor)
    return dict(channels=channels, channel_net=channel_net, context_net=context_net, latent_dim=latent_dim,
                action_init=float(action_init))


class _ChannelActorCritic:
    """What the PPO and RecurrentPPO set policies share: the per-channel Gaussian head with one shared log-std,
    built over SB3's dense ``action_net`` and ``log_std``."""

    def _channel_extractor(self) -> ChannelSetExtractor:
        return self.features_extractor if self.share_features_extractor else self.pi_features_extractor

    def _check_channels(self, action_space) -> None:
        fe = self._channel_extractor()
        if fe.channels != action_space.shape[0]:
            raise ValueError(f"{type(self).__name__}: {fe.channels} channels observed, {action_space.shape[0]} "
                             "actions")

    def _build(self, lr_schedule) -> None:
        super()._build(lr_schedule)
        self.action_net = ChannelHead(self._channel_extractor().channels, self.mlp_extractor.head_dim)
        self.log_std = nn.Parameter(th.full((1,), float(self.log_std_init)), requires_grad=True)
        if self.ortho_init:
            self.action_net.apply(lambda m: self.init_weights(m, gain=0.01))
        with th.no_grad():   # the initial mean action of every valid channel (policy_kwargs action_init)
            self.action_net.linear.bias.fill_(self._set_kwargs["action_init"])
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        data.pop("net_arch", None)
        data.update(self._set_kwargs)
        return data


class ChannelSetPolicy(_ChannelActorCritic, ActorCriticPolicy):
    """PPO / A2C actor-critic over a set of channels (module docstring). ``policy_kwargs``: ``channels``,
    ``channel_net``, ``context_net``, ``latent_dim`` and SB3's (``activation_fn``, ``log_std_init``, ``ortho_init``,
    ``optimizer_kwargs``, ...); ``net_arch`` and ``use_sde`` are not taken (the heads are per channel)."""

    def __init__(self, observation_space, action_space, lr_schedule, channels: int | None = None,
                 channel_net=DEFAULT_CHANNEL_NET, context_net=DEFAULT_CONTEXT_NET, latent_dim: int = DEFAULT_LATENT_DIM,
                 action_init: float = 0.0, **kwargs):
        self._set_kwargs = _set_policy_kwargs(type(self).__name__, kwargs, channels, channel_net, context_net,
                                              latent_dim, nn.Tanh, action_init)
        super().__init__(observation_space, action_space, lr_schedule, net_arch=[], **kwargs)
        self._check_channels(action_space)

    def _build_mlp_extractor(self) -> None:
        fe = self._channel_extractor()
        self.mlp_extractor = _ActorCriticLatents(fe.channels, fe.latent_dim)


class ChannelSetRecurrentPolicy(_ChannelActorCritic, RecurrentActorCriticPolicy):
    """RecurrentPPO over a set of channels: the LSTMs run on the pooled context ``ctx`` (so their state is the
    same for every channel order), channel i's action head sees ``[z_i, o]`` with ``o`` the actor LSTM's output, the
    value the critic LSTM's (or, with ``enable_critic_lstm=False``, a linear map of ``ctx``). ``policy_kwargs`` as
    :class:`ChannelSetPolicy` plus sb3-contrib's ``lstm_hidden_size``, ``n_lstm_layers``, ``shared_lstm``,
    ``enable_critic_lstm``, ``lstm_kwargs``."""

    def __init__(self, observation_space, action_space, lr_schedule, channels: int | None = None,
                 channel_net=DEFAULT_CHANNEL_NET, context_net=DEFAULT_CONTEXT_NET, latent_dim: int = DEFAULT_LATENT_DIM,
                 action_init: float = 0.0, **kwargs):
        self._set_kwargs = _set_policy_kwargs(type(self).__name__, kwargs, channels, channel_net, context_net,
                                              latent_dim, nn.Tanh, action_init)
        super().__init__(observation_space, action_space, lr_schedule, net_arch=[], **kwargs)
        self._check_channels(action_space)
        d, H = self._channel_extractor().latent_dim, self.lstm_output_dim
        layers = self.lstm_actor.num_layers
        self.lstm_actor = nn.LSTM(d, H, num_layers=layers, **self.lstm_kwargs)
        if self.lstm_critic is not None:
            self.lstm_critic = nn.LSTM(d, H, num_layers=layers, **self.lstm_kwargs)
        if self.critic is not None:
            self.critic = _ContextLinear(self._channel_extractor().channels, d, H)
        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    def _build_mlp_extractor(self) -> None:
        fe = self._channel_extractor()
        self.mlp_extractor = _RecurrentLatents(fe.channels, fe.latent_dim, self.lstm_output_dim)

    def _process_sequence(self, features, lstm_states, episode_starts, lstm):
        """The LSTM on the pooled context only; returns ``([z_1 .. z_C, mask, o], states)``."""
        z, ctx, valid = split_features(features, self._channel_extractor().channels,
                                       self._channel_extractor().latent_dim)
        out, states = RecurrentActorCriticPolicy._process_sequence(ctx, lstm_states, episode_starts, lstm)
        N = features.shape[0]
        return th.cat([z.reshape(N, -1), valid.to(features.dtype), out], 1), states


class _ContextLinear(nn.Module):
    """``Linear(ctx)`` of :class:`ChannelSetExtractor`'s output (RecurrentPPO's critic without an LSTM)."""

    def __init__(self, channels: int, latent_dim: int, hidden: int):
        super().__init__()
        self.channels, self.d = channels, latent_dim
        self.linear = nn.Linear(latent_dim, hidden)

    def forward(self, features: th.Tensor) -> th.Tensor:
        return self.linear(split_features(features, self.channels, self.d)[1])


class ChannelSetActor(Actor):
    """SAC's actor with per-channel mean and log-std heads on :class:`ChannelSetExtractor`'s latents (empty
    channels: mean 0, log-std 0, constants the gradient does not see)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.use_sde:
            raise ValueError("ChannelSetSACPolicy: use_sde is not supported")
        fe = self.features_extractor
        self.latent_pi = _ActorLatent(fe.channels, fe.latent_dim)
        self.mu = ChannelHead(fe.channels, fe.latent_dim)
        self.log_std = ChannelHead(fe.channels, fe.latent_dim)

    def get_action_dist_params(self, obs):
        features = self.extract_features(obs, self.features_extractor)
        latent = self.latent_pi(features)
        return self.mu(latent), th.clamp(self.log_std(latent), LOG_STD_MIN, LOG_STD_MAX), {}


class _ChannelQ(nn.Module):
    """``Q = w^T [mean over valid i of q([z_i, a_i]), ctx] + c``: invariant under channel permutations."""

    def __init__(self, channels: int, latent_dim: int, hidden, activation_fn):
        super().__init__()
        self.channels, self.d = channels, latent_dim
        self.q = _mlp((latent_dim + 1,) + tuple(hidden), activation_fn)
        self.out = nn.Linear(hidden[-1] + latent_dim, 1)

    def forward(self, features: th.Tensor, actions: th.Tensor) -> th.Tensor:
        z, ctx, valid = split_features(features, self.channels, self.d)
        w = valid.unsqueeze(-1).to(z.dtype)
        q = self.q(th.cat([z, actions.unsqueeze(-1)], 2))
        pooled = (q * w).sum(1) / w.sum(1).clamp(min=1.0)
        return self.out(th.cat([pooled, ctx], 1))


class ChannelSetCritic(ContinuousCritic):
    """SAC's twin critics as :class:`_ChannelQ` on :class:`ChannelSetExtractor`'s output (``net_arch``: the
    per-channel hidden sizes)."""

    def __init__(self, observation_space, action_space, net_arch, features_extractor, features_dim,
                 activation_fn=nn.ReLU, normalize_images=True, n_critics=2, share_features_extractor=True):
        super().__init__(observation_space, action_space, [], features_extractor, features_dim, activation_fn,
                         normalize_images, n_critics, share_features_extractor)
        hidden = _sizes("net_arch", net_arch or [64, 64])
        fe = features_extractor
        self.q_networks = []
        for idx in range(n_critics):
            q = _ChannelQ(fe.channels, fe.latent_dim, hidden, activation_fn)
            setattr(self, f"qf{idx}", q)  # replaces the dense MLP of the same name
            self.q_networks.append(q)

    def forward(self, obs, actions):
        with th.set_grad_enabled(not self.share_features_extractor):
            features = self.extract_features(obs, self.features_extractor)
        return tuple(q(features, actions) for q in self.q_networks)

    def q1_forward(self, obs, actions):
        with th.no_grad():
            features = self.extract_features(obs, self.features_extractor)
        return self.q_networks[0](features, actions)


class ChannelSetSACPolicy(SACPolicy):
    """SAC over a set of channels (module docstring): ``policy_kwargs`` as :class:`ChannelSetPolicy` plus
    ``net_arch`` (the per-channel hidden sizes of each Q network; the actor has none of its own)."""

    def __init__(self, observation_space, action_space, lr_schedule, net_arch=None, channels: int | None = None,
                 channel_net=DEFAULT_CHANNEL_NET, context_net=DEFAULT_CONTEXT_NET, latent_dim: int = DEFAULT_LATENT_DIM,
                 **kwargs):
        if kwargs.get("use_sde"):
            raise ValueError("ChannelSetSACPolicy: use_sde is not supported")
        fe = dict(channels=channels, channel_net=channel_net, context_net=context_net, latent_dim=latent_dim,
                  activation_fn=kwargs.get("activation_fn", nn.ReLU))
        fe.update(kwargs.pop("features_extractor_kwargs", None) or {})
        kwargs.setdefault("features_extractor_class", ChannelSetExtractor)
        self._set_kwargs = dict(channels=channels, channel_net=channel_net, context_net=context_net,
                                latent_dim=latent_dim)
        super().__init__(observation_space, action_space, lr_schedule, net_arch=list(net_arch or [64, 64]),
                         features_extractor_kwargs=fe, **kwargs)

    def make_actor(self, features_extractor=None) -> ChannelSetActor:
        kw = self._update_features_extractor(self.actor_kwargs, features_extractor)
        return ChannelSetActor(**kw).to(self.device)

    def make_critic(self, features_extractor=None) -> ChannelSetCritic:
        kw = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return ChannelSetCritic(**kw).to(self.device)

    def _get_constructor_parameters(self) -> dict:
        data = super()._get_constructor_parameters()
        data.update(self._set_kwargs)
        return data


def with_channels(policy, channels: int):
    """The set policy ``policy`` (any of this module's SB3 policies) rebuilt for observations and actions of
    ``channels`` receiver channels, with the same weights: every weight is shared by the channels or acts on pooled
    quantities, so the policy is defined for any channel count (a recording whose receiver has more channels than
    the simulated one the policy was trained on). The frames and the per-channel bounds are the policy's own.

    Parameters
    ----------
    policy : a ChannelSetPolicy, ChannelSetRecurrentPolicy or ChannelSetSACPolicy; channels : int >= 1.

    Returns
    -------
    A new policy of the same class in evaluation mode (``policy`` is left as it is).
    """
    from gymnasium import spaces
    if not isinstance(policy, CHANNEL_SET_POLICIES):
        raise ValueError(f"with_channels: {type(policy).__name__} is not a channel-set policy")
    if isinstance(channels, bool) or not isinstance(channels, int) or channels < 1:
        raise ValueError(f"with_channels: channels must be an int >= 1, got {channels!r}")
    old = policy.observation_space
    lay = channel_layout(old)
    G, F, C = lay.global_dim, lay.features, lay.channels

    def tile(a):
        return np.concatenate([a[:G], np.tile(a[G:G + F], channels), np.repeat(a[G + C * F:G + C * F + 1], channels)])

    obs = spaces.Box(tile(old.low), tile(old.high), dtype=old.dtype)
    act = spaces.Box(float(policy.action_space.low[0]), float(policy.action_space.high[0]), (channels,),
                     dtype=policy.action_space.dtype)
    params = policy._get_constructor_parameters()
    params.update(observation_space=obs, action_space=act, channels=channels)
    params["features_extractor_kwargs"] = {**(params.get("features_extractor_kwargs") or {}), "channels": channels}
    new = type(policy)(**params)
    new.load_state_dict(policy.state_dict())
    new.set_training_mode(False)
    return new


__all__ = ["with_channels", "ChannelSetExtractor", "ChannelSetPolicy", "ChannelSetRecurrentPolicy", "ChannelSetSACPolicy",
           "ChannelSetActor", "ChannelSetCritic", "ChannelHead", "split_features"]

CHANNEL_SET_POLICIES = (ChannelSetPolicy, ChannelSetRecurrentPolicy, ChannelSetSACPolicy)
"""The SB3 policy classes of this module (:func:`with_channels` rebuilds any of them)."""
