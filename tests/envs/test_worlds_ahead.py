"""Worlds of coming resets drawn in batches in this process (envs.worlds_ahead) change no result: the single env and
a small vector env give the same episodes, bit for bit, with it and without it (``max_rows = 1``), across resets
with and without a seed; the parts of a batch equal the worlds of their seeds drawn alone; the depth grows only
while the streams go on."""
import gc
import threading

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from envs.datasets.errors import shared_data_dir
from envs.gnss_ins_env import make_config
from envs.prepared import CHANNEL_ARRAY_NAMES, WORLD_ARRAY_NAMES, prepare_world
from envs.worlds_ahead import WorldsAhead, shared_buffers

EPISODE_S = 3.0  # 3 steps per episode


def _count_draws(ahead, buffers_seen=None):
    """Wrap the world draws of ``ahead``'s config: returns the list of each draw's batch size (and appends the
    buffers each draw was given to ``buffers_seen``)."""
    sizes = []
    config = ahead.config
    make = config.make_world

    class Counting:
        def __getattr__(self, name):
            return getattr(config, name)

        def make_world(self, seeds, buffers=None, for_reset=False):
            sizes.append(len(seeds))
            if buffers_seen is not None:
                buffers_seen.append(buffers)
            return make(seeds, buffers=buffers, for_reset=for_reset)

    ahead.config = Counting()
    return sizes


def _in_thread(fn):
    """``fn()`` run in a new thread (a thread of its own: its own shared bulk arrays); returns its result or raises
    its exception."""
    out = {}

    def run():
        try:
            out["result"] = fn()
        except BaseException as e:  # noqa: BLE001 - handed to the caller
            out["error"] = e

    t = threading.Thread(target=run)
    t.start()
    t.join()
    if "error" in out:
        raise out["error"]
    return out["result"]


def _episode(env, seed):
    """One zero-action episode after ``env.reset(seed=seed)``: its observations, world seed and rewards."""
    a = np.zeros(env.action_space.shape, np.float32)
    obs, info = env.reset(seed=seed)
    out = [obs, np.array([info["seed"]])]
    done = False
    while not done:
        obs, rew, term, trunc, _ = env.step(a)
        out += [obs, np.array([rew])]
        done = term or trunc
    return out


def _single_run(env, episodes, reseed=None):
    """Zero-action episodes; ``reseed``: reset with this seed (+ episode) every episode, else once."""
    out = []
    for ep in range(episodes):
        out += _episode(env, 7 if ep == 0 else (None if reseed is None else reseed + ep))
    return out


@pytest.mark.parametrize("env_id", ["GnssIns/SageHusa-v1", "GnssIns/SatelliteR-v0"])
def test_the_single_env_gives_the_same_episodes_with_worlds_drawn_ahead(env_id):
    plain = gym.make(env_id, episode_length_s=EPISODE_S)
    ahead = gym.make(env_id, episode_length_s=EPISODE_S)
    plain.unwrapped.core.worlds_ahead.max_rows = 1  # never ahead: every world drawn at its reset
    sizes = _count_draws(ahead.unwrapped.core.worlds_ahead)
    try:
        a, b = _single_run(plain, 12), _single_run(ahead, 12)
        assert len(a) == len(b)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x, y)
        # the first two resets draw their own worlds, then batches of 2, 4, 8 resets cover the other ten
        assert sizes == [2, 4, 8], sizes
    finally:
        plain.close()
        ahead.close()


