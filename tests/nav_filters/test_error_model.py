"""Tests of the 17-state error model (nav_filters.error_model).

The key test is the linearization test: the error-state transition matrix must
predict how a small difference between a true and an estimated navigation
state (plus IMU-bias residuals) evolves when both are propagated by the
nonlinear INS (nav_filters.ins.mechanize).
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg

from earth.rotations import exp_so3
from earth.wgs84 import OMEGA_IE, C_en, geodetic_to_ecef, gravity_ecef
from nav_filters.error_model import (
    ATT,
    BA,
    BG,
    CLK,
    DRIFT,
    N_STATES,
    POS,
    STATE_NAMES,
    VEL,
    ProcessNoise,
    discretize,
    gravity_gradient,
    system_matrix,
    transition,
)
from nav_filters.ins import mechanize, navigation_error, ned_attitude_to_ecef

NOISE = ProcessNoise.from_imu_specs(arw=1e-3, vrw=2e-2, gyro_bias_instability=1e-5, gyro_bias_tau_s=300.0,
                                    accel_bias_instability=1e-3, accel_bias_tau_s=200.0,
                                    clock_q_bias=0.1, clock_q_drift=0.01)


def _random_inputs(rng, B, dtype=np.float64):
    lat = rng.uniform(-1.3, 1.3, B)
    lon = rng.uniform(-3, 3, B)
    C = ned_attitude_to_ecef(rng.normal(size=B) * 0.1, rng.normal(size=B) * 0.1, rng.uniform(-3, 3, B), lat, lon)
    f = rng.normal(size=(B, 3)) * 2 + np.array([0.0, 0.0, -9.8])
    r = geodetic_to_ecef(lat, lon, rng.uniform(0, 3000, B))
    return C.astype(dtype), f.astype(dtype), r.astype(dtype)


def test_state_layout():
    assert N_STATES == 17 and len(STATE_NAMES) == 17
    idx = np.arange(17)
    assert [list(idx[s]) for s in (ATT, VEL, POS, BG, BA, CLK, DRIFT)] == [
        [0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11], [12, 13, 14], [15], [16]]


# --------------------------------------------------------------------------------------
# linearization test
# --------------------------------------------------------------------------------------
SCALES = np.array([1e-4] * 3 + [1e-2] * 3 + [1.0] * 3 + [1e-4] * 3 + [1e-2] * 3)  # rad, m/s, m, rad/s, m/s^2


def _propagate_pair(x0, n_steps=100, dt=0.01, phi_fn=None):
    """Mechanize truth and the perturbed estimate; return (actual x1, Phi-predicted x1), (B, 15) each.

    ``x0`` (B, 15) is the initial error under the project convention (truth minus
    estimate): estimate = truth corrected *backwards* by x0, and the estimate
    integrates ``f + b_a``, ``w + b_g`` (raw = true + bias_true, corrected =
    raw - bias_est = true + residual).
    """
    lat, lon = 0.7, 0.3
    B = x0.shape[0]
    rt = np.repeat(geodetic_to_ecef(lat, lon, 200.0)[None], B, 0)
    vt = np.repeat((C_en(lat, lon) @ np.array([12.0, -8.0, 0.5]))[None], B, 0)
    Ct = np.repeat(ned_attitude_to_ecef(0.08, -0.05, 0.7, lat, lon)[None], B, 0)
    f = np.repeat(np.array([[1.5, 0.8, -9.7]]), B, 0)      # accelerating and turning
    w = np.repeat(np.array([[0.02, -0.03, 0.25]]), B, 0)
    re, ve, Ce = rt - x0[:, POS], vt - x0[:, VEL], exp_so3(-x0[:, ATT]) @ Ct
    fe, we = f + x0[:, BA], w + x0[:, BG]
    Phi = np.broadcast_to(np.eye(N_STATES), (B, N_STATES, N_STATES)).copy()
    for _ in range(n_steps):
        Phi = phi_fn(Ce, fe, re, dt) @ Phi        # F evaluated on the estimate, as a filter does
        rt, vt, Ct = mechanize(rt, vt, Ct, f, w, dt)
        re, ve, Ce = mechanize(re, ve, Ce, fe, we, dt)
    actual = np.concatenate([navigation_error(rt, vt, Ct, re, ve, Ce), x0[:, 9:15]], axis=1)
    x0_17 = np.concatenate([x0, np.zeros((B, 2))], axis=1)
    pred = np.einsum("bij,bj->bi", Phi, x0_17)[:, :15]
    return actual, pred


def _block_errors(actual, pred):
    """Per row and per block (att, vel, pos): |actual - pred| and |pred|."""
    num = np.stack([np.linalg.norm(actual[:, s] - pred[:, s], axis=1) for s in (ATT, VEL, POS)], 1)
    den = np.stack([np.linalg.norm(pred[:, s], axis=1) for s in (ATT, VEL, POS)], 1)
    return num, den


def _linearization_rows():
    rng = np.random.default_rng(0)
    return np.concatenate([np.diag(SCALES), (rng.normal(size=(2, 15)) * SCALES)], 0)   # 15 unit columns + 2 mixed


def test_linearization_matches_nonlinear_ins():
    """Phi (product of 100 steps of 10 ms) predicts the nonlinear error growth over 1 s to < 2 %.

    Each of the first 15 rows perturbs one state (so every column of F is
    checked separately, block by block); the last two perturb all at once.
    Measured mismatch: < 0.5 % in every block (second-order terms and the
    neglected J2 gravity gradient).
    """
    def phi_fn(C, f, r, dt):
        return transition(C, f, r, NOISE, dt)[0]
    x0 = _linearization_rows()
    actual, pred = _propagate_pair(x0, phi_fn=phi_fn)
    num, den = _block_errors(actual, pred)
    atol = np.array([1e-12, 1e-10, 1e-9])        # rad, m/s, m: rounding level of the 1 s runs
    assert np.all(num <= 0.02 * den + atol), (num / np.maximum(den, 1e-300))
    # the test has teeth: every perturbation produced a clear response outside its own block
    assert den[0:3, 1].min() > 5e-4        # attitude -> velocity  (g * 1e-4 rad * 1 s ~ 1e-3 m/s)
    assert den[6:9, 1].min() > 5e-7        # position -> velocity  (gravity gradient, ~2e-6 m/s)
    assert den[9:12, 0].min() > 5e-5       # gyro bias -> attitude
    assert den[12:15, 1].min() > 5e-3      # accel bias -> velocity


def test_linearization_detects_wrong_signs():
    """Flipping the sign of one coupling block makes the prediction miss by > 50 %."""
    x0 = _linearization_rows()[:15]
    for rows, cols, probe_rows, blk in ((ATT, BG, slice(9, 12), 0), (VEL, ATT, slice(0, 3), 1),
                                        (VEL, POS, slice(6, 9), 1), (VEL, BA, slice(12, 15), 1)):
        def phi_fn(C, f, r, dt, rows=rows, cols=cols):
            F = system_matrix(C, f, r, NOISE.gyro_bias_tau_s, NOISE.accel_bias_tau_s)
            F[:, rows, cols] *= -1.0
            return discretize(F, C, NOISE, dt)[0]
        actual, pred = _propagate_pair(x0[probe_rows], n_steps=20, phi_fn=phi_fn)
        num, den = _block_errors(actual, pred)
        assert np.all(num[:, blk] > 0.5 * den[:, blk]), (rows, cols)


def test_radial_gravity_gradient_misses_horizontal_term():
    """Groves eq 14.49's radial-only gradient mispredicts horizontal position errors (Schuler term)."""
    x0 = _linearization_rows()[6:9]
    def phi_fn(C, f, r, dt):
        return transition(C, f, r, NOISE, dt, gravity_form="radial")[0]
    actual, pred = _propagate_pair(x0, phi_fn=phi_fn)
    num, den = _block_errors(actual, pred)
    assert np.max(num[:, 1] / den[:, 1]) > 0.3


