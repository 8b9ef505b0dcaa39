"""Tests of envs.sim.imu: IMU error model, grades, vibration."""
from __future__ import annotations

import math

import numpy as np
import pytest

from earth.units import G0, deg, dph, dpsh, mg, ugpsh
from envs.sim.imu import (
    IMU_GRADES,
    ImuGrade,
    Vibration,
    allan_deviation,
    get_imu_grade,
    simulate_imu,
    simulate_vibration,
    sinusoid_interval_mean,
)
from envs.sim.rng import row_generators

RATE = 100.0
DT = 1.0 / RATE


def static_truth(b, n):
    """Level, stationary IMU: f = (0, 0, -g) in FRD, w = 0."""
    f = np.zeros((b, n, 3))
    f[..., 2] = -G0
    return f, np.zeros((b, n, 3))


def rngs(seeds):
    return row_generators(list(seeds), "imu")


IDEAL = IMU_GRADES["ideal"]


# ----------------------------------------------------------------------------- grades
def test_ideal_grade_returns_truth_exactly():
    r = np.random.default_rng(1)
    f = r.normal(size=(3, 400, 3)) * 5
    w = r.normal(size=(3, 400, 3))
    d = simulate_imu(f, w, RATE, "ideal", rngs(range(3)))
    assert np.array_equal(d.f_b, f) and np.array_equal(d.w_b, w)
    assert not d.gyro_bias.any() and not d.accel_bias.any()
    assert not d.gyro_scale_misalignment.any() and not d.accel_scale_misalignment.any()
    assert d.f_b.shape == d.gyro_bias.shape == (3, 400, 3) and d.dt == DT
    assert IDEAL.is_ideal and not IMU_GRADES["seed000"].is_ideal


def test_presets_and_lookup():
    assert {"ideal", "consumer", "industrial", "tactical", "seed000"} <= set(IMU_GRADES)
    for name, g in IMU_GRADES.items():
        assert get_imu_grade(name) is g and g.name == name
    # seed000: per-sample sigma at 100 Hz is 3 mg and 1 deg/h (seed paper 000 sec. 5.1)
    s0 = IMU_GRADES["seed000"]
    assert s0.accel_vrw / math.sqrt(DT) == pytest.approx(mg(3.0), rel=1e-12)
    assert s0.gyro_arw / math.sqrt(DT) == pytest.approx(dph(1.0), rel=1e-12)
    # seed003 Table 1, and grades ordered by quality
    s3 = IMU_GRADES["seed003"]
    assert s3.gyro_arw == pytest.approx(dpsh(0.2)) and s3.accel_vrw == pytest.approx(ugpsh(700.0))
    assert s3.gyro_bias_turn_on_sigma == pytest.approx(dph(8.0))
    c, i, t = IMU_GRADES["consumer"], IMU_GRADES["industrial"], IMU_GRADES["tactical"]
    for field in ("gyro_arw", "gyro_bias_turn_on_sigma", "accel_bias_turn_on_sigma", "gyro_scale_sigma"):
        assert getattr(c, field) > getattr(i, field) > getattr(t, field), field
    with pytest.raises(ValueError, match="industrial"):
        get_imu_grade("navigation-grade-x")


def test_white_noise_sigma_and_allan_deviation():
    arw, vrw = dpsh(2.0), ugpsh(2000.0)
    grade = IDEAL.replace(name="white", gyro_arw=arw, accel_vrw=vrw)
    b, n = 4, 40000
    f, w = static_truth(b, n)
    d = simulate_imu(f, w, RATE, grade, rngs(range(b)))
    eg, ea = d.w_b - w, d.f_b - f
    # per-sample sigma of an interval mean: N / sqrt(dt); rel. std error 1/sqrt(2 * 480000) ~ 0.1 %
    assert np.std(eg) == pytest.approx(arw / math.sqrt(DT), rel=0.01)
    assert np.std(ea) == pytest.approx(vrw / math.sqrt(DT), rel=0.01)
    assert abs(np.mean(eg)) < 5 * arw / math.sqrt(DT) / math.sqrt(eg.size)
    # white: lag-1 autocorrelation ~ 0
    x = eg[..., 0]
    assert abs(np.mean(x[:, 1:] * x[:, :-1]) / np.mean(x * x)) < 0.01
    # Allan deviation (IEEE 952): ADEV(tau) = N / sqrt(tau)
    taus, adev = allan_deviation(eg, DT, [1.0, 10.0], axis=1)
    assert adev.shape == (b, 2, 3)
    assert np.mean(adev[:, 0]) == pytest.approx(arw, rel=0.1)
    assert np.mean(adev[:, 1]) == pytest.approx(arw / math.sqrt(10.0), rel=0.1)
    _, adev_a = allan_deviation(ea, DT, [1.0], axis=1)
    assert np.mean(adev_a) == pytest.approx(vrw, rel=0.1)


