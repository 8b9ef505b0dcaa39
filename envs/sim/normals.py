"""Standard normal draws of a numpy ``Generator``, compiled: the very numbers of ``gen.standard_normal``, ~3x as fast.

A world draws about 1e5 normal variates per row and minute (the IMU's white noise, bias processes and road
vibration), and numpy's ``Generator.standard_normal`` spends ~9 ns on each: every try of its ziggurat fetches
the next 64-bit word through a function pointer into the bit generator, and the sign of the variate is a
branch that the CPU mispredicts half of the time. :func:`standard_normal` runs the same bit generator and the
same ziggurat in one compiled loop, the generator's state held in registers and the sign applied without a
branch (~3 ns). It returns what ``gen.standard_normal(size)`` returns, to the bit, and leaves ``gen`` in the
state numpy would (tests/envs/test_normals.py, tails and wedges included); a generator over another bit
generator is drawn by numpy itself. The world's stages skip the ``Generator`` where they can: they take a row's
child stream as a raw state (:meth:`envs.sim.rng.ChildStreams.raw_state`) and draw with :func:`fill_normals`, or
one variate at a time inside their own kernels with :func:`normal_step`.

The algorithms (each step in its own function below):

* SFC64 (Doty-Humphrey's "small fast chaotic" generator, PractRand; ``numpy.random.SFC64``): state
  ``(a, b, c, w)``, output ``a + b + w``, then ``w += 1``, ``a = b ^ (b >> 11)``, ``b = c + (c << 3)``,
  ``c = rotl(c, 24) + output``.
* PCG64 (O'Neill 2014, "PCG: A family of simple fast space-efficient statistically good algorithms for random
  number generation", the 128-bit LCG with the XSL-RR output; ``numpy.random.PCG64``): ``s = s M + inc``
  (mod 2^128), output ``rotr64(hi(s) ^ lo(s), s >> 122)``.
* The ziggurat of Marsaglia & Tsang (2000, "The ziggurat method for generating random variables", J. Stat.
  Softw. 5(8)) in numpy's layout: one 64-bit word per try; its low 8 bits pick the layer ``i`` of 256, the next
  bit the sign, the next 52 bits the magnitude ``m``; ``x = m w_i``, accepted at once if ``m < k_i``; on layer 0
  the tail beyond ``r`` by Marsaglia's exponential method (two uniforms ``u = (word >> 11) 2^-53`` per try),
  on the others the wedge test ``f_i + (f_(i-1) - f_i) u < exp(-x^2 / 2)``. The tables ``k, w, f`` and ``r``
  are numpy's, which numba ships for its own ``Generator`` support (``numba.np.random._constants``).
"""
from __future__ import annotations

import numba as nb
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic
from numba.np.random._constants import fi_double, ki_double, wi_double, ziggurat_nor_inv_r, ziggurat_nor_r

__all__ = ["standard_normal", "fill_normals", "fill_normals_rows", "fill_stream", "pcg64_seed", "sfc64_seed",
           "stream_state", "store_stream_state", "SFC64", "PCG64"]

SFC64 = 0
"""Kind code of an SFC64 state ``[a, b, c, w]`` (uint64 words)."""
PCG64 = 1
"""Kind code of a PCG64 state ``[hi(s), lo(s), hi(inc), lo(inc)]`` (uint64 words)."""

_KI = np.asarray(ki_double, dtype=np.int64)     # < 2^52: compared with the magnitude as signed integers
_WI = np.asarray(wi_double, dtype=np.float64)
_FI = np.asarray(fi_double, dtype=np.float64)
_R = float(ziggurat_nor_r)
_INV_R = float(ziggurat_nor_inv_r)
_MUL_HI = np.uint64(0x2360ED051FC65DA4)          # PCG64's 128-bit multiplier (O'Neill 2014), high and low words
_MUL_LO = np.uint64(0x4385DF649FCCF645)
_U64 = (1 << 64) - 1
MIN_COMPILED = 512
"""Fewest variates :func:`standard_normal` draws compiled."""
_TO_UNIT = 1.0 / 9007199254740992.0               # 2^-53

_1, _3, _8, _11, _24, _40, _58 = (np.uint64(k) for k in (1, 3, 8, 11, 24, 40, 58))
_LOW8 = np.uint64(0xFF)
_LOW52 = np.uint64(0x000FFFFFFFFFFFFF)
_ZERO = np.uint64(0)
_SIXTY_FOUR = np.uint64(64)
_ROT_MASK = np.uint64(63)


