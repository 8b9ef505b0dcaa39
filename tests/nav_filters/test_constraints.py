"""Vehicle pseudo-measurements (ZUPT, ZIHR/ZARU, NHC, odometer) and their stacking.

Jacobians are checked by perturbing the TRUE state by a correction vector x
(x = truth minus estimate: C_true = exp([psi x]) C_est, v_true = v_est + dv,
bias_true = bias_est + b) and comparing the change of the innovation with H x.
The linearization residual must be second order: below the analytic bound of
the neglected terms, and shrinking ~64x when x shrinks 8x (a missing or wrong
first-order term would shrink it only ~8x).
"""
import numpy as np
import pytest

from earth import OMEGA_IE_E, geodetic_to_ecef
from earth.rotations import exp_so3
from nav_filters.constraints import (nhc, odometer, odometer_nhc, stack_measurements, yaw_rate, zero_heading_rate,
                                    zupt)
from nav_filters.error_model import ATT, BG, N_STATES, VEL
from nav_filters.forms import KalmanFilter
from nav_filters.ins import ned_attitude_to_ecef
from nav_filters.measurements import gnss_innovations


def _estimate(B=4, seed=0, speed=(5.0, 25.0)):
    """A random moving estimate: ECEF position, velocity mostly along body x, tilted attitude."""
    rng = np.random.default_rng(seed)
    lat, lon = rng.uniform(-1.2, 1.2, B), rng.uniform(-3, 3, B)
    r = geodetic_to_ecef(lat, lon, rng.uniform(0, 500, B))
    C = ned_attitude_to_ecef(rng.normal(0, 0.1, B), rng.normal(0, 0.1, B), rng.uniform(-np.pi, np.pi, B), lat, lon)
    s = rng.uniform(*speed, B) * rng.choice([-1.0, 1.0], B)
    v_b = np.stack([s, rng.normal(0, 0.3, B), rng.normal(0, 0.2, B)], 1)
    v = (C @ v_b[..., None])[..., 0]
    return r, v, C, lat, lon


def _correction(B, seed, att=0.02, vel=0.3, bg=1e-3):
    rng = np.random.default_rng(100 + seed)
    x = np.zeros((B, N_STATES))
    x[:, ATT] = rng.normal(0, att, (B, 3))
    x[:, VEL] = rng.normal(0, vel, (B, 3))
    x[:, BG] = rng.normal(0, bg, (B, 3))
    return x


def _truth(v, C, x):
    return v + x[:, VEL], exp_so3(x[:, ATT]) @ C


def _Hx(H, x):
    return (H @ x[..., None])[..., 0]


def _assert_second_order(delta_of, H, x, bound):
    """``delta_of(x) - H x`` is below ``bound`` (B, m) and shrinks quadratically with x."""
    e1 = np.abs(delta_of(x) - _Hx(H, x))
    assert np.all(e1 <= bound), (e1, bound)
    e8 = np.abs(delta_of(x / 8) - _Hx(H, x / 8))
    # quadratic: e8 ~ e1 / 64; a wrong first-order term would give e8 ~ e1 / 8
    assert e8.max() < e1.max() / 30
    # and first order dominates (the linearization carries the signal)
    assert e1.max() < 0.05 * np.abs(_Hx(H, x)).max()


# --------------------------------------------------------------------------------------
# Jacobians against finite perturbations of the true state
# --------------------------------------------------------------------------------------
def test_nhc_H_matches_perturbed_truth():
    B = 6
    r, v, C, *_ = _estimate(B)
    x = _correction(B, 0)
    on = np.ones(B, bool)
    dz0, H, R, rm = nhc(v, C, 0.1, 0.1, on)
    assert H.shape == (B, 2, 17) and rm.all() and np.allclose(R, 0.01)

    def delta(xx):  # h(truth) - h(est) = dz(est) - dz(truth), since dz = 0 - h
        vt, Ct = _truth(v, C, xx)
        return dz0 - nhc(vt, Ct, 0.1, 0.1, on)[0]

    # neglected terms: C^T (exp(-S) - I + S)(v + dv) - C^T S dv, |S| = |psi|
    psi, dv = np.linalg.norm(x[:, ATT], axis=1), np.linalg.norm(x[:, VEL], axis=1)
    bound = (0.5 * psi**2 * (np.linalg.norm(v, axis=1) + dv) + psi * dv)[:, None] * 1.01 + 1e-12
    _assert_second_order(delta, H, x, bound)
    # H depends on VEL and ATT only
    assert np.all(H[:, :, 6:] == 0)


