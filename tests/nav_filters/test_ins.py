"""Tests of the ECEF strapdown mechanization (nav_filters.ins).

The reference trajectories are analytic: every quantity (position, velocity,
attitude, angular rate, specific force) is a closed-form function of time, and
the IMU samples are their interval means computed by 5-point Gauss-Legendre
quadrature (exact to ~1e-15 relative for these smooth signals), i.e. exactly
the sample convention of the INS.
"""
from __future__ import annotations

import numpy as np
import pytest

from earth.rotations import dcm_from_euler, exp_so3, log_so3
from earth.wgs84 import OMEGA_IE, C_en, geodetic_to_ecef, gravity_ecef
from nav_filters.ins import (
    apply_correction,
    mechanize,
    navigation_error,
    ned_attitude_to_ecef,
    orthonormalize_dcm,
)

W_IE = np.array([0.0, 0.0, OMEGA_IE])
DT = 0.01


# --------------------------------------------------------------------------------------
# analytic truth
# --------------------------------------------------------------------------------------
def _imu_from_kinematics(r, v, a, C_eb, w_eb_b):
    """w_ib^b and f_b of an Earth-referenced motion (Groves eqs 5.24-5.36 solved for the IMU)."""
    C_be = np.swapaxes(C_eb, -1, -2)
    w_ib = w_eb_b + (C_be @ W_IE)
    f_e = a - gravity_ecef(r) + 2.0 * np.cross(W_IE, v)
    return (C_be @ f_e[..., None])[..., 0], w_ib


def stationary(t, lat, lon, h, roll, pitch, yaw):
    """A vehicle at rest on the Earth."""
    t = np.asarray(t, float)
    r = np.broadcast_to(geodetic_to_ecef(lat, lon, h), t.shape + (3,))
    C = np.broadcast_to(ned_attitude_to_ecef(roll, pitch, yaw, lat, lon), t.shape + (3, 3))
    zero = np.zeros(t.shape + (3,))
    f, w = _imu_from_kinematics(r, zero, zero, C, zero)
    return r, zero, C, f, w


def straight_line(t, r0, v0, C0):
    """Constant ECEF velocity along a straight line, attitude fixed in ECEF (a_e = 0)."""
    t = np.asarray(t, float)
    r = r0 + t[..., None] * v0
    v = np.broadcast_to(v0, r.shape)
    C = np.broadcast_to(C0, t.shape + (3, 3))
    zero = np.zeros(t.shape + (3,))
    f, w = _imu_from_kinematics(r, v, zero, C, zero)
    return r, v, C, f, w


def trochoid(t, lat0=0.8, lon0=0.2, h0=100.0):
    """Land-vehicle-like looping path in a local tangent plane (fixed NED axes at (lat0, lon0)).

    Horizontal path ``p = (V t + R sin wt, R (1 - cos wt))`` with V = 6 m/s,
    R = 75 m, w = 0.2 rad/s: speed 9..21 m/s, |acceleration| = 3 m/s^2,
    turn rate 8..19 deg/s, continuous looping; 2 m vertical undulation; yaw
    along the horizontal velocity plus 1 deg pitch and 2 deg roll oscillations
    (0.7 and 1.3 rad/s) so the body rotates about all three axes (coning).
    """
    t = np.asarray(t, float)
    V, R, om, Hz, omz = 6.0, 75.0, 0.2, 2.0, 0.05
    ph0, omr, th0, omp = np.deg2rad(2.0), 1.3, np.deg2rad(1.0), 0.7
    s, c = np.sin(om * t), np.cos(om * t)
    p = np.stack([V * t + R * s, R * (1 - c), -Hz * np.sin(omz * t)], -1)
    v = np.stack([V + R * om * c, R * om * s, -Hz * omz * np.cos(omz * t)], -1)
    a = np.stack([-R * om**2 * s, R * om**2 * c, Hz * omz**2 * np.sin(omz * t)], -1)
    psi = np.arctan2(v[..., 1], v[..., 0])
    psid = (v[..., 0] * a[..., 1] - v[..., 1] * a[..., 0]) / (v[..., 0] ** 2 + v[..., 1] ** 2)
    th, thd = th0 * np.sin(omp * t), th0 * omp * np.cos(omp * t)
    ph, phd = ph0 * np.sin(omr * t + 0.3), ph0 * omr * np.cos(omr * t + 0.3)
    C_nb = dcm_from_euler(ph, th, psi)
    # body rate w.r.t. the (Earth-fixed) tangent frame from the Z-Y-X Euler rates
    w_nb = np.stack([phd - psid * np.sin(th),
                     thd * np.cos(ph) + psid * np.sin(ph) * np.cos(th),
                     -thd * np.sin(ph) + psid * np.cos(ph) * np.cos(th)], -1)
    Cen = C_en(lat0, lon0)
    r = geodetic_to_ecef(lat0, lon0, h0) + p @ Cen.T
    C = Cen @ C_nb
    f, w = _imu_from_kinematics(r, v @ Cen.T, a @ Cen.T, C, w_nb)
    return r, v @ Cen.T, C, f, w


