"""Contracts of the world generator's stages (envs.sim.gnss_stages; simulate_imu's stages in envs.sim.imu).

simulate_gnss runs the stages of envs.sim.gnss_stages in order and simulate_imu its row stages; these tests
pin what each stage promises to the next (shapes, masks, orderings, neutral values), so that a stage can be
rewritten (vectorized, compiled) on its own. That the composition gives the same worlds as before is
tests/envs/test_world_fingerprints.py's job.
"""
from __future__ import annotations

import math
from dataclasses import fields, replace

import numpy as np
import pytest

import envs.sim.world as wmod
from envs.sim import events as ev
from envs.sim import gnss_stages as st
from envs.sim.geometry_kernels import BELOW_HORIZON_EL
from envs.sim.imu import IMU_GRADES, ImuEvents, _children, _row_events, _sensor_row, _sensor_specs
from envs.sim.rng import row_generators
from envs.sim.row_threads import run_row_ranges
from envs.sim.scenarios import get_scenario


def _gnss_inputs(name, seeds, monkeypatch, duration_s=60.0):
    """The arguments generate_world hands to simulate_gnss for ``name`` (with fresh row generators), and its
    result."""
    got = {}
    real = wmod.simulate_gnss

    def spy(*args, **kw):
        got["args"] = args
        got["out"] = real(*args, **kw)
        return got["out"]

    monkeypatch.setattr(wmod, "simulate_gnss", spy)
    wmod.generate_world(get_scenario(name, duration_s=duration_s), seeds)
    return got["args"][:7] + (row_generators(seeds, "gnss"),), got["out"]


def stages_to_channels(t, r_e, v_e, heading, con, rec, events, subs, cn0_cfg=None):
    """Stages 1-5 in simulate_gnss's order (sky, visibility and events, channel allocation with the C/N0
    scatter ``cn0_cfg``): ``(sky, sat, ch)``."""
    sky = st.sky_geometry(t, r_e, con, subs)
    sat = st.canyon_and_bursts(t, v_e, heading, sky, rec.elevation_mask_deg, events, subs)
    st.random_events(t, v_e, heading, sky, sat, events, subs)
    st.scheduled_events(t, sat, events)
    return sky, sat, st.allocate_channels(sky, sat.visible, rec.n_channels, subs, t, cn0_cfg)


def _run_stages(args):
    """The stages in simulate_gnss's order on its (checked) arguments; returns each stage's result."""
    t, r_e, v_e, heading, con, rec, events, rngs = args
    t = np.asarray(t, np.float64)
    subs = [st._row_children(g) for g in rngs]
    sky, sat, ch = stages_to_channels(t, r_e, v_e, heading, con, rec, events, subs)
    rng = st.channel_ranging(r_e, v_e, sky, ch, con)
    noise = st.channel_noise(t, ch, sat, events)
    err = st.receiver_errors(t, ch, noise, sat, rec, subs)
    return dict(t=t, sky=sky, sat=sat, ch=ch, rng=rng, noise=noise, err=err, rec=rec, events=events)


def _one_pass_and_ranges(monkeypatch, constant: str, run):
    """``run()`` with the stage's range-size ``constant`` of gnss_stages out of reach (one pass), then at 2 rows
    with its row ranges on 3 threads, each recorded as ``(min_rows, r0, r1)``: ``(one, split, ranges)``."""
    monkeypatch.setattr(st, constant, 10 ** 9)
    one = run()
    ranges = []
    monkeypatch.setattr(st, constant, 2)
    monkeypatch.setattr(st, "run_row_ranges", lambda fn, n, workers=None, min_rows=8: run_row_ranges(
        lambda r0, r1: ranges.append((min_rows, r0, r1)) or fn(r0, r1), n, 3, min_rows))
    return one, run(), ranges


