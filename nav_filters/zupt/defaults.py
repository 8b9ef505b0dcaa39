"""Shipped defaults of the zero-velocity detectors (tuned constants, weights location).

PLACEHOLDER values: replaced by the output of the tuning run (see agents.zupt_training).
"""
from __future__ import annotations

from pathlib import Path

from .classical import ClassicalConfig

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"

CLASSICAL_DEFAULTS = {
    "shoe": ClassicalConfig(kind="shoe", window_s=0.5, threshold=15.0, cutoff_hz=5.0),
    "are": ClassicalConfig(kind="are", window_s=1.0, threshold=0.12, cutoff_hz=5.0),
    "mag": ClassicalConfig(kind="mag", window_s=0.3, threshold=20.0, cutoff_hz=15.0),
    "mv": ClassicalConfig(kind="mv", window_s=1.0, threshold=1.2, cutoff_hz=5.0),
}

DEFAULT_DETECTOR = "shoe"
