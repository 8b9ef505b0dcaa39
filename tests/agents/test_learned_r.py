"""The supervised per-satellite noise model ``learned-r`` (agents.learned_r, train.py learned-r, eval.py
``learned-r:PATH``)."""
from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
import torch as th

from agents.learned_r import (INPUT_FEATURES, LearnedRConfig, LearnedRPolicy, build_net, collect_channel_data,
                              fit_net, gaussian_nll_loss, heldout_metrics, load_model, save_model, split_seeds,
                              train_learned_r)
from envs.channel_features import CHANNEL_FEATURES, N_CHANNEL_FEATURES

TINY = LearnedRConfig(episode_length_s=20.0, n_train=4, n_val=2, n_test=2, rows=4, max_epochs=3, patience=2,
                      batch_size=64, hidden=(8,))


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("lr")
    metrics = train_learned_r(out, TINY, progress=False)
    return out, metrics


def test_loss_is_minimized_by_the_true_log_variance():
    # y ~ N(0, v) per group: d/ds mean(exp(-s) y^2 + s) = 0 at s = log mean(y^2) (analytic), and the expected
    # loss at the true log variance is below any other constant
    rng = np.random.default_rng(0)
    v = np.array([0.25, 4.0, 100.0])
    y = rng.standard_normal((200_000, 3)) * np.sqrt(v)
    for k in range(3):
        s_hat = math.log(np.mean(y[:, k] ** 2))
        assert abs(s_hat - math.log(v[k])) < 0.02
        best = gaussian_nll_loss(np.full(y.shape[0], s_hat), y[:, k])
        for d in (-0.5, -0.1, 0.1, 0.5):
            assert gaussian_nll_loss(np.full(y.shape[0], s_hat + d), y[:, k]) > best
    # the torch loss is the numpy one, and its gradient vanishes at s = log mean(y^2)
    s = th.tensor(math.log(np.mean(y[:, 1] ** 2)), dtype=th.float64, requires_grad=True)
    loss = gaussian_nll_loss(s.expand(y.shape[0]), th.as_tensor(y[:, 1]))
    loss.backward()
    assert abs(s.grad.item()) < 1e-9
    assert loss.item() == pytest.approx(gaussian_nll_loss(np.full(y.shape[0], s.item()), y[:, 1]), rel=1e-12)


def test_fit_recovers_a_feature_dependent_variance():
    # two kinds of channel (cn0 feature 1 or 0) with error variances 1 and 100: the fitted s ~ log variance
    rng = np.random.default_rng(1)
    n = 4000
    x = np.zeros((n, N_CHANNEL_FEATURES), np.float32)
    bad = rng.random(n) < 0.5
    x[:, 0] = np.where(bad, 0.0, 1.0)
    y = rng.standard_normal(n) * np.where(bad, 10.0, 1.0)
    cfg = dataclasses.replace(TINY, max_epochs=60, patience=60, batch_size=100, lr=1e-2, hidden=(8,))
    net, hist = fit_net({"x": x[:3000], "y": y[:3000]}, {"x": x[3000:], "y": y[3000:]}, cfg)
    with th.no_grad():
        s = net(th.as_tensor(np.array([[1.0] + [0.0] * (N_CHANNEL_FEATURES - 1),
                                       [0.0] * N_CHANNEL_FEATURES])))
    assert abs(s[0].item() - 0.0) < 0.2 and abs(s[1].item() - math.log(100.0)) < 0.2
    assert hist["val_loss"][hist["best_epoch"] - 1] == min(hist["val_loss"])


def test_net_is_permutation_equivariant_and_masked_channels_are_isolated():
    net = build_net((16, 16), seed=3)
    rng = np.random.default_rng(2)
    x = th.as_tensor(rng.uniform(-1, 1, (5, 12, N_CHANNEL_FEATURES)))
    mask = th.as_tensor((rng.random((5, 12)) < 0.7).astype(np.float64))
    s = net(x, mask)
    perm = th.as_tensor(rng.permutation(12))
    assert th.allclose(net(x[:, perm], mask[:, perm]), s[:, perm], atol=1e-12)
    x2 = x.clone()
    x2[mask < 0.5] = 1e3  # garbage on the empty channels
    s2 = net(x2, mask)
    assert th.equal(s2, s) and th.all(s[mask < 0.5] == 0)
    # the excluded feature (the last action) does not move the output
    i = [f[0] for f in CHANNEL_FEATURES].index("last_action")
    x3 = x.clone()
    x3[..., i] = -x3[..., i]
    assert th.equal(net(x3, mask), s) and "last_action" not in INPUT_FEATURES


def test_collected_labels_are_the_simulators_errors():
    from envs.worlds import make_world
    seeds = [700_123, 700_124]
    d = collect_channel_data("urban", seeds, 10.0)
    w = make_world("urban", seeds, duration_s=10.0).gnss
    assert d["x"].shape == (d["y"].size, N_CHANNEL_FEATURES) and d["y"].size == int(w.mask.sum())
    # the normalized errors are those of the world's valid channels (the same multiset per episode)
    for b in range(2):
        m = w.mask[b]
        want = w.pr_error_m[b][m] / w.pr_sigma[b][m]
        assert np.allclose(np.sort(d["y"][d["episode"] == b]), np.sort(want))
        ratio = w.pr_var_true[b][m] / w.pr_sigma[b][m] ** 2
        assert np.allclose(np.sort(d["var_ratio"][d["episode"] == b]), np.sort(ratio))
    assert d["nlos"].sum() == int(w.nlos[w.mask].sum())


