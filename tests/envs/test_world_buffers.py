"""envs.sim.buffers.WorldBuffers: arrays reused across world draws only when nobody else holds them, and worlds
drawn through them equal to worlds drawn without."""
from __future__ import annotations

import copy
import pickle
from dataclasses import fields

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the env ids)
from envs.sim.buffers import WorldBuffers
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world


def test_reused_only_when_unreferenced():
    """The same array comes back once its holder is gone; a live reference or view, or another shape or dtype,
    gets a new one."""
    buf = WorldBuffers()
    a = buf.empty("x", (4, 3), np.float64)
    b = buf.empty("x", (4, 3), np.float64)
    assert b is not a                                        # a still held
    del a
    c = buf.empty("x", (4, 3), np.float64)
    assert c is not b                                        # b still held (the kept one is b now)
    del b
    v = c[1:]                                                # a view keeps c alive
    del c
    d = buf.empty("x", (4, 3), np.float64)
    assert np.shares_memory(d, v) is False
    del v, d
    e = buf.empty("x", (4, 3), np.float64)
    f_id = id(e)
    del e
    assert id(buf.empty("x", (4, 3), np.float64)) == f_id   # nobody holds it: handed out again
    assert buf.empty("x", (5, 3), np.float64).shape == (5, 3)
    assert buf.empty("x", (5, 3), np.float32).dtype == np.float32
    assert buf.nbytes == 5 * 3 * 4
    buf.clear()
    assert buf.nbytes == 0


def test_copies_and_pickles_start_empty():
    """A deep copy (TuningCore.clone) or a pickle of the buffers carries no memory."""
    buf = WorldBuffers()
    keep = buf.empty("x", (100, 3), np.float64)
    assert buf.nbytes == keep.nbytes
    assert copy.deepcopy(buf).nbytes == 0
    assert pickle.loads(pickle.dumps(buf)).nbytes == 0


def _arrays(w):
    out = {}
    for part in ("truth", "imu", "gnss"):
        obj = getattr(w, part)
        for f in fields(obj):
            v = getattr(obj, f.name)
            if isinstance(v, np.ndarray):
                out[f"{part}.{f.name}"] = v.copy()
    return out


def test_worlds_through_buffers_equal_and_a_held_world_survives():
    """Three draws through one WorldBuffers equal the draws without it, bit for bit; the first world, still held
    while the others are drawn, keeps its values (its arrays are never handed out again)."""
    scen = get_scenario("urban", duration_s=20.0)
    buf = WorldBuffers()
    held = generate_world(scen, [1, 2, 3], buffers=buf)
    held_copy = _arrays(held)
    for seeds in ([4, 5, 6], [7, 8, 9]):
        w = generate_world(scen, seeds, buffers=buf)
        ref = _arrays(generate_world(scen, seeds))
        for k, v in _arrays(w).items():
            np.testing.assert_array_equal(v, ref[k], err_msg=k)
        del w
    assert buf.nbytes > 0
    for k, v in _arrays(held).items():
        np.testing.assert_array_equal(v, held_copy[k], err_msg=k)
    np.testing.assert_array_equal(_arrays(generate_world(scen, [1, 2, 3]))["imu.f_b"], held_copy["imu.f_b"])


def test_overlapped_stages_give_the_world_of_the_stages_in_turn(monkeypatch):
    """From OVERLAP_ROWS rows on the IMU stage runs on its own thread beside the GNSS stages (through one
    WorldBuffers, two draws): the same world, bit for bit, as with the stages in turn."""
    from envs.sim import world
    scen = get_scenario("urban", duration_s=20.0)
    seeds = list(range(30, 30 + max(world.OVERLAP_ROWS, 2)))
    buf = WorldBuffers()
    overlapped = [_arrays(generate_world(scen, s, buffers=buf)) for s in (seeds, [x + 100 for x in seeds])]
    monkeypatch.setattr(world, "OVERLAP_ROWS", 10**9)
    in_turn = [_arrays(generate_world(scen, s)) for s in (seeds, [x + 100 for x in seeds])]
    for a, b in zip(overlapped, in_turn):
        assert a.keys() == b.keys()
        for k in a:
            np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_env_resets_reuse_the_buffers_and_close_releases_them():
    """The vector env's automatic resets draw into the same arrays; close() releases them."""
    env = gym.make_vec("GnssIns/SageHusa-v1", num_envs=4, vectorization_mode="vector_entry_point",
                       episode_length_s=5.0)
    env.reset(seed=0)
    buf = env.unwrapped.core.world_buffers
    first = {k: id(a) for k, a in buf._arrays.items()}
    assert "imu.f_b" in first and "truth.C_eb" in first
    zero = np.zeros(env.action_space.shape, env.action_space.dtype)
    for _ in range(12):                                      # two automatic resets of every row
        env.step(zero)
    assert {k: id(a) for k, a in buf._arrays.items()} == first
    env.close()
    assert buf.nbytes == 0


def test_a_world_for_a_reset_is_the_same_world_where_it_is_formed():
    """``generate_world(..., for_reset=True)`` (the env's resets, through buffers) forms the true states only at
    sample 0 and the epochs and records no IMU bias: the same bits there, the same IMU samples, GNSS, initial
    estimate and odometer, and the same reset arrays (``world_arrays``); a non-bool is refused."""
    from envs.prepared import world_arrays
    scen = get_scenario("urban", duration_s=20.0)
    seeds = [3, 4, 5]
    whole = generate_world(scen, seeds)
    buf = WorldBuffers()
    for _ in range(2):                                               # the second draw reuses the arrays
        w = generate_world(scen, seeds, buffers=buf, for_reset=True)
        assert w.truth.r_e is None and w.truth.states_every == scen.samples_per_epoch
        assert w.imu.gyro_bias is None and w.imu.accel_bias is None
        got, ref = _arrays(w), _arrays(whole)
        assert set(ref) - set(got) == {"truth.r_e", "truth.v_e", "truth.C_eb", "imu.gyro_bias", "imu.accel_bias"}
        for key, val in got.items():
            np.testing.assert_array_equal(val, ref[key], err_msg=key)
        idx = np.concatenate([[0], w.epoch_idx])
        for name in ("r_e", "v_e", "C_eb"):
            np.testing.assert_array_equal(getattr(w.truth.take(idx), name), getattr(whole.truth.take(idx), name))
        for name in ("r_e", "v_e", "C_eb", "pos_cov_e"):
            np.testing.assert_array_equal(getattr(w.init, name), getattr(whole.init, name))
        a, b = world_arrays(w), world_arrays(whole)
        for key in a:
            np.testing.assert_array_equal(a[key], b[key], err_msg=key)
        # the buffers hold the coarse states and no bias records: the whole world's buffers less those
        whole_buf = WorldBuffers()
        generate_world(scen, seeds, buffers=whole_buf)
        dense = [whole.truth.r_e, whole.truth.v_e, whole.truth.C_eb, whole.imu.gyro_bias, whole.imu.accel_bias]
        coarse = [w.truth.coarse.r_e, w.truth.coarse.v_e, w.truth.coarse.C_eb]
        assert whole_buf.nbytes - buf.nbytes == sum(x.nbytes for x in dense) - sum(x.nbytes for x in coarse)
        del w
    with pytest.raises(ValueError, match="for_reset must be a bool"):
        generate_world(scen, seeds, for_reset="yes")
