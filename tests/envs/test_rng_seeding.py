"""envs.sim.rng's compiled SeedSequence (FastSeedSequence) against numpy's SeedSequence: the same pool, the same
state words, the same streams from PCG64 and SFC64, and numpy's behaviour for everything it does not compute."""
from __future__ import annotations

import pickle

import numpy as np
import pytest

from envs.sim.rng import STREAMS, ChildStreams, FastSeedSequence, entropy_words, row_generators


def _entropies(rng, n):
    """Entropy word arrays of 1 .. 11 words, with zeros and the extremes mixed in."""
    out = [np.array([0], np.uint32), np.array([2**32 - 1] * 9, np.uint32), np.array([0, 0, 0, 0], np.uint32)]
    for _ in range(n):
        w = rng.integers(0, 2**32, int(rng.integers(1, 12)), dtype=np.uint64).astype(np.uint32)
        w[rng.random(w.size) < 0.2] = 0
        out.append(w)
    return out


def test_state_words_equal_seed_sequence():
    """The state words (uint32 and uint64, every length a bit generator asks for) and the pool of 600 entropies
    with spawn keys 0 .. 2^32-1 equal SeedSequence's."""
    rng = np.random.default_rng(123)
    for words in _entropies(rng, 600):
        key = int(rng.choice([0, 1, 16, 101, int(rng.integers(0, 2**32))]))
        ref = np.random.SeedSequence(words, spawn_key=(key,))
        fast = FastSeedSequence(words, key)
        for n in (1, 3, 4):
            np.testing.assert_array_equal(fast.generate_state(n, np.uint64), ref.generate_state(n, np.uint64))
        for n in (1, 6, 8, 9, 20):                            # 9 and 20: past the words computed ahead
            np.testing.assert_array_equal(fast.generate_state(n), ref.generate_state(n))
        np.testing.assert_array_equal(fast.pool, ref.pool)


@pytest.mark.parametrize("bit_generator", [np.random.PCG64, np.random.SFC64])
def test_streams_equal_seed_sequence(bit_generator):
    """A generator seeded through FastSeedSequence draws what the SeedSequence-seeded one draws."""
    rng = np.random.default_rng(5)
    for words in _entropies(rng, 30):
        a = np.random.Generator(bit_generator(FastSeedSequence(words, 7)))
        b = np.random.Generator(bit_generator(np.random.SeedSequence(words, spawn_key=(7,))))
        np.testing.assert_array_equal(a.standard_normal(50), b.standard_normal(50))
        np.testing.assert_array_equal(a.integers(0, 2**63, 5), b.integers(0, 2**63, 5))


def test_row_generators_and_children_keep_their_streams():
    """row_generators and ChildStreams give the streams of their documented SeedSequence recipes."""
    seeds = [0, 1, 2**32 - 1, 2**32, 2**40 + 3, 123456789, 2**64 - 1]
    for stream, key in STREAMS.items():                      # every row's state in one compiled call
        for g, s in zip(row_generators(seeds, stream), seeds):
            ref = np.random.default_rng(np.random.SeedSequence(s, spawn_key=(key,)))
            assert g.bit_generator.state == ref.bit_generator.state, (stream, s)
            np.testing.assert_array_equal(g.random(20), ref.random(20))
    for seeds in ([2**64], [3, 2**70 + 1]):                  # entropy beyond 64 bits: the row-by-row path
        for g, s in zip(row_generators(seeds, "imu"), seeds):
            np.testing.assert_array_equal(g.random(5), np.random.default_rng(np.random.SeedSequence(
                s, spawn_key=(2,))).random(5))
    seq = row_generators([2**40 + 3], "imu")[0].bit_generator.seed_seq   # its entropy words formed on request
    ref = np.random.SeedSequence(2**40 + 3, spawn_key=(2,))
    np.testing.assert_array_equal(np.asarray(seq.entropy, np.uint32), entropy_words([2**40 + 3]))
    np.testing.assert_array_equal(seq.pool, ref.pool)
    np.testing.assert_array_equal(seq.spawn(2)[1].generate_state(4), ref.spawn(2)[1].generate_state(4))
    for n, dtype in ((4, np.uint64), (2, np.uint64), (8, np.uint32), (9, np.uint32)):
        np.testing.assert_array_equal(seq.generate_state(n, dtype), ref.generate_state(n, dtype))
    ent = [2**63 - 5, 7, 0, 2**40]
    cs = ChildStreams(ent, 17)
    for k in (0, 5, -1):
        ref = np.random.default_rng(np.random.SeedSequence(ent, spawn_key=(range(17)[k],)))
        np.testing.assert_array_equal(cs[k].random(20), ref.random(20))
    assert cs[16] is cs[-1]                                   # built once, then the same generator
    sfc = ChildStreams(ent, 4, np.random.SFC64)
    ref = np.random.Generator(np.random.SFC64(np.random.SeedSequence(ent).spawn(4)[2]))
    np.testing.assert_array_equal(sfc[2].standard_normal(20), ref.standard_normal(20))


