"""Seed-pooled metrics agree with the single-log metrics where they must, and pool what they claim."""
import numpy as np
import pytest

from envs.episodes import EpisodeLog, concat_logs
from envs.metrics import paired_difference, summarize, summarize_seeds


def _log(h, diverged=None):
    """A log whose horizontal errors are ``h`` (E, M) [m] (north component), other fields neutral."""
    E, M = h.shape
    pos = np.zeros((E, M, 3))
    pos[..., 0] = h
    z = np.zeros((E, M))
    return EpisodeLog(t=np.arange(M, dtype=float), pos_err_ned=pos, vel_err_ned=np.zeros((E, M, 3)), nees_pv=z,
                      nis=z, n_used=z.astype(int), n_sats=z.astype(int), gdop=z, zupt=z.astype(bool),
                      diverged=np.zeros(E, bool) if diverged is None else diverged, filter_time_s=1.0)


def _same_pair(p, q):
    assert p["episodes"] == q["episodes"]
    assert p["diff_rmse_h_m"] == pytest.approx(q["diff_rmse_h_m"], rel=1e-12)
    assert p["rel_diff"] == pytest.approx(q["rel_diff"], rel=1e-12)
    assert p["diff_rmse_h_ci95_m"] == pytest.approx(q["diff_rmse_h_ci95_m"], rel=1e-12)


def test_one_seed_is_the_plain_summary_and_paired_difference():
    rng = np.random.default_rng(0)
    a, ref = _log(rng.gamma(2.0, 1.0, (12, 30))), _log(rng.gamma(2.0, 1.2, (12, 30)))
    g = summarize_seeds([a], ref)
    s = summarize(a)
    for k in ("rmse_h_m", "rmse_3d_m", "max_h_m", "p95_h_m"):
        assert g[k] == pytest.approx(s[k], rel=1e-12)
    assert g["rmse_h_ci95_m"] == pytest.approx(s["rmse_h_ci95_m"], rel=1e-12)
    _same_pair(g["paired_vs_reference"], paired_difference(a, ref))
    assert g["seeds"] == 1 and g["rmse_h_per_seed_m"] == [pytest.approx(s["rmse_h_m"])]


def test_pooling_over_seeds():
    rng = np.random.default_rng(1)
    hs = [rng.gamma(2.0, 1.0 + 0.3 * i, (10, 20)) for i in range(3)]
    logs = [_log(h) for h in hs]
    g = summarize_seeds(logs, logs[0])
    assert g["rmse_h_m"] == pytest.approx(np.sqrt(np.mean(np.square(hs))), rel=1e-12)
    assert g["episodes"] == 10 and g["seeds"] == 3
    assert g["rmse_h_per_seed_m"] == pytest.approx([np.sqrt(np.mean(h ** 2)) for h in hs])
    lo, hi = g["rmse_h_ci95_m"]
    assert lo < g["rmse_h_m"] < hi
    # seeds 1 and 2 have larger errors than the reference (seed 0) on every episode: the pooled difference
    # is positive and the episode bootstrap keeps it so
    p = g["paired_vs_reference"]
    expect = np.sqrt(np.mean(np.square(hs))) - np.sqrt(np.mean(hs[0] ** 2))
    assert p["diff_rmse_h_m"] == pytest.approx(expect, rel=1e-12)
    # identical seeds give the single seed's numbers
    same = summarize_seeds([logs[1]] * 3, logs[0])
    assert same["rmse_h_m"] == pytest.approx(summarize(logs[1])["rmse_h_m"])
    _same_pair(same["paired_vs_reference"], paired_difference(logs[1], logs[0]))


def test_diverged_episodes_leave_the_paired_statistics():
    h = np.ones((4, 5))
    div = np.array([False, True, False, False])
    g = summarize_seeds([_log(h), _log(2 * h, div)], _log(h))
    assert g["paired_vs_reference"]["episodes"] == 3
    assert g["diverged"] == 1
    assert concat_logs([_log(h), _log(h)]).diverged.shape == (8,)
    with pytest.raises(ValueError, match="at least one log"):
        summarize_seeds([])


# --------------------------------------------------------------------------- headroom
from envs.metrics import MIN_CI_EPISODES, headroom, headroom_share  # noqa: E402


