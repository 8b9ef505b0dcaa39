"""``learned-r``: a supervised per-satellite measurement-noise baseline (``train.py learned-r``, eval.py
``learned-r:PATH``).

The PrNet / NLOS-classifier line of work in this testbed's terms: a small network, shared by every receiver
channel, maps a channel's features -- those of ``GnssIns/SatelliteR-v0``'s observation
(:data:`envs.channel_features.CHANNEL_FEATURES`, without ``last_action``, :data:`INPUT_FEATURES`) -- to the log
variance of that channel's pseudorange error, trained in simulation against the simulator's true error. Used as
R, it is the learned counterpart of ``oracle-r`` (which is handed the true variances): the RL policies of the
per-satellite env must beat it to show that acting on the filter adds something to estimating the noise.

Data (:func:`collect_channel_data`): B rows of the env core on simulated worlds (scenarios ``urban`` and
``urban-transition`` by default; ``train.py learned-r --scenarios urban-smartloc`` for the scenario calibrated to
the smartLoc channels, whose C/N0 separates NLOS no better than the recording's), every valid channel at every step: its features as the env observes them
before the epoch's update, and its label ``y = e / sigma_rep``: the simulator's true pseudorange error of that
channel and epoch (``GnssData.pr_error_m``: atmosphere + NLOS / multipath bias + noise, without the receiver
clock) over the sigma the receiver reports for it. The rows run with the default action (x1, the kf as the
receiver reports) except a fraction ``explore_rows`` that draw a uniform log10 inflation in [0, 4] per channel
and step: the innovation features depend on the R the filter used, and the network is then run on its own
inflations (:class:`LearnedRPolicy`), so the training data cover that range too. The label does not depend on
the action. Seeds (:func:`split_seeds`): training ``700_000 + 1000 S + k``, validation ``780_000 + 100 S + k``,
test ``880_000 + k`` (the same for every run seed ``S``), all disjoint from eval.py's episode seeds
(``seed * 1_000_003 + k``) and from the RL evaluation seeds (``900_000 + ...``).

Model (:class:`LearnedRNet`): an MLP applied to each channel alone (permutation-equivariant by construction; an
empty channel changes no other channel's output) giving ``s``, the natural log of the inflation of the reported
pseudorange variance, i.e. the predicted variance ``sigma_rep^2 exp(s)``. Loss: the Gaussian negative
log-likelihood of the normalized error, ``mean(exp(-s) y^2 + s)`` (twice the NLL less ``log 2 pi``; minimized
at ``s = log E[y^2 | features]``, the log of the true variance ratio). Adam, minibatches, early stopping on the
validation loss (the best weights kept). The network never sees the truth at evaluation.

Use (:class:`LearnedRPolicy`): a fixed policy of ``GnssIns/SatelliteR-v0`` whose channel action is
``log10_inflation = clip(s / ln 10, 0, 4)``: the same inflation on the pseudorange and its rate. The env's action
space cannot deflate a variance: a predicted variance below the reported one gives x1 (``metrics.json`` reports
how often that happens on the test channels, ``frac_below_reported``). Any method the env accepts runs under it
(``learned-r:PATH[method=kf-fde]``; default ``kf``).

Files of a run (``train.py learned-r --out DIR``): ``model.pt`` (torch: the state dict and the network's
settings), ``config.json`` (features, scenarios, seeds, episode length, steps, training settings) and
``metrics.json`` (held-out NLLs against the reported and the true variances, AUC of ``s`` for the NLOS flags,
rank correlation with the true variance ratio, the training history).
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch as th
from torch import nn

from envs.channel_features import CHANNEL_FEATURES
from envs.json_io import dumps
from envs.outputs import atomic_path, write_atomic

ENV_ID = "GnssIns/SatelliteR-v0"
"""The per-satellite env whose observation the network reads and whose action it sets."""
EXCLUDED_FEATURES = ("last_action",)
"""Channel features the network does not read: the action of the policy that ran (not a property of the signal)."""
INPUT_FEATURES = tuple(f[0] for f in CHANNEL_FEATURES if f[0] not in EXCLUDED_FEATURES)
"""Names of the channel features the network reads, in observation order."""
INPUT_INDEX = np.array([i for i, f in enumerate(CHANNEL_FEATURES) if f[0] not in EXCLUDED_FEATURES], np.intp)
"""Their indices in a channel's feature vector."""
TRAIN_SEED_BASE, VAL_SEED_BASE, TEST_SEED_BASE = 700_000, 780_000, 880_000
"""Seed bases of the splits (module docstring)."""
MAX_RUN_SEED = 79
"""Largest run seed whose training seeds stay below the validation seeds."""
MODEL_FILE, CONFIG_FILE, METRICS_FILE = "model.pt", "config.json", "metrics.json"