def test_gravity_gradient_matches_numerical_jacobian():
    rng = np.random.default_rng(1)
    _, _, r = _random_inputs(rng, 4)
    G = gravity_gradient(r)
    e = 1.0
    num = np.stack([(gravity_ecef(r + e * np.eye(3)[j]) - gravity_ecef(r - e * np.eye(3)[j])) / (2 * e)
                    for j in range(3)], -1)
    scale = np.abs(num).max()
    assert np.abs(G - num).max() < 1e-2 * scale     # J2 part neglected (measured 5e-3 of the largest entry)
    np.testing.assert_allclose(G, np.swapaxes(G, -1, -2), atol=1e-22)
    Gr = gravity_gradient(r, "radial")
    u = r / np.linalg.norm(r, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("bi,bij,bj->b", u, Gr, u), np.einsum("bi,bij,bj->b", u, num, u), rtol=5e-3)
    with pytest.raises(ValueError, match="form"):
        gravity_gradient(r, "flat")


# --------------------------------------------------------------------------------------
# structure of F, Phi, Qd
# --------------------------------------------------------------------------------------
def test_system_matrix_blocks():
    rng = np.random.default_rng(2)
    C, f, r = _random_inputs(rng, 3)
    F = system_matrix(C, f, r, gyro_bias_tau_s=100.0, accel_bias_tau_s=None)
    a = np.einsum("bij,bj->bi", C, f)
    Om = np.array([[0, -OMEGA_IE, 0], [OMEGA_IE, 0, 0], [0, 0, 0]])
    np.testing.assert_array_equal(F[:, ATT, ATT], np.broadcast_to(-Om, (3, 3, 3)))
    np.testing.assert_array_equal(F[:, ATT, BG], -C)
    # velocity <- attitude is -[a x] with a = C f: applied to psi it gives -(a x psi) = psi x a
    psi = rng.normal(size=(3, 3))
    np.testing.assert_allclose(np.einsum("bij,bj->bi", F[:, VEL, ATT], psi), np.cross(psi, a), atol=1e-14)
    np.testing.assert_array_equal(F[:, VEL, VEL], np.broadcast_to(-2 * Om, (3, 3, 3)))
    np.testing.assert_array_equal(F[:, VEL, POS], gravity_gradient(r))
    np.testing.assert_array_equal(F[:, VEL, BA], -C)
    np.testing.assert_array_equal(F[:, POS, VEL], np.broadcast_to(np.eye(3), (3, 3, 3)))
    np.testing.assert_array_equal(F[:, BG, BG], np.broadcast_to(-np.eye(3) / 100.0, (3, 3, 3)))
    np.testing.assert_array_equal(F[:, BA, BA], 0.0)       # random walk
    assert np.all(F[:, 15, 16] == 1.0)
    # nothing else is nonzero
    mask = np.zeros((17, 17), bool)
    for rs, cs in ((ATT, ATT), (ATT, BG), (VEL, ATT), (VEL, VEL), (VEL, POS), (VEL, BA), (POS, VEL),
                   (BG, BG), (BA, BA), (CLK, DRIFT)):
        mask[rs, cs] = True
    assert np.all(F[:, ~mask] == 0.0)
    with pytest.raises(ValueError, match="gyro_bias_tau_s"):
        system_matrix(C, f, r, gyro_bias_tau_s=-1.0)
    buf = np.full((3, 17, 17), np.nan)
    F2 = system_matrix(C, f, r, gyro_bias_tau_s=100.0, out=buf)
    assert F2 is buf
    np.testing.assert_array_equal(F2, F)
    with pytest.raises(ValueError, match="out"):
        system_matrix(C, f, r, out=np.zeros((3, 17, 17), np.float32))


