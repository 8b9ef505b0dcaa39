"""The compiled epoch kernel implements the same equations as the numpy reference functions."""
import numpy as np
import pytest

from earth.wgs84 import gravity_ecef
from nav_filters import kernels as K
from nav_filters.propagation import propagate_epoch
from nav_filters.error_model import system_matrix
from nav_filters.ins import _earth_rate_matrices_np, mechanize


def _setup(B, n, seed=0):
    from envs.sim.world import generate_world
    w = generate_world("urban", list(range(seed, seed + B)))
    st = dict(r=w.init.r_e.copy(), v=w.init.v_e.copy(), C=w.init.C_eb.copy())
    rng = np.random.default_rng(seed)
    bg, ba = rng.normal(0, 1e-5, (B, 3)), rng.normal(0, 1e-2, (B, 3))
    f = np.ascontiguousarray(w.imu.f_b[:, 1:n + 1])
    ww = np.ascontiguousarray(w.imu.w_b[:, 1:n + 1])
    return st, bg, ba, f, ww


def _run_kernel(st, bg, ba, f, w, h, qg, qa, qd, kg, ka, exact, integrate=False):
    B = f.shape[0]
    r, v, C = st["r"].copy(), st["v"].copy(), st["C"].copy()
    clk, drift = np.zeros(B), np.full(B, 2.0)
    Cz, P, QH, Qh = _earth_rate_matrices_np(h)
    Phi = np.zeros((B, 17, 17)) if integrate else np.broadcast_to(np.eye(17), (B, 17, 17)).copy()
    Q = np.zeros((B, 17, 17))
    propagate_epoch(r, v, C, bg, ba, clk, drift, f, w, h, P, QH, Qh, Cz, qg, qa, qd, kg, ka, Phi, Q, exact,
                    False, K.F_NONZERO, integrate)
    return r, v, C, clk, Phi, Q


