"""Zero-velocity aiding in the loop: where the stationary decisions come from, and the epoch's constraint block.

One object for both users of the aiding, :class:`envs.core.TuningCore` (the
environments) and :func:`envs.episodes.run_episodes` (eval.py), so that a
detector choice means the same thing everywhere:

==========  ====================================================================
choice      per-IMU-sample decision "stationary"
==========  ====================================================================
``none``    no aiding
``truth``   the true speed is below :data:`STILL_SPEED_MPS` (an oracle detector)
``shoe``,   the classical detectors of :mod:`nav_filters.zupt` (Skog et al. 2010)
``are``,
``mag``,
``mv``
``mlp``,    the learned detectors; shipped weights unless a weights file is given
``lstm``
==========  ====================================================================

At an epoch where the last IMU sample is declared stationary, the ZUPT rows and
the zero-heading-rate row (:func:`nav_filters.zupt.stationary_block`) are fused
into the epoch's GNSS update.
"""
from __future__ import annotations

import os

import numpy as np

from nav_filters.zupt import ZuptAidingConfig, make_detector, stationary_block

ZUPT_CHOICES = ("none", "truth", "shoe", "are", "mag", "mv", "mlp", "lstm")
"""Zero-velocity detector choices: none, the truth (speed < 0.05 m/s), or a detector of :mod:`nav_filters.zupt`."""
STILL_SPEED_MPS = 0.05
"""True speed below which the ``'truth'`` choice (and the labels) declare the vehicle stationary [m/s]."""
ZUPT_SIGMA_MPS = 0.02
"""Standard deviation of the ZUPT rows per axis [m/s]."""


def check_zupt_choice(choice, weights=None, owner: str = "zupt") -> None:
    """``ValueError`` naming ``owner`` for an unknown choice, weights given to a detector without weights,
    or a missing weights file (the shipped default when ``weights`` is None)."""
    if choice not in ZUPT_CHOICES:
        raise ValueError(f"{owner} must be one of {ZUPT_CHOICES}, got {choice!r}")
    if weights is not None and choice not in ("mlp", "lstm"):
        raise ValueError(f"{owner}_weights is only for zupt='mlp' or 'lstm', not {choice!r}")
    if choice in ("mlp", "lstm"):
        from nav_filters.zupt import default_weights_path
        if weights is not None and not isinstance(weights, (str, os.PathLike)):
            raise ValueError(f"{owner}_weights must be a path, got {weights!r}")
        path = default_weights_path(choice) if weights is None else weights
        if not os.path.isfile(path):
            raise ValueError(f"{owner}_weights: weights file {str(path)!r} of the {choice!r} detector not found "
                             f"(train one: `python train.py zupt --model {choice} --seed 0 --out runs/DIR`)")


class ZuptSource:
    """The stationary decisions of one detector choice over a batch, and the constraint block they drive.

    Parameters
    ----------
    choice : one of :data:`ZUPT_CHOICES`.
    rate_hz : IMU sample rate [Hz].
    weights : weights file of ``'mlp'`` / ``'lstm'`` (None: the shipped default).
    aiding : constraint settings (default: ZUPT sigma :data:`ZUPT_SIGMA_MPS`).
    """

    def __init__(self, choice: str, rate_hz: float, weights=None,
                 aiding: ZuptAidingConfig = ZuptAidingConfig(zupt_sigma_mps=ZUPT_SIGMA_MPS)):
        check_zupt_choice(choice, weights)
        self.choice = choice
        self.aiding = aiding
        self.detector = None if choice in ("none", "truth") else make_detector(choice, rate_hz, weights)
        self._compiled = True

    @property
    def compiled(self) -> bool:
        """Whether the detector's step (a classical detector's whole step, a learned one's features) and the
        constraint block run compiled (the default; the same bits); False: their numpy specifications (for
        comparisons: ``benchmarks/bench_zupt.py``)."""
        return self._compiled

    @compiled.setter
    def compiled(self, value: bool) -> None:
        self._compiled = bool(value)
        if hasattr(self.detector, "compiled"):
            self.detector.compiled = self._compiled

    @property
    def enabled(self) -> bool:
        return self.choice != "none"

    def reset(self, rows=None) -> None:
        """New IMU streams on ``rows`` (None: every row) for the stateful detectors."""
        if self.detector is not None:
            self.detector.reset() if rows is None else self.detector.reset_rows(rows)

    def decide(self, f_b, w_b, truth_still) -> np.ndarray:
        """(B, n) bool decisions for the next n IMU samples of every row (the detector's state advances).

        ``f_b``, ``w_b``: (B, n, 3) specific force [m/s^2] and angular rate [rad/s];
        ``truth_still``: (B, n) bool, the true stationarity (read only by ``'truth'``).
        """
        if self.choice == "truth":
            return np.asarray(truth_still, bool)
        return self.detector.process(f_b, w_b).stationary

    def block(self, nav, w_b, decisions, dt: float):
        """``(extra, active)`` of :func:`nav_filters.zupt.stationary_block` for ``Navigator.update_gnss``."""
        return stationary_block(nav, w_b, decisions, dt, self.aiding, compiled=self._compiled)
