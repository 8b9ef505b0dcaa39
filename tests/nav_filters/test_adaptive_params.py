"""Per-row adaptive parameters (:class:`nav_filters.adaptive.params.ParamSpec`, ``AdaptiveLaw.set_params``):
one value (B = 1) and a batch are judged alike, errors name the parameter, and ``set_params`` reports the
changed rows."""
import numpy as np
import pytest

from nav_filters.adaptive.base import AdaptiveLaw
from nav_filters.adaptive.params import ParamSpec
from nav_filters.adaptive.sage_husa import SageHusa
from nav_filters.adaptive.strong_tracking import MeasurementAdaptiveSTKF, StrongTracking

LAWS = (SageHusa, StrongTracking, MeasurementAdaptiveSTKF)
SPECS = tuple({id(p): p for cls in LAWS for p in cls.PARAMS}.values()) + (
    ParamSpec("closed", -1.0, 2.0, True, True, "both ends in"), ParamSpec("open", -1, np.inf, False, False, "open"))


def _probe(spec):
    """Values at, just inside and just outside both bounds, and the non-finite ones."""
    ends = [spec.low, spec.high] if np.isfinite(spec.high) else [spec.low, 1e300]
    near = [np.nextafter(e, d) for e in ends for d in (-np.inf, np.inf)]
    return np.array([*ends, *near, 0.5 * (spec.low + min(spec.high, 10.0)), np.nan, np.inf, -np.inf, -0.0])


def _outcome(fn):
    try:
        return "ok", fn().tobytes()
    except ValueError as exc:
        return "raised", str(exc)


@pytest.mark.parametrize("spec", SPECS, ids=lambda s: s.name)
def test_one_value_and_a_batch_are_judged_alike(spec):
    for v in _probe(spec):
        want_in = bool(spec.inside(np.array([v]))[0])
        assert spec.inside(float(v)) is want_in  # the Python-float test of a single value
        lo_ok = v >= spec.low if spec.low_closed else v > spec.low
        hi_ok = v <= spec.high if spec.high_closed else v < spec.high
        assert want_in == bool(lo_ok and hi_ok)
        one = _outcome(lambda: spec.check(np.array([v]), 1))
        assert one[0] == ("ok" if want_in else "raised")
        # the same value in a batch of valid ones: the same message (the batch path names the bad value)
        ok_value = _probe(spec)[-5]
        batch = _outcome(lambda: spec.check(np.array([ok_value, v, ok_value]), 3))
        assert batch[0] == one[0]
        if one[0] == "raised":
            assert batch[1] == one[1] and spec.name in one[1]
            assert _outcome(lambda: spec.check(float(v)))[1] == one[1]  # a scalar configuration value alike


def test_check_returns_a_fresh_float64_array():
    spec = SageHusa.PARAMS[0]
    given = np.array([0.9])
    got = spec.check(given, 1)
    assert got.dtype == np.float64 and got.shape == (1,) and not np.shares_memory(got, given)
    assert spec.check(0.9, 3).tolist() == [0.9] * 3 and spec.check(0.9).shape == ()
    for bad, match in ((np.array([0.9, 0.9]), r"shape \(1,\)"), (True, "must be a number"), ("x", "must be a number")):
        with pytest.raises(ValueError, match=match):
            spec.check(bad, 1)


@pytest.mark.parametrize("cls", LAWS)
def test_param_names_are_unique(cls):
    names = [p.name for p in cls.PARAMS]
    assert len(set(names)) == len(names) == len(cls(np.eye(3)[None]).params())


@pytest.mark.parametrize("B", [1, 3])
def test_set_params_reports_the_changed_rows(B, monkeypatch):
    calls = []
    law = MeasurementAdaptiveSTKF(np.broadcast_to(np.eye(3), (B, 3, 3)).copy())
    monkeypatch.setattr(law, "_on_param_change", lambda name, rows: calls.append((name, rows.copy())))
    before = law.params()
    new_b = np.where(np.arange(B) == 0, before["b"] * 0.99, before["b"])  # row 0 changed, the others not
    given = new_b.copy()
    law.set_params(b=given, fading_scale=before["fading_scale"])
    assert [c[0] for c in calls] == ["b", "fading_scale"]
    np.testing.assert_array_equal(calls[0][1], np.arange(B) == 0)
    np.testing.assert_array_equal(calls[1][1], np.zeros(B, bool))
    np.testing.assert_array_equal(law.params()["b"], new_b)
    given[:] = 0.5  # the law keeps its own copy
    np.testing.assert_array_equal(law.params()["b"], new_b)
    with pytest.raises(ValueError, match=r"unknown adaptive parameter 'c' for MeasurementAdaptiveSTKF; "
                                         r"known: \['b', 'fading_scale', 'fault_threshold', 'softening'\]"):
        law.set_params(b=0.9, c=1.0)
    with pytest.raises(ValueError, match="softening"):
        law.set_params(b=0.9, softening=np.full(B, np.nan))
    assert len(calls) == 2 and np.array_equal(law.params()["b"], new_b)  # nothing half-applied
    assert isinstance(law, AdaptiveLaw)