def imu_means(fun, n, dt=DT, nodes=5):
    """Interval means of f_b, w_b over (t_{k-1}, t_k], k = 1..n (Gauss-Legendre)."""
    x, wgt = np.polynomial.legendre.leggauss(nodes)
    tt = (np.arange(n) * dt)[:, None] + dt * (1.0 + x) / 2.0
    _, _, _, f, w = fun(tt.ravel())
    f = f.reshape(n, nodes, 3)
    w = w.reshape(n, nodes, 3)
    return np.einsum("k,nki->ni", wgt / 2, f), np.einsum("k,nki->ni", wgt / 2, w)


def test_trochoid_imu_consistent_with_its_own_kinematics():
    """Guards the reference generator: w and f agree with finite differences of C and v."""
    t = np.array([3.0, 17.0, 41.0])
    e = 1e-4
    r, v, C, f, w = trochoid(t)
    _, vp, Cp, _, _ = trochoid(t + e)
    _, vm, Cm, _, _ = trochoid(t - e)
    # w_eb^b from C_eb(t+e) = C_eb(t) exp(w_eb e)
    w_eb = (log_so3(np.swapaxes(Cm, -1, -2) @ Cp)) / (2 * e)
    w_ib_fd = w_eb + np.swapaxes(C, -1, -2) @ W_IE
    np.testing.assert_allclose(w, w_ib_fd, atol=1e-8)
    a_fd = (vp - vm) / (2 * e)
    f_fd = (np.swapaxes(C, -1, -2) @ (a_fd - gravity_ecef(r) + 2 * np.cross(W_IE, v))[..., None])[..., 0]
    np.testing.assert_allclose(f, f_fd, atol=1e-6)
    assert np.max(np.abs(np.rad2deg(w[:, 2]))) > 3.0  # it really turns


# --------------------------------------------------------------------------------------
# long runs: 600 s at 100 Hz, four rows in one batch
# --------------------------------------------------------------------------------------
LAT1, LON1, H1 = 0.8, 0.2, 100.0
LAT2, LON2, H2 = -0.5, 2.5, 1500.0
R0_LINE = geodetic_to_ecef(0.3, -1.2, 50.0)
V0_LINE = C_en(0.3, -1.2) @ np.array([12.0, -16.0, 0.5])   # 20 m/s, slightly climbing
C0_LINE = ned_attitude_to_ecef(0.02, -0.01, -0.9, 0.3, -1.2)

CASES = {
    "static_level": lambda t: stationary(t, LAT1, LON1, H1, 0.0, 0.0, 0.5),
    "static_tilted": lambda t: stationary(t, LAT2, LON2, H2, 0.2, -0.3, 2.0),
    "trochoid": trochoid,
    "line": lambda t: straight_line(t, R0_LINE, V0_LINE, C0_LINE),
}
N_LONG = 60000          # 600 s
CHECK_STEPS = (6000, 60000)


