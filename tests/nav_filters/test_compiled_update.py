"""The compiled (numba) update path agrees with its numpy reference functions.

Each compiled kernel of the measurement update implements the same equations as
a numpy function that stays the readable specification. Tolerances: float64
agreement to a few ulps of the largest magnitude involved (the kernels sum in a
different order than BLAS/numpy reductions: relative 1e-12 is ~5000 ulps of
headroom, far below any physical effect); float32 to 1e-4 relative (float32
epsilon 6e-8 times the conditioning of the 17-state products); masking,
dtypes, shapes and error messages exactly.
"""
import copy

import numpy as np
import pytest

import nav_filters.forms  # noqa: F401  (registers the adaptive laws before they are imported below)
from earth import geodetic_to_ecef
from earth.ranging import range_and_rate, range_rate_pair
from nav_filters.adaptive.base import EpochContext, UpdatePlan
from nav_filters.adaptive.innovation import innovation_traces, innovation_traces_reference
from nav_filters.adaptive.sage_husa import SageHusa, SageHusaConfig
from nav_filters.forms import KalmanFilter
from nav_filters.forms.base import prepare_measurement, prepare_measurement_reference
from nav_filters.measurements import dop, dop_reference, gnss_innovations, gnss_innovations_reference

N = 17


def _geometry(rng, B, C):
    r = geodetic_to_ecef(rng.uniform(0.2, 1.0, B), rng.uniform(-1, 1, B), rng.uniform(0, 500, B))
    v = rng.normal(0, 10, (B, 3))
    up = r / np.linalg.norm(r, axis=1, keepdims=True)
    d = rng.normal(size=(B, C, 3)) + 2.0 * up[:, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return r, v, r[:, None, :] + 2.2e7 * d, rng.normal(0, 2500, (B, C, 3))


def _gnss_H(rng, B, m_half):
    H = np.zeros((B, 2 * m_half, N))
    H[:, :m_half, 6:9] = rng.normal(size=(B, m_half, 3))
    H[:, :m_half, 15] = 1.0
    H[:, m_half:, 3:6] = rng.normal(size=(B, m_half, 3))
    H[:, m_half:, 16] = 1.0
    return H


def spd(rng, B, n, scale=1.0):
    A = rng.normal(size=(B, n, n))
    return scale * (A @ A.mT + n * np.eye(n))


def rel(a, b):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300)


def test_range_rate_pair_matches_range_and_rate():
    rng = np.random.default_rng(0)
    r, v, sat, sv = _geometry(rng, 3, 5)
    rho, rho_dot, u = range_and_rate(sat, sv, r, v)
    uu = np.empty(3)
    for b in range(3):
        for j in range(5):
            p, pd = range_rate_pair(*sat[b, j], *sv[b, j], *r[b], *v[b], 3, uu)
            # same operations in the same order: equal up to libm's last bit of cos/sin (1e-9 m of 2e7 m)
            assert p == pytest.approx(rho[b, j], rel=1e-15, abs=1e-9)
            assert pd == pytest.approx(rho_dot[b, j], rel=1e-13, abs=1e-9)
            np.testing.assert_allclose(uu, u[b, j], rtol=0, atol=1e-15)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("rate", ["rate", "no-rate", "prr-none"])
