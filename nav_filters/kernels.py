"""Compiled (numba) inner loop of the navigator: one GNSS epoch of IMU samples for all rows; and the small
dense helpers (in-place Cholesky factor and solve, the non-zeros of an H row) shared by the navigator's
covariance check, the filter forms and the adaptive laws' residuals.

The per-IMU-sample work of a tightly coupled navigator (bias compensation,
strapdown mechanization, error-model transition) runs 100 times per GNSS epoch
and cannot be made fast with numpy calls (each costs ~1 us of overhead, and a
step needs dozens). :func:`nav_filters.propagation.propagate_epoch` does it in one compiled call,
parallel over the batch rows.

It implements *the same equations* as the numpy reference functions, which
stay the readable specification and are checked against this kernel in
``tests/nav_filters/test_kernels.py``:

* mechanization: :func:`nav_filters.ins.mechanize` (single-sample scheme);
* transition: ``Phi = I + F dt`` with ``F`` of
  :func:`nav_filters.error_model.system_matrix` (point-mass gravity gradient),
  and ``Q_d = G Q_c G^T dt`` (first order; Groves eq 3.46 truncated);
* gravity: :func:`earth.wgs84.gravity_ecef` (J2 + centrifugal).

Covariance accumulation over the samples of an epoch (the form's ``predict``
is then called once with the result):

``exact=True``
    ``Phi_acc <- Phi_i Phi_acc``, ``Q_acc <- Phi_i Q_acc Phi_i^T + Q_i``: the
    exact composition of the per-sample predictions, so ``predict(Phi_acc,
    Q_acc)`` equals predicting at every IMU sample (in exact arithmetic) for
    every filter form.
``exact=False``
    seed paper 001 (one-step prediction of P, multiplication method, eqs
    19-20): ``Phi_acc <- Phi_i Phi_acc`` and ``Q_acc <- Q_acc + Q_i`` (the
    process noise is not propagated through the transitions).
``integrate=True`` (with ``exact=False``; :mod:`nav_filters.imu_lanes`, rows in SIMD lanes)
    the averaged dynamics of :mod:`nav_filters.averaged_transition`:
    ``Phi_acc <- Phi_acc + sum_i F_i h`` (the integral of F, no product at all)
    and ``Q_acc <- Q_acc + sum_i Q_i``, from per-row sums of the parts that vary
    (``C``, ``C f``, the gravity gradient, ``c_m c_m^T``) written once per call;
    the transition and process noise are formed from the two integrals once
    per epoch.

Products with ``F`` use its fixed sparsity pattern (:data:`F_NONZERO`).
"""
from __future__ import annotations

from contextlib import contextmanager

import numpy as np
import numba as nb

from earth.wgs84 import A as _A, GM as _GM, J2 as _J2, OMEGA_IE as _W

N = 17


def serial_and_parallel(fn, **flags):
    """Two cached numba dispatchers of the row kernel ``fn``: ``(serial, parallel)``.

    Numba's on-disk cache names an entry by the function's module, qualified name and first line, and keys
    it by the signature and the bytecode, not by the compile flags: two dispatchers of *one* Python function
    (``njit(cache=True)(f)`` and ``njit(cache=True, parallel=True)(f)``) share one cache entry, and whichever
    variant a process compiled first is then loaded for both. Measured: the "serial" dispatchers ran the
    parallel code, a thread-pool launch per call, ~8 ms per call instead of ~20 us for one row on a loaded
    2-core machine (the single env's step). Each variant here is compiled from its own function object (same
    code and globals) with a distinct ``__qualname__``, hence its own cache entry; the arithmetic per row is
    the same in both.
    """
    import types

    out = []
    for suffix, parallel in (("serial", False), ("parallel", True)):
        f = types.FunctionType(fn.__code__, fn.__globals__, f"{fn.__name__}_{suffix}", fn.__defaults__,
                               fn.__closure__)
        f.__qualname__ = f"{fn.__qualname__}_{suffix}"
        f.__module__ = fn.__module__
        f.__doc__ = fn.__doc__
        out.append(nb.njit(cache=True, parallel=parallel, **flags)(f))
    return tuple(out)

# Structural non-zeros of F (row, col), in the order _fill_F writes them.
F_NONZERO = np.array(
    [(0, 1), (1, 0)] + [(i, 9 + j) for i in range(3) for j in range(3)]          # -Omega, -C (gyro bias)
    + [(3, 1), (3, 2), (4, 0), (4, 2), (5, 0), (5, 1), (3, 4), (4, 3)]            # -[a x], -2 Omega
    + [(3 + i, 6 + j) for i in range(3) for j in range(3)]                        # Gamma
    + [(3 + i, 12 + j) for i in range(3) for j in range(3)]                       # -C (accel bias)
    + [(6, 3), (7, 4), (8, 5)]                                                    # position <- velocity
    + [(i, i) for i in range(9, 15)] + [(15, 16)],                                # bias decay, clock
    dtype=np.int64)


