"""Truth trajectory and ideal IMU (envs.sim.trajectory): closed forms, mechanization consistency, API."""
import math

import numpy as np
import pytest

from earth import C_en, OMEGA_IE_E, euler_from_dcm, exp_so3, gravity_ecef, log_so3, skew
from envs.sim.rng import row_generators
from envs.sim.trajectory import (
    STYLES, Accelerate, Climb, Cruise, Decelerate, Motion, Static, Stop, Turn, generate_truth,
    random_drive,
)

DEG = math.pi / 180.0
OMEGA = skew(OMEGA_IE_E)

# every boundary on a 100 Hz node: the states are smooth between nodes
ON_GRID = Motion(45.0, 7.0, 200.0, 30.0, 0.0, (
    Static(3.0), Accelerate(5.0, 10.0), Cruise(4.0), Turn(90.0, 10.0), Climb(4.0, 8.0, 2.0),
    Climb(0.0, 3.0, 1.5), Turn(-45.0, 15.0), Decelerate(4.0, 2.0), Stop(1.0), Static(2.0, engine_on=False)))
# boundaries between nodes, several in one 0.1 s interval, turn + climb back to back
OFF_GRID = Motion(-33.9, 151.2, 50.0, -120.0, 3.0, (
    Accelerate(2.0137, 12.0), Turn(0.3, 10.0), Cruise(0.0123), Turn(-37.0, 13.0), Climb(-3.0, 3.0571, 1.1234),
    Turn(20.0, 7.3), Climb(2.0, 1.5, 0.777), Decelerate(3.3333, 0.0), Static(1.2345), Accelerate(1.987, 4.0)))


def _gravity(tr):
    return gravity_ecef(tr.r_e.astype(np.float64))


def _smooth_intervals(m, n, rate):
    """(n-1,) bool: interval (t_{k-1}, t_k] holds no segment boundary strictly inside."""
    ends = []
    t = 0.0
    for s in m.segments:
        if isinstance(s, Climb):
            ends.append(t + s.transition_s)          # the pitch arc ends inside a Climb
        t += s.duration_s
        ends.append(t)
    ends = np.array(ends) * rate
    off = ends[np.abs(ends - np.round(ends)) > 1e-6]
    smooth = np.ones(n - 1, bool)
    k = np.floor(off).astype(int)
    smooth[k[k < n - 1]] = False
    return smooth


def _check_velocity_increments(tr, tol_mps, motions=None):
    """Velocity increments of the ECEF mechanization (trapezoid of C_eb f_b, g, Coriolis) match the truth.

    The trapezoid rule for C_eb f_b is itself only exact on smooth intervals: where a boundary
    splits an interval (f_b jumps while the body turns) the test allows 0.2 s^-1 dt^2 (2e-5 m/s at 100 Hz;
    Simpson across such a jump would be off by ~1e-3 m/s).
    """
    dt = tr.dt
    g = _gravity(tr)
    C, f, v = tr.C_eb, tr.f_b, tr.v_e
    fe = 0.5 * ((C[:, :-1] + C[:, 1:]) @ f[:, 1:, :, None])[..., 0]
    cor = (0.5 * (v[:, :-1] + v[:, 1:])) @ OMEGA.T
    dv_pred = dt * (fe + 0.5 * (g[:, :-1] + g[:, 1:]) - 2.0 * cor)
    err = np.abs(np.diff(v, axis=1) - dv_pred).max(axis=-1)
    if motions is not None:
        smooth = np.stack([_smooth_intervals(m, tr.t.size, tr.imu_rate_hz) for m in motions])
        assert err.max() < 0.2 * dt**2, err.max()
        err = err[smooth]
    assert err.max() < tol_mps, err.max()
    return err.max()


def test_position_velocity_consistent_on_smooth_pieces():
    tr = generate_truth([ON_GRID], 45.0, 100.0)
    dt = tr.dt
    # trapezoid of v over each interval = position increment (error dt^3 jerk / 12 < 1e-7 m here)
    trap = 0.5 * (tr.v_e[:, 1:] + tr.v_e[:, :-1]) * dt
    assert np.abs(np.diff(tr.r_e, axis=1) - trap).max() < 1e-6
    # and the derivative really is the velocity (not trivially zero)
    assert np.abs(np.diff(tr.r_e, axis=1)).max() > 0.09
    np.testing.assert_allclose(np.linalg.norm(tr.v_e, axis=-1), tr.speed, atol=1e-12)