def test_odometer_H_matches_perturbed_truth():
    B = 6
    r, v, C, *_ = _estimate(B, seed=1)
    x = _correction(B, 1)
    on = np.ones(B, bool)
    H = odometer(v, C, np.zeros(B), 0.05, on)[1]

    def delta(xx):  # the odometer measures the TRUE forward speed
        vt, Ct = _truth(v, C, xx)
        speed = np.einsum("bi,bi->b", Ct[:, :, 0], vt)
        return odometer(v, C, speed, 0.05, on)[0]

    psi, dv = np.linalg.norm(x[:, ATT], axis=1), np.linalg.norm(x[:, VEL], axis=1)
    bound = (0.5 * psi**2 * (np.linalg.norm(v, axis=1) + dv) + psi * dv)[:, None] * 1.01 + 1e-12
    _assert_second_order(delta, H, x, bound)
    # at zero attitude error the model is exact in the velocity
    x0 = x.copy()
    x0[:, ATT] = 0
    np.testing.assert_allclose(delta(x0), _Hx(H, x0), atol=1e-12)


def test_zupt_H_ecef_exact_and_body_second_order():
    B = 5
    r, v, C, *_ = _estimate(B, seed=2, speed=(0.0, 0.5))  # near rest
    x = _correction(B, 2)
    on = np.ones(B, bool)
    dz, H, R, rm = zupt(v, C, 0.02, on)
    # truth at rest: the ECEF row is linear and exact, dz = dv with dv = -v_est
    np.testing.assert_array_equal(dz, -v)
    xr = np.zeros((B, N_STATES))
    xr[:, VEL] = -v
    np.testing.assert_allclose(_Hx(H, xr), dz, atol=1e-15)
    np.testing.assert_array_equal(H[:, :, VEL], np.broadcast_to(np.eye(3), (B, 3, 3)))
    assert np.all(H[:, :, :3] == 0) and np.all(H[:, :, 6:] == 0) and np.allclose(R, 4e-4)

    dzb, Hb, Rb, rmb = zupt(v, C, 0.02, on, frame="body")

    def delta(xx):
        vt, Ct = _truth(v, C, xx)
        return dzb - zupt(vt, Ct, 0.02, on, frame="body")[0]

    psi, dv = np.linalg.norm(x[:, ATT], axis=1), np.linalg.norm(x[:, VEL], axis=1)
    bound = (0.5 * psi**2 * (np.linalg.norm(v, axis=1) + dv) + psi * dv)[:, None] * 1.01 + 1e-12
    _assert_second_order(delta, Hb, x, bound)


@pytest.mark.parametrize("axes", ["heading", "all"])
def test_zero_rate_H_matches_perturbed_truth(axes):
    B = 6
    r, v, C, *_ = _estimate(B, seed=3)
    on = np.ones(B, bool)

    def delta(xx):  # stationary truth: corrected gyro = C_be_true w_ie + bias residual
        Ct = exp_so3(xx[:, ATT]) @ C
        w = np.swapaxes(Ct, 1, 2) @ OMEGA_IE_E + xx[:, BG]
        return zero_heading_rate(C, w, r, 1e-4, on, axes=axes)[0]

    H = zero_heading_rate(C, np.zeros((B, 3)), r, 1e-4, on, axes=axes)[1]
    assert H.shape == (B, 1 if axes == "heading" else 3, 17)
    assert np.all(H[:, :, 3:9] == 0) and np.all(H[:, :, 12:] == 0)
    # attitude only (large psi so the Earth-rate term is well above rounding): the
    # neglected term is C^T (exp(-S) - I + S) w_ie <= |psi|^2 / 2 * OMEGA_IE
    x = _correction(B, 3, att=0.05, vel=0.0, bg=0.0)
    psi = np.linalg.norm(x[:, ATT], axis=1)
    bound = (0.5 * psi**2 * np.linalg.norm(OMEGA_IE_E))[:, None] * 1.01 + 1e-18
    _assert_second_order(delta, H, x, bound)
    # the bias enters exactly (H_BG is evaluated at the estimate and the reading is linear in b)
    xb = _correction(B, 4, att=0.0, vel=0.0, bg=1e-3)
    np.testing.assert_allclose(delta(xb), _Hx(H, xb), atol=1e-17)
    # heading row: H_BG is the local down axis in body coordinates; for a near-level
    # vehicle that is close to body z
    if axes == "heading":
        assert np.all(np.abs(H[:, 0, BG][:, 2]) > 0.97)
        np.testing.assert_allclose(np.linalg.norm(H[:, 0, BG], axis=1), 1.0, atol=1e-12)


