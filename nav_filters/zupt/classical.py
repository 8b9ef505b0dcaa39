"""Classical zero-velocity detectors: SHOE (GLRT), ARE, MAG and MV test statistics.

Reference: I. Skog, P. Handel, J.-O. Nilsson, J. Rantakokko, "Zero-velocity
detection - an algorithm evaluation", IEEE Trans. Biomed. Eng. 57(11), 2010,
pp. 2657-2666 (seed paper 000 ref. 18). The paper is not in
``../shared/papers``, so its equation numbers are not quoted; the statistics
are those of its section on the detectors, each over a window ``Omega_n`` of
``W`` samples, with ``y^a_k`` the specific force, ``y^w_k`` the angular rate,
``ybar^a_n`` the window mean of ``y^a``, ``g`` the gravity magnitude and
``sigma_a``, ``sigma_w`` the accelerometer and gyro noise standard deviations::

    SHOE (the GLRT, "stance hypothesis optimal estimation"):
        T = 1/W sum_k [ ||y^a_k - g ybar^a_n / ||ybar^a_n|| ||^2 / sigma_a^2 + ||y^w_k||^2 / sigma_w^2 ]
    ARE (angular rate energy):
        T = 1/(sigma_w^2 W) sum_k ||y^w_k||^2
    MAG (acceleration magnitude):
        T = 1/(sigma_a^2 W) sum_k (||y^a_k|| - g)^2
    MV (acceleration moving variance):
        T = 1/(sigma_a^2 W) sum_k ||y^a_k - ybar^a_n||^2

The vehicle is declared stationary when ``T < gamma`` (the threshold).
Differences from the paper, for an online land-vehicle detector:

* the window is *trailing* (samples ``k - W + 1 .. k`` decide sample k; the
  paper centres it, which needs future samples), so the decision is causal;
* the samples are first low-pass filtered (:mod:`.prefilter`, seed paper 000
  sec 2) unless ``cutoff_hz`` is None;
* ``sigma_a`` and ``sigma_w`` are fixed nominal values that only set the
  units of ``T`` (and SHOE's weighting of the two sensors); the threshold is
  tuned on labelled data (:func:`tune_threshold`, max F1), so one detector
  serves several IMU grades.

Every sum over a window is a difference of cumulative sums (O(n) per chunk),
with the SHOE accelerometer term split in closed form:
``sum_k ||y_k - g u||^2 = sum_k ||y_k - ybar||^2 + W (||ybar|| - g)^2`` for
``u = ybar / ||ybar||`` (the cross term vanishes because ``sum_k (y_k - ybar) = 0``,
and ``||ybar - g u|| = | ||ybar|| - g |``); the moving variance is accumulated on
samples shifted by a per-row reference, so no ``g^2``-sized terms cancel.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..kernels import row_kernel
from .base import DetectorOutput, ZuptDetector, compiled_input, window_sums
from .classical_rows import KIND_CODES, _chunk_parallel, _chunk_serial
from .prefilter import LowPass, check_cutoff

__all__ = ["CLASSICAL_KINDS", "ClassicalConfig", "ClassicalDetector", "classical_statistic", "tune_threshold",
           "G0"]

CLASSICAL_KINDS = ("shoe", "are", "mag", "mv")
G0 = 9.80665
"""Standard gravity [m/s^2], the default ``g`` of SHOE and MAG (local gravity differs by < 0.3 %)."""


def _pos(owner, name, v, allow_none=False):
    if v is None and allow_none:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v) \
            or v <= 0:
        raise ValueError(f"{owner}.{name} must be a positive finite number, got {v!r}")
    return float(v)


@dataclass(frozen=True)
class ClassicalConfig:
    """A classical detector (validated; errors name the field).

    Attributes
    ----------
    kind : ``'shoe'``, ``'are'``, ``'mag'`` or ``'mv'``.
    window_s : trailing window length [s]; ``W = max(2, round(window_s * rate_hz))`` samples.
    threshold : gamma, stationary where ``T < gamma`` [-] (T is normalized by the sigmas).
    sigma_a : nominal accelerometer noise standard deviation [m/s^2] (units of T).
    sigma_w : nominal gyro noise standard deviation [rad/s] (units of T).
    gravity : g [m/s^2] (SHOE and MAG).
    cutoff_hz : pre-filter cutoff [Hz] (second-order Butterworth), or None for no pre-filter.
    """

    kind: str = "shoe"
    window_s: float = 0.5
    threshold: float = 1.0
    sigma_a: float = 0.01
    sigma_w: float = 1e-3
    gravity: float = G0
    cutoff_hz: float | None = 5.0

    def __post_init__(self):
        if self.kind not in CLASSICAL_KINDS:
            raise ValueError(f"ClassicalConfig.kind must be one of {CLASSICAL_KINDS}, got {self.kind!r}")
        for f in ("window_s", "threshold", "sigma_a", "sigma_w", "gravity"):
            object.__setattr__(self, f, _pos("ClassicalConfig", f, getattr(self, f)))
        object.__setattr__(self, "cutoff_hz", _pos("ClassicalConfig", "cutoff_hz", self.cutoff_hz, True))

    def window_samples(self, rate_hz: float) -> int:
        """W at ``rate_hz`` (at least 2)."""
        return max(2, int(round(self.window_s * rate_hz)))


def classical_statistic(kind: str, x: np.ndarray, W: int, sigma_a: float, sigma_w: float,
                        gravity: float = G0) -> np.ndarray:
    """Test statistic T of Skog et al. (2010) on every full trailing window of ``x``.

    SHOE, ARE, MAG, MV as in the module docstring (Skog et al. 2010, detector
    section; equation numbers not quoted).

    Parameters
    ----------
    kind : ``'shoe'``, ``'are'``, ``'mag'``, ``'mv'``.
    x : (B, L, 6) float64 samples ``[f_b (m/s^2), w_b (rad/s)]``.
    W : window length [samples], 1 <= W <= L.
    sigma_a, sigma_w : noise standard deviations [m/s^2], [rad/s].
    gravity : g [m/s^2].

    Returns
    -------
    T : (B, L - W + 1) float64, ``T[:, j]`` over samples ``j .. j + W - 1``; >= 0.
    """
    if kind not in CLASSICAL_KINDS:
        raise ValueError(f"kind must be one of {CLASSICAL_KINDS}, got {kind!r}")
    a, w = x[..., :3], x[..., 3:]
    if kind == "are":
        return window_sums(np.sum(w * w, -1, keepdims=True), W)[..., 0] / (W * sigma_w ** 2)
    if kind == "mag":
        m = np.linalg.norm(a, axis=-1, keepdims=True) - gravity
        return window_sums(m * m, W)[..., 0] / (W * sigma_a ** 2)
    # moving variance about the window mean, on samples shifted by a per-row reference: the variance is
    # shift-invariant, and the shift keeps the sums at noise scale (no cancellation of g^2-sized terms)
    ref = a[:, -1:, :]
    d = a - ref
    s = window_sums(np.concatenate([d, np.sum(d * d, -1, keepdims=True)], -1), W)
    mean_d = s[..., :3] / W
    var = np.maximum(s[..., 3] / W - np.sum(mean_d * mean_d, -1), 0.0)    # 1/W sum ||y_k - ybar||^2
    if kind == "mv":
        return var / sigma_a ** 2
    # SHOE: 1/W sum ||y_k - g u||^2 = 1/W sum ||y_k - ybar||^2 + (||ybar|| - g)^2, u = ybar / ||ybar||
    dg = np.linalg.norm(mean_d + ref, axis=-1) - gravity
    tw = window_sums(np.sum(w * w, -1, keepdims=True), W)[..., 0] / (W * sigma_w ** 2)
    return (var + dg * dg) / sigma_a ** 2 + tw


class ClassicalDetector(ZuptDetector):
    """Streaming classical detector: pre-filter, trailing window statistic, threshold.

    Parameters
    ----------
    config : ClassicalConfig
    rate_hz : IMU rate [Hz] (the pre-filter cutoff must be below its Nyquist frequency).
    """

    score_kind = "statistic"
    _CHUNK = 8192
    compiled = True
    """Run :meth:`process` through the compiled kernel (:mod:`.classical_rows`, the same bits) where its inputs
    allow; False: always the numpy specification (``_score``)."""

    def __init__(self, config: ClassicalConfig, rate_hz: float):
        if not isinstance(config, ClassicalConfig):
            raise ValueError(f"config must be a ClassicalConfig, got {type(config).__name__}")
        self.config = config
        self.name = config.kind
        self.rate_hz = _pos("ClassicalDetector", "rate_hz", rate_hz)
        if config.cutoff_hz is not None:
            check_cutoff(config.cutoff_hz, self.rate_hz, "ClassicalConfig.cutoff_hz")
        self.threshold = config.threshold
        self.W = config.window_samples(self.rate_hz)
        self._lp = LowPass(config.cutoff_hz, self.rate_hz) if config.cutoff_hz is not None else None
        self.reset()

    def reset(self):
        self._tail = None      # (B, W - 1, 6) last filtered samples
        self._count = None     # (B,) samples seen (capped)
        if self._lp is not None:
            self._lp.reset()

    def reset_rows(self, rows):
        if self._count is not None:
            self._count[np.asarray(rows, np.intp)] = 0
        if self._lp is not None:
            self._lp.reset_rows(rows)

    def process(self, f_b, w_b) -> DetectorOutput:
        """:meth:`ZuptDetector.process`, compiled (:func:`.classical_rows._classical_rows`) for float64 arrays of
        the same (B, n >= 1, 3) shape with finite samples and a batch size matching the detector's state; the
        numpy specification otherwise (it raises the error naming the bad input)."""
        out = self._process_compiled(f_b, w_b) if self.compiled else None
        return super().process(f_b, w_b) if out is None else out

    def _process_compiled(self, f, w):
        """The compiled :meth:`process`, or None where the numpy path must run (nothing changed then)."""
        if not compiled_input(f, w):
            return None
        B, n, _ = f.shape
        lp = self._lp
        if self._tail is not None and self._tail.shape[0] != B:
            return None
        lp_state = (lp.compiled_state(B) if lp is not None
                    else (np.zeros((0, 6)), np.zeros((0, 2)), np.zeros((0, B, 2, 6)), np.zeros(B, bool)))
        if lp_state is None:
            return None
        first = self._tail is None
        if first:
            self._tail = np.empty((B, self.W - 1, 6))
            self._count = np.zeros(B, np.int64)
        tail = self._tail = np.ascontiguousarray(self._tail)
        count = self._count = np.ascontiguousarray(self._count, np.int64)
        c = self.config
        W = self.W
        score, stationary = np.empty((B, n)), np.empty((B, n), bool)
        kern, nchunk = row_kernel(_chunk_serial, _chunk_parallel, B)
        for s in range(0, n, self._CHUNK):
            kern(f, w, s, min(self._CHUNK, n - s), *lp_state, lp is not None, tail, count, first, W,
                 KIND_CODES[c.kind], c.gravity, c.sigma_a ** 2, W * c.sigma_a ** 2, W * c.sigma_w ** 2,
                 float(self.threshold), score, stationary, nchunk)
            first = False
        return DetectorOutput(score=score, stationary=stationary)

    def _score(self, x):
        """Scores of one validated chunk by the numpy specification (pre-filter, window statistic)."""
        B, n, _ = x.shape
        if self._tail is None:
            self._tail = None if n == 0 else np.empty((B, self.W - 1, 6))
            self._count = np.zeros(B, np.int64)
            first = True
        elif self._tail.shape[0] != B:
            raise ValueError(f"the detector runs B={self._tail.shape[0]} streams, got a chunk with B={B} "
                             "(call reset() first)")
        else:
            first = False
        out = np.empty((B, n))
        for s in range(0, n, self._CHUNK):
            xs = x[:, s:s + self._CHUNK]
            if self._lp is not None:
                xs = self._lp(xs)
            if first:   # pad the (masked) not-yet-full windows with the first sample: sums stay at noise scale
                self._tail[:] = xs[:, :1]
                first = False
            buf = np.concatenate([self._tail, xs], axis=1)
            c = self.config
            T = classical_statistic(c.kind, buf, self.W, c.sigma_a, c.sigma_w, c.gravity)
            k = xs.shape[1]
            seen = self._count[:, None] + np.arange(1, k + 1)[None, :]
            T[seen < self.W] = np.inf
            out[:, s:s + k] = T
            self._tail = buf[:, buf.shape[1] - (self.W - 1):]
            self._count = np.minimum(self._count + k, self.W)
        return out


def tune_threshold(score, label, *, stationary_below: bool = True, max_false_rate: float | None = None):
    """Decision threshold that maximizes F1 of the stationary class on labelled samples.

    Sweeps every threshold between consecutive distinct scores at once (sort +
    cumulative counts: O(N log N)). With ``max_false_rate``, only thresholds
    whose false-ZUPT rate (moving samples declared stationary / moving samples)
    is at most that value are admitted.

    Parameters
    ----------
    score : (N,) scores (non-finite scores are never declared stationary).
    label : (N,) bool, True = truly stationary.
    stationary_below : True for test statistics (stationary where ``score < threshold``),
        False for probabilities (stationary where ``score >= threshold``).
    max_false_rate : optional cap on the false-ZUPT rate, in [0, 1].

    Returns
    -------
    threshold : float
    f1 : float, F1 at that threshold on these samples.
    """
    s = np.asarray(score, np.float64).ravel()
    y = np.asarray(label).ravel()
    if y.dtype != bool or y.shape != s.shape:
        raise ValueError(f"label must be a bool array with the shape of score {s.shape}, got {y.dtype} {y.shape}")
    if s.size == 0 or not y.any() or y.all():
        raise ValueError("tune_threshold needs both stationary and moving samples")
    if not stationary_below:
        s = -s
    s = np.where(np.isfinite(s), s, np.inf)
    order = np.argsort(s, kind="stable")
    ss, yy = s[order], y[order]
    tp = np.cumsum(yy)                                   # declaring the first i+1 sorted samples stationary
    fp = np.cumsum(~yy)
    P = tp[-1]
    Nm = fp[-1]
    last = np.r_[ss[1:] != ss[:-1], True] & np.isfinite(ss)   # cut only between distinct finite scores
    f1 = np.where(last, 2 * tp / (2 * tp + fp + (P - tp)), -1.0)
    if max_false_rate is not None:
        if not 0.0 <= max_false_rate <= 1.0:
            raise ValueError(f"max_false_rate must be in [0, 1], got {max_false_rate!r}")
        f1 = np.where(fp <= max_false_rate * Nm, f1, -1.0)
    i = int(np.argmax(f1))
    if f1[i] < 0:                                        # nothing admissible: never fire
        thr = ss[0] - 1.0 if np.isfinite(ss[0]) else 0.0
        return float(-thr if not stationary_below else thr), 0.0
    nxt = ss[i + 1] if i + 1 < ss.size and np.isfinite(ss[i + 1]) else ss[i] + max(abs(ss[i]), 1.0)
    thr = 0.5 * (ss[i] + nxt)
    if not stationary_below:
        thr = -thr
    return float(thr), float(f1[i])
