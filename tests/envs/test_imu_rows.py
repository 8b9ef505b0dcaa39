"""The IMU stage's compiled row pass (envs.sim.imu_kernels.imu_rows) against the one-row stages it runs.

simulate_imu draws each row's small numbers in Python, then runs the per-sample work of row ranges on threads in
one compiled call. These tests compose a row from the one-row stages instead (each tested against its numpy
specification in test_imu.py and test_world_stages.py) and require the same bits, on one thread or several.
"""
from __future__ import annotations

import copy

import numpy as np
import pytest

from envs.sim.imu import (
    IMU_GRADES,
    ImuEvents,
    Vibration,
    _children,
    _error_matrix,
    _row_events,
    _sensor_row,
    _sensor_specs,
    _vibration_row,
    simulate_imu,
)
from envs.sim.imu_kernels import steps_fill
from envs.sim.normals import fill_normals
from envs.sim.rng import row_generators

RATE = 100.0
DT = 1.0 / RATE
EVENTS = ImuEvents(gyro_step_rate_hz=0.05, accel_step_rate_hz=0.02, rough_rate_hz=0.05, rough_duration_s=(2.0, 6.0))


def _motion(b: int, n: int, seed: int):
    """Truth (f, w) (b, n, 3), speed (b, n) with stops, engine (b, n) off at the start of some rows."""
    rng = np.random.default_rng(seed)
    f = rng.normal(size=(b, n, 3)) + np.array([0.0, 0.0, -9.8])
    w = 0.05 * rng.normal(size=(b, n, 3))
    speed = np.abs(np.cumsum(rng.normal(size=(b, n)), axis=1)) * 0.3
    speed[:, n // 3:n // 2] = 0.0                                   # a stop in every row
    engine = np.ones((b, n), dtype=bool)
    engine[::4, : n // 5] = False                                   # some rows start with the engine off
    engine[5] = False                                               # and one never runs it: no vibration
    return f, w, speed, engine


def _reference_row(f, w, speed, engine, grade, gen, vgen, vib, events, dt, dtype):
    """One row from the one-row stages, in the draw order of simulate_imu: (w_b, f_b, gyro_bias, accel_bias)."""
    n = f.shape[0]
    ch = _children(gen)
    z = np.empty(24)
    fill_normals(*ch.raw_state("constants"), z)
    sensors = _sensor_specs(grade, dt)
    const = [s.fixed + z[3 * k:3 * k + 3] * s.turn_on_sigma for k, s in enumerate(sensors)]
    sm = [_error_matrix(z[6 + 9 * k:15 + 9 * k].reshape(3, 3), s.scale_sigma, s.mis_sigma)
          for k, s in enumerate(sensors)]
    v = _vibration_row(vgen, dt, engine, speed, vib) if vib is not None else None
    rough, sb = np.ones(n), (None, None)
    if events is not None:
        rates = (events.gyro_step_rate_hz, events.accel_step_rate_hz)
        _, rough_f, sb = _row_events(ch["events"], events, rates, dt, n)
        rough = rough if rough_f is None else rough_f
    outs = []
    for k, (s, truth) in enumerate(zip(sensors, (w, f))):
        out, bias = np.empty((n, 3), dtype), np.empty((n, 3), dtype)
        varies = _sensor_row(s, truth, None if v is None else v[:, 3 * (1 - k):3 * (2 - k)], rough, sm[k], const[k],
                             sb[k], ch, dt, out, bias)
        outs.append((out, bias if varies else np.broadcast_to(const[k].astype(dtype), (n, 3))))
    return outs[0][0], outs[1][0], outs[0][1], outs[1][1]


@pytest.mark.parametrize("vib_bits, dtype", [(np.random.PCG64, np.float64), (np.random.MT19937, np.float64),
                                             (np.random.PCG64, np.float32)])
def test_row_pass_equals_the_one_row_stages_on_any_thread_count(vib_bits, dtype):
    """40 rows (enough for several thread ranges) with vibration, rough road, bias steps and Gauss-Markov biases:
    every thread count gives the one-row stages' bits, and leaves the vibration generators where they leave
    them. MT19937 has no compiled stream: its road innovations are drawn by numpy and passed in."""
    b, n = 40, 1500
    f, w, speed, engine = _motion(b, n, 3)
    grade = IMU_GRADES["consumer"]
    vib = Vibration()
    seeds = list(range(100, 100 + b))

    def vgens():
        return [np.random.Generator(vib_bits(1000 + s)) for s in seeds]

    ref_v = vgens()
    refs = [_reference_row(f[i], w[i], speed[i], engine[i], grade, row_generators([s], "imu")[0], ref_v[i], vib,
                           EVENTS, DT, dtype) for i, s in enumerate(seeds)]
    assert all(np.any(r[0] != w[i]) for i, r in enumerate(refs))
    for workers in (1, 2, 3):
        got_v = vgens()
        got = simulate_imu(f, w, RATE, grade, row_generators(seeds, "imu"), engine_on=engine, speed=speed,
                           vibration=vib, dtype=dtype, workers=workers, vibration_rngs=got_v, events=EVENTS)
        for i, r in enumerate(refs):
            for name, want in zip(("w_b", "f_b", "gyro_bias", "accel_bias"), r):
                assert getattr(got, name).dtype == dtype
                assert np.array_equal(getattr(got, name)[i], want), (workers, i, name)
        assert [g.random() for g in got_v] == [copy.deepcopy(g).random() for g in ref_v]
    assert sum(map(bool, got.rough)) >= 5 and sum(map(bool, got.bias_steps)) >= 5   # events happened
    # without the bias records (an env's reset): the same samples and events, no bias arrays
    lean = simulate_imu(f, w, RATE, grade, row_generators(seeds, "imu"), engine_on=engine, speed=speed,
                        vibration=vib, dtype=dtype, workers=2, vibration_rngs=vgens(), events=EVENTS,
                        bias_records=False)
    assert lean.gyro_bias is None and lean.accel_bias is None
    assert np.array_equal(lean.w_b, got.w_b) and np.array_equal(lean.f_b, got.f_b)
    assert lean.rough == got.rough and lean.bias_steps == got.bias_steps
    with pytest.raises(ValueError, match="bias_records must be a bool"):
        simulate_imu(f, w, RATE, grade, row_generators(seeds, "imu"), bias_records=None)


def test_row_pass_without_vibration_or_events_and_ideal_grade():
    """No vibration, no events: the rows are the grade's errors alone; the ideal grade returns the truth."""
    b, n = 20, 400
    f, w, speed, engine = _motion(b, n, 4)
    seeds = list(range(b))
    got = simulate_imu(f, w, RATE, "tactical", row_generators(seeds, "imu"), workers=2)
    for i, s in enumerate(seeds):
        want = _reference_row(f[i], w[i], speed[i], None, IMU_GRADES["tactical"], row_generators([s], "imu")[0],
                              None, None, None, DT, np.float64)
        assert np.array_equal(got.w_b[i], want[0]) and np.array_equal(got.f_b[i], want[1])
    ideal = simulate_imu(f, w, RATE, "ideal", row_generators(seeds, "imu"), workers=2)
    assert np.array_equal(ideal.f_b, f) and np.array_equal(ideal.w_b, w)


def test_steps_fill_is_its_numpy_specification_to_the_bit():
    """Each step adds its size to its axis from its time on, in order, starting from zero: numpy's
    ``out[t_end > t, axis] += size``."""
    rng = np.random.default_rng(9)
    n, dt = 3000, 0.01
    steps = np.column_stack([rng.uniform(0, n * dt, 30), rng.integers(0, 2, 30), rng.integers(0, 3, 30),
                             rng.normal(size=30) * 1e-3])
    t_end = np.arange(n) * dt
    for sensor in (0, 1):
        want = np.zeros((n, 3))
        for t, s, axis, size in steps:
            if s == sensor:
                want[t_end > t, int(axis)] += size
        got = np.full((n, 3), np.nan)
        steps_fill(steps, sensor, dt, got)
        assert np.array_equal(got, want)