@intrinsic
def _mulhi(typingctx, a, b):
    """The high 64 bits of the 128-bit product of two uint64 (one ``mul i128``)."""
    sig = types.uint64(types.uint64, types.uint64)

    def codegen(context, builder, signature, args):
        wide = ir.IntType(128)
        p = builder.mul(builder.zext(args[0], wide), builder.zext(args[1], wide))
        return builder.trunc(builder.lshr(p, ir.Constant(wide, 64)), ir.IntType(64))

    return sig, codegen


@nb.njit(cache=True, inline="always")
def _sfc64_next(a, b, c, w):
    """One SFC64 step: ``(output, a, b, c, w)`` (module docstring)."""
    out = a + b + w
    return out, b ^ (b >> _11), c + (c << _3), ((c << _24) | (c >> _40)) + out, w + _1


@nb.njit(cache=True, inline="always")
def _pcg64_next(hi, lo, inc_hi, inc_lo):
    """One PCG64 step, the XSL-RR output of the advanced state: ``(output, hi, lo, inc_hi, inc_lo)``."""
    nhi = _mulhi(lo, _MUL_LO) + lo * _MUL_HI + hi * _MUL_LO
    nlo = lo * _MUL_LO + inc_lo
    nhi += inc_hi + (_1 if nlo < inc_lo else _ZERO)
    x = nhi ^ nlo
    rot = nhi >> _58
    return (x >> rot) | (x << ((_SIXTY_FOUR - rot) & _ROT_MASK)), nhi, nlo, inc_hi, inc_lo


@nb.njit(cache=True, inline="always")
def _next(kind, s0, s1, s2, s3):
    """The next 64-bit word of the bit generator ``kind`` (:data:`SFC64`, :data:`PCG64`) and its new state."""
    if kind == SFC64:
        return _sfc64_next(s0, s1, s2, s3)
    return _pcg64_next(s0, s1, s2, s3)


@nb.njit(cache=True, inline="always")
def _unit(word):
    """``[0, 1)`` from a word as numpy's ``next_double``: its top 53 bits times 2^-53."""
    return np.float64(np.int64(word >> _11)) * _TO_UNIT


@nb.njit(cache=True, inline="always")
def normal_step(kind, s0, s1, s2, s3):
    """One standard normal variate by the ziggurat (module docstring): ``(x, s0, s1, s2, s3)``."""
    while True:
        r, s0, s1, s2, s3 = _next(kind, s0, s1, s2, s3)
        idx = np.int64(r & _LOW8)
        r >>= _8
        rabs = np.int64((r >> _1) & _LOW52)
        x = np.float64(rabs) * _WI[idx] * (1.0 - 2.0 * np.float64(np.int64(r & _1)))  # sign without a branch
        if rabs < _KI[idx]:
            return x, s0, s1, s2, s3
        if idx == 0:                                   # the tail beyond r
            while True:
                u, s0, s1, s2, s3 = _next(kind, s0, s1, s2, s3)
                xx = -_INV_R * np.log1p(-_unit(u))
                u, s0, s1, s2, s3 = _next(kind, s0, s1, s2, s3)
                yy = -np.log1p(-_unit(u))
                if yy + yy > xx * xx:
                    return (-(_R + xx) if (rabs >> 8) & 1 else _R + xx), s0, s1, s2, s3
        u, s0, s1, s2, s3 = _next(kind, s0, s1, s2, s3)
        if (_FI[idx - 1] - _FI[idx]) * _unit(u) + _FI[idx] < np.exp(-0.5 * x * x):  # the wedge
            return x, s0, s1, s2, s3


@nb.njit(cache=True, nogil=True)
def fill_stream(kind, state, out):
    """``out`` (n,) float64 filled with standard normal variates in order from the stream ``(kind, state)``
    (``state`` (4,) uint64 advanced): :func:`fill_normals` for compiled callers."""
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    for i in range(out.shape[0]):
        out[i], s0, s1, s2, s3 = normal_step(kind, s0, s1, s2, s3)
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3


@nb.njit(cache=True, nogil=True)
def sfc64_seed(seed, state):
    """SFC64's seeding (numpy's ``SFC64(seed_seq)``): ``(a, b, c, w) = (s0, s1, s2, 1)`` from the three words
    ``seed`` (3,) uint64, then 12 steps discarded; into ``state`` (4,) uint64."""
    a, b, c, w = seed[0], seed[1], seed[2], _1
    for _ in range(12):
        _, a, b, c, w = _sfc64_next(a, b, c, w)
    state[0], state[1], state[2], state[3] = a, b, c, w