@pytest.mark.parametrize("name", ["urban", "urban-transition", "noise-mismatch"])
def test_stages_compose_to_simulate_gnss(name, monkeypatch):
    """The stages run in order give simulate_gnss's data (the errors, sigmas and masks bit for bit)."""
    args, ref = _gnss_inputs(name, [5, 6], monkeypatch)
    s = _run_stages(args)
    ch, err, noise = s["ch"], s["err"], s["noise"]
    np.testing.assert_array_equal(ch.mask, ref.mask)
    np.testing.assert_array_equal(noise.nlos, ref.nlos)
    np.testing.assert_array_equal(s["sat"].bits, ref.event_mask)
    for mine, theirs in ((err.pr_err, ref.pr_error_m), (err.prr_err, ref.prr_error_mps),
                         (err.pr_sigma, ref.pr_sigma), (err.prr_sigma, ref.prr_sigma), (ch.cn0, ref.cn0_dbhz)):
        np.testing.assert_array_equal(np.where(ch.mask, mine, 0.0), theirs)
    np.testing.assert_array_equal(err.pr_var_true, ref.pr_var_true)


def test_sky_geometry_contract(monkeypatch):
    """Elevation in [-90, 90] deg, azimuth in [0, 360) deg, flight times of a GPS orbit, and row i the same in
    any batch (its draws come from its own stream)."""
    args, _ = _gnss_inputs("open-sky", [1, 2, 3], monkeypatch)
    t, r_e, con, rngs = np.asarray(args[0], float), args[1], args[4], args[7]
    sky = st.sky_geometry(t, r_e, con, [st._row_children(g) for g in rngs])
    B, M = r_e.shape[:2]
    assert sky.el.shape == sky.az.shape == sky.t_tx.shape == (B, M, con.n_sats)
    assert np.all((sky.t0_gps >= 0) & (sky.t0_gps < st.GPS_WEEK_S))
    assert np.all(np.abs(sky.el) <= math.pi / 2) and np.all((sky.az >= 0) & (sky.az < 2 * math.pi))
    flight = sky.t0_gps[:, None, None] + t[None, :, None] - sky.t_tx
    up = sky.el > 0
    assert np.all((flight[up] > 0.066) & (flight[up] < 0.087))       # 20 200 km .. 25 800 km at light speed
    one = st.sky_geometry(t, r_e[1:2], con, [st._row_children(row_generators([2], "gnss")[0])])
    np.testing.assert_array_equal(one.el[0], sky.el[1])
    np.testing.assert_array_equal(one.t_tx[0], sky.t_tx[1])


def test_sky_geometry_ranges_and_below_horizon(monkeypatch):
    """Rows in ranges of 2 on 3 threads (each range forms its receivers' latitude and longitude) give the one-call
    sky bit for bit; a satellite below the horizon reads BELOW_HORIZON_EL, azimuth 0, and the satellites at or
    above it keep their angles."""
    args, _ = _gnss_inputs("open-sky", [1, 2, 3, 4, 5], monkeypatch)
    t, r_e, con, rngs = np.asarray(args[0], float), args[1], args[4], args[7]
    t0 = np.array([100.0, 2e5, 4e5, 5e5, 6e5])
    monkeypatch.setattr(st, "run_row_ranges", lambda fn, n, workers=None, min_rows=8: fn(0, n))
    one = st.sky_geometry(t, r_e, con, [], t0_gps=t0)
    ranges = []
    monkeypatch.setattr(st, "run_row_ranges", lambda fn, n, workers=None, min_rows=8: run_row_ranges(
        lambda r0, r1: ranges.append((r0, r1)) or fn(r0, r1), n, 3, 2))
    split = st.sky_geometry(t, r_e, con, [], t0_gps=t0)
    assert len(ranges) == 2
    for a in ("t_tx", "el", "az"):
        np.testing.assert_array_equal(getattr(split, a), getattr(one, a))
    below = one.el < 0
    assert 0.3 < below.mean() < 0.8
    assert np.all(one.el[below] == BELOW_HORIZON_EL) and np.all(one.az[below] == 0.0)
    assert np.all(one.el[~below] >= 0)


