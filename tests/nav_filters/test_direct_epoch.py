"""The navigator's compiled GNSS epoch (``Navigator._direct_gnss_epoch``) against the general sequence of
``update_gnss``: the same bits, the same failure isolation, the same errors, and the general sequence wherever a
precondition fails."""
import numpy as np
import pytest

from envs.episodes import navigator_for, satellite_keys
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world
from nav_filters.constraints import odometer_nhc, stack_measurements, zupt
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


def _run(w, method, epochs=8, poison=None, rate=True, extra=None, **config):
    """(navigator, per-epoch outputs) of ``epochs`` GNSS epochs on ``w``; ``extra(nav, j)``: the epoch's extra
    block."""
    nav = navigator_for(w, method, **config)
    g, keys, k, out = w.gnss, satellite_keys(w.gnss), 0, []
    for j, kk in enumerate(w.epoch_idx[:epochs]):
        nav.propagate_epoch(w.imu.f_b[:, k + 1:kk + 1], w.imu.w_b[:, k + 1:kk + 1], 0.01)
        k = kk
        if poison is not None and j == 3:
            poison(nav)
        res, gdop = nav.update_gnss(g.sat_pos[:, j], g.sat_vel[:, j], g.pr[:, j], g.prr[:, j] if rate else None,
                                    g.pr_sigma[:, j], g.prr_sigma[:, j] if rate else None, g.mask[:, j],
                                    sat_keys=keys[:, j], extra=None if extra is None else extra(nav, j))
        out.append((res.nis, res.n_used, res.innovation, res.innovation_var, res.applied, gdop,
                    nav.time_since_update.copy()))
    return nav, out


def _form_state(form):
    """Every array of a law and its inner form, or of a plain form."""
    if hasattr(form, "inner"):
        return _state(form)
    return {k: v for k, v in vars(form).items() if isinstance(v, np.ndarray)}


def _poison_covariance(nav, row=1):
    """Row ``row``'s covariance made negative definite (its next update's S is not positive definite)."""
    form = getattr(nav.form, "inner", nav.form)
    form.P = form.P.copy()
    form.P[row] = -1e6 * np.eye(N_STATES)


def _assert_same(a, b):
    nav_a, out_a = a
    nav_b, out_b = b
    for name in ("r", "v", "C", "clk", "drift", "bg", "ba", "diverged", "divergence_code", "time_since_update"):
        np.testing.assert_array_equal(getattr(nav_a, name), getattr(nav_b, name), err_msg=name)
    sa, sb = _form_state(nav_a.form), _form_state(nav_b.form)
    assert sa.keys() == sb.keys()
    for name in sa:
        np.testing.assert_array_equal(sa[name], sb[name], err_msg=name)
    for ea, eb in zip(out_a, out_b, strict=True):
        for x, y in zip(ea, eb, strict=True):
            np.testing.assert_array_equal(x, y)


@pytest.mark.parametrize("method", ["sage-husa", "stkf", "ma-stkf", "sage-husa+onestep", "kf", "kf+onestep"])
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


def _aiding(nav, j):
    """Odometer + NHC rows every epoch (row 1 without a speed reading at odd epochs) and, at epochs 2 and 5, ZUPT
    rows on rows 0 and 2 stacked before them."""
    speed = np.linalg.norm(nav.v, axis=1) + 0.05 * np.arange(nav.batch_size)
    if j % 2:
        speed[1] = np.nan
    block = odometer_nhc(nav.v, nav.C, speed, 0.1, 0.05, 0.08)
    if j in (2, 5):
        block = stack_measurements(zupt(nav.v, None, 0.02, np.array([True, False, True])), block)
    return block


@pytest.mark.parametrize("method", ["sage-husa", "stkf", "ma-stkf", "kf"])
def test_compiled_epoch_with_extra_rows_is_the_general_sequence(world, monkeypatch, method):
    """Constraint rows stacked after the GNSS rows (odometer + NHC, ZUPT): the compiled epoch stacks them as
    ``stack_measurements`` does, the same bits."""
    count = _counting(monkeypatch)
    fast = _run(world, method, extra=_aiding, **FAST)
    assert count == {"hits": 8, "misses": 0}
    _general(monkeypatch)
    _assert_same(fast, _run(world, method, extra=_aiding, **FAST))


