"""Per-row random streams: what makes batching change nothing but speed.

Row ``i`` of every batched simulation draws its random numbers only from the
generators built here from ``seeds[i]``, one independent stream per component
(trajectory, IMU, GNSS, initial errors). The draws of a row therefore do not
depend on the batch size or on the other rows: B = 1 with seed s equals row i
of B = 64 whose seeds[i] = s.
"""
from __future__ import annotations

from typing import Sequence

import numba as nb
import numpy as np
from numpy.random.bit_generator import ISpawnableSeedSequence

from .normals import PCG64, SFC64, fill_normals_rows, pcg64_seed, sfc64_seed

STREAMS = {"trajectory": 1, "imu": 2, "gnss": 3, "init": 4, "events": 5, "vibration": 6, "odometer": 101}
"""Fixed stream ids: adding a component never shifts another component's draws (``odometer``: 101, the id
the seed003 experiment drew its odometer from before the odometer became part of the world)."""


def as_seeds(seeds) -> list[int]:
    """Normalize an int or a sequence of non-negative ints to a list; ``ValueError`` otherwise."""
    if isinstance(seeds, (int, np.integer)):
        seeds = [int(seeds)]
    out = []
    for i, s in enumerate(seeds):
        if not isinstance(s, (int, np.integer)) or s < 0:
            raise ValueError(f"seeds[{i}] must be a non-negative int, got {s!r}")
        out.append(int(s))
    if not out:
        raise ValueError("seeds must not be empty")
    return out


def row_generators(seeds: Sequence[int], stream: str) -> list[np.random.Generator]:
    """One ``numpy.random.Generator`` per batch row for the named stream.

    Parameters
    ----------
    seeds : sequence of B non-negative ints (one per row).
    stream : a key of :data:`STREAMS`.

    Returns
    -------
    list of B generators; row i depends only on (seeds[i], stream).
    """
    if stream not in STREAMS:
        raise ValueError(f"unknown random stream {stream!r}; known: {sorted(STREAMS)}")
    key = STREAMS[stream]
    seeds = as_seeds(seeds)
    if max(seeds) >= 2**64:                                 # entropy beyond one 64-bit word: row by row
        return [np.random.Generator(np.random.PCG64(FastSeedSequence(entropy_words([s]), key))) for s in seeds]
    states = np.empty((len(seeds), _STATE_WORDS), np.uint32)
    _seed_states_rows(np.array(seeds, dtype=np.uint64), key, states)   # every row's state in one compiled call
    return [np.random.Generator(np.random.PCG64(FastSeedSequence.of_seed(s, key, st))) for s, st in zip(seeds, states)]


def entropy_words(entropy) -> np.ndarray:
    """The uint32 words ``SeedSequence`` makes of a list of non-negative ints, as a uint32 array.

    ``SeedSequence`` turns each int of its entropy into 32-bit words, least significant first, at
    least one word (0 -> [0]), and takes a uint32 array word for word: ``SeedSequence(words)`` is
    ``SeedSequence(entropy)`` (same pool, same streams; tested), and ~2.5x cheaper to build.
    """
    words = []
    for e in entropy:
        words.append(e & 0xFFFFFFFF)
        e >>= 32
        while e:
            words.append(e & 0xFFFFFFFF)
            e >>= 32
    return np.array(words, dtype=np.uint32)