@nb.njit(cache=True, inline="always")
def _gravity(x, y, z):
    """earth.wgs84.gravity_ecef for one position (J2 gravitation + centrifugal): ``(gx, gy, gz)``."""
    r2 = x * x + y * y + z * z
    ir2 = 1.0 / r2  # one division (a multiply is several times cheaper; the IMU kernel calls this every sample)
    zr2 = z * z * ir2
    k = (1.5 * _J2 * _A * _A) * ir2
    m = -_GM * ir2 / np.sqrt(r2)
    fxy = 1.0 + k * (1.0 - 5.0 * zr2)
    return m * x * fxy + _W * _W * x, m * y * fxy + _W * _W * y, m * z * (1.0 + k * (3.0 - 5.0 * zr2))


@nb.njit(cache=True, inline="always")
def _small_angle(th2):
    """``(sin t / t, (1 - cos t) / t^2, (1 - sin t / t) / t^2)`` of ``t^2 = th2 < 1e-4`` by their series (to
    t^4: below round-off there). Constant reciprocals: multiplies, not divisions."""
    t4 = th2 * th2
    ca = 1.0 - th2 * (1.0 / 6.0) + t4 * (1.0 / 120.0)
    cb = 0.5 - th2 * (1.0 / 24.0) + t4 * (1.0 / 720.0)
    cc = 1.0 / 6.0 - th2 * (1.0 / 120.0) + t4 * (1.0 / 5040.0)
    return ca, cb, cc


@nb.njit(cache=True, inline="always")
def _large_angle(th2):
    """The coefficients of :func:`_small_angle` from ``sin`` and ``cos`` (``th2 >= 1e-4``)."""
    th = np.sqrt(th2)
    ca = np.sin(th) / th
    cb = (1.0 - np.cos(th)) / th2
    cc = (1.0 - ca) / th2
    return ca, cb, cc


@nb.njit(cache=True, inline="always")
def _tuple9(M):
    """The (3, 3) ``M`` as a row-major 9-tuple."""
    return (M[0, 0], M[0, 1], M[0, 2], M[1, 0], M[1, 1], M[1, 2], M[2, 0], M[2, 1], M[2, 2])


