"""The action -> parameter maps of the envs (:class:`envs.config.ParamSpec`): the single-value path of
``to_value`` (one env, Python floats) gives the bits of the array path, and ``to_action`` inverts it."""
import numpy as np
import pytest

from envs.config import ParamSpec
from envs.gnss_ins_env import MASTKF_PARAMS, SAGE_HUSA_PARAMS, STKF_PARAMS

SPECS = SAGE_HUSA_PARAMS + STKF_PARAMS + MASTKF_PARAMS + (ParamSpec("x", -2, 3, "linear", 0),)
# 2001 actions beyond both ends, the clip points and their neighbours, signed zeros, infinities and NaN
ACTIONS = np.r_[np.linspace(-1.2, 1.2, 2001), np.nextafter(1.0, [0.0, 2.0]), np.nextafter(-1.0, [0.0, -2.0]),
                -0.0, np.inf, -np.inf, np.nan]


def _bits(x):
    return np.asarray(x).tobytes()


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: f"{s.name}-{s.map}")
def test_one_value_gives_the_bits_of_the_array_path(spec):
    whole = spec.to_value(ACTIONS)  # the array path (numpy calls on all values at once)
    assert whole.dtype == np.float64 and whole.shape == ACTIONS.shape
    col = spec.to_value(np.stack([ACTIONS, ACTIONS], 1)[:, 1])  # a strided column, as the env core passes
    assert _bits(col) == _bits(whole)
    for i, a in enumerate(ACTIONS):
        one = spec.to_value(ACTIONS[i:i + 1])  # (1,): a single env's step
        assert type(one) is np.ndarray and one.shape == (1,) and one.dtype == np.float64
        assert _bits(one) == _bits(whole[i:i + 1]), (a, one, whole[i])
        scalar = spec.to_value(float(a))
        assert type(scalar) is np.float64 and _bits(scalar) == _bits(whole[i])
    assert spec.to_value(np.array([[0.25]])).shape == (1, 1)
    assert spec.to_value(np.zeros(0)).shape == (0,)
    assert np.isnan(whole[-1]) and whole[-3] == spec.to_value(1.0) and whole[-2] == spec.to_value(-1.0)  # +-inf clip
    assert spec.to_value(-1.0) == pytest.approx(spec.low, rel=1e-12)
    assert spec.to_value(1.0) == pytest.approx(spec.high, rel=1e-12)


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: f"{s.name}-{s.map}")
def test_to_action_inverts_to_value(spec):
    values = np.linspace(spec.low, spec.high, 101)
    act = spec.to_action(values)
    assert act.shape == (101,) and np.all(np.diff(act) > 0)
    np.testing.assert_allclose(act[[0, -1]], [-1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(spec.to_value(act), values, rtol=1e-12, atol=1e-12 * abs(spec.high))
    for i, v in enumerate(values):
        assert _bits(spec.to_action(v)) == _bits(act[i])
    assert spec.to_value(spec.to_action(spec.default)) == pytest.approx(spec.default, rel=1e-12)