class ChildStreams:
    """The ``n`` fixed child generators of one row's component stream, each built on first use.

    Child ``k`` is ``Generator(bit_generator(SeedSequence(entropy, spawn_key=(k,))))``, the ``k``-th child of
    ``SeedSequence(entropy).spawn(n)`` (``bit_generator`` PCG64: ``np.random.default_rng`` of that child).
    Building only the children a run uses gives the very same streams at a fraction of the cost (~10 us per
    child). Indexing with an int or a slice returns generators, as a list of all children would; with
    ``names`` (one per child) a child can also be looked up by its name.
    """

    __slots__ = ("_words", "_gens", "_bit_generator", "_names")

    def __init__(self, entropy, n: int, bit_generator=np.random.PCG64, names: tuple | None = None):
        self._words = entropy_words(entropy)
        self._gens = [None] * n
        self._bit_generator = bit_generator
        self._names = names

    def __len__(self) -> int:
        return len(self._gens)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[j] for j in range(*k.indices(len(self._gens)))]
        k = self._index(k)
        g = self._gens[k]
        if g is _TAKEN:
            raise RuntimeError(f"child stream {k} was taken as a raw state (raw_state): it has no generator")
        if g is None:
            g = self._gens[k] = np.random.Generator(self._bit_generator(FastSeedSequence(self._words, k)))
        return g

    def _index(self, k) -> int:
        if isinstance(k, str):
            return self._names.index(k)
        return range(len(self._gens))[k]

    def _take(self, k) -> int:
        """Child ``k``'s index, the child marked as taken as a raw state; a child in use is refused."""
        k = self._index(k)
        if self._gens[k] is not None:
            raise RuntimeError(f"child stream {k} is already in use (its generator or its state was taken)")
        self._gens[k] = _TAKEN
        return k

    def raw_state(self, k) -> tuple[int, np.ndarray]:
        """Child ``k``'s stream as ``(kind, state)`` for the compiled draws of :mod:`envs.sim.normals`
        (:func:`~envs.sim.normals.fill_normals`): numpy's state of its SFC64 or PCG64 bit generator, a fresh
        (4,) uint64 array, its generator never built (~1 us instead of ~6-15). The stream is then the caller's:
        the child has no generator afterwards (``__getitem__`` raises), and a child whose generator was built
        cannot be taken."""
        kind = {np.random.SFC64: SFC64, np.random.PCG64: PCG64}.get(self._bit_generator)
        if kind is None:
            raise ValueError(f"raw_state: the children are {self._bit_generator.__name__}, not SFC64 or PCG64")
        k = self._take(k)
        state = np.empty(4, dtype=np.uint64)
        if not self._words.size:                            # no entropy words: numpy's own SeedSequence path
            seed = np.ascontiguousarray(FastSeedSequence(self._words, k).generate_state(4, np.uint64))
            (sfc64_seed if kind == SFC64 else pcg64_seed)(seed, state)  # SFC64 reads the first 3 words
        else:
            _child_state(kind, self._words, k, state)
        return kind, state


def row_normals(streams: Sequence["ChildStreams"], k, shape: tuple, out: np.ndarray | None = None) -> np.ndarray:
    """``np.stack([s[k].standard_normal(shape) for s in streams])`` (B,) + shape, the same numbers, drawn in one
    compiled call from the rows' raw child states (:meth:`ChildStreams.raw_state`: child ``k`` of every row is
    then taken); into ``out`` when given (a C-contiguous float64 array of that shape, returned)."""
    full = (len(streams),) + tuple(shape)
    if out is None:
        out = np.empty(full)
    elif out.shape != full or out.dtype != np.float64 or not out.flags.c_contiguous:
        raise ValueError(f"row_normals: out must be a C-contiguous float64 array of shape {full}, got "
                         f"{out.dtype} {out.shape}")
    kind, states = take_raw_states(streams, (k,))
    fill_normals_rows(kind, np.ascontiguousarray(states[:, 0]), out)
    return out