def test_zero_F_gives_identity_and_Qc_dt():
    B = 2
    F = np.zeros((B, 17, 17))
    C = np.repeat(np.eye(3)[None], B, 0)
    for order in (1, 2):
        Phi, Qd = discretize(F, C, NOISE, 0.02, order=order)
        np.testing.assert_array_equal(Phi, np.broadcast_to(np.eye(17), (B, 17, 17)))
        np.testing.assert_allclose(Qd, np.broadcast_to(np.diag(NOISE.diagonal()) * 0.02, (B, 17, 17)), rtol=1e-15)


def test_order_one_and_two():
    rng = np.random.default_rng(3)
    C, f, r = _random_inputs(rng, 2)
    F = system_matrix(C, f, r, 300.0, 200.0)
    dt = 0.05
    P1, _ = discretize(F, C, NOISE, dt, order=1)
    P2, _ = discretize(F, C, NOISE, dt, order=2)
    I = np.eye(17)
    np.testing.assert_allclose(P1, I + F * dt, atol=1e-15)
    np.testing.assert_allclose(P2, I + F * dt + 0.5 * (F * dt) @ (F * dt), atol=1e-15)
    with pytest.raises(ValueError, match="order"):
        discretize(F, C, NOISE, dt, order=3)
    with pytest.raises(ValueError, match="dt"):
        discretize(F, C, NOISE, -1.0)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_transition_is_discretize_of_system_matrix_with_noise_taus(dtype):
    rng = np.random.default_rng(4)
    B = 6
    C, f, r = _random_inputs(rng, B, dtype)
    dt = rng.uniform(0.005, 0.5, B)
    for noise in (NOISE, dataclasses.replace(NOISE, gyro_bias_tau_s=None, accel_bias_tau_s=None)):
        F = system_matrix(C, f, r, noise.gyro_bias_tau_s, noise.accel_bias_tau_s)
        P1, Q1 = discretize(F, C, noise, dt)
        P2, Q2 = transition(C, f, r, noise, dt)
        assert P2.dtype == Q2.dtype == P1.dtype == Q1.dtype == dtype
        np.testing.assert_array_equal(P2, P1)
        np.testing.assert_array_equal(Q2, Q1)
    with pytest.raises(TypeError):
        transition(C, f, r, {"gyro_psd": 1.0}, dt)