@dataclass(frozen=True)
class LearnedRConfig:
    """Settings of ``train.py learned-r`` (module docstring).

    Attributes
    ----------
    seed : run seed S (worlds of the training and validation splits, exploration, network initialization, batches),
        0 .. :data:`MAX_RUN_SEED`.
    scenarios : simulated scenario names the episodes are drawn from (each split: every scenario in turn).
    episode_length_s : episode length [s], > 0.
    n_train, n_val, n_test : episodes of each split (>= 1; n_train <= 1000, n_val <= 100).
    rows : episodes per batched core (>= 1).
    explore_rows : fraction of each batch's rows that draw random inflations, in [0, 1].
    hidden : hidden layer sizes of the per-channel MLP (ints >= 1).
    lr : Adam step size (> 0); batch_size : channel samples per minibatch (>= 1).
    max_epochs : passes over the training samples (>= 1); patience : epochs without a better validation loss
        before stopping (>= 1).
    """

    seed: int = 0
    scenarios: tuple = ("urban", "urban-transition")
    episode_length_s: float = 120.0
    n_train: int = 64
    n_val: int = 16
    n_test: int = 16
    rows: int = 16
    explore_rows: float = 0.5
    hidden: tuple = (64, 64)
    lr: float = 3e-3
    batch_size: int = 512
    max_epochs: int = 100
    patience: int = 10

    def __post_init__(self):
        ints = {"seed": (0, MAX_RUN_SEED), "n_train": (1, 1000), "n_val": (1, 100), "n_test": (1, 10_000),
                "rows": (1, 4096), "batch_size": (1, 10 ** 7), "max_epochs": (1, 10 ** 6), "patience": (1, 10 ** 6)}
        for name, (lo, hi) in ints.items():
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or not lo <= v <= hi:
                raise ValueError(f"LearnedRConfig.{name} must be an int in [{lo}, {hi}], got {v!r}")
        for name in ("episode_length_s", "lr"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"LearnedRConfig.{name} must be a positive finite number, got {v!r}")
        if not (isinstance(self.explore_rows, (int, float)) and 0.0 <= self.explore_rows <= 1.0):
            raise ValueError(f"LearnedRConfig.explore_rows must lie in [0, 1], got {self.explore_rows!r}")
        if not self.scenarios or not all(isinstance(s, str) for s in self.scenarios):
            raise ValueError(f"LearnedRConfig.scenarios must be a non-empty tuple of names, got {self.scenarios!r}")
        from envs.worlds import SCENARIOS
        for s in self.scenarios:
            if s not in SCENARIOS:
                raise ValueError(f"LearnedRConfig.scenarios: {s!r} is not a simulated scenario (the labels need the "
                                 "simulator's true errors)")
        if not self.hidden or not all(isinstance(h, int) and not isinstance(h, bool) and h >= 1 for h in self.hidden):
            raise ValueError(f"LearnedRConfig.hidden must be a non-empty tuple of ints >= 1, got {self.hidden!r}")


QUICK = LearnedRConfig(episode_length_s=60.0, n_train=16, n_val=8, n_test=8, rows=8, max_epochs=40, patience=10,
                       batch_size=128)
"""``--quick``: a small data set and few epochs (under a minute on 2 busy cores after compilation)."""