def test_gauss_markov_bias_variance_and_correlation():
    sg, tg, sa, ta = 1e-3, 0.5, 2e-2, 2.0
    grade = IDEAL.replace(name="gm", gyro_bias_instability=sg, gyro_bias_tau_s=tg,
                          accel_bias_instability=sa, accel_bias_tau_s=ta)
    b, n = 8, 20000
    f, w = static_truth(b, n)
    d = simulate_imu(f, w, RATE, grade, rngs(range(b)))
    assert np.array_equal(d.w_b - w, d.gyro_bias) and np.allclose(d.f_b - f, d.accel_bias, atol=1e-14)
    for bias, sigma, tau, tol in ((d.gyro_bias, sg, tg, 0.06), (d.accel_bias, sa, ta, 0.15)):
        assert np.mean(bias**2) == pytest.approx(sigma**2, rel=tol)
        x = np.moveaxis(bias, 1, -1).reshape(-1, n)
        x = x - x.mean(axis=1, keepdims=True)
        var = np.mean(x * x)
        rho1 = np.mean(x[:, 1:] * x[:, :-1]) / var
        assert rho1 == pytest.approx(math.exp(-DT / tau), abs=0.003)
        m = int(round(tau / DT))  # lag tau: 1/e
        rho_tau = np.mean(x[:, m:] * x[:, :-m]) / var
        assert rho_tau == pytest.approx(math.exp(-1.0), abs=0.06)
    # stationary from the first sample: var(b_1) over many runs = sigma^2
    f2, w2 = static_truth(600, 2)
    d2 = simulate_imu(f2, w2, RATE, grade.replace(gyro_bias_tau_s=1e4), rngs(range(600)), workers=1)
    assert np.mean(d2.gyro_bias[:, 0] ** 2) == pytest.approx(sg**2, rel=0.12)


def test_turn_on_bias_constant_within_run_random_across_runs():
    grade = IDEAL.replace(name="on", gyro_bias_turn_on_sigma=dph(8.0), accel_bias_turn_on_sigma=mg(1.0))
    b, n = 400, 30
    f, w = static_truth(b, n)
    d = simulate_imu(f, w, RATE, grade, rngs(range(b)))
    assert np.ptp(d.gyro_bias, axis=1).max() == 0.0 and np.ptp(d.accel_bias, axis=1).max() == 0.0
    assert np.array_equal(d.w_b - w, d.gyro_bias)
    bg = d.gyro_bias[:, 0]
    assert np.std(bg) == pytest.approx(dph(8.0), rel=0.1)
    assert np.std(d.accel_bias[:, 0]) == pytest.approx(mg(1.0), rel=0.1)
    assert abs(np.mean(bg)) < 4 * dph(8.0) / math.sqrt(bg.size)
    assert len(np.unique(bg[:, 0])) == b  # differs across seeds
    again = simulate_imu(f[:5], w[:5], RATE, grade, rngs(range(5)))
    assert np.array_equal(again.gyro_bias, d.gyro_bias[:5])  # same seed, same bias


def test_scale_factor_and_misalignment():
    grade = IDEAL.replace(name="sm", gyro_scale_sigma=1e-3, gyro_misalignment_sigma=2e-3,
                          accel_scale_sigma=3e-3, accel_misalignment_sigma=5e-4)
    b, n = 300, 4
    r = np.random.default_rng(5)
    f = r.normal(size=(b, n, 3)) * 10
    w = r.normal(size=(b, n, 3))
    d = simulate_imu(f, w, RATE, grade, rngs(range(b)))
    eye = np.eye(3)
    assert np.allclose(d.w_b, w @ (eye + d.gyro_scale_misalignment).mT, rtol=0, atol=1e-14)
    assert np.allclose(d.f_b, f @ (eye + d.accel_scale_misalignment).mT, rtol=0, atol=1e-13)
    off = ~np.eye(3, dtype=bool)
    for m, s, mis in ((d.gyro_scale_misalignment, 1e-3, 2e-3), (d.accel_scale_misalignment, 3e-3, 5e-4)):
        assert np.std(np.diagonal(m, axis1=1, axis2=2)) == pytest.approx(s, rel=0.1)
        assert np.std(m[:, off]) == pytest.approx(mis, rel=0.1)


