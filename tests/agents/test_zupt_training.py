"""Training code of the zero-velocity detectors (agents.zupt_training) and the real-data check.

The toy set is separable by construction (still: gravity + 5 mg noise; moving: a 3 Hz, 0.5 m/s^2
oscillation and a 0.2 rad/s yaw rate), so a working training loop must reach F1 >= 0.9 with at most
5 % false ZUPTs on unseen toy data; an untrained network (probability ~0.5 everywhere) or a
broken loop cannot (always-stationary has F1 = 0.67 and 100 % false ZUPTs).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from agents.zupt_training import (LABEL_SPEED_MPS, QUICK, DriveSet, ZuptTrainConfig, classification_metrics,
                                  in_loop_rmse, read_vn310_imu, simulate_drives, stop_heavy_drive, train_learned,
                                  train_zupt_detector, vn310_stationary_fraction)
from envs.datasets.errors import shared_data_dir
from envs.sim.trajectory import Static, Turn
from nav_filters.zupt import make_detector
from nav_filters.zupt.classical import G0

VN310 = shared_data_dir() / "instinct_tckf_static" / "vn310-imu.csv"
needs_vn310 = pytest.mark.skipif(not VN310.is_file(), reason=f"VN-310 static recording not found at {VN310} "
                                 "(../shared/data is absent beside this checkout)")


def _toy(seed, B=4, seconds=60.0, rate=100.0):
    """Alternating 4-8 s still / moving segments, separable by construction (module docstring)."""
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    still = np.zeros((B, n), bool)
    for b in range(B):
        k, s = 0, bool(rng.random() < 0.5)
        while k < n:
            m = int(rng.uniform(4.0, 8.0) * rate)
            still[b, k:k + m] = s
            k, s = k + m, not s
    f = rng.normal(0.0, 0.05, (B, n, 3))
    f[..., 2] -= G0
    w = rng.normal(0.0, 0.002, (B, n, 3))
    mv = ~still
    f[..., 0] += np.where(mv, 0.5 * np.sin(2 * np.pi * 3.0 * t + rng.uniform(0, 6, (B, 1))), 0.0)
    w[..., 2] += np.where(mv, 0.2, 0.0)
    return DriveSet(f, w, still, np.where(still, 0.0, 1.0), np.ones((B, n), bool), rate, "toy", tuple(range(B)))


TOY_CFG = ZuptTrainConfig(duration_s=60.0, rates_hz=(100.0,), max_epochs=8, patience=8, lr=1e-2, tbptt_steps=100,
                          mlp_batches=40, mlp_batch_size=128)


@pytest.mark.parametrize("kind", ["mlp", "lstm"])
def test_tiny_training_learns_a_separable_toy_set_and_weights_reload_identically(kind, tmp_path):
    pytest.importorskip("torch")
    from nav_filters.zupt.learned import LearnedConfig, LearnedDetector, load_detector, save_weights
    lc = LearnedConfig(kind=kind, window=10, hidden=16)
    train = [_toy(1), _toy(2)]
    model, lc2, hist = train_learned(lc, TOY_CFG, seed=0, progress=False, train_sets=lambda e: [train[e % 2]],
                                     val_sets=[_toy(3)])
    assert 1 <= len(hist["epochs"]) <= TOY_CFG.max_epochs and 0.0 < lc2.threshold < 1.0
    test = _toy(4)
    det = LearnedDetector(lc2, model, test.rate_hz)
    out = det.detect(test.f_b, test.w_b)
    m = classification_metrics(out.stationary, test.stationary)
    assert m["f1"] >= 0.9 and m["false_zupt_rate"] <= 0.05, m
    path = save_weights(tmp_path / f"zupt_{kind}.pt", lc2, model)
    again = load_detector(path, test.rate_hz).detect(test.f_b, test.w_b)
    np.testing.assert_array_equal(again.score, out.score)           # same network, same pipeline: bit-identical
    np.testing.assert_array_equal(again.stationary, out.stationary)
    via_factory = make_detector(kind, test.rate_hz, weights=path).detect(test.f_b, test.w_b)
    np.testing.assert_array_equal(via_factory.score, out.score)


def test_stop_heavy_drives_have_idle_stops_engine_off_parking_creeping_and_slow_turns():
    s = simulate_drives([11, 12, 13, 14], "industrial", 50.0, 600.0)
    assert s.f_b.shape == (4, 30001, 3) and s.stationary.dtype == bool
    still = s.speed < LABEL_SPEED_MPS
    np.testing.assert_array_equal(still, s.stationary)
    assert 0.15 < still.mean() < 0.6
    assert (still & s.engine_on).any() and (still & ~s.engine_on).any()           # idling and parked
    creep = (s.speed >= LABEL_SPEED_MPS) & (s.speed < 0.3)
    assert creep.mean() > 0.003
    # drives are deterministic per seed and start at rest
    m1 = stop_heavy_drive(np.random.default_rng(5), 300.0)
    assert m1 == stop_heavy_drive(np.random.default_rng(5), 300.0)
    assert isinstance(m1.segments[0], Static) and m1.duration_s >= 300.0
    segs = [seg for k in range(5) for seg in stop_heavy_drive(np.random.default_rng(k), 600.0).segments]
    assert any(isinstance(seg, Turn) and seg.rate_deg_s < 5.0 for seg in segs)                # slow turns
    assert any(isinstance(seg, Static) and not seg.engine_on and seg.duration_s > 5.0 for seg in segs)


def test_classification_metrics_on_a_known_confusion_matrix():
    y = np.array([1, 1, 1, 1, 0, 0, 0, 0, 0, 0], bool)
    d = np.array([1, 1, 1, 0, 1, 0, 0, 0, 0, 0], bool)        # tp 3, fn 1, fp 1, tn 5
    m = classification_metrics(d, y)
    assert (m["tp"], m["fn"], m["fp"], m["tn"]) == (3, 1, 1, 5)
    assert m["precision"] == 0.75 and m["recall"] == 0.75 and m["f1"] == 0.75
    assert m["accuracy"] == 0.8 and m["false_zupt_rate"] == pytest.approx(1 / 6) and m["detection_rate"] == 0.75
    assert math.isnan(classification_metrics(np.zeros(3, bool), np.zeros(3, bool))["precision"])
    with pytest.raises(ValueError, match="same size"):
        classification_metrics(d, y[:5])


def test_quick_train_run_writes_weights_and_complete_metrics(tmp_path):
    pytest.importorskip("torch")
    metrics = train_zupt_detector("lstm", 0, tmp_path, quick=True, progress=False)
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["model"] == "lstm" and (tmp_path / saved["weights"]).is_file()
    for split in ("heldout_seeds", "heldout_grades"):
        for det in ("lstm", "shoe", "are", "mag", "mv"):
            row = saved["test"][split][det]
            for k in ("precision", "recall", "f1", "accuracy", "false_zupt_rate", "detection_rate"):
                assert k in row
    for kind in ("shoe", "are", "mag", "mv"):
        assert saved["classical_tuned"][kind]["threshold"] > 0
    assert saved["label"]["stationary_if_true_speed_below_mps"] == LABEL_SPEED_MPS
    assert metrics["test"] == saved["test"]
    with pytest.raises(ValueError, match="model must be"):
        train_zupt_detector("svm", 0, tmp_path, quick=True)
    with pytest.raises(ValueError, match="ZuptTrainConfig.patience"):
        ZuptTrainConfig(patience=0)
    assert QUICK.max_epochs <= 3


@needs_vn310
def test_vn310_static_recording_is_parsed_and_classified_stationary_by_the_shipped_default():
    from nav_filters.zupt.defaults import DEFAULT_DETECTOR
    rate, f, w = read_vn310_imu()
    assert rate == pytest.approx(50.0, rel=1e-3) and f.shape == w.shape and f.shape[1] > 1500
    assert np.linalg.norm(f[0].mean(0)) == pytest.approx(9.80, abs=0.02) and f[0, :, 2].mean() < -9.7  # FRD
    frac = vn310_stationary_fraction(lambda r: make_detector(DEFAULT_DETECTOR, r))
    assert frac >= 0.99, f"{DEFAULT_DETECTOR}: {frac:.4f} of the static samples declared stationary"


def test_detectors_drive_zupts_in_the_environment_core_only_where_the_vehicle_stands():
    # seed003-sim starts with 30 s at rest (engine idling), then accelerates: over the first 60 epochs the
    # truth is stationary at ~30 of them. 'none' never constrains; 'truth' constrains exactly those;
    # a detector must fire on most of them and never while moving.
    zs = ["none", "truth", "shoe"] + (["lstm"] if _has_torch() else [])
    r = in_loop_rmse("seed003-sim", zs, [3], episode_length_s=60.0)
    assert r["none"]["zupt_epochs_frac"] == 0.0
    still = r["truth"]["stationary_epochs"]
    assert 25 <= still <= 35 and r["truth"]["zupt_epochs_frac"] == pytest.approx(still / r["truth"]["epochs_run"])
    for z in zs[2:]:
        assert r[z]["false_zupt_epochs"] == 0, z
        assert r[z]["zupt_epochs_frac"] * r[z]["epochs_run"] >= 0.8 * still, z
    with pytest.raises(ValueError, match="EnvConfig.zupt must be one of"):
        in_loop_rmse("seed003-sim", ["glrt"], [3], episode_length_s=5.0)


def _has_torch():
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


@pytest.mark.skipif(not _has_torch(), reason="torch is not installed")
def test_shipped_metrics_file_is_what_the_evaluation_gives():
    """nav_filters/zupt/weights/metrics_shipped.json is reproduced by evaluate_shipped (no typed figures), and
    the shipped LSTM beats every tuned classical detector on held-out drives at a low false-ZUPT rate."""
    import json
    from pathlib import Path

    import nav_filters.zupt as z
    from agents.zupt_training import evaluate_shipped
    shipped = json.loads((Path(z.__file__).parent / "weights" / "metrics_shipped.json").read_text())
    fresh = evaluate_shipped()
    for split, per in shipped["test"].items():
        for det, m in per.items():
            for k in ("precision", "recall", "f1", "false_zupt_rate"):
                assert fresh["test"][split][det][k] == pytest.approx(m[k], abs=1e-6), (split, det, k)
        classical = max(per[k]["f1"] for k in ("shoe", "are", "mag", "mv"))
        assert per["lstm"]["f1"] > classical + 0.1 and per["lstm"]["false_zupt_rate"] < 0.002