def test_specific_force_consistent_with_ecef_mechanization():
    tr = generate_truth([ON_GRID], 45.0, 100.0)
    _check_velocity_increments(tr, 5e-8)
    # the tolerance resolves the Coriolis term: a sign error would show as 4 |Omega v| dt ~ 3e-5 m/s per step
    assert 4.0 * np.abs(tr.v_e @ OMEGA.T).max() * tr.dt > 100 * 5e-8


def test_gyro_rates_reproduce_attitude():
    for m in (ON_GRID, OFF_GRID):
        tr = generate_truth([m], 30.0, 100.0)
        dt = tr.dt
        C = tr.C_eb[0]
        np.testing.assert_allclose(C @ C.mT, np.broadcast_to(np.eye(3), C.shape), atol=1e-14)
        # C_eb(k) = exp(-omega_ie dt) C_eb(k-1) exp(mean w_ib^b dt): exact without coning
        pred = exp_so3(-OMEGA_IE_E * dt) @ C[:-1] @ exp_so3(tr.w_b[0, 1:] * dt)
        err = np.linalg.norm(log_so3(pred.mT @ C[1:]), axis=-1)
        # an interval holding a boundary between pieces that turn about different axes carries
        # the true coning of the motion, |phi_1 x phi_2| / 2 < 2e-7 rad here (the rate mean is exact)
        smooth = _smooth_intervals(m, tr.t.size, 100.0)
        assert smooth.sum() < smooth.size or m is ON_GRID
        assert err[smooth].max() < 1e-10, err[smooth].max()
        assert err.max() < 2e-7, err.max()


def test_imu_means_split_at_boundaries():
    # mean over a 0.1 s interval = average of the ten 10 ms means inside it, across boundaries too
    coarse = generate_truth([OFF_GRID], 20.0, 10.0)
    fine = generate_truth([OFF_GRID], 20.0, 100.0)
    for name in ("f_b", "w_b"):
        c = getattr(coarse, name)[0, 1:]
        fm = getattr(fine, name)[0, 1:].reshape(-1, 10, 3).mean(axis=1)
        np.testing.assert_allclose(c, fm, rtol=0, atol=1e-9 if name == "f_b" else 1e-13)
    np.testing.assert_allclose(coarse.r_e[0], fine.r_e[0, ::10], rtol=0, atol=1e-8)
    np.testing.assert_allclose(coarse.C_eb[0], fine.C_eb[0, ::10], rtol=0, atol=1e-14)
    _check_velocity_increments(fine, 5e-8, [OFF_GRID])


def test_low_rate_imu_is_the_mean_of_a_fast_one():
    # below 10 Hz gravity anchors lie between the nodes: every interval gets its Simpson midpoint
    slow = generate_truth([OFF_GRID, ON_GRID], 20.0, 4.0)
    fast = generate_truth([OFF_GRID, ON_GRID], 20.0, 100.0)
    for name in ("f_b", "w_b"):
        fm = getattr(fast, name)[:, 1:].reshape(2, -1, 25, 3).mean(axis=2)
        np.testing.assert_allclose(getattr(slow, name)[:, 1:], fm, rtol=0, atol=1e-7)
    np.testing.assert_allclose(slow.v_e, fast.v_e[:, ::25], rtol=0, atol=1e-10)


def test_instantaneous_first_sample_and_mean_afterwards():
    # during a pitch arc the body-frame gravity turns: the sample must be the interval mean, not t_k
    m = Motion(10.0, 20.0, 0.0, 0.0, 10.0, (Climb(10.0, 5.0, 5.0),))
    tr = generate_truth([m], 4.0, 10.0)
    tr0 = generate_truth([m], 4.0, 1000.0)
    np.testing.assert_allclose(tr.f_b[0, 0], tr0.f_b[0, 0], atol=1e-12)
    mean_fine = tr0.f_b[0, 1:].reshape(-1, 100, 3).mean(axis=1)
    np.testing.assert_allclose(tr.f_b[0, 1:], mean_fine, atol=1e-9)
    assert np.abs(tr.f_b[0, 1:] - tr0.f_b[0, 100::100]).max() > 1e-3   # end values differ


