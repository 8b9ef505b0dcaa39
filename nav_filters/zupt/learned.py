"""Learned zero-velocity detectors: an MLP on a window and an LSTM over the sequence (torch, lazily imported).

Seed paper 000 sec 2 classifies the motion state (stationary / moving) with a
neural network on low-pass-filtered raw IMU samples (three-axis specific force
and angular rate; network details in its ref. 21, the windowed network of
AZUPT; the recurrent alternative is Wagstaff & Kelly's LSTM detector, its ref.
22). The paper fixes no architecture; the two here are:

``mlp``
    a multilayer perceptron on the trailing window of the last ``window``
    feature vectors (``window / model_rate_hz`` seconds);
``lstm``
    a single-layer LSTM run over the whole feature sequence, carrying its
    state from sample to sample (and chunk to chunk): it can remember the
    acceleration that started a slow creep or the braking that ended at a stop
    long after a window detector has forgotten it.

Input pipeline (:class:`FeatureStream`, shared by training and inference so
the two cannot drift apart), per stream:

1. the seed-000 pre-filter: second-order Butterworth low-pass at ``cutoff_hz``
   on the six raw channels at the IMU rate (:mod:`.prefilter`); it is also the
   anti-alias filter of step 2;
2. decimation to ``model_rate_hz`` (the IMU rate must be an integer multiple),
   so one network serves 50, 100, 200 Hz ... IMUs;
3. per model step, 10 features: the filtered specific force minus its causal
   exponential moving averages of time constants ``ema_tau_s`` (short: fast
   events) and ``ema_long_tau_s`` (long: keeps a braking or an acceleration of
   several seconds, which a detector must integrate to tell "braked to a stop"
   from "braked to walking pace"), both over ``accel_scale``; the filtered
   angular rate over ``gyro_scale`` (biases kept: the network sees the
   stationary level); and ``(|short EMA| - gravity) / accel_scale``. The moving
   averages remove gravity, mounting tilt and accelerometer bias; they start
   at a stream's first sample (a drive starts at rest).

The detector runs the network at the model steps and holds each probability
over the IMU samples up to the next model step (causal). A stream's first
model steps (MLP: until its window is full) give probability 0 (moving).

Weights files (``torch.save`` of a plain dict, loaded with
``weights_only=True``): ``{"format": "navgym-zupt-v1", "config": {...},
"state_dict": {...}}``; see :func:`save_weights`, :func:`load_detector`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.signal import lfilter

from ..kernels import row_kernel
from .base import DetectorOutput, ZuptDetector, compiled_input
from .classical import G0
from .learned_rows import _features_parallel, _features_serial
from .prefilter import LowPass, check_cutoff

__all__ = ["LEARNED_KINDS", "N_FEATURES", "LearnedConfig", "FeatureStream", "LearnedDetector", "build_model",
           "save_weights", "load_detector", "WEIGHTS_FORMAT"]

LEARNED_KINDS = ("mlp", "lstm")
N_FEATURES = 10
WEIGHTS_FORMAT = "navgym-zupt-v1"


def _num(owner, name, v, *, lo=0.0, lo_open=True, integer=False, hi=None):
    if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not math.isfinite(v):
        raise ValueError(f"{owner}.{name} must be a finite number, got {v!r}")
    if integer and int(v) != v:
        raise ValueError(f"{owner}.{name} must be an integer, got {v!r}")
    if (v <= lo if lo_open else v < lo) or (hi is not None and v > hi):
        rng = f"{'>' if lo_open else '>='} {lo}" + (f" and <= {hi}" if hi is not None else "")
        raise ValueError(f"{owner}.{name} must be {rng}, got {v!r}")
    return int(v) if integer else float(v)


@dataclass(frozen=True)
class LearnedConfig:
    """Architecture and input pipeline of a learned detector (validated; errors name the field).

    Attributes
    ----------
    kind : ``'mlp'`` or ``'lstm'``.
    model_rate_hz : rate the network runs at [Hz]; the IMU rate must be an integer multiple.
    cutoff_hz : pre-filter cutoff [Hz], below ``model_rate_hz / 2`` (anti-alias).
    window : MLP window length [model steps] (unused by the LSTM), >= 1.
    hidden : hidden width (MLP: both hidden layers; LSTM: input embedding and state size).
    ema_tau_s, ema_long_tau_s : time constants of the two specific-force moving averages [s].
    accel_scale : specific-force feature scale [m/s^2]; gyro_scale : angular-rate feature scale [rad/s].
    gravity : g [m/s^2] of the magnitude feature.
    threshold : stationary where the probability is >= threshold, in (0, 1).
    """

    kind: str = "lstm"
    model_rate_hz: float = 50.0
    cutoff_hz: float = 20.0
    window: int = 50
    hidden: int = 48
    ema_tau_s: float = 2.0
    ema_long_tau_s: float = 30.0
    accel_scale: float = 0.1
    gyro_scale: float = 0.05
    gravity: float = G0
    threshold: float = 0.5

    def __post_init__(self):
        o = "LearnedConfig"
        if self.kind not in LEARNED_KINDS:
            raise ValueError(f"{o}.kind must be one of {LEARNED_KINDS}, got {self.kind!r}")
        for f in ("model_rate_hz", "cutoff_hz", "ema_tau_s", "ema_long_tau_s", "accel_scale", "gyro_scale",
                  "gravity"):
            object.__setattr__(self, f, _num(o, f, getattr(self, f)))
        for f, hi in (("window", 10000), ("hidden", 4096)):
            object.__setattr__(self, f, _num(o, f, getattr(self, f), lo=1, lo_open=False, integer=True, hi=hi))
        object.__setattr__(self, "threshold", _num(o, "threshold", self.threshold, hi=1.0))
        if self.threshold >= 1.0:
            raise ValueError(f"{o}.threshold must be < 1, got {self.threshold!r}")
        check_cutoff(self.cutoff_hz, self.model_rate_hz, f"{o}.cutoff_hz")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d) -> "LearnedConfig":
        if not isinstance(d, dict):
            raise ValueError(f"a LearnedConfig dict is required, got {type(d).__name__}")
        names = {f.name for f in dataclasses.fields(cls)}
        bad = sorted(set(d) - names)
        if bad:
            raise ValueError(f"unknown LearnedConfig field(s) {bad}")
        return cls(**d)

    def replace(self, **kw) -> "LearnedConfig":
        return dataclasses.replace(self, **kw)


def decimation_factor(model_rate_hz: float, rate_hz: float) -> int:
    """Integer ``rate_hz / model_rate_hz`` (ValueError naming ``rate_hz`` if it is not an integer multiple)."""
    r = _num("detector", "rate_hz", rate_hz)
    k = r / model_rate_hz
    if k < 1 - 1e-9 or abs(k - round(k)) > 1e-6:
        raise ValueError(f"rate_hz ({r} Hz) must be an integer multiple of the model rate {model_rate_hz} Hz")
    return int(round(k))


class FeatureStream:
    """Causal, batched feature extraction (module docstring steps 1-3), chunk by chunk.

    Parameters
    ----------
    config : LearnedConfig; rate_hz : IMU rate [Hz] (integer multiple of ``config.model_rate_hz``).

    ``push(x)`` with a validated chunk ``x`` (B, n, 6) ``[f_b, w_b]`` returns
    ``(feats (B, m, 10) float32, pos (m,) int)``: the features of the m model steps
    that fall in the chunk and their sample positions in it. Model steps are the
    samples whose running index (counted over the whole batch, from the last
    :meth:`reset`) is ``factor - 1`` modulo ``factor``; the chunk boundaries do not
    matter (chunked == one-shot, tested).
    """

    def __init__(self, config: LearnedConfig, rate_hz: float):
        self.config = config
        self.rate_hz = float(rate_hz)
        self.factor = decimation_factor(config.model_rate_hz, rate_hz)
        check_cutoff(config.cutoff_hz, self.rate_hz, "LearnedConfig.cutoff_hz")
        self.alpha = np.array([1.0 - math.exp(-1.0 / (tau * config.model_rate_hz))
                               for tau in (config.ema_tau_s, config.ema_long_tau_s)])
        self._lp = LowPass(config.cutoff_hz, self.rate_hz)
        self.reset()

    def reset(self):
        self._lp.reset()
        self._phase = 0
        self._ema = None        # (2, B, 3) last short and long EMA values
        self._fresh = None      # (B,) rows whose EMA starts at their next model step

    def reset_rows(self, rows):
        self._lp.reset_rows(rows)
        if self._fresh is not None:
            self._fresh[np.asarray(rows, np.intp)] = True

    def push(self, x):
        B, n, _ = x.shape
        if self._ema is None:
            self._ema = np.zeros((2, B, 3))
            self._fresh = np.ones(B, bool)
        y = self._lp(x)
        pos = np.arange((self.factor - 1 - self._phase) % self.factor, n, self.factor)
        self._phase = (self._phase + n) % self.factor
        m = pos.size
        if m == 0:
            return np.zeros((B, 0, N_FEATURES), np.float32), pos
        z = y[:, pos]
        a = z[..., :3]
        if self._fresh.any():
            self._ema[:, self._fresh] = a[self._fresh, 0]
            self._fresh[:] = False
        emas = []
        for i, al in enumerate(self.alpha):
            # EMA e_k = (1 - al) e_{k-1} + al a_k, state carried in e_{k-1} = self._ema[i]
            e, _ = lfilter([al], [1.0, -(1.0 - al)], a, axis=1, zi=((1.0 - al) * self._ema[i])[:, None, :])
            self._ema[i] = e[:, -1]
            emas.append(e)
        c = self.config
        feats = np.empty((B, m, N_FEATURES), np.float32)
        feats[..., 0:3] = (a - emas[0]) / c.accel_scale
        feats[..., 3:6] = (a - emas[1]) / c.accel_scale
        feats[..., 6:9] = z[..., 3:6] / c.gyro_scale
        feats[..., 9] = (np.linalg.norm(emas[0], axis=-1) - c.gravity) / c.accel_scale
        return feats, pos

    def push_compiled(self, f, w):
        """:meth:`push` of the chunk ``[f, w]`` (float64 (B, n >= 1, 3) each, finite, checked by the caller) by
        the compiled kernel (:func:`.learned_rows._feature_rows`, the same bits), or None where the stream's
        state has another batch size (nothing changed then; :meth:`push` raises)."""
        B, n, _ = f.shape
        if self._ema is not None and self._ema.shape[1] != B:
            return None
        lp_state = self._lp.compiled_state(B)
        if lp_state is None:
            return None
        if self._ema is None:
            self._ema = np.zeros((2, B, 3))
            self._fresh = np.ones(B, bool)
        ema = self._ema = np.ascontiguousarray(self._ema)
        pos = np.arange((self.factor - 1 - self._phase) % self.factor, n, self.factor)
        self._phase = (self._phase + n) % self.factor
        c = self.config
        feats = np.empty((B, pos.size, N_FEATURES), np.float32)
        kern, nchunk = row_kernel(_features_serial, _features_parallel, B)
        kern(f, w, pos, *lp_state, ema, self._fresh, self.alpha, c.accel_scale, c.gyro_scale, c.gravity, feats,
             nchunk)
        return feats, pos


# ----------------------------------------------------------------------------------------- networks
def _torch():
    try:
        import torch
    except ImportError as exc:  # pragma: no cover - torch is a project dependency
        raise ImportError("the learned zero-velocity detectors need PyTorch (pip install torch)") from exc
    return torch


def build_model(config: LearnedConfig):
    """The torch module of ``config`` (float32, CPU), returning logits.

    * MLP: ``(K, window, 10) -> flatten -> Linear(hidden) -> ReLU -> Linear(hidden) -> ReLU -> Linear(1)``,
      output (K,) logits;
    * LSTM: ``(B, T, 10) -> Linear(hidden) -> tanh -> LSTM(hidden) -> Linear(1)``, ``forward(x, state)``
      returns ((B, T) logits, state).
    """
    torch = _torch()
    nn = torch.nn
    H = config.hidden

    if config.kind == "mlp":
        class ZuptMLP(nn.Module):
            def __init__(self):
                super().__init__()
                self.net = nn.Sequential(nn.Flatten(), nn.Linear(config.window * N_FEATURES, H), nn.ReLU(),
                                         nn.Linear(H, H), nn.ReLU(), nn.Linear(H, 1))

            def forward(self, x):
                return self.net(x)[:, 0]

        return ZuptMLP()

    class ZuptLSTM(nn.Module):
        def __init__(self):
            super().__init__()
            self.inp = nn.Linear(N_FEATURES, H)
            self.lstm = nn.LSTM(H, H, batch_first=True)
            self.out = nn.Linear(H, 1)

        def forward(self, x, state=None):
            y, state = self.lstm(torch.tanh(self.inp(x)), state)
            return self.out(y)[..., 0], state

    return ZuptLSTM()


class LearnedDetector(ZuptDetector):
    """Streaming learned detector (module docstring): features, network at the model rate, held output.

    Parameters
    ----------
    config : LearnedConfig
    model : the torch module from :func:`build_model` (trained), or None for untrained weights.
    rate_hz : IMU rate [Hz], an integer multiple of ``config.model_rate_hz``.
    """

    score_kind = "probability"
    compiled = True
    """Form the features in :meth:`process` by the compiled kernel (:mod:`.learned_rows`, the same bits) where
    the inputs allow; False: always the numpy specification (``FeatureStream.push``)."""

    def __init__(self, config: LearnedConfig, model, rate_hz: float):
        if not isinstance(config, LearnedConfig):
            raise ValueError(f"config must be a LearnedConfig, got {type(config).__name__}")
        self.config = config
        self.name = config.kind
        self.threshold = config.threshold
        self.model = build_model(config) if model is None else model
        self.model.eval()
        self.features = FeatureStream(config, rate_hz)
        self.rate_hz = self.features.rate_hz
        self.reset()

    def reset(self):
        self.features.reset()
        self._state = None      # LSTM (h, c), each (1, B, H)
        self._tail = None       # MLP (B, window - 1, N_FEATURES)
        self._count = None      # MLP (B,) model steps seen (capped)
        self._last = None       # (B,) last probability (held between model steps)

    def reset_rows(self, rows):
        rows = np.asarray(rows, np.intp)
        self.features.reset_rows(rows)
        if self._last is not None:
            self._last[rows] = 0.0
        if self._count is not None:
            self._count[rows] = 0
        if self._state is not None:
            for s in self._state:
                s[:, rows] = 0.0

    # ------------------------------------------------------------------ network on features
    def predict_windows(self, windows) -> np.ndarray:
        """MLP stationary probabilities for feature windows (K, window, 10) -> (K,) (ValueError on bad shape/NaN)."""
        if self.config.kind != "mlp":
            raise ValueError("predict_windows is for the 'mlp' detector; use predict_sequence for 'lstm'")
        w = np.asarray(windows, np.float32)
        want = (self.config.window, N_FEATURES)
        if w.ndim != 3 or w.shape[1:] != want:
            raise ValueError(f"windows must have shape (K, {want[0]}, {want[1]}), got {w.shape}")
        if not np.isfinite(w).all():
            raise ValueError("windows contain NaN or inf")
        torch = _torch()
        with torch.no_grad():
            out = []
            for s in range(0, w.shape[0], 65536):
                out.append(torch.sigmoid(self.model(torch.from_numpy(w[s:s + 65536]))).numpy())
        return np.concatenate(out).astype(np.float64) if out else np.zeros(0)

    def predict_sequence(self, feats, state=None):
        """LSTM probabilities over feature sequences (B, T, 10) -> ((B, T), new state) (ValueError on bad shape/NaN)."""
        if self.config.kind != "lstm":
            raise ValueError("predict_sequence is for the 'lstm' detector; use predict_windows for 'mlp'")
        x = np.asarray(feats, np.float32)
        if x.ndim != 3 or x.shape[2] != N_FEATURES:
            raise ValueError(f"feats must have shape (B, T, {N_FEATURES}), got {x.shape}")
        if not np.isfinite(x).all():
            raise ValueError("feats contain NaN or inf")
        torch = _torch()
        with torch.no_grad():
            logit, state = self.model(torch.from_numpy(x), state)
        return torch.sigmoid(logit).numpy().astype(np.float64), state

    # ------------------------------------------------------------------ streaming
    def process(self, f_b, w_b) -> DetectorOutput:
        """:meth:`ZuptDetector.process` with the features formed by the compiled kernel
        (:meth:`FeatureStream.push_compiled`) for float64 arrays of the same (B, n >= 1, 3) shape with finite
        samples and a batch size matching the detector's state; the numpy specification otherwise (it raises the
        error naming the bad input)."""
        f, w = f_b, w_b
        if (self.compiled and compiled_input(f, w)
                and (self._last is None or self._last.shape[0] == f.shape[0])):
            B, n, _ = f.shape
            got = self.features.push_compiled(f, w)
            if got is not None:
                if self._last is None:
                    self._last = np.zeros(B)
                score = self._score_features(B, n, *got)
                return DetectorOutput(score=score, stationary=self.decide(score))
        return super().process(f_b, w_b)

    def _score(self, x):
        """Scores of one validated chunk by the numpy specification (features, network, hold)."""
        B, n, _ = x.shape
        if self._last is None:
            self._last = np.zeros(B)
        elif self._last.shape[0] != B:
            raise ValueError(f"the detector runs B={self._last.shape[0]} streams, got a chunk with B={B} "
                             "(call reset() first)")
        return self._score_features(B, n, *self.features.push(x))

    def _score_features(self, B, n, feats, pos):
        """Scores (B, n) of a chunk of n samples from the features (B, m, 10) of its model steps at ``pos``: the
        network's probabilities, each held until the next model step."""
        m = pos.size
        out = np.empty((B, n))
        if m == 0:
            out[:] = self._last[:, None]
            return out
        if self.config.kind == "lstm":
            p, self._state = self.predict_sequence(feats, self._state)
        else:
            W = self.config.window
            if self._tail is None:
                self._tail = np.zeros((B, W - 1, N_FEATURES), np.float32)
                self._count = np.zeros(B, np.int64)
            buf = np.concatenate([self._tail, feats], axis=1)
            p = np.empty((B, m))
            step = max(1, 16384 // B)                                       # bounded window batches
            for a in range(0, m, step):
                k = min(step, m - a)
                idx = a + np.arange(k)[:, None] + np.arange(W)[None, :]    # (k, W) windows ending at steps a..
                p[:, a:a + k] = self.predict_windows(buf[:, idx].reshape(B * k, W, N_FEATURES)).reshape(B, k)
            seen = self._count[:, None] + np.arange(1, m + 1)[None, :]
            p[seen < W] = 0.0
            self._tail = buf[:, buf.shape[1] - (W - 1):]
            self._count = np.minimum(self._count + m, W)
        # hold: sample i takes the probability of the last model step at or before it
        j = np.searchsorted(pos, np.arange(n), side="right") - 1          # -1: before the first step in this chunk
        out[:, j >= 0] = p[:, j[j >= 0]]
        out[:, j < 0] = self._last[:, None]
        self._last = p[:, -1].copy()
        return out


# ----------------------------------------------------------------------------------------- weights
def save_weights(path, config: LearnedConfig, model, extra: dict | None = None) -> Path:
    """Write ``{"format", "config", "state_dict", "extra"}`` to ``path`` (torch.save); returns the path."""
    torch = _torch()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}
    torch.save({"format": WEIGHTS_FORMAT, "config": config.to_dict(), "state_dict": state,
                "extra": dict(extra or {})}, path)
    return path


