"""The compiled plans of the strong-tracking laws (:mod:`nav_filters.adaptive.strong_tracking_rows`) against
their numpy specification (``_plan_reference``), bit for bit.

* :func:`nav_filters.kernels.pairwise_sum` is numpy's summation order: the same bits as ``numpy.sum`` for 0 to
  600 numbers and a few longer vectors (the halving above 128), at any offset;
* the scalar helpers propagate NaN as ``np.clip`` / ``np.maximum`` / ``np.minimum`` do;
* on every epoch of real episodes (simulated worlds: NLOS, outages, a noise burst, the seed 003 drive with its
  odometer), ``stkf`` and ``ma-stkf`` on the fused path plan exactly what the numpy lines plan: fading factors,
  the scaled R, the mask of a rejected epoch, every pending statistic; float64 and float32, serial and parallel
  (B >= 64) kernels, and the configurations the kernels cover (STKF's printed ``fading_noise``, an uncapped
  fading, MA-STKF's printed ``N_k`` noise); the others keep the numpy lines.
"""
import numpy as np
import pytest

import nav_filters.registry as registry
from envs.episodes import run_episodes
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world
from nav_filters.adaptive import law_factory
from nav_filters.adaptive.strong_tracking import MeasurementAdaptiveSTKF, StrongTracking
from nav_filters.adaptive.strong_tracking_rows import _clip, _max_nan, _min_nan
from nav_filters.kernels import PARALLEL_MIN_BATCH, pairwise_sum


def test_pairwise_sum_is_numpys_sum():
    rng = np.random.default_rng(1)
    for m in list(range(0, 601)) + [1000, 1025, 4099]:
        x = rng.normal(size=(2, m)) * 10.0 ** rng.integers(-8, 8, size=(2, m))
        ref = x.sum(1)
        for b in range(2):
            got = pairwise_sum(x[b], 0, m)
            assert np.float64(got).tobytes() == ref[b].tobytes(), (m, b, got, ref[b])
        y = np.concatenate([rng.normal(size=5), x[0], rng.normal(size=3)])  # at an offset
        assert np.float64(pairwise_sum(y, 5, m)).tobytes() == ref[0].tobytes(), m
    # a naive left-to-right sum differs (so the test can tell the orders apart)
    x = rng.normal(size=200) * 10.0 ** rng.integers(-8, 8, size=200)
    naive = 0.0
    for v in x:
        naive += v
    assert naive != x.sum()


def test_scalar_helpers_propagate_nan_like_numpy():
    vals = [np.nan, np.inf, -np.inf, 0.0, -0.0, 0.5, 1.0, 2.0, 1e300]
    for v in vals:
        for lo, hi in ((1.0, 10.0), (0.1, 1e4)):
            np.testing.assert_array_equal(_clip(v, lo, hi), np.clip(v, lo, hi))
        for w in vals:
            np.testing.assert_array_equal(_max_nan(v, w), np.maximum(v, w))
            np.testing.assert_array_equal(_min_nan(v, w), np.minimum(v, w))


