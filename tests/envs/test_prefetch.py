"""Worlds drawn ahead in a background process (envs.prefetch) change no result: a vector env with
``prefetch_worlds`` equals one drawing every world at its reset, bit for bit, across automatic resets, a new
``reset(seed=...)``, cancelled requests and a dead worker."""
import os
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from envs.gnss_ins_env import make_config
from envs.prefetch import WorldPrefetcher
from envs.prepared import WORLD_ARRAY_NAMES, prepare_world

EPISODE_S = 4.0  # 4 steps per episode: automatic resets every 4 steps


def _env(prefetch, B=3):
    env = gym.make_vec("GnssIns/SageHusa-v1", num_envs=B, vectorization_mode="vector_entry_point",
                       episode_length_s=EPISODE_S, prefetch_worlds=prefetch)
    if prefetch:
        assert env.unwrapped._prefetch.wait_ready(120)
    return env


def _run(env, seed, steps, B=3):
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    out = {"obs": [obs], "rew": [], "seed": [info["seed"]], "final": []}
    for _ in range(steps):
        obs, rew, term, trunc, info = env.step(rng.uniform(-1, 1, (B, 1)).astype(np.float32))
        out["obs"].append(obs)
        out["rew"].append(rew)
        if "final_obs" in info:
            done = info["_final_obs"]
            out["final"].append(np.stack(info["final_obs"][done]))
            out["final"].append(np.array([info["final_info"][i]["episode_metrics"]["rmse_h_m"]
                                          for i in np.flatnonzero(done)]))
    return out


def _same(a, b):
    for k in a:
        assert len(a[k]) == len(b[k]), k
        for x, y in zip(a[k], b[k]):
            np.testing.assert_array_equal(x, y, err_msg=k)


def test_prefetched_worlds_give_the_same_episodes():
    plain = _env(0)
    ahead = _env(2)
    try:
        _same(_run(plain, 11, 17), _run(ahead, 11, 17))   # 4 automatic resets
        pf = ahead.unwrapped._prefetch
        assert pf.hits >= 3, (pf.hits, pf.misses)
        # a new reset(seed=...) drops what was drawn ahead for the old seeds
        _same(_run(plain, 5, 9), _run(ahead, 5, 9))
        assert pf.hits >= 5
        # a reset without a seed continues the rows' streams: it takes the worlds drawn ahead for them
        hits = pf.hits
        np.testing.assert_array_equal(plain.reset()[0], ahead.reset()[0])
        np.testing.assert_array_equal(plain.reset()[0], ahead.reset()[0])
        assert pf.hits >= hits + 1, (pf.hits, hits)
    finally:
        plain.close()
        ahead.close()
    assert ahead.unwrapped._prefetch is None  # close() stopped the worker


def test_a_dead_worker_falls_back_to_drawing_at_reset():
    plain = _env(0)
    ahead = _env(2)
    try:
        pf = ahead.unwrapped._prefetch
        pf._proc.kill()
        pf._proc.wait()
        with pytest.warns(RuntimeWarning, match="prefetch process exited"):
            got = _run(ahead, 3, 9)
        _same(_run(plain, 3, 9), got)
        assert pf.hits == 0
    finally:
        plain.close()
        ahead.close()


def test_take_serves_requests_in_order_and_cancels_on_another_grouping():
    config = make_config({"method": "sage-husa"}, {"episode_length_s": EPISODE_S})
    pf = WorldPrefetcher(config, depth=2)
    try:
        assert pf.wait_ready(120)
        assert pf.request([1, 2]) and pf.request([3, 4])
        assert not pf.request([5, 6])  # depth 2 in flight
        assert pf.take([9, 9]) is None and pf.in_flight == 0  # another grouping: both cancelled
        assert pf.request([5, 6]) and pf.request([7])
        got = pf.take([5, 6])
        ref = prepare_world(config, [5, 6])
        assert got.seeds == (5, 6) and got.has_rate == ref.has_rate
        for name in WORLD_ARRAY_NAMES:
            np.testing.assert_array_equal(got.arrays[name], ref.arrays[name], err_msg=name)
        np.testing.assert_array_equal(got.world.init.r_e, ref.world.init.r_e)
        assert pf.take([7]).seeds == (7,)
        assert (pf.hits, pf.misses) == (2, 1)
    finally:
        pf.close()