def test_static_vehicle_feels_gravity_and_earth_rate():
    m = Motion(48.1, 11.6, 520.0, 73.0, 0.0, (Static(5.0),))
    tr = generate_truth([m, m], 5.0, 50.0)
    assert np.all(tr.speed == 0.0) and np.all(tr.stationary()) and np.all(tr.engine_on)
    C_be = tr.C_eb.mT
    np.testing.assert_allclose(tr.w_b, (C_be @ OMEGA_IE_E), rtol=0, atol=1e-18)
    g = _gravity(tr)
    np.testing.assert_allclose(np.linalg.norm(tr.f_b, axis=-1), np.linalg.norm(g, axis=-1), rtol=1e-13)
    # level vehicle: specific force points up (-z body) along the gravity direction
    np.testing.assert_allclose(tr.f_b, -(C_be @ g[..., None])[..., 0], rtol=0, atol=1e-12)
    up = -tr.f_b / np.linalg.norm(tr.f_b, axis=-1, keepdims=True)
    assert np.all(up[..., 2] > np.cos(1e-4))
    assert np.abs(tr.f_b[..., 2] + 9.8).max() < 0.02


def test_known_segment_list_closed_form():
    R = 10.0 / (10.0 * DEG)                          # turn radius [m]
    v, q = 10.0, 5.0 * DEG / 2.0
    m = Motion(30.0, -100.0, 10.0, 0.0, 0.0, (
        Accelerate(5.0, 10.0), Cruise(10.0), Turn(90.0, 10.0), Climb(5.0, 10.0, 2.0), Decelerate(4.0, 0.0)))
    tr = generate_truth([m], 40.0, 100.0)
    i = lambda ts: int(round(ts * 100))            # noqa: E731
    C_Le = C_en(30.0 * DEG, -100.0 * DEG).T
    pL = (tr.r_e[0] - tr.r_e[0, 0]) @ C_Le.T
    hd = lambda a, b: np.angle(np.exp(1j * (tr.heading[0, b] - tr.heading[0, a])))  # noqa: E731
    assert tr.speed[0, i(5.0)] == pytest.approx(10.0, abs=1e-12)          # Accelerate reaches to_speed
    assert hd(i(15.0), i(24.0)) == pytest.approx(math.pi / 2, abs=1e-12)  # Turn: exactly +90 deg
    np.testing.assert_allclose(pL[i(15.0)], [125.0, 0.0, 0.0], atol=1e-8)
    np.testing.assert_allclose(pL[i(24.0)], [125.0 + R, R, 0.0], atol=1e-8)
    rise = v / q * (1 - math.cos(5 * DEG)) + v * 8.0 * math.sin(5 * DEG)
    run = v / q * math.sin(5 * DEG) + v * 8.0 * math.cos(5 * DEG)
    np.testing.assert_allclose(pL[i(34.0)], [125.0 + R, R + run, -rise], atol=1e-8)
    assert tr.pitch[0, i(30.0)] == pytest.approx(5 * DEG, abs=1e-14)
    end = [125.0 + R, R + run + 20.0 * math.cos(5 * DEG), -rise - 20.0 * math.sin(5 * DEG)]
    np.testing.assert_allclose(pL[-1], end, atol=1e-8)
    # travelled distance: speed is piecewise linear with nodes on the boundaries
    dist = np.sum(0.5 * (tr.speed[0, 1:] + tr.speed[0, :-1])) * tr.dt
    assert dist == pytest.approx(25.0 + 100.0 + 90.0 + 100.0 + 20.0, abs=1e-9)
    # attitude = C_en0 dcm(0, pitch, heading)
    eul = euler_from_dcm(C_Le @ tr.C_eb[0])
    np.testing.assert_allclose(eul[:, 0], 0.0, atol=1e-12)
    np.testing.assert_allclose(eul[:, 1], tr.pitch[0], atol=1e-12)
    np.testing.assert_allclose(np.angle(np.exp(1j * (eul[:, 2] - tr.heading[0]))), 0.0, atol=1e-12)
    # after the segments: at rest, engine idling (Decelerate keeps it on)
    assert np.all(tr.speed[0, i(38.0):] == 0.0) and np.all(tr.engine_on[0])


