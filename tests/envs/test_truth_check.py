"""Recorded pseudoranges against the truth: the lower-tail clock, the real-data R oracle, the consistency check."""
import dataclasses

import numpy as np
import pytest

from envs.datasets.truth_check import (ORACLE_THRESHOLD_M, recorded_oracle_world, replay_consistency, system_clocks,
                                       truth_errors)
from envs.worlds import make_world, oracle_r_world


def test_lower_tail_clock_resists_a_positive_majority():
    """Two systems, 12 channels each, 60% of them delayed by 20-100 m (NLOS: positive, the majority), 0.5 m noise
    on the rest: the clock of each system (with its own offset) is recovered within 0.5 m at every epoch; the
    median of the channels, which the delays pull up, is off by metres."""
    rng = np.random.default_rng(0)
    M, C = 400, 24
    t = np.arange(M) * 0.2
    clock = -136_000.0 - 50.0 * t + 3.0 * np.sin(t / 20)
    system = np.repeat([[0] * 12 + [1] * 12], M, 0)
    offset = np.where(system == 1, -5.0, 0.0)
    delayed = rng.random((M, C)) < 0.6
    d = clock[:, None] + offset + 0.5 * rng.normal(size=(M, C)) + np.where(delayed, rng.uniform(20, 100, (M, C)), 0)
    clocks = system_clocks(t, d, system)
    for s, truth in ((0, clock), (1, clock - 5.0)):
        err = np.abs(clocks[s] - truth)
        assert err.mean() < 0.2 and err.max() < 1.0, (s, err.mean(), err.max())
    assert np.abs(np.median(d[:, :12], 1) - clock).mean() > 5.0


@pytest.fixture(scope="module")
def open_sky():
    return make_world("open-sky", [3], duration_s=60.0)


def test_consistency_finds_a_known_truth_offset(open_sky):
    """Pseudoranges with 0.5 m white errors (a fifth of them 30-80 m late) are consistent with their truth (no
    offset, every clean one within 3 m); moving the truth by a known east/north/up offset is found back within
    0.3 m per axis. (Errors that persist per satellite, such as the simulator's atmosphere residuals over one
    minute, also fit an offset: the check is a diagnostic of a recording, not a proof of a truth error.)"""
    g = open_sky.gnss
    rng = np.random.default_rng(1)
    noise = 0.5 * rng.normal(size=g.pr.shape) + np.where(rng.random(g.pr.shape) < 0.2, rng.uniform(30, 80, g.pr.shape), 0)
    clean = dataclasses.replace(open_sky, gnss=dataclasses.replace(g, pr_error_m=noise))
    c = replay_consistency(clean)
    assert np.abs(c["offset_enu_m"]).max() < 0.3 and c["within_3m"] > 0.75
    el, az = g.elevation, g.azimuth
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)
    o = np.array([2.0, -4.0, 6.0])   # the truth moved by o: every range seen from it shortens by u . o
    moved = dataclasses.replace(open_sky, gnss=dataclasses.replace(g, pr_error_m=noise + u @ o))
    c = replay_consistency(moved)
    np.testing.assert_allclose(c["offset_enu_m"], -o, atol=0.3)  # the receiver sits at the moved truth - o
    assert c["within_3m_offset"] > c["within_3m"]


def test_recorded_oracle_world_variances_and_exclusion(open_sky):
    """On a world without simulator variances the R oracle is the truth-error one: variances floor^2 + e^2, or
    the pseudoranges more than 3 m off dropped."""
    g = open_sky.gnss
    rec = dataclasses.replace(open_sky, gnss=dataclasses.replace(g, pr_var_true=None, prr_var_true=None))
    e, ok = truth_errors(rec)
    w = oracle_r_world(rec)
    np.testing.assert_allclose(w.gnss.pr_sigma[0][ok], np.sqrt(1.0 + e[ok] ** 2))
    x = recorded_oracle_world(rec, exclude=True)
    np.testing.assert_array_equal(x.gnss.mask[0], ok & (np.abs(np.nan_to_num(e)) <= ORACLE_THRESHOLD_M))
    with pytest.raises(ValueError, match="recorded data set without them"):
        oracle_r_world(dataclasses.replace(rec, gnss=dataclasses.replace(rec.gnss, pr_error_m=None)))