def test_heldout_metrics_auc_and_nll():
    y = np.array([0.1, -0.2, 30.0, -25.0])
    data = {"y": y, "sigma": np.ones(4), "var_ratio": np.array([1.0, 1.0, 900.0, 600.0]),
            "nlos": np.array([False, False, True, True])}
    m = heldout_metrics(np.log(data["var_ratio"]), data)
    assert m["auc_nlos"] == 1.0 and m["nll_m"] == pytest.approx(m["nll_true_var_m"])
    assert m["nll_m"] < m["nll_reported_m"] and m["frac_below_reported"] == 0.0
    assert heldout_metrics(-np.log(data["var_ratio"]), data)["auc_nlos"] == 0.0


def test_train_writes_files_with_finite_metrics(run_dir):
    out, metrics = run_dir
    assert {p.name for p in out.iterdir()} == {"model.pt", "config.json", "metrics.json"}
    m = json.loads((out / "metrics.json").read_text())
    for k in ("nll_m", "nll_reported_m", "nll_true_var_m", "spearman_true_var", "mean_log10_inflation"):
        assert math.isfinite(m["test"][k])
    assert m["training"]["epochs"] >= 1 and m["test"]["samples"] > 0
    c = json.loads((out / "config.json").read_text())
    assert c["seeds"] == split_seeds(TINY) and c["input_features"] == list(INPUT_FEATURES)
    assert c["train_config"]["scenarios"] == ["urban", "urban-transition"]
    # held-out seeds are disjoint from training and from eval.py's episode seeds (seed * 1_000_003 + k)
    assert not set(c["seeds"]["train"]) & (set(c["seeds"]["val"]) | set(c["seeds"]["test"]))
    assert min(min(v) for v in c["seeds"].values()) >= 500_000
    net = load_model(out)  # the folder or the file
    assert all(th.equal(a, b) for a, b in zip(net.state_dict().values(), load_model(out / "model.pt")
                                              .state_dict().values()))


def test_policy_actions_follow_the_prediction():
    from envs.satellite_env import INFLATION_SPEC, ChannelLayout
    net = build_net((4,), seed=0)
    with th.no_grad():
        for p in net.parameters():
            p.zero_()
        net.mlp[-1].bias.fill_(math.log(100.0))  # s = ln 100 everywhere: x100, log10 inflation 2
    lay = ChannelLayout(19, 3, N_CHANNEL_FEATURES)
    obs = np.zeros((2, lay.size), np.float32)
    obs[:, -3:] = [[1, 0, 1], [0, 0, 0]]
    a = LearnedRPolicy(net, lay).act(obs)
    want = INFLATION_SPEC.to_action(2.0)
    assert np.allclose(a, [[want, -1.0, want], [-1.0, -1.0, -1.0]])
    net.mlp[-1].bias.data.fill_(-5.0)  # deflation is not in the action space: x1
    assert np.allclose(LearnedRPolicy(net, lay).act(obs), -1.0)
    with pytest.raises(ValueError, match="expected"):
        LearnedRPolicy(net, lay).act(obs[:, :-1])


def test_eval_runs_learned_r(run_dir, tmp_path):
    import eval as ev
    out, _ = run_dir
    res = ev.main(["--scenario", "urban", "--episodes", "2", "--methods",
                   f"kf,learned-r:{out / 'model.pt'},learned-r:{out}[method=kf-fde]", "--out", str(tmp_path / "e"),
                   "--no-plots"])
    per = res["scenarios"]["urban"]
    for label in (f"learned-r:{out / 'model.pt'}", f"learned-r:{out}[method=kf-fde]"):
        assert per[label]["episodes"] == 2 and math.isfinite(per[label]["rmse_h_m"])
    labels = ev.method_labels(res, "urban")
    assert labels[f"learned-r:{out / 'model.pt'}"] == "learned-r"
    assert labels[f"learned-r:{out}[method=kf-fde]"] == "learned-r method=kf-fde"
    assert "| urban | learned-r | 2 |" in ev.format_table(res)


def test_bad_specs_fail_with_one_line(tmp_path):
    from agents.methods import parse_method_spec
    with pytest.raises(FileNotFoundError, match="learned-r: no model file") as e:
        parse_method_spec(f"learned-r:{tmp_path / 'nope.pt'}")
    assert "\n" not in str(e.value)
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="junk.pt is not a torch file"):
        parse_method_spec(f"learned-r:{junk}")
    other = tmp_path / "other.pt"
    th.save({"state_dict": {}}, other)
    with pytest.raises(ValueError, match="not a learned-r model"):
        parse_method_spec(f"learned-r:{other}")
    good = save_model(tmp_path / "m.pt", build_net((4,)))
    with pytest.raises(ValueError, match="unknown option 'b=3'"):
        parse_method_spec(f"learned-r:{good}[b=3]")
    with pytest.raises(ValueError, match="nosuchfilter"):
        parse_method_spec(f"learned-r:{good}[method=nosuchfilter]")
    assert parse_method_spec(f"learned-r:{good}[method=kf-fde]").method == "kf-fde"


def test_config_rejects_bad_values():
    with pytest.raises(ValueError, match="LearnedRConfig.seed"):
        LearnedRConfig(seed=80)
    with pytest.raises(ValueError, match="not a simulated scenario"):
        LearnedRConfig(scenarios=("smartloc-berlin",))
    with pytest.raises(ValueError, match="explore_rows"):
        LearnedRConfig(explore_rows=1.5)