def test_continuation_and_truncation():
    m = Motion(0.0, 0.0, 0.0, 90.0, 5.0, (Accelerate(2.0, 7.0),))
    tr = generate_truth([m], 10.0, 20.0)
    assert np.all(tr.speed[0, 40:] == 7.0) and np.allclose(tr.heading[0], 90 * DEG)
    np.testing.assert_allclose(np.diff(tr.r_e[0, 40:], axis=0), np.broadcast_to(tr.v_e[0, 40:41] * 0.05, (160, 3)),
                               atol=1e-8)
    off = Motion(0.0, 0.0, 0.0, 0.0, 0.0, (Static(1.0), Accelerate(1.0, 1.0), Stop(1.0), Static(1.0, False)))
    tr = generate_truth([off], 8.0, 10.0)
    assert not tr.engine_on[0, 31:].any() and tr.engine_on[0, :30].all()
    assert np.all(tr.speed[0, 30:] == 0.0)
    long = Motion(0.0, 0.0, 0.0, 0.0, 5.0, (Cruise(1000.0),))
    tr = generate_truth([long], 2.0, 100.0)
    assert tr.t.shape == (201,) and tr.t[-1] == pytest.approx(2.0)


@pytest.mark.parametrize("m, d_short", [(ON_GRID, 12.0), (ON_GRID, 21.0), (OFF_GRID, 4.91), (OFF_GRID, 2.0137)])
def test_shorter_episode_is_a_prefix(m, d_short):
    # the sample means do not depend on where the episode ends (even on a segment boundary)
    long = generate_truth([m], 30.0, 100.0)
    short = generate_truth([m], d_short, 100.0)
    n = short.t.size
    for name in ("r_e", "v_e", "C_eb", "f_b", "w_b", "speed", "heading", "pitch", "engine_on"):
        np.testing.assert_allclose(getattr(short, name)[0], getattr(long, name)[0, :n], rtol=0, atol=1e-12,
                                   err_msg=name)


def test_batch_rows_equal_single_runs():
    rngs = row_generators([3, 4, 5], "trajectory")
    ms = [random_drive(rngs[0], 60.0, "urban"), OFF_GRID, random_drive(rngs[2], 60.0, "open"), OFF_GRID]
    tb = generate_truth(ms, 60.0, 50.0)
    for b, m in enumerate(ms):
        t1 = generate_truth([m], 60.0, 50.0)
        for name in ("r_e", "v_e", "C_eb", "f_b", "w_b", "speed", "heading", "pitch", "engine_on"):
            np.testing.assert_array_equal(getattr(tb, name)[b], getattr(t1, name)[0], err_msg=name)
        assert tb.lat0[b] == t1.lat0[0] and tb.h0[b] == t1.h0[0]


@pytest.mark.parametrize("rate", [100.0, 3.0, 13.7])
def test_batch_rows_equal_single_runs_bit_for_bit(rate):
    # the compiled node pass and the batched numpy parts give every row exactly what it gets alone, also with
    # anchors off the nodes (3 Hz), equal motions, and a row with a single arc node (a one-row BLAS product)
    one_arc = Motion(10.0, 20.0, 0.0, 0.0, 5.0, (Cruise(1.0), Turn(0.05, 10.0), Cruise(2.0)))
    rngs = row_generators([7, 8], "trajectory")
    ms = [random_drive(rngs[0], 40.0, "highway"), one_arc, ON_GRID, random_drive(rngs[1], 40.0, "open"), ON_GRID]
    tb = generate_truth(ms, 40.0, rate)
    for b, m in enumerate(ms):
        t1 = generate_truth([m], 40.0, rate)
        for name in ("r_e", "v_e", "C_eb", "f_b", "w_b", "speed", "heading", "pitch", "engine_on"):
            np.testing.assert_array_equal(getattr(tb, name)[b], getattr(t1, name)[0], err_msg=name)


