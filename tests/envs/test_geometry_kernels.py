"""The compiled geometry kernels (envs.sim.geometry_kernels) against the numpy chain they replaced, and the row
ranges on threads (envs.sim.row_threads).

The numpy chain is an independent form: Constellation.positions_velocities (vectorized over times and
satellites), the line of sight of Groves eq 8.36 and earth.ranging.range_and_rate. Agreement is to a few ulp
(numpy's reductions may add in another order on another CPU); the split of the rows over threads must not change
a bit.
"""
from __future__ import annotations

import math
import threading

import numpy as np
import pytest

from earth.ranging import range_and_rate
from earth.wgs84 import C_LIGHT, OMEGA_IE, ecef_to_geodetic, geodetic_to_ecef
from envs.sim.constellation import Constellation
from envs.sim.geometry_kernels import BELOW_HORIZON_EL, channel_order_rows, ranging_rows, sky_rows
from envs.sim.row_threads import run_row_ranges


def _receivers(rng, B, M):
    """(B, M, 3) ECEF positions on the ground around the world, (B, M) GPS reception times."""
    lat = rng.uniform(-1.2, 1.2, (B, 1)) + rng.normal(0, 1e-4, (B, M))
    lon = rng.uniform(-math.pi, math.pi, (B, 1)) + rng.normal(0, 1e-4, (B, M))
    r_e = geodetic_to_ecef(lat, lon, rng.uniform(0, 500, (B, M)))
    t_rx = rng.uniform(0, 604_800.0, (B, 1)) + np.arange(M)[None, :] * 1.0
    return r_e, t_rx


def _sky_numpy(con, t_rx, r_e):
    """Transmission time, elevation, azimuth by the numpy chain (one light-time pass, Groves eq 8.36)."""
    p, v = con.positions_velocities(t_rx)                       # (B, M, S, 3)
    d = p - r_e[..., None, :]
    tau = np.sqrt(np.sum(d * d, axis=-1)) / C_LIGHT
    th = OMEGA_IE * tau
    c, s = np.cos(th), np.sin(th)
    q = p - v * tau[..., None]
    dx = c * q[..., 0] + s * q[..., 1] - r_e[..., None, 0]
    dy = -s * q[..., 0] + c * q[..., 1] - r_e[..., None, 1]
    dz = q[..., 2] - r_e[..., None, 2]
    lat, lon, _ = ecef_to_geodetic(r_e)
    sl, cl, so, co = (f(x)[..., None] for x in (lat, lon) for f in (np.sin, np.cos))
    h = co * dx + so * dy
    n, e, up = -sl * h + cl * dz, -so * dx + co * dy, cl * h + sl * dz
    return t_rx[..., None] - tau, np.arctan2(up, np.hypot(n, e)), np.mod(np.arctan2(e, n), 2 * np.pi)


def _sky_kernel(con, t_rx, r_e, workers=1, min_rows=8):
    B, M = t_rx.shape
    S = con.n_sats
    out = [np.full((B, M, S), np.nan) for _ in range(3)]
    lat, lon, _ = ecef_to_geodetic(r_e)
    trig = (np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon))
    run_row_ranges(lambda r0, r1: sky_rows(r0, r1, t_rx, r_e, *trig, *con.kernel_constants(), *out), B,
                   workers=workers, min_rows=min_rows)
    return out


def test_sky_rows_matches_numpy_chain():
    """Every satellite-epoch of 40 receivers: the same transmission time to a few ulp; above the horizon the same
    elevation and azimuth, below it (``up < 0`` by the numpy chain, whichever of the kernel's two tests caught it)
    :data:`BELOW_HORIZON_EL` and azimuth 0."""
    rng = np.random.default_rng(7)
    con = Constellation()
    r_e, t_rx = _receivers(rng, 40, 25)
    t_tx, el, az = _sky_kernel(con, t_rx, r_e)
    t_ref, el_ref, az_ref = _sky_numpy(con, t_rx, r_e)
    np.testing.assert_allclose(t_tx, t_ref, rtol=0, atol=1e-10)      # ulp of t ~ 604 800 s is 1.2e-10
    up = el_ref >= 0
    np.testing.assert_allclose(el[up], el_ref[up], rtol=0, atol=4e-15)
    d_az = np.abs(az[up] - az_ref[up])
    assert np.all(np.minimum(d_az, 2 * np.pi - d_az) < 4e-15)
    assert np.all((az >= 0) & (az < 2 * np.pi))
    assert np.all(el[~up] == BELOW_HORIZON_EL) and np.all(az[~up] == 0.0)
    assert np.all(el[up] >= 0)
    assert 0.3 < np.mean(~up) < 0.8                                   # both sides of the horizon were covered


