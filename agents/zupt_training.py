"""Training and evaluation of the zero-velocity detectors (``python train.py zupt``).

Data (all simulated by :mod:`envs.sim`, nothing recorded):

* :func:`stop_heavy_drive` -- long drives with many stops: traffic lights
  (engine idling), stop-and-go, creeping below 0.3 m/s, parking with the engine
  off, slow turns at walking pace, intersection turns, cruising; half of the
  drives start parked with the engine off;
* several IMU grades (``consumer``, ``industrial``, ``tactical`` for training;
  ``seed000`` and ``seed003`` held out) and rates (50, 100, 200 Hz), with the
  vehicle vibration model of :class:`envs.sim.imu.Vibration`;
* label: stationary = true speed below :data:`LABEL_SPEED_MPS` (0.05 m/s, the
  speed below which the simulator's vehicle idles and the environments'
  ``zupt='truth'`` option fires);
* splits by seed: training drives are drawn fresh every epoch from seeds of the
  run seed ``S`` (``S * 10**7 + epoch * 10**4 + i``), validation from
  ``8 * 10**8 + S * 10**3 + i``, the test set from fixed seeds ``9 * 10**8 + i``
  (the same for every ``S``), on the training grades (held-out seeds) and on the
  held-out grades.

Training: the LSTM by truncated back-propagation through time over whole drives
(state carried across chunks), the MLP on random windows; Adam; early stopping
on the validation loss (best weights kept); the probability threshold is then
tuned on the validation drives (max F1 with the false-ZUPT rate capped at
0.1 %). The four classical detectors are tuned on training drives (window and
pre-filter cutoff by grid, threshold by max F1, :func:`tune_threshold`) and all
detectors are scored on the same held-out test drives at their native rates.

Metrics (stationary = positive class), :func:`classification_metrics`:
precision, recall, F1, accuracy, false-ZUPT rate (moving samples declared
stationary / moving samples) and the detection rate. Seed paper 000 (sec 5.3)
reports a "detection rate" (94.73 %) without a formula; it motivates the
pre-filter with stationary samples lost to vibration, i.e. the probability of
detecting a truly stationary sample, so ``detection_rate`` here is the
sample-level recall of the stationary class (P_D); ``accuracy`` is the other
possible reading and is reported beside it.
"""
from __future__ import annotations

import dataclasses
import json
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from earth.rotations import dcm_from_euler
from envs.json_io import jsonable
from envs.outputs import atomic_path, write_atomic
from envs.sim.imu import IMU_GRADES, Vibration, simulate_imu
from envs.sim.rng import row_generators
from envs.sim.trajectory import Cruise, Motion, SegmentPlan, Static, Turn, generate_truth
from nav_filters.zupt.classical import CLASSICAL_KINDS, ClassicalConfig, ClassicalDetector, tune_threshold
from nav_filters.zupt.learned import (LearnedConfig, LearnedDetector, build_model, decimation_factor,
                                      FeatureStream, save_weights)

__all__ = [
    "LABEL_SPEED_MPS", "stop_heavy_drive", "DriveSet", "simulate_drives", "ZuptTrainConfig",
    "classification_metrics", "tune_classical", "train_learned", "evaluate_detector", "train_zupt_detector",
    "training_drives", "validation_drives", "heldout_drives", "format_table", "read_vn310_imu",
    "vn310_stationary_fraction", "in_loop_rmse",
    "QUICK",
]

LABEL_SPEED_MPS = 0.05
"""True speed [m/s] below which a sample is labelled stationary."""

TRAIN_SEED_STRIDE = 10 ** 7
VAL_SEED_BASE = 8 * 10 ** 8
TEST_SEED_BASE = 9 * 10 ** 8