def test_visibility_and_channel_allocation_contract(monkeypatch):
    """Visible satellites lie above the mask; the channels hold the min(C, visible) highest ones, tracked
    channels first, elevation descending, no satellite twice; ranging is zero off the tracked channels."""
    args, _ = _gnss_inputs("urban", [11, 12], monkeypatch)
    s = _run_stages(args)
    sky, sat, ch, rng, rec = s["sky"], s["sat"], s["ch"], s["rng"], s["rec"]
    assert not np.any(sat.visible & (sky.el < math.radians(rec.elevation_mask_deg)))
    n_vis = sat.visible.sum(-1)
    np.testing.assert_array_equal(ch.mask.sum(-1), np.minimum(n_vis, rec.n_channels))
    n_trk = ch.mask.sum(-1)
    C = rec.n_channels
    np.testing.assert_array_equal(ch.mask, np.arange(C) < n_trk[..., None])   # tracked channels first
    el = np.where(ch.mask, ch.el, -10.0)
    assert np.all(np.diff(el, axis=-1)[ch.mask[..., 1:]] <= 0)
    assert np.all(sat.visible.reshape(-1)[ch.flat_sel[ch.mask]])
    assert all(len(set(r[m])) == m.sum() for r, m in zip(ch.sel.reshape(-1, C), ch.mask.reshape(-1, C)))
    off = ~ch.mask
    assert not np.any(rng.sat_pos[off]) and not np.any(rng.rho[off]) and not np.any(rng.rho_dot[off])
    geo = np.linalg.norm(rng.sat_pos - args[1][:, :, None, :], axis=-1)
    assert np.all(np.abs(rng.rho - geo)[ch.mask] < 50.0)                 # the Sagnac term: tens of metres


def test_outage_stage_blocks_every_satellite(monkeypatch):
    """scheduled_events: no satellite visible inside an outage, the OUTAGE bit exactly there."""
    args, _ = _gnss_inputs("outage", [4], monkeypatch, duration_s=150.0)
    s = _run_stages(args)
    t, sat = s["t"], s["sat"]
    inside = np.zeros(t.shape, bool)
    for t0, t1 in s["events"].outages:
        inside |= (t >= t0) & (t < t1)
    assert inside.any() and not sat.visible[:, inside].any() and sat.visible[:, ~inside].any()
    np.testing.assert_array_equal((sat.bits & ev.OUTAGE) != 0, np.broadcast_to(inside, sat.bits.shape))


def test_channel_noise_and_receiver_errors_contract(monkeypatch):
    """NLOS only on tracked channels with its bias there alone; the noise-burst multiplier where the scenario
    puts it; true variances 1 on empty channels and at least the NLOS bias squared elsewhere."""
    args, _ = _gnss_inputs("noise-burst", [8, 9], monkeypatch, duration_s=120.0)
    s = _run_stages(args)
    t, ch, noise, err, events = s["t"], s["ch"], s["noise"], s["err"], s["events"]
    assert not np.any(noise.nlos & ~ch.mask)
    assert not np.any(noise.pr_bias[~noise.nlos]) and not np.any(noise.prr_bias[~noise.nlos])
    scale = np.ones(t.shape)
    for t0, t1, k in events.noise_scale:
        scale = np.where((t >= t0) & (t < t1), scale * k, scale)
    assert (scale > 1).any()
    np.testing.assert_array_equal(noise.code_mult[ch.mask], np.broadcast_to(scale[None, :, None],
                                                                           ch.mask.shape)[ch.mask])
    assert np.all(err.pr_var_true[~ch.mask] == 1.0) and np.all(err.prr_var_true[~ch.mask] == 1.0)
    assert np.all(err.pr_var_true[ch.mask] >= noise.pr_bias[ch.mask] ** 2)
    assert np.all(err.pr_sigma[ch.mask] > 0) and np.all(err.prr_sigma[ch.mask] > 0)
    assert err.bias_m.shape == err.drift_mps.shape == ch.mask.shape[:2]
    assert {f.name for f in fields(err)} >= {"pr_err", "prr_err", "pr_var_true"}