def test_zero_heading_rate_is_zero_for_a_true_stationary_reading():
    """At rest with a perfect estimate the corrected gyro is exactly the Earth rate: dz = 0."""
    B = 3
    r, v, C, lat, lon = _estimate(B, seed=5)
    w = np.swapaxes(C, 1, 2) @ OMEGA_IE_E
    for axes in ("heading", "all"):
        dz = zero_heading_rate(C, w, r, 1e-4, np.ones(B, bool), axes=axes)[0]
        np.testing.assert_allclose(dz, 0.0, atol=1e-19)
    # heading row of a gyro z-bias on a level vehicle: the bias itself (down = body z)
    Cl = ned_attitude_to_ecef(np.zeros(B), np.zeros(B), np.array([0.3, 2.0, -1.0]), lat, lon)
    wb = np.swapaxes(Cl, 1, 2) @ OMEGA_IE_E + np.array([0.0, 0.0, 2e-4])
    dz = zero_heading_rate(Cl, wb, r, 1e-4, np.ones(B, bool))[0]
    np.testing.assert_allclose(dz[:, 0], 2e-4, rtol=1e-9)
    # the heading axis is the local (geodetic) vertical: for a level vehicle H_BG = body z,
    # within the stated e^2 h / (2 a) of the closed-form ellipsoid normal (here h = 3 km)
    r3 = geodetic_to_ecef(lat, lon, np.full(B, 3000.0))
    Hbg = zero_heading_rate(Cl, wb, r3, 1e-4, np.ones(B, bool))[1][:, 0, BG]
    assert np.abs(Hbg - np.array([0.0, 0.0, 1.0])).max() < 0.00669438 * 3000.0 / (2 * 6378137.0) * 1.01


def test_yaw_rate_H_matches_perturbed_truth():
    """A moving, turning body: the sensor reads the true Earth-referenced rate about body z; the row's dz
    against the corrected gyro of a perturbed truth is H x to first order (attitude), exactly in the bias."""
    B = 6
    r, v, C, *_ = _estimate(B, seed=6)
    rng = np.random.default_rng(6)
    w_eb = rng.normal(0.0, 0.3, (B, 3))                 # true body rate w.r.t. the Earth [rad/s]
    on = np.ones(B, bool)

    def delta(xx):  # truth: C_true = exp(psi) C, corrected gyro = omega_ib_true + b; sensor: w_eb_z exactly
        Ct = exp_so3(xx[:, ATT]) @ C
        w = w_eb + np.swapaxes(Ct, 1, 2) @ OMEGA_IE_E + xx[:, BG]
        return yaw_rate(C, w, w_eb[:, 2], 1e-3, on)[0]

    H = yaw_rate(C, np.zeros((B, 3)), np.zeros(B), 1e-3, on)[1]
    assert H.shape == (B, 1, 17) and np.all(H[:, :, 3:9] == 0) and np.all(H[:, :, 12:] == 0)
    np.testing.assert_array_equal(H[:, 0, BG], np.broadcast_to([0.0, 0.0, -1.0], (B, 3)))
    x = _correction(B, 6, att=0.05, vel=0.0, bg=0.0)
    psi = np.linalg.norm(x[:, ATT], axis=1)
    bound = (0.5 * psi**2 * np.linalg.norm(OMEGA_IE_E))[:, None] * 1.01 + 1e-18
    _assert_second_order(delta, H, x, bound)
    xb = _correction(B, 7, att=0.0, vel=0.0, bg=1e-3)
    np.testing.assert_allclose(delta(xb), _Hx(H, xb), atol=1e-17)