@pytest.fixture(scope="module")
def long_run():
    names = list(CASES)
    imu = [imu_means(CASES[k], N_LONG) for k in names]
    f = np.stack([x[0] for x in imu], 1)
    w = np.stack([x[1] for x in imu], 1)
    truth0 = [CASES[k](np.array([0.0])) for k in names]
    r = np.concatenate([x[0] for x in truth0])
    v = np.concatenate([x[1] for x in truth0])
    C = np.concatenate([x[2] for x in truth0])
    errors = {}
    for k in range(N_LONG):
        r, v, C = mechanize(r, v, C, f[k], w[k], DT)
        if k + 1 in CHECK_STEPS:
            tk = np.array([(k + 1) * DT])
            tr = [CASES[n](tk) for n in names]
            err = navigation_error(np.concatenate([x[0] for x in tr]), np.concatenate([x[1] for x in tr]),
                                   np.concatenate([x[2] for x in tr]), r, v, C)
            errors[k + 1] = {n: err[i] for i, n in enumerate(names)}
    return errors, C


@pytest.mark.slow
def test_stationary_vehicle_stays_put(long_run):
    """f_b = -C_be g, w_b = C_be w_ie: the exact solution is r, v, C constant.

    For this input the scheme is exact up to O((w_ie dt)^2) terms (~1e-14
    m/s per step), so what remains is rounding: the attitude random-walks by
    ~1e-17..1e-16 rad per step (measured 3e-12 rad after 600 s), which tilts
    gravity into a velocity error of ~g psi t / 2 (measured 2e-8 m/s); the
    position increments stay below the float64 spacing of |r| (~9e-10 m) and
    the position does not move at all. The bounds allow ~30x those figures.
    """
    errors, C = long_run
    for name in ("static_level", "static_tilted"):
        e = errors[N_LONG][name]
        assert np.linalg.norm(e[6:9]) < 1e-6, (name, e[6:9])     # 1 um after 600 s
        assert np.linalg.norm(e[3:6]) < 1e-6, (name, e[3:6])
        assert np.linalg.norm(e[0:3]) < 1e-10, (name, e[0:3])
    # float64 DCMs stay orthonormal without re-orthonormalization (~2e-16 per step at most)
    orth = np.abs(C @ np.swapaxes(C, -1, -2) - np.eye(3)).max()
    assert orth < 1e-10


@pytest.mark.slow
def test_straight_line_constant_ecef_velocity(long_run):
    """Straight line at 20 m/s with Coriolis and a varying gravity along the path."""
    errors, _ = long_run
    e60 = errors[6000]["line"]
    e600 = errors[N_LONG]["line"]
    assert np.linalg.norm(e60[6:9]) < 1e-5, e60        # < 10 um after 60 s
    assert np.linalg.norm(e600[6:9]) < 1e-4, e600      # < 0.1 mm after 600 s (measured 1.2e-5)
    assert np.linalg.norm(e600[3:6]) < 1e-7, e600      # measured 9e-9 m/s


@pytest.mark.slow
def test_land_vehicle_trajectory_600s(long_run):
    """Noise-free IMU, turns up to 19 deg/s, 3 m/s^2: position error < 0.5 m after 600 s.

    Measured 8.6e-2 m (single-sample scheme; the residual is the uncorrected
    coning/sculling, O(dt^3) per step). The 0.15 m bound keeps a margin
    against rounding differences but fails for any first-order defect (e.g.
    without the rotation correction 0.5 dtheta x dv the error is hundreds of metres).
    """
    errors, _ = long_run
    e60 = errors[6000]["trochoid"]
    e600 = errors[N_LONG]["trochoid"]
    assert np.linalg.norm(e60[6:9]) < 5e-3, e60
    assert np.linalg.norm(e600[6:9]) < 0.15, e600
    assert np.linalg.norm(e600[3:6]) < 1e-3, e600
    assert np.linalg.norm(e600[0:3]) < 5e-6, e600