@pytest.mark.parametrize("rate", [100.0, 13.7])
def test_rows_on_threads_equal_single_runs(rate):
    """The node pass runs row ranges on threads from 16 rows on (_node_rows): each of 40 rows of mixed drives
    (turns, climbs, stops; anchors on and off the nodes) is what it is alone, bit for bit."""
    rngs = row_generators(list(range(100, 140)), "trajectory")
    styles = ("urban", "open", "highway")
    ms = [random_drive(g, 30.0, styles[i % 3]) for i, g in enumerate(rngs)]
    tb = generate_truth(ms, 30.0, rate)
    for b in (0, 7, 8, 15, 16, 23, 31, 39):
        t1 = generate_truth([ms[b]], 30.0, rate)
        for name in ("r_e", "v_e", "C_eb", "f_b", "w_b", "speed", "heading", "pitch", "engine_on"):
            np.testing.assert_array_equal(getattr(tb, name)[b], getattr(t1, name)[0], err_msg=f"row {b} {name}")


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_row_ranges_of_the_stage_equal_one_pass(monkeypatch, dtype):
    """From 2 TRUTH_RANGE_ROWS rows on, generate_truth runs its rows in ranges on threads (each range the whole
    stage): 40 rows of mixed drives and a duplicated motion, in ranges of 8 rows on 3 threads, equal one pass over
    all rows, bit for bit, also into reused buffers."""
    from envs.sim import trajectory
    from envs.sim.buffers import WorldBuffers
    rngs = row_generators(list(range(200, 239)), "trajectory")
    styles = ("urban", "open", "highway")
    ms = [random_drive(g, 30.0, styles[i % 3]) for i, g in enumerate(rngs)] + [OFF_GRID]
    ms[5] = ms[30]  # equal motions are evaluated once, then copied
    ranges = []
    inner = trajectory.run_row_ranges

    def spy(fn, n_rows, workers=None, min_rows=8):
        if workers is not None:  # a range's node pass (on one thread)
            return inner(fn, n_rows, workers, min_rows)
        return inner(lambda u0, u1: ranges.append((u0, u1)) or fn(u0, u1), n_rows, 3, min_rows)

    monkeypatch.setattr(trajectory, "TRUTH_RANGE_ROWS", 10 ** 9)
    one = generate_truth(ms, 30.0, 13.7, dtype=dtype)
    monkeypatch.setattr(trajectory, "TRUTH_RANGE_ROWS", 8)
    monkeypatch.setattr(trajectory, "run_row_ranges", spy)
    buffers = WorldBuffers()
    for _ in range(2):
        split = generate_truth(ms, 30.0, 13.7, dtype=dtype, buffers=buffers)
        for name in ("r_e", "v_e", "C_eb", "f_b", "w_b", "speed", "heading", "pitch", "engine_on", "lat0", "h0"):
            np.testing.assert_array_equal(getattr(split, name), getattr(one, name), err_msg=name)
        del split
    # 39 distinct motions in 4 ranges of at least 8 rows, twice
    assert sorted(ranges) == [(0, 9), (0, 9), (9, 19), (9, 19), (19, 29), (19, 29), (29, 39), (29, 39)]


def test_float32_is_float64_rounded_once():
    t64 = generate_truth([ON_GRID, OFF_GRID], 20.0, 50.0)
    t32 = generate_truth([ON_GRID, OFF_GRID], 20.0, 50.0, dtype=np.float32)
    for name in ("r_e", "v_e", "C_eb", "f_b", "w_b", "speed", "heading", "pitch"):
        np.testing.assert_array_equal(getattr(t32, name), getattr(t64, name).astype(np.float32), err_msg=name)


def test_float32_output():
    t64 = generate_truth([ON_GRID, OFF_GRID], 20.0, 50.0)
    t32 = generate_truth([ON_GRID, OFF_GRID], 20.0, 50.0, dtype=np.float32)
    for name in ("r_e", "v_e", "C_eb", "f_b", "w_b", "speed", "heading", "pitch"):
        a = getattr(t32, name)
        assert a.dtype == np.float32, name
        np.testing.assert_allclose(a, getattr(t64, name), rtol=1e-6, atol=1e-6, err_msg=name)
    assert t32.engine_on.dtype == bool and t32.t.dtype == np.float64


def test_take_and_stationary():
    tr = generate_truth([ON_GRID, OFF_GRID], 20.0, 100.0)
    idx = np.array([0, 100, 1999])
    s = tr.take(idx)
    assert s.r_e.shape == (2, 3, 3) and s.C_eb.shape == (2, 3, 3, 3) and s.heading.shape == (2, 3)
    np.testing.assert_array_equal(s.v_e, tr.v_e[:, idx])
    np.testing.assert_array_equal(s.t, tr.t[idx])
    for idx in ([100, 200, 300], [5, 6, 7, 8], [-2001, -1901, -1801], [1999], [], [300, 200, 100], [7, 7, 7],
                [0, 100, 150]):                       # evenly spaced ones are sliced, the others gathered
        idx = np.array(idx, dtype=np.int64)
        s = tr.take(idx)
        for name in ("r_e", "v_e", "C_eb", "speed", "heading"):
            a = getattr(s, name)
            np.testing.assert_array_equal(a, getattr(tr, name)[:, idx], err_msg=name)
            assert not np.shares_memory(a, getattr(tr, name)), name            # a copy, as numpy gathers
    st = tr.stationary(0.05)
    assert st.shape == (2, 2001) and st.dtype == bool
    np.testing.assert_array_equal(st, tr.speed < 0.05)
    assert st[0, :300].all() and not st[0, 310:800].any()
    with pytest.raises(ValueError, match="idx"):
        tr.take(np.array([0.5]))
    with pytest.raises(ValueError, match="threshold_mps"):
        tr.stationary(-1.0)