def test_yaw_rate_sign_and_masking():
    """Level vehicle turning right at 0.1 rad/s (FRD: +z): a perfect gyro gives dz = 0, a +1e-3 rad/s z-gyro bias
    residual dz = -1e-3; rows without a reading (NaN) are neutral."""
    B = 3
    _, _, _, lat, lon = _estimate(B, seed=8)
    Cl = ned_attitude_to_ecef(np.zeros(B), np.zeros(B), np.array([0.3, 2.0, -1.0]), lat, lon)
    w = np.swapaxes(Cl, 1, 2) @ OMEGA_IE_E + np.array([0.0, 0.0, 0.1])
    z = np.array([0.1, 0.1, np.nan])
    have = np.isfinite(z)
    dz, H, R, rm = yaw_rate(Cl, w, np.where(have, z, 0.0), 2e-3, have)
    np.testing.assert_allclose(dz[:2, 0], 0.0, atol=1e-15)
    assert rm[:, 0].tolist() == [True, True, False] and dz[2, 0] == 0 and R[2, 0] == 1 and np.all(H[2] == 0)
    np.testing.assert_allclose(R[:2, 0], 4e-6)
    dz_b = yaw_rate(Cl, w + np.array([0.0, 0.0, 1e-3]), np.where(have, z, 0.0), 2e-3, have)[0]
    np.testing.assert_allclose(dz_b[:2, 0], -1e-3, rtol=1e-9)


# --------------------------------------------------------------------------------------
# Filter behaviour
# --------------------------------------------------------------------------------------
def _P0(B, p_vel, att=1e-2):
    d = np.array([att**2] * 3 + [0.0] * 3 + [4.0] * 3 + [1e-8] * 3 + [1e-4] * 3 + [100.0, 1.0])
    P = np.repeat(np.diag(d)[None], B, 0)
    P[:, 3, 3], P[:, 4, 4], P[:, 5, 5] = p_vel.T
    return P


@pytest.mark.parametrize("dtype,rtol", [(np.float64, 1e-12), (np.float32, 2e-5)])
def test_zupt_kf_update_pulls_velocity_to_zero_by_the_expected_gain(dtype, rtol):
    """Stationary truth, velocity error only: x_vel = -p/(p+r) v_est per axis, P_vel = p r/(p+r)."""
    B = 3
    rng = np.random.default_rng(7)
    r, v, C, *_ = _estimate(B, seed=7, speed=(0.2, 0.5))
    p = rng.uniform(0.01, 0.3, (B, 3))            # per-row, per-axis velocity variances
    sig = 0.05
    kf = KalmanFilter(_P0(B, p), dtype=dtype)
    dz, H, R, rm = zupt(v, C, sig, np.ones(B, bool), dtype=dtype)
    assert dz.dtype == H.dtype == R.dtype == np.dtype(dtype)
    kf.update(dz, H, R, rm)
    gain = p / (p + sig**2)
    np.testing.assert_allclose(kf.x[:, VEL], -gain * v, rtol=rtol)
    np.testing.assert_allclose(v + kf.x[:, VEL], v * sig**2 / (p + sig**2), rtol=rtol * 10)
    np.testing.assert_allclose(np.diagonal(kf.P[:, VEL, VEL], axis1=1, axis2=2), p * sig**2 / (p + sig**2),
                               rtol=rtol * 10)
    others = np.ones(N_STATES, bool)
    others[VEL] = False
    assert np.all(kf.x[:, others] == 0)       # diagonal P0: nothing else moves


def test_body_frame_zupt_equals_ecef_zupt_for_isotropic_velocity_uncertainty():
    """C_be is a rotation: with P_vel = p I and no attitude uncertainty both frames give the same update."""
    B = 4
    r, v, C, *_ = _estimate(B, seed=8, speed=(0.1, 1.0))
    p = np.full((B, 3), 0.04)
    out = []
    for frame in ("ecef", "body"):
        kf = KalmanFilter(_P0(B, p, att=0.0))
        res = kf.update(*zupt(v, C, 0.03, np.ones(B, bool), frame=frame))
        out.append((kf.x.copy(), kf.P.copy(), res.nis))
    np.testing.assert_allclose(out[1][0], out[0][0], atol=1e-13)
    np.testing.assert_allclose(out[1][1], out[0][1], atol=1e-13)
    np.testing.assert_allclose(out[1][2], out[0][2], rtol=1e-10)


