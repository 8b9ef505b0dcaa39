"""Branching in the env core (copy_rows, clone) and the hindsight oracles built on it (agents.oracles).

Small on purpose (2-4 episodes of 20-40 s): each property is checked on few rows, exactly.
"""
import numpy as np
import pytest

from agents.rollout import env_class, run_policy_episodes
from envs.core import TuningCore
from envs.gnss_ins_env import make_config


def _core(env_id, B, **kw):
    cls = env_class(env_id)
    cfg = make_config(cls.DEFAULTS, {"scenario": "noise-burst", "episode_length_s": 30.0, **kw})
    return TuningCore(cfg, cls.PARAMS, B)


def _step_all(core, actions):
    """Step with (B, k) actions; the step's arrays that must match between branches."""
    r = core.step(actions)
    out = {"obs": r.obs, "reward": r.reward, "terminated": r.terminated, "truncated": r.truncated}
    out.update({f"info:{k}": np.asarray(v) for k, v in r.info.items()})
    return out


def _row(d, b):
    return {k: v[b] for k, v in d.items()}


@pytest.mark.parametrize("env_id, kw", [
    ("GnssIns/SageHusa-v0", {}),
    ("GnssIns/SageHusa-v0", {"method": "svd-asrkf", "reward": "advantage", "history": 3}),
    ("GnssIns/STKF-v0", {}),
    ("GnssIns/MASTKF-v0", {"zupt": "truth"}),
])
def test_core_copy_rows_continues_bit_identically(env_id, kw):
    """Rows 0 <- 1 and 2 <- 0 (overlapping, different worlds) continue exactly like the uncopied rows."""
    seeds = [101, 102, 103]
    core, ref = _core(env_id, 3, **kw), _core(env_id, 3, **kw)
    core.reset_rows(np.arange(3), seeds)
    ref.reset_rows(np.arange(3), seeds)
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (core.M, 3, core.k))  # per epoch, per world
    n0 = 12
    for j in range(n0):
        _step_all(core, acts[j])
        _step_all(ref, acts[j])
    core.copy_rows([0, 2], [1, 0])
    perm = np.array([1, 1, 0])  # the world each row of `core` now carries
    assert core.seeds == [seeds[p] for p in perm]
    for j in range(n0, core.M):
        a, b = _step_all(core, acts[j][perm]), _step_all(ref, acts[j])
        for row in range(3):
            for k in a:
                np.testing.assert_array_equal(a[k][row], b[k][perm[row]], err_msg=f"epoch {j} row {row} {k}")
    np.testing.assert_array_equal(core.est_track, ref.est_track[perm])
    assert core.episode_metrics(range(3)) == [ref.episode_metrics([p])[0] for p in perm]


def test_clone_is_an_independent_snapshot():
    core = _core("GnssIns/SageHusa-v0", 2)
    core.reset_rows(np.arange(2), [5, 6])
    for _ in range(5):
        core.step(np.zeros((2, 1)))
    snap = core.clone()
    assert snap.f is core.f  # the world is shared, not copied
    later = [_step_all(core, np.full((2, 1), 0.3)) for _ in range(4)]
    np.testing.assert_array_equal(snap.t, [5, 5])  # the snapshot did not move with the core
    again = [_step_all(snap, np.full((2, 1), 0.3)) for _ in range(4)]
    for a, b in zip(later, again):
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])
    snap.copy_rows([0], [1])  # copying rows of the snapshot leaves the original alone
    assert core.seeds == [5, 6] and snap.seeds == [6, 6]
    assert not np.array_equal(core.f[0], core.f[1])


def test_copy_rows_refuses_stateful_zupt_detectors():
    core = _core("GnssIns/SageHusa-v0", 2, zupt="shoe")
    core.reset_rows(np.arange(2), [1, 2])
    with pytest.raises(ValueError, match="'shoe' zero-velocity detector.*needs zupt='none'"):
        core.copy_rows([0], [1])
    with pytest.raises(RuntimeError, match="reset"):
        _core("GnssIns/SageHusa-v0", 2).copy_rows([0], [1])