def split_seeds(config: LearnedRConfig) -> dict:
    """``{"train", "val", "test"}`` lists of world seeds (module docstring)."""
    S = config.seed
    return {"train": [TRAIN_SEED_BASE + 1000 * S + k for k in range(config.n_train)],
            "val": [VAL_SEED_BASE + 100 * S + k for k in range(config.n_val)],
            "test": [TEST_SEED_BASE + k for k in range(config.n_test)]}


# --------------------------------------------------------------------------------------------------- data
def collect_channel_data(scenario: str, seeds, episode_length_s: float, explore_rows: float = 0.0,
                         rng: np.random.Generator | None = None, policy=None, env_kwargs: dict | None = None) -> dict:
    """Per-channel samples of ``GnssIns/SatelliteR-v0`` episodes (one batched core over ``seeds``).

    Parameters
    ----------
    scenario : a simulated scenario name; seeds : B world seeds; episode_length_s : episode length [s].
    explore_rows : fraction of the rows (the last ``round(explore_rows * B)``) that act with a uniform random
        log10 inflation in [0, 4] per channel and step; the others act with x1.
    rng : the exploration's generator (default: seeded by the first seed).
    policy : optional, acts instead of x1 on the rows that do not explore: ``policy.act(obs)`` -> (B, C)
        actions in [-1, 1] (:class:`agents.policies.Sb3Policy`, reset to ``B`` rows here); the samples then
        also hold ``action`` (N,), the action each channel got at that epoch.
    env_kwargs : further env arguments (e.g. ``method``), beside ``scenario`` and ``episode_length_s``.

    Returns
    -------
    dict of arrays over the N valid (row, epoch, channel) samples:
    ``x`` (N, F) float32 channel features (all of :data:`~envs.channel_features.CHANNEL_FEATURES`) observed
    before the epoch's update; ``y`` (N,) the true pseudorange error over the reported sigma [-];
    ``sigma`` (N,) the reported sigma [m]; ``var_ratio`` (N,) the simulator's true variance over the reported
    one [-]; ``nlos`` (N,) bool; ``episode`` (N,) int index into ``seeds``.
    """
    from .rollout import env_class
    from envs.prepared import prepared_from
    seeds = [int(s) for s in seeds]
    B = len(seeds)
    rng = np.random.default_rng(seeds[0]) if rng is None else rng
    cls = env_class(ENV_ID)
    cfg = cls.config_from({**(env_kwargs or {}), "scenario": scenario, "episode_length_s": float(episode_length_s)})
    world = cfg.make_world(seeds)
    g = world.gnss
    if g.pr_var_true is None or g.pr_error_m is None:
        raise ValueError(f"scenario {scenario!r} has no simulated truth of its pseudorange errors")
    core = cls.core_for(cfg, B)
    obs = core.reset_rows(np.arange(B), seeds, prepared_from(world))
    C, M = core.n_channels, core.M
    err = _pad(g.pr_error_m, C)
    sig = core.pr_sigma  # (B, M, C) the reported sigmas as the core holds them (padded)
    vtrue = _pad(g.pr_var_true, C, 1.0)
    nlos = _pad(g.nlos, C, False)
    explore = np.arange(B) >= B - int(round(explore_rows * B))
    lo = float(core.default_channel_action)
    xs, ys, ss, vs, ns, es, acts = [], [], [], [], [], [], []
    if policy is not None:
        policy.reset(B)
    for _ in range(M):
        e = np.minimum(core.t, M - 1)
        _, ch, mask = core.channel_view(obs)
        valid = mask > 0.5
        b, i = np.nonzero(valid)
        xs.append(ch[b, i])
        sg = sig[b, e[b], i]
        ys.append(err[b, e[b], i] / sg)
        ss.append(sg)
        vs.append(vtrue[b, e[b], i] / sg ** 2)
        ns.append(nlos[b, e[b], i])
        es.append(b)
        a = np.full((B, C), lo) if policy is None else np.clip(np.asarray(policy.act(obs), np.float64), -1.0, 1.0)
        a[explore] = rng.uniform(-1.0, 1.0, (int(explore.sum()), C))
        acts.append(a[b, i])
        obs = core.step(a).obs
    out = {"x": np.concatenate(xs).astype(np.float32), "y": np.concatenate(ys), "sigma": np.concatenate(ss),
           "var_ratio": np.concatenate(vs), "nlos": np.concatenate(ns).astype(bool),
           "episode": np.concatenate(es).astype(np.int64)}
    if policy is not None:
        out["action"] = np.concatenate(acts)
    return out


