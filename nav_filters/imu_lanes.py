"""The averaged-dynamics epoch propagation (``integrate=True`` of :func:`~nav_filters.propagation.propagate_epoch`)
with the batch rows in SIMD lanes.

The row kernel (:func:`~nav_filters.kernels._propagate_epoch`) advances one row at a time through its IMU samples:
every sample's mechanization is a chain of scalar operations. Here a block of :data:`LANES` rows advances together,
sample by sample, with each quantity of the rows held side by side (row ``q`` of the block, lane ``l``), and each
step of a sample is a loop over the lanes whose body is straight-line scalar code, which LLVM vectorizes (8 rows
per AVX-512 instruction). The per-row arithmetic is the row kernel's, operation for operation
(:func:`~nav_filters.kernels._mechanize_sample`, the same sums in the same order), so the results are the same
bits (``tests/nav_filters/test_imu_lanes.py``).

What keeps the lane loops vectorizable (numba runs LLVM's loop vectorizer only, which gives up silently):

* the rotation coefficients: the series of :func:`~nav_filters.kernels._small_angle` for every lane, then, in a
  scalar pass, :func:`~nav_filters.kernels._large_angle` for the lanes whose rotation increment is not small
  (``|w h|^2 >= 1e-4``: turns faster than 1 rad/s at 100 Hz; a call to ``sin`` would keep the loop scalar);
* ``error_model='numpy'``: no division check (a branch) in the loop;
* the block's rows a constant distance apart in one flat array (so LLVM sees that different rows do not
  overlap), and short loops: one per summed quantity, one for the mechanization, none reading a tuple at a
  loop index. One loop over all of a sample's ~140 accesses, or the new state stored from the returned tuple
  by a loop, stayed scalar.
Only the averaged mode is here: its per-sample work is the mechanization and a few sums. The composing modes
(``exact``, seed 001's one-step prediction) multiply 17 x 17 matrices at every sample and stay row by row.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from earth.wgs84 import GM as _GM, OMEGA_IE as _OMEGA

from .kernels import N, _large_angle, _mechanize_sample, _small_angle, _tuple9, row_kernel, serial_and_parallel

LANES = 32
"""Rows advanced together (the lane count of a block): a multiple of the widest vector loop body LLVM emits
(4 x 8 doubles); the block's quantities (76 x LANES doubles) stay in the L1 cache."""

# rows of the lane block St: position, velocity, attitude (row-major), clock bias, then the per-row sums of
# the averaged mode (kernels._propagate_epoch): C f, C, the gravity gradient, c_m c_m^T per body axis, GM / |r|^3;
# then the inputs of the sample at hand: clock drift, bias-compensated specific force and angular rate, |d|^2 and
# the rotation coefficients (d = w h is formed again where used: cheaper than storing it, measured)
_R, _V, _C, _CLK, _SA, _SC, _SG, _SCC, _SK = 0, 3, 6, 15, 16, 19, 28, 37, 64
_DR, _F, _WR, _TH2, _CA, _CB, _CC = 65, 66, 69, 72, 73, 74, 75
_NQ = 76


