"""The env core's compiled kernels agree with their numpy references: the observation frame
(``TuningCore._frame_reference``) and the action check (``_clip_if_finite``)."""
import numpy as np
import pytest

from envs.config import EnvConfig
from envs.core import TuningCore, _clip_if_finite
from envs.gnss_ins_env import SAGE_HUSA_PARAMS


@pytest.mark.parametrize("zupt", ["none", "truth"])
def test_frame_kernel_matches_reference(zupt, monkeypatch):
    core = TuningCore(EnvConfig(scenario="urban", episode_length_s=20.0, zupt=zupt), SAGE_HUSA_PARAMS, 3)
    core.reset_rows(np.arange(3), [0, 1, 2])
    checked = []

    def compare(res, zflag):
        ema, prev = core.ema.copy(), core.prev_nsat.copy()
        out = TuningCore._frame(core, res, zflag)
        ema_new, core.ema[:] = core.ema.copy(), ema
        prev_new, core.prev_nsat = core.prev_nsat, prev
        ref = core._frame_reference(res, zflag)
        np.testing.assert_array_equal(prev_new, core.prev_nsat)
        assert out.dtype == ref.dtype == np.float32 and out.shape == ref.shape
        # float32 frames: log10/sqrt and the reduction order differ by a last bit at most
        np.testing.assert_allclose(out, ref, rtol=2e-7, atol=1e-7)
        np.testing.assert_allclose(ema_new, core.ema, rtol=1e-13)
        return out

    def both(res, zflag):
        out = compare(res, zflag)
        saved = core._last_mask.copy()
        core._last_mask[0] = False  # an outage row: no NIS, outage flag, EMA kept
        compare(res, zflag)
        core._last_mask[:] = saved
        checked.append(out)
        return out

    monkeypatch.setattr(core, "_frame", both)
    rng = np.random.default_rng(0)
    for _ in range(18):  # past the 10-epoch warm-up: the per-satellite scales move
        core.step(rng.uniform(-1, 1, (3, 1)))
    assert len(checked) == 18
    k = core.k
    late = np.array(checked[12:])
    assert late[:, :, k + 17].max() > 0  # some satellite's R scale above its reported variance
    assert np.all(late[:, :, k + 13] >= late[:, :, k + 14])  # max >= 90th percentile


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