def _pad(x, C: int, fill=0.0) -> np.ndarray:
    """(B, M, Cw) -> (B, M, C) with ``fill`` on the added channels (as :func:`envs.satellite_env.pad_channels`)."""
    Cw = x.shape[2]
    if Cw == C:
        return x
    return np.pad(x, [(0, 0), (0, 0), (0, C - Cw)], constant_values=fill)


def collect_split(config: LearnedRConfig, seeds, rng: np.random.Generator, explore: bool = True) -> dict:
    """:func:`collect_channel_data` over ``seeds`` in batches of ``config.rows``, the scenarios in turn (batch k
    on ``config.scenarios[k % n]``); the samples of every batch concatenated (``episode`` indexes ``seeds``)."""
    parts = []
    for k, c0 in enumerate(range(0, len(seeds), config.rows)):
        chunk = seeds[c0:c0 + config.rows]
        d = collect_channel_data(config.scenarios[k % len(config.scenarios)], chunk, config.episode_length_s,
                                 config.explore_rows if explore else 0.0, rng)
        d["episode"] = d["episode"] + c0
        parts.append(d)
    return {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}


# -------------------------------------------------------------------------------------------------- model
def gaussian_nll_loss(s, y):
    """``mean(exp(-s) y^2 + s)``: twice the Gaussian negative log-likelihood of the zero-mean errors ``y`` under
    the log variances ``s``, less ``log 2 pi`` (torch tensors, or numpy arrays -> float; one shape). Minimized
    over a constant ``s`` at ``s = log mean(y^2)``."""
    if isinstance(s, th.Tensor):
        return (th.exp(-s) * y * y + s).mean()
    s, y = np.asarray(s, np.float64), np.asarray(y, np.float64)
    return float(np.mean(np.exp(-s) * y * y + s))


class LearnedRNet(nn.Module):
    """The per-channel network: ``(..., C, F)`` channel features (all of ``CHANNEL_FEATURES``; the ones of
    :data:`EXCLUDED_FEATURES` are dropped here) and an optional ``(..., C)`` mask -> ``(..., C)`` log variance
    inflation ``s`` [-] (0 on masked channels). One MLP (tanh) shared by every channel, applied to each alone.

    Parameters
    ----------
    hidden : hidden layer sizes.
    """

    def __init__(self, hidden=(64, 64)):
        super().__init__()
        self.hidden = tuple(int(h) for h in hidden)
        layers, a = [], len(INPUT_INDEX)
        for h in self.hidden:
            layers += [nn.Linear(a, h), nn.Tanh()]
            a = h
        layers.append(nn.Linear(a, 1))
        self.mlp = nn.Sequential(*layers)
        self.register_buffer("index", th.as_tensor(INPUT_INDEX, dtype=th.long), persistent=False)

    def forward(self, x, mask=None):
        s = self.mlp(x.index_select(-1, self.index)).squeeze(-1)
        return s if mask is None else th.where(mask > 0.5, s, th.zeros_like(s))


def build_net(hidden=(64, 64), seed: int | None = None) -> LearnedRNet:
    """A new float64 :class:`LearnedRNet` (``hidden``: layer sizes; ``seed``: torch's initialization seed)."""
    if seed is not None:
        th.manual_seed(int(seed))
    return LearnedRNet(hidden).double()


def predict_log_inflation(net: LearnedRNet, x, batch: int = 65536) -> np.ndarray:
    """(N,) ``s`` of the network for channel features ``x`` (N, F) (numpy in, numpy out, no gradient)."""
    x = np.asarray(x, np.float64)
    out = np.empty(x.shape[0])
    with th.no_grad():
        for a in range(0, x.shape[0], batch):
            out[a:a + batch] = net(th.as_tensor(x[a:a + batch])).numpy()
    return out


