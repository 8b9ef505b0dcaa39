"""The compiled kernels of the IMU stage (:mod:`envs.sim.imu`): vibration samples, one sensor's output, and all
of a range of rows in one call.

:func:`envs.sim.imu.simulate_imu` draws each row's small random numbers (per-run constants, vibration
parameters, events) in Python, then hands the per-sample work of a range of rows to :func:`imu_rows`, which
releases the GIL: the ranges run on threads without waiting on each other for the interpreter. Each kernel
evaluates the operations of the numpy specification it replaced in that specification's order, so the samples
are the same bits (tests/envs/test_imu.py, tests/envs/test_world_stages.py, tests/envs/test_imu_rows.py).
"""
from __future__ import annotations

import numba as nb
import numpy as np

from .normals import fill_stream, normal_step

NONE_SAMPLE, IDLE, ROAD = 0, 1, 2
"""Vibration regime codes of a sample (:func:`regimes`): engine off, engine idle, road."""


@nb.njit(cache=True, nogil=True)
def regimes(speed, eng, has_eng, stationary, kinds):
    """The vibration regime of each sample into ``kinds`` (n,) int8 (:data:`IDLE` where the engine runs and
    ``|speed| <= stationary``, :data:`ROAD` where it runs faster, :data:`NONE_SAMPLE` where it is off; ``eng``
    (n,) bool read when ``has_eng``, else the engine runs throughout). Returns ``(n_idle, n_road)``."""
    n_idle = n_road = 0
    for k in range(speed.shape[0]):
        if has_eng and not eng[k]:
            kinds[k] = NONE_SAMPLE
        elif abs(speed[k]) > stationary:
            kinds[k] = ROAD
            n_road += 1
        else:
            kinds[k] = IDLE
            n_idle += 1
    return n_idle, n_road


@nb.njit(cache=True, nogil=True)
def finite_rows(a, r0, r1, ok):
    """``ok[i]`` = whether every element of row ``i`` of ``a`` (B, m) is finite, for rows ``r0 .. r1-1``: ``x - x``
    is 0 for a finite ``x`` and NaN for an infinite or NaN one (a branch-free pass over the row)."""
    for i in range(r0, r1):
        bad = False
        for k in range(a.shape[1]):
            x = a[i, k]
            bad |= (x - x) != 0.0
        ok[i] = not bad


@nb.njit(cache=True, nogil=True)
def regimes_rows(speed, eng, has_eng, stationary, kinds, counts):
    """:func:`regimes` of each row ``i``: ``speed[i]`` (n,), ``eng[i]`` (read when ``has_eng``; ``eng`` may then
    be (1, 0) otherwise) into ``kinds[i]`` (n,) int8, its ``(n_idle, n_road)`` into ``counts[i]`` (B, 2)."""
    for i in range(speed.shape[0]):
        counts[i, 0], counts[i, 1] = regimes(speed[i], eng[i if has_eng else 0], has_eng, stationary, kinds[i])


@nb.njit(cache=True, nogil=True)
def idle_samples(kinds, dt, w1, w2, coef, out):
    """The idle samples of ``out`` (n, 6): at the interval midpoint ``t = (k + 1/2) dt`` the interval means of the
    fundamental ``w1`` and the harmonic ``w2`` [rad/s], ``sum_i basis_i coef_i`` over the basis ``(sin w1 t,
    cos w1 t, sin w2 t, cos w2 t)`` and the rows of ``coef`` (4, 6) (amplitude x sinc attenuation x the phase's
    cosine or sine, ``envs.sim.imu.sinusoid_interval_mean``), summed in that order from 0."""
    for k in range(kinds.shape[0]):
        if kinds[k] != IDLE:
            continue
        t = (k + 0.5) * dt
        th1 = w1 * t
        th2 = w2 * t
        b0, b1, b2, b3 = np.sin(th1), np.cos(th1), np.sin(th2), np.cos(th2)
        for c in range(6):
            acc = 0.0
            acc += b0 * coef[0, c]
            acc += b1 * coef[1, c]
            acc += b2 * coef[2, c]
            acc += b3 * coef[3, c]
            out[k, c] = acc