def test_two_sample_coning_sculling_correction():
    """With the previous sample the third-order coning/sculling errors cancel (T&W 11.2)."""
    n = 3000  # 30 s
    f, w = imu_means(trochoid, n)
    r0, v0, C0, _, _ = trochoid(np.array([0.0]))
    rt, vt, Ct, _, _ = trochoid(np.array([n * DT]))
    out = []
    for two_sample in (False, True):
        r, v, C = r0, v0, C0
        for k in range(n):
            if two_sample and k > 0:
                r, v, C = mechanize(r, v, C, f[k:k + 1], w[k:k + 1], DT, f_prev=f[k - 1:k], w_prev=w[k - 1:k])
            else:
                r, v, C = mechanize(r, v, C, f[k:k + 1], w[k:k + 1], DT)
        out.append(navigation_error(rt, vt, Ct, r, v, C)[0])
    single, double = out
    assert np.linalg.norm(double[0:3]) < 0.02 * np.linalg.norm(single[0:3])
    assert np.linalg.norm(double[3:6]) < 0.05 * np.linalg.norm(single[3:6])
    assert np.linalg.norm(double[6:9]) < 0.05 * np.linalg.norm(single[6:9])
    assert np.linalg.norm(double[6:9]) < 3e-5


def test_previous_sample_equal_to_current_changes_nothing_when_rates_constant():
    """dtheta_prev x dtheta = 0 and the sculling terms cancel for identical samples."""
    rng = np.random.default_rng(1)
    r = geodetic_to_ecef(0.7, 0.1, 10.0)[None].repeat(3, 0)
    v = rng.normal(size=(3, 3)) * 10
    C = exp_so3(rng.normal(size=(3, 3)))
    f = rng.normal(size=(3, 3)) * 3
    w = rng.normal(size=(3, 3)) * 0.3
    a = mechanize(r, v, C, f, w, DT)
    b = mechanize(r, v, C, f, w, DT, f_prev=f, w_prev=w)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-12 * max(1.0, np.abs(x).max()))
    with pytest.raises(ValueError, match="f_prev"):
        mechanize(r, v, C, f, w, DT, w_prev=w)


# --------------------------------------------------------------------------------------
# corrections, batching, dtypes, helpers
# --------------------------------------------------------------------------------------
def _random_state(rng, B):
    lat = rng.uniform(-1.4, 1.4, B)
    lon = rng.uniform(-np.pi, np.pi, B)
    r = geodetic_to_ecef(lat, lon, rng.uniform(0, 2000, B))
    v = rng.normal(size=(B, 3)) * 15
    C = ned_attitude_to_ecef(rng.normal(size=B) * 0.1, rng.normal(size=B) * 0.1, rng.uniform(-3, 3, B), lat, lon)
    return r, v, C


