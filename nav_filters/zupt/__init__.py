"""Zero-velocity (ZUPT) detection: pre-filter, classical and learned detectors, in-the-loop aiding.

Seed paper 000 sec 2: the IMU samples are low-pass filtered and a detector
classifies the motion state; when the vehicle is stationary, zero-velocity and
heading constraints are applied. This package holds everything a navigation
loop needs for that (numpy and scipy; torch is imported only by the learned
detectors, lazily):

* :mod:`.prefilter` -- causal second-order Butterworth low-pass;
* :mod:`.classical` -- SHOE (GLRT), ARE, MAG, MV statistics of Skog et al. (2010),
  streaming, and the max-F1 threshold tuning (:mod:`.classical_rows`: the streaming step compiled,
  the same bits);
* :mod:`.learned` -- MLP (window) and LSTM (sequence) detectors, their feature
  pipeline (:mod:`.learned_rows`: compiled, the same bits), weights files;
* :mod:`.aiding` -- the ZUPT + zero-heading-rate measurement block from a
  detector's decisions (fused by ``Navigator.update_gnss(..., extra=block)``);
* :mod:`.defaults` -- the shipped tuned constants and default weights.

The training code (simulated data, training loops, tuning, metrics) lives in
:mod:`agents.zupt_training`; ``python train.py zupt --model {mlp,lstm}``.

:func:`make_detector` is the one factory used by the environments and eval::

    det = make_detector("shoe", rate_hz=100.0)                # tuned default constants
    det = make_detector("lstm", rate_hz=100.0)                # shipped default weights
    det = make_detector("lstm", rate_hz=100.0, weights="runs/z/zupt_lstm.pt")
    out = det.process(f_b, w_b)                               # (B, n, 3) each -> out.stationary (B, n)
"""
from __future__ import annotations

from pathlib import Path

from .aiding import ZuptAidingConfig, stationary_block
from .base import DetectorOutput, ZuptDetector, check_imu
from .classical import CLASSICAL_KINDS, ClassicalConfig, ClassicalDetector, classical_statistic, tune_threshold
from .prefilter import LowPass, butter_lowpass, lowpass

__all__ = [
    "DETECTORS", "make_detector", "default_weights_path",
    "ZuptDetector", "DetectorOutput", "check_imu",
    "ClassicalConfig", "ClassicalDetector", "classical_statistic", "tune_threshold", "CLASSICAL_KINDS",
    "LowPass", "butter_lowpass", "lowpass",
    "ZuptAidingConfig", "stationary_block",
]

DETECTORS = CLASSICAL_KINDS + ("mlp", "lstm")
"""Detector names accepted by :func:`make_detector`."""


def default_weights_path(kind: str) -> Path:
    """Path of the shipped weights of learned detector ``kind`` (``'mlp'`` or ``'lstm'``)."""
    from .defaults import WEIGHTS_DIR
    if kind not in ("mlp", "lstm"):
        raise ValueError(f"kind must be 'mlp' or 'lstm', got {kind!r}")
    return WEIGHTS_DIR / f"zupt_{kind}.pt"


def make_detector(name: str, rate_hz: float, weights=None) -> ZuptDetector:
    """A detector by name at IMU rate ``rate_hz``.

    Parameters
    ----------
    name : one of :data:`DETECTORS`.
    rate_hz : IMU sample rate [Hz].
    weights : for ``'mlp'`` / ``'lstm'``: path of a weights file (None: the shipped default,
        :func:`default_weights_path`). Must be None for the classical detectors.

    Raises
    ------
    ValueError
        unknown name, weights given for a classical detector, a bad rate or weights file.
    FileNotFoundError
        the weights file does not exist.
    """
    from .defaults import CLASSICAL_DEFAULTS
    if name not in DETECTORS:
        raise ValueError(f"unknown detector {name!r}; known: {DETECTORS}")
    if name in CLASSICAL_KINDS:
        if weights is not None:
            raise ValueError(f"weights are only for the learned detectors ('mlp', 'lstm'), not {name!r}")
        return ClassicalDetector(CLASSICAL_DEFAULTS[name], rate_hz)
    from .learned import load_detector
    return load_detector(default_weights_path(name) if weights is None else weights, rate_hz)
