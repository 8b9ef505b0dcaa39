"""The one streaming interface of every zero-velocity detector, and the IMU input checks.

A detector consumes the IMU samples of B vehicles in lock step, chunk by chunk
(e.g. the samples between two GNSS epochs), and returns per sample a *score*
and the stationary decision:

* classical detectors (:mod:`.classical`): the score is the test statistic
  ``T`` of Skog et al. (2010), stationary where ``T < threshold``;
* learned detectors (:mod:`.learned`): the score is the stationary probability
  ``p``, stationary where ``p >= threshold``.

Detectors are causal: the decision at sample k uses samples up to k only, so
running a stream in one call or in chunks gives identical results (tested).
Samples whose window is not yet full (the first ``W - 1`` of a stream, or of a
row after :meth:`ZuptDetector.reset_rows`) are declared moving (score ``inf``
or probability 0): a detector never fires on too little data.

Input convention: ``f_b`` specific force [m/s^2] and ``w_b`` angular rate
[rad/s], (B, n, 3), body FRD, raw (uncompensated: the detectors see what the
sensor delivers, biases included), as interval means at ``rate_hz``.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numba as nb
import numpy as np

__all__ = ["ZuptDetector", "DetectorOutput", "check_imu", "SCORE_KINDS", "compiled_input"]

SCORE_KINDS = ("statistic", "probability")


def check_imu(f_b, w_b) -> np.ndarray:
    """Validate one chunk of IMU samples and stack it as (B, n, 6) float64 ``[f_b, w_b]``.

    Raises
    ------
    ValueError
        naming ``f_b`` / ``w_b``: not (B, n, 3), shapes differ, not real, or a
        NaN / inf sample (with its row and sample index).
    """
    arrs = []
    for name, x in (("f_b", f_b), ("w_b", w_b)):
        a = np.asarray(x)
        if a.ndim != 3 or a.shape[2] != 3:
            raise ValueError(f"{name} must have shape (B, n, 3), got {a.shape}")
        if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
            raise ValueError(f"{name} must be a real array, got dtype {a.dtype}")
        a = a.astype(np.float64, copy=False)
        bad = ~np.isfinite(a).all(-1)
        if bad.any():
            b, k = np.argwhere(bad)[0]
            raise ValueError(f"{name} has a NaN or inf sample (row {b}, sample {k}); "
                             "a zero-velocity detector needs finite IMU data")
        arrs.append(a)
    if arrs[0].shape != arrs[1].shape:
        raise ValueError(f"f_b and w_b must have the same shape, got {arrs[0].shape} and {arrs[1].shape}")
    return np.concatenate(arrs, axis=2)


def compiled_input(f, w) -> bool:
    """Whether a chunk ``f_b``, ``w_b`` is what the compiled detector steps take: float64 arrays of one
    (B, n >= 1, 3) shape with finite samples (what :func:`check_imu` accepts, less the conversions). Elsewhere
    the numpy path runs, and raises the error naming the input."""
    return (type(f) is np.ndarray and type(w) is np.ndarray and f.dtype == np.float64 and w.dtype == np.float64
            and f.ndim == 3 and f.shape == w.shape and f.shape[2] == 3 and f.shape[1] > 0 and _all_finite(f, w))


@nb.njit(cache=True)
def _all_finite(f, w):
    """Whether every entry of ``f`` and ``w`` (B, n, 3) is finite."""
    for b in range(f.shape[0]):
        for i in range(f.shape[1]):
            for c in range(3):
                if not (np.isfinite(f[b, i, c]) and np.isfinite(w[b, i, c])):
                    return False
    return True


@dataclass(frozen=True)
class DetectorOutput:
    """Per-sample detector output for one chunk.

    Attributes
    ----------
    score : (B, n) float64, test statistic (classical) or stationary probability (learned).
    stationary : (B, n) bool decision.
    """

    score: np.ndarray
    stationary: np.ndarray


class ZuptDetector(ABC):
    """Streaming, batched zero-velocity detector (see the module docstring).

    Attributes
    ----------
    name : detector name (``'shoe'``, ``'are'``, ``'mag'``, ``'mv'``, ``'mlp'``, ``'lstm'``).
    rate_hz : IMU sample rate the detector runs at [Hz].
    threshold : decision threshold on the score.
    score_kind : ``'statistic'`` (stationary below the threshold) or ``'probability'`` (at or above).
    """

    name: str
    rate_hz: float
    threshold: float
    score_kind: str

    @abstractmethod
    def reset(self) -> None:
        """Forget every stream (the next chunk may have another batch size)."""

    @abstractmethod
    def reset_rows(self, rows) -> None:
        """Restart the streams of batch rows ``rows`` (new episodes on those rows)."""

    @abstractmethod
    def _score(self, x: np.ndarray) -> np.ndarray:
        """Scores (B, n) of one validated chunk ``x`` (B, n, 6) ``[f_b, w_b]``."""

    def decide(self, score) -> np.ndarray:
        """Stationary decision (bool, shape of ``score``) for scores at this detector's threshold."""
        s = np.asarray(score, np.float64)
        return s < self.threshold if self.score_kind == "statistic" else s >= self.threshold

    def process(self, f_b, w_b) -> DetectorOutput:
        """Advance every stream by one chunk.

        Parameters
        ----------
        f_b, w_b : (B, n, 3) raw specific force [m/s^2] and angular rate [rad/s] at ``rate_hz``.

        Returns
        -------
        DetectorOutput with (B, n) score and decision.
        """
        x = check_imu(f_b, w_b)
        score = self._score(x)
        return DetectorOutput(score=score, stationary=self.decide(score))

    def detect(self, f_b, w_b) -> DetectorOutput:
        """One-shot: :meth:`reset`, then :meth:`process` the whole streams (B, N, 3)."""
        self.reset()
        return self.process(f_b, w_b)


def window_sums(x: np.ndarray, W: int) -> np.ndarray:
    """Trailing-window sums: ``out[:, k] = x[:, k:k + W].sum(1)`` for k = 0 .. L - W.

    Parameters
    ----------
    x : (B, L, C) float64; W : window length (1 <= W <= L).

    Returns
    -------
    (B, L - W + 1, C) float64 (by a cumulative sum: O(L), not O(L W)).
    """
    c = np.cumsum(x, axis=1)
    out = c[:, W - 1:].copy()
    out[:, 1:] -= c[:, :-W]
    return out
