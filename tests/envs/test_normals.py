"""envs.sim.normals: the compiled standard normal draws are numpy's, bit for bit, and leave the generator where
numpy would."""
import numba as nb
import numpy as np
import pytest

from envs.sim import normals
from envs.sim.normals import MIN_COMPILED, standard_normal, stream_state


def _pair(bit_generator, seed):
    return np.random.Generator(bit_generator(seed)), np.random.Generator(bit_generator(seed))


@pytest.mark.parametrize("bit_generator", [np.random.SFC64, np.random.PCG64])
@pytest.mark.parametrize("seed", [0, 12345])
def test_same_numbers_as_numpy_tails_and_wedges_included(bit_generator, seed):
    ref, ours = _pair(bit_generator, seed)
    ref.random(5), ours.random(5)                                # not at the start of the stream
    a = ref.standard_normal((200_000, 3))
    b = standard_normal(ours, (200_000, 3))
    assert b.dtype == np.float64 and b.shape == a.shape
    assert np.array_equal(a.view(np.uint64), b.view(np.uint64))
    # the sample reaches the ziggurat's tail (layer 0 beyond r) on both signs: that branch was run
    assert (a > normals._R).any() and (a < -normals._R).any()
    # the generator continues where numpy's does
    assert np.array_equal(ref.random(7), ours.random(7))
    assert np.array_equal(ref.standard_normal(1000), standard_normal(ours, 1000))


@pytest.mark.parametrize("bit_generator", [np.random.SFC64, np.random.PCG64])
def test_buffered_half_word_kept(bit_generator):
    """A 32-bit draw leaves half a word buffered; normal draws neither use nor drop it."""
    ref, ours = _pair(bit_generator, 7)
    assert ref.integers(0, 2**32 - 1, dtype=np.uint32) == ours.integers(0, 2**32 - 1, dtype=np.uint32)
    assert ours.bit_generator.state["has_uint32"] == 1
    assert np.array_equal(ref.standard_normal(4096), standard_normal(ours, 4096))
    assert ref.integers(0, 2**32 - 1, dtype=np.uint32) == ours.integers(0, 2**32 - 1, dtype=np.uint32)


@pytest.mark.parametrize("bit_generator", [np.random.MT19937, np.random.Philox])
def test_other_bit_generators_drawn_by_numpy(bit_generator):
    ref, ours = _pair(bit_generator, 3)
    assert stream_state(ours) is None
    assert np.array_equal(ref.standard_normal((700, 2)), standard_normal(ours, (700, 2)))
    assert ref.random() == ours.random()


@pytest.mark.parametrize("size", [0, 1, (3, 3), MIN_COMPILED - 1, MIN_COMPILED, (MIN_COMPILED + 1, 2)])
def test_sizes_on_both_sides_of_the_compiled_threshold(size):
    ref, ours = _pair(np.random.SFC64, 11)
    a, b = ref.standard_normal(size), standard_normal(ours, size)
    assert a.shape == b.shape and np.array_equal(a, b)
    assert ref.random() == ours.random()


def test_mulhi_is_the_high_word_of_the_128_bit_product():
    f = nb.njit(lambda a, b: normals._mulhi(a, b))
    rng = np.random.default_rng(1)
    pairs = [(0, 0), (2**64 - 1, 2**64 - 1), (2**63, 2), (2**32, 2**32)]
    pairs += [tuple(int(v) for v in rng.integers(0, 2**64, size=2, dtype=np.uint64)) for _ in range(200)]
    for a, b in pairs:
        assert int(f(np.uint64(a), np.uint64(b))) == (a * b) >> 64