@pytest.mark.parametrize("B", [2, 70])  # serial and parallel variants
def test_kernel_matches_numpy_reference(B):
    n, h = 50, 0.01
    st, bg, ba, f, w = _setup(B, n)
    qg, qa = np.array([1e-8, 2e-8, 3e-8]), np.array([1e-4, 1e-4, 2e-4])
    qd = np.r_[qg, qa, np.zeros(3), np.full(6, 1e-12), 0.01, 0.04]
    r, v, C, clk, Phi, Q = _run_kernel(st, bg, ba, f, w, h, qg, qa, qd, -1 / 300, -1 / 600, True)
    r2, v2, C2 = st["r"].copy(), st["v"].copy(), st["C"].copy()
    Phi2 = np.broadcast_to(np.eye(17), (B, 17, 17)).copy()
    Q2 = np.zeros((B, 17, 17))
    Q1 = np.zeros((B, 17, 17))
    F_int = np.zeros((B, 17, 17))
    for k in range(n):
        fc, wc = f[:, k] - ba, w[:, k] - bg
        F_int += h * system_matrix(C2, fc, r2, 300.0, 600.0)
        Ph = np.eye(17) + h * system_matrix(C2, fc, r2, 300.0, 600.0)
        Qi = np.zeros((B, 17, 17))
        Qi[:, :3, :3] = C2 @ np.diag(qg) @ C2.mT * h
        Qi[:, 3:6, 3:6] = C2 @ np.diag(qa) @ C2.mT * h
        Qi[:, np.arange(6, 17), np.arange(6, 17)] += qd[6:] * h
        Phi2 = Ph @ Phi2
        Q2 = Ph @ Q2 @ Ph.mT + Qi
        Q1 = Q1 + Qi
        r2, v2, C2 = mechanize(r2, v2, C2, fc, wc, h)
    np.testing.assert_allclose(r, r2, rtol=0, atol=1e-8)
    np.testing.assert_allclose(v, v2, rtol=0, atol=1e-10)
    np.testing.assert_allclose(C, C2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(clk, 2.0 * n * h, rtol=1e-12)
    np.testing.assert_allclose(Phi, Phi2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Q, Q2, rtol=1e-10, atol=1e-22)
    # seed 001 one-step: same Phi, Q summed without propagation (differs from the exact Q)
    _, _, _, _, Phi1, Qs = _run_kernel(st, bg, ba, f, w, h, qg, qa, qd, -1 / 300, -1 / 600, False)
    np.testing.assert_allclose(Phi1, Phi2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(Qs, Q1, rtol=1e-10, atol=1e-22)
    assert np.abs(Qs - Q2).max() > 1e-6 * np.abs(Q2).max()
    # averaged dynamics (integrate): the integral of F and the summed Q; the mechanization is bit for bit the same
    ri, vi, Ci, clki, F_acc, Qi = _run_kernel(st, bg, ba, f, w, h, qg, qa, qd, -1 / 300, -1 / 600, False, True)
    for a, b in ((ri, r), (vi, v), (Ci, C), (clki, clk)):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(F_acc, F_int, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(Qi, Q1, rtol=1e-10, atol=1e-22)
    with pytest.raises(ValueError, match="integrate"):
        _run_kernel(st, bg, ba, f, w, h, qg, qa, qd, -1 / 300, -1 / 600, True, True)


def test_kernel_gravity_matches_earth():
    rng = np.random.default_rng(3)
    r = rng.normal(size=(20, 3)) * 6.4e6
    for x in r:
        np.testing.assert_allclose(K._gravity(x[0], x[1], x[2]), gravity_ecef(x), rtol=1e-13)


def test_F_nonzero_pattern_covers_system_matrix():
    st, bg, ba, f, w = _setup(3, 2)
    F = system_matrix(st["C"], f[:, 0], st["r"], 300.0, 300.0)
    pattern = np.zeros((17, 17), bool)
    pattern[K.F_NONZERO[:, 0], K.F_NONZERO[:, 1]] = True
    assert np.all(F[:, ~pattern] == 0)
    Fk = np.zeros((17, 17))
    K._fill_F(Fk, st["C"][0], f[0, 0], st["r"][0], -1 / 300, -1 / 300)
    np.testing.assert_allclose(Fk, F[0], rtol=1e-14, atol=1e-20)


@pytest.mark.parametrize("B", [1, 5, 70])
@pytest.mark.parametrize("dtypes", [("float64", "float64"), ("float32", "float32"), ("float32", "float64")])
def test_scale_symmetric_matches_numpy_bit_for_bit(B, dtypes):
    """The compiled ``D R D`` equals the numpy specification bit for bit (serial below 64 rows, parallel
    above), with and without the unit diagonal on masked rows, and is not the unscaled R."""
    from nav_filters.kernels import scale_symmetric, scale_symmetric_reference
    rng = np.random.default_rng(B)
    m = 9
    A = rng.normal(size=(B, m, m))
    R = (A @ A.transpose(0, 2, 1) + m * np.eye(m)).astype(dtypes[0])
    s = np.sqrt(rng.uniform(0.1, 30.0, (B, m))).astype(dtypes[1])
    keep = rng.random((B, m)) < 0.7
    for k in (None, keep):
        got = scale_symmetric(R, s, keep=k)
        want = scale_symmetric_reference(R, s, k)
        assert got.dtype == want.dtype == np.result_type(R, s)
        assert np.array_equal(got, want)
        assert not np.allclose(got, R)
    idx = np.arange(m)
    assert np.all(scale_symmetric(R, s, keep=keep)[:, idx, idx][~keep] == 1)
    assert np.array_equal(scale_symmetric(R[:, ::-1, ::-1], s[:, ::-1]), scale_symmetric_reference(R[:, ::-1, ::-1], s[:, ::-1]))


def test_row_nonzeros_lists_the_nonzero_columns_in_order():
    rng = np.random.default_rng(8)
    for _ in range(50):
        h = rng.normal(size=17) * (rng.random(17) < 0.3)
        if rng.random() < 0.3:
            h[rng.integers(17)] = np.nan   # a non-finite entry is a non-zero (the products then carry it)
        nzc, nzv = np.full(17, -1, np.int64), np.full(17, np.inf)
        c = K.row_nonzeros(h, nzc, nzv)
        cols = np.flatnonzero(h != 0)
        assert c == cols.size
        np.testing.assert_array_equal(nzc[:c], cols)
        np.testing.assert_array_equal(nzv[:c], h[cols])