def test_extra_rows_of_a_parked_row_are_left_out_as_in_the_general_sequence(world, monkeypatch):
    """Row 1 fails at epoch 3 and is parked: its constraint rows are not used afterwards, on either path."""
    poison = _poison_covariance
    count = _counting(monkeypatch)
    general = []
    orig = Navigator._update_checked
    monkeypatch.setattr(Navigator, "_update_checked", lambda self, *a: general.append(1) or orig(self, *a))
    fast = _run(world, "sage-husa", poison=poison, extra=_aiding, **FAST)
    assert count["hits"] == 8 and fast[0].divergence_code.tolist() == [0, REASON_UPDATE, 0]
    assert len(general) == 1  # only the failing epoch needed the general update, the later ones ran compiled
    assert fast[1][-1][1][1] == 0  # n_used of the parked row
    _general(monkeypatch)
    _assert_same(fast, _run(world, "sage-husa", poison=poison, extra=_aiding, **FAST))


def _full_covariance(block):
    dz, H, R, mask = block
    return dz, H, R[:, :, None] * np.eye(R.shape[1]), mask


@pytest.mark.parametrize("extra", [lambda nav, j: _full_covariance(_aiding(nav, j)),
                                   lambda nav, j: tuple(np.asarray(a, np.float32) if a.dtype.kind == "f" else a
                                                        for a in _aiding(nav, j))])
def test_extra_rows_the_compiled_epoch_does_not_take_run_the_general_sequence(world, monkeypatch, extra):
    """A full (B, m_e, m_e) covariance or float32 extra rows: the general sequence, with the same result."""
    count = _counting(monkeypatch)
    got = _run(world, "sage-husa", epochs=3, extra=extra, **FAST)
    assert count == {"hits": 0, "misses": 3}
    _general(monkeypatch)
    _assert_same(got, _run(world, "sage-husa", epochs=3, extra=extra, **FAST))


def test_a_non_finite_extra_row_raises_the_general_sequences_error(world):
    w = world
    nav = navigator_for(w, "sage-husa", **FAST)
    nav.propagate_epoch(w.imu.f_b[:, 1:w.epoch_idx[0] + 1], w.imu.w_b[:, 1:w.epoch_idx[0] + 1], 0.01)
    dz, H, R, mask = _aiding(nav, 0)
    dz = dz.copy()
    dz[2, 1] = np.inf
    before = (nav.r.copy(), nav.form.inner.P.copy())
    g = w.gnss
    with pytest.raises(ValueError, match="dz"):
        nav.update_gnss(g.sat_pos[:, 0], g.sat_vel[:, 0], g.pr[:, 0], g.prr[:, 0], g.pr_sigma[:, 0],
                        g.prr_sigma[:, 0], g.mask[:, 0], sat_keys=satellite_keys(g)[:, 0], extra=(dz, H, R, mask))
    np.testing.assert_array_equal(nav.r, before[0])
    np.testing.assert_array_equal(nav.form.inner.P, before[1])


@pytest.mark.parametrize("method,config", [("svd-kf", FAST), ("kf-huber", FAST), ("kf", dict(exact_transition=False)),
                                           ("sage-husa", dict(exact_transition=False)),
                                           ("sage-husa", dict(fused_update=True)),
                                           ("sage-husa", dict(FAST, dtype="float32"))])
def test_general_sequence_where_a_precondition_fails(world, monkeypatch, method, config):
    """A plain form other than kf, a robust screen, an unfused kf or law, the exact composition, float32: nothing
    to hand the compiled epoch."""
    count = _counting(monkeypatch)
    _run(world, method, epochs=3, **config)
    assert count == {"hits": 0, "misses": 3}


@pytest.mark.parametrize("method", ["sage-husa", "kf"])
def test_a_failing_update_is_isolated_as_in_the_general_sequence(world, monkeypatch, method):
    """Row 1's covariance made negative definite: the compiled epoch's S is not positive definite, the law keeps
    the epoch open (the kf keeps its time update, as after ``predict``) and the general update flags and parks row
    1 alone, as the general sequence does."""
    count = _counting(monkeypatch)
    fast = _run(world, method, poison=_poison_covariance, **FAST)
    assert count["hits"] == 8  # the failing epoch runs on the compiled path and recovers through the general update
    assert fast[0].divergence_code.tolist() == [0, REASON_UPDATE, 0]
    _general(monkeypatch)
    _assert_same(fast, _run(world, method, poison=_poison_covariance, **FAST))


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