def test_headroom_and_its_placebo_net_on_known_errors():
    E = 12
    f, o = np.full(E, 4.0), np.full(E, 1.0)  # RMSE 2 m and 1 m: headroom 50%
    h = headroom(f, o)
    assert h["headroom"] == pytest.approx(0.5) and h["headroom_ci95"] == pytest.approx([0.5, 0.5])
    assert h["net_headroom"] is None and h["ci_note"] is None
    hp = headroom(f, o, placebo=(np.full(15, 4.0), np.full(15, 3.24)))  # placebo oracle RMSE 1.8 m: 10% by luck
    assert hp["placebo_headroom"] == pytest.approx(0.1) and hp["net_headroom"] == pytest.approx(0.4)
    assert hp["net_headroom_ci95"] == pytest.approx([0.4, 0.4]) and hp["placebo_episodes"] == 15
    rng = np.random.default_rng(3)
    fr = rng.gamma(3.0, 2.0, 40)
    orc = fr * rng.uniform(0.5, 0.9, 40)
    r = headroom(fr, orc)
    lo, hi = r["headroom_ci95"]
    assert lo < r["headroom"] < hi and 0 < lo
    expect = 1 - np.sqrt(orc.mean()) / np.sqrt(fr.mean())
    assert r["headroom"] == pytest.approx(expect, rel=1e-12)


def test_share_of_the_headroom_closed():
    E = 10
    f, m, o = np.full(E, 4.0), np.full(E, 2.25), np.full(E, 1.0)  # RMSE 2, 1.5, 1 m
    s = headroom_share(f, m, o)
    assert s["share"] == pytest.approx(0.5) and s["share_ci95"] == pytest.approx([0.5, 0.5])
    assert s["gap_m"] == pytest.approx(1.0) and not s["net"]
    # net of a placebo headroom of 10%: the gap is 1 m - 0.1 x 2 m
    sp = headroom_share(f, m, o, placebo=(np.full(E, 4.0), np.full(E, 3.24)))
    assert sp["gap_m"] == pytest.approx(0.8) and sp["share"] == pytest.approx(0.5 / 0.8) and sp["net"]
    # the oracle closes all of the (gross) headroom, the fixed parameter none of it
    assert headroom_share(f, o, o)["share"] == pytest.approx(1.0)
    assert headroom_share(f, f, o)["share"] == pytest.approx(0.0)
    # no headroom (the oracle is no better than the fixed parameter): no share
    none = headroom_share(f, m, f)
    assert none["share"] is None and "no headroom to close" in none["note"]
    # a headroom indistinguishable from 0: a point share but no CI
    rng = np.random.default_rng(0)
    fr = rng.gamma(2.0, 2.0, 30)
    orc = fr * rng.uniform(0.8, 1.2, 30)
    orc *= fr.mean() / orc.mean() * 0.999  # a 0.05% gap under large per-episode noise
    u = headroom_share(fr, fr, orc)
    assert u["share"] == pytest.approx(0.0, abs=1e-12) and u["share_ci95"] is None and "CI includes 0" in u["note"]


def test_minimum_episodes_for_a_ci():
    n = MIN_CI_EPISODES - 1
    f, m, o = np.full(n, 4.0), np.full(n, 2.25), np.full(n, 1.0)
    h = headroom(f, o, placebo=(np.full(20, 4.0), np.full(20, 3.24)))
    assert h["headroom"] == pytest.approx(0.5) and h["headroom_ci95"] is None and h["net_headroom_ci95"] is None
    assert h["ci_note"] == f"n < {MIN_CI_EPISODES}: no CI"
    s = headroom_share(f, m, o)
    assert s["share"] == pytest.approx(0.5) and s["share_ci95"] is None and s["gap_ci95_m"] is None
    assert s["note"] == f"n < {MIN_CI_EPISODES}: no CI"
    # the placebo's own episode count counts too
    big = np.full(20, 4.0)
    assert headroom(big, big / 4, placebo=(np.full(3, 4.0), np.full(3, 3.24)))["net_headroom_ci95"] is None
    with pytest.raises(ValueError, match="oracle must be a 1-D array"):
        headroom(np.ones(5), np.ones(4))
    with pytest.raises(ValueError, match="method must hold finite"):
        headroom_share(np.ones(5), np.full(5, np.nan), np.ones(5))
