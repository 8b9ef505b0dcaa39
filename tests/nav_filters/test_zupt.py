"""Zero-velocity detectors (nav_filters.zupt): pre-filter, classical statistics, learned streaming, aiding block.

Tolerances: the filter gains are checked against the analytic Butterworth response to 2e-3
(a 40-period steady-state fit of a sampled sinusoid; the design itself is exact); the closed-form
window statistics against a direct per-window implementation of Skog et al.'s definitions to 1e-9
relative (float64 cumulative sums over < 1e4 samples); streaming against one-shot exactly for the
filter and to 1e-11 relative for the statistics (the chunked cumulative sums re-associate the additions).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from nav_filters.zupt import (DETECTORS, ClassicalConfig, ClassicalDetector, LowPass, ZuptAidingConfig,
                              butter_lowpass, classical_statistic, lowpass, make_detector, stationary_block,
                              tune_threshold)
from nav_filters.zupt.classical import G0

RATE = 100.0


def _still(B=2, n=300, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    f = np.zeros((B, n, 3))
    f[..., 2] = -G0
    w = np.zeros((B, n, 3))
    if noise:
        f += noise * rng.standard_normal(f.shape)
        w += 0.1 * noise * rng.standard_normal(w.shape)
    return f, w


# ------------------------------------------------------------------------------------------ pre-filter
@pytest.mark.parametrize("cutoff", [2.0, 5.0, 20.0])
def test_lowpass_gain_is_minus_3db_at_cutoff_unity_at_dc_and_butterworth_beyond(cutoff):
    t = np.arange(4000) / RATE
    for f_sig, want in ((cutoff, 1 / math.sqrt(2)), (0.0, 1.0),
                        (min(2 * cutoff, 45.0), None)):
        x = np.sin(2 * np.pi * f_sig * t + 0.3) if f_sig else np.full_like(t, 0.7)
        y = lowpass(x[None, :, None], RATE, cutoff)[0, :, 0]
        if f_sig == 0.0:
            assert np.allclose(y, 0.7, atol=1e-12)          # steady-state start: no transient at all
            continue
        seg = slice(2000, 4000)                              # steady state: 20 cutoff periods in
        A = np.c_[np.sin(2 * np.pi * f_sig * t[seg]), np.cos(2 * np.pi * f_sig * t[seg])]
        gain = np.hypot(*np.linalg.lstsq(A, y[seg], rcond=None)[0])
        if want is None:   # analytic digital Butterworth magnitude (bilinear transform, pre-warped)
            r = math.tan(math.pi * f_sig / RATE) / math.tan(math.pi * cutoff / RATE)
            want = 1 / math.sqrt(1 + r ** 4)
        assert gain == pytest.approx(want, abs=2e-3)


def test_lowpass_streaming_equals_one_shot_and_reset_rows_restarts_a_row():
    rng = np.random.default_rng(1)
    x = rng.standard_normal((3, 250, 6)) + 5.0
    one = lowpass(x, RATE, 10.0)
    lp = LowPass(10.0, RATE)
    parts = [lp(x[:, a:b]) for a, b in ((0, 1), (1, 77), (77, 77), (77, 250))]
    np.testing.assert_array_equal(np.concatenate(parts, 1), one)
    lp.reset_rows([1])
    y = lp(x[:, :50])
    np.testing.assert_array_equal(y[1], lowpass(x[1:2, :50], RATE, 10.0)[0])


def test_lowpass_rejects_cutoff_at_nyquist_and_nan():
    with pytest.raises(ValueError, match="Nyquist"):
        butter_lowpass(50.0, RATE)
    with pytest.raises(ValueError, match="order"):
        butter_lowpass(5.0, RATE, order=0)
    x = np.zeros((1, 10, 3))
    x[0, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        lowpass(x, RATE, 5.0)


# ------------------------------------------------------------------------------------------ classical
def _direct(kind, x, W, sa, sw, g):
    """Skog et al. (2010) statistics, one window at a time, straight from the definitions."""
    out = []
    for j in range(x.shape[0] - W + 1):
        a, w = x[j:j + W, :3], x[j:j + W, 3:]
        ab = a.mean(0)
        if kind == "shoe":
            T = np.sum(np.sum((a - g * ab / np.linalg.norm(ab)) ** 2, 1) / sa ** 2 + np.sum(w ** 2, 1) / sw ** 2) / W
        elif kind == "are":
            T = np.sum(w ** 2) / (sw ** 2 * W)
        elif kind == "mag":
            T = np.sum((np.linalg.norm(a, axis=1) - g) ** 2) / (sa ** 2 * W)
        else:
            T = np.sum((a - ab) ** 2) / (sa ** 2 * W)
        out.append(T)
    return np.array(out)


@pytest.mark.parametrize("kind", ["shoe", "are", "mag", "mv"])
def test_closed_form_statistics_equal_the_per_window_definitions(kind):
    rng = np.random.default_rng(2)
    x = np.c_[rng.normal(0, 0.3, (400, 2)), rng.normal(-9.7, 0.3, (400, 1)), rng.normal(0, 0.05, (400, 3))]
    got = classical_statistic(kind, x[None], 17, 0.02, 0.003, 9.79)[0]
    np.testing.assert_allclose(got, _direct(kind, x, 17, 0.02, 0.003, 9.79), rtol=1e-9)


def test_perfectly_still_is_stationary_for_every_classical_detector():
    f, w = _still()
    for kind in ("shoe", "are", "mag", "mv"):
        det = ClassicalDetector(ClassicalConfig(kind=kind, window_s=0.2, threshold=1.0), RATE)
        out = det.detect(f, w)
        W = det.W
        assert not out.stationary[:, :W - 1].any()          # window not full yet: never fires
        assert out.stationary[:, W - 1:].all(), kind
        assert np.abs(out.score[:, W - 1:]).max() < 1e-8     # T = 0 exactly up to rounding


def test_constant_rate_turn_is_moving_for_are_and_shoe_but_invisible_to_accelerometer_detectors():
    # a vehicle turning at a constant 10 deg/s at constant speed: constant specific force (gravity and a
    # constant centripetal term), constant angular rate. ARE and SHOE see the rate; MAG and MV only see a
    # constant acceleration magnitude / zero variance -- the known blind spot of accelerometer-only tests.
    f, w = _still(noise=1e-3)
    w[..., 2] += math.radians(10.0)
    f[..., 1] += 5.0 * math.radians(10.0)                   # centripetal v * omega at 5 m/s
    dec = {}
    for kind in ("shoe", "are", "mag", "mv"):
        det = ClassicalDetector(ClassicalConfig(kind=kind, window_s=0.2, threshold=10.0), RATE)
        dec[kind] = det.detect(f, w).stationary[:, det.W - 1:]
    assert not dec["are"].any() and not dec["shoe"].any()
    assert dec["mv"].all()


def test_classical_streaming_equals_one_shot_and_rows_restart():
    rng = np.random.default_rng(3)
    f = rng.normal(0, 0.05, (3, 500, 3)) + [0, 0, -G0]
    w = rng.normal(0, 0.01, (3, 500, 3))
    for kind in ("shoe", "mv"):
        det = ClassicalDetector(ClassicalConfig(kind=kind, window_s=0.3, threshold=50.0), RATE)
        one = det.detect(f, w)
        det.reset()
        s = np.concatenate([det.process(f[:, a:b], w[:, a:b]).score for a, b in ((0, 7), (7, 200), (200, 500))], 1)
        np.testing.assert_allclose(s, one.score, rtol=1e-11)  # cumulative sums re-associate: rounding only
        det.reset_rows([2])
        again = det.process(f[:, :40], w[:, :40]).score
        assert np.isinf(again[2, :det.W - 1]).all() and np.isfinite(again[0]).all()


def test_tune_threshold_is_the_max_f1_cut_and_respects_a_false_rate_cap():
    rng = np.random.default_rng(4)
    y = rng.random(3000) < 0.4
    s = np.where(y, rng.normal(1.0, 1.0, y.size), rng.normal(3.0, 1.0, y.size))
    thr, f1 = tune_threshold(s, y)
    # brute force over every cut
    cuts = np.unique(s)
    best = max(2 * np.sum((s < c) & y) / (2 * np.sum((s < c) & y) + np.sum((s < c) & ~y) + np.sum(~(s < c) & y))
               for c in cuts)
    assert f1 == pytest.approx(best, abs=1e-12)
    d = s < thr
    assert 2 * np.sum(d & y) / (2 * np.sum(d & y) + np.sum(d & ~y) + np.sum(~d & y)) == pytest.approx(f1)
    thr2, _ = tune_threshold(s, y, max_false_rate=0.001)
    assert np.sum((s < thr2) & ~y) <= 0.001 * np.sum(~y) and thr2 < thr
    # probabilities: stationary where score >= threshold
    tp, f1p = tune_threshold(-s, y, stationary_below=False)
    assert f1p == pytest.approx(f1) and tp == pytest.approx(-thr)
    # perfectly separable -> F1 = 1
    assert tune_threshold(np.r_[np.zeros(5), np.ones(5)], np.r_[np.ones(5, bool), np.zeros(5, bool)])[1] == 1.0


# ------------------------------------------------------------------------------------------ bad input
def test_bad_input_gives_clear_errors(tmp_path):
    det = make_detector("shoe", RATE)
    f, w = _still(n=20)
    with pytest.raises(ValueError, match=r"f_b must have shape \(B, n, 3\)"):
        det.process(f[..., :2], w)
    with pytest.raises(ValueError, match="same shape"):
        det.process(f, w[:, :10])
    f[1, 7, 0] = np.nan
    with pytest.raises(ValueError, match=r"f_b has a NaN or inf sample \(row 1, sample 7\)"):
        det.process(f, w)
    with pytest.raises(ValueError, match="unknown detector"):
        make_detector("glrt2", RATE)
    with pytest.raises(ValueError, match="weights are only for the learned"):
        make_detector("mv", RATE, weights="x.pt")
    with pytest.raises(ValueError, match="ClassicalConfig.window_s"):
        ClassicalConfig(window_s=-1.0)
    with pytest.raises(ValueError, match="ClassicalConfig.kind"):
        ClassicalConfig(kind="zupt")
    with pytest.raises(ValueError, match="Nyquist"):
        ClassicalDetector(ClassicalConfig(cutoff_hz=30.0), 50.0)
    pytest.importorskip("torch")
    with pytest.raises(FileNotFoundError, match="weights file not found"):
        make_detector("lstm", RATE, weights=tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match="not a readable detector weights file"):
        make_detector("mlp", RATE, weights=junk)


def test_learned_detector_streams_like_one_shot_and_validates_windows():
    torch = pytest.importorskip("torch")
    from nav_filters.zupt.learned import LearnedConfig, LearnedDetector, build_model
    rng = np.random.default_rng(5)
    f = rng.normal(0, 0.05, (2, 403, 3)) + [0, 0, -G0]
    w = rng.normal(0, 0.01, (2, 403, 3))
    for kind in ("mlp", "lstm"):
        torch.manual_seed(0)
        cfg = LearnedConfig(kind=kind, window=8, hidden=8)
        det = LearnedDetector(cfg, build_model(cfg), RATE)
        one = det.detect(f, w).score
        det.reset()
        parts = [det.process(f[:, a:b], w[:, a:b]).score for a, b in ((0, 3), (3, 100), (100, 101), (101, 403))]
        np.testing.assert_allclose(np.concatenate(parts, 1), one, atol=1e-6)   # float32 network, re-batched
        assert np.all((one >= 0) & (one <= 1))
        if kind == "mlp":
            assert (one[:, :2 * 8 - 1] == 0).all()       # 8 model steps at 50 Hz = 16 samples before it fires
            with pytest.raises(ValueError, match=r"windows must have shape \(K, 8, 10\)"):
                det.predict_windows(np.zeros((4, 9, 10)))
            with pytest.raises(ValueError, match="NaN"):
                det.predict_windows(np.full((1, 8, 10), np.nan))
        else:
            with pytest.raises(ValueError, match=r"feats must have shape \(B, T, 10\)"):
                det.predict_sequence(np.zeros((4, 9, 6)))
    with pytest.raises(ValueError, match="integer multiple"):
        LearnedDetector(LearnedConfig(), None, 75.0)


# ------------------------------------------------------------------------------------------ aiding
class _Nav:
    """The navigator attributes stationary_block reads."""

    def __init__(self, B):
        from earth.wgs84 import geodetic_to_ecef, C_en
        from nav_filters.error_model import ProcessNoise
        self.batch_size = B
        lat, lon = np.radians(52.0), np.radians(13.0)
        self.r = np.repeat(geodetic_to_ecef(lat, lon, 30.0)[None], B, 0)
        self.v = np.tile([0.03, -0.02, 0.01], (B, 1))
        self.C = np.repeat(C_en(lat, lon)[None], B, 0)
        self.bg = np.zeros((B, 3))
        self.diverged = np.zeros(B, bool)
        self.dtype = np.dtype(np.float64)

        class _Cfg:
            noise = ProcessNoise(gyro_psd=1e-8)

        self.config = _Cfg()


def test_stationary_block_constrains_only_rows_stationary_at_the_epoch_end():
    nav = _Nav(3)
    st = np.zeros((3, 10), bool)
    st[0] = True                        # stationary throughout
    st[1, 6:] = True                    # stopped 4 samples before the epoch
    st[2, :9] = True                    # started moving on the last sample
    w = np.zeros((3, 10, 3))
    w[1, :6] = 1.0                      # rotating before the stop: must not enter the mean
    block, active = stationary_block(nav, w, st, 0.01)
    assert active.tolist() == [True, True, False]
    dz, H, R, mask = block
    assert dz.shape == (3, 4) and mask[:2].all() and not mask[2].any()
    np.testing.assert_allclose(dz[0, :3], -nav.v[0])
    # heading-rate variance: ARW^2 / T + (angle / T)^2 with T = 10 and 4 samples
    for row, T in ((0, 0.1), (1, 0.04)):
        assert R[row, 3] == pytest.approx(1e-8 / T + (1e-4 / T) ** 2)
    assert abs(dz[1, 3]) < 1e-4         # mean over the 4 still samples only (Earth rate residual)
    none, act = stationary_block(nav, w, np.zeros((3, 10), bool), 0.01)
    assert none is None and not act.any()
    with pytest.raises(ValueError, match="stationary must be a bool array"):
        stationary_block(nav, w, st[:, :5], 0.01)
    with pytest.raises(ValueError, match="zupt_sigma_mps"):
        ZuptAidingConfig(zupt_sigma_mps=0.0)


def test_every_detector_name_is_constructible_or_says_why():
    for name in DETECTORS:
        try:
            det = make_detector(name, RATE)
        except (FileNotFoundError, ImportError) as exc:   # learned weights not shipped / torch absent
            assert name in ("mlp", "lstm"), exc
            continue
        assert det.name == name and det.rate_hz == RATE