@pytest.mark.parametrize("name,sigma_model", [("noise-mismatch", None), ("urban", "elevation-cn0")])
def test_receiver_errors_in_row_ranges_equal_one_pass(name, sigma_model, monkeypatch):
    """receiver_errors runs its rows in ranges on threads (from 2 RECEIVER_RANGE_ROWS rows on): in ranges of 2 rows
    (on 3 threads) it gives what one pass over the 7 rows gives, bit for bit, with the reported-sigma mismatch and
    with a variance sigma model."""
    from envs.sim.sigma_models import SigmaModel
    args, _ = _gnss_inputs(name, list(range(20, 27)), monkeypatch, duration_s=40.0)
    if sigma_model is not None:
        args = args[:5] + (replace(args[5], sigma_model=SigmaModel(sigma_model)),) + args[6:]
    t, rec = np.asarray(args[0], np.float64), args[5]
    s = _run_stages(args)

    def errors():
        subs = [st._row_children(g) for g in row_generators(list(range(20, 27)), "gnss")]  # its streams, fresh
        return st.receiver_errors(t, s["ch"], s["noise"], s["sat"], rec, subs)

    one, split, ranges = _one_pass_and_ranges(monkeypatch, "RECEIVER_RANGE_ROWS", errors)
    assert sorted(ranges) == [(2, 0, 2), (2, 2, 4), (2, 4, 7)]
    for f in fields(one):
        np.testing.assert_array_equal(getattr(split, f.name), getattr(one, f.name), err_msg=f.name)
    assert sigma_model is None or not np.array_equal(one.pr_sigma, _run_stages(_gnss_inputs(name, list(
        range(20, 27)), monkeypatch, duration_s=40.0)[0])["err"].pr_sigma)  # the model changed the sigmas


@pytest.mark.parametrize("name,extra_channels", [("urban-smartloc", 0), ("urban", 3)])
def test_channel_allocation_in_row_ranges_equals_one_pass(name, extra_channels, monkeypatch):
    """allocate_channels runs its rows in ranges on threads (from 2 CHANNEL_RANGE_ROWS rows on): in ranges of 2 rows
    it gives what one pass over the 7 rows gives, bit for bit, with the C/N0 scatter and with more channels than
    satellites (padding channels)."""
    seeds = list(range(30, 37))
    args, _ = _gnss_inputs(name, seeds, monkeypatch, duration_s=30.0)
    t, r_e, v_e, heading, con, rec, events = np.asarray(args[0], np.float64), *args[1:7]
    sky = st.sky_geometry(t, r_e, con, [st._row_children(g) for g in row_generators(seeds, "gnss")])
    sat = st.canyon_and_bursts(t, v_e, heading, sky, rec.elevation_mask_deg, events,
                               [st._row_children(g) for g in row_generators(seeds, "gnss")])
    C = con.n_sats + extra_channels if extra_channels else rec.n_channels

    def channels():
        subs = [st._row_children(g) for g in row_generators(seeds, "gnss")]
        return st.allocate_channels(sky, sat.visible, C, subs, t, events.cn0)

    one, split, ranges = _one_pass_and_ranges(monkeypatch, "CHANNEL_RANGE_ROWS", channels)
    assert sorted(ranges) == [(2, 0, 2), (2, 2, 4), (2, 4, 7)]
    assert (one.nlos_deficit is None) == (events.cn0 is None)
    for f in fields(one):
        a, b = getattr(split, f.name), getattr(one, f.name)
        if b is None:
            assert a is None, f.name
        else:
            assert a.dtype == b.dtype, f.name
            np.testing.assert_array_equal(a, b, err_msg=f.name)
    assert not extra_channels or not one.mask[..., con.n_sats:].any()


@pytest.mark.parametrize("name", ["urban-smartloc", "urban-transition", "seed003-sim"])
def test_event_stages_in_row_ranges_equal_one_pass(name, monkeypatch):
    """The events' row stages (the urban zones of random_events, the re-acquisition transient of
    scheduled_events, channel_noise) run their rows in ranges on threads (from 2 EVENT_RANGE_ROWS rows on): in
    ranges of 2 rows they give what one pass over the 7 rows gives, bit for bit (visibility, event bits, the
    zones' NLOS, bias, rate and C/N0 loss, the transient, the C/N0 and every channel's noise)."""
    seeds = list(range(40, 47))
    args, _ = _gnss_inputs(name, seeds, monkeypatch, duration_s=320.0 if name == "seed003-sim" else 120.0)
    t, r_e, v_e, heading, con, rec, events = np.asarray(args[0], np.float64), *args[1:7]
    assert events.reacquisition is not None

    def stages():
        subs = [st._row_children(g) for g in row_generators(seeds, "gnss")]
        _, sat, ch = stages_to_channels(t, r_e, v_e, heading, con, rec, events, subs, events.cn0)
        return sat, ch, st.channel_noise(t, ch, sat, events)

    one, split, ranges = _one_pass_and_ranges(monkeypatch, "EVENT_RANGE_ROWS", stages)
    assert ranges.count((2, 0, 2)) == ranges.count((2, 4, 7)) == (3 if events.zones is not None else 2)
    (sat1, ch1, n1), (sat2, ch2, n2) = one, split
    assert (sat1.reacq > 1.0).any()
    if events.zones is not None:
        assert sat1.zone[0].any() and (sat1.bits & ev.OVERPASS).any() and n1.nlos.any()
        for a, b, what in zip(sat2.zone, sat1.zone, ("nlos", "bias", "rate", "atten")):
            np.testing.assert_array_equal(a, b, err_msg=what)
    for a, b, what in ((sat2.visible, sat1.visible, "visible"), (sat2.bits, sat1.bits, "bits"),
                       (sat2.reacq, sat1.reacq, "reacq"), (ch2.cn0, ch1.cn0, "cn0")):
        np.testing.assert_array_equal(a, b, err_msg=what)
    for f in fields(n1):
        np.testing.assert_array_equal(getattr(n2, f.name), getattr(n1, f.name), err_msg=f.name)