def test_nhc_reveals_a_yaw_error():
    """Level vehicle, true velocity along body x, estimate yawed by dyaw: dz_lat = -s sin(dyaw).

    With isotropic attitude variance sa^2 and velocity variance sv^2 the two NHC rows
    decouple (H is taken at the estimate: lateral row H_att = -s cos(dyaw) d^T) and the
    KF attitude correction is s^2 sa^2 cos(dyaw) sin(dyaw) / (s^2 sa^2 cos^2(dyaw) + sv^2 + r)
    along the local down axis d (analytic, exact for the linear update).
    """
    B = 4
    lat, lon = np.array([0.5, -0.3, 1.0, 0.1]), np.array([0.2, 2.0, -1.0, 3.0])
    yaw = np.array([0.3, 1.5, -2.0, 3.0])
    dyaw = np.array([0.01, -0.02, 0.005, 0.03])   # truth minus estimate, about local down
    s = np.array([5.0, 10.0, 20.0, -8.0])         # the last one reversing
    C_true = ned_attitude_to_ecef(np.zeros(B), np.zeros(B), yaw, lat, lon)
    C_est = ned_attitude_to_ecef(np.zeros(B), np.zeros(B), yaw - dyaw, lat, lon)
    v = C_true[:, :, 0] * s[:, None]              # estimate has no velocity error
    sig = 0.05
    dz, H, R, rm = nhc(v, C_est, sig, sig)
    np.testing.assert_allclose(dz[:, 0], -s * np.sin(dyaw), rtol=1e-9)
    assert np.all(np.abs(dz[:, 0] + s * dyaw) <= np.abs(s) * np.abs(dyaw) ** 3 / 6 * 1.01 + 1e-12)
    np.testing.assert_allclose(dz[:, 1], 0.0, atol=1e-12)     # rotation about down: no vertical part

    sa, sv = 0.05, 1e-3
    P0 = np.repeat(np.diag([sa**2] * 3 + [sv**2] * 3 + [1.0] * 3 + [1e-8] * 3 + [1e-4] * 3 + [1.0, 1.0])[None], B, 0)
    kf = KalmanFilter(P0)
    kf.update(dz, H, R, rm)
    down = C_true[:, :, 2]
    est_dyaw = np.einsum("bi,bi->b", kf.x[:, ATT], down)
    cy, sy = np.cos(dyaw), np.sin(dyaw)
    expected = s**2 * sa**2 * cy * sy / (s**2 * sa**2 * cy**2 + sv**2 + sig**2)
    np.testing.assert_allclose(est_dyaw, expected, rtol=1e-9)
    assert np.all(np.sign(est_dyaw) == np.sign(dyaw)) and np.all(np.abs(est_dyaw) > 0.9 * np.abs(dyaw))
    # nothing leaks into roll/pitch
    resid = kf.x[:, ATT] - est_dyaw[:, None] * down
    assert np.abs(resid).max() < 1e-12