def test_apply_correction_is_inverse_of_navigation_error():
    rng = np.random.default_rng(2)
    r, v, C = _random_state(rng, 6)
    dx = np.concatenate([rng.normal(size=(6, 3)) * 0.05, rng.normal(size=(6, 3)), rng.normal(size=(6, 3)) * 10,
                         rng.normal(size=(6, 8))], axis=1)        # 17 states; the last 8 are ignored
    r2, v2, C2 = apply_correction(r, v, C, dx)
    np.testing.assert_allclose(navigation_error(r2, v2, C2, r, v, C), dx[:, :9], atol=1e-12)
    # truth = apply_correction(estimate, truth - estimate)
    r3, v3, C3 = apply_correction(r, v, C, navigation_error(r2, v2, C2, r, v, C))
    np.testing.assert_allclose(r3, r2, atol=1e-8)
    np.testing.assert_allclose(v3, v2, atol=1e-13)
    np.testing.assert_allclose(C3, C2, atol=1e-14)
    # the correction is applied on the left, in the e frame: C_true = exp(dpsi) C_est
    np.testing.assert_allclose(C2, exp_so3(dx[:, 0:3]) @ C, atol=1e-15)
    assert np.abs(C2 - C @ exp_so3(dx[:, 0:3])).max() > 1e-3
    # undo
    r4, v4, C4 = apply_correction(r2, v2, C2, -dx)
    np.testing.assert_allclose(C4, C, atol=1e-14)
    np.testing.assert_allclose(v4, v, atol=1e-13)
    np.testing.assert_allclose(r4, r, atol=1e-8)
    # first-order convention: C_true ~ (I + [dpsi x]) C_est
    small = dx * 1e-4
    _, _, C5 = apply_correction(r, v, C, small)
    first_order = C + np.stack([np.cross(small[:, 0:3], C[:, :, j]) for j in range(3)], -1)
    np.testing.assert_allclose(C5, first_order, atol=1e-10)
    with pytest.raises(ValueError, match="dx"):
        apply_correction(r, v, C, dx[:, :5])


def test_batch_rows_are_independent_and_dt_array_matches_scalar():
    rng = np.random.default_rng(3)
    B = 5
    r, v, C = _random_state(rng, B)
    f = rng.normal(size=(B, 3)) * 2 + np.array([0, 0, -9.8])
    w = rng.normal(size=(B, 3)) * 0.5
    w[2] *= 40  # one row turns fast (|dtheta| > 0.01 rad: the sin/cos branch)
    batch = mechanize(r, v, C, f, w, DT)
    for i in range(B):
        single = mechanize(r[i:i + 1], v[i:i + 1], C[i:i + 1], f[i:i + 1], w[i:i + 1], DT)
        for x, y in zip(batch, single):
            np.testing.assert_allclose(x[i:i + 1], y, rtol=1e-15, atol=1e-12)
    arr = mechanize(r, v, C, f, w, np.full(B, DT))
    for x, y in zip(batch, arr):
        np.testing.assert_allclose(x, y, rtol=1e-15, atol=1e-12)
    # a row with a different dt gets the result of that dt
    dts = np.array([DT, 2 * DT, DT, 0.5 * DT, DT])
    mixed = mechanize(r, v, C, f, w, dts)
    one = mechanize(r[1:2], v[1:2], C[1:2], f[1:2], w[1:2], 2 * DT)
    np.testing.assert_allclose(mixed[0][1:2], one[0], atol=1e-9)
    np.testing.assert_allclose(mixed[2][1:2], one[2], atol=1e-15)
    # a large batch takes the large-B kernels (einsum, row mixing): same rows
    B = 70
    r, v, C = _random_state(rng, B)
    f = rng.normal(size=(B, 3)) * 2
    w = rng.normal(size=(B, 3)) * 0.5
    big = mechanize(r, v, C, f, w, DT)
    for i in (0, 33, 69):
        single = mechanize(r[i:i + 1], v[i:i + 1], C[i:i + 1], f[i:i + 1], w[i:i + 1], DT)
        for x, y in zip(big, single):
            np.testing.assert_allclose(x[i:i + 1], y, rtol=1e-15, atol=1e-12)


def test_large_rotation_per_step_is_exact_for_constant_rate():
    """|dtheta| = 0.5 rad per step: the closed-form attitude update is exact (no series)."""
    r, v, C = _random_state(np.random.default_rng(4), 1)
    w_e = np.array([[0.3, -40.0, 20.0]])             # body rate, rad/s
    f = np.zeros((1, 3))
    _, _, C1 = mechanize(r, v, C, f, w_e, DT)
    c, s = np.cos(OMEGA_IE * DT), np.sin(OMEGA_IE * DT)
    Cz = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(C1, Cz @ C @ exp_so3(w_e * DT), atol=1e-14)


