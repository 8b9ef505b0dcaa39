"""The fused path of the SVD forms (issue 37: ``svd-kf``, ``svd-srkf`` and the laws around them, ``svd-akf``,
``svd-asrkf``) against the numpy recursion it compiles (:mod:`nav_filters.forms.svd_rows`).

* :func:`~nav_filters.forms.svd_rows.svd_right` (Golub-Kahan-Reinsch, right singular vectors only) gives LAPACK's
  singular values and a factorization of ``A^T A``, also for rank-deficient and graded arrays;
* the forms' fused ``update`` and ``predicted_update`` equal the numpy ``predict`` + ``_update_reference`` (float64
  to round-off, float32 to its precision) for every kind of process noise the numpy path factors (diagonal, full,
  zero rows, rank-deficient: Cholesky and eigen factors), diagonal and correlated R, masked rows, a batch row
  without measurements, per-state fading, serial and parallel kernels; the kernel decided every row (the numpy
  update is never called);
* what the kernel does not decide (an indefinite Q, a non-finite factor) goes to the numpy path, which raises as
  before and commits nothing, and in the navigator the failing row alone is flagged;
* ``svd-akf`` and ``svd-asrkf`` take the compiled path in the navigator's fused mode and run the same episodes as
  without it.
"""
import dataclasses

import numpy as np
import pytest

from envs.episodes import navigator_for, run_episodes
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world
from nav_filters.forms import SvdKalmanFilter, SvdSquareRootKF
from nav_filters.forms.svd_rows import svd_right
from nav_filters.kernels import PARALLEL_MIN_BATCH, padded_width
from tests.nav_filters.test_fused_update import _problem
from tests.nav_filters.test_svd_forms import random_psd_q

N = 17
FORMS = [SvdKalmanFilter, SvdSquareRootKF]
TOL = {np.float64: 1e-10, np.float32: 1e-4}
"""Normwise relative tolerance (max |fused - numpy| / max |numpy|); measured 1e-14 and 2e-6."""