def fit_net(train: dict, val: dict, config: LearnedRConfig, progress: bool = False) -> tuple:
    """Adam on :func:`gaussian_nll_loss` over the training samples, early stopping on the validation loss.

    Parameters
    ----------
    train, val : samples of :func:`collect_channel_data` (``x`` (N, F), ``y`` (N,)).
    config : the network and optimizer settings (``hidden``, ``lr``, ``batch_size``, ``max_epochs``,
        ``patience``, ``seed``: initialization and minibatch order).
    progress : one line per epoch on stderr.

    Returns
    -------
    ``(net, history)``: the network with the weights of the best validation loss; ``history`` with the
    per-epoch ``train_loss`` / ``val_loss`` lists, ``best_epoch`` (1-based), ``epochs`` run and ``steps``
    (minibatch updates).
    """
    if train["x"].shape[0] == 0 or val["x"].shape[0] == 0:
        raise ValueError("no channel samples to train on (every episode had no satellite?)")
    threads = th.get_num_threads()
    th.set_num_threads(1)  # small net, small batches: one thread is as fast and leaves the other cores free
    try:
        net = build_net(config.hidden, seed=config.seed)
        opt = th.optim.Adam(net.parameters(), lr=config.lr)
        x, y = th.as_tensor(np.asarray(train["x"], np.float64)), th.as_tensor(np.asarray(train["y"], np.float64))
        xv, yv = th.as_tensor(np.asarray(val["x"], np.float64)), th.as_tensor(np.asarray(val["y"], np.float64))
        gen = th.Generator().manual_seed(int(config.seed))
        hist = {"train_loss": [], "val_loss": [], "best_epoch": 0, "epochs": 0, "steps": 0}
        best, best_state, stale = math.inf, None, 0
        N = x.shape[0]
        for epoch in range(1, config.max_epochs + 1):
            perm = th.randperm(N, generator=gen)
            total = 0.0
            for a in range(0, N, config.batch_size):
                idx = perm[a:a + config.batch_size]
                loss = gaussian_nll_loss(net(x[idx]), y[idx])
                opt.zero_grad()
                loss.backward()
                opt.step()
                total += loss.item() * idx.numel()
                hist["steps"] += 1
            with th.no_grad():
                v = float(gaussian_nll_loss(net(xv), yv))
            hist["train_loss"].append(total / N)
            hist["val_loss"].append(v)
            hist["epochs"] = epoch
            if progress:
                import sys
                print(f"learned-r epoch {epoch}: train {total / N:.4f} val {v:.4f}", file=sys.stderr)
            if v < best - 1e-6:
                best, stale, hist["best_epoch"] = v, 0, epoch
                best_state = {k: t.clone() for k, t in net.state_dict().items()}
            else:
                stale += 1
                if stale >= config.patience:
                    break
        if best_state is not None:
            net.load_state_dict(best_state)
        return net, hist
    finally:
        th.set_num_threads(threads)


def heldout_metrics(s, data: dict) -> dict:
    """Scores of the log inflations ``s`` (N,) on held-out samples ``data`` (:func:`collect_channel_data`).

    Returns
    -------
    dict: ``nll_m`` the mean Gaussian NLL of the true pseudorange errors [nats, errors in m] under the predicted
    variances ``sigma^2 exp(s)``, beside ``nll_reported_m`` (the receiver's sigmas, ``s = 0``) and
    ``nll_true_var_m`` (the simulator's true variances, the floor of a variance model); ``auc_nlos`` the
    probability that an NLOS channel gets a larger ``s`` than a clean one (None without both classes);
    ``spearman_true_var`` the rank correlation of ``s`` with the true variance ratio (NaN for a constant ``s``); ``frac_below_reported``
    the share of channels with ``s < 0`` (deflation: clipped to x1 in the env); ``mean_log10_inflation`` of
    the clipped action; ``samples``, ``nlos_fraction``.
    """
    from scipy.stats import rankdata, spearmanr
    s = np.asarray(s, np.float64)
    y, sig, vr, nl = (np.asarray(data[k]) for k in ("y", "sigma", "var_ratio", "nlos"))

    def nll(si):
        return float(np.mean(0.5 * (math.log(2 * math.pi) + np.log(sig ** 2) + si + y * y * np.exp(-si))))
    n1, n0 = int(nl.sum()), int((~nl).sum())
    auc = None
    if n1 and n0:
        r = rankdata(s)
        auc = float((r[nl].sum() - n1 * (n1 + 1) / 2) / (n1 * n0))
    rho = spearmanr(s, vr).statistic if s.size > 2 and np.ptp(s) > 0 else float("nan")  # constant s: no rank order
    return {"samples": int(s.size), "nlos_fraction": float(nl.mean()) if s.size else None,
            "nll_m": nll(s), "nll_reported_m": nll(np.zeros_like(s)), "nll_true_var_m": nll(np.log(vr)),
            "auc_nlos": auc, "spearman_true_var": float(rho),
            "frac_below_reported": float(np.mean(s < 0)),
            "mean_log10_inflation": float(np.mean(np.clip(s / math.log(10), 0.0, 4.0)))}