@nb.njit(cache=True, nogil=True)
def road_samples(kinds, speed, inv_ref, exponent, a, zi, scale, kind, state, e, out):
    """The road samples of ``out`` (n, 6): ``(L_k y_k - L_(k-1) y_(k-1)) scale`` over the road samples in order,
    ``L_(-1) y_(-1) = 0``, with the speed level ``L = (|speed| inv_ref) ** exponent`` and ``y`` the AR(2)
    resonance ``1 / A(z)``, ``a = [1, -a1, -a2]``, driven by unit normal innovations from the delay state ``zi``
    (2, 6): ``scipy.signal.lfilter([1], a, e, axis=0, zi=zi)``'s direct form II transposed recursion, its
    operations in its order (the numerator padded to ``[1, 0, 0]``).

    The innovations (6 per road sample, C order) are drawn here from the stream ``(kind, state)``
    (:mod:`envs.sim.normals`; ``state`` advanced) when ``kind >= 0``, else read from ``e`` (m, 6).
    The level's power as numpy's ``**`` takes it: a square and a square root for 2 and 1/2."""
    s0, s1, s2, s3 = state[0], state[1], state[2], state[3]
    z0 = zi[0].copy()
    z1 = zi[1].copy()
    prev = np.zeros(6)
    m = 0
    for k in range(kinds.shape[0]):
        if kinds[k] != ROAD:
            continue
        lev = abs(speed[k]) * inv_ref
        if exponent == 2.0:
            lev = lev * lev
        elif exponent == 0.5:
            lev = np.sqrt(lev)
        elif exponent != 1.0:
            lev = lev ** exponent
        for j in range(6):
            if kind >= 0:
                xn, s0, s1, s2, s3 = normal_step(kind, s0, s1, s2, s3)
            else:
                xn = e[m, j]
            yn = z0[j] + 1.0 * xn
            z0[j] = z1[j] + xn * 0.0 - yn * a[1]
            z1[j] = xn * 0.0 - yn * a[2]
            yl = yn * lev
            out[k, j] = (yl - prev[j]) * scale[j]
            prev[j] = yl
        m += 1
    state[0], state[1], state[2], state[3] = s0, s1, s2, s3