# --------------------------------------------------------------------------------------
# Masks and stacking
# --------------------------------------------------------------------------------------
def test_inactive_rows_are_neutral_and_change_nothing():
    B = 3
    r, v, C, *_ = _estimate(B, seed=9)
    active = np.array([True, False, True])
    v_nan = v.copy()
    v_nan[1] = np.nan                               # inactive rows are not inspected
    C_nan = C.copy()
    C_nan[1] = np.nan
    with np.errstate(all="raise"):
        blocks = [
            zupt(v_nan, C_nan, 0.02, active),
            zupt(v_nan, C_nan, 0.02, active, frame="body"),
            zero_heading_rate(C_nan, np.where(active[:, None], np.full((B, 3), 1e-5), np.nan), np.where(active[:, None], r, np.nan),
                              1e-4, active),
            zero_heading_rate(C_nan, np.zeros((B, 3)), None, 1e-4, active, axes="all"),
            nhc(v_nan, C_nan, 0.1, 0.1, active),
            odometer(v_nan, C_nan, np.array([10.0, np.nan, 3.0]), 0.1, active),
        ]
    for dz, H, R, rm in blocks:
        assert rm.shape == dz.shape and rm.dtype == bool
        assert np.all(rm[active]) and not rm[1].any()
        assert np.all(dz[1] == 0) and np.all(H[1] == 0) and np.all(R[1] == 1)
        assert np.all(np.isfinite(dz)) and np.all(np.isfinite(H)) and np.all(np.isfinite(R))
        assert np.any(H[0] != 0)
    # an update where every row is inactive leaves the filter exactly as it was
    P0 = _P0(B, np.full((B, 3), 0.1))
    kf = KalmanFilter(P0)
    none = np.zeros(B, bool)
    res = kf.update(*stack_measurements(zupt(v, C, 0.02, none), nhc(v, C, 0.1, 0.1, none)))
    assert np.all(kf.x == 0) and np.array_equal(kf.P, P0) and np.all(res.n_used == 0)
    # a bool scalar broadcasts; nhc's default is all active
    assert zupt(v, C, 0.02, True)[3].all() and nhc(v, C, 0.1, 0.1)[3].all()


def _gnss_block(r, v, B, C=5, seed=11):
    rng = np.random.default_rng(seed)
    up = r / np.linalg.norm(r, axis=1, keepdims=True)
    d = rng.normal(size=(B, C, 3)) + 2.0 * up[:, None, :]
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    sat = r[:, None, :] + 2.2e7 * d
    sv = rng.normal(0, 2500, (B, C, 3))
    mask = np.ones((B, C), bool)
    mask[0, -1] = False
    zeros, ones = np.zeros((B, C)), np.ones((B, C))
    neg_rho, neg_rho_dot = np.split(gnss_innovations(r, v, np.zeros(B), np.zeros(B), sat, sv, zeros, zeros,
                                                     ones, ones, np.ones((B, C), bool))[0], 2, axis=1)
    pr = -neg_rho + rng.normal(0, 3, (B, C))
    prr = -neg_rho_dot + rng.normal(0, 0.1, (B, C))
    return gnss_innovations(r, v, np.zeros(B), np.zeros(B), sat, sv, pr, prr,
                            np.full((B, C), 9.0), np.full((B, C), 0.01), mask)[:4]


def test_stacked_update_equals_sequential_updates():
    """For a KF, one update with stacked uncorrelated blocks equals the blocks applied in turn."""
    B = 3
    r, v, C, *_ = _estimate(B, seed=12)
    rng = np.random.default_rng(12)
    A = rng.normal(size=(B, N_STATES, N_STATES)) * 0.1
    P0 = A @ A.mT + np.diag([1e-4] * 3 + [0.1] * 3 + [4.0] * 3 + [1e-7] * 3 + [1e-4] * 3 + [100.0, 1.0])
    w = np.swapaxes(C, 1, 2) @ OMEGA_IE_E + rng.normal(0, 1e-4, (B, 3))
    active = np.array([True, True, False])
    g = _gnss_block(r, v, B)
    # one block with a full (correlated) covariance, to exercise the block-diagonal path
    dzg, Hg, Rg, mg = g
    m = Rg.shape[1]
    Rg_full = np.repeat(np.diag(np.ones(m))[None], B, 0) * Rg[:, :, None]
    Rg_full[:, 0, 1] = Rg_full[:, 1, 0] = 0.5 * np.sqrt(Rg[:, 0] * Rg[:, 1])
    Rg_full[:, 0, 4] = Rg_full[:, 4, 0] = 0.3 * np.sqrt(Rg[:, 0] * Rg[:, 4])   # channel 4 is masked on row 0
    blocks = [
        (dzg, Hg, Rg_full, mg),
        zupt(v, C, 0.05, active),
        zero_heading_rate(C, w, r, 2e-4, active),
        nhc(v, C, 0.1, 0.2),
        odometer(v, C, rng.normal(10, 1, B), 0.1, np.array([True, False, True])),
    ]
    dz, H, R, mask = stack_measurements(*blocks)
    assert dz.shape == (B, 2 * 5 + 3 + 1 + 2 + 1) and H.shape[2] == 17 and R.shape == (B, 17, 17)
    # masked rows: unit variance and no cross-covariance; valid rows keep their correlation
    eye = np.eye(R.shape[1])
    b, j = np.nonzero(~mask)
    np.testing.assert_array_equal(R[b, j, :], eye[j])
    np.testing.assert_array_equal(R[b, :, j], eye[j])
    assert not mask[0, 4] and R[0, 0, 4] == 0 and R[1, 0, 4] != 0 and R[0, 0, 1] != 0
    kf_one = KalmanFilter(P0)
    res = kf_one.update(dz, H, R, mask)
    kf_seq = KalmanFilter(P0)
    for blk in blocks:
        kf_seq.update(*blk)
    np.testing.assert_allclose(kf_one.x, kf_seq.x, rtol=1e-9, atol=1e-13)
    np.testing.assert_allclose(kf_one.P, kf_seq.P, rtol=1e-8, atol=1e-14)
    assert np.array_equal(res.n_used, mask.sum(1))
    # all-diagonal blocks keep R as (B, m) variances; None is skipped; dtype follows the blocks
    dz2, H2, R2, m2 = stack_measurements(blocks[1], None, blocks[3])
    assert R2.shape == (B, 5) and np.array_equal(m2[:, :3], blocks[1][3])
    b32 = [zupt(v, C, 0.05, active, dtype=np.float32), nhc(v, C, 0.1, 0.2, dtype=np.float32)]
    assert stack_measurements(*b32)[0].dtype == np.float32
    assert stack_measurements(*b32, dtype=np.float64)[1].dtype == np.float64


