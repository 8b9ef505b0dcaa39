"""The compiled zero-velocity detector steps against their numpy specifications: the classical detectors
(``nav_filters.zupt.classical_rows``; ``ClassicalDetector.compiled = False``: ``LowPass`` by
``scipy.signal.sosfilt``, ``_score``, ``decide``), the learned detectors' features (``learned_rows``;
``FeatureStream.push`` with ``scipy.signal.lfilter``) and the stationary constraint block (``stationary_block``
against its composition). The same bits for every kind, with and without the pre-filter, over streamed chunks,
restarted rows, several kernel chunks per call and the parallel row kernel; the state after each call the same;
input the kernels do not take left to the numpy path, and its errors."""
from __future__ import annotations

import numpy as np
import pytest

from nav_filters.kernels import PARALLEL_MIN_BATCH
from nav_filters.zupt import ClassicalConfig, ClassicalDetector, make_detector
from nav_filters.zupt.classical import CLASSICAL_KINDS, G0

RATE = 100.0


def _pair(kind, cutoff=5.0, threshold=5.0):
    cfg = ClassicalConfig(kind=kind, window_s=0.3, threshold=threshold, cutoff_hz=cutoff)
    fast, ref = ClassicalDetector(cfg, RATE), ClassicalDetector(cfg, RATE)
    ref.compiled = False
    return fast, ref