@pytest.mark.parametrize("make, field", [
    (lambda: Static(-1.0), "duration_s"),
    (lambda: Cruise(float("nan")), "duration_s"),
    (lambda: Static(1.0, engine_on="yes"), "engine_on"),
    (lambda: Accelerate(1.0, -2.0), "to_speed_mps"),
    (lambda: Turn(90.0, 0.0), "rate_deg_s"),
    (lambda: Turn(float("inf"), 10.0), "angle_deg"),
    (lambda: Climb(95.0, 10.0, 2.0), "pitch_deg"),
    (lambda: Climb(5.0, 1.0, 2.0), "transition_s"),
    (lambda: Motion(91.0, 0.0, 0.0, 0.0), "lat0_deg"),
    (lambda: Motion(0.0, float("nan"), 0.0, 0.0), "lon0_deg"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, -1.0), "speed0_mps"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 0.0, (Turn(90.0, 10.0),)), r"segments\[0\].*speed"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 0.0, (Static(1.0), Climb(3.0, 5.0, 1.0))), r"segments\[1\].*speed"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 10.0, (Accelerate(2.0, 5.0),)), r"segments\[0\].*to_speed_mps"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 5.0, (Decelerate(2.0, 8.0),)), r"segments\[0\].*to_speed_mps"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 5.0, (Static(2.0),)), r"segments\[0\].*Static"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 5.0, (Accelerate(0.0, 8.0),)), r"segments\[0\].*duration_s"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 5.0, (Climb(3.0, 5.0, 0.0),)), r"segments\[0\].*transition_s"),
    (lambda: Motion(0.0, 0.0, 0.0, 0.0, 5.0, (Cruise(1.0), "turn")), r"segments\[1\]"),
    (lambda: generate_truth([ON_GRID], -1.0, 100.0), "duration_s"),
    (lambda: generate_truth([ON_GRID], 1.0, float("nan")), "imu_rate_hz"),
    (lambda: generate_truth([ON_GRID], 1.0, 100.0, dtype=np.int32), "dtype"),
    (lambda: generate_truth([], 1.0, 100.0), "motions"),
    (lambda: generate_truth([ON_GRID, "x"], 1.0, 100.0), r"motions\[1\]"),
    (lambda: random_drive(np.random.default_rng(0), 60.0, "offroad"), "style"),
    (lambda: random_drive(np.random.default_rng(0), -5.0), "duration_s"),
    (lambda: random_drive(0, 60.0), "rng"),
])
def test_bad_input_names_the_field(make, field):
    with pytest.raises(ValueError, match=field):
        make()


@pytest.mark.parametrize("style", STYLES)
def test_random_drive_deterministic_fills_duration_and_consistent(style):
    D = 300.0
    a = random_drive(row_generators([7], "trajectory")[0], D, style)
    b = random_drive(row_generators([7], "trajectory")[0], D, style)
    c = random_drive(row_generators([8], "trajectory")[0], D, style)
    assert a == b and a != c
    for m in (a, c):
        assert m.duration_s >= D
        assert isinstance(m.segments[0], Static) and 5.0 <= m.segments[0].duration_s <= 10.0
    tr = generate_truth([a, c], D, 20.0)
    sp = tr.speed
    assert np.all(tr.stationary()[:, :100])                      # initial alignment at rest
    start = [int(np.ceil(20.0 * (m.segments[0].duration_s + m.segments[1].duration_s))) for m in (a, c)]
    moving = np.concatenate([sp[0, start[0]:], sp[1, start[1]:]])
    if style == "urban":
        assert sp.max() <= 15.0 + 1e-9 and np.any(tr.stationary()[:, 300:])   # stops at lights
        assert any(isinstance(s, Turn) and abs(s.angle_deg) == 90.0 for s in a.segments + c.segments)
    elif style == "highway":
        assert moving.min() >= 25.0 - 1e-9 and moving.max() <= 33.0 + 1e-9
    else:
        assert moving.min() >= 10.0 - 1e-9 and moving.max() <= 25.0 + 1e-9
        assert np.abs(tr.pitch).max() > 0.5 * DEG
        assert np.abs(tr.pitch[:, -1]).max() < 5.1 * DEG
    _check_velocity_increments(tr, 2e-6, [a, c])   # 50 ms steps: trapezoid residual grows as dt^3


