"""The navigator's compiled GNSS epoch (``Navigator._direct_gnss_epoch``) against the general sequence of
``update_gnss``: the same bits, the same failure isolation, the same errors, and the general sequence wherever a
precondition fails."""
import numpy as np
import pytest

from envs.episodes import navigator_for, satellite_keys
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world
from nav_filters.error_model import N_STATES
from nav_filters.navigator import REASON_STATE, REASON_UPDATE, Navigator
from tests.nav_filters.test_compiled_epochs import _state

FAST = dict(exact_transition=False, fused_update=True)


@pytest.fixture(scope="module")
def world():
    return generate_world(get_scenario("noise-burst", duration_s=12.0), [0, 1, 2])


def _general(monkeypatch):
    """Every navigator runs the general sequence."""
    monkeypatch.setattr(Navigator, "_direct_gnss_epoch", lambda self, *a: None)


def _counting(monkeypatch):
    """Counts the epochs the compiled path ran (``hits``) and declined (``misses``)."""
    orig = Navigator._direct_gnss_epoch
    count = {"hits": 0, "misses": 0}

    def wrapped(self, *a):
        out = orig(self, *a)
        count["hits" if out is not None else "misses"] += 1
        return out

    monkeypatch.setattr(Navigator, "_direct_gnss_epoch", wrapped)
    return count


def _run(w, method, epochs=8, poison=None, rate=True, **config):
    """(navigator, per-epoch outputs) of ``epochs`` GNSS epochs on ``w``."""
    nav = navigator_for(w, method, **config)
    g, keys, k, out = w.gnss, satellite_keys(w.gnss), 0, []
    for j, kk in enumerate(w.epoch_idx[:epochs]):
        nav.propagate_epoch(w.imu.f_b[:, k + 1:kk + 1], w.imu.w_b[:, k + 1:kk + 1], 0.01)
        k = kk
        if poison is not None and j == 3:
            poison(nav)
        res, gdop = nav.update_gnss(g.sat_pos[:, j], g.sat_vel[:, j], g.pr[:, j], g.prr[:, j] if rate else None,
                                    g.pr_sigma[:, j], g.prr_sigma[:, j] if rate else None, g.mask[:, j],
                                    sat_keys=keys[:, j])
        out.append((res.nis, res.n_used, res.innovation, res.innovation_var, res.applied, gdop,
                    nav.time_since_update.copy()))
    return nav, out


def _assert_same(a, b):
    nav_a, out_a = a
    nav_b, out_b = b
    for name in ("r", "v", "C", "clk", "drift", "bg", "ba", "diverged", "divergence_code", "time_since_update"):
        np.testing.assert_array_equal(getattr(nav_a, name), getattr(nav_b, name), err_msg=name)
    sa, sb = _state(nav_a.form), _state(nav_b.form)
    assert sa.keys() == sb.keys()
    for name in sa:
        np.testing.assert_array_equal(sa[name], sb[name], err_msg=name)
    for ea, eb in zip(out_a, out_b, strict=True):
        for x, y in zip(ea, eb, strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("method", ["sage-husa", "stkf", "ma-stkf", "sage-husa+onestep"])
def test_compiled_epoch_is_the_general_sequence_bit_for_bit(world, monkeypatch, method):
    count = _counting(monkeypatch)
    fast = _run(world, method, **FAST)
    assert count == {"hits": 8, "misses": 0}
    _general(monkeypatch)
    _assert_same(fast, _run(world, method, **FAST))


def test_compiled_epoch_without_rates_is_the_general_sequence(world, monkeypatch):
    count = _counting(monkeypatch)
    fast = _run(world, "sage-husa", rate=False, **FAST)
    assert count["hits"] == 8
    _general(monkeypatch)
    _assert_same(fast, _run(world, "sage-husa", rate=False, **FAST))


@pytest.mark.parametrize("method,config", [("kf", FAST), ("sage-husa", dict(exact_transition=False)),
                                           ("sage-husa", dict(fused_update=True)),
                                           ("sage-husa", dict(FAST, dtype="float32"))])
def test_general_sequence_where_a_precondition_fails(world, monkeypatch, method, config):
    """A plain form, an unfused law, the exact composition, float32: nothing to hand the compiled epoch."""
    count = _counting(monkeypatch)
    _run(world, method, epochs=3, **config)
    assert count == {"hits": 0, "misses": 3}


def test_a_failing_update_is_isolated_as_in_the_general_sequence(world, monkeypatch):
    """Row 1's covariance made negative definite: the compiled epoch's S is not positive definite, the law keeps
    the epoch open and the general update flags and parks row 1 alone, as the general sequence does."""
    def poison(nav):
        nav.form.inner.P = nav.form.inner.P.copy()
        nav.form.inner.P[1] = -1e6 * np.eye(N_STATES)

    count = _counting(monkeypatch)
    fast = _run(world, "sage-husa", poison=poison, **FAST)
    assert count["hits"] == 8  # the failing epoch runs on the compiled path and recovers through the general update
    assert fast[0].divergence_code.tolist() == [0, REASON_UPDATE, 0]
    _general(monkeypatch)
    _assert_same(fast, _run(world, "sage-husa", poison=poison, **FAST))


def test_a_non_finite_state_leaves_the_epoch_to_the_general_sequence(world, monkeypatch):
    def poison(nav):
        nav.v = nav.v.copy()
        nav.v[2, 0] = np.nan

    count = _counting(monkeypatch)
    fast = _run(world, "stkf", poison=poison, **FAST)
    assert count == {"hits": 7, "misses": 1}
    assert fast[0].divergence_code.tolist() == [0, 0, REASON_STATE]
    _general(monkeypatch)
    _assert_same(fast, _run(world, "stkf", poison=poison, **FAST))


@pytest.mark.parametrize("field,value,match", [("pr", np.nan, "dz"), ("pr_sigma", 0.0, "variance"),
                                               ("keys", 10 ** 6, "sat_keys")])
def test_bad_input_raises_the_general_sequences_error(world, field, value, match):
    w = world
    nav = navigator_for(w, "sage-husa", **FAST)
    nav.propagate_epoch(w.imu.f_b[:, 1:w.epoch_idx[0] + 1], w.imu.w_b[:, 1:w.epoch_idx[0] + 1], 0.01)
    g = w.gnss
    args = {"pr": g.pr[:, 0].copy(), "pr_sigma": g.pr_sigma[:, 0].copy(), "keys": satellite_keys(g)[:, 0]}
    used = np.argmax(g.mask[1, 0])
    args[field][1, used] = value
    before = (nav.r.copy(), nav.form.inner.P.copy())
    with pytest.raises(ValueError, match=match):
        nav.update_gnss(g.sat_pos[:, 0], g.sat_vel[:, 0], args["pr"], g.prr[:, 0], args["pr_sigma"],
                        g.prr_sigma[:, 0], g.mask[:, 0], sat_keys=args["keys"])
    np.testing.assert_array_equal(nav.r, before[0])  # nothing changed before the error
    np.testing.assert_array_equal(nav.form.inner.P, before[1])