def _propagate_lanes(r, v, C, bg, ba, clk, drift, f_raw, w_raw, h, Av, Au, Ag, Cz, qg, qa, qdiag, kg, ka,
                     A_acc, S_acc, orthonormalize, start, nchunk):
    """:func:`~nav_filters.propagation.propagate_epoch` with ``integrate=True`` (arguments as there), in blocks of
    :data:`LANES` rows; the blocks run in ``nchunk`` chunks (parallel in the parallel variant)."""
    B = f_raw.shape[0]
    n = f_raw.shape[1]
    nblk = (B + LANES - 1) // LANES
    for ch in nb.prange(nchunk):
        St = np.empty((_NQ, LANES))
        Sf = St.ravel()
        c3 = np.empty(LANES)            # per sample: 3 GM / |r|^5
        fw = np.empty((n, 6, LANES))    # per sample: bias-compensated specific force and angular rate
        sa = np.empty(3)
        sC = np.empty((3, 3))
        sG = np.empty((3, 3))
        sCC = np.empty((3, 3, 3))
        Avt = _tuple9(Av)
        Aut = _tuple9(Au)
        Agt = _tuple9(Ag)
        Czt = _tuple9(Cz)
        for blk in range(ch * nblk // nchunk, (ch + 1) * nblk // nchunk):
            lo = blk * LANES
            L = min(LANES, B - lo)
            for l in range(L):
                b = lo + l
                for i in range(3):
                    St[_R + i, l] = r[b, i]
                    St[_V + i, l] = v[b, i]
                    for j in range(3):
                        St[_C + 3 * i + j, l] = C[b, i, j]
                St[_CLK, l] = clk[b]
                for q in range(_SA, _DR):
                    St[q, l] = 0.0
                St[_DR, l] = drift[b]
                for k in range(n):
                    for i in range(3):
                        fw[k, i, l] = f_raw[b, k, i] - ba[b, i]
                        fw[k, 3 + i, l] = w_raw[b, k, i] - bg[b, i]
            for k in range(n):
                for q in range(6):
                    for l in range(L):
                        St[_F + q, l] = fw[k, q, l]
                _lane_angles(St, L, h)
                for l in range(L):
                    if not St[_TH2, l] < 1e-4:
                        St[_CA, l], St[_CB, l], St[_CC, l] = _large_angle(St[_TH2, l])
                if orthonormalize:
                    _lane_samples(Sf, c3, L, h, Avt, Aut, Agt, Czt, True)
                else:
                    _lane_samples(Sf, c3, L, h, Avt, Aut, Agt, Czt, False)
            for l in range(L):
                b = lo + l
                for i in range(3):
                    r[b, i] = St[_R + i, l]
                    v[b, i] = St[_V + i, l]
                    sa[i] = St[_SA + i, l]
                    for j in range(3):
                        C[b, i, j] = St[_C + 3 * i + j, l]
                        sC[i, j] = St[_SC + 3 * i + j, l]
                        sG[i, j] = St[_SG + 3 * i + j, l]
                        for m in range(3):
                            sCC[m, i, j] = St[_SCC + 9 * m + 3 * min(i, j) + max(i, j), l]
                clk[b] = St[_CLK, l]
                if start:
                    for i in range(A_acc.shape[1]):
                        for j in range(A_acc.shape[2]):
                            A_acc[b, i, j] = 0.0
                            S_acc[b, i, j] = 0.0
                if n > 0:
                    _add_integrals(A_acc, S_acc, b, n * h, h, sC, sa, sG, St[_SK, l], sCC, qg, qa, qdiag, kg, ka)


@nb.njit(cache=True, error_model="numpy")
def _lane_angles(St, L, h):
    """``|d|^2`` (``d = w h``) of the sample at hand and the series coefficients (:func:`~.kernels._small_angle`)
    of lanes ``0..L-1``."""
    for l in range(L):
        d0 = St[_WR, l] * h
        d1 = St[_WR + 1, l] * h
        d2 = St[_WR + 2, l] * h
        th2 = d0 * d0 + d1 * d1 + d2 * d2
        ca, cb, cc = _small_angle(th2)
        St[_TH2, l] = th2
        St[_CA, l] = ca
        St[_CB, l] = cb
        St[_CC, l] = cc


@nb.njit(cache=True, error_model="numpy")
def _lane_samples(S, c3, L, h, Av, Au, Ag, Cz, orthonormalize):
    """The sample at hand in lanes ``0..L-1``: the sums of the averaged mode at the state of the sample's start,
    then the mechanization (:func:`~nav_filters.kernels._mechanize_sample`) and the clock; per lane the row
    kernel's operations in its order.

    ``S`` the lane block flat (row q of lane l at ``q * LANES + l``: the rows' distance a constant, so LLVM can
    tell that the reads and writes of different rows do not overlap), ``c3`` (LANES,) scratch; ``Av`` ... ``Cz``
    9-tuples (:func:`~.kernels._tuple9`). Every lane loop is short and straight-line (LLVM's vectorizer gives up
    on a loop with very many accesses to one array, and on a tuple read at a loop index), so each one
    vectorizes."""
    for i in range(3):       # sum C f
        o = (_SA + i) * LANES
        c = (_C + 3 * i) * LANES
        for l in range(L):
            S[o + l] += S[c + l] * S[_F * LANES + l] + S[c + LANES + l] * S[(_F + 1) * LANES + l] \
                + S[c + 2 * LANES + l] * S[(_F + 2) * LANES + l]
    for q in range(9):       # sum C
        o = (_SC + q) * LANES
        c = (_C + q) * LANES
        for l in range(L):
            S[o + l] += S[c + l]
    for m in range(3):       # sum c_m c_m^T (c_m column m of C), the upper triangle: the lower is its mirror
        for i in range(3):
            for j in range(i, 3):
                o = (_SCC + 9 * m + 3 * i + j) * LANES
                a = (_C + 3 * i + m) * LANES
                c = (_C + 3 * j + m) * LANES
                for l in range(L):
                    S[o + l] += S[a + l] * S[c + l]
    for l in range(L):       # sum GM / |r|^3, and 3 GM / |r|^5 into c3
        r0 = S[_R * LANES + l]
        r1 = S[(_R + 1) * LANES + l]
        r2 = S[(_R + 2) * LANES + l]
        rs2 = r0 * r0 + r1 * r1 + r2 * r2
        ir2 = 1.0 / rs2
        kr = _GM * ir2 / np.sqrt(rs2)
        S[_SK * LANES + l] += kr
        c3[l] = 3.0 * kr * ir2
    for i in range(3):       # sum 3 GM r r^T / |r|^5
        for j in range(3):
            o = (_SG + 3 * i + j) * LANES
            a = (_R + i) * LANES
            c = (_R + j) * LANES
            for l in range(L):
                S[o + l] += c3[l] * S[a + l] * S[c + l]
    for l in range(L):
        (r0, r1, r2, v0, v1, v2, c00, c01, c02, c10, c11, c12, c20, c21, c22) = _mechanize_sample(
            S[_R * LANES + l], S[(_R + 1) * LANES + l], S[(_R + 2) * LANES + l],
            S[_V * LANES + l], S[(_V + 1) * LANES + l], S[(_V + 2) * LANES + l],
            S[_C * LANES + l], S[(_C + 1) * LANES + l], S[(_C + 2) * LANES + l],
            S[(_C + 3) * LANES + l], S[(_C + 4) * LANES + l], S[(_C + 5) * LANES + l],
            S[(_C + 6) * LANES + l], S[(_C + 7) * LANES + l], S[(_C + 8) * LANES + l],
            S[_F * LANES + l], S[(_F + 1) * LANES + l], S[(_F + 2) * LANES + l],
            S[_WR * LANES + l] * h, S[(_WR + 1) * LANES + l] * h, S[(_WR + 2) * LANES + l] * h,
            (S[_TH2 * LANES + l], S[_CA * LANES + l], S[_CB * LANES + l], S[_CC * LANES + l]),
            h, Av, Au, Ag, Cz, orthonormalize)
        S[_R * LANES + l] = r0
        S[(_R + 1) * LANES + l] = r1
        S[(_R + 2) * LANES + l] = r2
        S[_V * LANES + l] = v0
        S[(_V + 1) * LANES + l] = v1
        S[(_V + 2) * LANES + l] = v2
        S[_C * LANES + l] = c00
        S[(_C + 1) * LANES + l] = c01
        S[(_C + 2) * LANES + l] = c02
        S[(_C + 3) * LANES + l] = c10
        S[(_C + 4) * LANES + l] = c11
        S[(_C + 5) * LANES + l] = c12
        S[(_C + 6) * LANES + l] = c20
        S[(_C + 7) * LANES + l] = c21
        S[(_C + 8) * LANES + l] = c22
    for l in range(L):
        S[_CLK * LANES + l] += S[_DR * LANES + l] * h


@nb.njit(cache=True, inline="always")
def _add_integrals(A, S, b, nh, h, sC, sa, sG, sk, sCC, qg, qa, qdiag, kg, ka):
    """``A[b] += sum_i F_i h`` and ``S[b] += sum_i G_i Q_c G_i^T h`` from the per-row sums of the varying
    parts (the entries of :func:`~.kernels._fill_F`, term by term; ``nh``: the summed interval)."""
    for i in range(3):
        for j in range(3):
            A[b, i, 9 + j] -= h * sC[i, j]
            A[b, 3 + i, 12 + j] -= h * sC[i, j]
            A[b, 3 + i, 6 + j] += h * sG[i, j]
            qgs = 0.0
            qas = 0.0
            for m in range(3):
                qgs += qg[m] * sCC[m, i, j]
                qas += qa[m] * sCC[m, i, j]
            S[b, i, j] += h * qgs
            S[b, 3 + i, 3 + j] += h * qas
    A[b, 3, 1] += h * sa[2]
    A[b, 3, 2] -= h * sa[1]
    A[b, 4, 0] -= h * sa[2]
    A[b, 4, 2] += h * sa[0]
    A[b, 5, 0] += h * sa[1]
    A[b, 5, 1] -= h * sa[0]
    A[b, 3, 6] -= h * sk - nh * _OMEGA * _OMEGA
    A[b, 4, 7] -= h * sk - nh * _OMEGA * _OMEGA
    A[b, 5, 8] -= h * sk
    A[b, 0, 1] += nh * _OMEGA
    A[b, 1, 0] -= nh * _OMEGA
    A[b, 3, 4] += 2.0 * nh * _OMEGA
    A[b, 4, 3] -= 2.0 * nh * _OMEGA
    A[b, 6, 3] += nh
    A[b, 7, 4] += nh
    A[b, 8, 5] += nh
    for i in range(9, 12):
        A[b, i, i] += nh * kg
    for i in range(12, 15):
        A[b, i, i] += nh * ka
    A[b, 15, 16] += nh
    for i in range(6, N):
        S[b, i, i] += nh * qdiag[i]


_serial, _parallel = serial_and_parallel(_propagate_lanes, error_model="numpy")


def propagate_lanes(r, v, C, bg, ba, clk, drift, f_raw, w_raw, h, Av, Au, Ag, Cz, qg, qa, qdiag, kg, ka, A_acc,
                    S_acc, orthonormalize, start):
    """:func:`_propagate_lanes` of every row; parallel over blocks from
    :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows."""
    kern, nchunk = row_kernel(_serial, _parallel, f_raw.shape[0])
    kern(r, v, C, bg, ba, clk, drift, f_raw, w_raw, h, Av, Au, Ag, Cz, qg, qa, qdiag, kg, ka, A_acc, S_acc,
         bool(orthonormalize), bool(start), nchunk)


__all__ = ["LANES", "propagate_lanes"]