def test_sky_rows_horizon_split_is_exact_near_the_horizon():
    """Receivers whose satellites sit within a few metres of the horizon plane: the margin test never takes a
    satellite the exact test would keep (every kept one is the numpy chain's, to the ulp)."""
    rng = np.random.default_rng(11)
    con = Constellation()
    r_e, t_rx = _receivers(rng, 400, 4)
    _, el_ref, _ = _sky_numpy(con, t_rx, r_e)
    near = np.abs(el_ref) < np.radians(2.0)
    assert near.sum() > 50                                           # the case is exercised
    _, el, _ = _sky_kernel(con, t_rx, r_e)
    keep = el_ref >= 0
    np.testing.assert_allclose(el[keep & near], el_ref[keep & near], rtol=0, atol=4e-15)
    assert np.all(el[~keep & near] == BELOW_HORIZON_EL)


def test_ranging_rows_matches_range_and_rate():
    """Tracked channels: the ephemeris at transmission time and range / rate of range_and_rate; the others stay
    as the caller left them (zeros)."""
    rng = np.random.default_rng(8)
    con = Constellation()
    B, M, C = 12, 6, 9
    r_e, _ = _receivers(rng, B, M)
    v_e = rng.normal(0, 20, (B, M, 3))
    t_tx = rng.uniform(0, 604_800.0, (B, M, C))
    sel = rng.integers(0, con.n_sats, (B, M, C))
    mask = rng.random((B, M, C)) < 0.7
    pos, vel = np.zeros((B, M, C, 3)), np.zeros((B, M, C, 3))
    rho, rho_dot = np.zeros((B, M, C)), np.zeros((B, M, C))
    run_row_ranges(lambda r0, r1: ranging_rows(r0, r1, t_tx, sel, mask, r_e, v_e, *con.kernel_constants(), pos,
                                               vel, rho, rho_dot), B, workers=2, min_rows=2)
    p_ref, v_ref = con.positions_velocities(t_tx, sel[..., None])
    p_ref, v_ref = p_ref[..., 0, :], v_ref[..., 0, :]
    r_ref, rd_ref, _ = range_and_rate(p_ref[..., None, :], v_ref[..., None, :], r_e[..., None, :], v_e[..., None, :])
    np.testing.assert_array_equal(pos[mask], p_ref[mask])             # the same formula, one point at a time
    np.testing.assert_array_equal(vel[mask], v_ref[mask])
    np.testing.assert_allclose(rho[mask], r_ref[..., 0][mask], rtol=1e-15)
    np.testing.assert_allclose(rho_dot[mask], rd_ref[..., 0][mask], rtol=0, atol=1e-11)
    assert not pos[~mask].any() and not rho[~mask].any() and not rho_dot[~mask].any()


def test_row_split_does_not_change_a_bit():
    """The sky of 37 rows on 3 threads in ranges of 2 rows equals one call over all rows."""
    rng = np.random.default_rng(9)
    con = Constellation()
    r_e, t_rx = _receivers(rng, 37, 4)
    one = _sky_kernel(con, t_rx, r_e, workers=1)
    split = _sky_kernel(con, t_rx, r_e, workers=3, min_rows=2)
    for a, b in zip(one, split):
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("n_rows, workers, min_rows", [(0, 2, 8), (1, 4, 8), (15, 2, 8), (16, 2, 8), (101, 3, 2),
                                                       (50, 1, 1)])
def test_run_row_ranges_covers_each_row_once(n_rows, workers, min_rows):
    """The ranges partition 0 .. n_rows; more than one thread only when every range holds min_rows rows."""
    seen = np.zeros(n_rows, dtype=np.int64)
    threads, lock = set(), threading.Lock()

    def fn(r0, r1):
        with lock:
            threads.add(threading.get_ident())
            assert r1 - r0 >= min(min_rows, n_rows) and 0 <= r0 < r1 <= n_rows
            seen[r0:r1] += 1

    run_row_ranges(fn, n_rows, workers=workers, min_rows=min_rows)
    assert np.all(seen == 1)
    if workers == 1 or n_rows < 2 * min_rows:
        assert len(threads) <= 1


@pytest.mark.parametrize("C", [5, 12, 34])
def test_channel_order_rows_is_numpys_stable_argsort(C):
    """The channel order equals numpy's stable argsort of ``-where(visible, el, -inf)``, ties included (elevations
    drawn from 6 values, so most epochs have equal ones), the first C of it, index 0 beyond S."""
    rng = np.random.default_rng(21)
    B, M, S = 7, 40, 30
    el = rng.choice(np.radians([-10.0, 0.0, 5.0, 15.0, 40.0, 80.0]), (B, M, S))
    el[0, 0, :3] = -0.0                                                # signed zeros tie too
    visible = (el >= 0) & (rng.random((B, M, S)) < 0.8)
    order = np.argsort(-np.where(visible, el, -np.inf), axis=-1, kind="stable")
    ref = np.zeros((B, M, C), np.intp)
    ref[..., :min(C, S)] = order[..., :C]
    sel = np.full((B, M, C), -1, np.intp)
    run_row_ranges(lambda r0, r1: channel_order_rows(r0, r1, visible, el, sel), B, workers=2, min_rows=2)
    np.testing.assert_array_equal(sel, ref)