@nb.njit(cache=True, nogil=True)
def sensor_kernel(truth, vib, rough, a, has_sm, const, add_const, gm_z, gm_scale, zi, phi, has_gm, step, has_step,
                  white_z, white_sigma, has_white, out, bias_out) -> None:
    """One sensor's output of one row, in one pass: ``out = (I + S + M) src + bias + white`` (n, 3).

    ``src`` is ``truth`` (n, 3) plus, when ``vib`` (n, 3) is not empty, the vibration times ``rough`` (n,) (ones
    off the rough-road segments: multiplying by 1 changes no bit). ``a = I + S + M`` applied when ``has_sm``
    (:func:`apply_matrix`'s sum order). The bias, written to ``bias_out`` (n, 3) when it varies in time (not at
    all when ``bias_out`` has no rows: not recorded):

    * with ``has_gm`` the first-order Gauss-Markov process (Groves 2013 sec. 4.4; Brown & Hwang, first-order
      Gauss-Markov process): ``b_k = phi b_(k-1) + u_k``, ``u = gm_scale gm_z`` (``gm_scale = sigma
      sqrt(1 - phi^2)``), from the state ``zi = phi b_0`` (``scipy.signal.lfilter``'s direct form II transposed
      recursion with ``a = [1, -phi]``, ``b = [1, 0]``, its operations in its order), plus ``const`` (3,), plus
      ``step`` (n, 3) when ``has_step``;
    * else ``step + const`` when ``has_step``; else ``const`` when ``add_const`` (not at all when it is zero).

    The white noise ``white_z white_sigma rough`` when ``has_white``. The operations of the numpy sequence
    this replaces (``o = A src; o += bias; o += noise``), in its order: the same bits.
    """
    n = truth.shape[0]
    has_vib = vib.shape[0] > 0
    # the three axes in scalar locals (registers) rather than small arrays, which the compiler must keep in
    # memory since ``out`` might alias them: the same operations, 1.5-2x faster (microbenchmark of one row)
    z0, z1, z2 = zi[0], zi[1], zi[2]
    nphi = -phi
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = (a[0, 0], a[0, 1], a[0, 2], a[1, 0], a[1, 1], a[1, 2], a[2, 0],
                                                   a[2, 1], a[2, 2])
    c0, c1, c2 = const[0], const[1], const[2]
    keep_bias = bias_out.shape[0] > 0
    for k in range(n):
        if has_vib:
            r = rough[k]
            s0, s1, s2 = vib[k, 0] * r + truth[k, 0], vib[k, 1] * r + truth[k, 1], vib[k, 2] * r + truth[k, 2]
        else:
            s0, s1, s2 = truth[k, 0], truth[k, 1], truth[k, 2]
        if has_sm:
            o0 = s0 * a00 + s1 * a01 + s2 * a02
            o1 = s0 * a10 + s1 * a11 + s2 * a12
            o2 = s0 * a20 + s1 * a21 + s2 * a22
        else:
            o0, o1, o2 = s0, s1, s2
        if has_gm or has_step:
            if has_gm:
                x0, x1, x2 = gm_z[k, 0] * gm_scale, gm_z[k, 1] * gm_scale, gm_z[k, 2] * gm_scale
                y0, y1, y2 = z0 + 1.0 * x0, z1 + 1.0 * x1, z2 + 1.0 * x2
                z0, z1, z2 = x0 * 0.0 - y0 * nphi, x1 * 0.0 - y1 * nphi, x2 * 0.0 - y2 * nphi
                b0, b1, b2 = y0 + c0, y1 + c1, y2 + c2
                if has_step:
                    b0, b1, b2 = b0 + step[k, 0], b1 + step[k, 1], b2 + step[k, 2]
            else:
                b0, b1, b2 = step[k, 0] + c0, step[k, 1] + c1, step[k, 2] + c2
            o0, o1, o2 = o0 + b0, o1 + b1, o2 + b2
            if keep_bias:
                bias_out[k, 0], bias_out[k, 1], bias_out[k, 2] = b0, b1, b2
        elif add_const:
            o0, o1, o2 = o0 + c0, o1 + c1, o2 + c2
        if has_white:
            r = rough[k]
            o0 += white_z[k, 0] * white_sigma * r
            o1 += white_z[k, 1] * white_sigma * r
            o2 += white_z[k, 2] * white_sigma * r
        out[k, 0], out[k, 1], out[k, 2] = o0, o1, o2


@nb.njit(cache=True, nogil=True)
def apply_matrix(a: np.ndarray, x: np.ndarray, out: np.ndarray) -> None:
    """``out = x @ a.T`` for x, out (n, 3) and a (3, 3), sample by sample: ``(x0 a_j0 + x1 a_j1) + x2 a_j2``.

    Compiled (releasing the GIL for the row threads) rather than ``np.matmul``, which would hand this tiny
    product to a threaded BLAS whose spinning worker threads steal the cores that the row-parallel
    simulation uses.
    """
    for k in range(x.shape[0]):
        x0, x1, x2 = x[k, 0], x[k, 1], x[k, 2]
        for j in range(3):
            out[k, j] = x0 * a[j, 0] + x1 * a[j, 1] + x2 * a[j, 2]