@pytest.mark.parametrize("scenario, rows, every", [("urban", 3, 10), ("noise-burst", 130, 10), ("urban", 2, 7)])
def test_states_every_kth_sample_equal_those_samples_of_every_samples_states(scenario, rows, every):
    """``generate_truth(..., states_every=s)`` forms r_e, v_e, C_eb only at samples 0, s, 2 s, ...: the same bits
    there as the truth with every sample's states (arcs, straight pieces, the row ranges on threads from 128 rows,
    float32), and every other field the same; ``take`` refuses the samples it did not form."""
    from envs.sim.scenarios import get_scenario
    scen = get_scenario(scenario, duration_s=20.0)
    motions = scen.motions(row_generators(list(range(40, 40 + rows)), "trajectory"))
    for dtype in (np.float64, np.float32):
        dense = generate_truth(motions, 20.0, 100.0, dtype=dtype)
        coarse = generate_truth(motions, 20.0, 100.0, dtype=dtype, states_every=every)
        assert coarse.r_e is None and coarse.v_e is None and coarse.C_eb is None and coarse.states_every == every
        assert coarse.batch_size == rows
        idx = np.arange(0, dense.t.size, every)
        assert idx.size == coarse.coarse.r_e.shape[1]
        a, b = dense.take(idx), coarse.take(idx)
        for name in ("t", "r_e", "v_e", "C_eb", "speed", "heading"):
            assert getattr(b, name).dtype == getattr(a, name).dtype
            np.testing.assert_array_equal(getattr(b, name), getattr(a, name), err_msg=name)
        last = coarse.take(np.array([-1 - (dense.t.size - 1) % every]))          # a negative index of a formed one
        np.testing.assert_array_equal(last.r_e[:, 0], a.r_e[:, -1])
        for name in ("t", "f_b", "w_b", "speed", "heading", "pitch", "engine_on", "lat0", "lon0", "h0"):
            np.testing.assert_array_equal(getattr(coarse, name), getattr(dense, name), err_msg=name)
    with pytest.raises(ValueError, match=rf"multiples of {every} .*sample {every + 1} is not one"):
        coarse.take(np.array([0, every + 1]))
    with pytest.raises(ValueError, match="states_every must be an int >= 1"):
        generate_truth(motions, 20.0, 100.0, states_every=0)


def test_pieces_of_many_motions_equal_each_motions_own_forms():
    """The pieces of many motions formed at once (one table per motion, the trigonometry and the Earth rate in
    the body over all pieces) hold, bit for bit, what each motion's pieces alone give by the per-row forms: its
    columns, ``cos`` / ``sin`` of its own start headings and pitches, ``np.einsum('pji,j->pi', C_Lb, w_L)`` and
    ``r0 + p0 C_eL^T`` (signed zeros included: a piece heading north, and an Earth rate with a -0 east term)."""
    from earth import dcm_from_euler, geodetic_to_ecef
    from envs.sim.trajectory import _PLAN_COLUMNS, _pieces
    north = Motion(10.0, 20.0, 0.0, 0.0, 5.0, (Cruise(3.0), Turn(90.0, 30.0), Cruise(2.0)))   # heading 0, 90
    motions = [ON_GRID, OFF_GRID, north] + [random_drive(g, 120.0, style=s) for g, s in
                                             zip(row_generators(range(9), "trajectory"), STYLES * 3)]
    lat0 = np.array([m.lat0_deg for m in motions]) * DEG
    lon0 = np.array([m.lon0_deg for m in motions]) * DEG
    C_eL = C_en(lat0, lon0)
    r0 = geodetic_to_ecef(lat0, lon0, np.array([m.h0_m for m in motions]))
    wL = np.einsum("uji,j->ui", C_eL, OMEGA_IE_E)
    pc = _pieces([m._plan for m in motions], C_eL, r0, wL)
    bits = lambda a: np.ascontiguousarray(a).tobytes()  # noqa: E731
    a = 0
    for u, m in enumerate(motions):
        tab = m._plan
        assert tab.shape[1] == len(_PLAN_COLUMNS)
        b = a + tab.shape[0]
        psi0, gam0 = tab[:, 7].copy(), tab[:, 9].copy()
        assert bits(pc.pl.t0[a:b]) == bits(tab[:, 0]) and bits(pc.pl.p0[a:b]) == bits(tab[:, 2:5])
        assert (pc.pl.kind[a:b] == tab[:, 1]).all() and (pc.pl.engine[a:b] == (tab[:, 11] == 1.0)).all()
        for got, want in ((pc.pl.cpsi, np.cos(psi0)), (pc.pl.spsi, np.sin(psi0)), (pc.pl.cgam, np.cos(gam0)),
                          (pc.pl.sgam, np.sin(gam0))):
            assert bits(got[a:b]) == bits(want), u
        C_Lb = dcm_from_euler(0.0, gam0, psi0)
        assert bits(pc.wb[a:b]) == bits(np.einsum("pji,j->pi", C_Lb, wL[u])), u
        assert bits(pc.re0[a:b]) == bits(r0[u] + tab[:, 2:5].copy() @ C_eL[u].T), u
        assert (pc.row[a:b] == u).all() and pc.last[b - 1] and not pc.last[a:b - 1].any()
        a = b
    assert a == pc.row.size
    # any Earth rate (three non-zero terms; signed zeros): still einsum's sum, row by row
    rng = np.random.default_rng(4)
    for wX in (rng.normal(0.0, 7e-5, (len(motions), 3)), np.tile([-7e-5, -0.0, -7e-5], (len(motions), 1))):
        pc = _pieces([m._plan for m in motions], C_eL, r0, wX)
        a = 0
        for u, m in enumerate(motions):
            b = a + m._plan.shape[0]
            C_Lb = dcm_from_euler(0.0, m._plan[:, 9].copy(), m._plan[:, 7].copy())
            assert bits(pc.wb[a:b]) == bits(np.einsum("pji,j->pi", C_Lb, wX[u])), u
            a = b