def test_gnss_innovations_compiled_matches_reference(dtype, rate):
    rng = np.random.default_rng(1)
    B, C = 4, 9
    r, v, sat, sv = _geometry(rng, B, C)
    mask = rng.random((B, C)) > 0.3
    sat[~mask] = 0.0  # padded channels carry anything
    clk, drift = rng.normal(0, 100, B), rng.normal(0, 1, B)
    pr = np.linalg.norm(sat - r[:, None], axis=-1) + rng.normal(0, 5, (B, C))
    prr = None if rate == "prr-none" else rng.normal(0, 100, (B, C))
    pv, prv = rng.uniform(1, 10, (B, C)), (None if prr is None else rng.uniform(0.01, 0.1, (B, C)))
    args = (r, v, clk, drift, sat, sv, pr, prr, pv, prv, mask)
    kw = dict(use_rate=rate == "rate", dtype=dtype)
    got, ref = gnss_innovations(*args, **kw), gnss_innovations_reference(*args, **kw)
    for name, a, b in zip(("dz", "H", "R", "row_mask", "u"), got, ref):
        assert a.dtype == b.dtype and a.shape == b.shape, name
        if a.dtype == bool:
            np.testing.assert_array_equal(a, b)
        else:  # dz: 1e-9 m absolute covers a last-bit difference of libm cos/sin on a 2e7 m range
            np.testing.assert_allclose(a, b, rtol=1e-14 if dtype == np.float64 else 1e-7, atol=1e-9, err_msg=name)


def test_dop_compiled_matches_reference():
    rng = np.random.default_rng(2)
    r, v, sat, sv = _geometry(rng, 6, 8)
    _, _, u = range_and_rate(sat, sv, r, v)
    mask = rng.random((6, 8)) > 0.2
    mask[0, 3:] = False  # 3 satellites: no fix
    mask[1] = True
    g, g_ref = dop(u, mask), dop_reference(u, mask)
    np.testing.assert_array_equal(np.isinf(g), np.isinf(g_ref))
    assert np.isinf(g[0]) and np.isfinite(g[1:]).all()
    np.testing.assert_allclose(g[1:], g_ref[1:], rtol=1e-12)  # Cholesky vs LU inverse of a 4x4


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("full_r", [False, True])
def test_prepare_measurement_compiled_is_identical(dtype, full_r):
    rng = np.random.default_rng(3)
    B, m = 5, 12
    dz, H = rng.normal(size=(B, m)), rng.normal(size=(B, m, N))
    R = spd(rng, B, m) if full_r else rng.uniform(0.5, 2.0, (B, m))
    mask = rng.random((B, m)) < 0.7
    dz[~mask], H[~mask] = np.nan, np.inf  # garbage on masked rows is neutralized
    for a, b in zip(prepare_measurement(dz, H, R, mask, dtype), prepare_measurement_reference(dz, H, R, mask, dtype)):
        assert a.dtype == b.dtype
        np.testing.assert_array_equal(a, b)  # pure copies and selections: bit-identical