def take_raw_states(streams: Sequence["ChildStreams"], keys) -> tuple[int, np.ndarray]:
    """``[[s.raw_state(k)[1] for k in keys] for s in streams]`` as a (B, K, 4) uint64 array, with its kind: the
    same states, taken as :meth:`ChildStreams.raw_state` takes them (the same checks, in the same order; every
    child then has no generator), the states formed in one compiled call instead of one call per row and key
    (~0.5 us per state instead of ~6, most of it the Python around each call). Streams of different bit
    generators, or without entropy words, are taken one by one.

    Parameters
    ----------
    streams : B :class:`ChildStreams`; keys : K child indices or names.

    Returns
    -------
    (kind, states): :data:`~.normals.SFC64` or :data:`~.normals.PCG64` (SFC64 for an empty batch) and the
    (B, K, 4) uint64 states.
    """
    keys = tuple(keys)
    out = np.empty((len(streams), len(keys), 4), dtype=np.uint64)
    if not streams:
        return SFC64, out
    bit_gen = streams[0]._bit_generator
    kind = {np.random.SFC64: SFC64, np.random.PCG64: PCG64}.get(bit_gen)
    if kind is None or any(s._bit_generator is not bit_gen or not s._words.size for s in streams):
        for i, s in enumerate(streams):
            for c, k in enumerate(keys):
                kind, out[i, c] = s.raw_state(k)
        return kind, out
    index = np.empty((len(streams), len(keys)), dtype=np.int64)
    for i, s in enumerate(streams):   # raw_state's checks and bookkeeping, row by row, key by key
        for c, k in enumerate(keys):
            index[i, c] = s._take(k)
    lengths = np.fromiter((s._words.size for s in streams), dtype=np.int64, count=len(streams))
    offsets = np.zeros(len(streams) + 1, dtype=np.int64)
    np.cumsum(lengths, out=offsets[1:])
    _child_states_words(kind, np.concatenate([s._words for s in streams]), offsets, index, out)
    return kind, out


_TAKEN = object()
"""A :class:`ChildStreams` child handed out as a raw state (:meth:`ChildStreams.raw_state`)."""


def child_states_rows(words: np.ndarray, keys: Sequence[int], kind: int = SFC64) -> np.ndarray:
    """The raw states of children ``keys`` of many rows' :class:`ChildStreams`, in one compiled call.

    Row ``i``'s children are those of ``ChildStreams([int(w) for w in words[i]], n, bit_generator)`` (the
    bit generator SFC64 or PCG64 as ``kind``): ``out[i, c]`` is its ``raw_state(keys[c])[1]``, the same
    state (tested), for a fraction of the Python cost per row.

    Parameters
    ----------
    words : (B, W) uint64, each row's entropy as 64-bit ints (W <= 4); keys : K child indices, each in [0, 2^32).
    kind : :data:`~.normals.SFC64` or :data:`~.normals.PCG64`.

    Returns
    -------
    (B, K, 4) uint64 states for :func:`~.normals.fill_normals_rows` and the compiled draws.
    """
    words = np.ascontiguousarray(words, dtype=np.uint64)
    keys = np.asarray(keys, dtype=np.int64).reshape(-1)
    if words.ndim != 2 or not 1 <= words.shape[1] <= 4:
        raise ValueError(f"child_states_rows: words must have shape (B, W), 1 <= W <= 4, got {words.shape}")
    if keys.size and (keys.min() < 0 or keys.max() >= 2**32):
        raise ValueError(f"child_states_rows: keys must lie in [0, 2^32), got {keys.tolist()}")
    if kind not in (SFC64, PCG64):
        raise ValueError(f"child_states_rows: kind must be SFC64 ({SFC64}) or PCG64 ({PCG64}), got {kind!r}")
    out = np.empty((words.shape[0], keys.size, 4), dtype=np.uint64)
    _child_states_rows(kind, words, keys, out)
    return out


@nb.njit(cache=True, inline="always")
def _words_of(values, w32):
    """:func:`entropy_words` of the 64-bit ints ``values`` (W,) uint64 into ``w32`` (>= 2 W,) uint32 (each the low
    word, then the high word where it is not zero); returns how many words it wrote."""
    low, shift = np.uint64(0xFFFFFFFF), np.uint64(32)
    m = 0
    for j in range(values.shape[0]):
        v = values[j]
        w32[m] = np.uint32(v & low)
        m += 1
        if v >> shift:
            w32[m] = np.uint32(v >> shift)
            m += 1
    return m


@nb.njit(cache=True, nogil=True)
def _child_states_rows(kind, words, keys, out):
    """:func:`child_states_rows`: each row's uint32 entropy words (:func:`_words_of` its 64-bit ints), then
    :func:`_child_state` per key."""
    w32 = np.empty(2 * words.shape[1], np.uint32)
    for i in range(words.shape[0]):
        m = _words_of(words[i], w32)
        for c in range(keys.shape[0]):
            _child_state(kind, w32[:m], keys[c], out[i, c])