def test_Qd_symmetric_psd_and_matches_van_loan():
    rng = np.random.default_rng(5)
    C, f, r = _random_inputs(rng, 3)
    dt = 0.01
    Phi, Qd = transition(C, f, r, NOISE, dt)
    np.testing.assert_array_equal(Qd, np.swapaxes(Qd, -1, -2))
    assert np.linalg.eigvalsh(Qd).min() > -1e-12 * np.abs(Qd).max()
    assert np.all(np.diagonal(Qd, axis1=1, axis2=2) > 0)
    F = system_matrix(C, f, r, NOISE.gyro_bias_tau_s, NOISE.accel_bias_tau_s)
    Qs = np.diag(NOISE.diagonal())
    for b in range(3):
        # Van Loan: expm([[-F, Qs], [0, F^T]] dt) -> exact Phi and Qd
        A = np.zeros((34, 34))
        A[:17, :17] = -F[b]
        A[:17, 17:] = Qs
        A[17:, 17:] = F[b].T
        E = scipy.linalg.expm(A * dt)
        Phi_x = E[17:, 17:].T
        Q_x = Phi_x @ E[:17, 17:]
        assert np.abs(Phi[b] - Phi_x).max() < 1e-5                        # third-order terms (~1.3e-6)
        assert np.linalg.norm(Qd[b] - Q_x) < 1e-4 * np.linalg.norm(Q_x)   # measured ~2e-6
        # the trapezoid's known weakness: position variance q_a dt^3 / 2 instead of / 3
        np.testing.assert_allclose(np.diagonal(Qd[b])[6:9] / np.diagonal(Q_x)[6:9], 1.5, rtol=0.02)


def test_anisotropic_psd_is_rotated_into_ecef():
    rng = np.random.default_rng(6)
    C, f, r = _random_inputs(rng, 2)
    q = (1e-6, 4e-6, 9e-6)
    noise = ProcessNoise(gyro_psd=q, accel_psd=0.0)
    F = np.zeros((2, 17, 17))
    _, Qd = discretize(F, C, noise, 1.0)
    np.testing.assert_allclose(Qd[:, ATT, ATT], C @ np.diag(q) @ np.swapaxes(C, -1, -2), atol=1e-20)
    iso = ProcessNoise(gyro_psd=(2e-6, 2e-6, 2e-6), accel_psd=0.0)
    assert iso.isotropic and iso.gyro_psd == 2e-6


def test_dtype_preserved():
    rng = np.random.default_rng(7)
    C, f, r = _random_inputs(rng, 2, np.float32)
    F = system_matrix(C, f, r)
    assert F.dtype == np.float32
    Phi, Qd = discretize(F, C, NOISE, 0.01)
    assert Phi.dtype == Qd.dtype == np.float32
    Phi2, Qd2 = transition(C, f, r, NOISE, np.full(2, 0.01))
    assert Phi2.dtype == Qd2.dtype == np.float32
    assert gravity_gradient(r).dtype == np.float32
    assert system_matrix(C.astype(np.float64), f, r).dtype == np.float64


def test_batch_rows_independent_and_out_buffers():
    rng = np.random.default_rng(8)
    B = 40
    C, f, r = _random_inputs(rng, B)
    dts = rng.uniform(0.005, 0.02, B)
    Phi, Qd = transition(C, f, r, NOISE, dts)
    for i in (0, 17, 39):
        P1, Q1 = transition(C[i:i + 1], f[i:i + 1], r[i:i + 1], NOISE, dts[i])
        np.testing.assert_allclose(Phi[i:i + 1], P1, rtol=0, atol=1e-15)
        np.testing.assert_allclose(Qd[i:i + 1], Q1, rtol=0, atol=1e-15 * np.abs(Q1).max())
    # writing into the caller's (dirty) buffers gives the same result, in place
    bufs = (np.full((B, 17, 17), np.nan), np.full((B, 17, 17), 7.0))
    P2, Q2 = transition(C, f, r, NOISE, dts, out=bufs)
    assert P2 is bufs[0] and Q2 is bufs[1]
    np.testing.assert_array_equal(P2, Phi)
    np.testing.assert_array_equal(Q2, Qd)
    with pytest.raises(ValueError, match="out"):
        transition(C, f, r, NOISE, dts, out=(bufs[0], bufs[0]))
    with pytest.raises(ValueError, match="out"):
        transition(C, f, r, NOISE, dts, out=(bufs[0][:3], bufs[1][:3]))


