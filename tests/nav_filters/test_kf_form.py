"""The reference form ``kf`` against independent computations, and the interface's input checks."""
import numpy as np
import pytest

from nav_filters.forms import KalmanFilter
from nav_filters.registry import make_form, parse_method


def random_spd(rng, B, n, scale=1.0):
    A = rng.normal(size=(B, n, n))
    return scale * (A @ A.mT + n * np.eye(n))


def test_update_equals_information_form_and_least_squares():
    """Joseph-form update equals the information-form posterior (independent algebra)."""
    rng = np.random.default_rng(0)
    B, n, m = 5, 17, 9
    P0 = random_spd(rng, B, n)
    x0 = rng.normal(size=(B, n))
    H = rng.normal(size=(B, m, n))
    Rd = rng.uniform(0.5, 2.0, size=(B, m))
    dz = rng.normal(size=(B, m))
    kf = KalmanFilter(P0, x0=x0)
    res = kf.update(dz, H, Rd)
    Rinv = np.zeros((B, m, m))
    Rinv[:, np.arange(m), np.arange(m)] = 1 / Rd
    Y = np.linalg.inv(P0) + H.mT @ Rinv @ H
    P_post = np.linalg.inv(Y)
    x_post = (P_post @ (np.linalg.inv(P0) @ x0[..., None] + H.mT @ Rinv @ dz[..., None]))[..., 0]
    np.testing.assert_allclose(kf.covariance, P_post, rtol=1e-9, atol=1e-11)
    np.testing.assert_allclose(kf.x, x_post, rtol=1e-9, atol=1e-10)
    S = H @ P0 @ H.mT + Rinv * 0 + np.einsum("bi,ij->bij", Rd, np.eye(m))
    r = dz - (H @ x0[..., None])[..., 0]
    np.testing.assert_allclose(res.nis, np.einsum("bi,bi->b", r, np.linalg.solve(S, r[..., None])[..., 0]), rtol=1e-10)


def test_masked_rows_change_nothing():
    rng = np.random.default_rng(1)
    B, n, m = 3, 17, 8
    P0 = random_spd(rng, B, n)
    H = rng.normal(size=(B, m, n))
    dz = rng.normal(size=(B, m))
    R = np.ones((B, m))
    mask = np.ones((B, m), bool)
    mask[:, 5:] = False
    a = KalmanFilter(P0)
    a.update(dz, H, R, mask)
    b = KalmanFilter(P0)
    b.update(dz[:, :5], H[:, :5], R[:, :5])
    np.testing.assert_allclose(a.covariance, b.covariance, rtol=1e-12)
    np.testing.assert_allclose(a.x, b.x, rtol=1e-12, atol=1e-14)
    # garbage (even NaN) in masked rows is ignored
    dz2 = dz.copy()
    dz2[:, 6] = np.nan
    c = KalmanFilter(P0)
    c.update(dz2, H, R, mask)
    np.testing.assert_allclose(c.x, a.x, rtol=1e-12, atol=1e-14)


def test_predict_and_take_correction():
    rng = np.random.default_rng(2)
    B, n = 4, 6
    P0 = random_spd(rng, B, n)
    x0 = rng.normal(size=(B, n))
    Phi = np.eye(n) + 0.1 * rng.normal(size=(B, n, n))
    Q = random_spd(rng, B, n, 0.01)
    kf = KalmanFilter(P0, x0=x0)
    kf.predict(Phi, Q)
    np.testing.assert_allclose(kf.covariance, Phi @ P0 @ Phi.mT + Q, rtol=1e-12)
    np.testing.assert_allclose(kf.take_correction(), (Phi @ x0[..., None])[..., 0])
    assert np.all(kf.x == 0)


def test_float32_runs_and_keeps_dtype():
    rng = np.random.default_rng(3)
    P0 = random_spd(rng, 2, 17).astype(np.float32)
    kf = make_form("kf", P0, dtype=np.float32)
    kf.predict(np.eye(17, dtype=np.float32)[None].repeat(2, 0), np.eye(17, dtype=np.float32)[None].repeat(2, 0))
    kf.update(rng.normal(size=(2, 4)), rng.normal(size=(2, 4, 17)), np.ones((2, 4)))
    assert kf.covariance.dtype == np.float32 and kf.x.dtype == np.float32
    assert np.all(np.isfinite(kf.covariance))


def test_bad_input_names_the_culprit():
    P0 = np.eye(3)[None]
    kf = KalmanFilter(P0)
    with pytest.raises(ValueError, match="dz"):
        kf.update(np.array([[np.nan]]), np.ones((1, 1, 3)), np.ones((1, 1)))
    with pytest.raises(ValueError, match="R must be positive"):
        kf.update(np.zeros((1, 1)), np.ones((1, 1, 3)), -np.ones((1, 1)))
    with pytest.raises(ValueError, match="H must have shape"):
        kf.update(np.zeros((1, 2)), np.ones((1, 1, 3)), np.ones((1, 2)))
    with pytest.raises(ValueError, match="unknown filter method"):
        parse_method("kalman")
    with pytest.raises(ValueError, match="dtype"):
        KalmanFilter(P0, dtype=np.int32)
    assert parse_method("kf+onestep") == ("kf", True)