@nb.njit(cache=True, nogil=True)
def _child_states_words(kind, words, offsets, index, out):
    """:func:`take_raw_states`' states: row ``i``'s uint32 entropy words ``words[offsets[i]:offsets[i + 1]]``, then
    :func:`_child_state` of each of its children ``index[i]`` into ``out[i]``."""
    for i in range(index.shape[0]):
        w = words[offsets[i]:offsets[i + 1]]
        for c in range(index.shape[1]):
            _child_state(kind, w, index[i, c], out[i, c])


# ----------------------------------------------------------------------------- SeedSequence's state, compiled
_POOL = 4
"""Words of ``SeedSequence``'s entropy pool (numpy's ``DEFAULT_POOL_SIZE``)."""
_STATE_WORDS = 8
"""uint32 state words :class:`FastSeedSequence` computes ahead: a PCG64 or SFC64 takes 8 or 6 of them."""


@nb.njit(cache=True, nogil=True)
def _seed_state(words, key, out):
    """``SeedSequence(words, spawn_key=(key,))``'s state: its first ``out.size`` words.

    The algorithm of ``numpy.random.SeedSequence`` (numpy's ``bit_generator.pyx``, after M. E. O'Neill's
    ``seed_seq_fe``). The assembled entropy is the run entropy ``words``, zero-padded to 4 words, then the key.
    Each entropy word is hashed (``hashmix``: xor with a running constant that is multiplied by ``0x931e8875``
    per use, multiply, xor-shift by 16) and mixed into a pool of 4 words (``mix(x, y) = 0xca01f9dd x -
    0x4973f715 y``, xor-shift by 16), every pool word into every other; state word ``i`` is pool word
    ``i mod 4`` hashed with the constant of ``generate_state`` (multiplier ``0x58f38ded``). All arithmetic
    mod 2^32 (uint64, masked).

    Parameters
    ----------
    words : (L,) uint32 run entropy, L >= 1; key : int in [0, 2^32), the one-word spawn key.
    out : (n,) uint32 output, the state words.
    """
    n_run = max(words.shape[0], _POOL)
    n_ent = n_run + 1
    ent = np.zeros(n_ent, np.uint64)
    for i in range(words.shape[0]):
        ent[i] = words[i]
    ent[n_run] = key
    m32, sh = np.uint64(0xFFFFFFFF), np.uint64(16)
    mult_a, mult_b = np.uint64(0x931e8875), np.uint64(0x58f38ded)
    mix_l, mix_r = np.uint64(0xca01f9dd), np.uint64(0x4973f715)
    pool = np.zeros(_POOL, np.uint64)
    h = np.uint64(0x43b0d7e5)
    for i in range(_POOL):
        v = ent[i]
        v ^= h
        h = (h * mult_a) & m32
        v = (v * h) & m32
        pool[i] = v ^ (v >> sh)
    for i_src in range(n_ent):                              # the pool words, then the entropy beyond them
        for i_dst in range(_POOL):
            if i_src == i_dst:
                continue
            v = pool[i_src] if i_src < _POOL else ent[i_src]
            v ^= h
            h = (h * mult_a) & m32
            v = (v * h) & m32
            r = (mix_l * pool[i_dst] - mix_r * (v ^ (v >> sh))) & m32
            pool[i_dst] = r ^ (r >> sh)
    h = np.uint64(0x8b51f9dd)
    for i in range(out.shape[0]):
        v = pool[i % _POOL] ^ h
        h = (h * mult_b) & m32
        v = (v * h) & m32
        out[i] = np.uint32(v ^ (v >> sh))