def test_seed000_fixed_biases_are_the_mean_error():
    g = IMU_GRADES["seed000"]
    b, n = 4, 6000
    f, w = static_truth(b, n)
    d = simulate_imu(f, w, RATE, g, rngs(range(b)))
    fa, fg = np.array(g.accel_bias_fixed), np.array(g.gyro_bias_fixed)
    assert np.array_equal(fa, [0.0883, -0.1275, 0.0785]) and np.array_equal(fg, [-8.7e-4, 13e-4, -8.7e-4])
    assert np.array_equal(d.accel_bias, np.broadcast_to(fa, (b, n, 3)))
    assert np.array_equal(d.gyro_bias, np.broadcast_to(fg, (b, n, 3)))
    ea, eg = (d.f_b - f).reshape(-1, 3), (d.w_b - w).reshape(-1, 3)
    se_a, se_g = mg(3.0) / math.sqrt(b * n), dph(1.0) / math.sqrt(b * n)
    assert np.all(np.abs(ea.mean(0) - fa) < 5 * se_a)
    assert np.all(np.abs(eg.mean(0) - fg) < 5 * se_g)
    assert np.std(ea - fa) == pytest.approx(mg(3.0), rel=0.02)
    assert np.std(eg - fg) == pytest.approx(dph(1.0), rel=0.02)
    assert not d.gyro_scale_misalignment.any()