@pytest.mark.parametrize("value", [-1, 1.5, True, "2"])
def test_prefetch_worlds_must_be_a_non_negative_int(value):
    with pytest.raises(ValueError, match="prefetch_worlds must be an int >= 0"):
        gym.make_vec("GnssIns/SageHusa-v1", num_envs=2, vectorization_mode="vector_entry_point",
                     prefetch_worlds=value)


def test_depth_must_be_positive():
    with pytest.raises(ValueError, match="depth must be an int >= 1"):
        WorldPrefetcher(make_config({"method": "sage-husa"}, {}), depth=0)


def test_reset_rows_rejects_a_prepared_world_of_other_seeds():
    env = gym.make_vec("GnssIns/SageHusa-v1", num_envs=2, vectorization_mode="vector_entry_point",
                       episode_length_s=EPISODE_S)
    core = env.unwrapped.core
    with pytest.raises(ValueError, match="prepared world holds seeds"):
        core.reset_rows(np.arange(2), [1, 2], prepared=prepare_world(core.config, [1, 3]))


def test_a_main_script_without_a_main_guard_can_prefetch(tmp_path):
    """The worker is a fresh interpreter that imports navgym only: the user's script is not re-imported in it
    (as multiprocessing's spawn would), so a script without ``if __name__ == "__main__"`` works."""
    import subprocess
    import sys
    root = Path(__file__).resolve().parents[2]
    script = tmp_path / "plain.py"
    script.write_text(
        "import gymnasium as gym, numpy as np, envs\n"
        "env = gym.make_vec('GnssIns/SageHusa-v1', num_envs=2, vectorization_mode='vector_entry_point',\n"
        f"                   episode_length_s={EPISODE_S}, prefetch_worlds=1)\n"
        "assert env.unwrapped._prefetch.wait_ready(120)\n"
        "env.reset(seed=1)\n"
        "for _ in range(9):\n"
        "    env.step(np.zeros((2, 1), np.float32))\n"
        "print('hits', env.unwrapped._prefetch.hits)\n"
        "env.close()\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(root)] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    p = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.split()[-1] == "2"  # both automatic resets took their prefetched world


def test_a_config_that_cannot_be_pickled_is_refused():
    with pytest.raises(ValueError, match="cannot be sent to the worker process"):
        WorldPrefetcher(lambda: None, depth=1)


class _FailingConfig:
    """A config whose world cannot be drawn, naming the content of ``marker.txt`` in the folder the worker runs
    in (pickled by reference: the worker imports this module)."""

    def make_world(self, seeds, buffers=None, for_reset=False):
        raise ValueError(f"no world for {seeds} (marker: {Path('marker.txt').read_text()})")


@pytest.fixture
def failing_prefetch(tmp_path, monkeypatch):
    """A prefetcher of :class:`_FailingConfig` started from ``tmp_path``, which holds ``marker.txt``."""
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(Path(__file__).parent)]
                                                     + [p for p in [os.environ.get("PYTHONPATH")] if p]))
    (tmp_path / "marker.txt").write_text("here")
    monkeypatch.chdir(tmp_path)
    pf = WorldPrefetcher(_FailingConfig(), depth=1)
    yield pf
    pf.close()


def test_a_world_the_worker_cannot_draw_is_drawn_at_reset_with_a_warning(failing_prefetch):
    """The worker's error comes back as a warning (and the reset draws the world itself, raising it there); the
    worker ran in the caller's folder (a relative path in a config, a dataset spec say, is the same file)."""
    pf = failing_prefetch
    assert pf.wait_ready(120)
    assert pf.request([4, 5])
    with pytest.warns(RuntimeWarning, match=r"failed to draw the world of seeds \[4, 5\].*no world for .*marker: here"):
        assert pf.take([4, 5]) is None
    assert (pf.hits, pf.misses, pf.in_flight) == (0, 1, 0)
