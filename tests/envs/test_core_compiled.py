"""The env core's compiled kernels agree with their numpy references: the observation frame
(``TuningCore._frame_reference``), the action check (``_clip_if_finite``), the step's scoring
(``_score_reference``) and position errors (``_errors_reference``)."""
import math

import numpy as np
import pytest

from envs.config import EnvConfig
from envs.core import (LOG_REWARD_OFFSET_M, TuningCore, _clip_if_finite, _errors_kernel, _errors_reference,
                       _score_kernel, _score_reference)
from envs.gnss_ins_env import MASTKF_PARAMS, SAGE_HUSA_PARAMS
from nav_filters.kernels import PARALLEL_MIN_BATCH


@pytest.mark.parametrize("zupt,B", [("none", 3), ("truth", 3), ("none", PARALLEL_MIN_BATCH + 2)])  # + the parallel one
def test_frame_kernel_matches_reference(zupt, B, monkeypatch):
    core = TuningCore(EnvConfig(scenario="urban", episode_length_s=20.0, zupt=zupt), SAGE_HUSA_PARAMS, B)
    core.reset_rows(np.arange(B), list(range(B)))
    checked = []

    def compare(res, zflag):
        ema, prev = core.ema.copy(), core.prev_nsat.copy()
        out = TuningCore._frame(core, res, zflag)
        assert out.base is not None and np.shares_memory(out, core.frames[:, -1])  # written in place
        out = out.copy()
        ema_new, core.ema[:] = core.ema.copy(), ema
        prev_new, core.prev_nsat = core.prev_nsat.copy(), prev
        ref = core._frame_reference(res, zflag)
        np.testing.assert_array_equal(prev_new, core.prev_nsat)
        np.testing.assert_array_equal(prev_new, core._last_mask.sum(1))  # the kernel's satellite counts
        assert out.dtype == ref.dtype == np.float32 and out.shape == ref.shape
        # float32 frames: log10/sqrt and the reduction order differ by a last bit at most
        np.testing.assert_allclose(out, ref, rtol=2e-7, atol=1e-7)
        np.testing.assert_allclose(ema_new, core.ema, rtol=1e-13)
        return out

    def both(res, zflag):
        state = core.ema.copy(), core.prev_nsat.copy()
        out = compare(res, zflag)
        saved = core._last_mask.copy()
        core._last_mask[0] = False  # an outage row: no NIS, outage flag, EMA kept
        compare(res, zflag)
        core._last_mask[:] = saved
        core.ema[:], core.prev_nsat = state  # the step goes on from the real epoch's frame
        new = TuningCore._frame(core, res, zflag)
        np.testing.assert_array_equal(new, out)
        checked.append(out)
        return new

    monkeypatch.setattr(core, "_frame", both)
    rng = np.random.default_rng(0)
    for _ in range(18):  # past the 10-epoch warm-up: the per-satellite scales move
        core.step(rng.uniform(-1, 1, (B, 1)))
    assert len(checked) == 18
    k = core.k
    late = np.array(checked[12:])
    assert late[:, :, k + 17].max() > 0  # some satellite's R scale above its reported variance
    assert np.all(late[:, :, k + 13] >= late[:, :, k + 14])  # max >= 90th percentile


def test_frame_is_written_into_the_history_and_stacks(monkeypatch):
    """``history > 1``: the kernel writes the newest frame into a strided view; the older frames shift."""
    core = TuningCore(EnvConfig(scenario="noise-burst", episode_length_s=10.0, history=3, method="ma-stkf"),
                       MASTKF_PARAMS, 2)
    core.reset_rows(np.arange(2), [5, 6])
    rng = np.random.default_rng(1)
    prev = core.frames.copy()
    for _ in range(4):
        res = core.step(rng.uniform(-1, 1, (2, 2)))
        np.testing.assert_array_equal(core.frames[:, :-1], prev[:, 1:])
        np.testing.assert_array_equal(res.obs, core.frames.reshape(2, -1))
        np.testing.assert_array_equal(res.obs[:, -core.frame_dim:][:, :2], core.action.astype(np.float32))
        np.testing.assert_array_equal(res.info["n_sats"], core._last_mask.sum(1))
        assert res.info["n_sats"].dtype == np.int64 and not np.shares_memory(res.info["n_sats"], core.prev_nsat)
        prev = core.frames.copy()


def _bits(x):
    return x.dtype, x.shape, x.tobytes()


@pytest.mark.parametrize("layout", ["C", "F", "strided"])
def test_clip_if_finite_matches_numpy(layout):
    rng = np.random.default_rng(2)
    a = rng.uniform(-3, 3, (64, 3))
    a[::5] = rng.choice([-1.0, 1.0, -0.0, 0.0, 1e300, -1e300, 5e-324], size=a[::5].shape)

    def laid_out(x):  # a new array of x's values in the layout under test
        return {"C": np.ascontiguousarray, "F": np.asfortranarray, "strided": lambda y: np.repeat(y, 2, 1)[:, ::2]}[
            layout](x.copy())

    want = np.minimum(np.maximum(a, -1.0), 1.0)
    got = laid_out(a)
    assert _clip_if_finite(got)
    got = np.ascontiguousarray(got)
    assert _bits(got) == _bits(want)
    for bad in (np.nan, np.inf, -np.inf):
        b = a.copy()
        b[7, 1] = bad
        untouched = b.copy()
        b = laid_out(b)
        assert not _clip_if_finite(b)
        np.testing.assert_array_equal(b, untouched)  # left as it was: the error message shows the raw values