# ----------------------------------------------------------------------------- batching, dtype
def _drive_profile(b, n):
    speed = np.zeros((b, n))
    speed[:, n // 3: 2 * n // 3] = 12.0
    engine = np.ones((b, n), dtype=bool)
    engine[:, 5 * n // 6:] = False
    return speed, engine


def test_batch_invariance_row_i_equals_single_run():
    b, n = 6, 900
    f, w = static_truth(b, n)
    f = f + np.random.default_rng(2).normal(size=f.shape)
    speed, engine = _drive_profile(b, n)
    seeds = [11, 3, 7, 0, 42, 5]
    kw = dict(engine_on=engine, speed=speed, vibration=Vibration())
    full = simulate_imu(f, w, RATE, "consumer", rngs(seeds), **kw)
    serial = simulate_imu(f, w, RATE, "consumer", rngs(seeds), workers=1, **kw)
    for name in ("f_b", "w_b", "gyro_bias", "accel_bias", "gyro_scale_misalignment"):
        assert np.array_equal(getattr(full, name), getattr(serial, name)), name
    for i, s in enumerate(seeds):
        one = simulate_imu(f[i:i + 1], w[i:i + 1], RATE, "consumer", rngs([s]),
                           engine_on=engine[i:i + 1], speed=speed[i:i + 1], vibration=Vibration())
        for name in ("f_b", "w_b", "gyro_bias", "accel_bias", "gyro_scale_misalignment", "accel_scale_misalignment"):
            assert np.array_equal(getattr(one, name)[0], getattr(full, name)[i]), (name, i)
    assert not np.array_equal(full.w_b[0], full.w_b[1])


def test_float32_output():
    b, n = 2, 500
    f, w = static_truth(b, n)
    d64 = simulate_imu(f, w, RATE, "industrial", rngs(range(b)))
    d32 = simulate_imu(f, w, RATE, "industrial", rngs(range(b)), dtype=np.float32)
    for name in ("f_b", "w_b", "gyro_bias", "accel_bias", "gyro_scale_misalignment", "accel_scale_misalignment"):
        a32, a64 = getattr(d32, name), getattr(d64, name)
        assert a32.dtype == np.float32, name
        assert np.array_equal(a32, a64.astype(np.float32)), name
    const = simulate_imu(f, w, RATE, "seed000", rngs(range(b)), dtype=np.float32)
    assert const.gyro_bias.dtype == np.float32 and const.f_b.dtype == np.float32


def test_error_streams_are_independent_of_other_terms():
    """Changing one error term (or adding vibration) leaves the other realizations unchanged."""
    b, n = 2, 800
    f, w = static_truth(b, n)
    base = IMU_GRADES["industrial"]
    d1 = simulate_imu(f, w, RATE, base, rngs(range(b)))
    d2 = simulate_imu(f, w, RATE, base.replace(gyro_arw=0.0), rngs(range(b)))
    assert np.array_equal(d1.gyro_bias, d2.gyro_bias) and np.array_equal(d1.f_b, d2.f_b)
    speed, engine = _drive_profile(b, n)
    d3 = simulate_imu(f, w, RATE, base, rngs(range(b)), engine_on=engine, speed=speed, vibration=Vibration())
    off = ~engine
    assert np.array_equal(d3.f_b[off], d1.f_b[off]) and np.array_equal(d3.w_b[off], d1.w_b[off])
    assert np.array_equal(d3.accel_bias, d1.accel_bias)
    assert np.all(np.abs(d3.f_b[engine] - d1.f_b[engine]) > 0)


# ----------------------------------------------------------------------------- vibration
def test_sinusoid_interval_mean_matches_fine_grid_integration():
    r = np.random.default_rng(0)
    for _ in range(20):
        a, fr, ph = r.uniform(0.1, 2), r.uniform(1, 120), r.uniform(0, 2 * np.pi)
        t0, dt = r.uniform(0, 1000), r.choice([0.01, 0.1, 0.008])
        om = 2 * np.pi * fr
        t = np.linspace(t0, t0 + dt, 20001)
        y = a * np.sin(om * t + ph)
        numeric = np.sum((y[1:] + y[:-1]) * 0.5) / (len(t) - 1)  # trapezoid mean
        closed = a * (np.cos(om * t0 + ph) - np.cos(om * (t0 + dt) + ph)) / (om * dt)
        got = sinusoid_interval_mean(a, om, ph, t0, dt)
        assert got == pytest.approx(numeric, abs=1e-7)
        assert got == pytest.approx(closed, abs=1e-9)
    assert sinusoid_interval_mean(1.0, 2 * np.pi * 100.0, 0.3, 2.0, 0.01) == pytest.approx(0.0, abs=1e-12)


def test_vibration_only_idle_with_engine_on_and_analytic_rms():
    b, n = 3, 6000
    f, w = static_truth(b, n)
    speed, engine = _drive_profile(b, n)
    idle_only = Vibration(engine_freq_hz_range=(25.0, 25.0), harmonic_ratio=0.0,
                          idle_accel_rms_range=(0.2, 0.2), idle_gyro_rms_range=(deg(0.1), deg(0.1)),
                          road_accel_rms_ref_range=(0.0, 0.0), road_gyro_rms_ref_range=(0.0, 0.0))
    d = simulate_imu(f, w, RATE, "ideal", rngs(range(b)), engine_on=engine, speed=speed, vibration=idle_only)
    vf, vw = d.f_b - f, d.w_b - w
    idle = engine & (speed == 0)
    assert not vf[~idle].any() and not vw[~idle].any()  # moving (no road level) and engine off
    # interval mean of a 25 Hz sinusoid at 100 Hz: rms attenuated by sinc(w dt / 2)
    att = math.sin(np.pi * 25 * DT) / (np.pi * 25 * DT)
    assert np.sqrt(np.mean(vf[idle] ** 2, axis=0)) == pytest.approx([0.2 * att] * 3, rel=0.01)
    assert np.sqrt(np.mean(vw[idle] ** 2, axis=0)) == pytest.approx([deg(0.1) * att] * 3, rel=0.01)
    # with road vibration: also while moving, still nothing with the engine off
    d2 = simulate_imu(f, w, RATE, "ideal", rngs(range(b)), engine_on=engine, speed=speed, vibration=Vibration())
    moving = engine & (speed > 0)
    assert not (d2.f_b - f)[~engine].any()
    assert np.all(np.abs(d2.f_b - f)[moving] > 0) and np.all(np.abs(d2.w_b - w)[idle] > 0)
    # the vehicle's own stream: simulate_imu applies exactly simulate_vibration's output
    vr = lambda: row_generators(range(b), "vibration")  # noqa: E731
    fv, wv = simulate_vibration(RATE, vr(), speed=speed, engine_on=engine)
    d4 = simulate_imu(f, w, RATE, "ideal", rngs(range(b)), engine_on=engine, speed=speed, vibration=Vibration(),
                      vibration_rngs=vr())
    assert np.array_equal(d4.f_b, f + fv) and np.array_equal(d4.w_b, w + wv)
    # disabled vibration: truth
    d3 = simulate_imu(f, w, RATE, "ideal", rngs(range(b)), engine_on=engine, speed=speed, vibration=Vibration.none())
    assert np.array_equal(d3.f_b, f)


def test_engine_harmonic_aliases_into_interval_means():
    n = 4000
    vib = Vibration(engine_freq_hz_range=(35.0, 35.0), harmonic_ratio=1.0,
                    idle_accel_rms_range=(0.3, 0.3), idle_gyro_rms_range=(0.0, 0.0))
    fv, wv = simulate_vibration(RATE, rngs([4]), speed=np.zeros((1, n)), vibration=vib)
    assert not wv.any()
    spec = np.abs(np.fft.rfft(fv[0, :, 2]))
    freqs = np.fft.rfftfreq(n, DT)
    top2 = sorted(freqs[np.argsort(spec)[-2:]])
    assert top2 == pytest.approx([30.0, 35.0])  # 70 Hz harmonic folds to 100 - 70 = 30 Hz
    # each tone's amplitude is sqrt(2) * rms / sqrt(2) times its own sinc attenuation
    amp = 2 * spec / n
    for fr in (35.0, 70.0):
        k = int(round(abs(RATE * round(fr / RATE) - fr) / (RATE / n)))
        att = abs(math.sin(np.pi * fr * DT) / (np.pi * fr * DT))
        assert amp[k] == pytest.approx(0.3 * att, rel=0.02)


def test_road_vibration_grows_with_speed():
    b, n = 4, 8000
    speed = np.full((b, n), 10.0)
    speed[:, n // 2:] = 20.0
    vib = Vibration(road_accel_rms_ref_range=(0.4, 0.4), road_gyro_rms_ref_range=(deg(0.5), deg(0.5)),
                    road_ref_speed_mps=20.0, road_speed_exponent=1.0)
    fv, wv = simulate_vibration(RATE, rngs(range(b)), speed=speed, vibration=vib)
    rms_lo = np.sqrt(np.mean(fv[:, : n // 2] ** 2))
    rms_hi = np.sqrt(np.mean(fv[:, n // 2:] ** 2))
    assert rms_hi == pytest.approx(0.4, rel=0.1)
    assert rms_hi / rms_lo == pytest.approx(2.0, rel=0.1)
    assert np.sqrt(np.mean(wv[:, n // 2:] ** 2)) == pytest.approx(deg(0.5), rel=0.1)
    # band-limited, not white: strongly correlated at lag 1
    x = fv[:, n // 2:, 0]
    assert np.mean(x[:, 1:] * x[:, :-1]) / np.mean(x * x) > 0.3


# ----------------------------------------------------------------------------- validation
@pytest.mark.parametrize("field,value", [
    ("gyro_arw", -1e-4), ("accel_vrw", float("nan")), ("gyro_bias_turn_on_sigma", float("inf")),
    ("accel_bias_instability", -1.0), ("gyro_bias_tau_s", 0.0), ("accel_bias_tau_s", float("inf")),
    ("gyro_scale_sigma", -1e-6), ("accel_misalignment_sigma", "x"),
    ("gyro_bias_fixed", (1.0, 2.0)), ("accel_bias_fixed", (0.0, float("nan"), 0.0)),
])
def test_grade_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        IDEAL.replace(**{field: value})


@pytest.mark.parametrize("field,value", [
    ("engine_freq_hz_range", (30.0, 20.0)), ("idle_accel_rms_range", (-0.1, 0.2)),
    ("idle_gyro_rms_range", (0.0, float("nan"))), ("harmonic_ratio", -0.5), ("road_damping", 1.0),
    ("road_ref_speed_mps", 0.0), ("axis_weights", (1.0, 1.0)), ("stationary_speed_mps", -1.0),
])
def test_vibration_validation_names_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        Vibration(**{field: value})


def test_simulate_imu_bad_inputs_name_the_argument():
    f, w = static_truth(2, 10)
    r = rngs(range(2))
    cases = [
        (dict(f_true=f[..., :2]), "f_true"),
        (dict(f_true=f[0]), "f_true"),
        (dict(f_true=f[:, :0], w_true=w[:, :0]), "f_true"),
        (dict(w_true=w[:, :5]), "w_true"),
        (dict(rngs=r[:1]), "rngs"),
        (dict(engine_on=np.ones((2, 9), bool), speed=np.zeros((2, 10)), vibration=Vibration()), "engine_on"),
        (dict(speed=np.zeros((2, 11))), "speed"),
        (dict(vibration=Vibration()), "speed"),
        (dict(imu_rate_hz=0.0), "imu_rate_hz"),
        (dict(dtype=np.int32), "dtype"),
        (dict(grade="gold"), "known grades"),
        (dict(workers=0), "workers"),
        (dict(speed=np.zeros((2, 10)), vibration=Vibration(), vibration_rngs=r[:1]), "vibration_rngs"),
    ]
    for kw, match in cases:
        args = dict(f_true=f, w_true=w, imu_rate_hz=RATE, grade="consumer", rngs=r)
        args.update(kw)
        with pytest.raises(ValueError, match=match):
            simulate_imu(**args)
    bad = f.copy()
    bad[0, 3, 1] = np.nan
    with pytest.raises(ValueError, match="f_true"):
        simulate_imu(bad, w, RATE, "consumer", r)
    # one non-finite element anywhere, in a float64 or float32, C-ordered or strided array, on 1 or 2 threads
    # (the compiled row check), is refused; integer truth is finite
    big_f, big_w = static_truth(40, 50)
    big_r = rngs(range(40))
    for value, (i, k, j) in ((np.inf, (39, 49, 2)), (-np.inf, (0, 0, 0)), (np.nan, (21, 17, 1))):
        for dtype, order in ((np.float64, "C"), (np.float32, "C"), (np.float64, "F")):
            for workers in (1, 2):
                bad_w = np.array(big_w, dtype=dtype, order=order)
                bad_w[i, k, j] = value
                with pytest.raises(ValueError, match="w_true must be finite"):
                    simulate_imu(big_f, bad_w, RATE, "consumer", big_r, workers=workers)
    ints = simulate_imu(np.zeros((2, 10, 3), np.int64), np.zeros((2, 10, 3), np.int32), RATE, "ideal", r)
    assert np.array_equal(ints.f_b, np.zeros((2, 10, 3)))


def _vibration_reference(gen, dt, engine_on, speed, vib):
    """The vibration of one run by numpy and scipy, as :func:`envs.sim.imu._vibration_row` computed it before its
    per-sample work was compiled: the specification it must equal bit for bit."""
    from scipy.signal import lfilter

    from envs.sim.imu import _ar2_coefficients
    n = speed.shape[0]
    f_e = gen.uniform(*vib.engine_freq_hz_range)
    a_rms, g_rms = gen.uniform(*vib.idle_accel_rms_range), gen.uniform(*vib.idle_gyro_rms_range)
    phases = gen.uniform(0.0, 2.0 * math.pi, size=(2, 6))
    road_a, road_g = gen.uniform(*vib.road_accel_rms_ref_range), gen.uniform(*vib.road_gyro_rms_ref_range)
    moving = np.abs(speed) > vib.stationary_speed_mps
    eng = np.ones(n, dtype=bool) if engine_on is None else engine_on
    idle, road = eng & ~moving, eng & moving
    if not idle.any() and not road.any():
        return None
    weights = np.asarray(vib.axis_weights)
    out = np.zeros((n, 6))
    if idle.any():
        rms = np.concatenate([a_rms * weights, g_rms * weights])
        h = vib.harmonic_ratio
        amp1 = math.sqrt(2.0) * rms / math.sqrt(1.0 + h * h)
        idx = np.flatnonzero(idle)
        t_mid = (idx + 0.5) * dt
        basis, coef = [], []
        for j, (mult, amp) in enumerate(((1.0, amp1), (2.0, h * amp1))):
            w = 2.0 * math.pi * f_e * mult
            atten = float(np.sinc(w * dt / (2.0 * math.pi)))
            basis += [np.sin(w * t_mid), np.cos(w * t_mid)]
            coef += [amp * atten * np.cos(phases[j]), amp * atten * np.sin(phases[j])]
        acc = np.zeros((idx.size, 6))
        for bj, cj in zip(basis, coef):
            acc += bj[:, None] * cj[None, :]
        out[idx] = acc
    if road.any() and (road_a > 0.0 or road_g > 0.0):
        ridx = np.flatnonzero(road)
        a1, a2, gamma0 = _ar2_coefficients(vib.road_center_hz, vib.road_damping, dt)
        z = gen.standard_normal((2, 6))
        e = gen.standard_normal((ridx.size, 6))
        rho1 = a1 / (1.0 - a2)
        y2 = rho1 * z[0] + math.sqrt(max(1.0 - rho1 * rho1, 0.0)) * z[1]
        zi = np.stack([a1 * z[0] + a2 * y2, a2 * z[0]]) * math.sqrt(gamma0)
        y, _ = lfilter([1.0], [1.0, -a1, -a2], e, axis=0, zi=zi)
        level = np.abs(speed[ridx]) * (1.0 / vib.road_ref_speed_mps)
        if vib.road_speed_exponent != 1.0:
            level **= vib.road_speed_exponent
        y *= level[:, None]
        y = np.diff(y, axis=0, prepend=0.0)
        unit = 1.0 / math.sqrt(2.0 * gamma0 * (1.0 - rho1))
        y *= np.concatenate([road_a * weights, road_g * weights]) * unit
        out[ridx] = y
    return out


@pytest.mark.parametrize("bit_generator", [np.random.SFC64, np.random.PCG64, np.random.MT19937])
@pytest.mark.parametrize("exponent", [1.0, 2.0, 0.5, 1.37, 0.0])
def test_vibration_row_is_its_numpy_specification_to_the_bit(bit_generator, exponent):
    """The compiled vibration (regimes, idle tones, the road resonance with its innovations drawn inline) equals
    the numpy / scipy chain, bit for bit, and leaves the stream where the chain does: with and without an engine
    flag, on the compiled bit generators and on one drawn by numpy.

    An exponent other than 0, 1/2, 1 or 2 takes the speed level's power from ``pow``: the C library's in the
    kernel, numpy's own vectorized one in the chain on a CPU with AVX-512 (they may differ in the last bit), so
    there the samples agree to rounding (the stream still exactly)."""
    exact = exponent in (0.0, 0.5, 1.0, 2.0)
    from envs.sim.imu import Vibration, _vibration_row
    rng = np.random.default_rng(int(exponent * 100))
    dt = 0.01
    for trial in range(6):
        n = int(rng.integers(50, 3000))
        speed = np.where(rng.uniform(size=n) < 0.3, 0.0, rng.uniform(-30, 30, n))
        speed[: n // 7] = 0.0                                   # a stop
        engine = None if trial % 2 else rng.uniform(size=n) < 0.8
        vib = Vibration(road_speed_exponent=exponent, harmonic_ratio=0.3 * trial)
        ref_gen, gen = bit_generator(trial), bit_generator(trial)
        ref_gen, gen = np.random.Generator(ref_gen), np.random.Generator(gen)
        ref = _vibration_reference(ref_gen, dt, engine, speed, vib)
        got = _vibration_row(gen, dt, engine, speed, vib)
        if exact:
            assert np.array_equal(got.view(np.uint64), ref.view(np.uint64))
        else:
            np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12 * np.abs(ref).max())
        assert ref_gen.random() == gen.random()
    off = np.zeros(40, dtype=bool)
    assert _vibration_row(np.random.default_rng(0), dt, off, np.ones(40), Vibration()) is None


def test_apply_matrix_sums_in_order():
    from envs.sim.imu_kernels import apply_matrix as _apply_matrix
    rng = np.random.default_rng(6)
    a, x = rng.normal(size=(3, 3)), rng.normal(size=(50, 3))
    out = np.empty((50, 3))
    _apply_matrix(a, x, out)
    ref = np.stack([x[:, 0] * a[j, 0] + x[:, 1] * a[j, 1] + x[:, 2] * a[j, 2] for j in range(3)], axis=1)
    np.testing.assert_array_equal(out, ref)