def _imu(B, n, seed=0):
    """A stream that stands still, moves, and stands still again (each detector fires in part of it)."""
    rng = np.random.default_rng(seed)
    f = rng.normal(0, 0.01, (B, n, 3)) + [0.0, 0.0, -G0]
    w = rng.normal(0, 2e-4, (B, n, 3))
    move = slice(n // 3, 2 * n // 3)
    f[:, move] += rng.normal(0, 1.5, f[:, move].shape)
    w[:, move] += rng.normal(0, 0.2, w[:, move].shape)
    return f, w


def _same_state(a, b):
    np.testing.assert_array_equal(a._tail, b._tail)
    np.testing.assert_array_equal(a._count, b._count)
    if a._lp is not None:
        np.testing.assert_array_equal(a._lp.zi, b._lp.zi)
        np.testing.assert_array_equal(a._lp._fresh, b._lp._fresh)


@pytest.mark.parametrize("kind", CLASSICAL_KINDS)
@pytest.mark.parametrize("cutoff", [5.0, None])
@pytest.mark.parametrize("B", [1, 3, PARALLEL_MIN_BATCH + 3])
def test_compiled_detector_gives_the_numpy_bits(kind, cutoff, B):
    f, w = _imu(B, 420, seed=B)
    probe, _ = _pair(kind, cutoff)  # the threshold at the median statistic, so both decisions occur
    T = probe.detect(f, w).score
    fast, ref = _pair(kind, cutoff, threshold=float(np.median(T[np.isfinite(T)])))
    fired = np.zeros(2, int)
    for s, e in ((0, 1), (1, 20), (20, 140), (140, 141), (141, 330), (330, 420)):
        if s == 141:  # new streams on some rows: the filter restarts from their next sample, windows refill
            fast.reset_rows([0, B - 1])
            ref.reset_rows([0, B - 1])
        got, want = fast.process(f[:, s:e], w[:, s:e]), ref.process(f[:, s:e], w[:, s:e])
        np.testing.assert_array_equal(got.score, want.score)
        np.testing.assert_array_equal(np.signbit(got.score), np.signbit(want.score))
        np.testing.assert_array_equal(got.stationary, want.stationary)
        _same_state(fast, ref)
        fired += np.bincount(got.stationary.ravel(), minlength=2)
    assert fired.min() > 0  # both decisions were exercised


def test_compiled_detector_runs_long_calls_in_chunks_as_the_numpy_path(monkeypatch):
    monkeypatch.setattr(ClassicalDetector, "_CHUNK", 7)
    for kind in ("shoe", "mv"):
        fast, ref = _pair(kind)
        f, w = _imu(2, 100)
        for s, e in ((0, 3), (3, 80), (80, 100)):  # first call shorter than the window, then several chunks
            got, want = fast.process(f[:, s:e], w[:, s:e]), ref.process(f[:, s:e], w[:, s:e])
            np.testing.assert_array_equal(got.score, want.score)
            _same_state(fast, ref)


def test_unusual_chunks_give_the_numpy_bits():
    fast, ref = _pair("shoe")
    f, w = _imu(2, 60)
    # float32 input and an empty chunk (the numpy path), a strided view (the kernel on non-contiguous arrays)
    for args in ((f[:, :10].astype(np.float32), w[:, :10].astype(np.float32)), (f[:, 10:40:2], w[:, 10:40:2]),
                 (f[:, 40:40], w[:, 40:40]), (f[:, 40:], w[:, 40:])):
        got, want = fast.process(*args), ref.process(*args)
        np.testing.assert_array_equal(got.score, want.score)
        _same_state(fast, ref)


def test_bad_input_raises_the_numpy_error_and_leaves_the_state_unchanged():
    det = make_detector("shoe", RATE)
    assert det.compiled
    ref = make_detector("shoe", RATE)
    ref.compiled = False
    f, w = _imu(2, 50)
    det.process(f[:, :20], w[:, :20])
    ref.process(f[:, :20], w[:, :20])
    bad = f[:, 20:].copy()
    bad[1, 7, 2] = np.inf
    with pytest.raises(ValueError, match=r"f_b has a NaN or inf sample \(row 1, sample 7\)"):
        det.process(bad, w[:, 20:])
    _same_state(det, ref)
    np.testing.assert_array_equal(det.process(f[:, 20:], w[:, 20:]).score, ref.process(f[:, 20:], w[:, 20:]).score)
    with pytest.raises(ValueError, match="the detector runs B=2 streams"):
        det.process(f[:1, :5], w[:1, :5])
    with pytest.raises(ValueError, match="same shape"):
        det.process(f, w[:, :10])


@pytest.mark.parametrize("zupt", ["shoe", "lstm"])
def test_env_with_a_detector_steps_the_same_with_and_without_the_compiled_passes(zupt):
    import gymnasium as gym
    import envs  # noqa: F401  (registers the ids)

    if zupt == "lstm":
        pytest.importorskip("torch")
    out = []
    for compiled in (True, False):
        env = gym.make("GnssIns/SageHusa-v1", episode_length_s=40.0, scenario="urban", zupt=zupt)
        env.reset(seed=3)
        env.unwrapped.core._zupt.compiled = compiled  # the detector's step and the constraint block
        assert env.unwrapped.core._zupt.detector.compiled is compiled
        steps = [env.step(np.array([0.3 * np.sin(k)], np.float32)) for k in range(30)]
        out.append((np.array([s[0] for s in steps]), np.array([s[1] for s in steps]),
                    np.array([s[4]["zupt"] for s in steps])))
    for a, b in zip(*out):
        np.testing.assert_array_equal(a, b)
    assert out[0][2].any()  # the urban drive stops: ZUPT rows were used


# ------------------------------------------------------------------------------------------ stationary block
class _Nav:
    """The navigator attributes ``stationary_block`` reads, with a varied state per row."""

    def __init__(self, B, dtype=np.float64, seed=0):
        from earth.rotations import exp_so3
        from earth.wgs84 import C_en, geodetic_to_ecef
        from nav_filters.error_model import ProcessNoise

        rng = np.random.default_rng(seed)
        self.batch_size = B
        lat, lon = np.radians(rng.uniform(-60, 60, B)), np.radians(rng.uniform(-180, 180, B))
        self.r = np.stack([geodetic_to_ecef(a, o, h) for a, o, h in zip(lat, lon, rng.uniform(0, 900, B))])
        self.v = rng.normal(0, 0.05, (B, 3))
        self.C = np.stack([C_en(a, o) @ exp_so3(rng.normal(0, 0.5, 3)) for a, o in zip(lat, lon)])
        self.bg = rng.normal(0, 1e-4, (B, 3))
        self.diverged = np.zeros(B, bool)
        self.dtype = np.dtype(dtype)

        class _Cfg:
            noise = ProcessNoise(gyro_psd=rng.uniform(1e-9, 1e-7, 3))

        self.config = _Cfg()


def _blocks(nav, w, st, dt=0.01, config=None):
    from nav_filters.zupt import ZuptAidingConfig, stationary_block

    config = config or ZuptAidingConfig()
    return (stationary_block(nav, w, st, dt, config), stationary_block(nav, w, st, dt, config, compiled=False))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("heading", [True, False])
def test_compiled_stationary_block_gives_the_composition_bits(dtype, heading):
    from nav_filters.zupt import ZuptAidingConfig

    B, n = 40, 25
    nav = _Nav(B, dtype)
    rng = np.random.default_rng(1)
    w = rng.normal(0, 0.02, (B, n, 3))
    st = np.arange(n)[None, :] >= rng.integers(0, n, B)[:, None]  # runs of every length from the 10th row
    st[:9] = True
    st[1, :10] = False                  # stopped 15 samples before the epoch
    st[2, 23] = False                   # a one-sample run
    st[3, -1] = False                   # moving at the epoch: no rows
    st[4, :] = False
    st[4, -1] = True
    nav.diverged[5] = True              # parked: no rows
    nav.v[6] = np.nan                   # a moving row's state is not read
    st[6, -1] = False
    nav.v[7] = 0.0                      # -0.0 rows
    cfg = ZuptAidingConfig(zupt_sigma_mps=0.03, heading_rate=heading, vibration_angle_rad=2e-4)
    (got, act), (want, act_ref) = _blocks(nav, w, st, 0.01, cfg)
    np.testing.assert_array_equal(act, act_ref)
    assert act[:9].tolist() == [True, True, True, False, True, False, False, True, True] and act[9:].all()
    for g, r in zip(got, want):
        assert g.dtype == r.dtype and g.shape == r.shape
        np.testing.assert_array_equal(g, r)
        np.testing.assert_array_equal(np.signbit(g), np.signbit(r))
    assert got[0].shape == (B, 4 if heading else 3)


def test_compiled_stationary_block_leaves_bad_state_to_the_composition_and_its_error():
    nav = _Nav(3)
    w = np.zeros((3, 10, 3))
    st = np.ones((3, 10), bool)
    nav.C[1, 2, 0] = np.inf
    from nav_filters.zupt import stationary_block

    with pytest.raises(ValueError, match="C_eb has a non-finite value on active batch row 1"):
        stationary_block(nav, w, st, 0.01)
    nav.C[1, 2, 0] = 0.0
    w[2, 4, 1] = np.nan                 # inside the trailing run of row 2: its gyro mean is not finite
    with pytest.raises(ValueError, match="w_b_corrected has a non-finite value on active batch row 2"):
        stationary_block(nav, w, st, 0.01)
    st[2, 5] = False                    # the NaN sample is now before the run: not in the mean
    (got, _), (want, _) = _blocks(nav, w, st)
    for g, r in zip(got, want):
        np.testing.assert_array_equal(g, r)


# ------------------------------------------------------------------------------------------ learned features
def _streams(B, factor=2):
    from nav_filters.zupt.learned import FeatureStream, LearnedConfig

    cfg = LearnedConfig(kind="lstm", model_rate_hz=RATE / factor, cutoff_hz=0.2 * RATE / factor)
    return FeatureStream(cfg, RATE), FeatureStream(cfg, RATE)


@pytest.mark.parametrize("B", [1, 3, PARALLEL_MIN_BATCH + 3])
@pytest.mark.parametrize("factor", [1, 2, 3])
def test_compiled_features_give_the_numpy_bits(B, factor):
    from nav_filters.zupt.base import check_imu

    fast, ref = _streams(B, factor)
    f, w = _imu(B, 420, seed=10 + B)
    # chunks of 1 sample (no model step in some of them at factor > 1), odd lengths, rows restarted midway
    for s, e in ((0, 1), (1, 2), (2, 3), (3, 104), (104, 250), (250, 251), (251, 420)):
        if s == 250:
            fast.reset_rows([0, B - 1])
            ref.reset_rows([0, B - 1])
        got, want = fast.push_compiled(f[:, s:e], w[:, s:e]), ref.push(check_imu(f[:, s:e], w[:, s:e]))
        np.testing.assert_array_equal(got[1], want[1])
        assert got[0].dtype == want[0].dtype == np.float32 and got[0].shape == want[0].shape
        np.testing.assert_array_equal(got[0], want[0])
        np.testing.assert_array_equal(np.signbit(got[0]), np.signbit(want[0]))
        for name in ("_ema", "_fresh", "_phase"):
            np.testing.assert_array_equal(getattr(fast, name), getattr(ref, name))
        np.testing.assert_array_equal(fast._lp.zi, ref._lp.zi)
        np.testing.assert_array_equal(fast._lp._fresh, ref._lp._fresh)


@pytest.mark.parametrize("kind", ["lstm", "mlp"])
def test_learned_detector_with_compiled_features_scores_as_the_numpy_path(kind):
    pytest.importorskip("torch")
    from nav_filters.zupt.learned import LearnedConfig, LearnedDetector

    cfg = LearnedConfig(kind=kind, window=8, hidden=16)
    fast = LearnedDetector(cfg, None, RATE)
    ref = LearnedDetector(cfg, fast.model, RATE)
    ref.compiled = False
    assert fast.compiled
    f, w = _imu(3, 300, seed=7)
    for s, e in ((0, 1), (1, 130), (130, 300)):
        got, want = fast.process(f[:, s:e], w[:, s:e]), ref.process(f[:, s:e], w[:, s:e])
        np.testing.assert_array_equal(got.score, want.score)
        np.testing.assert_array_equal(got.stationary, want.stationary)
    bad = f[:, :10].copy()
    bad[2, 3, 0] = np.nan
    with pytest.raises(ValueError, match=r"f_b has a NaN or inf sample \(row 2, sample 3\)"):
        fast.process(bad, w[:, :10])
    np.testing.assert_array_equal(fast.features._ema, ref.features._ema)  # nothing changed by the bad chunk
    with pytest.raises(ValueError, match="the detector runs B=3 streams"):
        fast.process(f[:1, :10], w[:1, :10])
    # float32 input (the numpy path) and a strided view (the kernel on non-contiguous arrays): the same scores
    for args in ((f[:, 10:30].astype(np.float32), w[:, 10:30].astype(np.float32)), (f[:, 30:90:3], w[:, 30:90:3])):
        np.testing.assert_array_equal(fast.process(*args).score, ref.process(*args).score)