@pytest.mark.parametrize("bit_generator", [np.random.SFC64, np.random.PCG64])
def test_child_taken_as_a_raw_state_is_the_child_stream(bit_generator):
    """ChildStreams.raw_state: numpy's state of that child's bit generator (compiled draws from it equal the
    child generator's, with or without entropy words), the child then has no generator; a built child, or
    children of another bit generator, cannot be taken."""
    from envs.sim.normals import fill_normals, pcg64_seed, sfc64_seed, stream_state
    ent = [2**63 - 5, 7, 0, 2**40]
    seed_fn = sfc64_seed if bit_generator is np.random.SFC64 else pcg64_seed
    for seed in ([0], [2**32 + 1], ent):
        seq = np.random.SeedSequence(seed, spawn_key=(5,))
        state = np.empty(4, np.uint64)
        seed_fn(seq.generate_state(4, np.uint64), state)
        np.testing.assert_array_equal(state, stream_state(np.random.Generator(bit_generator(seq)))[1])
    for entropy in (ent, []):
        taken, built = ChildStreams(entropy, 4, bit_generator, ("a", "b", "c", "d")), ChildStreams(entropy, 4,
                                                                                                    bit_generator)
        kind, state = taken.raw_state("c")
        out = np.empty((300, 3))
        fill_normals(kind, state, out)
        np.testing.assert_array_equal(out, built[2].standard_normal((300, 3)))
        assert built[2].random() == np.random.Generator(_with_state(bit_generator, kind, state)).random()
    with pytest.raises(RuntimeError, match="taken as a raw state"):
        taken[2]
    with pytest.raises(RuntimeError, match="already in use"):
        taken.raw_state(2)
    taken[0]
    with pytest.raises(RuntimeError, match="already in use"):
        taken.raw_state("a")
    with pytest.raises(ValueError, match="MT19937, not SFC64 or PCG64"):
        ChildStreams(ent, 4, np.random.MT19937).raw_state(0)


@pytest.mark.parametrize("bit_generator", [np.random.SFC64, np.random.PCG64])
def test_row_normals_are_the_rows_child_draws_stacked(bit_generator):
    from envs.sim.rng import row_normals
    rows = [[s, 2**40 + s] for s in range(5)]
    taken = [ChildStreams(e, 6, bit_generator) for e in rows]
    ref = np.stack([ChildStreams(e, 6, bit_generator)[4].standard_normal((7, 3)) for e in rows])
    np.testing.assert_array_equal(row_normals(taken, 4, (7, 3)), ref)
    with pytest.raises(RuntimeError, match="taken as a raw state"):
        taken[0][4]
    # into a given array: the same numbers; a wrong one is refused before any stream is taken
    into = [ChildStreams(e, 6, bit_generator) for e in rows]
    for bad in (np.empty((5, 3, 7)), np.empty((5, 7, 3), np.float32), np.empty((5, 3, 7)).transpose(0, 2, 1)):
        with pytest.raises(ValueError, match="row_normals: out must be a C-contiguous float64 array"):
            row_normals(into, 4, (7, 3), out=bad)
    buf = np.full((5, 7, 3), np.nan)
    assert row_normals(into, 4, (7, 3), out=buf) is buf
    np.testing.assert_array_equal(buf, ref)