# --------------------------------------------------------------------------------------------- drives
def stop_heavy_drive(rng: np.random.Generator, duration_s: float) -> Motion:
    """A random drive of at least ``duration_s`` seconds dominated by stops and slow motion.

    Events, drawn independently until the duration is covered (probabilities in brackets):

    * traffic light (0.25): 6-16 m/s for 3-25 s, brake at 0.8-3 m/s^2, idle 2-45 s;
    * stop-and-go (0.15): 2-5 cycles of 0.5-4 m/s (0.3-1.5 m/s^2), 0-3 s, stop, idle 0.5-5 s;
    * creep (0.12): to 0.06-0.3 m/s at 0.05-0.3 m/s^2, 0.5-6 s, stop at 0.05-0.5 m/s^2, idle 1-8 s;
    * park (0.08): stop, engine off 5-60 s, engine on 1-8 s;
    * slow turn (0.15): 1-6 m/s, 20-180 deg at 2-12 deg/s;
    * intersection turn (0.10): 4-7 m/s, 90 deg at 10-20 deg/s;
    * cruise (0.15): 8-20 m/s for 5-30 s and a gentle curve (3-30 deg at 0.5-3 deg/s).

    The drive starts at rest: half of the time parked with the engine off (3-30 s) before the engine
    starts, otherwise idling (3-10 s). Start point uniform in latitude [-60, 60] deg, any longitude,
    height 0-2000 m (gravity 9.77-9.83 m/s^2), heading uniform.

    Parameters
    ----------
    rng : the row's generator; duration_s : minimum duration [s], > 0.
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy Generator, got {type(rng).__name__}")
    if not (isinstance(duration_s, (int, float)) and math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s must be a positive finite number, got {duration_s!r}")
    U = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    sign = lambda: 1.0 if rng.random() < 0.5 else -1.0  # noqa: E731
    plan = SegmentPlan()
    add, speed = plan.add, plan.change_speed

    if rng.random() < 0.5:
        add(Static(U(3.0, 30.0), False))
    add(Static(U(3.0, 10.0), True))
    while plan.total < duration_s:
        r = rng.random()
        if r < 0.25:
            speed(U(6.0, 16.0), U(0.8, 2.5))
            add(Cruise(U(3.0, 25.0)))
            speed(0.0, U(0.8, 3.0))
            add(Static(U(2.0, 45.0), True))
        elif r < 0.40:
            for _ in range(int(rng.integers(2, 6))):
                speed(U(0.5, 4.0), U(0.3, 1.5))
                add(Cruise(U(0.0, 3.0)))
                speed(0.0, U(0.3, 1.5))
                add(Static(U(0.5, 5.0), True))
        elif r < 0.52:
            if plan.speed > 0.0:
                speed(0.0, U(0.8, 2.5))
                add(Static(U(1.0, 5.0), True))
            speed(U(0.06, 0.3), U(0.05, 0.3))
            add(Cruise(U(0.5, 6.0)))
            speed(0.0, U(0.05, 0.5))
            add(Static(U(1.0, 8.0), True))
        elif r < 0.60:
            speed(0.0, U(0.8, 2.5))
            add(Static(U(5.0, 60.0), False), Static(U(1.0, 8.0), True))
        elif r < 0.75:
            speed(U(1.0, 6.0), U(0.5, 2.0))
            add(Turn(sign() * U(20.0, 180.0), U(2.0, 12.0)))
        elif r < 0.85:
            speed(U(4.0, 7.0), U(1.0, 2.5))
            add(Turn(sign() * 90.0, U(10.0, 20.0)))
        else:
            speed(U(8.0, 20.0), U(0.5, 2.5))
            add(Cruise(U(5.0, 30.0)), Turn(sign() * U(3.0, 30.0), U(0.5, 3.0)))
    return Motion(U(-60.0, 60.0), U(-180.0, 180.0), U(0.0, 2000.0), U(0.0, 360.0), 0.0, tuple(plan.segments))


@dataclass(frozen=True, eq=False)
class DriveSet:
    """D simulated drives of one IMU grade at one rate.

    Attributes
    ----------
    f_b, w_b : (D, N, 3) measured specific force [m/s^2] and angular rate [rad/s].
    stationary : (D, N) bool label; speed : (D, N) true speed [m/s]; engine_on : (D, N) bool.
    rate_hz : IMU rate [Hz]; grade : IMU grade name; seeds : the D seeds.
    """

    f_b: np.ndarray
    w_b: np.ndarray
    stationary: np.ndarray
    speed: np.ndarray
    engine_on: np.ndarray
    rate_hz: float
    grade: str
    seeds: tuple


def simulate_drives(seeds, grade: str, rate_hz: float, duration_s: float,
                    label_speed_mps: float = LABEL_SPEED_MPS, mount_deg: float = 5.0) -> DriveSet:
    """Simulate :func:`stop_heavy_drive` drives (truth, IMU with vibration) for ``seeds``.

    The IMU of each drive is mounted with a random small rotation (roll and pitch uniform in
    ``+-mount_deg``, yaw in ``+-mount_deg / 2``; drawn from the seed): the simulated vehicle never rolls,
    a real installation is never perfectly level, and a detector must not learn the simulator's axes.
    """
    if grade not in IMU_GRADES:
        raise ValueError(f"unknown IMU grade {grade!r}; known: {sorted(IMU_GRADES)}")
    seeds = [int(s) for s in seeds]
    motions = [stop_heavy_drive(g, duration_s) for g in row_generators(seeds, "trajectory")]
    tr = generate_truth(motions, duration_s, rate_hz)
    imu = simulate_imu(tr.f_b, tr.w_b, rate_hz, IMU_GRADES[grade], row_generators(seeds, "imu"),
                       engine_on=tr.engine_on, speed=tr.speed, vibration=Vibration(),
                       vibration_rngs=row_generators(seeds, "vibration"))
    R = np.stack([dcm_from_euler(*(np.radians(mount_deg) * np.random.default_rng([s, 7919]).uniform(-1, 1, 3)
                                   * [1.0, 1.0, 0.5])) for s in seeds])          # (D, 3, 3) sensor <- body
    f = np.einsum("dij,dnj->dni", R, imu.f_b)
    w = np.einsum("dij,dnj->dni", R, imu.w_b)
    return DriveSet(f, w, tr.stationary(label_speed_mps), tr.speed, tr.engine_on, float(rate_hz), grade,
                    tuple(seeds))


# --------------------------------------------------------------------------------------------- config
@dataclass(frozen=True)
class ZuptTrainConfig:
    """Data, training and evaluation settings (validated; errors name the field).

    Attributes
    ----------
    duration_s : length of every simulated drive [s].
    train_grades, heldout_grades : IMU grades for training / only for testing.
    rates_hz : IMU rates of every split [Hz] (integer multiples of the model rate).
    drives_per_epoch : fresh training drives per (grade, rate) and epoch.
    val_drives, test_drives : drives per (grade, rate) in the validation and test sets.
    tune_drives : training drives per (grade, rate) for the classical threshold tuning.
    max_epochs, patience : early stopping on the validation loss.
    lr : Adam learning rate; tbptt_steps : LSTM truncation length [model steps];
    mlp_batches, mlp_batch_size : MLP minibatches per epoch and their size.
    moving_weight : loss weight of the moving samples (> 1: a false ZUPT costs more than a missed one).
    max_false_rate : cap on the validation false-ZUPT rate when tuning the learned threshold.
    threads : torch CPU threads (1 is the fastest on a shared 2-core machine).
    classical_windows_s, classical_cutoffs_hz : grid of the classical tuning (None = no pre-filter).
    """

    duration_s: float = 600.0
    train_grades: tuple = ("consumer", "industrial", "tactical")
    heldout_grades: tuple = ("seed000", "seed003")
    rates_hz: tuple = (50.0, 100.0, 200.0)
    drives_per_epoch: int = 4
    val_drives: int = 2
    test_drives: int = 2
    tune_drives: int = 2
    max_epochs: int = 40
    patience: int = 12
    lr: float = 3e-3
    tbptt_steps: int = 500
    mlp_batches: int = 300
    mlp_batch_size: int = 512
    moving_weight: float = 2.0
    max_false_rate: float = 1e-3
    threads: int = 1
    classical_windows_s: tuple = (0.1, 0.25, 0.5, 1.0)
    classical_cutoffs_hz: tuple = (None, 2.0, 5.0, 10.0, 20.0)

    def __post_init__(self):
        o = "ZuptTrainConfig"
        for f in ("duration_s", "lr", "moving_weight"):
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise ValueError(f"{o}.{f} must be a positive finite number, got {v!r}")
        for f in ("drives_per_epoch", "val_drives", "test_drives", "tune_drives", "max_epochs", "patience",
                  "tbptt_steps", "mlp_batches", "mlp_batch_size", "threads"):
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{o}.{f} must be a positive int, got {v!r}")
        for f in ("train_grades", "heldout_grades"):
            g = getattr(self, f)
            if not isinstance(g, tuple) or (f == "train_grades" and not g) or any(x not in IMU_GRADES for x in g):
                raise ValueError(f"{o}.{f} must be a tuple of IMU grades {sorted(IMU_GRADES)}, got {g!r}")
        if not isinstance(self.rates_hz, tuple) or not self.rates_hz or \
                any(not (isinstance(r, (int, float)) and r > 0) for r in self.rates_hz):
            raise ValueError(f"{o}.rates_hz must be a non-empty tuple of positive rates, got {self.rates_hz!r}")
        if not 0.0 <= self.max_false_rate <= 1.0:
            raise ValueError(f"{o}.max_false_rate must be in [0, 1], got {self.max_false_rate!r}")
        if not self.classical_windows_s or any(not (isinstance(w, (int, float)) and w > 0)
                                               for w in self.classical_windows_s):
            raise ValueError(f"{o}.classical_windows_s must be positive window lengths, got {self.classical_windows_s!r}")
        if not self.classical_cutoffs_hz:
            raise ValueError(f"{o}.classical_cutoffs_hz must not be empty")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


QUICK = ZuptTrainConfig(duration_s=120.0, train_grades=("industrial",), heldout_grades=("seed003",),
                        rates_hz=(100.0,), drives_per_epoch=2, val_drives=1, test_drives=1, tune_drives=1,
                        max_epochs=2, patience=2, tbptt_steps=200, mlp_batches=30, mlp_batch_size=256,
                        classical_windows_s=(0.25, 0.5), classical_cutoffs_hz=(5.0,))
"""A config that trains and evaluates in seconds (tests, smoke runs); its metrics mean nothing."""


# --------------------------------------------------------------------------------------------- metrics
def classification_metrics(decision, label) -> dict:
    """Sample-level metrics of stationary decisions against labels (stationary = positive).

    Returns
    -------
    dict with ``precision``, ``recall``, ``f1``, ``accuracy``, ``false_zupt_rate`` (moving samples
    declared stationary / moving samples), ``detection_rate`` (= recall, see the module docstring),
    and the counts ``tp``, ``fp``, ``fn``, ``tn``, ``n``. A ratio with an empty denominator is NaN
    (written as null in JSON).
    """
    d = np.asarray(decision, bool).ravel()
    y = np.asarray(label, bool).ravel()
    if d.shape != y.shape:
        raise ValueError(f"decision and label must have the same size, got {d.size} and {y.size}")
    tp = int(np.sum(d & y))
    fp = int(np.sum(d & ~y))
    fn = int(np.sum(~d & y))
    tn = int(np.sum(~d & ~y))
    div = lambda a, b: float(a / b) if b else float("nan")  # noqa: E731
    return {"precision": div(tp, tp + fp), "recall": div(tp, tp + fn), "f1": div(2 * tp, 2 * tp + fp + fn),
            "accuracy": div(tp + tn, tp + tn + fp + fn), "false_zupt_rate": div(fp, fp + tn),
            "detection_rate": div(tp, tp + fn), "tp": tp, "fp": fp, "fn": fn, "tn": tn, "n": tp + fp + fn + tn}


# --------------------------------------------------------------------------------------------- splits
def _combos(grades, rates):
    return [(g, float(r)) for g in grades for r in rates]


def _split(cfg: ZuptTrainConfig, base: int, per_combo: int, grades) -> list[DriveSet]:
    sets = []
    for c, (g, r) in enumerate(_combos(grades, cfg.rates_hz)):
        seeds = [base + c * per_combo + i for i in range(per_combo)]
        sets.append(simulate_drives(seeds, g, r, cfg.duration_s))
    return sets


def training_drives(cfg: ZuptTrainConfig, seed: int, epoch: int, per_combo: int | None = None) -> list[DriveSet]:
    """Fresh training drives of epoch ``epoch`` of run ``seed`` (one DriveSet per (grade, rate))."""
    n = cfg.drives_per_epoch if per_combo is None else per_combo
    return _split(cfg, seed * TRAIN_SEED_STRIDE + epoch * 10 ** 4, n, cfg.train_grades)


def validation_drives(cfg: ZuptTrainConfig, seed: int) -> list[DriveSet]:
    return _split(cfg, VAL_SEED_BASE + seed * 10 ** 3, cfg.val_drives, cfg.train_grades)


def heldout_drives(cfg: ZuptTrainConfig) -> dict[str, list[DriveSet]]:
    """The held-out test sets: ``'heldout_seeds'`` (training grades) and ``'heldout_grades'``."""
    out = {"heldout_seeds": _split(cfg, TEST_SEED_BASE, cfg.test_drives, cfg.train_grades)}
    if cfg.heldout_grades:
        out["heldout_grades"] = _split(cfg, TEST_SEED_BASE + 10 ** 6, cfg.test_drives, cfg.heldout_grades)
    return out


# --------------------------------------------------------------------------------------------- classical
def tune_classical(sets: list[DriveSet], cfg: ZuptTrainConfig, kinds=CLASSICAL_KINDS) -> dict:
    """Tune each classical detector on labelled drives: grid over window and cutoff, max-F1 threshold.

    Returns ``{kind: {"config": ClassicalConfig, "train_f1": float}}``; the grid is
    ``cfg.classical_windows_s x cfg.classical_cutoffs_hz`` (cutoffs at or above a set's Nyquist skipped).
    """
    from nav_filters.zupt.base import check_imu
    from nav_filters.zupt.classical import classical_statistic
    from nav_filters.zupt.prefilter import lowpass
    labels = np.concatenate([s.stationary.ravel() for s in sets])
    best = {k: None for k in kinds}
    for cut in cfg.classical_cutoffs_hz:
        if cut is not None and any(cut >= 0.5 * s.rate_hz for s in sets):
            continue
        # the pre-filtered drives, once per cutoff (the detector's one-shot path: filter, then statistic)
        xs = [check_imu(s.f_b, s.w_b) if cut is None else lowpass(check_imu(s.f_b, s.w_b), s.rate_hz, cut)
              for s in sets]
        for kind in kinds:
            for win in cfg.classical_windows_s:
                c0 = ClassicalConfig(kind=kind, window_s=win, cutoff_hz=cut)
                scores = []
                for s, x in zip(sets, xs):
                    W = c0.window_samples(s.rate_hz)
                    T = np.full(x.shape[:2], np.inf)       # first W - 1 samples: window not full (moving)
                    T[:, W - 1:] = classical_statistic(kind, x, W, c0.sigma_a, c0.sigma_w, c0.gravity)
                    scores.append(T.ravel())
                thr, f1 = tune_threshold(np.concatenate(scores), labels)
                if best[kind] is None or f1 > best[kind][1]:
                    best[kind] = (dataclasses.replace(c0, threshold=max(thr, 1e-12)), f1)
    return {k: {"config": b[0], "train_f1": b[1]} for k, b in best.items()}


# --------------------------------------------------------------------------------------------- learned
def _features(sets: list[DriveSet], lc: LearnedConfig):
    """Model-rate features (D, M, 7) and labels (D, M) of drive sets (trimmed to a common M)."""
    F, Y = [], []
    for s in sets:
        fs = FeatureStream(lc, s.rate_hz)
        from nav_filters.zupt.base import check_imu
        feats, pos = fs.push(check_imu(s.f_b, s.w_b))
        F.append(feats)
        Y.append(s.stationary[:, pos])
    M = min(f.shape[1] for f in F)
    return np.concatenate([f[:, :M] for f in F]), np.concatenate([y[:, :M] for y in Y])


def _mlp_windows(feats, W, b, k):
    idx = k[:, None] - np.arange(W)[None, ::-1]
    return feats[b[:, None], idx]


def _val_probs(model, lc, vf, torch):
    """Validation probabilities at the model steps (D, M) (MLP: NaN where not evaluated)."""
    with torch.no_grad():
        if lc.kind == "lstm":
            logit, _ = model(torch.from_numpy(vf))
            return torch.sigmoid(logit).numpy()
        D, M, _ = vf.shape
        W = lc.window
        P = np.full((D, M), np.nan, np.float32)   # every 4th full window (validation cost)
        for d in range(D):
            k = np.arange(W - 1, M, 4)
            for s in range(0, k.size, 32768):
                kk = k[s:s + 32768]
                P[d, kk] = torch.sigmoid(model(torch.from_numpy(_mlp_windows(vf, W, np.full(kk.size, d), kk)))).numpy()
        return P


def train_learned(lc: LearnedConfig, cfg: ZuptTrainConfig, seed: int, progress: bool = True, log=None,
                  train_sets=None, val_sets=None):
    """Train an MLP or LSTM detector on fresh simulated drives with early stopping.

    Parameters
    ----------
    lc : architecture; cfg : training settings; seed : run seed.
    progress : progress bar; log : optional callable receiving each epoch's record.
    train_sets : optional callable ``epoch -> list[DriveSet]`` replacing :func:`training_drives`.
    val_sets : optional list of DriveSet replacing :func:`validation_drives`.

    Returns
    -------
    model : the trained torch module (best validation loss), config with the tuned threshold,
    history : list of per-epoch dicts (train_loss, val_loss, val_f1, seconds).
    """
    import torch
    torch.set_num_threads(cfg.threads)
    torch.manual_seed(seed)
    rng = np.random.default_rng([seed, 17])
    model = build_model(lc)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.max_epochs, eta_min=cfg.lr * 0.05)
    bce = torch.nn.functional.binary_cross_entropy_with_logits
    vf, vy = _features(validation_drives(cfg, seed) if val_sets is None else val_sets, lc)
    vy_t = torch.from_numpy(vy.astype(np.float32))
    best, best_loss, bad = None, math.inf, 0
    history = []
    bar = _bar(cfg.max_epochs, f"zupt {lc.kind}", progress)
    t_start = time.perf_counter()

    def epoch_data(e):
        return _features(training_drives(cfg, seed, e) if train_sets is None else train_sets(e), lc)

    # the next epoch's drives are simulated in a thread while this epoch trains (numpy/scipy release the GIL)
    pool = ThreadPoolExecutor(max_workers=1)
    nxt = pool.submit(epoch_data, 0)
    for epoch in range(cfg.max_epochs):
        t0 = time.perf_counter()
        tf, ty = nxt.result()
        nxt = pool.submit(epoch_data, epoch + 1) if epoch + 1 < cfg.max_epochs else None
        model.train()
        losses = []
        if lc.kind == "lstm":
            perm = rng.permutation(tf.shape[0])
            x = torch.from_numpy(tf[perm])
            y = torch.from_numpy(ty[perm].astype(np.float32))
            state = None
            for s in range(0, x.shape[1], cfg.tbptt_steps):
                logit, state = model(x[:, s:s + cfg.tbptt_steps], state)
                state = tuple(h.detach() for h in state)
                yy = y[:, s:s + cfg.tbptt_steps]
                loss = bce(logit, yy, weight=1.0 + (cfg.moving_weight - 1.0) * (1.0 - yy))
                opt.zero_grad()
                loss.backward()
                torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
                opt.step()
                losses.append(loss.item())
        else:
            D, M, _ = tf.shape
            W = lc.window
            for _ in range(cfg.mlp_batches):
                b = rng.integers(0, D, cfg.mlp_batch_size)
                k = rng.integers(W - 1, M, cfg.mlp_batch_size)
                logit = model(torch.from_numpy(_mlp_windows(tf, W, b, k)))
                yy = torch.from_numpy(ty[b, k].astype(np.float32))
                loss = bce(logit, yy, weight=1.0 + (cfg.moving_weight - 1.0) * (1.0 - yy))
                opt.zero_grad()
                loss.backward()
                opt.step()
                losses.append(loss.item())
        sched.step()
        model.eval()
        vp = _val_probs(model, lc, vf, torch)
        valid = np.isfinite(vp)
        vp_t = torch.from_numpy(np.clip(vp[valid], 1e-7, 1 - 1e-7))
        val_loss = float(torch.nn.functional.binary_cross_entropy(vp_t, vy_t[torch.from_numpy(valid)]))
        val_f1 = classification_metrics(vp[valid] >= 0.5, vy[valid])["f1"]
        rec = {"epoch": epoch, "train_loss": float(np.mean(losses)), "val_loss": val_loss, "val_f1": val_f1,
               "seconds": time.perf_counter() - t0}
        history.append(rec)
        if log is not None:
            log(rec)
        bar.update(1)
        bar.set_postfix(loss=f"{rec['train_loss']:.4f}", val=f"{val_loss:.4f}", f1=f"{val_f1:.4f}")
        if val_loss < best_loss - 1e-6:
            best_loss, bad = val_loss, 0
            best = {k: v.detach().clone() for k, v in model.state_dict().items()}
        else:
            bad += 1
            if bad >= cfg.patience:
                break
    if nxt is not None:
        nxt.cancel()
    pool.shutdown(wait=True)
    bar.close()
    model.load_state_dict(best)
    model.eval()
    vp = _val_probs(model, lc, vf, torch)
    valid = np.isfinite(vp)
    thr, _ = tune_threshold(vp[valid], vy[valid], stationary_below=False, max_false_rate=cfg.max_false_rate)
    thr = float(min(max(thr, 1e-3), 0.999))
    thr_f1, _ = tune_threshold(vp[valid], vy[valid], stationary_below=False)          # unconstrained max F1
    return model, lc.replace(threshold=thr), {"epochs": history, "train_seconds": time.perf_counter() - t_start,
                                              "best_val_loss": best_loss,
                                              "threshold_max_f1": float(min(max(thr_f1, 1e-3), 0.999))}


def _bar(total, desc, enabled):
    if enabled:
        try:
            from tqdm import tqdm
            return tqdm(total=total, desc=desc, leave=True)
        except ImportError:  # pragma: no cover
            pass

    class _Null:
        def update(self, n=1):
            pass

        def set_postfix(self, **kw):
            pass

        def close(self):
            pass

    return _Null()


# --------------------------------------------------------------------------------------------- evaluation
def evaluate_detector(make, sets: list[DriveSet]) -> dict:
    """Metrics of a detector over drive sets at their native rates.

    ``make(rate_hz)`` returns a fresh detector for that rate. Returns ``{"all": metrics, "by_grade": {...},
    "by_rate": {...}, "samples_per_s": float}`` (throughput of the one-shot run, all rows at once).
    """
    dec, lab, grade, rate = [], [], [], []
    t, n = 0.0, 0
    for s in sets:
        det = make(s.rate_hz)
        t0 = time.perf_counter()
        d = det.detect(s.f_b, s.w_b).stationary
        t += time.perf_counter() - t0
        n += d.size
        dec.append(d.ravel())
        lab.append(s.stationary.ravel())
        grade.append(np.full(d.size, s.grade, object))
        rate.append(np.full(d.size, s.rate_hz))
    dec, lab, grade, rate = (np.concatenate(a) for a in (dec, lab, grade, rate))
    out = {"all": classification_metrics(dec, lab), "by_grade": {}, "by_rate": {}, "samples_per_s": n / max(t, 1e-9)}
    for g in dict.fromkeys(grade):
        m = grade == g
        out["by_grade"][str(g)] = classification_metrics(dec[m], lab[m])
    for r in dict.fromkeys(rate):
        m = rate == r
        out["by_rate"][f"{r:g}"] = classification_metrics(dec[m], lab[m])
    return out


def _short(m):
    keys = ("precision", "recall", "f1", "accuracy", "false_zupt_rate", "detection_rate")
    return {k: m[k] for k in keys}


# --------------------------------------------------------------------------------------------- in the loop
_METHOD_PARAMS = {"sage-husa": "SAGE_HUSA_PARAMS", "stkf": "STKF_PARAMS", "ma-stkf": "MASTKF_PARAMS"}


def in_loop_rmse(scenario: str, zupts, seeds, method: str = "sage-husa", episode_length_s: float | None = None,
                 weights: dict | None = None) -> dict:
    """Position error of the navigator with each zero-velocity choice, through the environments' core.

    Every choice runs the same episodes (``seeds``; paired) in :class:`envs.core.TuningCore` with the
    filter's default parameters (the action that maps to them), so the only difference is the ZUPT /
    zero-heading-rate aiding driven by ``EnvConfig.zupt``.

    Parameters
    ----------
    scenario : scenario name; zupts : iterable of ``EnvConfig.zupt`` choices; seeds : episode seeds (B rows).
    method : an adaptive method of the environments (``'sage-husa'``, ``'stkf'``, ``'ma-stkf'``).
    episode_length_s : episode length [s] (default: the scenario's duration).
    weights : optional ``{choice: weights path}`` for ``'mlp'`` / ``'lstm'``.

    Returns
    -------
    ``{choice: {"rmse_h_m", "rmse_3d_m", "max_h_m", "zupt_epochs_frac", "false_zupt_epochs",
    "stationary_epochs", "epochs_run", "diverged_episodes", "seconds"}}``: RMSE over all epochs of all
    episodes; the epoch fraction with a ZUPT; ZUPT epochs at which the truth moved (speed >= 0.05 m/s);
    epochs at which the truth was stationary; epochs run (the loop stops at the first diverged episode,
    a horizontal error beyond ``EnvConfig.divergence_bound_m``, so ``epochs_run`` below the episode
    length means a divergence); episodes terminated as diverged.
    """
    import envs.gnss_ins_env as gie
    from envs.config import EnvConfig
    from envs.core import STILL_SPEED_MPS, TuningCore
    from envs.sim.scenarios import get_scenario
    if method not in _METHOD_PARAMS:
        raise ValueError(f"method must be one of {sorted(_METHOD_PARAMS)}, got {method!r}")
    specs = getattr(gie, _METHOD_PARAMS[method])
    seeds = [int(s) for s in seeds]
    L = float(episode_length_s if episode_length_s is not None else get_scenario(scenario).duration_s)
    out = {}
    for z in zupts:
        cfg = EnvConfig(scenario=scenario, method=method, episode_length_s=L, zupt=z,
                        zupt_weights=(weights or {}).get(z))
        core = TuningCore(cfg, specs, len(seeds))
        core.reset_rows(np.arange(len(seeds)), seeds)
        act = np.broadcast_to(core.default_action, (len(seeds), core.k))
        h, e3, zf, still = [], [], [], []
        div = np.zeros(len(seeds), bool)
        t0 = time.perf_counter()
        while not np.any(core.t >= core.M):
            j = core.t.copy()
            r = core.step(act)
            h.append(r.info["horizontal_error_m"])
            e3.append(r.info["error_3d_m"])
            zf.append(r.info["zupt"])
            still.append(core.truth_still[np.arange(len(seeds)), j])
            div |= r.terminated
            if np.any(r.terminated):
                break
        h, e3, zf, still = (np.array(a) for a in (h, e3, zf, still))
        out[z] = {"rmse_h_m": float(np.sqrt(np.mean(h ** 2))), "rmse_3d_m": float(np.sqrt(np.mean(e3 ** 2))),
                  "max_h_m": float(h.max()), "zupt_epochs_frac": float(zf.mean()),
                  "false_zupt_epochs": int(np.sum(zf & ~still)), "stationary_epochs": int(still.sum()),
                  "epochs_run": int(h.shape[0]), "diverged_episodes": int(div.sum()),
                  "seconds": time.perf_counter() - t0}
    return out


# --------------------------------------------------------------------------------------------- VN-310 check
VN310_FILE = ("instinct_tckf_static", "vn310-imu.csv")
"""Path parts of the static VN-310 recording under ``shared_data_dir()``."""

_VN310_COLUMNS = {
    False: ("IMU::UncompAccel::", "IMU::UncompGyro::"),
    True: ("IMU::Accel::", "IMU::AngularRate::"),
}


def read_vn310_imu(path=None, compensated: bool = False):
    """Read the VectorNav VN-310 IMU log of the INSTINCT static test data (CSV).

    Columns used: ``Time [s]`` and either the uncompensated (default: what the sensor measured,
    biases included) ``IMU::UncompAccel::{X,Y,Z} [m/s^2]`` / ``IMU::UncompGyro::{X,Y,Z} [rad/s]`` or the
    compensated ``IMU::Accel::*`` / ``IMU::AngularRate::*`` (rad/s). Axes: VectorNav body frame, x forward,
    y right, z down (FRD, as in navgym: at rest ``f_z ~ -9.8 m/s^2``).

    Parameters
    ----------
    path : the CSV (default ``shared_data_dir() / instinct_tckf_static / vn310-imu.csv``).
    compensated : read the compensated columns.

    Returns
    -------
    rate_hz : float (from the median sample interval); f_b, w_b : (1, N, 3) float64.

    Raises
    ------
    FileNotFoundError (missing file), envs.datasets.DatasetFormatError (missing columns, bad numbers).
    """
    import csv

    from envs.datasets.errors import DatasetFormatError, require_file, shared_data_dir
    p = require_file(shared_data_dir().joinpath(*VN310_FILE) if path is None else path)
    with open(p, newline="") as fh:
        reader = csv.reader(fh)
        header = next(reader, None)
        if header is None:
            raise DatasetFormatError(p, None, "empty file")
        cols = []
        for prefix in ("Time [s]",) + tuple(f"{pre}{ax}" for pre in _VN310_COLUMNS[bool(compensated)]
                                            for ax in "XYZ"):
            hits = [i for i, h in enumerate(header) if h.strip().startswith(prefix)]
            if not hits:
                raise DatasetFormatError(p, 1, f"column {prefix!r} not found")
            cols.append(hits[0])
        rows = []
        for ln, row in enumerate(reader, start=2):
            try:
                rows.append([float(row[i]) for i in cols])
            except (ValueError, IndexError):
                raise DatasetFormatError(p, ln, "missing or non-numeric IMU value") from None
    a = np.asarray(rows)
    if a.shape[0] < 2 or not np.isfinite(a).all():
        raise DatasetFormatError(p, None, "fewer than two finite IMU samples")
    dt = float(np.median(np.diff(a[:, 0])))
    if not dt > 0:
        raise DatasetFormatError(p, None, "time stamps do not increase")
    return 1.0 / dt, a[None, :, 1:4].copy(), a[None, :, 4:7].copy()


def vn310_stationary_fraction(make, path=None) -> float | None:
    """Fraction of the static VN-310 samples declared stationary by ``make(rate_hz)``'s detector.

    The recording is 50 Hz; None when the file is absent (``../shared/data`` not beside the checkout).
    """
    try:
        rate, f, w = read_vn310_imu(path)
    except FileNotFoundError:
        return None
    return float(make(round(rate)).detect(f, w).stationary.mean())


# --------------------------------------------------------------------------------------------- entry point
def train_zupt_detector(model: str, seed: int, out: Path, quick: bool = False, progress: bool = True,
                        config: ZuptTrainConfig | None = None, learned: LearnedConfig | None = None) -> dict:
    """Train a learned detector, tune the classical ones, score all on held-out drives; write the results.

    Parameters
    ----------
    model : ``'mlp'`` or ``'lstm'``.
    seed : run seed S (training/validation drives and network initialization; the test set is fixed).
    out : output directory; receives ``zupt_<model>.pt`` (weights, loadable by
        :func:`nav_filters.zupt.learned.load_detector` / ``make_detector(model, rate, weights=...)``)
        and ``metrics.json``.
    quick : use :data:`QUICK` (seconds; for tests and smoke runs).
    progress : show a progress bar.
    config, learned : override the training / architecture settings.

    Returns
    -------
    the metrics dict written to ``metrics.json``.
    """
    if model not in ("mlp", "lstm"):
        raise ValueError(f"model must be 'mlp' or 'lstm', got {model!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ValueError(f"seed must be a non-negative int, got {seed!r}")
    cfg = config if config is not None else (QUICK if quick else ZuptTrainConfig())
    lc = learned if learned is not None else LearnedConfig(kind=model)
    if lc.kind != model:
        raise ValueError(f"learned.kind ({lc.kind!r}) must equal model ({model!r})")
    for r in cfg.rates_hz:
        decimation_factor(lc.model_rate_hz, r)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    net, lc, hist = train_learned(lc, cfg, int(seed), progress=progress)
    weights = out / f"zupt_{model}.pt"
    with atomic_path(weights) as tmp:
        save_weights(tmp, lc, net, extra={"seed": int(seed), "train_config": jsonable(cfg.to_dict())})
    t1 = time.perf_counter()
    tuned = tune_classical(training_drives(cfg, seed, 10 ** 3 - 1, cfg.tune_drives), cfg)
    tune_s = time.perf_counter() - t1
    results = _score_heldout(cfg, {
        model: lambda r: LearnedDetector(lc, net, r),
        f"{model}@max-f1": lambda r: LearnedDetector(lc.replace(threshold=hist["threshold_max_f1"]), net, r)}, tuned)
    metrics = {
        "model": model, "seed": int(seed), "quick": bool(quick),
        "label": {"stationary_if_true_speed_below_mps": LABEL_SPEED_MPS},
        "definitions": {
            "positive_class": "stationary",
            "false_zupt_rate": "moving samples declared stationary / moving samples",
            "detection_rate": "stationary samples declared stationary / stationary samples (P_D, recall); "
                              "seed paper 000 sec 5.3 gives no formula",
            "splits": "heldout_seeds: training IMU grades, unseen seeds; heldout_grades: IMU grades never trained on",
        },
        "weights": str(weights.name),
        "learned_config": lc.to_dict(),
        "threshold": lc.threshold,
        "threshold_note": f"shipped threshold: max F1 on the validation drives with the false-ZUPT rate capped at "
                          f"{cfg.max_false_rate:g}; '{model}@max-f1' rows use the uncapped max-F1 threshold "
                          f"{hist['threshold_max_f1']:.4f} (also from validation)",
        "train_config": cfg.to_dict(),
        "training": hist,
        "classical_tuned": {k: {"config": dataclasses.asdict(v["config"]), "threshold": v["config"].threshold,
                                "train_f1": v["train_f1"]} for k, v in tuned.items()},
        "classical_tuning_seconds": tune_s,
        "test": _test_section(results),
        "wall_seconds": time.perf_counter() - t0,
    }
    metrics = jsonable(metrics)
    write_atomic(out / "metrics.json", json.dumps(metrics, indent=2))
    return metrics


def _score_heldout(cfg: ZuptTrainConfig, learned: dict, tuned: dict) -> dict:
    """{split: {detector: evaluate_detector(...)}} on the held-out drives: the ``learned`` makers
    (``{name: make(rate)}``) and the tuned classical detectors."""
    results = {}
    for split, sets in heldout_drives(cfg).items():
        results[split] = {name: evaluate_detector(make, sets) for name, make in learned.items()}
        for kind, tc in tuned.items():
            results[split][kind] = evaluate_detector(lambda r, c=tc["config"]: ClassicalDetector(c, r), sets)
    return results


def _test_section(results: dict) -> dict:
    return {split: {det: {**_short(r["all"]), "counts": {k: r["all"][k] for k in ("tp", "fp", "fn", "tn")},
                          "by_grade": {g: _short(m) for g, m in r["by_grade"].items()},
                          "by_rate": {q: _short(m) for q, m in r["by_rate"].items()},
                          "samples_per_s": r["samples_per_s"]}
                    for det, r in res.items()} for split, res in results.items()}


def evaluate_shipped(seed: int = 0, config: ZuptTrainConfig | None = None) -> dict:
    """Held-out metrics of the shipped ``mlp`` and ``lstm`` weights beside the four classical detectors tuned
    (max F1) on training drives of ``seed``, on the same held-out drives as ``train.py zupt``; plus the
    fraction of the static VN-310 recording each declares stationary (None without ``../shared/data``)."""
    from nav_filters.zupt import default_weights_path, make_detector
    cfg = config if config is not None else ZuptTrainConfig()
    t0 = time.perf_counter()
    tuned = tune_classical(training_drives(cfg, seed, 10 ** 3 - 1, cfg.tune_drives), cfg)
    learned = {k: (lambda r, k=k: make_detector(k, r)) for k in ("mlp", "lstm")}
    results = _score_heldout(cfg, learned, tuned)
    makers = {**learned, **{k: (lambda r, c=v["config"]: ClassicalDetector(c, r)) for k, v in tuned.items()}}
    return jsonable({
        "weights": {k: default_weights_path(k).name for k in learned},
        "classical_tuned": {k: dataclasses.asdict(v["config"]) for k, v in tuned.items()},
        "test": _test_section(results),
        "vn310_stationary_fraction": {k: vn310_stationary_fraction(m) for k, m in makers.items()},
        "wall_seconds": time.perf_counter() - t0,
    })


def format_table(metrics: dict) -> str:
    """Markdown table of the held-out metrics of every detector in a ``metrics.json`` dict."""
    lines = ["| split | detector | precision | recall | F1 | accuracy | false-ZUPT | detection rate |",
             "|---|---|---|---|---|---|---|---|"]
    for split, res in metrics["test"].items():
        for det, m in res.items():
            f = lambda k: "n/a" if m[k] is None else f"{m[k]:.4f}"  # noqa: E731
            fz = "n/a" if m["false_zupt_rate"] is None else f"{100 * m['false_zupt_rate']:.3f} %"
            lines.append(f"| {split} | {det} | {f('precision')} | {f('recall')} | {f('f1')} | {f('accuracy')} "
                         f"| {fz} | {f('detection_rate')} |")
    return "\n".join(lines)


if __name__ == "__main__":  # pragma: no cover - convenience; the CLI is `python train.py zupt`
    import argparse
    ap = argparse.ArgumentParser(description="train a zero-velocity detector (same as `train.py zupt`)")
    ap.add_argument("--model", choices=("mlp", "lstm"), default="lstm")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--epochs", type=int, default=None, help="max_epochs (default: the default config's)")
    ap.add_argument("--evaluate-shipped", action="store_true",
                    help="instead of training: score the shipped weights and the tuned classical detectors on "
                         "the held-out drives; writes OUT/metrics_shipped.json")
    a = ap.parse_args()
    if a.evaluate_shipped:
        a.out.mkdir(parents=True, exist_ok=True)
        m = evaluate_shipped(a.seed)
        write_atomic(a.out / "metrics_shipped.json", json.dumps(m, indent=2))
        print(format_table(m))
        print("VN-310 static samples declared stationary: "
              + ", ".join(f"{k} {v:.4f}" for k, v in m["vn310_stationary_fraction"].items() if v is not None))
        print(f"wall {m['wall_seconds']:.1f} s; {a.out / 'metrics_shipped.json'}")
        raise SystemExit(0)
    conf = None
    if a.epochs is not None:
        conf = dataclasses.replace(QUICK if a.quick else ZuptTrainConfig(), max_epochs=a.epochs)
    m = train_zupt_detector(a.model, a.seed, a.out, quick=a.quick, config=conf)
    print(format_table(m))
    print(f"wall {m['wall_seconds']:.1f} s; weights and metrics.json in {a.out}")
