"""The vector env's ``parallel_kernels``: the serial fallback gives the parallel path's episodes bit for bit.

A vector env of ``PARALLEL_MIN_BATCH`` rows (its row kernels parallel by the fixed rule) stepped with
``parallel_kernels='always'``, ``'never'`` and ``'auto'`` (its governor made to switch often) gives the same
observations, rewards, terminations, truncations and infos over steps with automatic resets; each mode runs the
kernels it claims (checked at every batched step)."""
import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from nav_filters import kernels
from nav_filters.kernels import PARALLEL_MIN_BATCH
from nav_filters.parallel_governor import ParallelGovernor

B = PARALLEL_MIN_BATCH
EPISODE_S = 3.0  # 3 steps per episode: automatic resets at steps 3 and 6
STEPS = 7


def _env(env_id, method, mode):
    kw = {} if method is None else {"method": method}
    env = gym.make_vec(env_id, num_envs=B, vectorization_mode="vector_entry_point", episode_length_s=EPISODE_S,
                       parallel_kernels=mode, **kw)
    u = env.unwrapped
    if mode == "auto":  # switch every few steps, whatever this machine's threads and speed
        u.parallel_governor = ParallelGovernor("auto", batch_size=B, threads=2, probe_every=2, window=1,
                                               start_samples=1)
    seen = []
    step = u.core.step

    def spied(actions):
        seen.append(kernels.rows_forced_serial())  # serial_rows in force during the batched step?
        assert (kernels.row_chunks(B) == 1) == seen[-1]
        return step(actions)

    u.core.step = spied
    return env, seen


def _run(env):
    rng = np.random.default_rng(3)
    obs, info = env.reset(seed=21)
    out = [obs, info]
    for _ in range(STEPS):
        out.extend(env.step(rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)))
    return out


def _same(a, b, where="out"):
    if isinstance(a, dict):
        assert a.keys() == b.keys(), where
        for k in a:
            _same(a[k], b[k], f"{where}[{k!r}]")
    elif isinstance(a, np.ndarray) and a.dtype == object:
        assert a.shape == b.shape, where
        for i, (x, y) in enumerate(zip(a, b)):
            _same(x, y, f"{where}[{i}]")
    elif isinstance(a, (np.ndarray, np.generic, float, int, bool, str)) or a is None:
        np.testing.assert_array_equal(a, b, err_msg=where)
        assert np.asarray(a).dtype == np.asarray(b).dtype, where
    else:
        raise AssertionError(f"{where}: unexpected type {type(a)}")


@pytest.mark.parametrize("env_id, method", [("GnssIns/SageHusa-v1", None), ("GnssIns/SageHusa-v1", "svd-akf"),
                                            ("GnssIns/MASTKF-v1", None), ("GnssIns/SatelliteSageHusa-v0", None)])
def test_serial_fallback_equals_the_parallel_path(env_id, method):
    runs, seen = {}, {}
    for mode in ("always", "never", "auto"):
        env, seen[mode] = _env(env_id, method, mode)
        runs[mode] = _run(env)
        env.close()
    assert len(seen["always"]) == STEPS and not any(seen["always"])
    assert all(seen["never"])
    assert set(seen["auto"]) == {True, False}  # both modes ran
    resets = [i for i, x in enumerate(runs["always"]) if isinstance(x, dict) and "final_obs" in x]
    assert len(resets) == 2  # automatic resets inside the compared steps
    for mode in ("never", "auto"):
        assert len(runs[mode]) == len(runs["always"])
        for i, (a, b) in enumerate(zip(runs["always"], runs[mode])):
            _same(a, b, f"{mode} item {i}")


def test_parallel_kernels_must_be_a_known_mode():
    with pytest.raises(ValueError, match=r"^parallel_kernels must be one of 'auto', 'always', 'never', got 'on'$"):
        gym.make_vec("GnssIns/SageHusa-v1", num_envs=2, vectorization_mode="vector_entry_point",
                     episode_length_s=EPISODE_S, parallel_kernels="on")


def test_the_default_is_auto_and_active_only_where_it_can_choose():
    import numba
    big = gym.make_vec("GnssIns/SageHusa-v1", num_envs=B, vectorization_mode="vector_entry_point",
                       episode_length_s=EPISODE_S).unwrapped.parallel_governor
    small = gym.make_vec("GnssIns/SageHusa-v1", num_envs=2, vectorization_mode="vector_entry_point",
                         episode_length_s=EPISODE_S).unwrapped.parallel_governor
    assert big.policy == small.policy == "auto"
    assert big.active == (numba.get_num_threads() > 1) and not small.active