@nb.njit(cache=True, nogil=True)
def pcg64_seed(seed, state):
    """PCG64's seeding (numpy's ``PCG64(seed_seq)``, O'Neill's ``srandom``) into ``state`` (4,) uint64 (kind
    :data:`PCG64`): from the four words ``seed`` (4,) uint64, the initial state ``s0 = (seed[0], seed[1])`` and
    the stream ``(seed[2], seed[3])`` (high word first), ``inc = 2 stream + 1``, ``s = 0``; one step, ``s += s0``,
    one step."""
    inc_hi = (seed[2] << _1) | (seed[3] >> np.uint64(63))
    inc_lo = (seed[3] << _1) | _1
    _, hi, lo, inc_hi, inc_lo = _pcg64_next(_ZERO, _ZERO, inc_hi, inc_lo)
    lo2 = lo + seed[1]
    hi = hi + seed[0] + (_1 if lo2 < lo else _ZERO)
    _, hi, lo, inc_hi, inc_lo = _pcg64_next(hi, lo2, inc_hi, inc_lo)
    state[0], state[1], state[2], state[3] = hi, lo, inc_hi, inc_lo


@nb.njit(cache=True, nogil=True)
def fill_normals_rows(kind, states, out):
    """Row ``i`` of ``out`` (B, ...) C-contiguous float64 filled in C order with standard normal variates from the
    stream ``(kind, states[i])`` (``states`` (B, 4) uint64, advanced in place): B streams in one call."""
    flat = out.reshape(out.shape[0], -1)
    for i in range(flat.shape[0]):
        fill_stream(kind, states[i], flat[i])


def fill_normals(kind: int, state: np.ndarray, out: np.ndarray) -> None:
    """Fill the C-contiguous float64 array ``out`` with standard normal variates in C order, from the stream
    ``(kind, state)`` (:func:`stream_state`, :meth:`envs.sim.rng.ChildStreams.raw_state`; ``state`` advanced in
    place): what a generator in that state draws as ``standard_normal(out.shape)``. Releases the GIL."""
    fill_stream(kind, state, out.reshape(-1))


def stream_state(gen: np.random.Generator):
    """``(kind, state)`` of ``gen``'s bit generator for the compiled draws (``state`` (4,) uint64, a copy), or
    None for a bit generator other than SFC64 and PCG64."""
    st = gen.bit_generator.state
    name = st["bit_generator"]
    if name == "SFC64":
        return SFC64, np.array(st["state"]["state"], dtype=np.uint64)
    if name == "PCG64":
        s, inc = st["state"]["state"], st["state"]["inc"]
        return PCG64, np.array([s >> 64, s & _U64, inc >> 64, inc & _U64], dtype=np.uint64)
    return None


def store_stream_state(gen: np.random.Generator, kind: int, state: np.ndarray) -> None:
    """Set ``gen``'s bit generator to ``state`` (of :func:`stream_state`, advanced by compiled draws); its buffered
    32-bit half-word, which normal draws neither use nor change, is kept."""
    bg = gen.bit_generator
    st = bg.state
    words = [int(v) for v in state]
    if kind == SFC64:
        st["state"]["state"] = np.array(words, dtype=np.uint64)
    else:
        st["state"]["state"] = (words[0] << 64) | words[1]
        st["state"]["inc"] = (words[2] << 64) | words[3]
    bg.state = st


def standard_normal(gen: np.random.Generator, size) -> np.ndarray:
    """``gen.standard_normal(size)`` (float64), the same numbers and the same state of ``gen`` afterwards, drawn
    compiled for SFC64 and PCG64 generators (module docstring) and by numpy for the others and for fewer than
    :data:`MIN_COMPILED` variates (reading and setting the state costs ~3 us).

    Parameters
    ----------
    gen : numpy.random.Generator.
    size : int or tuple of ints, the output shape.
    """
    ks = stream_state(gen) if int(np.prod(size)) >= MIN_COMPILED else None
    if ks is None:
        return gen.standard_normal(size)
    out = np.empty(size, dtype=np.float64)
    fill_normals(*ks, out)
    store_stream_state(gen, *ks)
    return out
