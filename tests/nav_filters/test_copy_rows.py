"""copy_rows: a copied row continues bit for bit like its source row (exact branching inside a batch).

A navigator of three rows on three different worlds runs a few epochs, rows are copied with overlapping
``dst`` / ``src`` (row 0 <- row 1, row 2 <- row 0), and every row then continues on the data of the world
it now carries. A reference navigator that never copied runs each world on its own row. The copied rows
must equal the reference rows of their source worlds exactly: nominal state, covariance, adaptive state
and per-row parameters.
"""
import numpy as np
import pytest

from envs.episodes import navigator_for
from envs.worlds import make_world
from nav_filters.registry import FORMS
from nav_filters.rows import check_row_pairs

SEEDS = [11, 12, 13]
PERM = np.array([1, 1, 0])      # after the copy, row i carries world PERM[i]
DST, SRC = [0, 2], [1, 0]       # overlapping: row 0 is both written and read


@pytest.fixture(scope="module")
def world():
    return make_world("noise-burst", SEEDS, duration_s=30.0)


def _run(nav, world, j0, j1, rows, mid_epoch_hook=None):
    """Epochs j0..j1-1 of ``world``, row b fed the data of world row ``rows[b]``; with ``mid_epoch_hook``, the
    IMU samples of epoch j0 are each row's own (the rows before the copy) and the hook runs before its update."""
    ep, g = world.epoch_idx, world.gnss
    dt = 1.0 / world.scenario.imu_rate_hz
    for j in range(j0, j1):
        a = (ep[j - 1] if j > 0 else 0) + 1
        imu_rows = np.arange(len(rows)) if (mid_epoch_hook is not None and j == j0) else rows
        nav.propagate_epoch(world.imu.f_b[imu_rows, a:ep[j] + 1], world.imu.w_b[imu_rows, a:ep[j] + 1], dt)
        if mid_epoch_hook is not None and j == j0:
            mid_epoch_hook()
        nav.update_gnss(g.sat_pos[rows, j], g.sat_vel[rows, j], g.pr[rows, j], g.prr[rows, j], g.pr_sigma[rows, j],
                        g.prr_sigma[rows, j], g.mask[rows, j])


def _state(nav, b):
    out = {k: getattr(nav, k)[b].copy() for k in ("r", "v", "C", "clk", "drift", "bg", "ba", "diverged",
                                                    "time_since_update")}
    out["P"] = np.asarray(nav.covariance)[b].copy()
    f = nav.form
    if hasattr(f, "adaptive_state"):
        out.update({f"state:{k}": v[b] for k, v in f.adaptive_state().items()})
        out.update({f"param:{k}": v[b] for k, v in f.params().items()})
    return out


def _assert_same(a, b, what):
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=f"{what}: {k}")


@pytest.mark.parametrize("method", sorted(FORMS))
@pytest.mark.parametrize("mid_epoch", [False, True])
def test_copied_rows_continue_bit_identically(world, method, mid_epoch):
    if mid_epoch and method not in ("kf", "sage-husa", "ma-stkf"):
        pytest.skip("the mid-epoch copy (pending transition) is checked on three forms")
    nav, ref = navigator_for(world, method), navigator_for(world, method)
    if getattr(nav.form, "PARAMS", ()):  # different per-row parameters: the copy must carry them
        name = nav.form.PARAMS[0].name
        vals = {"b": [0.95, 0.99, 0.999], "softening": [0.5, 1.0, 2.0], "rho": [0.8, 0.9, 0.99]}.get(name)
        if vals is not None:
            nav.form.set_params(**{name: np.array(vals)})
            ref.form.set_params(**{name: np.array(vals)})
    own = np.arange(3)
    n0, n1 = 12, 18  # warm-up of the Sage-Husa law is 10 epochs: it adapts before the copy
    _run(nav, world, 0, n0, own)
    _run(ref, world, 0, n0 + n1, own)
    if mid_epoch:  # copy between the IMU propagation and the update: the pending transition is copied too
        _run(nav, world, n0, n0 + n1, PERM, mid_epoch_hook=lambda: nav.copy_rows(DST, SRC))
    else:
        nav.copy_rows(DST, SRC)
        _run(nav, world, n0, n0 + n1, PERM)
    for b in range(3):
        _assert_same(_state(nav, b), _state(ref, PERM[b]), f"{method} row {b}")


@pytest.mark.parametrize("method", ["kf", "sage-husa"])
def test_copied_rows_continue_bit_identically_with_averaged_transition(world, method):
    """exact_transition=False: the pending integrals of F and Q are per-row state copied mid-epoch."""
    nav, ref = (navigator_for(world, method, exact_transition=False) for _ in range(2))
    own = np.arange(3)
    n0, n1 = 12, 6
    _run(nav, world, 0, n0, own)
    _run(ref, world, 0, n0 + n1, own)
    _run(nav, world, n0, n0 + n1, PERM, mid_epoch_hook=lambda: nav.copy_rows(DST, SRC))
    for b in range(3):
        _assert_same(_state(nav, b), _state(ref, PERM[b]), f"{method} row {b}")


def test_copy_without_continuing_is_the_source_row(world):
    nav = navigator_for(world, "sage-husa")
    _run(nav, world, 0, 12, np.arange(3))
    before = [_state(nav, b) for b in range(3)]
    nav.copy_rows([2, 1], [0, 2])  # row 1 gets row 2's state *before* row 2 is overwritten
    _assert_same(_state(nav, 2), before[0], "row 2")
    _assert_same(_state(nav, 1), before[2], "row 1")
    _assert_same(_state(nav, 0), before[0], "row 0")


def test_copy_rows_leaves_shared_arrays_and_snapshots_alone(world):
    """Copy-on-write: an array object held elsewhere (a snapshot of the state) is never written."""
    nav = navigator_for(world, "kf")
    _run(nav, world, 0, 3, np.arange(3))
    P, r = nav.form.P, nav.r
    P0, r0 = P.copy(), r.copy()
    nav.copy_rows([0], [1])
    np.testing.assert_array_equal(P, P0)
    np.testing.assert_array_equal(r, r0)
    np.testing.assert_array_equal(nav.form.P[0], P0[1])


def test_pending_epoch_context_is_copied_or_refused(world):
    nav = navigator_for(world, "stkf")
    _run(nav, world, 0, 3, np.arange(3))
    law = nav.form
    law.predict(np.broadcast_to(np.eye(17), (3, 17, 17)), np.zeros((3, 17, 17)))
    law._ctx = law._open_epoch()  # what an update that failed on every row leaves behind
    prior = law._ctx.prior.copy()
    law.copy_rows([2], [0])
    np.testing.assert_array_equal(law._ctx.prior[2], prior[0])
    law._ctx.Q = [[0.0]]  # a field that is not a per-row array cannot be copied row-wise
    with pytest.raises(ValueError, match="pending epoch context of StrongTracking.*'Q'"):
        law.copy_rows([1], [0])


@pytest.mark.parametrize("dst, src, msg", [
    ([0, 1], [1], "same length"),
    ([3], [0], "dst has a row index outside"),
    ([0], [-1], "src has a row index outside"),
    ([0.5], [1], "dst must be a 1-D array of integer"),
    ([[0]], [[1]], "dst must be a 1-D array of integer"),
])
def test_bad_row_indices(dst, src, msg):
    with pytest.raises(ValueError, match=msg):
        check_row_pairs(dst, src, 3)