# -------------------------------------------------------------------------------------------------- files
MODEL_FORMAT = "navgym-learned-r-1"


def save_model(path, net: LearnedRNet) -> Path:
    """Write ``net`` to ``path`` atomically (torch: format tag, input feature names, hidden sizes, state dict)."""
    path = Path(path)
    blob = {"format": MODEL_FORMAT, "env": ENV_ID, "input_features": list(INPUT_FEATURES),
            "hidden": list(net.hidden), "state_dict": net.state_dict()}
    with atomic_path(path) as tmp:
        th.save(blob, tmp)
    return path


def load_model(path) -> LearnedRNet:
    """The network of a ``train.py learned-r`` run: ``path`` is its ``model.pt`` or its folder.

    Raises
    ------
    FileNotFoundError
        no such file (one line naming the path).
    ValueError
        the file is not a learned-r model, or was trained on other channel features (one line naming it).
    """
    p = Path(path)
    if p.is_dir():
        p = p / MODEL_FILE
    if not p.is_file():
        raise FileNotFoundError(f"learned-r: no model file {str(p)!r} (train.py learned-r --out DIR writes "
                                f"DIR/{MODEL_FILE})")
    try:
        blob = th.load(p, map_location="cpu", weights_only=True)
    except Exception as e:  # torch raises many kinds for a file that is not its own
        raise ValueError(f"learned-r: {p} is not a torch file ({type(e).__name__})") from None
    if not isinstance(blob, dict) or blob.get("format") != MODEL_FORMAT:
        raise ValueError(f"learned-r: {p} is not a learned-r model (no format tag {MODEL_FORMAT!r})")
    if list(blob.get("input_features", [])) != list(INPUT_FEATURES):
        raise ValueError(f"learned-r: {p} was trained on other channel features than this version's "
                         f"({len(blob.get('input_features', []))} vs {len(INPUT_FEATURES)}); retrain it")
    net = build_net(tuple(blob["hidden"]))
    try:
        net.load_state_dict(blob["state_dict"])
    except (RuntimeError, KeyError) as e:
        raise ValueError(f"learned-r: {p}: weights do not fit the network ({str(e).splitlines()[0]})") from None
    net.eval()
    return net


