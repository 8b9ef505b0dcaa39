"""Tests of the simulated GNSS world (envs.sim.gnss / envs.sim.constellation)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from earth.wgs84 import C_LIGHT, GM, OMEGA_IE, C_en, ecef_to_geodetic, geodetic_to_ecef
from envs.sim.constellation import Constellation
from envs.sim.gnss import (
    ClockModel,
    GnssData,
    GnssEvents,
    NlosConfig,
    ReceiverConfig,
    UrbanCanyon,
    _gauss_markov,
    iono_obliquity,
    simulate_clock,
    simulate_gnss,
    tropo_mapping,
)
from envs.sim.rng import row_generators

CON = Constellation()


def _rz(theta, v):
    """Frame rotation C_z(theta) applied to (..., 3) vectors (written here, independently of earth.ranging)."""
    c, s = np.cos(theta), np.sin(theta)
    return np.stack([c * v[..., 0] + s * v[..., 1], -s * v[..., 0] + c * v[..., 1], v[..., 2]], -1)


def _static(lats_deg, M, lon_deg=11.0, h=300.0):
    """(B, M, 3) static receivers at the given latitudes, zero velocity."""
    r = np.stack([np.broadcast_to(geodetic_to_ecef(math.radians(la), math.radians(lon_deg), h), (M, 3))
                  for la in lats_deg])
    return r.copy(), np.zeros_like(r)


def _driving(B, t, speed=15.0, heading_deg=90.0, lat_deg=52.5, lon_deg=13.4):
    """(B, M, 3) receivers driving straight at constant ECEF velocity along a local heading."""
    r0 = geodetic_to_ecef(math.radians(lat_deg), math.radians(lon_deg), 50.0)
    hd = math.radians(heading_deg)
    v_n = np.array([speed * math.cos(hd), speed * math.sin(hd), 0.0])
    v_e = C_en(math.radians(lat_deg), math.radians(lon_deg)) @ v_n
    r = r0 + t[:, None] * v_e
    r = np.broadcast_to(r, (B,) + r.shape).copy()
    v = np.broadcast_to(v_e, r.shape).copy()
    heading = np.full((B, t.size), hd)
    return r, v, heading


def _sim(t, r, v, heading=None, receiver=None, events=None, seeds=None, t0_gps=None, dtype=np.float64,
         constellation=CON):
    B = r.shape[0]
    seeds = list(range(B)) if seeds is None else seeds
    return simulate_gnss(t, r, v, heading, constellation, receiver or ReceiverConfig(), events or GnssEvents(),
                         row_generators(seeds, "gnss"), t0_gps=t0_gps, dtype=dtype)


def _light_time_range(sat_pos, r_rx):
    """Own light-time loop: rho = |C_z(w tau) r_s - r_r|, tau = rho / c, iterated to convergence."""
    tau = np.zeros(sat_pos.shape[:-1])
    for _ in range(8):
        d = _rz(OMEGA_IE * tau, sat_pos) - r_rx
        rho = np.sqrt(np.sum(d * d, -1))
        tau = rho / C_LIGHT
    return rho, d


# ============================================================================ constellation
def test_orbits_radius_speed_inclination_period():
    t = np.array([0.0, 1000.0, 43_210.5, 3.0e5])
    pos, vel = CON.positions_velocities(t)
    S = CON.n_sats
    assert 24 <= S <= 31 and pos.shape == (4, S, 3) and vel.shape == (4, S, 3)
    r = np.linalg.norm(pos, axis=-1)
    np.testing.assert_allclose(r, 26_559_700.0, rtol=1e-12)
    # inertial velocity resolved in ECEF: v_e + Omega x r_e
    v_i = vel + np.cross(np.array([0.0, 0.0, OMEGA_IE]), pos)
    speed = np.linalg.norm(v_i, axis=-1)
    np.testing.assert_allclose(speed, math.sqrt(GM / 26_559_700.0), rtol=1e-10)
    assert np.all(np.abs(speed - 3874.0) < 10.0)
    np.testing.assert_allclose(np.sum(pos * v_i, -1) / (r * speed), 0.0, atol=1e-12)   # circular
    h = np.cross(pos, v_i)                                                               # angular momentum
    inc = np.degrees(np.arccos(h[..., 2] / np.linalg.norm(h, axis=-1)))
    np.testing.assert_allclose(inc, 55.0, atol=1e-9)
    # six distinct planes (node directions), sats_per_plane satellites in each
    node = np.round(np.degrees(np.arctan2(h[0, :, 0], -h[0, :, 1])), 6) % 360.0
    vals, counts = np.unique(node, return_counts=True)
    assert len(vals) == 6 and np.all(counts == CON.sats_per_plane)
    # ECEF velocity is the time derivative of the ECEF position (includes -Omega x r)
    dt = 0.01
    pp, _ = CON.positions_velocities(t + dt)
    pm, _ = CON.positions_velocities(t - dt)
    np.testing.assert_allclose((pp - pm) / (2 * dt), vel, atol=2e-3)
    # one orbital period later the inertial position repeats
    T = CON.period_s
    assert 11.9 * 3600 < T < 12.0 * 3600
    p0, _ = CON.positions_velocities(np.array(100.0))
    p1, _ = CON.positions_velocities(np.array(100.0 + T))
    np.testing.assert_allclose(_rz(-OMEGA_IE * (100.0 + T), p1), _rz(-OMEGA_IE * 100.0, p0), atol=1e-4)


def test_constellation_sizes_and_subset():
    assert Constellation(sats_per_plane=4).n_sats == 24
    assert Constellation(sats_per_plane=5).n_sats == 30
    t = np.array([[10.0, 20.0]])
    idx = np.array([[[3, 7], [29, 0]]])
    p_all, v_all = CON.positions_velocities(t)
    p_sub, v_sub = CON.positions_velocities(t, idx)
    np.testing.assert_allclose(p_sub[0, 0], p_all[0, 0, [3, 7]], rtol=0, atol=1e-6)
    np.testing.assert_allclose(v_sub[0, 1], v_all[0, 1, [29, 0]], rtol=0, atol=1e-9)


# ============================================================================ visibility
def test_static_receiver_visibility_and_channels():
    lats = [0.0, 45.0, -35.0, 70.0]
    t = np.arange(0.0, 86_400.0, 240.0)
    r, v = _static(lats, t.size)
    rec = ReceiverConfig.ideal()
    d = _sim(t, r, v, receiver=rec, t0_gps=np.array([0.0, 1e4, 3e5, 5e5]))
    n = d.n_used()
    assert n.shape == (4, t.size)
    frac = np.mean((n >= 6) & (n <= 12), axis=1)
    assert np.all(frac >= 0.9), frac
    assert n.min() >= 5
    m = d.mask
    mask_rad = math.radians(rec.elevation_mask_deg)
    assert np.all(d.elevation[m] >= mask_rad)
    # channels sorted by elevation (descending), valid ones first, PRNs unique per epoch
    el = np.where(m, d.elevation, -10.0)
    assert np.all(np.diff(el, axis=-1) <= 0.0)
    assert np.all(m[..., :-1] >= m[..., 1:])
    prn_sorted = np.sort(np.where(m, d.prn, -np.arange(1, 17)), axis=-1)
    assert np.all(np.diff(prn_sorted, axis=-1) > 0)
    assert np.all((d.prn[m] >= 1) & (d.prn[m] <= CON.n_sats))
    # masked channels: finite zeros, prn -1
    for name in ("pr", "prr", "pr_sigma", "prr_sigma", "elevation", "azimuth", "pr_error_m"):
        a = getattr(d, name)
        assert np.all(np.isfinite(a)) and np.all(a[~m] == 0.0), name
    assert np.all(d.sat_pos[~m] == 0.0) and np.all(d.prn[~m] == -1)
    # elevation / azimuth recomputed independently from the ephemeris positions (NED at the receiver)
    rho, los = _light_time_range(d.sat_pos, r[:, :, None, :])
    lat, lon, _ = ecef_to_geodetic(r)
    los_n = np.einsum("bmji,bmcj->bmci", C_en(lat, lon), los)
    el_ind = np.arcsin(-los_n[..., 2] / rho)
    az_ind = np.arctan2(los_n[..., 1], los_n[..., 0]) % (2 * np.pi)
    np.testing.assert_allclose(d.elevation[m], el_ind[m], atol=1e-7)
    daz = np.angle(np.exp(1j * (d.azimuth[m] - az_ind[m])))
    assert np.max(np.abs(daz)) < 1e-6
    # the tracked set is every satellite above the mask (16 channels suffice): independent count
    t_gps = d.t0_gps[:, None] + t[None, :]
    p_all, _ = CON.positions_velocities(t_gps)
    u = p_all - r[:, :, None, :]
    up = np.einsum("bmj,bmcj->bmc", -C_en(lat, lon)[..., :, 2], u) / np.linalg.norm(u, axis=-1)
    n_ind = np.sum(np.arcsin(up) >= mask_rad, axis=-1)
    assert np.mean(n_ind == n) > 0.99


def test_channel_limit_and_mask():
    t = np.arange(0.0, 600.0, 60.0)
    r, v = _static([45.0], t.size)
    d8 = _sim(t, r, v, receiver=ReceiverConfig.ideal(n_channels=6), t0_gps=np.zeros(1))
    d16 = _sim(t, r, v, receiver=ReceiverConfig.ideal(), t0_gps=np.zeros(1))
    assert d8.pr.shape == (1, t.size, 6)
    assert np.all(d8.n_used() == np.minimum(d16.n_used(), 6))
    # the 6 channels hold the 6 highest satellites
    np.testing.assert_array_equal(d8.prn, d16.prn[..., :6])
    d_hi = _sim(t, r, v, receiver=ReceiverConfig.ideal(elevation_mask_deg=30.0), t0_gps=np.zeros(1))
    assert np.all(d_hi.n_used() < d16.n_used())
    assert np.all(d_hi.elevation[d_hi.mask] >= math.radians(30.0))


# ============================================================================ geometry of pr / prr
def test_noise_free_pseudorange_is_light_time_range():
    t = np.arange(0.0, 30.0, 5.0)
    r, v, _ = _driving(2, t, speed=25.0)
    d = _sim(t, r, v, receiver=ReceiverConfig.ideal(), t0_gps=np.array([1234.5, 400_000.0]))
    m = d.mask
    assert m.sum() > 2 * t.size * 5
    rho, _ = _light_time_range(d.sat_pos, r[:, :, None, :])
    np.testing.assert_allclose(d.pr[m], rho[m], rtol=0, atol=1e-6)
    assert np.all(d.pr_error_m == 0.0) and np.all(d.clock_bias_m == 0.0) and np.all(d.clock_drift_mps == 0.0)
    # the satellite positions are the ephemeris at the transmission time t_rx - rho / c
    t_tx = d.t0_gps[:, None, None] + t[None, :, None] - rho / C_LIGHT
    p_ref, v_ref = CON.positions_velocities(t_tx, np.where(m, d.prn - 1, 0)[..., None])
    np.testing.assert_allclose(d.sat_pos[m], p_ref[..., 0, :][m], rtol=0, atol=0.01)
    np.testing.assert_allclose(d.sat_vel[m], v_ref[..., 0, :][m], rtol=0, atol=1e-6)
    # the reception-time ECEF satellite is where the signal comes from: not the transmission-time one
    d_naive = np.linalg.norm(d.sat_pos - r[:, :, None, :], axis=-1)
    assert np.max(np.abs(d_naive - rho)[m]) > 1.0               # the Sagnac term is tens of metres


def test_pseudorange_rate_is_range_derivative():
    dt = 0.2
    t = np.arange(0.0, 10.0 + dt / 2, dt)
    r, v, _ = _driving(1, t, speed=30.0, heading_deg=30.0)
    d = _sim(t, r, v, receiver=ReceiverConfig.ideal(), t0_gps=np.array([77_777.0]))
    diffs = []
    for k in range(1, t.size - 1):
        for c in range(d.pr.shape[-1]):
            if not d.mask[0, k, c]:
                continue
            p = d.prn[0, k, c]
            cm, cp = np.flatnonzero(d.prn[0, k - 1] == p), np.flatnonzero(d.prn[0, k + 1] == p)
            if cm.size and cp.size:
                fd = (d.pr[0, k + 1, cp[0]] - d.pr[0, k - 1, cm[0]]) / (2 * dt)
                diffs.append(d.prr[0, k, c] - fd)
    diffs = np.abs(np.array(diffs))
    assert diffs.size > 100
    # Groves eq 8.46 neglects d(tau)/dt: |error| <~ rho_dot_inertial^2 / c, a few mm/s
    assert diffs.max() < 5e-3, diffs.max()
    assert np.all(np.abs(d.prr[d.mask]) > 0) and np.abs(d.prr[d.mask]).max() < 1500.0


# ============================================================================ clock
def test_clock_process_statistics():
    q = ClockModel(init_bias_sigma_m=0.0, init_drift_sigma_mps=0.0)
    assert q.q_bias == pytest.approx(0.5 * 2e-19 * C_LIGHT**2)
    assert q.q_drift == pytest.approx(2 * math.pi**2 * 2e-20 * C_LIGHT**2)
    assert 0.005 < q.q_bias < 0.02 and 0.02 < q.q_drift < 0.06          # Groves' typical TCXO values
    N = 600
    t = np.concatenate([np.arange(0.0, 500.0, 10.0), 500.0 + np.arange(0.0, 501.0, 25.0)])  # non-uniform steps
    b, d = simulate_clock(t, row_generators(range(N), "gnss"), q)
    assert b.shape == (N, t.size) and d.shape == (N, t.size)
    T = t[-1]
    var_d, var_b = d[:, -1].var(), b[:, -1].var()
    assert var_d == pytest.approx(q.q_drift * T, rel=0.25)
    assert var_b == pytest.approx(q.q_bias * T + q.q_drift * T**3 / 3, rel=0.25)
    corr = np.corrcoef(b[:, -1], d[:, -1])[0, 1]
    assert corr == pytest.approx(math.sqrt(3) / 2, abs=0.05)
    # variance grows linearly in time: half-way the drift variance is half
    k = np.searchsorted(t, 500.0)
    assert d[:, k].var() / var_d == pytest.approx(0.5, abs=0.15)
    # white frequency only: constant drift, bias = b0 + d0 t + random walk of PSD q_b
    w = ClockModel(h0=2e-19, h_minus2=0.0, init_bias_sigma_m=1e5, init_drift_sigma_mps=100.0)
    b, d = simulate_clock(t, row_generators(range(N), "gnss"), w)
    assert np.all(d == d[:, :1])
    assert b[:, 0].std() == pytest.approx(1e5, rel=0.15) and d[:, 0].std() == pytest.approx(100.0, rel=0.15)
    resid = b - b[:, :1] - d[:, :1] * t[None, :]
    assert resid[:, -1].var() == pytest.approx(w.q_bias * T, rel=0.25)
    # the ideal clock is exactly zero
    b, d = simulate_clock(t, row_generators([0], "gnss"), ClockModel.ideal())
    assert np.all(b == 0.0) and np.all(d == 0.0)


def test_clock_matches_exact_two_state_recursion():
    """The cumulative-sum implementation equals x_k+1 = Phi x_k + chol(Q_k) z_k with the documented draw order."""
    clk = ClockModel(h0=2e-19, h_minus2=2e-20, init_bias_sigma_m=50.0, init_drift_sigma_mps=2.0)
    t = np.array([0.0, 1.0, 2.0, 4.5, 10.0, 10.1, 30.0])
    b, d = simulate_clock(t, [np.random.default_rng(9)], clk)
    g = np.random.default_rng(9)
    z0 = g.standard_normal(2)
    z = g.standard_normal((t.size - 1, 2))
    x = np.array([50.0 * z0[0], 2.0 * z0[1]])
    for k in range(t.size):
        assert b[0, k] == pytest.approx(x[0], rel=1e-12, abs=1e-9)
        assert d[0, k] == pytest.approx(x[1], rel=1e-12, abs=1e-12)
        if k + 1 < t.size:
            h = t[k + 1] - t[k]
            qb, qd = clk.q_bias, clk.q_drift
            Q = np.array([[qb * h + qd * h**3 / 3, qd * h**2 / 2], [qd * h**2 / 2, qd * h]])
            x = np.array([[1.0, h], [0.0, 1.0]]) @ x + np.linalg.cholesky(Q) @ z[k]


def test_atmosphere_structure():
    t = np.arange(0.0, 200.0, 1.0)
    r, v = _static([40.0] * 16, t.size)
    # troposphere: one zenith delay per row, mapped to every satellite
    rec_t = ReceiverConfig.ideal(tropo_zenith_sigma_m=0.2)
    d = _sim(t, r, v, receiver=rec_t)
    zen = np.where(d.mask, d.pr_error_m / tropo_mapping(d.elevation), np.nan)
    spread = np.nanmax(zen, axis=-1) - np.nanmin(zen, axis=-1)
    assert np.nanmax(spread) < 1e-12
    assert np.nanstd(zen[:, 0, 0]) == pytest.approx(0.2, rel=0.35)
    # first-order Gauss-Markov, tau = 1800 s: one-second steps have sigma 0.2 sqrt(1 - exp(-2/1800))
    step = np.diff(zen[..., 0], axis=1)
    assert np.nanstd(step) == pytest.approx(0.2 * math.sqrt(-math.expm1(-2.0 / 1800.0)), rel=0.1)
    # ionosphere: an independent vertical delay per satellite, Klobuchar obliquity
    rec_i = ReceiverConfig.ideal(iono_zenith_sigma_m=0.7)
    d = _sim(t, r, v, receiver=rec_i)
    vert = d.pr_error_m / iono_obliquity(d.elevation)
    assert np.std(vert[d.mask]) == pytest.approx(0.7, rel=0.12)
    first = vert[:, 0][d.mask[:, 0]]
    assert np.std(first) == pytest.approx(0.7, rel=0.25)
    m0 = d.mask[:, 0]
    assert np.abs(np.corrcoef(vert[:, 0, 0][m0[:, 0]], vert[:, 0, 1][m0[:, 1]])[0, 1]) < 0.6


def test_gauss_markov_exact_recursion():
    rng = np.random.default_rng(3)
    for t in (np.arange(0.0, 200.0, 2.0), np.cumsum(rng.uniform(0.5, 400.0, size=300))):
        z = rng.standard_normal((t.size, 3))
        x = _gauss_markov(t, 60.0, 0.7, z)
        ref = np.empty_like(z)
        ref[0] = 0.7 * z[0]
        for k in range(1, t.size):
            a = math.exp(-(t[k] - t[k - 1]) / 60.0)
            ref[k] = a * ref[k - 1] + 0.7 * math.sqrt(1 - a * a) * z[k]
        np.testing.assert_allclose(x, ref, rtol=1e-9, atol=1e-12)
    # stationary sigma and lag correlation
    t = np.arange(0.0, 2000.0, 1.0)
    x = _gauss_markov(t, 50.0, 2.0, rng.standard_normal((t.size, 200)))
    assert x.std() == pytest.approx(2.0, rel=0.1)
    lag = np.mean(x[10:] * x[:-10]) / x.var()
    assert lag == pytest.approx(math.exp(-10.0 / 50.0), abs=0.05)


# ============================================================================ noise, sigmas, atmosphere
def test_reported_sigma_and_normalized_errors():
    rec = ReceiverConfig(clock=ClockModel.ideal())
    t = np.arange(0.0, 300.0, 1.0)
    r, v = _static([48.0] * 6, t.size)
    d = _sim(t, r, v, receiver=rec)
    m = d.mask
    el = d.elevation[m]
    s = np.sin(el)
    expect = np.sqrt((rec.pr_sigma_m / s) ** 2 + (tropo_mapping(el) * rec.tropo_zenith_sigma_m) ** 2
                     + (iono_obliquity(el) * rec.iono_zenith_sigma_m) ** 2)
    np.testing.assert_allclose(d.pr_sigma[m], expect, rtol=1e-12)
    np.testing.assert_allclose(d.prr_sigma[m], rec.prr_sigma_mps / s, rtol=1e-12)
    assert np.all(d.pr_sigma[m] >= rec.pr_sigma_m)
    # prr errors are white with the reported sigma
    zr = d.prr_error_mps[m] / d.prr_sigma[m]
    assert zr.std() == pytest.approx(1.0, rel=0.05) and abs(zr.mean()) < 0.05
    # pr errors: the atmospheric part is slowly varying (remove the white part by differencing in time)
    e = np.where(m, d.pr_error_m, np.nan)
    assert np.nanstd(e / np.where(m, d.pr_sigma, np.nan)) < 1.5
    assert tropo_mapping(math.pi / 2) == pytest.approx(1.0, abs=1e-3)
    assert iono_obliquity(math.pi / 2) == pytest.approx(1.0 + 16 * 0.03**3)
    assert iono_obliquity(0.0) == pytest.approx(1.0 + 16 * 0.53**3)


def test_noise_scale_multiplies_true_not_reported_sigma():
    rec = ReceiverConfig(pr_sigma_m=1.0, prr_sigma_mps=0.1, tropo_zenith_sigma_m=0.0, iono_zenith_sigma_m=0.0,
                         clock=ClockModel.ideal())
    ev = GnssEvents(noise_scale=((100.0, 200.0, 4.0), (150.0, 200.0, 0.5)))
    t = np.arange(0.0, 300.0, 1.0)
    r, v = _static([30.0] * 8, t.size)
    d = _sim(t, r, v, receiver=rec, events=ev)
    d0 = _sim(t, r, v, receiver=rec)
    np.testing.assert_array_equal(d.pr_sigma, d0.pr_sigma)        # reported sigma stays nominal
    np.testing.assert_array_equal(d.prr_sigma, d0.prr_sigma)
    zp = np.where(d.mask, d.pr_error_m / np.where(d.mask, d.pr_sigma, 1.0), np.nan)
    zr = np.where(d.mask, d.prr_error_mps / np.where(d.mask, d.prr_sigma, 1.0), np.nan)
    for z in (zp, zr):
        assert np.nanstd(z[:, t < 100]) == pytest.approx(1.0, rel=0.08)
        assert np.nanstd(z[:, (t >= 100) & (t < 150)]) == pytest.approx(4.0, rel=0.08)
        assert np.nanstd(z[:, (t >= 150) & (t < 200)]) == pytest.approx(2.0, rel=0.08)
        assert np.nanstd(z[:, t >= 200]) == pytest.approx(1.0, rel=0.08)
    # same seeds: outside the intervals the noise is identical to the clean run
    out = (t < 100) | (t >= 200)
    np.testing.assert_array_equal(d.pr[:, out], d0.pr[:, out])


# ============================================================================ events
def test_outages_remove_all_satellites():
    ev = GnssEvents(outages=((10.0, 20.0), (30.5, 31.5)))
    t = np.arange(0.0, 40.0, 1.0)
    r, v, hd = _driving(3, t)
    d = _sim(t, r, v, hd, events=ev)
    n = d.n_used()
    inside = ((t >= 10) & (t < 20)) | (t == 31.0)
    assert np.all(n[:, inside] == 0)
    assert np.all(n[:, ~inside] >= 4)
    assert np.all(d.pr[:, inside] == 0.0) and np.all(np.isfinite(d.sat_pos))
    p = GnssEvents.periodic_outages(duration_s=60.0, period_s=180.0, t_start_s=100.0, t_end_s=700.0)
    assert p.outages == ((100.0, 160.0), (280.0, 340.0), (460.0, 520.0), (640.0, 700.0))


def test_nlos_bursts_positive_on_flagged_channels_only():
    nl = NlosConfig(rate_hz=0.02, duration_s=(5.0, 15.0), bias_m=(10.0, 80.0), rate_sigma_mps=0.3, noise_factor=1.0)
    rec = ReceiverConfig.ideal()
    t = np.arange(0.0, 600.0, 1.0)
    r, v, hd = _driving(6, t)
    d = _sim(t, r, v, hd, receiver=rec, events=GnssEvents(nlos=nl))
    m, f = d.mask, d.nlos
    assert np.all(~f | m)                                    # flags only on valid channels
    e = d.pr_error_m
    assert np.all((e[f] >= 10.0) & (e[f] <= 80.0))
    assert np.all(e[m & ~f] == 0.0)
    assert np.all(d.prr_error_mps[m & ~f] == 0.0) and np.std(d.prr_error_mps[f]) > 0.1
    # duty cycle of the alternating renewal process: r d / (1 + r d), d = mean duration
    duty = 0.02 * 10.0 / (1 + 0.02 * 10.0)
    assert f.sum() / m.sum() == pytest.approx(duty, abs=0.04)
    # a burst keeps its bias: consecutive flagged epochs of one satellite share it
    same = 0
    for k in range(1, t.size):
        for c in np.flatnonzero(f[0, k]):
            p = d.prn[0, k, c]
            cm = np.flatnonzero((d.prn[0, k - 1] == p) & f[0, k - 1])
            if cm.size:
                assert e[0, k, c] == e[0, k - 1, cm[0]]
                same += 1
    assert same > 20
    # noise factor: extra noise on flagged channels, reported sigma nominal
    rec2 = ReceiverConfig(tropo_zenith_sigma_m=0.0, iono_zenith_sigma_m=0.0, clock=ClockModel.ideal())
    d2 = _sim(t, r, v, hd, receiver=rec2, events=GnssEvents(nlos=NlosConfig(rate_hz=0.02, noise_factor=3.0,
                                                                             rate_sigma_mps=0.0)))
    zr = d2.prr_error_mps / np.where(d2.mask, d2.prr_sigma, 1.0)
    assert np.std(zr[d2.nlos]) == pytest.approx(3.0, rel=0.12)
    assert np.std(zr[d2.mask & ~d2.nlos]) == pytest.approx(1.0, rel=0.08)


def test_urban_canyon_blockage_geometry():
    t = np.arange(0.0, 300.0, 2.0)
    r, v, hd = _driving(4, t, speed=10.0, heading_deg=60.0)
    rec = ReceiverConfig.ideal()

    def run(canyon):
        return _sim(t, r, v, hd, receiver=rec, events=GnssEvents(canyon=canyon))

    full = dict(building_height_m=(20.0, 20.0), blockage_probability=1.0, nlos_probability=0.0)
    d_open = run(None)
    d_narrow = run(UrbanCanyon(street_width_m=10.0, **full))
    d_wide = run(UrbanCanyon(street_width_m=60.0, **full))
    n_o, n_n, n_w = d_open.n_used().mean(), d_narrow.n_used().mean(), d_wide.n_used().mean()
    assert n_n < n_w < n_o and n_n < 0.7 * n_o, (n_n, n_w, n_o)
    assert not d_narrow.nlos.any()
    # every tracked satellite clears the walls: tan(el) w/2 >= h |sin(az - heading)|
    for d, w in ((d_narrow, 10.0), (d_wide, 60.0)):
        m = d.mask
        sa = np.abs(np.sin(d.azimuth - hd[..., None]))
        assert np.all((np.tan(d.elevation) * w / 2 >= 20.0 * sa - 1e-9)[m])
    # along-street satellites survive, across-street low ones do not
    sa_o = np.abs(np.sin(d_open.azimuth - hd[..., None]))
    low_across = d_open.mask & (sa_o > 0.9) & (d_open.elevation < math.radians(60.0))
    assert low_across.sum() > 0
    for b in range(4):
        for k in range(t.size):
            for c in np.flatnonzero(low_across[b, k]):
                assert d_open.prn[b, k, c] not in d_narrow.prn[b, k]
    # with reflections always received, no satellite is lost but the blocked ones are NLOS with
    # the two-ray excess path w cos(el) |sin(alpha)| > 0
    d_refl = run(UrbanCanyon(street_width_m=10.0, building_height_m=(20.0, 20.0), blockage_probability=1.0,
                             nlos_probability=1.0))
    np.testing.assert_array_equal(d_refl.prn, d_open.prn)
    f = d_refl.nlos
    assert f.sum() > 0
    sa = np.abs(np.sin(d_refl.azimuth - hd[..., None]))
    np.testing.assert_allclose(d_refl.pr_error_m[f], (10.0 * np.cos(d_refl.elevation) * sa)[f], rtol=1e-12)
    assert np.all(d_refl.pr_error_m[f] > 0.0) and np.all(d_refl.pr_error_m[d_refl.mask & ~f] == 0.0)
    # intervals: the canyon only acts inside them
    d_int = run(UrbanCanyon(street_width_m=10.0, intervals=((100.0, 200.0),), **full))
    np.testing.assert_array_equal(d_int.prn[:, t < 100], d_open.prn[:, t < 100])
    assert d_int.n_used()[:, (t >= 100) & (t < 200)].mean() < 0.7 * n_o


def test_urban_canyon_random_buildings_vary_visibility():
    t = np.arange(0.0, 600.0, 1.0)
    r, v, hd = _driving(4, t, speed=12.0)
    d = _sim(t, r, v, hd, events=GnssEvents.urban())
    d_open = _sim(t, r, v, hd)
    n = d.n_used()
    assert n.mean() < d_open.n_used().mean() - 2
    assert np.all(n.max(axis=1) - n.min(axis=1) >= 3)       # building heights change along the drive
    assert d.nlos.any() and np.all(d.pr_error_m[d.nlos] - d_open.pr_error_m.max() > -50)


# ============================================================================ batching, dtype, presets
def test_batch_invariance_and_determinism():
    t = np.arange(0.0, 120.0, 1.0)
    r, v, hd = _driving(8, t)
    r = r + np.arange(8)[:, None, None] * 100.0            # different rows
    ev = GnssEvents.urban().combine(GnssEvents(noise_scale=((30.0, 60.0, 3.0),)))
    rec = ReceiverConfig()
    d8 = _sim(t, r, v, hd, receiver=rec, events=ev, seeds=list(range(100, 108)))
    assert len(np.unique(d8.t0_gps)) == 8
    for i in (0, 5, 7):
        d1 = _sim(t, r[i:i + 1], v[i:i + 1], hd[i:i + 1], receiver=rec, events=ev, seeds=[100 + i])
        sub = d8.rows(i)
        for name in GnssData.__dataclass_fields__:
            a, b = getattr(sub, name), getattr(d1, name)
            if a.dtype.kind in "bi":
                np.testing.assert_array_equal(a, b, err_msg=name)
            else:
                np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9, err_msg=name)
    d8b = _sim(t, r, v, hd, receiver=rec, events=ev, seeds=list(range(100, 108)))
    np.testing.assert_array_equal(d8.pr, d8b.pr)
    d8c = _sim(t, r, v, hd, receiver=rec, events=ev, seeds=list(range(200, 208)))
    assert not np.array_equal(d8.clock_bias_m, d8c.clock_bias_m)


def test_float32_output():
    t = np.arange(0.0, 60.0, 1.0)
    r, v, hd = _driving(2, t)
    d64 = _sim(t, r, v, hd, events=GnssEvents.urban())
    d32 = _sim(t, r, v, hd, events=GnssEvents.urban(), dtype=np.float32)
    for name in GnssData.__dataclass_fields__:
        a32, a64 = getattr(d32, name), getattr(d64, name)
        if name == "t0_gps":
            assert a32.dtype == np.float64
        elif a64.dtype.kind == "f":
            assert a32.dtype == np.float32, name
            # float32 keeps ~7 digits: a 2e7 m pseudorange to ~2 m
            np.testing.assert_allclose(a32, a64, rtol=2e-7, atol=1e-6, err_msg=name)
        else:
            np.testing.assert_array_equal(a32, a64, err_msg=name)
    assert d32.n_used().dtype == np.int64


def test_events_presets_and_combine():
    assert GnssEvents() == GnssEvents.clean() == GnssEvents.preset("open-sky")
    u = GnssEvents.preset("urban")
    assert u.nlos is not None and u.canyon is not None
    nb = GnssEvents.noise_bursts(scale=5.0, duration_s=30.0, period_s=120.0, t_start_s=60.0, t_end_s=300.0)
    assert nb.noise_scale == ((60.0, 90.0, 5.0), (180.0, 210.0, 5.0))
    c = GnssEvents(outages=((1.0, 2.0),)).combine(nb, GnssEvents(outages=((5.0, 6.0),)), u)
    assert c.outages == ((1.0, 2.0), (5.0, 6.0)) and c.noise_scale == nb.noise_scale
    assert c.nlos == u.nlos and c.canyon == u.canyon
    with pytest.raises(ValueError, match="nope"):
        GnssEvents.preset("nope")


@pytest.mark.parametrize("make, field", [
    (lambda: Constellation(n_planes=0), "n_planes"),
    (lambda: Constellation(inclination_deg=float("nan")), "inclination_deg"),
    (lambda: Constellation(semi_major_axis_m=1e6), "semi_major_axis_m"),
    (lambda: Constellation(phasing=6), "phasing"),
    (lambda: ClockModel(h0=-1e-19), "h0"),
    (lambda: ClockModel(init_drift_sigma_mps=float("inf")), "init_drift_sigma_mps"),
    (lambda: ReceiverConfig(pr_sigma_m=-0.5), "pr_sigma_m"),
    (lambda: ReceiverConfig(n_channels=0), "n_channels"),
    (lambda: ReceiverConfig(iono_tau_s=0.0), "iono_tau_s"),
    (lambda: ReceiverConfig(elevation_mask_deg=float("nan")), "elevation_mask_deg"),
    (lambda: ReceiverConfig(clock="tcxo"), "clock"),
    (lambda: NlosConfig(bias_m=(80.0, 10.0)), "bias_m"),
    (lambda: NlosConfig(rate_hz=-0.1), "rate_hz"),
    (lambda: NlosConfig(duration_s=(0.0, 5.0)), "duration_s"),
    (lambda: UrbanCanyon(street_width_m=0.0), "street_width_m"),
    (lambda: UrbanCanyon(blockage_probability=1.5), "blockage_probability"),
    (lambda: GnssEvents(outages=((10.0, 5.0),)), "outages"),
    (lambda: GnssEvents(outages=((0.0, float("inf")),)), "outages"),
    (lambda: GnssEvents(noise_scale=((0.0, 10.0, -1.0),)), "noise_scale"),
    (lambda: GnssEvents(nlos=0.1), "nlos"),
])
def test_config_validation(make, field):
    with pytest.raises(ValueError, match=field):
        make()


def test_simulate_input_validation():
    t = np.arange(0.0, 5.0)
    r, v, hd = _driving(2, t)
    rngs = row_generators([0, 1], "gnss")
    args = (CON, ReceiverConfig(), GnssEvents())
    with pytest.raises(ValueError, match="r_e"):
        simulate_gnss(t, r[:, :3], v, hd, *args, rngs)
    with pytest.raises(ValueError, match="r_e"):
        simulate_gnss(t, r, v, hd, *args, rngs[:1])                # B mismatch
    with pytest.raises(ValueError, match="v_e"):
        simulate_gnss(t, r, v * np.nan, hd, *args, rngs)
    with pytest.raises(ValueError, match="t must be strictly increasing"):
        simulate_gnss(t[::-1], r, v, hd, *args, rngs)
    with pytest.raises(ValueError, match="dtype"):
        simulate_gnss(t, r, v, hd, *args, rngs, dtype=np.int32)
    with pytest.raises(ValueError, match="t0_gps"):
        simulate_gnss(t, r, v, hd, *args, rngs, t0_gps=np.zeros(3))
    with pytest.raises(ValueError, match="heading"):
        simulate_gnss(t, r, v, None, CON, ReceiverConfig(), GnssEvents.urban(), rngs)
    with pytest.raises(ValueError, match="rngs"):
        simulate_gnss(t, r, v, hd, *args, [0, 1])
    with pytest.raises(ValueError, match="t must be"):
        simulate_clock(np.array([0.0, 1.0, 1.0]), rngs)