def test_single_envs_of_one_thread_draw_into_one_set_of_bulk_arrays_and_give_the_same_episodes():
    """A DummyVecEnv of single envs (RL Zoo): their batches share this thread's bulk arrays (one set, not one per env)
    and each env's episodes, interleaved with the other's, equal its episodes alone; the last ``close()`` releases
    the arrays."""
    def run():
        plain = gym.make("GnssIns/SageHusa-v1", episode_length_s=EPISODE_S)
        plain.unwrapped.core.worlds_ahead.max_rows = 1
        pair = [gym.make("GnssIns/SageHusa-v1", episode_length_s=EPISODE_S) for _ in range(2)]
        seen = []
        sizes = [_count_draws(e.unwrapped.core.worlds_ahead, seen) for e in pair]
        alone = _single_run(plain, 8)
        plain.close()
        runs = [[], []]
        for ep in range(8):
            for e, out in zip(pair, runs):  # episode by episode, in turn
                out += _episode(e, 7 if ep == 0 else None)
        for out in runs:
            for x, y in zip(alone, out, strict=True):
                np.testing.assert_array_equal(x, y)
        assert sizes == [[2, 4], [2, 4]], sizes
        assert len(seen) == 4 and all(b is shared_buffers() for b in seen)
        held = shared_buffers().nbytes
        pair[0].close()
        kept = shared_buffers().nbytes
        pair[1].close()
        return held, kept, shared_buffers().nbytes, shared_buffers()

    held, kept, left, theirs = _in_thread(run)
    assert held > 0 and kept == held and left == 0
    assert theirs is not shared_buffers()  # another thread, another set


def test_an_env_dropped_without_close_releases_the_shared_bulk_arrays():
    def run():
        env = gym.make("GnssIns/SageHusa-v1", episode_length_s=EPISODE_S)
        _single_run(env, 6)
        held = shared_buffers().nbytes
        del env
        gc.collect()
        return held, shared_buffers().nbytes

    held, left = _in_thread(run)
    assert held > 0 and left == 0


def test_a_loop_that_reseeds_every_episode_never_draws_ahead():
    env = gym.make("GnssIns/SageHusa-v1", episode_length_s=EPISODE_S)
    sizes = _count_draws(env.unwrapped.core.worlds_ahead)
    try:
        _single_run(env, 6, reseed=100)
        assert sizes == []
    finally:
        env.close()


def _vector_run(env, seed, steps, B):
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    out = [obs, info["seed"]]
    for _ in range(steps):
        obs, rew, term, trunc, info = env.step(rng.uniform(-1, 1, (B, 1)).astype(np.float32))
        out += [obs, rew]
        if "final_obs" in info:
            out.append(np.stack(info["final_obs"][info["_final_obs"]]))
    return out


def test_a_small_vector_env_gives_the_same_episodes_with_worlds_drawn_ahead():
    B = 3
    envs_ = [gym.make_vec("GnssIns/SageHusa-v1", num_envs=B, vectorization_mode="vector_entry_point",
                          episode_length_s=EPISODE_S) for _ in range(2)]
    plain, ahead = envs_
    plain.unwrapped.core.worlds_ahead.max_rows = 1
    sizes = _count_draws(ahead.unwrapped.core.worlds_ahead)
    try:
        # 8 automatic resets, a new seed, then 4 more
        for seed, steps in ((11, 25), (5, 13)):
            a, b = _vector_run(plain, seed, steps, B), _vector_run(ahead, seed, steps, B)
            for x, y in zip(a, b, strict=True):
                np.testing.assert_array_equal(x, y)
        # 3 rows, at most 16 // 3 = 5 resets per batch: after each seed the first reset and the first automatic
        # one draw their own worlds, then batches of 2, 4, 5 resets (6, 12, 15 rows)
        assert sizes == [6, 12, 15, 6, 12], sizes
    finally:
        plain.close()
        ahead.close()


