"""Causal low-pass pre-filter of the IMU samples (second-order digital Butterworth).

Seed paper 000 sec 2 low-pass filters the raw accelerometer and gyro samples
before its zero-velocity network ("a second-order digital low-pass filter is
chosen, which allows for minimal delay while rapidly attenuating information
outside the cutoff frequency"; sec 5.3: it removes the high-frequency
environmental and engine vibration of a stopped car). The paper gives neither
the cutoff nor the design; here it is a Butterworth low-pass (maximally flat
pass band), designed by the bilinear transform with frequency pre-warping
(``scipy.signal.butter(order, cutoff_hz, fs=rate_hz)``), so the digital
magnitude response is exactly ``1/sqrt(2)`` (-3 dB) at the cutoff and 1 at DC.

The filter is causal (run forward only, as an online detector must) and
stateful: :class:`LowPass` filters a stream chunk by chunk and gives exactly
the one-shot result of :func:`lowpass` on the concatenated stream. It starts in
the steady state of its first input sample (``scipy.signal.sosfilt_zi``), so a
stream that begins with gravity on the z axis does not ring through a 9.8 m/s^2
start-up transient.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np
from scipy.signal import butter, sosfilt, sosfilt_zi

__all__ = ["butter_lowpass", "LowPass", "lowpass", "check_cutoff", "lowpass_channel"]


def check_cutoff(cutoff_hz, rate_hz, name="cutoff_hz"):
    """Validate a cutoff against a sample rate: ``0 < cutoff < rate / 2`` (ValueError naming ``name``)."""
    for n, v in ((name, cutoff_hz), ("rate_hz", rate_hz)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v) \
                or v <= 0:
            raise ValueError(f"{n} must be a positive finite number, got {v!r}")
    if not cutoff_hz < 0.5 * rate_hz:
        raise ValueError(f"{name} ({cutoff_hz} Hz) must be below the Nyquist frequency {0.5 * rate_hz} Hz "
                         f"of rate_hz = {rate_hz} Hz")
    return float(cutoff_hz), float(rate_hz)


def butter_lowpass(cutoff_hz: float, rate_hz: float, order: int = 2) -> np.ndarray:
    """Second-order sections of a digital Butterworth low-pass.

    Seed paper 000 sec 2 (second-order low-pass before the detector); the
    Butterworth design by the bilinear transform with pre-warping (``scipy.signal.butter``):
    ``|H(e^{j 2 pi f / fs})|^2 = 1 / (1 + (tan(pi f / fs) / tan(pi fc / fs))^(2 order))``,
    so ``|H| = 1/sqrt(2)`` at ``f = fc`` and ``|H| = 1`` at DC.

    Parameters
    ----------
    cutoff_hz : -3 dB frequency fc [Hz], ``0 < fc < rate_hz / 2``.
    rate_hz : sample rate fs [Hz].
    order : filter order (default 2, the paper's), 1..8.

    Returns
    -------
    sos : (ceil(order / 2), 6) float64 second-order sections.
    """
    cutoff_hz, rate_hz = check_cutoff(cutoff_hz, rate_hz)
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or not 1 <= order <= 8:
        raise ValueError(f"order must be an int in 1..8, got {order!r}")
    return butter(int(order), cutoff_hz, btype="low", fs=rate_hz, output="sos")


def _check_stream(x, channels=None, name="x"):
    a = np.asarray(x)
    if a.ndim != 3 or (channels is not None and a.shape[2] != channels):
        want = f"(B, n, {channels})" if channels is not None else "(B, n, C)"
        raise ValueError(f"{name} must have shape {want}, got {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"{name} must be a real array, got dtype {a.dtype}")
    a = a.astype(np.float64, copy=False)
    if not np.isfinite(a).all():
        b, k = np.argwhere(~np.isfinite(a).all(-1))[0]
        raise ValueError(f"{name} has a NaN or inf sample (row {b}, sample {k}); the detectors need finite IMU data")
    return a


class LowPass:
    """Stateful causal Butterworth low-pass over a batch of multichannel streams.

    Parameters
    ----------
    cutoff_hz, rate_hz, order : see :func:`butter_lowpass`.

    Call it with successive chunks ``x`` of shape (B, n, C) (n may be 0); the
    filter state (B rows) is created from the first chunk's first sample
    (steady state), and :meth:`reset_rows` restarts single rows (their next
    sample re-initializes them). Output float64 (B, n, C).
    """

    def __init__(self, cutoff_hz: float, rate_hz: float, order: int = 2):
        self.sos = butter_lowpass(cutoff_hz, rate_hz, order)
        self.cutoff_hz, self.rate_hz, self.order = float(cutoff_hz), float(rate_hz), int(order)
        self._zi_unit = sosfilt_zi(self.sos)  # (S, 2): state for a unit step held forever
        self.zi = None                        # (S, B, 2, C)
        self._fresh = None                    # (B,) rows whose state is to be initialized

    def reset(self):
        """Forget all state (the next chunk may have another batch size)."""
        self.zi = None
        self._fresh = None

    def reset_rows(self, rows):
        """Restart rows ``rows``: their next sample re-initializes their state (steady state)."""
        if self._fresh is not None:
            self._fresh[np.asarray(rows, np.intp)] = True

    def compiled_state(self, B: int):
        """``(sos, zi_unit, zi, fresh)`` for a compiled step of B rows (:func:`lowpass_channel`): the state
        created as :meth:`__call__` creates it on a first chunk (C = 6 channels) and made C-contiguous, updated in
        place by the kernel; None where the filter runs another batch size (then :meth:`__call__` raises)."""
        if self.zi is None:
            self.zi = np.zeros((self.sos.shape[0], B, 2, 6))
            self._fresh = np.ones(B, bool)
        elif self.zi.shape[1:] != (B, 2, 6):
            return None
        self.zi = np.ascontiguousarray(self.zi)
        return self.sos, self._zi_unit, self.zi, self._fresh

    def __call__(self, x) -> np.ndarray:
        x = _check_stream(x)
        B, n, C = x.shape
        if self.zi is not None and self.zi.shape[1:] != (B, 2, C):
            raise ValueError(f"x has B={B}, C={C} but the filter runs B={self.zi.shape[1]}, C={self.zi.shape[3]} "
                             "(call reset() first)")
        if n == 0:
            return x.copy()
        if self.zi is None:
            self.zi = np.zeros((self.sos.shape[0], B, 2, C))
            self._fresh = np.ones(B, bool)
        if self._fresh.any():
            r = np.flatnonzero(self._fresh)
            self.zi[:, r] = self._zi_unit[:, None, :, None] * x[r, 0][None, :, None, :]
            self._fresh[r] = False
        y, self.zi = sosfilt(self.sos, x, axis=1, zi=self.zi)
        return y


def lowpass(x, rate_hz: float, cutoff_hz: float, order: int = 2) -> np.ndarray:
    """One-shot causal low-pass of whole streams ``x`` (B, n, C), starting in the first sample's steady state.

    Seed paper 000 sec 2 pre-filter (see :func:`butter_lowpass`). Returns float64 (B, n, C).
    """
    return LowPass(cutoff_hz, rate_hz, order)(x)


@nb.njit(cache=True, inline="always")
def lowpass_channel(src, b, s0, k, cc, c, sos, zi_unit, zi, fresh, out, o0):
    """Compiled :class:`LowPass` step of one channel of one row (the same bits as ``scipy.signal.sosfilt``, direct
    form II transposed, and the steady-state start of ``sosfilt_zi``).

    Filters ``src[b, s0 : s0 + k, cc]`` with the sections ``sos`` (S, 6) and the state ``zi[:, b, :, c]``
    (``zi`` (S, B, 2, C), updated in place) into ``out[o0 : o0 + k, c]``; per sample and section
    ``y = b0 x + z0``, ``z0 <- b1 x - a1 y + z1``, ``z1 <- b2 x - a2 y``. Where ``fresh`` the state is first set to
    the steady state of the chunk's first sample, ``zi_unit`` (S, 2) times it (the caller clears the flag).
    Used by the compiled detector steps (:mod:`.classical_rows`, :mod:`.learned_rows`).
    """
    S = sos.shape[0]
    if fresh:
        x0 = src[b, s0, cc]
        for s in range(S):
            zi[s, b, 0, c] = zi_unit[s, 0] * x0
            zi[s, b, 1, c] = zi_unit[s, 1] * x0
    for i in range(k):
        x_cur = src[b, s0 + i, cc]
        for s in range(S):
            x_new = sos[s, 0] * x_cur + zi[s, b, 0, c]
            zi[s, b, 0, c] = sos[s, 1] * x_cur - sos[s, 4] * x_new + zi[s, b, 1, c]
            zi[s, b, 1, c] = sos[s, 2] * x_cur - sos[s, 5] * x_new
            x_cur = x_new
        out[o0 + i, c] = x_cur