@pytest.mark.parametrize("bit_generator", [np.random.SFC64, np.random.PCG64])
def test_take_raw_states_is_raw_state_row_by_row(bit_generator):
    """take_raw_states: the states raw_state gives row by row and key by key (keys by index or name; entropy of 1
    to 8 uint32 words, and rows without entropy, taken one by one), the children then taken; a child in use is
    refused with raw_state's error, and so are children of another bit generator."""
    from envs.sim.normals import PCG64, SFC64
    from envs.sim.rng import take_raw_states
    names = tuple("abcdef")
    rows = [[s, 2**40 + s] for s in range(6)] + [[3], [2**63 - 1, 5, 2**33, 1]]
    for entropy in (rows, rows + [[]]):
        taken = [ChildStreams(e, 6, bit_generator, names) for e in entropy]
        kind, got = take_raw_states(taken, (4, "b", 0))
        assert kind == (SFC64 if bit_generator is np.random.SFC64 else PCG64)
        assert got.shape == (len(entropy), 3, 4) and got.dtype == np.uint64
        for i, e in enumerate(entropy):
            ref = ChildStreams(e, 6, bit_generator, names)
            for c, k in enumerate((4, 1, 0)):
                np.testing.assert_array_equal(got[i, c], ref.raw_state(k)[1], err_msg=f"{e} {k}")
        with pytest.raises(RuntimeError, match="taken as a raw state"):
            taken[-1][1]
    assert take_raw_states([], (0,))[1].shape == (0, 1, 4)
    used = [ChildStreams(e, 6, bit_generator) for e in rows]
    used[3][2]
    with pytest.raises(RuntimeError, match="child stream 2 is already in use"):
        take_raw_states(used, (2,))
    with pytest.raises(ValueError, match="MT19937, not SFC64 or PCG64"):
        take_raw_states([ChildStreams(e, 4, np.random.MT19937) for e in rows], (0,))


@pytest.mark.parametrize("bit_generator", [np.random.SFC64, np.random.PCG64])
def test_child_states_rows_are_each_rows_raw_states(bit_generator):
    """child_states_rows: row i's states are ChildStreams(words[i] as ints).raw_state(key), for 64-bit words with
    and without a high word (entropy_words makes 2, 3 or 4 uint32 words of them), zero words, one word or four;
    bad shapes, keys and kinds are refused."""
    from envs.sim.normals import PCG64, SFC64
    from envs.sim.rng import child_states_rows
    kind = SFC64 if bit_generator is np.random.SFC64 else PCG64
    rng = np.random.default_rng(8)
    keys = [0, 3, 6, 101]
    for width in (1, 2, 4):
        words = rng.integers(0, 2**64 - 1, size=(60, width), dtype=np.uint64, endpoint=True)
        words[::3, 0] &= np.uint64(0xFFFFFFFF)                  # no high word
        words[::5, -1] = 0
        words[7] = 0
        words[8] = np.iinfo(np.uint64).max
        got = child_states_rows(words, keys, kind)
        assert got.shape == (60, 4, 4) and got.dtype == np.uint64
        for i, row in enumerate(words):
            cs = ChildStreams([int(w) for w in row], 102, bit_generator)
            for c, k in enumerate(keys):
                np.testing.assert_array_equal(got[i, c], cs.raw_state(k)[1], err_msg=f"{width} {i} {k}")
    with pytest.raises(ValueError, match=r"words must have shape \(B, W\)"):
        child_states_rows(np.zeros((3, 5), np.uint64), keys, kind)
    with pytest.raises(ValueError, match="keys must lie in"):
        child_states_rows(np.zeros((3, 2), np.uint64), [-1], kind)
    with pytest.raises(ValueError, match="kind must be SFC64"):
        child_states_rows(np.zeros((3, 2), np.uint64), keys, 7)


def _with_state(bit_generator, kind, state):
    """A fresh ``bit_generator`` set to the raw ``(kind, state)``."""
    from envs.sim.normals import store_stream_state
    g = np.random.Generator(bit_generator(0))
    store_stream_state(g, kind, state)
    return g.bit_generator


def test_spawn_attributes_and_pickle_behave_like_seed_sequence():
    """spawn, entropy and spawn_key come from the real SeedSequence; a generator survives pickling."""
    words = entropy_words([99, 2**50])
    fast, ref = FastSeedSequence(words, 4), np.random.SeedSequence(words, spawn_key=(4,))
    for a, b in zip(fast.spawn(3), ref.spawn(3)):
        np.testing.assert_array_equal(a.generate_state(4), b.generate_state(4))
    assert fast.spawn_key == (4,) and fast.n_children_spawned == 3
    np.testing.assert_array_equal(np.asarray(fast.entropy, np.uint32), words)
    g = np.random.Generator(np.random.PCG64(FastSeedSequence(words, 4)))
    g.random(3)
    h = pickle.loads(pickle.dumps(g))
    np.testing.assert_array_equal(g.random(10), h.random(10))
    kids = g.spawn(2)
    ref_kids = np.random.default_rng(np.random.SeedSequence(words, spawn_key=(4,))).spawn(2)
    np.testing.assert_array_equal(kids[1].random(5), ref_kids[1].random(5))