def _bits_equal(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


@pytest.fixture
def compare_plans(monkeypatch):
    """Wrap both laws' ``_plan``: every call also runs ``_plan_reference`` on the same state and records whether
    the two plans are the same bits (``calls``, ``compiled`` (calls that took the kernel), ``mismatches``).

    The laws run their Python sequence (``_plan``, update, ``_commit``), not the compiled epoch that calls the
    same plan kernel inside (the two are the same bits: tests/nav_filters/test_compiled_epochs.py)."""
    import nav_filters.adaptive.strong_tracking as st
    for cls in (StrongTracking, MeasurementAdaptiveSTKF):
        monkeypatch.setattr(cls, "_has_compiled_epoch", lambda self: False)
    log = {"calls": 0, "compiled": 0, "mismatches": []}
    kernels = []
    for name in ("_st_plan_serial", "_st_plan_parallel", "_ma_plan_serial", "_ma_plan_parallel"):
        orig_k = getattr(st, name)
        monkeypatch.setattr(st, name, (lambda k, n: lambda *a: (kernels.append(n), k(*a))[1])(orig_k, name))

    def wrap(cls):
        orig = cls._plan

        def both(self, r, H, R, mask, ctx):
            ref = self._plan_reference(r, H, R, mask, ctx)
            n = len(kernels)
            got = orig(self, r, H, R, mask, ctx)
            log["calls"] += 1
            log["compiled"] += len(kernels) > n
            pairs = [("fade", got.fade, ref.fade), ("R", got.R, ref.R), ("mask", got.mask, ref.mask)]
            if set(got.pending) != set(ref.pending):
                log["mismatches"].append(("pending keys", sorted(got.pending), sorted(ref.pending)))
            pairs += [(k, got.pending.get(k), v) for k, v in ref.pending.items()]
            log["mismatches"] += [name for name, a, b in pairs if not _bits_equal(a, b)]
            return got
        monkeypatch.setattr(cls, "_plan", both)

    wrap(StrongTracking)
    wrap(MeasurementAdaptiveSTKF)
    log["kernels"] = kernels
    return log


@pytest.mark.parametrize("method", ["stkf", "ma-stkf"])
@pytest.mark.parametrize("scenario,B,dtype", [("urban", 3, "float64"), ("noise-burst", 2, "float32"),
                                              ("seed003-sim", 2, "float64"),
                                              ("urban-transition", PARALLEL_MIN_BATCH + 3, "float64"),
                                              ("regime-switch", PARALLEL_MIN_BATCH + 1, "float32")])
def test_compiled_plan_is_the_numpy_plan(compare_plans, method, scenario, B, dtype):
    w = generate_world(get_scenario(scenario, duration_s=60.0), list(range(B)))
    log = run_episodes(w, method, dtype=dtype, exact_transition=False, fused_update=True)
    assert compare_plans["calls"] >= 50 and compare_plans["compiled"] == compare_plans["calls"]
    assert compare_plans["mismatches"] == []
    parallel = B >= PARALLEL_MIN_BATCH
    assert all(k.endswith("_parallel") == parallel for k in compare_plans["kernels"])
    assert np.isfinite(log.pos_err_ned).all()


@pytest.mark.parametrize("law,config,compiled", [
    (StrongTracking, dict(fading_noise="reported"), True),
    (StrongTracking, dict(fading_cap=np.inf), True),
    (MeasurementAdaptiveSTKF, dict(fading_uses_alpha=False, fading_cap=np.inf, warmup_epochs=0), True),
    (MeasurementAdaptiveSTKF, dict(max_consecutive_rejections=0, fault_threshold=1.05), True),
    (MeasurementAdaptiveSTKF, dict(fading_noise="reported"), False),
    (MeasurementAdaptiveSTKF, dict(r_mode="satellite"), False),
])
def test_configurations(compare_plans, monkeypatch, law, config, compiled):
    """The kernels cover the configurations they claim (the same bits); the others run the numpy lines."""
    method = law.name
    monkeypatch.setitem(registry.FORMS, method, law_factory(law, **config))
    w = generate_world(get_scenario("urban", duration_s=40.0), [4, 5])
    run_episodes(w, method, exact_transition=False, fused_update=True)
    assert compare_plans["calls"] >= 30
    assert compare_plans["compiled"] == (compare_plans["calls"] if compiled else 0)
    assert compare_plans["mismatches"] == []


def test_rejections_happen_in_the_compared_episodes(compare_plans, monkeypatch):
    """The fault test and its streak limit are exercised: in a noise burst MA-STKF rejects epochs."""
    faults = []
    orig = MeasurementAdaptiveSTKF._commit

    def commit(self, plan, *a):
        faults.append(plan.pending["fault"].copy())
        return orig(self, plan, *a)
    monkeypatch.setattr(MeasurementAdaptiveSTKF, "_commit", commit)
    w = generate_world(get_scenario("noise-burst", duration_s=120.0), [0, 1, 2])
    run_episodes(w, "ma-stkf", exact_transition=False, fused_update=True)
    assert np.concatenate(faults).any()
    assert compare_plans["mismatches"] == []


@pytest.mark.parametrize("method", ["stkf", "ma-stkf"])
@pytest.mark.parametrize("B,dtype", [(4, np.float64), (PARALLEL_MIN_BATCH, np.float32)])
def test_synthetic_drive_with_second_updates(compare_plans, method, B, dtype):
    """A law driven directly: GNSS-like sparse rows, random masks (a row without any measurement), noise bursts,
    and every third epoch a second update without a transition (no fading: ``pending`` False)."""
    N, m = 17, 14
    rng = np.random.default_rng(7)
    A = rng.normal(size=(B, N, N))
    law = registry.make_form(method, A @ A.mT / N + np.eye(N), dtype=dtype)
    law.set_fused(True)
    for k in range(40):
        Phi = np.eye(N) + 0.02 * rng.normal(size=(B, N, N))
        law.predict(Phi, 0.01 * np.broadcast_to(np.eye(N), (B, N, N)))
        for _ in range(2 if k % 3 == 0 else 1):
            H = np.zeros((B, m, N))
            for i in range(m):
                cols = [6, 7, 8, 15] if i % 2 == 0 else [3, 4, 5, 16]
                H[:, i, cols] = rng.normal(size=(B, 4))
            R = np.zeros((B, m, m))
            R[:, np.arange(m), np.arange(m)] = rng.uniform(0.5, 2.0, (B, m))
            noise = np.where(rng.random((B, 1)) < 0.2, 10.0, 1.0)  # bursts: faults, large alpha
            dz = rng.normal(size=(B, m)) * noise
            mask = rng.random((B, m)) < 0.8
            mask[k % B] = False
            law.update(dz, H, R, mask)
    assert compare_plans["calls"] == 54 and compare_plans["compiled"] == 54
    assert compare_plans["mismatches"] == []