# -------------------------------------------------------------------------------------------------- train
def train_learned_r(out, config: LearnedRConfig | None = None, quick: bool = False, progress: bool = True) -> dict:
    """Collect the splits, fit the network, score it on the test split and write ``model.pt``,
    ``config.json`` and ``metrics.json`` into ``out`` (each atomically); returns the metrics.

    Parameters
    ----------
    out : output folder (created).
    config : settings (default :class:`LearnedRConfig`, or :data:`QUICK` with ``quick``; a given config wins).
    quick : the small preset (recorded in ``config.json``); progress : lines on stderr (collection, epochs).
    """
    import sys
    cfg = config if config is not None else (QUICK if quick else LearnedRConfig())
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    seeds = split_seeds(cfg)
    rng = np.random.default_rng([cfg.seed, 36])
    data = {}
    for name in ("train", "val", "test"):
        if progress:
            print(f"learned-r: collecting {name} ({len(seeds[name])} episodes)", file=sys.stderr)
        # the test split runs at x1 only: the kf as the receiver reports, as eval.py's baseline rows
        data[name] = collect_split(cfg, seeds[name], rng, explore=name != "test")
    collect_s = time.perf_counter() - t0
    net, hist = fit_net(data["train"], data["val"], cfg, progress=progress)
    save_model(out / MODEL_FILE, net)
    test = heldout_metrics(predict_log_inflation(net, data["test"]["x"]), data["test"])
    val = heldout_metrics(predict_log_inflation(net, data["val"]["x"]), data["val"])
    settings = {"env": ENV_ID, "seed": cfg.seed, "quick": bool(quick),
                "input_features": list(INPUT_FEATURES), "excluded_features": list(EXCLUDED_FEATURES),
                "label": "y = true pseudorange error (GnssData.pr_error_m) / reported sigma, per channel and epoch",
                "output": "s = ln(predicted variance / reported variance); action log10_inflation = clip(s / ln 10, "
                          "0, 4)",
                "train_config": dataclasses.asdict(cfg), "seeds": seeds,
                "samples": {k: int(v["x"].shape[0]) for k, v in data.items()},
                "env_steps": int(sum(len(v) for v in seeds.values()) * round(cfg.episode_length_s))}
    write_atomic(out / CONFIG_FILE, dumps(settings, indent=2))
    metrics = {"seed": cfg.seed, "test": test, "val": val, "training": hist,
               "collect_seconds": collect_s, "wall_seconds": time.perf_counter() - t0,
               "definitions": {"nll_m": "mean 0.5 (log 2 pi + log var + e^2 / var) of the true pseudorange errors e "
                                        "[m] on the split's channels (lower is better)",
                               "test": f"seeds {TEST_SEED_BASE}+k, default action (x1); val: the early-stopping "
                                       "split, with exploration rows"}}
    write_atomic(out / METRICS_FILE, dumps(metrics, indent=2))
    return metrics


# ------------------------------------------------------------------------------------------------- policy
class LearnedRPolicy:
    """``learned-r`` as a fixed policy of ``GnssIns/SatelliteR-v0`` (module docstring): per channel the action of
    ``log10_inflation = clip(s / ln 10, 0, 4)``, the default action (x1) on empty channels.

    Parameters
    ----------
    net : the network (:func:`load_model`); layout : the env observation's
        :class:`~envs.satellite_env.ChannelLayout` (any channel count: the network is per channel).
    """

    def __init__(self, net: LearnedRNet, layout):
        from envs.satellite_env import INFLATION_SPEC
        self.net, self.layout, self.spec = net, layout, INFLATION_SPEC

    @classmethod
    def for_env(cls, net: LearnedRNet, env_kwargs: dict) -> "LearnedRPolicy":
        """The policy for the observations of ``GnssIns/SatelliteR-v0`` with ``env_kwargs``."""
        from envs.channel_features import N_CHANNEL_FEATURES
        from envs.satellite_env import ChannelLayout
        from .rollout import env_class
        env = env_class(ENV_ID)
        core = env.core_for(env.config_from(env_kwargs), 1)
        return cls(net, ChannelLayout(core.global_dim, core.n_channels, N_CHANNEL_FEATURES))

    def reset(self, batch_size: int):
        pass

    def log_inflation(self, obs) -> np.ndarray:
        """(B, C) ``s`` of the channels of observations ``obs`` (B, obs_dim) (0 on empty channels)."""
        G, C, F = self.layout.global_dim, self.layout.channels, self.layout.features
        obs = np.asarray(obs, np.float64)
        if obs.ndim != 2 or obs.shape[1] != self.layout.size:
            raise ValueError(f"learned-r: observations of shape {obs.shape}, expected (B, {self.layout.size})")
        x = th.as_tensor(obs[:, G:G + C * F].reshape(-1, C, F))
        with th.no_grad():
            return self.net(x, th.as_tensor(obs[:, G + C * F:])).numpy()

    def act(self, obs) -> np.ndarray:
        s = self.log_inflation(obs)
        v = np.clip(s / math.log(10.0), self.spec.low, self.spec.high)
        return np.asarray(self.spec.to_action(v), np.float64)