def test_imu_sensor_specs_and_sensor_row_contract():
    """_sensor_specs: the per-sample white sigma ARW / sqrt(dt); _sensor_row: an error-free sensor passes the
    sensed motion through, a constant bias is added as it is (and reported as no time-varying bias), the
    vibration is added times the rough-road factor, and a Gauss-Markov bias is the exact recursion."""
    dt = 0.01
    g = IMU_GRADES["industrial"]
    gyro, accel = _sensor_specs(g, dt)
    assert gyro.white_sigma == g.gyro_arw / math.sqrt(dt) and accel.white_sigma == g.accel_vrw / math.sqrt(dt)
    rng = np.random.default_rng(0)
    src, vib = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    rough = np.where(np.arange(50) < 20, 1.0, 3.0)
    ideal = _sensor_specs(IMU_GRADES["ideal"], dt)[0]
    o = np.empty((50, 3))
    none = np.empty((0, 3))
    assert not _sensor_row(ideal, src, None, np.ones(50), np.zeros((3, 3)), np.zeros(3), None, None, dt, o, none)
    np.testing.assert_array_equal(o, src)
    const = np.array([1e-3, -2e-3, 5e-4])
    assert not _sensor_row(ideal, src, vib, rough, np.zeros((3, 3)), const, None, None, dt, o, none)
    np.testing.assert_array_equal(o, (src + vib * rough[:, None]) + const)
    gm = replace(ideal, gm_sigma=0.1, gm_tau=2.0)
    bias = np.empty((50, 3))
    ch = _children(np.random.default_rng(5))
    assert _sensor_row(gm, src, None, np.ones(50), np.zeros((3, 3)), const, None, ch, dt, o, bias)
    z = _children(np.random.default_rng(5))[gm.gm_stream]
    phi = math.exp(-dt / 2.0)
    b = z.standard_normal(3) * 0.1                       # b_0
    u = z.standard_normal((50, 3)) * (0.1 * math.sqrt(1 - phi ** 2))
    for k in range(50):
        b = phi * b + u[k]
        np.testing.assert_allclose(bias[k], b + const, rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(o, src + bias)


def test_imu_row_events_contract():
    """_row_events: the rough factor is 1 outside the segments and their largest factor inside; a step bias
    holds from its time to the end, so the last sample carries the sum of the steps per sensor and axis."""
    events = ImuEvents(gyro_step_rate_hz=0.05, accel_step_rate_hz=0.05, rough_rate_hz=0.05)
    dt, n = 0.01, 12001
    for seed in range(6):
        (steps, rough), rough_f, sb = _row_events(np.random.default_rng(seed), events, (0.05, 0.05), dt, n)
        t_end = np.arange(n) * dt
        want = np.ones(n)
        for t0, t1, fac in rough:
            want = np.where((t_end > t0) & (t_end <= t1), np.maximum(want, fac), want)
        np.testing.assert_array_equal(np.ones(n) if rough_f is None else rough_f, want)
        for k, sensor in enumerate(("gyro", "accel")):
            last = np.zeros(3)
            for ts, s, axis, size in steps:
                if s == sensor:
                    last[axis] += size
            np.testing.assert_allclose(sb[k][-1], last, rtol=1e-12, atol=0)
            assert not np.any(sb[k][0])