@nb.njit(cache=True, inline="always")
def _mechanize_sample(r0, r1, r2, v0, v1, v2, c00, c01, c02, c10, c11, c12, c20, c21, c22, f0, f1, f2, d0, d1, d2,
                      rot, h, Av, Au, Ag, Cz, orthonormalize):
    """One sample of :func:`nav_filters.ins.mechanize` (single-sample scheme) on scalars.

    Position ``r``, velocity ``v``, attitude ``C`` (row-major), the bias-compensated specific force ``f``
    [m/s^2], the rotation increment ``d = w h`` [rad] with ``rot = (th2, ca, cb, cc)``: ``th2 = |d|^2`` and its
    coefficients (:func:`_small_angle` or :func:`_large_angle`); ``Av``, ``Au``, ``Ag``, ``Cz`` the (3, 3)
    matrices of :func:`~nav_filters.propagation.propagate_epoch` as row-major 9-tuples (:func:`_tuple9`: constants in registers, no loads
    that a store might alias). Returns the new ``(r, v, C)`` as 15 scalars. Scalars in and out, no branch but the
    loop-invariant ``orthonormalize``, so a loop over rows of it vectorizes (:mod:`nav_filters.imu_lanes`). At
    most 30 arguments: CPython passes more as ``*args``, which numba's inlining does not take."""
    th2, ca, cb, cc = rot
    u0 = f0 * h
    u1 = f1 * h
    u2 = f2 * h
    tdv = d0 * u0 + d1 * u1 + d2 * u2
    e0 = (1.0 - cc * th2) * u0 + cb * (d1 * u2 - d2 * u1) + cc * tdv * d0
    e1 = (1.0 - cc * th2) * u1 + cb * (d2 * u0 - d0 * u2) + cc * tdv * d1
    e2 = (1.0 - cc * th2) * u2 + cb * (d0 * u1 - d1 * u0) + cc * tdv * d2
    uu0 = c00 * e0 + c01 * e1 + c02 * e2
    uu1 = c10 * e0 + c11 * e1 + c12 * e2
    uu2 = c20 * e0 + c21 * e1 + c22 * e2
    g0, g1, g2 = _gravity(r0 + 0.5 * h * v0, r1 + 0.5 * h * v1, r2 + 0.5 * h * v2)
    vn0 = (Av[0] * v0 + Av[1] * v1 + Av[2] * v2
           + Au[0] * uu0 + Au[1] * uu1 + Au[2] * uu2
           + Ag[0] * g0 + Ag[1] * g1 + Ag[2] * g2)
    vn1 = (Av[3] * v0 + Av[4] * v1 + Av[5] * v2
           + Au[3] * uu0 + Au[4] * uu1 + Au[5] * uu2
           + Ag[3] * g0 + Ag[4] * g1 + Ag[5] * g2)
    vn2 = (Av[6] * v0 + Av[7] * v1 + Av[8] * v2
           + Au[6] * uu0 + Au[7] * uu1 + Au[8] * uu2
           + Ag[6] * g0 + Ag[7] * g1 + Ag[8] * g2)
    r0 += 0.5 * h * (v0 + vn0)
    r1 += 0.5 * h * (v1 + vn1)
    r2 += 0.5 * h * (v2 + vn2)
    # attitude: C+ = Cz C exp([d x]) with exp = (1 - cb th2) I + ca [d x] + cb d d^T
    x00 = 1.0 - cb * th2 + cb * d0 * d0
    x11 = 1.0 - cb * th2 + cb * d1 * d1
    x22 = 1.0 - cb * th2 + cb * d2 * d2
    x01 = -ca * d2 + cb * d0 * d1
    x10 = ca * d2 + cb * d0 * d1
    x02 = ca * d1 + cb * d0 * d2
    x20 = -ca * d1 + cb * d0 * d2
    x12 = -ca * d0 + cb * d1 * d2
    x21 = ca * d0 + cb * d1 * d2
    e00 = c00 * x00 + c01 * x10 + c02 * x20
    e01 = c00 * x01 + c01 * x11 + c02 * x21
    e02 = c00 * x02 + c01 * x12 + c02 * x22
    e10 = c10 * x00 + c11 * x10 + c12 * x20
    e11 = c10 * x01 + c11 * x11 + c12 * x21
    e12 = c10 * x02 + c11 * x12 + c12 * x22
    e20 = c20 * x00 + c21 * x10 + c22 * x20
    e21 = c20 * x01 + c21 * x11 + c22 * x21
    e22 = c20 * x02 + c21 * x12 + c22 * x22
    c00 = Cz[0] * e00 + Cz[1] * e10 + Cz[2] * e20
    c01 = Cz[0] * e01 + Cz[1] * e11 + Cz[2] * e21
    c02 = Cz[0] * e02 + Cz[1] * e12 + Cz[2] * e22
    c10 = Cz[3] * e00 + Cz[4] * e10 + Cz[5] * e20
    c11 = Cz[3] * e01 + Cz[4] * e11 + Cz[5] * e21
    c12 = Cz[3] * e02 + Cz[4] * e12 + Cz[5] * e22
    c20 = Cz[6] * e00 + Cz[7] * e10 + Cz[8] * e20
    c21 = Cz[6] * e01 + Cz[7] * e11 + Cz[8] * e21
    c22 = Cz[6] * e02 + Cz[7] * e12 + Cz[8] * e22
    if orthonormalize:
        # C <- 1.5 C - 0.5 (C C^T) C
        k00 = c00 * c00 + c01 * c01 + c02 * c02
        k01 = c00 * c10 + c01 * c11 + c02 * c12
        k02 = c00 * c20 + c01 * c21 + c02 * c22
        k10 = c10 * c00 + c11 * c01 + c12 * c02
        k11 = c10 * c10 + c11 * c11 + c12 * c12
        k12 = c10 * c20 + c11 * c21 + c12 * c22
        k20 = c20 * c00 + c21 * c01 + c22 * c02
        k21 = c20 * c10 + c21 * c11 + c22 * c12
        k22 = c20 * c20 + c21 * c21 + c22 * c22
        o00 = 1.5 * c00 - 0.5 * (k00 * c00 + k01 * c10 + k02 * c20)
        o01 = 1.5 * c01 - 0.5 * (k00 * c01 + k01 * c11 + k02 * c21)
        o02 = 1.5 * c02 - 0.5 * (k00 * c02 + k01 * c12 + k02 * c22)
        o10 = 1.5 * c10 - 0.5 * (k10 * c00 + k11 * c10 + k12 * c20)
        o11 = 1.5 * c11 - 0.5 * (k10 * c01 + k11 * c11 + k12 * c21)
        o12 = 1.5 * c12 - 0.5 * (k10 * c02 + k11 * c12 + k12 * c22)
        o20 = 1.5 * c20 - 0.5 * (k20 * c00 + k21 * c10 + k22 * c20)
        o21 = 1.5 * c21 - 0.5 * (k20 * c01 + k21 * c11 + k22 * c21)
        o22 = 1.5 * c22 - 0.5 * (k20 * c02 + k21 * c12 + k22 * c22)
        c00, c01, c02, c10, c11, c12, c20, c21, c22 = o00, o01, o02, o10, o11, o12, o20, o21, o22
    return r0, r1, r2, vn0, vn1, vn2, c00, c01, c02, c10, c11, c12, c20, c21, c22