def test_node_pass_arcs_equal_numpy_trigonometry_bit_for_bit(monkeypatch):
    """On the arcs the node pass forms the turning angle and its cos / sin itself: the heading (wrapped to
    [-pi, pi)) and pitch at arc nodes, and the Simpson means over intervals on one arc, equal bit for bit those
    formed with numpy's trigonometry (``_kin``, ``_arc_kin``) and the point evaluation ``_imu_points``."""
    import envs.sim.trajectory as T
    seen = {}
    evaluate = T._evaluate

    def spy(pc, t, grav, linear_gravity, out, workers=None, se=1):
        seen.update(pc=pc, t=t, grav=grav)
        return evaluate(pc, t, grav, linear_gravity, out, workers, se)

    monkeypatch.setattr(T, "_evaluate", spy)
    motions = [ON_GRID, OFF_GRID] + [random_drive(g, 30.0, style=s) for g, s in
                                      zip(row_generators(range(20, 26), "trajectory"), STYLES * 2)]
    tr = generate_truth(motions, 30.0, 100.0)
    pc, t, grav = seen["pc"], seen["t"], seen["grav"]
    n = t.size
    pn = T._grid_pieces(pc, t)[2]
    arc = np.flatnonzero(pc.pl.kind[pn] != T._STRAIGHT)
    assert arc.size > 1000 and (pc.pl.kind[pn[arc]] == T._VARC).any()
    k = T._kin(pc.pl, t[arc % n], pn[arc])
    assert tr.heading.reshape(-1)[arc[k.i_h]].tobytes() == T._wrap(k.psi_h).tobytes()
    assert tr.pitch.reshape(-1)[arc[k.i_v]].tobytes() == k.gam_v.tobytes()
    assert (tr.heading >= -math.pi).all() and (tr.heading < math.pi).all()
    g = arc[arc % n != 0]
    g = g[pn[g - 1] == pn[g]]                                   # intervals (t_k-1, t_k] on one arc piece
    kk, p = g % n, pn[g]
    vals = []
    for tt in (t[kk - 1], t[kk], 0.5 * (t[kk - 1] + t[kk])):
        _, c, s = T._arc_kin(pc.pl, tt, p)
        f, w = np.empty((g.size, 3)), np.empty((g.size, 3))
        T._imu_points(tt, p, c, s, pc, *grav, f, w)
        vals.append((f, w))
    e, d = (np.diff(t)[kk - 1] / 6.0)[:, None], np.diff(t)[kk - 1][:, None]
    for j, name in enumerate(("f_b", "w_b")):
        mean = (vals[0][j] + vals[1][j] + 4.0 * vals[2][j]) * e / d
        assert getattr(tr, name).reshape(-1, 3)[g].tobytes() == mean.tobytes(), name