# --------------------------------------------------------------------------------------
# Bad input
# --------------------------------------------------------------------------------------
def _bad_calls():
    B = 2
    r, v, C, *_ = _estimate(B, seed=13)
    on = np.ones(B, bool)
    vn = v.copy()
    vn[0, 1] = np.nan
    Cn = C.copy()
    Cn[1, 0, 0] = np.inf
    w = np.zeros((B, 3))
    return [
        ("v_e", lambda: zupt(v[:, :2], C, 0.1, on)),
        ("sigma_mps", lambda: zupt(v, C, -0.1, on)),
        ("sigma_mps", lambda: zupt(v, C, 0.0, on)),
        ("sigma_mps", lambda: zupt(v, C, np.array([0.1, 0.1, 0.1]), on)),
        ("v_e", lambda: zupt(vn, C, 0.1, on)),
        ("active", lambda: zupt(v, C, 0.1, np.ones(B + 1, bool))),
        ("active", lambda: zupt(v, C, 0.1, np.ones(B))),
        ("active", lambda: zupt(v, C, 0.1, None)),
        ("frame", lambda: zupt(v, C, 0.1, on, frame="ned")),
        ("C_eb", lambda: zupt(v, None, 0.1, on, frame="body")),
        ("C_eb", lambda: zupt(v, Cn, 0.1, on, frame="body")),
        ("dtype", lambda: zupt(v, C, 0.1, on, dtype=np.int32)),
        ("C_eb", lambda: nhc(v, C[:, 0], 0.1, 0.1)),
        ("C_eb", lambda: nhc(v, C[:1], 0.1, 0.1)),
        ("sigma_vert_mps", lambda: nhc(v, C, 0.1, np.nan)),
        ("sigma_lat_mps", lambda: nhc(v, C, -1.0, 0.1)),
        ("C_eb", lambda: nhc(v, Cn, 0.1, 0.1)),
        ("speed_mps", lambda: odometer(v, C, np.zeros((B, 1)), 0.1, on)),
        ("speed_mps", lambda: odometer(v, C, np.array([1.0, np.nan]), 0.1, on)),
        ("mask", lambda: odometer(v, C, np.zeros(B), 0.1, None)),
        ("sigma_mps", lambda: odometer(v, C, np.zeros(B), -1.0, on)),
        ("axes", lambda: zero_heading_rate(C, w, r, 1e-4, on, axes="yaw")),
        ("r_e", lambda: zero_heading_rate(C, w, None, 1e-4, on)),
        ("w_b_corrected", lambda: zero_heading_rate(C, np.full((B, 3), np.nan), r, 1e-4, on)),
        ("w_b_corrected", lambda: zero_heading_rate(C, w[:1], r, 1e-4, on)),
        ("sigma_rps", lambda: zero_heading_rate(C, w, r, -1e-4, on)),
        ("yaw_rate_rps", lambda: yaw_rate(C, w, np.array([0.1, np.nan]), 1e-3, on)),
        ("sigma_rps", lambda: yaw_rate(C, w, np.zeros(B), 0.0, on)),
        ("w_b_corrected", lambda: yaw_rate(C, w[:1], np.zeros(B), 1e-3, on)),
        ("blocks", lambda: stack_measurements()),
        ("blocks", lambda: stack_measurements(None)),
        (r"blocks\[0\]", lambda: stack_measurements(zupt(v, C, 0.1, on) + (None,))),
        (r"blocks\[1\]", lambda: stack_measurements(zupt(v, C, 0.1, on), zupt(v[:1], C[:1], 0.1, on[:1]))),
        (r"blocks\[0\] R", lambda: stack_measurements(zupt(v, C, 0.1, on)[:2] + (np.ones((B, 2)), np.ones((B, 3), bool)))),
    ]