@nb.njit(cache=True)
def _fill_F(F, C, f, r, kg, ka):
    """Write system_matrix(C, f, r, tau_g, tau_a) for one row into the zeroed (17, 17) F."""
    F[0, 1] = _W
    F[1, 0] = -_W
    for i in range(3):
        for j in range(3):
            F[i, 9 + j] = -C[i, j]
            F[3 + i, 12 + j] = -C[i, j]
    a0 = C[0, 0] * f[0] + C[0, 1] * f[1] + C[0, 2] * f[2]
    a1 = C[1, 0] * f[0] + C[1, 1] * f[1] + C[1, 2] * f[2]
    a2 = C[2, 0] * f[0] + C[2, 1] * f[1] + C[2, 2] * f[2]
    F[3, 1] = a2
    F[3, 2] = -a1
    F[4, 0] = -a2
    F[4, 2] = a0
    F[5, 0] = a1
    F[5, 1] = -a0
    F[3, 4] = 2.0 * _W
    F[4, 3] = -2.0 * _W
    r2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2]
    k = _GM / (r2 * np.sqrt(r2))
    for i in range(3):
        for j in range(3):
            F[3 + i, 6 + j] = 3.0 * k * r[i] * r[j] / r2
    F[3, 6] -= k - _W * _W
    F[4, 7] -= k - _W * _W
    F[5, 8] -= k
    F[6, 3] = 1.0
    F[7, 4] = 1.0
    F[8, 5] = 1.0
    for i in range(9, 12):
        F[i, i] = kg
    for i in range(12, 15):
        F[i, i] = ka
    F[15, 16] = 1.0


@nb.njit(cache=True, inline="always")
def _sparse_left(F, X, T, nz):
    """T = F @ X using only the structural non-zeros nz of F."""
    T[:, :] = 0.0
    for p in range(nz.shape[0]):
        i = nz[p, 0]
        j = nz[p, 1]
        fij = F[i, j]
        for c in range(N):
            T[i, c] += fij * X[j, c]


def _propagate_epoch(r, v, C, bg, ba, clk, drift, f_raw, w_raw, h, Av, Au, Ag, Cz, qg, qa, qdiag, kg, ka,
                    Phi_acc, Q_acc, exact, orthonormalize, nz, start=False, nchunk=1):
    """Advance every row by the n IMU samples of ``f_raw[:, :n]``, accumulating the transition (the composing
    modes; the averaged one is :mod:`nav_filters.imu_lanes`).

    Parameters
    ----------
    r : (B, 3) float64 ECEF position [m] (in/out); v : (B, 3) velocity [m/s] (in/out);
    C : (B, 3, 3) attitude C_eb (in/out); bg, ba : (B, 3) bias estimates (in);
    clk : (B,) float64 clock bias [m] (in/out); drift : (B,) clock drift [m/s] (in);
    f_raw, w_raw : (B, n, 3) raw IMU interval means [m/s^2], [rad/s];
    h : sample interval [s]; Av, Au, Ag, Cz : (3, 3) Earth-rate matrices of ins.mechanize for h
        (left-multiplying: v+ = Av v + Au u + Ag g dt-scaled as in ins.mechanize);
    qg, qa : (3,) gyro / accelerometer white-noise PSDs per body axis; qdiag : (17,) PSDs of the other states;
    kg, ka : -1/tau of the bias Gauss-Markov processes (0 for random walk);
    Phi_acc, Q_acc : (B, 17, 17) accumulators (in/out); exact : bool (see module docstring);
    orthonormalize : bool, re-orthonormalize C every sample (float32); nz : F_NONZERO.
    start : bool, these are the first samples since the accumulators were handed over: each row's are set
        first (``I`` and 0) instead of read, so no caller pass clears them.
    nchunk : the rows run in this many chunks (parallel in the parallel variant), each allocating its scratch once.
    """
    B = f_raw.shape[0]
    n = f_raw.shape[1]
    for ch in nb.prange(nchunk):
        F = np.zeros((N, N))
        T = np.zeros((N, N))
        T2 = np.zeros((N, N))
        fc = np.empty(3)
        wc = np.empty(3)
        rr = np.empty(3)
        Cb = np.empty((3, 3))
        FQFt = np.zeros((N, N))
        vb = np.empty(3)
        Avt = _tuple9(Av)
        Aut = _tuple9(Au)
        Agt = _tuple9(Ag)
        Czt = _tuple9(Cz)
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            if start:
                for i in range(N):
                    for j in range(N):
                        Phi_acc[b, i, j] = 0.0
                        Q_acc[b, i, j] = 0.0
                    Phi_acc[b, i, i] = 1.0
            for i in range(3):
                rr[i] = r[b, i]
                vb[i] = v[b, i]
                for j in range(3):
                    Cb[i, j] = C[b, i, j]
            for k in range(n):
                for i in range(3):
                    fc[i] = f_raw[b, k, i] - ba[b, i]
                    wc[i] = w_raw[b, k, i] - bg[b, i]
                # ---- covariance: Phi = I + F h at the state of the interval start ----
                F[:, :] = 0.0
                _fill_F(F, Cb, fc, rr, kg, ka)
                _sparse_left(F, Phi_acc[b], T, nz)
                if exact:
                    _sparse_left(F, Q_acc[b], T2, nz)          # T2 = F Q
                    # Q <- Q + h (F Q + Q F^T) + h^2 F Q F^T   (= Phi Q Phi^T)
                    for i in range(N):
                        for c in range(N):
                            Q_acc[b, i, c] += h * (T2[i, c] + T2[c, i])
                    # F (F Q)^T = F Q F^T, using T2^T as the right factor (written out: _sparse_left on the
                    # transposed view T2.T gives the same bits but runs ~1.8x slower, a non-contiguous layout)
                    FQFt[:, :] = 0.0
                    for p in range(nz.shape[0]):
                        i = nz[p, 0]
                        j = nz[p, 1]
                        fij = F[i, j]
                        for c in range(N):
                            FQFt[i, c] += fij * T2[c, j]
                    for i in range(N):
                        for c in range(N):
                            Q_acc[b, i, c] += h * h * FQFt[i, c]
                for i in range(N):
                    for c in range(N):
                        Phi_acc[b, i, c] += h * T[i, c]
                # process noise of this sample: C diag(qg) C^T, C diag(qa) C^T, diag(qdiag)
                for i in range(3):
                    for j in range(3):
                        sg = 0.0
                        sq = 0.0
                        for m in range(3):
                            sg += Cb[i, m] * qg[m] * Cb[j, m]
                            sq += Cb[i, m] * qa[m] * Cb[j, m]
                        Q_acc[b, i, j] += sg * h
                        Q_acc[b, 3 + i, 3 + j] += sq * h
                for i in range(6, N):
                    Q_acc[b, i, i] += qdiag[i] * h
                # ---- mechanization (ins.mechanize, single-sample scheme) ----
                d0 = wc[0] * h
                d1 = wc[1] * h
                d2 = wc[2] * h
                th2 = d0 * d0 + d1 * d1 + d2 * d2
                if th2 < 1e-4:
                    ca, cb, cc = _small_angle(th2)
                else:
                    ca, cb, cc = _large_angle(th2)
                out = _mechanize_sample(rr[0], rr[1], rr[2], vb[0], vb[1], vb[2], Cb[0, 0], Cb[0, 1], Cb[0, 2],
                                        Cb[1, 0], Cb[1, 1], Cb[1, 2], Cb[2, 0], Cb[2, 1], Cb[2, 2], fc[0], fc[1], fc[2],
                                        d0, d1, d2, (th2, ca, cb, cc), h, Avt, Aut, Agt, Czt, orthonormalize)
                for i in range(3):
                    rr[i] = out[i]
                    vb[i] = out[3 + i]
                    for j in range(3):
                        Cb[i, j] = out[6 + 3 * i + j]
                clk[b] += drift[b] * h
            for i in range(3):
                r[b, i] = rr[i]
                v[b, i] = vb[i]
                for j in range(3):
                    C[b, i, j] = Cb[i, j]


