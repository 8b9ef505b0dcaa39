"""Compiled streaming step of the classical zero-velocity detectors (:class:`~.classical.ClassicalDetector`).

The numpy lines are the specification: :class:`~.prefilter.LowPass` (``scipy.signal.sosfilt``, direct form II
transposed), ``ClassicalDetector._score`` (the trailing window of the stream, :func:`~.classical.
classical_statistic` by cumulative sums) and ``ZuptDetector.decide``. :func:`_classical_rows` does the same
operations in the same order on each batch row, for one chunk of samples, with no temporary arrays, so it gives
the same bits (test: ``tests/nav_filters/test_zupt_compiled.py``). In a single ``urban`` env's step with
``zupt="shoe"`` the numpy path (input checks, a concatenation, scipy's argument handling, some forty small array
operations for 100 samples) took 45% of the step (cProfile).
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels import serial_and_parallel
from .prefilter import lowpass_channel

KIND_CODES = {"shoe": 0, "are": 1, "mag": 2, "mv": 3}
"""The ``kind`` argument of :func:`_classical_rows` for each classical detector."""


@nb.njit(cache=True, inline="always")
def _window_sum(cs, i, e, c):
    """Sum of column ``c`` over samples ``i .. e`` from its cumulative sums ``cs`` (L, C), as ``window_sums``
    forms it: ``cs[e]`` for the first window, ``cs[e] - cs[i - 1]`` after it."""
    return cs[e, c] if i == 0 else cs[e, c] - cs[i - 1, c]


def _classical_rows(f, w, s0, k, sos, zi_unit, zi, fresh, has_lp, tail, count, first, W, kind, gravity, sa2,
                    den_a, den_w, threshold, score, stationary, nchunk):
    """One chunk, samples ``s0 .. s0 + k - 1`` of ``f``, ``w`` (B, n, 3), of every row's stream.

    Per row, as the numpy path:

    1. the six channels ``[f, w]`` low-pass filtered when ``has_lp`` (:func:`~.prefilter.lowpass_channel`:
       second-order sections ``sos`` (S, 6), state ``zi`` (S, B, 2, 6) updated in place, a ``fresh`` row started
       in the steady state of its first sample and unflagged);
    2. on the ``first`` chunk of a stream the window's history ``tail`` (B, W - 1, 6) filled with the first
       filtered sample; the buffer ``[tail, chunk]`` of ``L = W - 1 + k`` samples;
    3. the statistic ``T`` of ``kind`` (:data:`KIND_CODES`) on each of its ``k`` full windows, window sums as
       differences of cumulative sums; SHOE and MV on the accelerometer samples shifted by the buffer's last one
       (``classical_statistic``), ``sa2 = sigma_a^2``, ``den_a = W sigma_a^2``, ``den_w = W sigma_w^2``;
    4. ``T = inf`` where the row has seen fewer than ``W`` samples (``count`` + the chunk's), then
       ``score[b, s0 + i] = T`` and ``stationary = T < threshold``; ``tail`` the buffer's last ``W - 1``
       samples and ``count <- min(count + k, W)``.

    The rows run in ``nchunk`` chunks (parallel in the parallel variant), each with its scratch.
    """
    B = f.shape[0]
    L = W - 1 + k
    for ch in nb.prange(nchunk):
        buf = np.empty((L, 6))
        cs = np.empty((L, 5))  # cumulative sums of the per-sample terms
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            for c in range(6):
                src = f if c < 3 else w
                if has_lp:
                    lowpass_channel(src, b, s0, k, c % 3, c, sos, zi_unit, zi, fresh[b], buf, W - 1)
                else:
                    for i in range(k):
                        buf[W - 1 + i, c] = src[b, s0 + i, c % 3]
            if has_lp:
                fresh[b] = False
            for j in range(W - 1):
                for c in range(6):
                    if first:
                        tail[b, j, c] = buf[W - 1, c]
                    buf[j, c] = tail[b, j, c]
            # per-sample terms, then their cumulative sums (column by column, in sample order, as np.cumsum):
            # SHOE / MV the shifted accelerometer d (columns 0-2) and ||d||^2 (3); SHOE / ARE ||w||^2 and MAG
            # (||a|| - g)^2 (4)
            r0, r1, r2 = buf[L - 1, 0], buf[L - 1, 1], buf[L - 1, 2]
            for j in range(L):
                if kind == 0 or kind == 3:
                    d0 = buf[j, 0] - r0
                    d1 = buf[j, 1] - r1
                    d2 = buf[j, 2] - r2
                    cs[j, 0], cs[j, 1], cs[j, 2] = d0, d1, d2
                    cs[j, 3] = (d0 * d0 + d1 * d1) + d2 * d2
                if kind == 0 or kind == 1:
                    cs[j, 4] = (buf[j, 3] * buf[j, 3] + buf[j, 4] * buf[j, 4]) + buf[j, 5] * buf[j, 5]
                elif kind == 2:
                    m = np.sqrt((buf[j, 0] * buf[j, 0] + buf[j, 1] * buf[j, 1]) + buf[j, 2] * buf[j, 2]) - gravity
                    cs[j, 4] = m * m
            c_lo = 0 if (kind == 0 or kind == 3) else 4
            c_hi = 4 if kind == 3 else 5
            for j in range(1, L):
                for c in range(c_lo, c_hi):
                    cs[j, c] += cs[j - 1, c]
            for i in range(k):
                e = W - 1 + i  # the window's last sample
                if kind == 1 or kind == 2:
                    T = _window_sum(cs, i, e, 4) / (den_w if kind == 1 else den_a)
                else:
                    m0 = _window_sum(cs, i, e, 0) / W
                    m1 = _window_sum(cs, i, e, 1) / W
                    m2 = _window_sum(cs, i, e, 2) / W
                    var = max(_window_sum(cs, i, e, 3) / W - ((m0 * m0 + m1 * m1) + m2 * m2), 0.0)
                    if kind == 3:
                        T = var / sa2
                    else:
                        g0, g1, g2 = m0 + r0, m1 + r1, m2 + r2
                        dg = np.sqrt((g0 * g0 + g1 * g1) + g2 * g2) - gravity
                        T = (var + dg * dg) / sa2 + _window_sum(cs, i, e, 4) / den_w
                if count[b] + i + 1 < W:
                    T = np.inf
                score[b, s0 + i] = T
                stationary[b, s0 + i] = T < threshold
            for j in range(W - 1):
                for c in range(6):
                    tail[b, j, c] = buf[k + j, c]
            count[b] = min(count[b] + k, W)


_chunk_serial, _chunk_parallel = serial_and_parallel(_classical_rows)