# --------------------------------------------------------------------------------------
# ProcessNoise
# --------------------------------------------------------------------------------------
@pytest.mark.parametrize("field", ["gyro_psd", "accel_psd", "gyro_bias_psd", "accel_bias_psd",
                                   "clock_bias_psd", "clock_drift_psd"])
@pytest.mark.parametrize("bad", [-1e-9, float("nan"), float("inf"), "x"])
def test_process_noise_rejects_bad_values_naming_the_field(field, bad):
    kw = dict(gyro_psd=1e-6, accel_psd=1e-4)
    kw[field] = bad
    with pytest.raises(ValueError, match=field):
        ProcessNoise(**kw)


@pytest.mark.parametrize("field", ["gyro_bias_tau_s", "accel_bias_tau_s"])
@pytest.mark.parametrize("bad", [0.0, -5.0, float("inf"), float("nan")])
def test_process_noise_rejects_bad_tau(field, bad):
    with pytest.raises(ValueError, match=field):
        ProcessNoise(gyro_psd=1e-6, accel_psd=1e-4, **{field: bad})


def test_process_noise_per_axis_and_frozen():
    with pytest.raises(ValueError, match="gyro_psd"):
        ProcessNoise(gyro_psd=(1e-6, 2e-6), accel_psd=1e-4)
    with pytest.raises(ValueError, match="accel_bias_psd"):
        ProcessNoise(gyro_psd=1e-6, accel_psd=1e-4, accel_bias_psd=(1e-6, -1.0, 0.0))
    with pytest.raises(ValueError, match="clock_bias_psd"):
        ProcessNoise(gyro_psd=1e-6, accel_psd=1e-4, clock_bias_psd=(1.0, 1.0, 1.0))
    n = ProcessNoise(gyro_psd=[1e-6, 2e-6, 3e-6], accel_psd=1e-4)
    assert n.gyro_psd == (1e-6, 2e-6, 3e-6) and not n.isotropic
    with pytest.raises(dataclasses.FrozenInstanceError):
        n.gyro_psd = 0.0


def test_from_imu_specs():
    n = ProcessNoise.from_imu_specs(arw=2e-3, vrw=3e-2, gyro_bias_instability=1e-5, gyro_bias_tau_s=500.0,
                                    accel_bias_instability=(1e-3, 2e-3, 3e-3), accel_bias_tau_s=100.0,
                                    clock_q_bias=0.5, clock_q_drift=0.05)
    assert n.gyro_psd == pytest.approx(4e-6) and n.accel_psd == pytest.approx(9e-4)
    assert n.gyro_bias_psd == pytest.approx(2 * 1e-10 / 500.0)
    assert n.accel_bias_psd == pytest.approx((2e-6 / 100, 8e-6 / 100, 18e-6 / 100))
    assert n.gyro_bias_tau_s == 500.0 and n.accel_bias_tau_s == 100.0
    assert (n.clock_bias_psd, n.clock_drift_psd) == (0.5, 0.05)
    # GM steady state: q tau / 2 = sigma^2 (the discretized recursion converges to it)
    F = system_matrix(np.eye(3)[None], np.zeros((1, 3)), np.array([[6.4e6, 0, 0]]), 500.0, 100.0)
    Phi, Qd = discretize(F, np.eye(3)[None], n, 1.0)
    p = 0.0
    for _ in range(20000):
        p = Phi[0, 9, 9] ** 2 * p + Qd[0, 9, 9]
    assert p == pytest.approx(1e-10, rel=2e-3)
    # tau None or inf: a random constant, no driving noise
    c = ProcessNoise.from_imu_specs(1e-3, 1e-2, gyro_bias_instability=1e-5, gyro_bias_tau_s=float("inf"))
    assert c.gyro_bias_psd == 0.0 and c.gyro_bias_tau_s is None
    with pytest.raises(ValueError, match="accel_bias_tau_s"):
        ProcessNoise.from_imu_specs(1e-3, 1e-2, accel_bias_instability=1e-3, accel_bias_tau_s=-3.0)
    with pytest.raises(ValueError, match="arw"):
        ProcessNoise.from_imu_specs(-1e-3, 1e-2)
    with pytest.raises(TypeError):
        discretize(F, np.eye(3)[None], {"gyro_psd": 1.0}, 1.0)