@nb.njit(cache=True, nogil=True)
def sensor_pass(truth, vib, rough, a, has_sm, const, add_const, gm_par, gm_kind, gm_state, has_gm, step, has_step,
                white_sigma, white_kind, white_state, has_white, gm_z, white_z, out, bias_out) -> None:
    """One sensor of one row with its draws: :func:`sensor_kernel` after its normal variates.

    With ``has_gm`` the Gauss-Markov variates, ``n + 1`` x 3 in C order from the stream ``(gm_kind, gm_state)``
    into ``gm_z`` (n + 1, 3): the first three start the process, ``zi = phi (z_0 sigma)``, the others drive it;
    ``gm_par = (sigma, phi, gm_scale)`` (:func:`sensor_kernel`). With ``has_white`` the white noise, n x 3 from
    ``(white_kind, white_state)`` into ``white_z`` (n, 3). The states are advanced. Other arguments as in
    :func:`sensor_kernel`.
    """
    zi = np.zeros(3)
    gz = gm_z[:0]
    if has_gm:
        fill_stream(gm_kind, gm_state, gm_z.reshape(-1))
        for j in range(3):
            zi[j] = gm_par[1] * (gm_z[0, j] * gm_par[0])
        gz = gm_z[1:]
    wz = white_z[:0]
    if has_white:
        fill_stream(white_kind, white_state, white_z.reshape(-1))
        wz = white_z
    sensor_kernel(truth, vib, rough, a, has_sm, const, add_const, gz, gm_par[2], zi, gm_par[1], has_gm, step,
                  has_step, wz, white_sigma, has_white, out, bias_out)


@nb.njit(cache=True, nogil=True)
def rough_fill(segments, dt, out) -> None:
    """The rough-road factor of each sample into ``out`` (n,): 1, raised to the largest ``factor`` of the
    segments ``(t0, t1, factor)`` (R, 3) that hold the sample's end time ``k dt`` in ``(t0, t1]``, in order (the
    numpy ``ones``, then ``f[sel] = maximum(f[sel], factor)`` per segment)."""
    for k in range(out.shape[0]):
        out[k] = 1.0
    for j in range(segments.shape[0]):
        t0, t1, fac = segments[j, 0], segments[j, 1], segments[j, 2]
        for k in range(out.shape[0]):
            t = k * dt
            if t > t0 and t <= t1:
                out[k] = max(out[k], fac)


@nb.njit(cache=True, nogil=True)
def steps_fill(steps, sensor, dt, out) -> None:
    """The bias steps of ``sensor`` (0 gyro, 1 accel) into ``out`` (n, 3), zeroed first: each step ``(t,
    sensor, axis, size)`` of ``steps`` (S, 4), in order, adds ``size`` to ``axis`` of the samples whose end time
    ``k dt`` is after ``t`` (the numpy ``out[t_end > t, axis] += size``)."""
    out[:] = 0.0
    for j in range(steps.shape[0]):
        if steps[j, 1] != sensor:
            continue
        ts, axis, size = steps[j, 0], int(steps[j, 2]), steps[j, 3]
        for k in range(out.shape[0]):
            if k * dt > ts:
                out[k, axis] += size


@nb.njit(cache=True, nogil=True)
def vibration_row(i, kinds, speed, dt, idle_on, w12, coef, road_on, road_par, zi, scale, road_kind, road_state,
                   e_off, e_flat, out) -> None:
    """Row ``i``'s vibration (n, 6) into ``out``, zeroed first: :func:`idle_samples` where ``idle_on[i]``,
    :func:`road_samples` where ``road_on[i]``, drawing from ``(road_kind[i], road_state[i])`` or, for kind -1,
    reading ``e_flat[e_off[i]:e_off[i+1]]``; ``road_par = (1, -a1, -a2, 1 / ref speed, exponent)``."""
    out[:] = 0.0
    if idle_on[i]:
        idle_samples(kinds[i], dt, w12[i, 0], w12[i, 1], coef[i], out)
    if road_on[i]:
        road_samples(kinds[i], speed[i], road_par[3], road_par[4], road_par[:3], zi[i], scale[i], road_kind[i],
                     road_state[i], e_flat[e_off[i]:e_off[i + 1]], out)