@pytest.mark.parametrize("bad", ["dz", "H", "R", "R<=0"])
def test_prepare_measurement_errors_are_the_references(bad):
    B, m = 3, 4
    dz, H, R, mask = np.ones((B, m)), np.ones((B, m, N)), np.ones((B, m)), np.ones((B, m), bool)
    if bad == "dz":
        dz[1, 2] = np.nan
    elif bad == "H":
        H[2, 1, 5] = np.inf
    elif bad == "R":
        R[0, 3] = np.nan
    else:
        R[0, 3] = -1.0
    msgs = []
    for f in (prepare_measurement, prepare_measurement_reference):
        with pytest.raises(ValueError) as e:
            f(dz, H, R, mask, np.float64)
        msgs.append(str(e.value))
    assert msgs[0] == msgs[1]


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("structure,B", [("gnss", 6), ("dense", 6), ("full-R", 6), ("gnss", 70)])  # 70: parallel
def test_joseph_update_matches_reference(dtype, structure, B):
    rng = np.random.default_rng(4)
    m = 14
    P0, x0 = spd(rng, B, N), rng.normal(size=(B, N))
    H = _gnss_H(rng, B, m // 2) if structure == "gnss" else rng.normal(size=(B, m, N)) * (rng.random((B, m, N)) < 0.5)
    R = spd(rng, B, m, 0.1) if structure == "full-R" else rng.uniform(0.5, 2.0, (B, m))
    mask = rng.random((B, m)) < 0.8
    mask[0] = False  # a row without measurements
    a, b = KalmanFilter(P0, x0=x0, dtype=dtype), KalmanFilter(P0, x0=x0, dtype=dtype)
    args = prepare_measurement(rng.normal(size=(B, m)), H, R, mask, a.dtype)
    ra, rb = a._update(*args), b._update_reference(*args)
    tol = 1e-12 if dtype == np.float64 else 1e-4
    for got, ref in ((a.P, b.P), (a.x, b.x), (ra.nis, rb.nis), (ra.innovation, rb.innovation),
                     (ra.innovation_var, rb.innovation_var)):
        assert got.dtype == ref.dtype == np.dtype(dtype) and got.shape == ref.shape
        assert rel(got, ref) < tol
    np.testing.assert_array_equal(a.P, a.P.mT)
    np.testing.assert_array_equal(ra.n_used, rb.n_used)
    np.testing.assert_array_equal(ra.applied, rb.applied)
    np.testing.assert_array_equal(a.P[0], np.asarray(P0[0], dtype))  # no measurement: P unchanged


def test_joseph_update_raises_like_cholesky_on_non_pd_innovation_covariance():
    rng = np.random.default_rng(5)
    kf = KalmanFilter(spd(rng, 2, N))
    H = np.ones((2, 1, N))
    P_before = kf.P.copy()
    with pytest.raises(np.linalg.LinAlgError):
        kf._update(np.zeros((2, 1)), H, np.full((2, 1, 1), -1e9), np.ones((2, 1), bool))
    np.testing.assert_array_equal(kf.P, P_before)  # nothing committed


@pytest.mark.parametrize("epoch_end", [False, True])
def test_feedback_compiled_matches_reference(epoch_end):
    """The compiled feedback against its numpy specification; ``epoch_end``: the form a small batch's compiled GNSS
    epoch calls (:func:`~nav_filters.navigator._feedback_clear_dop`), which also restarts ``time_since_update``
    on the rows with a used channel and returns the GDOP, and flags the same rows."""
    from envs.episodes import navigator_for
    from envs.sim.world import generate_world
    nav = navigator_for(generate_world("open-sky", [0, 1, 2, 3, 4]), "sage-husa")
    rng = np.random.default_rng(6)
    dx = rng.normal(size=(5, N)) * np.r_[[1e-3, 1e-5, 1e-6], [0.1] * 3, [1.0] * 3, [1e-6] * 6, 10.0, 1.0]
    dx[1, :3] = [0.3, -0.2, 0.1]  # large angle: Rodrigues, not the series
    dx[3, 5] = np.nan  # becomes non-finite: flagged and parked
    nav.diverged[2] = True  # frozen row: unchanged
    nav.time_since_update[:] = 3.0
    ref = copy.deepcopy(nav)
    if epoch_end:
        u = rng.normal(size=(5, 9, 3))
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        mask = rng.random((5, 9)) < 0.7
        mask[4] = False  # an outage: its time keeps counting
        gdop = nav._feedback(dx.copy(), mask, u)
        np.testing.assert_array_equal(gdop, dop(u, mask))  # the general sequence's call
        np.testing.assert_array_equal(nav.time_since_update, [0.0, 0.0, 0.0, 0.0, 3.0])
    else:
        assert nav._feedback(dx.copy()) is None
    ref._feedback_reference(dx.copy())
    for k in ("r", "v", "bg", "ba", "clk", "drift", "diverged", "divergence_code"):
        np.testing.assert_array_equal(getattr(nav, k), getattr(ref, k), err_msg=k)
    np.testing.assert_allclose(nav.C, ref.C, rtol=0, atol=1e-15)  # 3x3 products: last-bit differences
    assert nav.diverged[3] and nav.diverged[2] and not nav.diverged[[0, 1, 4]].any()


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_innovation_traces_compiled_matches_reference(dtype):
    rng = np.random.default_rng(7)
    B, m = 5, 12
    H = _gnss_H(rng, B, m // 2)
    H[:, 2] = rng.normal(size=(B, N))  # a dense row
    mask = rng.random((B, m)) < 0.8
    H[~mask] = 0
    dz = np.where(mask, rng.normal(size=(B, m)), 0).astype(dtype)
    P, Q, R = (spd(rng, B, k).astype(dtype) for k in (N, N, m))
    for q in (Q, None):
        a = innovation_traces(dz, H.astype(dtype), P, q, R, mask)
        b = innovation_traces_reference(dz, H.astype(dtype), P, q, R, mask)
        for k in ("energy", "tr_m", "tr_q", "tr_r"):
            assert getattr(a, k).dtype == getattr(b, k).dtype
            np.testing.assert_allclose(getattr(a, k), getattr(b, k), rtol=1e-12 if dtype == np.float64 else 1e-5)
        np.testing.assert_array_equal(a.n_used, b.n_used)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("groups", ["inferred", "callable"])
def test_sage_husa_r_law_compiled_matches_reference(dtype, groups):
    rng = np.random.default_rng(8)
    B, m = 6, 16
    cfg = SageHusaConfig(warmup_epochs=0, groups=None if groups == "inferred" else (lambda H, mask: np.arange(
        H.shape[1])[None, :].repeat(H.shape[0], 0) % 3))
    law = SageHusa(spd(rng, B, N, 0.01), dtype=dtype, config=cfg)
    law._r_scale = rng.uniform(0.5, 2.0, (B, 3))
    H = _gnss_H(rng, B, m // 2)
    H[:, 3] = rng.normal(size=(B, N))  # an 'other' row
    mask = rng.random((B, m)) < 0.8
    for full_r, pending in ((False, True), (True, True), (False, False)):
        R = spd(rng, B, m) if full_r else rng.uniform(0.5, 2.0, (B, m))
        dz, Hp, Rp, mk = prepare_measurement(rng.normal(0, 3, (B, m)), H, R, mask, law.dtype)
        Q, prior = spd(rng, B, N, 1e-4).astype(dtype), spd(rng, B, N, 0.01).astype(dtype)
        ctx = EpochContext(pending=pending, Phi=None, Q=Q if pending else None, prior=prior)
        plan = law._plan(dz, Hp, Rp, mk, ctx)
        s_ref, R_ref = law._r_scales_reference(dz, Hp, Rp, mk, ctx, plan.pending["d"], plan.pending["active"])
        s = plan.pending["r_scale"]
        assert ((s > law.config.r_scale_min) & (s < law.config.r_scale_max)).any()  # not all clipped
        assert plan.R.dtype == R_ref.dtype
        tol = 1e-12 if dtype == np.float64 else 1e-5
        assert rel(s, s_ref) < tol and rel(plan.R, R_ref) < tol


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("diagonal,B", [(False, 6), (True, 6), (False, 70)])  # B = 70: the parallel kernel
@pytest.mark.parametrize("fused", [False, True])  # True: the own eigen-decomposition (fused_update)
@pytest.mark.parametrize("q_lower", ["floor", "nominal"])
def test_sage_husa_q_law_compiled_matches_reference(dtype, diagonal, B, fused, q_lower):
    rng = np.random.default_rng(9)
    law = SageHusa(spd(rng, B, N), dtype=dtype, config=SageHusaConfig(diagonal_q=diagonal, q_lower=q_lower))
    assert law.set_fused(fused) is fused
    jumps = 0
    for it in range(4):
        prior = spd(rng, B, N).astype(dtype)
        law.inner.P = (prior + spd(rng, B, N, 0.1 * (1 + 20 * (it == 2)))).astype(dtype)  # a jump at it = 2
        ctx = EpochContext(pending=True, Phi=None, Q=spd(rng, B, N, 1e-3).astype(dtype), prior=prior)
        rows = rng.random(B) < 0.8
        d, dx = rng.uniform(0.01, 0.5, B), rng.normal(size=(B, N)).astype(dtype)
        law._step = rng.integers(1, 20, B)
        ref = copy.deepcopy(law)
        law._adapt_q(rows, d, ctx, dx)
        ref._adapt_q_reference(rows, d, ctx, dx)
        jumps += int((ref._b_used != ref._params["b"]).sum())
        tol = 1e-12 if dtype == np.float64 else 1e-5
        for k in ("_Q", "_Q_raw", "_q_ref", "_e_prev", "_b_used") + (("_Q_nom",) if q_lower == "nominal" else ()):
            assert getattr(law, k).dtype == getattr(ref, k).dtype
            assert rel(getattr(law, k), getattr(ref, k)) < tol, k
        np.testing.assert_array_equal(law._q_init, ref._q_init)
    assert jumps > 0  # the eq 24 branch was exercised


@pytest.mark.parametrize("warmup", [0, 3])
def test_sage_husa_epoch_rows_and_bookkeeping_compiled_are_the_numpy_bits(monkeypatch, warmup):
    """The fused path's row flags and weights (``_epoch_rows``: rows with a measurement, past the warm-up, the
    eq 21-23 weight at the frozen count, b = 1's limit) and its commit bookkeeping (``_count_rows``: the rows
    adapting Q, b_used, the counts) are the numpy lines' bits (the weights to the rounding of a power), with and
    without a pending transition."""
    B, m = 40, 6
    rng = np.random.default_rng(4)
    laws = {}
    for fused in (False, True):
        law = SageHusa(spd(rng, B, N), config=SageHusaConfig(warmup_epochs=warmup, d_freeze_tol=1e-3))
        law.set_fused(fused)
        laws[fused] = law
    b = np.concatenate([[1.0, 1.0, 0.5], 1.0 - 10.0 ** rng.uniform(-6, -0.5, B - 3)])
    for law in laws.values():
        law.set_params(b=b)
    calls = {False: [], True: []}
    for fused, law in laws.items():
        monkeypatch.setattr(law, "_adapt_q", lambda rows, d, ctx, dx, f=fused: calls[f].append((rows.copy(), d)))
    for it in range(6):
        mask = rng.random((B, m)) < 0.6
        mask[it] = False  # a row without measurements
        seen, step = rng.integers(0, 6, B), rng.integers(0, 5000, B)
        d_prev, b_used = rng.uniform(0, 1, B), rng.uniform(0.5, 1, B)
        for law in laws.values():
            law._seen, law._step, law._d, law._b_used = seen.copy(), step.copy(), d_prev.copy(), b_used.copy()
        got, ref = laws[True]._epoch_rows(mask), laws[False]._epoch_rows(mask)
        for a, r in zip(got[:2], ref[:2]):
            assert a.dtype == r.dtype and a.tobytes() == r.tobytes()
        # the weights to the rounding of b^(j+1): numpy's power runs its own SIMD code where the CPU has AVX-512,
        # which rounds differently from the C library's pow the kernel calls (an ulp apart in some cases), and
        # 1 - b^(j+1) amplifies that ulp by up to 5e5 for b = 1 - 1e-6
        assert got[2].dtype == ref[2].dtype
        np.testing.assert_allclose(got[2], ref[2], rtol=1e-9, atol=0)
        has, active, d = ref
        assert (laws[True]._jcap < step + 1).any() and (~active).any() and active.any()  # frozen, idle, active
        pending = it % 2 == 0
        plan = UpdatePlan(fade=np.ones(B), R=None, mask=mask, pending={"d": d, "has": has, "active": active})
        ctx = EpochContext(pending=pending, Phi=None, Q=None, prior=None)
        for law in laws.values():
            law._commit(plan, ctx, None, None, mask, None)
        for k in ("_b_used", "_step", "_seen", "_d", "_epoch"):
            a, r = getattr(laws[True], k), getattr(laws[False], k)
            assert a.dtype == r.dtype and a.tobytes() == r.tobytes(), k
        assert [c[0].tobytes() for c in calls[True]] == [c[0].tobytes() for c in calls[False]]
    assert len(calls[False]) == 3  # Q adapts on the epochs with a pending transition only
