"""Invariants of the shared Earth layer (WGS84, gravity, rotations, ranging)."""
import numpy as np
import pytest

import earth
from earth import rotations as rot
from earth import units, wgs84
from earth.ranging import range_and_rate


def test_geodetic_round_trip_and_known_point():
    rng = np.random.default_rng(0)
    lat = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, 500)
    lon = rng.uniform(-np.pi, np.pi, 500)
    h = rng.uniform(-500, 20000, 500)
    r = wgs84.geodetic_to_ecef(lat, lon, h)
    lat2, lon2, h2 = wgs84.ecef_to_geodetic(r)
    assert np.max(np.abs(lat2 - lat)) < 1e-12
    assert np.max(np.abs(np.angle(np.exp(1j * (lon2 - lon))))) < 1e-12
    assert np.max(np.abs(h2 - h)) < 1e-6
    # equator / prime meridian is the semi-major axis; the pole is the semi-minor axis
    np.testing.assert_allclose(wgs84.geodetic_to_ecef(0.0, 0.0, 0.0), [wgs84.A, 0, 0], atol=1e-9)
    np.testing.assert_allclose(wgs84.geodetic_to_ecef(np.pi / 2, 0.0, 0.0), [0, 0, wgs84.B_AXIS], atol=1e-6)


def test_C_en_orthonormal_and_axes():
    C = wgs84.C_en(np.array([0.3, -1.0]), np.array([2.0, 0.1]))
    np.testing.assert_allclose(C @ C.mT, np.broadcast_to(np.eye(3), C.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(C), 1.0, atol=1e-14)
    # down axis is minus the ellipsoid normal: it points from a surface point toward the equatorial plane
    lat, lon = 0.7, 0.2
    r = wgs84.geodetic_to_ecef(lat, lon, 0.0)
    r_up = wgs84.geodetic_to_ecef(lat, lon, 1.0)
    np.testing.assert_allclose(wgs84.C_en(lat, lon)[:, 2], r - r_up, atol=1e-8)


def test_gravity_matches_somigliana_normal_gravity():
    # Somigliana normal gravity on the ellipsoid with the free-air gradient: an independent formula.
    for lat_deg in (0.0, 30.0, 48.8, 80.0):
        lat = np.deg2rad(lat_deg)
        s2 = np.sin(lat) ** 2
        g0 = 9.7803253359 * (1 + 0.00193185265241 * s2) / np.sqrt(1 - 0.00669437999013 * s2)
        g = wgs84.gravity_ecef(wgs84.geodetic_to_ecef(lat, 0.0, 0.0))
        g_ned = wgs84.C_en(lat, 0.0).T @ g
        assert abs(g_ned[2] - g0) < 2e-4  # J2-only series vs closed form: 4e-5..1.2e-4 m/s^2 (< 20 ug)
        assert abs(g_ned[0]) < 5e-5 and abs(g_ned[1]) < 1e-12  # plumb line ~ along the normal


def test_compiled_gravity_is_the_numpy_formula_to_the_bit():
    """gravity_ecef's compiled float64 path equals the numpy evaluation of Groves eqs 2.133 and 2.142
    (gravitation_ecef plus the centrifugal term) bit for bit, in every shape and layout, signed zeros included;
    float32 keeps the numpy form and its dtype."""
    def numpy_form(r):
        g = wgs84.gravitation_ecef(r)
        cent = np.zeros_like(g)
        cent[..., 0] = wgs84.OMEGA_IE**2 * r[..., 0]
        cent[..., 1] = wgs84.OMEGA_IE**2 * r[..., 1]
        return g + cent

    rng = np.random.default_rng(11)
    for shape in ((3,), (1, 3), (17, 3), (4, 601, 3), (2, 3, 5, 3)):
        u = rng.normal(size=shape)
        u /= np.linalg.norm(u, axis=-1, keepdims=True)
        r = u * rng.uniform(6.35e6, 6.6e6, shape[:-1] + (1,))
        for x in (r, np.asfortranarray(r), r[..., ::-1].copy()[..., ::-1]):
            got = wgs84.gravity_ecef(x)
            assert got.shape == x.shape and got.dtype == np.float64
            assert got.tobytes() == numpy_form(x).tobytes()
    poles = np.array([[0.0, 0.0, 6.4e6], [-0.0, 0.0, -6.4e6], [6.4e6, -0.0, 0.0]])
    assert wgs84.gravity_ecef(poles).tobytes() == numpy_form(poles).tobytes()
    r32 = r.astype(np.float32)
    got32 = wgs84.gravity_ecef(r32)
    assert got32.dtype == np.float32 and got32.tobytes() == numpy_form(r32).tobytes()


def test_rotations():
    rng = np.random.default_rng(1)
    phi = rng.normal(size=(100, 3))
    C = rot.exp_so3(phi)
    np.testing.assert_allclose(C @ C.mT, np.broadcast_to(np.eye(3), C.shape), atol=1e-13)
    ok = np.linalg.norm(phi, axis=1) < 3.0
    np.testing.assert_allclose(rot.log_so3(C[ok]), phi[ok], atol=1e-9)
    small = 1e-5 * rng.normal(size=(10, 3))
    S = rot.skew(small)
    np.testing.assert_allclose(rot.exp_so3(small), np.eye(3) + S + S @ S / 2, atol=1e-17)
    v, w = rng.normal(size=(2, 50, 3))
    np.testing.assert_allclose(rot.skew(v) @ w[..., None], np.cross(v, w)[..., None], atol=1e-14)
    eul = np.stack([rng.uniform(-3, 3, 50), rng.uniform(-1.5, 1.5, 50), rng.uniform(-3, 3, 50)], -1)
    np.testing.assert_allclose(rot.euler_from_dcm(rot.dcm_from_euler(*eul.T)), eul, atol=1e-10)
    # yaw 90 deg maps body forward to east
    np.testing.assert_allclose(rot.dcm_from_euler(0, 0, np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-15)


def test_units():
    assert units.dph(3600 * 180 / np.pi) == pytest.approx(1.0)
    assert units.mg(1000) == pytest.approx(units.G0)
    assert units.dpsh(60 * 180 / np.pi) == pytest.approx(1.0)


def test_ranging_sagnac_and_rate():
    r_rx = earth.geodetic_to_ecef(0.85, 0.16, 300.0)
    v_rx = np.array([10.0, -5.0, 2.0])
    sat = np.array([[15.0e6, 4.0e6, 21.0e6], [-2.0e6, 14.0e6, 22.0e6]])
    sv = np.array([[1500.0, -2500.0, 300.0], [-3000.0, 100.0, 800.0]])
    rho, rho_dot, u = range_and_rate(sat, sv, r_rx, v_rx)
    # independent light-time solution: rotate the satellite by w*tau until tau converges
    for j in range(2):
        tau = 0.07
        for _ in range(10):
            th = wgs84.OMEGA_IE * tau
            Cz = np.array([[np.cos(th), np.sin(th), 0], [-np.sin(th), np.cos(th), 0], [0, 0, 1]])
            tau = np.linalg.norm(Cz @ sat[j] - r_rx) / wgs84.C_LIGHT
        assert abs(tau * wgs84.C_LIGHT - rho[j]) < 1e-6
    # Sagnac correction is tens of metres at most, and real
    plain = np.linalg.norm(sat - r_rx, axis=1)
    assert np.all(np.abs(rho - plain) < 50) and np.any(np.abs(rho - plain) > 1)
    np.testing.assert_allclose(np.linalg.norm(u, axis=-1), 1.0, atol=1e-15)
    # rate: finite difference of range with both ends moving, in a frame where the Earth turns
    dt = 1e-3
    rho2, _, _ = range_and_rate(sat + sv * dt, sv, r_rx + v_rx * dt, v_rx)
    np.testing.assert_allclose((rho2 - rho) / dt, rho_dot, atol=2e-3)