@nb.njit(cache=True, nogil=True)
def _seed_states_rows(seeds, key, out):
    """Row ``i`` of ``out`` (B, n) uint32: the state words of ``SeedSequence(entropy_words([seeds[i]]),
    spawn_key=(key,))`` (:func:`_seed_state` of :func:`_words_of` the seed; ``seeds`` (B,) uint64)."""
    w32 = np.empty(2, np.uint32)
    for i in range(seeds.shape[0]):
        _seed_state(w32[:_words_of(seeds[i:i + 1], w32)], key, out[i])


@nb.njit(cache=True, nogil=True)
def _child_state(kind, words, key, state):
    """The state of ``SFC64`` or ``PCG64`` (``kind``, :mod:`envs.sim.normals`) seeded by ``SeedSequence(words,
    spawn_key=(key,))``, into ``state`` (4,) uint64: 3 or 4 seed words (pairs of :func:`_seed_state`'s uint32
    words, low word first) through :func:`~.normals.sfc64_seed` or :func:`~.normals.pcg64_seed`."""
    w32 = np.empty(_STATE_WORDS, np.uint32)
    _seed_state(words, key, w32)
    seed = np.empty(4, np.uint64)
    for i in range(4):
        seed[i] = np.uint64(w32[2 * i]) | (np.uint64(w32[2 * i + 1]) << np.uint64(32))
    if kind == SFC64:
        sfc64_seed(seed, state)
    else:
        pcg64_seed(seed, state)


class FastSeedSequence(ISpawnableSeedSequence):
    """``numpy.random.SeedSequence(entropy_words, spawn_key=(key,))`` for seeding one bit generator, built
    ~4x faster: the state a PCG64 or SFC64 asks for comes from the compiled :func:`_seed_state`, the same words
    (tested against ``SeedSequence``). Anything else (``spawn``, ``entropy``, ``pool``, a longer state) is asked
    of a real ``SeedSequence`` built on first use.

    Parameters
    ----------
    words : (L,) uint32 run entropy (:func:`entropy_words`); key : int, the one-element spawn key, >= 0.
    """

    def __init__(self, words: np.ndarray, key: int):
        self._words = np.asarray(words, dtype=np.uint32)
        self._seed = None
        self._key = int(key)
        self._seq = None
        self._state = None                                  # no entropy or a multi-word key: numpy's own path
        if self._words.size and 0 <= self._key < 2**32:
            self._state = np.empty(_STATE_WORDS, np.uint32)
            _seed_state(self._words, self._key, self._state)

    @classmethod
    def of_seed(cls, seed: int, key: int, state: np.ndarray) -> "FastSeedSequence":
        """``FastSeedSequence(entropy_words([seed]), key)`` whose state words ``state`` (8,) uint32 were computed
        already (:func:`_seed_states_rows`, many rows in one call); the entropy words are formed only if
        something other than the state is asked of it."""
        self = cls.__new__(cls)
        self._words, self._seed, self._key, self._seq, self._state = None, seed, key, None, state
        return self

    def _real(self) -> np.random.SeedSequence:
        if self._seq is None:
            words = entropy_words([self._seed]) if self._words is None else self._words
            self._seq = np.random.SeedSequence(words, spawn_key=(self._key,))
        return self._seq

    def generate_state(self, n_words: int, dtype=np.uint32) -> np.ndarray:
        """``SeedSequence.generate_state``: (n_words,) uint32 or uint64 (pairs of words, low word first)."""
        if dtype is np.uint64 and n_words == 4 and self._state is not None:   # what a PCG64 asks for
            return self._state.view(np.uint64).copy()
        wide = dtype is np.uint64 or np.dtype(dtype) == np.uint64   # PCG64 and SFC64 pass np.uint64 itself
        n32 = n_words * (2 if wide else 1)
        if self._state is None or not (wide or np.dtype(dtype) == np.uint32) or n32 > _STATE_WORDS:
            return self._real().generate_state(n_words, dtype)
        return self._state[:n32].view("<u8" if wide else "<u4").astype(np.uint64 if wide else np.uint32)

    def spawn(self, n_children: int) -> list:
        """``SeedSequence.spawn``: the children of the real sequence."""
        return self._real().spawn(n_children)

    def __getattr__(self, name):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._real(), name)
