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