def _svd(A, dtype):
    nr, nc = A.shape
    X = np.zeros((nc, nr + 3), dtype)
    X[:, :nr] = A.T
    d, f = np.empty(nc, dtype), np.empty(nc, dtype)
    Vt = np.full((nc, padded_width(nc)), np.nan, dtype)
    ok = svd_right(X, nr, d, f, Vt, np.empty((nc, nc), dtype), np.empty(nr + nc, dtype), np.empty(nc, np.int64),
                   float(np.finfo(dtype).eps))
    return ok, d, Vt


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_own_svd_equals_lapack(dtype):
    rng = np.random.default_rng(0)
    tol = 50 * np.finfo(dtype).eps
    for nr, nc in [(34, 17), (37, 20), (17, 17), (9, 3), (3, 2), (1, 1)]:
        for kind in ("graded", "zero column", "equal columns", "plain"):
            A = rng.normal(size=(nr, nc))
            if kind == "graded":
                A *= 10 ** rng.uniform(-3, 3, nc)
            elif kind == "zero column":
                A[:, nc // 2] = 0
            elif kind == "equal columns" and nc > 1:
                A[:, 1] = A[:, 0]
            A = A.astype(dtype)
            ok, d, Vt = _svd(A, dtype)
            A64 = A.astype(np.float64)
            s = np.linalg.svd(A64, compute_uv=False)
            assert ok
            np.testing.assert_allclose(d, s, rtol=0, atol=tol * s[0], err_msg=f"{nr}x{nc} {kind}")
            assert np.all(Vt[:, nc:] == 0)
            V = Vt[:, :nc].astype(np.float64)
            np.testing.assert_allclose(V @ V.T, np.eye(nc), rtol=0, atol=tol)
            np.testing.assert_allclose((V.T * d.astype(np.float64) ** 2) @ V, A64.T @ A64, rtol=0,
                                       atol=tol * s[0] ** 2)
    A[0, 0] = np.nan
    assert not _svd(A, dtype)[0]


def test_own_svd_keeps_the_small_singular_values_of_graded_pre_arrays():
    """``svd-srkf``'s information pre-array ``[G ; D^-1]`` has columns scaled over six decades: in float32 (against
    float64 LAPACK, a reference 1e9 times more precise) its small singular values (the large posterior variances)
    keep their relative accuracy: measured 25 eps (LAPACK's sgesdd: 0.5 eps; 1e-4 = 800 eps without the column
    ordering and the QR first)."""
    dtype = np.float32
    rng = np.random.default_rng(1)
    worst = 0.0
    for _ in range(50):
        A = np.vstack([rng.normal(size=(16, N)) * rng.uniform(0.1, 3, N), np.diag(10 ** rng.uniform(-2.5, 4, N))])
        A = A.astype(dtype)
        s = np.linalg.svd(A.astype(np.float64), compute_uv=False)
        ok, d, _ = _svd(A, dtype)
        assert ok
        worst = max(worst, np.max(np.abs(d - s) / s))
    assert worst < 100 * np.finfo(dtype).eps


def _compare(fast, ref, res_f, res_r, tol, what):
    def close(a, b, name):
        a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
        np.testing.assert_allclose(a, b, rtol=0, atol=tol * max(np.abs(b).max(), 1e-300), err_msg=f"{what}: {name}")

    close(fast.covariance, ref.covariance, "P")
    close(fast.x, ref.x, "x")
    close(fast.last_correction, ref.last_correction, "K r")
    for name in ("nis", "innovation", "innovation_var", "n_used", "applied"):
        close(getattr(res_f, name), getattr(res_r, name), name)


@pytest.mark.parametrize("form_cls", FORMS, ids=lambda c: c.name)
@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("B, correlated", [(5, False), (5, True), (PARALLEL_MIN_BATCH + 6, False)])
def test_fused_form_equals_the_numpy_recursion(form_cls, dtype, B, correlated):
    P, x, H, R, dz, mask, Phi, Q, fade = _problem(B, seed=2, correlated=correlated)
    R = R if correlated else np.diagonal(R, axis1=1, axis2=2)
    ref, fast = form_cls(P, x0=x, dtype=dtype), form_cls(P, x0=x, dtype=dtype)
    assert fast.set_fused(True) and fast.fused and not ref.fused

    def numpy_update(*args):
        raise AssertionError("the fused path left a row to the numpy update")

    fast._update_reference = numpy_update
    rng = np.random.default_rng(3)
    tol = TOL[dtype]
    _compare(fast, ref, fast.update(dz, H, R, mask), ref.update(dz, H, R, mask), tol, "update")
    for kind in ("full-pd", "full-zero-rows", "rank-deficient", "diag", "diag-broadcast", "zero"):
        Qk = random_psd_q(rng, B, N, kind)
        for fk in (fade, None):
            res = [f.predicted_update(Phi, Qk, dz, H, R, mask, fade=fk) for f in (fast, ref)]
            _compare(fast, ref, *res, tol, f"predicted_update, Q {kind}, fade {fk is not None}")
    res = [f.predicted_update(Phi, Q, dz, H, R, mask, fade=fade) for f in (fast, ref)]
    _compare(fast, ref, *res, tol, "predicted_update, navigator-like Q")
    with pytest.raises(AssertionError):  # the check sees a wrong result: the other form's update
        other = (SvdSquareRootKF if form_cls is SvdKalmanFilter else SvdKalmanFilter)(P, x0=x, dtype=dtype)
        _compare(other, ref, other.update(dz, 0.5 * H, R, mask), ref.update(dz, H, R, mask), tol, "wrong")


@pytest.mark.parametrize("form_cls", FORMS, ids=lambda c: c.name)
def test_fused_form_leaves_what_it_does_not_decide_to_numpy(form_cls):
    """An indefinite Q raises the numpy path's ValueError naming Q; a non-finite factor its LinAlgError; neither
    commits anything (an adaptive law retries a failed epoch)."""
    P, x, H, R, dz, mask, Phi, Q, fade = _problem(6, seed=4)
    R = np.diagonal(R, axis1=1, axis2=2)
    f = form_cls(P, x0=x)
    f.set_fused(True)
    V, _ = np.linalg.qr(np.random.default_rng(5).normal(size=(N, N)))
    lam = np.full(N, 1e-3)
    lam[4] = -1e-5
    bad_U = f.U.copy()
    bad_U[2, 3, 3] = np.nan
    for Qb, U, err, match in (((V * lam) @ V.T, f.U, ValueError, "Q"), (np.diag(lam), f.U, ValueError, "Q"),
                              (Q, bad_U, np.linalg.LinAlgError, None)):
        f.U = U
        before = [a.copy() for a in (f.U, f.D, f.x)]
        with pytest.raises(err, match=match or None):
            f.predicted_update(Phi, np.broadcast_to(Qb, (6, N, N)), dz, H, R, mask, fade=fade)
        for a, b in zip((f.U, f.D, f.x), before):
            np.testing.assert_array_equal(a, b)


@pytest.fixture(scope="module")
def short_world():
    """Three rows of the seed paper's drive (``seed000-sim``), its first 20 s."""
    return generate_world(dataclasses.replace(get_scenario("seed000-sim"), duration_s=20.0), [0, 1, 2])


@pytest.mark.parametrize("method", ["svd-akf", "svd-asrkf"])
@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_svd_laws_take_the_compiled_path_and_run_the_same_episodes(short_world, method, dtype):
    """The Sage-Husa law around the SVD forms, averaged transition, with and without the fused path: the inner
    form reports the compiled path, and the episodes agree: float64 to 1e-7 m and NIS to 1e-6 (measured 2e-9 m,
    7e-9); float32 within its precision (measured: svd-akf 2.4 mm and NIS 7 %, where the numpy float32 run itself
    is 2.3 mm and 3 % from float64; svd-asrkf 6e-5 m and NIS 1e-3)."""
    nav = navigator_for(short_world, method, dtype, exact_transition=False, fused_update=True)
    assert nav.form.fused and nav.form.inner.fused and nav.form.inner.HAS_FUSED
    assert not navigator_for(short_world, method, dtype, exact_transition=False).form.inner.fused
    base = run_episodes(short_world, method, dtype, exact_transition=False)
    fast = run_episodes(short_world, method, dtype, exact_transition=False, fused_update=True)
    assert not fast.diverged.any() and not base.diverged.any()
    atol, rtol = (1e-7, 1e-6) if dtype == "float64" else (1e-2, 0.15)
    np.testing.assert_allclose(fast.pos_err_ned, base.pos_err_ned, rtol=0, atol=atol)
    np.testing.assert_allclose(fast.nis, base.nis, rtol=rtol, atol=rtol)


@pytest.mark.parametrize("method", ["svd-akf", "svd-asrkf"])
def test_a_failing_row_is_isolated_on_the_fused_path(method):
    """A row whose SVD factors are not finite: the kernel leaves the batch to numpy, whose SVD raises; the navigator
    flags that row alone (the update failed) and the others end bit for bit where a clean fused run ends (the
    kernel's rows are independent)."""
    from nav_filters.navigator import REASON_UPDATE
    from tests.nav_filters.test_failure_isolation import _run

    w = generate_world("seed000-sim", [0, 1, 2])
    kw = dict(exact_transition=False, fused_update=True)
    clean = _run(navigator_for(w, method, **kw), w, 8)

    def poison(nav):
        nav.flush_prediction()
        inner = nav.form.inner
        inner.U = inner.U.copy()
        inner.U[1, 2, 2] = np.nan

    nav = _run(navigator_for(w, method, **kw), w, 8, poison)
    assert nav.divergence_code.tolist() == [0, REASON_UPDATE, 0]
    for name in ("r", "v", "C", "clk", "drift"):
        np.testing.assert_array_equal(getattr(nav, name)[[0, 2]], getattr(clean, name)[[0, 2]], err_msg=name)
    np.testing.assert_array_equal(nav.covariance[[0, 2]], clean.covariance[[0, 2]])