def test_the_parts_of_a_batch_equal_the_worlds_of_their_seeds_alone():
    config = make_config({"method": "sage-husa"}, {"episode_length_s": EPISODE_S})
    ahead = WorldsAhead(config)
    ahead._draws = 3  # as after three draws: the next covers 4 resets
    coming = [[3, 4], [5, 6], [7, 8]]
    got = ahead.take([1, 2], lambda k: coming[:k])
    assert got.seeds == (1, 2)
    for seeds in ([1, 2], [3, 4], [5, 6], [7, 8]):
        part = got if seeds == [1, 2] else ahead.take(seeds, None)  # drawn ahead: no coming seeds asked for
        ref = prepare_world(config, seeds)
        assert part.seeds == tuple(seeds) and part.world.seeds == seeds and part.has_rate == ref.has_rate
        for name in WORLD_ARRAY_NAMES + CHANNEL_ARRAY_NAMES:
            np.testing.assert_array_equal(part.arrays[name], ref.arrays[name], err_msg=name)
        for name in ("r_e", "v_e", "C_eb", "clock_bias_m", "pos_cov_e"):
            np.testing.assert_array_equal(getattr(part.world.init, name), getattr(ref.world.init, name))
    # now 8 resets per batch (16 // 2 of 2 rows, 16 // 3 = 5 of 3); a reset of seeds not drawn ahead draws again
    assert ahead.depth(2) == 8 and ahead.depth(3) == 5
    assert ahead.take([9], lambda k: [[10 + j] for j in range(k)]).seeds == (9,)
    assert set(ahead._parts) == {(10 + j,) for j in range(7)}


def test_coming_seeds_of_the_wrong_shape_are_refused():
    ahead = WorldsAhead(make_config({"method": "sage-husa"}, {"episode_length_s": EPISODE_S}))
    ahead._draws = 3
    with pytest.raises(ValueError, match=r"coming\(3\) must give 3 lists of 2 seeds"):
        ahead.take([1, 2], lambda k: [[3]] * k)


def test_rows_outside_the_prepared_world_are_refused():
    p = prepare_world(make_config({"method": "sage-husa"}, {"episode_length_s": EPISODE_S}), [1, 2])
    with pytest.raises(ValueError, match="rows 1:3 outside the 2 rows"):
        p.rows(1, 3)


@pytest.mark.parametrize("episode_s, rows", [(60.0, 16), (120.0, 8), (300.0, 3), (600.0, 1)])
def test_long_episodes_draw_fewer_rows_ahead(episode_s, rows):
    ahead = WorldsAhead(make_config({"method": "sage-husa"}, {"episode_length_s": episode_s}))
    assert ahead.depth(1) == 1  # the first two draws after a restart: never ahead
    ahead._draws = 10
    assert ahead.depth(1) == rows and ahead.depth(2) == max(1, rows // 2)


def test_a_cloned_core_starts_with_empty_world_caches_and_steps_the_same():
    env = gym.make("GnssIns/SageHusa-v1", episode_length_s=EPISODE_S)
    try:
        _single_run(env, 6)
        env.reset()  # the 7th reset: the world of the 8th is drawn ahead, in the core's caches
        core = env.unwrapped.core
        assert core.worlds_ahead._parts and shared_buffers().nbytes
        twin = core.clone()
        assert twin.worlds_ahead is not core.worlds_ahead and not twin.worlds_ahead._parts
        assert not twin.world_buffers._arrays and twin.worlds_ahead.config is core.config
        a = np.zeros((1, core.action_dim))
        np.testing.assert_array_equal(core.step(a).obs, twin.step(a).obs)
    finally:
        env.close()


@pytest.mark.skipif(not (shared_data_dir() / "smartloc" / "Berlin_Potsdamer_Platz_GT.txt").is_file(),
                    reason="smartLoc data not found in ../shared/data (absent in a fresh clone; CI has it)")
def test_a_replayed_recording_gives_the_same_episodes_with_worlds_drawn_ahead():
    """A recording's rows differ only in their seeds' synthesized IMU and initial errors: a batch's part is the
    world of its seed alone there too."""
    kw = dict(scenario="smartloc-potsdamer-platz", episode_length_s=EPISODE_S)
    plain, ahead = gym.make("GnssIns/SageHusa-v1", **kw), gym.make("GnssIns/SageHusa-v1", **kw)
    plain.unwrapped.core.worlds_ahead.max_rows = 1
    sizes = _count_draws(ahead.unwrapped.core.worlds_ahead)
    try:
        for x, y in zip(_single_run(plain, 8), _single_run(ahead, 8), strict=True):
            np.testing.assert_array_equal(x, y)
        assert sizes == [2, 4], sizes  # resets 3-4 and 5-8 drawn ahead
    finally:
        plain.close()
        ahead.close()