@nb.njit(cache=True, nogil=True)
def imu_rows(r0, r1, w_true, f_true, dt, flags, sm_a, const, add_const, gm_par, white_sigma, child_kind, gm_state,
             white_state, vib_on, idle_on, w12, coef, road_on, road_par, zi, scale, road_kind, road_state, e_off,
             e_flat, kinds, speed, rough_off, rough_seg, step_off, step_rec, w_out, f_out, w_bias, f_bias) -> None:
    """Rows ``r0 .. r1-1`` of the IMU stage: each row's vibration, events and both sensors, written into its rows
    of ``w_out``, ``f_out`` (B, n, 3) and of the biases ``w_bias``, ``f_bias`` (B, n, 3) where they vary in time.

    Per sensor ``k`` (0 gyro, vibration columns 3-5; 1 accel, columns 0-2): ``flags[k] = (has_sm, has_gm,
    has_step, has_white, has_bias)`` (``has_bias``: the bias is recorded in ``w_bias`` / ``f_bias``, else those
    are a (1, 0, 3) placeholder), ``sm_a[k]`` (B, 3, 3) ``I + S + M``, ``const[k]`` (B, 3) with
    ``add_const[k]`` (B,), ``gm_par[k] = (sigma, phi, scale)``, ``white_sigma[k]``, the rows' child stream
    states ``gm_state[k]``, ``white_state[k]`` (B, 4) of kind ``child_kind`` (advanced). Vibration per row:
    ``vib_on`` (B,) (none where False), then :func:`vibration_row`'s arrays, ``kinds`` (B, n) the regimes and
    ``speed`` (B, n).
    Events: the rough-road segments of row i are ``rough_seg[rough_off[i]:rough_off[i+1]]`` (R, 3), its bias steps
    ``step_rec[step_off[i]:step_off[i+1]]`` (S, 4) (:func:`rough_fill`, :func:`steps_fill`).
    """
    n = w_true.shape[1]
    # scratch for the terms these rows have (one sample where none has it: no large allocation for nothing)
    vib = np.empty((n if vib_on[r0:r1].any() else 1, 6))
    rough = np.empty(n)
    ones = False                                        # whether rough holds ones (a row without a segment)
    step = np.empty((2, n if flags[0, 2] or flags[1, 2] else 1, 3))
    gm_z = np.empty((n + 1 if flags[0, 1] or flags[1, 1] else 1, 3))
    white_z = np.empty((n if flags[0, 3] or flags[1, 3] else 1, 3))
    for i in range(r0, r1):
        if vib_on[i]:
            vibration_row(i, kinds, speed, dt, idle_on, w12, coef, road_on, road_par, zi, scale, road_kind,
                           road_state, e_off, e_flat, vib)
        if rough_off[i + 1] > rough_off[i]:
            rough_fill(rough_seg[rough_off[i]:rough_off[i + 1]], dt, rough)
            ones = False
        elif not ones:
            rough[:] = 1.0
            ones = True
        for k in range(2):
            if flags[k, 2]:
                steps_fill(step_rec[step_off[i]:step_off[i + 1]], k, dt, step[k])
            c = 3 * (1 - k)
            v = vib[:, c:c + 3] if vib_on[i] else vib[:0, c:c + 3]
            truth = w_true[i] if k == 0 else f_true[i]
            out = w_out[i] if k == 0 else f_out[i]
            bias = (w_bias if k == 0 else f_bias)[i if flags[k, 4] else 0]
            sensor_pass(truth, v, rough, sm_a[k, i], flags[k, 0], const[k, i], add_const[k, i], gm_par[k], child_kind,
                        gm_state[k, i], flags[k, 1], step[k], flags[k, 2], white_sigma[k], child_kind,
                        white_state[k, i], flags[k, 3], gm_z, white_z, out, bias)