@pytest.mark.parametrize("mode", ["horizontal", "3d", "log", "advantage"])
@pytest.mark.parametrize("B", [1, 3, 200])
def test_score_kernel_matches_reference(mode, B):
    """Bit for bit, on rows that diverge every way (navigator, NaN/inf error, above the bound, at the bound)."""
    rng = np.random.default_rng(B)
    bound = 50.0
    penalty = -math.log(bound + LOG_REWARD_OFFSET_M) if mode == "log" else -bound
    M = 7
    t0 = rng.integers(0, M, B)
    sq0, mx0 = rng.uniform(0, 1e3, B), rng.uniform(0, 60, B)
    for trial in range(20):
        h = rng.exponential(20.0, B)
        e3 = h * rng.uniform(1.0, 1.5, B)
        ref = rng.exponential(20.0, B)
        pick = rng.random(B)
        h[pick < 0.05] = np.nan
        h[(pick > 0.05) & (pick < 0.1)] = np.inf
        h[(pick > 0.1) & (pick < 0.15)] = bound
        ref[rng.random(B) < 0.1] = np.nan
        ref[rng.random(B) < 0.1] = np.inf
        nav_div = rng.random(B) < 0.1
        src = {"horizontal": h, "3d": e3, "log": np.log(h + LOG_REWARD_OFFSET_M), "advantage": ref}[mode]
        args = (h, src, mode == "advantage", nav_div, bound, penalty)
        t1, sq1, mx1 = t0.copy(), sq0.copy(), mx0.copy()
        div, rew, trunc = np.empty(B, bool), np.empty(B), np.empty(B, bool)
        n = _score_kernel(*args, t1, M, sq1, mx1, div, rew, trunc)
        t2, sq2, mx2 = t0.copy(), sq0.copy(), mx0.copy()
        with np.errstate(all="ignore"):
            want = _score_reference(*args, t2, M, sq2, mx2)
        for got_x, want_x in zip((div, rew, trunc, t1, sq1, mx1), (*want, t2, sq2, mx2)):
            assert _bits(got_x) == _bits(want_x)
        assert n == int(want[0].sum())


@pytest.mark.parametrize("B", [1, 5])
def test_errors_kernel_matches_reference(B):
    """Horizontal and 3D errors of rows at different epochs (one past the last: clamped to it), against the numpy
    specification (to round-off: the rotation may be contracted to fused multiply-adds), and a known case."""
    rng = np.random.default_rng(B)
    M = 6
    r = rng.normal(0.0, 1e6, (B, 3))
    truth_r = r[:, None, :] + rng.normal(0.0, 30.0, (B, M, 3))
    q, _ = np.linalg.qr(rng.normal(size=(B, M, 3, 3)))  # rotations (orthonormal)
    j = rng.integers(0, M + 1, B)
    h, e3 = np.empty(B), np.empty(B)
    _errors_kernel(r, truth_r, q, j, M - 1, h, e3)
    h_ref, e3_ref = _errors_reference(r, truth_r, q, j, M - 1)
    np.testing.assert_allclose(h, h_ref, rtol=1e-14)
    np.testing.assert_allclose(e3, e3_ref, rtol=1e-14)
    k = np.minimum(j, M - 1)
    np.testing.assert_allclose(e3, np.linalg.norm(r - truth_r[np.arange(B), k], axis=1), rtol=1e-12)  # rotation-free
    # NED axes: an error of (3, 4, 12) m north, east, down gives 5 m horizontal and 13 m in 3D
    C = np.broadcast_to(np.eye(3), (B, M, 3, 3)).copy()
    truth = r[:, None, :] - np.array([3.0, 4.0, 12.0])
    _errors_kernel(r, np.broadcast_to(truth, (B, M, 3)).copy(), C, j, M - 1, h, e3)
    np.testing.assert_allclose(h, 5.0, rtol=1e-9)
    np.testing.assert_allclose(e3, 13.0, rtol=1e-9)


def test_default_parameters_are_to_value_of_the_default_actions():
    """The reference navigator's parameters (``_set_params(nav)``): fresh copies equal to ``to_value`` of the
    default actions, as passing those actions gives."""
    core = TuningCore(EnvConfig(scenario="noise-burst", episode_length_s=5.0, reward="advantage", method="ma-stkf"),
                       MASTKF_PARAMS, 3)
    core.reset_rows(np.arange(3), [1, 2, 3])
    got = core._set_params(core.ref)
    want = core._set_params(core.ref, np.broadcast_to(core.default_action, (3, core.k)))
    assert list(got) == list(want)
    for name in got:
        assert _bits(got[name]) == _bits(want[name])
        assert not np.shares_memory(got[name], core._default_values[name])