@pytest.mark.parametrize("i", range(len(_bad_calls())))
def test_bad_input_raises_value_error_naming_the_argument(i):
    name, call = _bad_calls()[i]
    with pytest.raises(ValueError, match=name):
        call()


def _odometer_nhc_composition(v, C, speed, sigmas, dtype):
    have = np.isfinite(speed)
    return stack_measurements(odometer(v, C, np.where(have, speed, 0.0), sigmas[0], have, dtype=dtype),
                              nhc(v, C, sigmas[1], sigmas[2], dtype=dtype))


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("B", [1, 7])
def test_odometer_nhc_equals_the_stacked_odometer_and_nhc_rows(dtype, B):
    """The compiled block equals its specification, the stacked :func:`odometer` and :func:`nhc` rows, bit for
    bit: rows with and without a speed reading, a reversing vehicle, either dtype."""
    _, v, C, _, _ = _estimate(B, seed=B)
    speed = np.random.default_rng(B).normal(10.0, 5.0, B)
    speed[::3] = np.nan  # no reading: the odometer row is neutral
    sigmas = (0.1, 0.2, 0.35)
    got = odometer_nhc(v, C, speed, *sigmas, dtype=dtype)
    want = _odometer_nhc_composition(v, C, speed, sigmas, dtype)
    for g, w, name in zip(got, want, ("dz", "H", "R", "row_mask")):
        assert g.dtype == w.dtype and g.shape == w.shape, name
        np.testing.assert_array_equal(g, w, err_msg=name)
    assert got[3][:, 0].tolist() == np.isfinite(speed).tolist() and got[3][:, 1:].all()
    np.testing.assert_array_equal(got[0][::3, 0], 0.0)


def test_odometer_nhc_bad_inputs_raise_the_composition_errors():
    """Inputs the compiled pass does not take run the composition: per-row sigmas give its result, a non-finite
    state or a bad sigma its error naming the argument."""
    _, v, C, _, _ = _estimate(3, seed=4)
    speed = np.array([3.0, np.nan, -2.0])
    per_row = (np.array([0.1, 0.2, 0.3]), 0.2, 0.3)
    for g, w in zip(odometer_nhc(v, C, speed, *per_row), _odometer_nhc_composition(v, C, speed, per_row, np.float64)):
        np.testing.assert_array_equal(g, w)
    v_bad = v.copy()
    v_bad[1, 2] = np.nan  # on the row without a speed reading: the NHC rows need it
    with pytest.raises(ValueError, match="v_e has a non-finite value on active batch row 1"):
        odometer_nhc(v_bad, C, speed, 0.1, 0.2, 0.3)
    C_bad = C.copy()
    C_bad[0, 0, 0] = np.inf
    with pytest.raises(ValueError, match="C_eb has a non-finite value on active batch row 0"):
        odometer_nhc(v, C_bad, speed, 0.1, 0.2, 0.3)
    with pytest.raises(ValueError, match="sigma_lat_mps must be positive and finite"):
        odometer_nhc(v, C, speed, 0.1, 0.0, 0.3)
    with pytest.raises(ValueError, match="C_eb must have shape"):
        odometer_nhc(v, C[:2], speed, 0.1, 0.2, 0.3)