_serial, _parallel = serial_and_parallel(_propagate_epoch)

PARALLEL_MIN_BATCH = 64
"""Below this batch size every row kernel of the package runs its serial variant (this module's, the forms'
and the adaptive laws'): a parallel launch costs more than it saves, and on 2 cores its worker threads compete
with BLAS threads still spinning after the caller's last matmul. The parallel variants need free cores: on a
busy machine the serial ones are faster (:func:`serial_rows` forces them; the native vector env picks between the
two by measuring both, :class:`~nav_filters.parallel_governor.ParallelGovernor`; docs/usage.md, Benchmarks)."""


_serial_only = False
"""Whether every row kernel runs its serial variant whatever the batch size (:func:`serial_rows`). Plain
process-wide Python state, read by :func:`row_chunks` at each launch (the kernels are launched from Python)."""


@contextmanager
def serial_rows(enabled: bool = True):
    """Context manager: inside it every row kernel of the package runs its serial variant in one chunk
    (:func:`row_chunks` returns 1), at any batch size; the previous setting comes back on exit, also when the
    body raises. ``enabled=False`` leaves the setting as it is (``with serial_rows(mode == "serial")``).

    A row's arithmetic does not depend on the chunking, so the results are the same bits either way; what
    changes is the wall time: the parallel variants wait for their slowest thread, which on a core that another
    process keeps busy is several times slower (:class:`~nav_filters.parallel_governor.ParallelGovernor` picks
    between the two by measuring them). The setting is process-wide, not per thread.

    Parameters
    ----------
    enabled : bool
        Force the serial variants (True) or change nothing (False).
    """
    global _serial_only
    previous = _serial_only
    _serial_only = previous or bool(enabled)
    try:
        yield
    finally:
        _serial_only = previous


def rows_forced_serial() -> bool:
    """Whether :func:`serial_rows` is in force (every row kernel serial)."""
    return _serial_only


def row_chunks(B: int) -> int:
    """The number of row chunks a row kernel over ``B`` rows runs in: 1 (its serial variant) below
    :data:`PARALLEL_MIN_BATCH` rows or inside :func:`serial_rows`, else ``4 x threads`` chunks of its parallel
    variant (each chunk allocates its scratch once; a row's arithmetic does not depend on the chunking)."""
    return min(B, 4 * nb.get_num_threads()) if B >= PARALLEL_MIN_BATCH and not _serial_only else 1


def row_kernel(serial, parallel, B: int):
    """``(kernel, nchunk)`` for a row kernel of :func:`serial_and_parallel` over ``B`` rows (:func:`row_chunks`):
    the serial variant in one chunk, or the parallel one."""
    nchunk = row_chunks(B)
    return (parallel if nchunk > 1 else serial), nchunk


