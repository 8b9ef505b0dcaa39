"""Shipped defaults of the zero-velocity detectors: tuned classical constants and the default weights.

The classical constants are the output of the tuning in ``agents.zupt_training.tune_classical``
(grid over window {0.1, 0.25, 0.5, 1.0} s and pre-filter cutoff {none, 2, 5, 10, 20} Hz, max-F1
threshold) on the simulated stop-heavy training drives of seed 0, as written to
``metrics.json["classical_tuned"]`` by::

    python train.py zupt --model lstm --seed 0 --out runs/zupt_lstm

(the tuning set does not depend on the model or on the number of epochs). Units of the thresholds:
the statistic T of :mod:`.classical`, normalized by ``sigma_a = 0.01 m/s^2`` and
``sigma_w = 1e-3 rad/s``. Training-set F1: shoe 0.714, are 0.713, mag 0.651, mv 0.767.

The learned detectors' weights live in :data:`WEIGHTS_DIR` (``zupt_mlp.pt``, ``zupt_lstm.pt``, each
< 200 kB); how each was produced is recorded in ``WEIGHTS_DIR / "README.md"``.
"""
from __future__ import annotations

from pathlib import Path

from .classical import ClassicalConfig

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"

CLASSICAL_DEFAULTS = {
    "shoe": ClassicalConfig(kind="shoe", window_s=0.5, threshold=16.59054241420383, cutoff_hz=5.0),
    "are": ClassicalConfig(kind="are", window_s=1.0, threshold=0.18574615609066697, cutoff_hz=5.0),
    "mag": ClassicalConfig(kind="mag", window_s=0.5, threshold=31.64748822104002, cutoff_hz=10.0),
    "mv": ClassicalConfig(kind="mv", window_s=1.0, threshold=3.297807232791154, cutoff_hz=5.0),
}
"""Tuned classical detectors (see the module docstring for the command that produced them)."""

DEFAULT_DETECTOR = "lstm"
"""The shipped default detector (its weights: ``WEIGHTS_DIR / "zupt_lstm.pt"``)."""