def load_detector(path, rate_hz: float, threshold: float | None = None) -> LearnedDetector:
    """A :class:`LearnedDetector` at ``rate_hz`` from a weights file written by :func:`save_weights`.

    Raises
    ------
    FileNotFoundError
        the file does not exist (the message says how to train one).
    ValueError
        the file is not a navgym detector weights file, or its config / tensors do not fit.
    """
    torch = _torch()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"zero-velocity detector weights file not found: {str(path)!r} "
                                "(train one with `python train.py zupt --model lstm --seed 0 --out runs/DIR`)")
    try:
        blob = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling error means "not a weights file"
        raise ValueError(f"{str(path)!r} is not a readable detector weights file: {exc}") from None
    if not isinstance(blob, dict) or blob.get("format") != WEIGHTS_FORMAT:
        raise ValueError(f"{str(path)!r} is not a navgym zero-velocity detector weights file "
                         f"(format {WEIGHTS_FORMAT!r} expected)")
    config = LearnedConfig.from_dict(dict(blob["config"]))
    if threshold is not None:
        config = config.replace(threshold=threshold)
    model = build_model(config)
    try:
        model.load_state_dict(blob["state_dict"])
    except (RuntimeError, KeyError) as exc:
        raise ValueError(f"weights in {str(path)!r} do not fit the {config.kind} architecture: {exc}") from None
    return LearnedDetector(config, model, rate_hz)