@nb.njit(cache=True, inline="always")
def padded_width(n):
    """The column count, a multiple of 4 (20 for n = 17), of a kernel's scratch rows padded with zeros: LLVM
    vectorizes a row loop of a run-time length but leaves a scalar remainder of up to 15 elements, which for 17
    columns is most of the loop; over the padded width there is none. The padding stays zero, so every kept entry
    is the same sum in the same order (used by the fused kf update, the averaged series, the per-satellite R law)."""
    return (n + 3) // 4 * 4


# ----------------------------------------------------------------------------- small dense helpers
@nb.njit(cache=True)
def _pairwise_block(a, lo, n):
    """numpy's pairwise summation of ``a[lo:lo + n]`` for n <= 128 (:func:`pairwise_sum`)."""
    if n < 8:
        res = 0.0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = lo + 8
    stop = lo + n - n % 8
    while i < stop:
        r0 += a[i]
        r1 += a[i + 1]
        r2 += a[i + 2]
        r3 += a[i + 3]
        r4 += a[i + 4]
        r5 += a[i + 5]
        r6 += a[i + 6]
        r7 += a[i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < lo + n:
        res += a[i]
        i += 1
    return res


@nb.njit(cache=True)
def pairwise_sum(a, lo, n):
    """``a[lo:lo + n].sum()`` of a float64 vector in numpy's order, so the same bits as numpy's ``sum`` along
    a contiguous axis (e.g. ``x.sum(1)`` of a C-contiguous (B, m) array).

    numpy's pairwise summation: fewer than 8 numbers are added one at a time from 0; up to 128 in 8
    interleaved partial sums, combined as ``((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))``, then the rest
    one at a time; more as the sum of two halves, the first a multiple of 8 long. The halving is done with an
    explicit stack (numba's cache cannot load a self-recursive function). Checked against ``numpy.sum`` for 1
    to 600 numbers in ``tests/nav_filters/test_strong_tracking_rows.py``.
    """
    if n <= 128:
        return _pairwise_block(a, lo, n)
    depth = 64  # each level halves n: far more than any length needs
    s_lo = np.empty(depth, np.int64)
    s_n = np.empty(depth, np.int64)
    stage = np.empty(depth, np.int64)  # 0: left half next, 1: right half next, 2: both done
    left = np.empty(depth)
    right = np.empty(depth)
    s_lo[0], s_n[0], stage[0] = lo, n, 0
    sp = 1
    out = 0.0
    while sp > 0:
        top = sp - 1
        k = s_n[top]
        if k <= 128 or stage[top] == 2:
            val = _pairwise_block(a, s_lo[top], k) if k <= 128 else left[top] + right[top]
            sp -= 1
            if sp == 0:
                out = val
            elif stage[sp - 1] == 1:
                left[sp - 1] = val
            else:
                right[sp - 1] = val
            continue
        n2 = k // 2
        n2 -= n2 % 8
        if stage[top] == 0:
            stage[top] = 1
            s_lo[sp], s_n[sp] = s_lo[top], n2
        else:
            stage[top] = 2
            s_lo[sp], s_n[sp] = s_lo[top] + n2, k - n2
        stage[sp] = 0
        sp += 1
    return out


def scale_symmetric(R, s, keep=None):
    """``D R D`` with ``D = diag(s)`` per row, compiled (:func:`scale_symmetric_reference` is the numpy
    specification; same products in the same order, so the same bits, float32 and float64).

    Parameters
    ----------
    R : (B, m, m) covariance (a measurement noise R); s : (B, m) scales (the square roots of variance
        factors); keep : optional (B, m) bool: where False the row's diagonal entry is set to 1 (the
        documented neutral value of a masked measurement row).

    Returns
    -------
    (B, m, m) new array of dtype ``result_type(R, s)``, parallel over rows for B >= 64 (:func:`row_chunks`).
    """
    R = np.ascontiguousarray(R)
    s = np.ascontiguousarray(s)
    B, m = s.shape
    out = np.empty(R.shape, np.result_type(R.dtype, s.dtype))
    k = np.ones((B, m), np.bool_) if keep is None else np.ascontiguousarray(keep, np.bool_)
    kern = _scale_parallel if row_chunks(B) > 1 else _scale_serial  # (serial inside serial_rows too)
    kern(R, s, k, out)
    return out


def scale_symmetric_reference(R, s, keep=None):
    """Numpy specification of :func:`scale_symmetric`: ``R * s[:, :, None] * s[:, None, :]``, then 1 on the
    diagonal entries of the rows where ``keep`` is False."""
    out = R * s[:, :, None] * s[:, None, :]
    return out if keep is None else unit_diagonal(out, keep)


def unit_diagonal(R, keep):
    """``R[b, i, i] = 1`` where ``keep[b, i]`` is False, in place (the documented neutral variance of a masked
    measurement row; its other entries are left as they are); returns ``R`` (B, m, m)."""
    idx = np.arange(R.shape[1])
    R[:, idx, idx] = np.where(keep, R[:, idx, idx], 1)
    return R


@nb.njit(cache=True)
def scale_symmetric_row(R, s, keep, out):
    """One row of :func:`scale_symmetric`: ``out = D R D`` (m, m), ``D = diag(s)``, 1 on the diagonal entries
    of the rows where ``keep`` (m,) is False (also called by kernels that form their scales per row)."""
    m = s.shape[0]
    for i in range(m):
        si = s[i]
        for j in range(m):
            out[i, j] = R[i, j] * si * s[j]
        if not keep[i]:
            out[i, i] = 1


def _scale_rows(R, s, keep, out):
    for b in nb.prange(s.shape[0]):
        scale_symmetric_row(R[b], s[b], keep[b], out[b])


_scale_serial, _scale_parallel = serial_and_parallel(_scale_rows)


@nb.njit(cache=True)
def cholesky_inplace(A, rel_tol):
    """``A = L L^T`` in place (lower triangle of the square A); False when a pivot is not above
    ``rel_tol`` times the diagonal entry (0: not positive)."""
    p = A.shape[0]
    for k in range(p):
        dkk = A[k, k]
        for q in range(k):
            dkk -= A[k, q] * A[k, q]
        if not dkk > rel_tol * max(A[k, k], 1e-300):
            return False
        A[k, k] = np.sqrt(dkk)
        for i in range(k + 1, p):
            s = A[i, k]
            for q in range(k):
                s -= A[i, q] * A[k, q]
            A[i, k] = s / A[k, k]
    return True


@nb.njit(cache=True)
def cholesky_solve(L, x):
    """Solve ``L L^T y = x`` in place (``L`` from :func:`cholesky_inplace`)."""
    p = L.shape[0]
    for i in range(p):
        s = x[i]
        for q in range(i):
            s -= L[i, q] * x[q]
        x[i] = s / L[i, i]
    for i in range(p - 1, -1, -1):
        s = x[i]
        for q in range(i + 1, p):
            s -= L[q, i] * x[q]
        x[i] = s / L[i, i]


@nb.njit(cache=True, error_model="numpy")
def row_nonzeros(h_row, nzc_row, nzv_row):
    """Column indices (increasing) and values of the non-zeros of one row of H (n,) into ``nzc_row`` /
    ``nzv_row``; their count.

    A GNSS row of the 17-state H has 4 non-zeros: products with H over these lists, in this (increasing column)
    order, add the same terms in the same order as a loop over all n columns that skips the zeros, so they
    give the same bits. ``nzc_row`` / ``nzv_row`` need n slots: every column is written at the running count
    and the count advances past the non-zeros (no branch to mispredict; the slots past the count hold
    leftovers)."""
    c = 0
    for l in range(h_row.shape[0]):
        h = h_row[l]
        nzc_row[c] = l
        nzv_row[c] = h
        c += h != 0
    return c


@nb.njit(cache=True, error_model="numpy", inline="always")
def _tridiagonalize(A, d, Vt, e, v, wk):
    """Phase 1 of :func:`sym_eig_inplace`: the Householder reduction ``T = H A H`` (Golub & Van Loan alg. 8.3.1) of
    the symmetric ``A`` (n, W) (destroyed) into its diagonal ``d`` (n,) and off-diagonal ``e`` (``e[i]`` couples
    ``d[i]`` and ``d[i + 1]``; ``e[n - 1] = 0``), the reflections accumulated into ``Vt`` (n, W), set to I first
    (``A = Vt^T T Vt``); ``v``, ``wk`` (W,) scratch."""
    n = A.shape[0]
    W = A.shape[1]
    for i in range(n):
        for j in range(W):
            Vt[i, j] = 0.0
        Vt[i, i] = 1.0
        e[i] = 0.0
    for j in range(W):
        v[j] = 0.0
    # ---- Householder tridiagonalization: A <- H A H on the trailing block, Vt <- H Vt; v is zero outside the
    # block's rows k+1..n-1 (so are the padding entries of every product below)
    for k in range(n - 2):
        v[k] = 0.0
        a2 = 0.0
        for i in range(k + 2, n):
            a2 += A[k, i] * A[k, i]
        x0 = A[k, k + 1]
        if a2 == 0.0:  # column already reduced
            e[k] = x0
            continue
        a2 += x0 * x0
        alpha = -np.sqrt(a2) if x0 >= 0 else np.sqrt(a2)
        vn = np.sqrt(2.0 * (a2 - x0 * alpha))
        for i in range(k + 1, n):
            v[i] = A[k, i] / vn
        v[k + 1] = (x0 - alpha) / vn
        # p = A v (rows k+1..n-1 of A, whole rows), K = v^T p, w = 2 (p - K v);  A <- A - (v w^T + w v^T)
        for c in range(W):
            wk[c] = 0.0
        for j in range(k + 1, n):
            vj = v[j]
            for c in range(W):
                wk[c] += A[j, c] * vj
        kk = 0.0
        for i in range(k + 1, n):
            kk += v[i] * wk[i]
        for c in range(W):
            wk[c] = 2.0 * (wk[c] - kk * v[c])
        for i in range(k + 1, n):
            vi = v[i]
            wi = wk[i]
            for c in range(W):
                A[i, c] -= vi * wk[c] + wi * v[c]
        e[k] = alpha
        # Vt <- H Vt on rows k+1..n-1:  Vt[i, :] -= 2 v_i (v^T Vt)
        for c in range(W):
            wk[c] = 0.0
        for i in range(k + 1, n):
            vi = v[i]
            for c in range(W):
                wk[c] += vi * Vt[i, c]
        for i in range(k + 1, n):
            f = 2.0 * v[i]
            for c in range(W):
                Vt[i, c] -= f * wk[c]
    if n >= 2:
        e[n - 2] = A[n - 1, n - 2]
    for i in range(n):
        d[i] = A[i, i]


@nb.njit(cache=True, error_model="numpy", inline="always")
def _tridiagonal_qr(d, e, Vt):
    """Phase 2 of :func:`sym_eig_inplace`: the implicit symmetric QR iteration with Wilkinson shifts (Golub & Van
    Loan alg. 8.3.3) on the tridiagonal ``(d, e)`` of :func:`_tridiagonalize` (both destroyed; ``d`` becomes the
    eigenvalues, unsorted), each rotation applied to two rows of ``Vt`` (n, W) over all W columns. Returns False
    when it did not converge in 30 n steps."""
    n = d.shape[0]
    W = Vt.shape[1]
    # ---- implicit symmetric QR with Wilkinson shifts; e[i] couples d[i] and d[i + 1]
    eps = np.finfo(np.float64).eps
    h = n - 1
    it = 0
    while h > 0:
        if abs(e[h - 1]) <= eps * (abs(d[h - 1]) + abs(d[h])):
            e[h - 1] = 0.0
            h -= 1
            continue
        it += 1
        if it > 30 * n:
            return False
        l = h - 1
        while l > 0 and abs(e[l - 1]) > eps * (abs(d[l - 1]) + abs(d[l])):
            l -= 1
        if l > 0:
            e[l - 1] = 0.0
        t = 0.5 * (d[h - 1] - d[h])
        eh = e[h - 1]
        rr = np.sqrt(t * t + eh * eh)
        mu = d[h] - eh * eh / (t + (rr if t >= 0 else -rr))
        x = d[l] - mu
        z = e[l]
        for k in range(l, h):
            r = np.sqrt(x * x + z * z)
            if r == 0.0:
                c = 1.0
                s = 0.0
            else:
                c = x / r
                s = z / r
            if k > l:
                e[k - 1] = r
            dk = d[k]
            dk1 = d[k + 1]
            ek = e[k]
            d[k] = c * c * dk + 2.0 * c * s * ek + s * s * dk1
            d[k + 1] = s * s * dk - 2.0 * c * s * ek + c * c * dk1
            e[k] = c * s * (dk1 - dk) + (c * c - s * s) * ek
            if k < h - 1:
                x = e[k]
                z = s * e[k + 1]
                e[k + 1] = c * e[k + 1]
            for j in range(W):
                a = Vt[k, j]
                b = Vt[k + 1, j]
                Vt[k, j] = c * a + s * b
                Vt[k + 1, j] = c * b - s * a
    return True


@nb.njit(cache=True, error_model="numpy")
def sym_eig_inplace(A, d, Vt, e, v, wk):
    """Eigen-decomposition of the symmetric ``A`` (n rows, overwritten): ``A = Vt^T diag(d) Vt``.

    Householder reduction to tridiagonal form with the transformations accumulated, then the implicit
    symmetric QR iteration with Wilkinson shifts on the tridiagonal matrix, rotations accumulated into the
    eigenvectors (Golub & Van Loan, *Matrix Computations*, 4th ed., algorithms 8.3.1 and 8.3.3). Backward
    stable like LAPACK's ``syevd`` (what ``np.linalg.eigh`` runs), with no allocation and no call overhead.

    The rows of ``A`` and ``Vt`` are padded with zero columns to ``W >= n`` (:func:`padded_width`: 20 for n = 17)
    and every row operation runs over all W (vectorized, no scalar remainder): the Householder step's product
    ``p = A v`` as a sum of rows of the full symmetric ``A`` and its rank-2 update on whole rows (the columns left
    of the trailing block take values never read again), the accumulation and the QR rotations on whole rows of
    ``Vt``; the padding stays zero. Faster than the same steps over the lower triangle and n columns, whose short
    row loops leave most of their work to a scalar remainder.

    Parameters
    ----------
    A : (n, W) symmetric in its first n columns, both triangles stored, zero in the others (destroyed).
    d : (n,) output eigenvalues (unsorted). Vt : (n, W) output, row k the eigenvector of ``d[k]`` (zero padding).
    e : (>= n,), v, wk : (W,) scratch.

    Returns
    -------
    bool, False when the QR iteration did not converge in 30 n steps (outputs undefined).

    The two phases are :func:`_tridiagonalize` and :func:`_tridiagonal_qr`.
    """
    _tridiagonalize(A, d, Vt, e, v, wk)
    return _tridiagonal_qr(d, e, Vt)