def test_float32_preserved_and_close_to_float64():
    rng = np.random.default_rng(5)
    B = 4
    r, v, C = _random_state(rng, B)
    f = rng.normal(size=(B, 3)) * 2 + np.array([0, 0, -9.8])
    w = rng.normal(size=(B, 3)) * 0.3
    args32 = [x.astype(np.float32) for x in (r, v, C, f, w)]
    args64 = [x.astype(np.float64) for x in args32]
    o32 = mechanize(*args32, DT)
    o64 = mechanize(*args64, DT)
    assert all(x.dtype == np.float32 for x in o32)
    assert all(x.dtype == np.float64 for x in o64)
    # one step: within a few float32 ulps of each quantity
    assert np.abs(o32[0] - o64[0]).max() <= 2 * np.spacing(np.float32(6.4e6))   # 1 m: |r| spacing is 0.5 m
    np.testing.assert_allclose(o32[1], o64[1], atol=2e-5)
    np.testing.assert_allclose(o32[2], o64[2], atol=5e-7)
    # 10 s of the trochoid: attitude and velocity stay close (float32 DCM re-orthonormalized)
    n = 1000
    fm, wm = imu_means(trochoid, n)
    r0, v0, C0, _, _ = trochoid(np.array([0.0]))
    s32 = [x.astype(np.float32) for x in (r0, v0, C0)]
    s64 = [r0, v0, C0]
    fm32, wm32 = fm.astype(np.float32), wm.astype(np.float32)
    for k in range(n):
        s32 = mechanize(*s32, fm32[k:k + 1], wm32[k:k + 1], DT)
        s64 = mechanize(*s64, fm[k:k + 1], wm[k:k + 1], DT)
    assert all(np.isfinite(x).all() and x.dtype == np.float32 for x in s32)
    e = navigation_error(*s64, *[x.astype(np.float64) for x in s32])[0]
    assert np.linalg.norm(e[0:3]) < 2e-5          # rad
    assert np.abs(s32[2].astype(float) @ s32[2][0].T.astype(float) - np.eye(3)).max() < 1e-6
    # position: float32 rounding of |r| ~ 6.4e6 m is 0.25 m per moving step at worst
    assert np.linalg.norm(e[6:9]) < 0.25 * n


def test_orthonormalize_dcm_converges_quadratically():
    rng = np.random.default_rng(6)
    C = exp_so3(rng.normal(size=(8, 3)))
    E = 1e-4 * rng.normal(size=(8, 3, 3))
    C1 = orthonormalize_dcm(C + E)
    err0 = np.abs((C + E) @ np.swapaxes(C + E, -1, -2) - np.eye(3)).max()
    err1 = np.abs(C1 @ np.swapaxes(C1, -1, -2) - np.eye(3)).max()
    assert err0 > 1e-5 and err1 < 10 * err0**2


def test_ned_attitude_to_ecef():
    lat, lon = np.array([0.7, -0.2]), np.array([0.3, 2.0])
    C = ned_attitude_to_ecef(np.zeros(2), np.zeros(2), np.zeros(2), lat, lon)
    assert C.shape == (2, 3, 3)
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], -1)
    north = np.stack([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)], -1)
    np.testing.assert_allclose(C[:, :, 2], -up, atol=1e-15)     # body z (down)
    np.testing.assert_allclose(C[:, :, 0], north, atol=1e-15)   # body x (forward) north at yaw 0
    C90 = ned_attitude_to_ecef(0.0, 0.0, np.pi / 2, lat, lon)
    np.testing.assert_allclose(C90[:, :, 1], -north, atol=1e-15)  # yaw 90: right wing points south
    C32 = ned_attitude_to_ecef(*(np.zeros(2, np.float32),) * 3, lat.astype(np.float32), lon.astype(np.float32))
    assert C32.dtype == np.float32
