"""Compiled feature step of the learned zero-velocity detectors (:class:`~.learned.FeatureStream`).

``FeatureStream.push`` is the specification: the pre-filter (:class:`~.prefilter.LowPass`, ``scipy.signal.
sosfilt``), the decimation to the model rate, the two exponential moving averages of the specific force
(``scipy.signal.lfilter`` with ``b = [alpha]``, ``a = [1, alpha - 1]``) and the ten features. :func:`_feature_rows`
does the same operations in the same order per batch row, so the features are the same bits (test:
``tests/nav_filters/test_zupt_compiled.py``); the network itself stays torch's. With the shipped LSTM at B = 1
the numpy and scipy feature path (input checks, scipy's argument handling, some thirty small array operations
per 100 samples) took about 40% of the detector's time.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels import serial_and_parallel
from .prefilter import lowpass_channel


def _feature_rows(f, w, pos, sos, zi_unit, zi, lp_fresh, ema, ema_fresh, alpha, accel_scale, gyro_scale, gravity,
                  feats, nchunk):
    """Features of the model steps at the chunk's samples ``pos`` (m,) for every row of ``f``, ``w`` (B, n, 3).

    Per row, as ``FeatureStream.push``: the six channels ``[f, w]`` low-pass filtered over the whole chunk
    (:func:`~.prefilter.lowpass_channel`, state ``zi`` (S, B, 2, 6) in place, ``lp_fresh`` rows started in the
    steady state of their first sample and unflagged); if there is a model step, an ``ema_fresh`` row's two
    averages ``ema`` (2, B, 3) set to its first model step's specific force ``a`` and the flag cleared; per average
    ``i`` with weight ``alpha[i]`` the recursion of ``lfilter`` (direct form II transposed, state
    ``z = (1 - alpha) e``): ``e = z + alpha a``, ``z <- 0 a - (alpha - 1) e``, and ``ema[i]`` its last value; the
    float32 features (B, m, 10) ``(a - e_0) / accel_scale``, ``(a - e_1) / accel_scale``, the filtered angular
    rate ``/ gyro_scale`` and ``(||e_0|| - gravity) / accel_scale``, each formed in float64 and rounded once.
    The rows run in ``nchunk`` chunks (parallel in the parallel variant), each with its scratch.
    """
    B, n = f.shape[0], f.shape[1]
    m = pos.shape[0]
    for ch in nb.prange(nchunk):
        y = np.empty((n, 6))
        e = np.empty((2, m, 3))
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            for c in range(6):
                lowpass_channel(f if c < 3 else w, b, 0, n, c % 3, c, sos, zi_unit, zi, lp_fresh[b], y, 0)
            lp_fresh[b] = False
            if m == 0:
                continue
            if ema_fresh[b]:
                for i in range(2):
                    for c in range(3):
                        ema[i, b, c] = y[pos[0], c]
                ema_fresh[b] = False
            for i in range(2):
                al = alpha[i]
                a1 = -(1.0 - al)
                for c in range(3):
                    z = (1.0 - al) * ema[i, b, c]
                    for t in range(m):
                        x = y[pos[t], c]
                        v = z + al * x
                        z = x * 0.0 - v * a1
                        e[i, t, c] = v
                    ema[i, b, c] = e[i, m - 1, c]
            for t in range(m):
                p = pos[t]
                for c in range(3):
                    a = y[p, c]
                    feats[b, t, c] = (a - e[0, t, c]) / accel_scale
                    feats[b, t, 3 + c] = (a - e[1, t, c]) / accel_scale
                    feats[b, t, 6 + c] = y[p, 3 + c] / gyro_scale
                g0, g1, g2 = e[0, t, 0], e[0, t, 1], e[0, t, 2]
                feats[b, t, 9] = (np.sqrt((g0 * g0 + g1 * g1) + g2 * g2) - gravity) / accel_scale


_features_serial, _features_parallel = serial_and_parallel(_feature_rows)
