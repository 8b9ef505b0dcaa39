"""Compiled fused path of the SVD forms (``svd-kf``, ``svd-srkf``; ``set_fused(True)``, the envs' default).

The numpy methods of :mod:`.svd` are the specification: :func:`svd_fused_update` runs the same recursion (seed
paper 000 eqs 4-17) per batch row in one compiled call, over row chunks in parallel, with the masked measurement
rows left out instead of neutralized (a masked row changes nothing, DESIGN.md sec 2) and every factor refreshed
by a singular value decomposition of its pre-array, as the numpy path does:

* time update (eqs 8-11): the SVD of ``[D U^T Phi^T ; L_Q^T]``, ``L_Q`` the square root of Q (``svd-kf``: its SVD
  factor, Kulikova & Tsyganova 2017; ``svd-srkf``: its Cholesky factor, eq 7, else the SVD factor);
* ``svd-kf`` update (eq 17, :meth:`.svd.SvdKalmanFilter._update_reference`): the SVD of the innovation pre-array,
  the gain from those factors, the SVD of the factored Joseph form;
* ``svd-srkf`` update (eqs 12-16, :meth:`.svd.SvdSquareRootKF._update_reference`): the SVD of the information
  pre-array ``[L_R^T H U ; D^-1]``.

The SVDs are :func:`svd_right`, the Golub-Kahan-Reinsch algorithm (Golub & Reinsch 1970; Golub & Van Loan,
*Matrix Computations*, 4th ed., sec 8.6) that forms only what the forms read, the singular values and the right
singular vectors (the left factor W of ``A = W diag(s) V^T`` is never used, :mod:`.svd`), without LAPACK's
call overhead, which dominates for pre-arrays of 17 columns (a 34 x 17 pre-array: about half the time of numpy's
batched ``svd``, which also forms W). The symmetric PSD
matrices Q and R are factored by their eigendecomposition (:func:`~nav_filters.kernels.sym_eig_inplace`, in
float64; for a symmetric PSD matrix it is its SVD, as :func:`.svd._sym_svd_factor` notes), or, diagonal, by the
square roots of their variances. Same equations, different rounding: the numpy path's results to round-off in
float64 and to float32's precision in float32 (``tests/nav_filters/test_svd_fused.py``; in float32 the SVDs
here are less accurate than LAPACK's on strongly graded pre-arrays, 25 eps against 0.5 eps, so a float32
``svd-asrkf`` episode of ``seed000-sim`` ends 6e-5 m from its float64 run where the numpy path ends 1.3e-5 m).

A row the kernel does not decide (a Q or R outside what the numpy path accepts, a non-finite pre-array, an SVD
that did not converge) is flagged and the caller runs the numpy path instead, which raises the error or computes.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels import (cholesky_inplace, padded_width, row_kernel, row_nonzeros, serial_and_parallel,
                       sym_eig_inplace)

MAX_QR_STEPS = 60
"""Implicit QR steps per singular value before :func:`svd_right` gives up (LAPACK's ``dbdsqr``: 6 per value on
average; a failure sends the batch to the numpy path)."""


@nb.njit(cache=True, inline="always")
def _dot(a, b, lo, hi):
    """``sum_(lo <= t < hi) a[t] b[t]`` in four interleaved partial sums (independent chains: a single running sum
    waits for each addition in turn, the latency that bounds short dot products)."""
    s0 = s1 = s2 = s3 = 0.0
    t = lo
    while t + 4 <= hi:
        s0 += a[t] * b[t]
        s1 += a[t + 1] * b[t + 1]
        s2 += a[t + 2] * b[t + 2]
        s3 += a[t + 3] * b[t + 3]
        t += 4
    while t < hi:
        s0 += a[t] * b[t]
        t += 1
    return (s0 + s1) + (s2 + s3)


@nb.njit(cache=True, error_model="numpy")
def _triangularize(X, nr):
    """Householder QR ``A = Q R`` of the (nr x nc) array ``A`` stored transposed in ``X`` (nc, >= nr): on return
    ``X[j, :j+1]`` is column j of R (``X[j, t] = R[t, j]``) and ``X[j, j+1:nr]`` zero, so that ``X[:, :nc]`` holds
    ``R^T`` (``A^T A = R^T R``). Reflections on the columns of A only: a scaling of A's columns (the grading of
    a pre-array such as ``[G ; D^-1]``) scales R's columns alike."""
    nc = X.shape[0]
    for k in range(nc):
        v = X[k]
        alpha = np.sqrt(_dot(v, v, k, nr))
        if alpha == 0.0:
            continue
        x0 = X[k, k]
        beta = -alpha if x0 >= 0 else alpha
        X[k, k] = x0 - beta
        c = 1.0 / (alpha * (alpha + abs(x0)))
        for j in range(k + 1, nc):
            xj = X[j]
            s = c * _dot(v, xj, k, nr)
            for t in range(k, nr):
                xj[t] -= s * v[t]
        X[k, k] = beta
        for t in range(k + 1, nr):
            X[k, t] = 0.0


@nb.njit(cache=True, error_model="numpy")
def _reflect_rows(X, k, c, A, hi, w):
    """The right reflection of step k (``I - c u u^T``, ``u = X[k+1:, k]``) as a row operation on ``A``'s rows
    ``k+1 ..`` and columns ``k+1 .. hi-1``: ``A[i, t] -= c u_i (u^T A[:, t])``; ``w`` (>= hi,) scratch. ``A`` may
    be ``X`` itself (column k is not touched)."""
    nc = X.shape[0]
    for t in range(k + 1, hi):
        w[t] = 0.0
    for i in range(k + 1, nc):
        u = X[i, k]
        for t in range(k + 1, hi):
            w[t] += u * A[i, t]
    for i in range(k + 1, nc):
        cu = c * X[i, k]
        for t in range(k + 1, hi):
            A[i, t] -= cu * w[t]


@nb.njit(cache=True, error_model="numpy")
def _bidiagonalize(X, nr, d, f, wk):
    """Householder bidiagonalization ``A = W B V_B^T`` of the (nr x nc) array ``A`` stored transposed,
    ``X[j, t] = A[t, j]`` (X (nc, >= nr), its rows the columns of A: every reflection is a row operation).

    On return ``d`` (nc,) is the diagonal of the upper bidiagonal B, ``f`` (nc,) its superdiagonal with
    ``f[i] = B[i-1, i]`` (``f[0] = 0``), and ``X[k+1:, k]`` holds the vector of the right reflection of step k
    (``I - c u u^T`` with ``c = 2 / u^T u`` in ``wk[nr + k]``; 0: none). The left reflections are not kept.
    ``wk`` (>= nr + nc,) scratch."""
    nc = X.shape[0]
    f[0] = 0.0
    for k in range(nc):
        # left reflection: A[k:, k] (= X[k, k:nr]) -> d_k e_1, applied to the columns right of k
        v = X[k]
        alpha = np.sqrt(_dot(v, v, k, nr))
        if alpha == 0.0:
            d[k] = 0.0
        else:
            x0 = X[k, k]
            beta = -alpha if x0 >= 0 else alpha
            X[k, k] = x0 - beta
            c = 1.0 / (alpha * (alpha + abs(x0)))
            for j in range(k + 1, nc):
                xj = X[j]
                s = c * _dot(v, xj, k, nr)
                for t in range(k, nr):
                    xj[t] -= s * v[t]
            d[k] = beta
        wk[nr + k] = 0.0
        if k + 2 < nc:  # right reflection: A[k, k+1:] (= X[k+1:, k]) -> f_(k+1) e_1, applied to the rows below k
            a2 = 0.0
            for i in range(k + 1, nc):
                a2 += X[i, k] * X[i, k]
            alpha = np.sqrt(a2)
            if alpha == 0.0:
                f[k + 1] = 0.0
                continue
            y0 = X[k + 1, k]
            beta = -alpha if y0 >= 0 else alpha
            X[k + 1, k] = y0 - beta
            c = 1.0 / (alpha * (alpha + abs(y0)))
            wk[nr + k] = c
            _reflect_rows(X, k, c, X, nr, wk)
            f[k + 1] = beta
        elif k + 1 < nc:
            f[k + 1] = X[k + 1, k]


@nb.njit(cache=True, error_model="numpy")
def _right_vectors(X, nr, Vt, W, Mv, wk):
    """``Vt = V_B^T`` (rows the columns of ``V_B = H_0 H_1 ... H_(nc-3)``) from the right reflections that
    :func:`_bidiagonalize` left in ``X`` and ``wk``: ``V_B`` accumulated backwards in ``Mv`` (>= nc, >= nc) as row
    operations (``Mv <- H_k Mv``: ``Mv[i] -= c u_i (u^T Mv)``), then transposed into ``Vt[:, :W]`` (nc <= W), whose
    padding columns are set to zero."""
    nc = X.shape[0]
    for i in range(nc):
        for j in range(nc):
            Mv[i, j] = 0.0
        Mv[i, i] = 1.0
    for k in range(nc - 3, -1, -1):
        c = wk[nr + k]
        if c == 0.0:
            continue
        _reflect_rows(X, k, c, Mv, nc, wk)
    for i in range(nc):
        for j in range(W):
            Vt[i, j] = Mv[j, i] if j < nc else 0.0


@nb.njit(cache=True, error_model="numpy")
def _bidiagonal_qr(d, f, Vt, W, eps):
    """Diagonalize the upper bidiagonal ``(d, f)`` of :func:`_bidiagonalize` by implicit-shift QR steps (Golub &
    Reinsch 1970; Golub & Van Loan alg. 8.6.1-8.6.2): the right rotations are applied to the rows of ``Vt``, the
    left ones are dropped; the rotations run over the first W columns of ``Vt`` (the rest are not read). A
    superdiagonal entry below ``eps`` times its neighbours on the diagonal splits the matrix (the relative test, as
    LAPACK's ``dbdsqr``); a diagonal entry below ``eps^2 max_i(|d_i| + |f_i|)`` is chased off its row by left
    rotations first. Singular values made non-negative (row of Vt negated). Returns False where a value took more
    than :data:`MAX_QR_STEPS` steps (outputs undefined)."""
    nc = d.shape[0]
    anorm = 0.0
    for i in range(nc):
        anorm = max(anorm, abs(d[i]) + abs(f[i]))
    tol = eps * anorm
    for k in range(nc - 1, -1, -1):
        for _ in range(MAX_QR_STEPS):
            l = k
            cancel = False
            while l > 0:
                if abs(f[l]) <= eps * (abs(d[l - 1]) + abs(d[l])):
                    break
                if abs(d[l - 1]) <= eps * tol:
                    cancel = True
                    break
                l -= 1
            if cancel:  # d[l-1] ~ 0: chase f[l] along row l-1 (left rotations only)
                c, s = 0.0, 1.0
                for i in range(l, k + 1):
                    g = s * f[i]
                    f[i] = c * f[i]
                    if abs(g) <= tol:
                        break
                    h = np.sqrt(g * g + d[i] * d[i])
                    c, s = d[i] / h, -g / h
                    d[i] = h
            z = d[k]
            if l == k:
                if z < 0:
                    d[k] = -z
                    for j in range(W):
                        Vt[k, j] = -Vt[k, j]
                break
            # Wilkinson shift from the trailing 2 x 2 of B^T B, then one chase of the bulge from l to k
            x, y, g, h = d[l], d[k - 1], f[k - 1], f[k]
            a = ((y - z) * (y + z) + (g - h) * (g + h)) / (2.0 * h * y)
            g = np.hypot(a, 1.0)
            a = ((x - z) * (x + z) + h * (y / (a + (g if a >= 0 else -g)) - h)) / x
            c, s = 1.0, 1.0
            for j in range(l, k):
                i = j + 1
                g, y = f[i], d[i]
                h, g = s * g, c * g
                z = np.sqrt(a * a + h * h)
                f[j] = z
                rz = 1.0 / z
                c, s = a * rz, h * rz
                a, g = x * c + g * s, g * c - x * s
                h, y = y * s, y * c
                for t in range(W):
                    vj, vi = Vt[j, t], Vt[i, t]
                    Vt[j, t] = vj * c + vi * s
                    Vt[i, t] = vi * c - vj * s
                z = np.sqrt(a * a + h * h)
                d[j] = z
                if z != 0.0:
                    rz = 1.0 / z
                    c, s = a * rz, h * rz
                a, x = c * g + s * y, c * y - s * g
            f[l] = 0.0
            f[k] = a
            d[k] = x
        else:
            return False
    return True


@nb.njit(cache=True, error_model="numpy")
def svd_right(X, nr, d, f, Vt, Mv, wk, perm, eps):
    """Singular values and right singular vectors of the (nr x nc) array ``A`` (``nr >= nc``) stored transposed in
    ``X`` (nc, >= nr) (destroyed): ``A^T A = Vt^T diag(d)^2 Vt``, ``d`` (nc,) descending, ``Vt`` (nc, >= nc) its rows
    the right singular vectors, written up to the padded width of nc (:func:`~nav_filters.kernels.padded_width`,
    zero beyond nc; the columns beyond that width are left as they were: the rotations skip the zero padding of a
    scratch wider than nc).

    Golub-Kahan-Reinsch as LAPACK's ``gesvd`` / ``gesdd`` run it on a tall array: the columns ordered by decreasing
    norm, a Householder QR (:func:`_triangularize`), the bidiagonalization of R (:func:`_bidiagonalize`,
    :func:`_right_vectors`), implicit-shift QR on the bidiagonal (:func:`_bidiagonal_qr`). Backward stable, and
    on pre-arrays whose columns are scaled over many decades (``svd-srkf``'s ``[G ; D^-1]``) the small singular
    values keep their relative accuracy (measured on such float32 arrays: 3e-6, against 1e-4 without the ordering
    and the QR). ``f`` (nc,), ``Mv`` (>= nc, >= nc), ``wk`` (>= nr + nc,), ``perm`` (>= nc,) int scratch; ``eps``
    the unit round-off of the arrays' dtype. Returns False (outputs undefined) for a non-finite A or a QR iteration
    that did not converge."""
    nc = X.shape[0]
    for j in range(nc):
        for t in range(nr):
            if not np.isfinite(X[j, t]):
                return False
        wk[j] = _dot(X[j], X[j], 0, nr)
        perm[j] = j
    for i in range(nc):  # columns of A (rows of X) by decreasing norm (selection sort)
        k = i
        for j in range(i + 1, nc):
            if wk[j] > wk[k]:
                k = j
        if k != i:
            wk[i], wk[k] = wk[k], wk[i]
            perm[i], perm[k] = perm[k], perm[i]
            for t in range(nr):
                X[i, t], X[k, t] = X[k, t], X[i, t]
    if nr > nc:
        _triangularize(X, nr)
        nr = nc
    _bidiagonalize(X, nr, d, f, wk)
    W = min(Vt.shape[1], padded_width(nc))  # the rotations' width: the columns of Vt beyond it are not read
    _right_vectors(X, nr, Vt, W, Mv, wk)
    if not _bidiagonal_qr(d, f, Vt, W, eps):
        return False
    for i in range(nc):  # descending (numpy's order), and back to A's column order: Vt[:, perm[j]] <- Vt[:, j]
        k = i
        for j in range(i + 1, nc):
            if d[j] > d[k]:
                k = j
        if k != i:
            d[i], d[k] = d[k], d[i]
            for t in range(W):
                Vt[i, t], Vt[k, t] = Vt[k, t], Vt[i, t]
    for i in range(nc):
        for j in range(nc):
            wk[perm[j]] = Vt[i, j]
        for j in range(nc):
            Vt[i, j] = wk[j]
    return True


# --------------------------------------------------------------------------- square roots of Q and R
@nb.njit(cache=True, error_model="numpy")
def _sym_block_eig(M, rows, k, ew, eps):
    """Eigendecomposition (float64) of the symmetric part of ``M[rows][:, rows]`` (k x k) into ``ew``'s ``lam`` (k,)
    and ``Ve`` (rows the eigenvectors), validated as :func:`.svd._sym_svd_factor` validates the SVD of a symmetric
    PSD matrix: False where the negative eigenvalues sum to more than ``10 k eps max|lam|`` or the iteration did
    not converge."""
    Ae, lam, Ve, ee, ve, we, _ = ew
    W = Ae.shape[1]
    for a in range(k):
        for b in range(W):
            Ae[a, b] = 0.5 * (np.float64(M[rows[a], rows[b]]) + np.float64(M[rows[b], rows[a]])) if b < k else 0.0
    if not sym_eig_inplace(Ae[:k], lam[:k], Ve[:k], ee, ve, we):
        return False
    neg, top = 0.0, 0.0
    for q in range(k):
        top = max(top, abs(lam[q]))
        if lam[q] < 0:
            neg -= lam[q]
    return neg <= 10.0 * k * eps * top


@nb.njit(cache=True, error_model="numpy")
def _q_columns(Q, cholesky, X, c0, ew, eps):
    """The columns of ``L_Q`` (``L_Q L_Q^T = Q``) into ``X[:, c0:c0 + k]`` (the time update pre-array's rows
    ``L_Q^T``, transposed), as :func:`.svd._sqrt_factor_rows` forms them: a diagonal Q by the square roots of its
    positive variances; else the block of its non-zero rows by Cholesky (``cholesky``: ``svd-srkf``, seed 000 eq 7)
    or, failing that or for ``svd-kf``, by its eigendecomposition ``sqrt|lam_q| v_q`` (its SVD factor). Returns
    k, or -1 where the numpy path raises (a non-finite entry, a variance or eigenvalues negative beyond
    round-off)."""
    n = Q.shape[0]
    nz = ew[6]
    diagonal = True
    top = 0.0
    for i in range(n):
        top = max(top, abs(np.float64(Q[i, i])))
        for j in range(n):
            if not np.isfinite(Q[i, j]):
                return -1
            if i != j and Q[i, j] != 0:
                diagonal = False
    if diagonal:
        k = 0
        for i in range(n):
            q = np.float64(Q[i, i])
            if q < -10.0 * n * eps * top:
                return -1
            if q > 0:
                for j in range(n):
                    X[j, c0 + k] = 0.0
                X[i, c0 + k] = np.sqrt(q)
                k += 1
        return k
    nk = 0
    for i in range(n):
        for j in range(n):
            if Q[i, j] != 0:
                nz[nk] = i
                nk += 1
                break
    for j in range(n):
        for q in range(nk):
            X[j, c0 + q] = 0.0
    if cholesky:
        Ae = ew[0]
        for a in range(nk):
            for b in range(nk):
                Ae[a, b] = 0.5 * (np.float64(Q[nz[a], nz[b]]) + np.float64(Q[nz[b], nz[a]]))
        if cholesky_inplace(Ae[:nk, :nk], 0.0):
            for q in range(nk):
                for a in range(q, nk):
                    X[nz[a], c0 + q] = Ae[a, q]
            return nk
    if not _sym_block_eig(Q, nz, nk, ew, eps):
        return -1
    lam, Ve = ew[1], ew[2]
    for q in range(nk):
        sq = np.sqrt(abs(lam[q]))
        for a in range(nk):
            X[nz[a], c0 + q] = sq * Ve[q, a]
    return nk


@nb.njit(cache=True, error_model="numpy")
def _valid_block_diagonal(R, idx, mv):
    """Whether the valid rows ``idx[:mv]`` of R have no covariance between them."""
    for a in range(mv):
        for b in range(mv):
            if a != b and R[idx[a], idx[b]] != 0:
                return False
    return True


# --------------------------------------------------------------------------- one row
@nb.njit(cache=True, error_model="numpy")
def _time_row(U, D, Phi, s, Q, x, cholesky, eps, sw, ew, Vp, Dp, xm, T):
    """Seed 000 eqs 8-11 for one row: ``xm = diag(s) Phi x`` and the predicted factors ``Vp`` (rows the columns of
    U), ``Dp`` from the SVD of the pre-array ``[D U^T Phi^T diag(s) ; L_Q^T]`` (``s`` the square roots of the fading
    factors, :meth:`FilterForm.predicted_update`). ``sw = (X, d, f, Vt, Mv, wk, perm)`` the SVD's scratch, ``ew`` the
    eigendecomposition's (rows of n or more), ``T`` (n, n) scratch. False where the numpy path must decide."""
    X, d, f, Vt, Mv, wk, perm = sw
    n = D.shape[0]
    for j in range(n):  # X[:, :n] = (diag(s) Phi U diag(D)): the pre-array's upper block, transposed
        for i in range(n):
            T[j, i] = 0.0
        acc = 0.0
        for l in range(n):
            a = Phi[j, l]
            if a != 0:
                acc += a * x[l]
                for i in range(n):
                    T[j, i] += a * U[l, i]
        xm[j] = s[j] * acc
        for i in range(n):
            X[j, i] = s[j] * T[j, i] * D[i]
    k = _q_columns(Q, cholesky, X, n, ew, eps)
    if k < 0 or not svd_right(X[:n], n + k, d[:n], f[:n], Vt[:n], Mv, wk, perm, eps):
        return False
    for i in range(n):
        Dp[i] = d[i]
        for j in range(n):
            Vp[i, j] = Vt[i, j]
    return True


@nb.njit(cache=True, error_model="numpy")
def _valid_rows(H, dz, mask, xm, Vp, mw, r, Sd):
    """The valid measurement rows of one row (``idx``, the non-zeros of their H rows), their residuals
    ``rv = dz - H xm`` (also into ``r``; 0 and ``Sd = 1`` on the masked rows, as the neutral rows of the numpy
    path give) and ``HU[t, i] = H_t . U[:, i]`` (``Vp`` rows the columns of U). Returns their number."""
    idx, nzc, nzv, cnt, HU, rv = mw[0], mw[1], mw[2], mw[3], mw[4], mw[6]
    n = xm.shape[0]
    mv = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            idx[mv] = i
            cnt[mv] = row_nonzeros(H[i], nzc[mv], nzv[mv])
            mv += 1
        else:
            r[i] = 0.0
            Sd[i] = 1.0
    for t in range(mv):
        acc = dz[idx[t]]
        for q in range(cnt[t]):
            acc -= nzv[t, q] * xm[nzc[t, q]]
        rv[t] = acc
        r[idx[t]] = acc
        for i in range(n):
            acc = 0.0
            for q in range(cnt[t]):
                acc += Vp[i, nzc[t, q]] * nzv[t, q]
            HU[t, i] = acc
    return mv


@nb.njit(cache=True, error_model="numpy")
def _no_update(Vp, Dp, Un, Dn):
    """The posterior factors of a row without valid measurement rows: the prior ones (``Un`` = U)."""
    n = Dp.shape[0]
    for i in range(n):
        Dn[i] = Dp[i]
        for l in range(n):
            Un[l, i] = Vp[i, l]


@nb.njit(cache=True, error_model="numpy")
def _kf_update_row(Vp, Dp, xm, H, R, dz, mask, eps, sw, ew, mw, Un, Dn, dx, r, Sd):
    """``svd-kf``'s measurement update of one row (Kulikova & Tsyganova 2017; seed 000 eq 17; the numpy
    specification :meth:`.svd.SvdKalmanFilter._update_reference`, its steps 1-3) on the valid rows, from the
    prior factors ``Vp`` (rows the columns of U), ``Dp`` and state ``xm``: posterior factors into ``Un`` (n, n)
    (``P = Un diag(Dn)^2 Un^T``), ``Dn``, the correction ``dx = K r``, ``r``, ``Sd = diag(S)``. Products are formed
    on transposed factors (``Mt = M^T``, ``Kt = K^T``, ...) as sums of rows. Returns ``(ok, nis)``, ok False where
    the numpy path must decide (an R that is not positive definite, an SVD that failed)."""
    X, d, f, Vt, Mv, wk, perm = sw
    idx, Mt, SRt, rv, fv, MVt, Gt, Kt, UDt, g = mw[0], mw[4], mw[5], mw[6], mw[7], mw[8], mw[9], mw[10], mw[11], mw[12]
    n = Dp.shape[0]
    mv = _valid_rows(H, dz, mask, xm, Vp, mw, r, Sd)
    for t in range(mv):  # Mt = (D U^T H^T)^T, diag(S) = sum_i M_it^2 + R_tt
        row = Mt[t]
        for i in range(n):
            row[i] *= Dp[i]
        Sd[idx[t]] = _dot(row, row, 0, n) + R[idx[t], idx[t]]
    for i in range(n):
        dx[i] = 0.0
        for l in range(n):
            UDt[i, l] = Dp[i] * Vp[i, l]
    if mv == 0:
        _no_update(Vp, Dp, Un, Dn)
        return True, 0.0
    # 1. SRt = (D_R^(1/2) U_R^T)^T and the innovation pre-array [SR ; M], transposed: S = VS^T diag(sig)^2 VS
    diagonal = _valid_block_diagonal(R, idx, mv)
    if diagonal:
        for t in range(mv):
            for q in range(mv):
                SRt[t, q] = np.sqrt(R[idx[t], idx[t]]) if q == t else 0.0
    else:
        if not _sym_block_eig(R, idx, mv, ew, eps):
            return False, 0.0
        lam, Ve = ew[1], ew[2]
        for q in range(mv):
            if lam[q] == 0:
                return False, 0.0
            sq = np.sqrt(abs(lam[q]))
            for t in range(mv):
                SRt[t, q] = sq * Ve[q, t]
    for t in range(mv):
        for q in range(mv):
            X[t, q] = SRt[t, q]
        for i in range(n):
            X[t, mv + i] = Mt[t, i]
    if not svd_right(X[:mv], mv + n, d[:mv], f[:mv], Vt[:mv], Mv, wk, perm, eps):
        return False, 0.0
    # 2. f = VS r / sig (NIS = |f|^2); MV = M VS^T; K = UD (MV / sig^2) VS; dx = UD MV f / sig
    nis = 0.0
    for i in range(n):
        g[i] = 0.0
    for q in range(mv):
        fv[q] = _dot(Vt[q], rv, 0, mv) / d[q]
        nis += fv[q] * fv[q]
        row = MVt[q]
        for i in range(n):
            row[i] = 0.0
        for t in range(mv):
            a = Vt[q, t]
            for i in range(n):
                row[i] += a * Mt[t, i]
        a = fv[q] / d[q]
        for i in range(n):
            g[i] += a * row[i]
    for t in range(mv):
        gt = Gt[t]
        for i in range(n):
            gt[i] = 0.0
        for q in range(mv):
            a = Vt[q, t] / (d[q] * d[q])
            for i in range(n):
                gt[i] += a * MVt[q, i]
        kt = Kt[t]
        for l in range(n):
            kt[l] = 0.0
        for i in range(n):
            a = gt[i]
            for l in range(n):
                kt[l] += a * UDt[i, l]
    for i in range(n):
        a = g[i]
        for l in range(n):
            dx[l] += a * UDt[i, l]
    # 3. the factored Joseph form [D U^T (I - K H)^T ; SR K^T] = [UD^T - M K^T ; SR K^T], transposed (eq 17)
    for l in range(n):
        xl = X[l]
        for i in range(n):
            xl[i] = UDt[i, l]
        for q in range(mv):
            xl[n + q] = 0.0
        for t in range(mv):
            a = Kt[t, l]
            for i in range(n):
                xl[i] -= a * Mt[t, i]
            if diagonal:
                xl[n + t] = a * SRt[t, t]
            else:
                for q in range(mv):
                    xl[n + q] += a * SRt[t, q]
    if not svd_right(X[:n], n + mv, d[:n], f[:n], Vt[:n], Mv, wk, perm, eps):
        return False, 0.0
    for i in range(n):
        Dn[i] = d[i]
        for l in range(n):
            Un[l, i] = Vt[i, l]
    return True, nis


@nb.njit(cache=True, error_model="numpy")
def _srkf_update_row(Vp, Dp, xm, H, R, dz, mask, eps, tiny, sw, ew, mw, Un, Dn, dx, r, Sd):
    """``svd-srkf``'s measurement update of one row (seed 000 eqs 6 and 12-16; the numpy specification
    :meth:`.svd.SvdSquareRootKF._update_reference`) on the valid rows: ``G = L_R^T H U``, ``e = L_R^T r``
    (``L_R L_R^T = R^-1``: ``diag(1/sqrt(r))``, or ``C^-1`` of the Cholesky factor ``R = C C^T``), the SVD
    ``[G ; D^-1] = W diag(s) V^T`` (eq 12), ``U <- U V`` (eq 13), ``D <- 1/s`` (eq 14), ``K r = U D^2 (G V)^T e``
    (eqs 15-16), and the NIS as the least-squares cost at its minimum. Outputs and return as
    :func:`_kf_update_row`; ``tiny`` the dtype's smallest normal number (the floor of D before it is inverted)."""
    X, d, f, Vt, Mv, wk, perm = sw
    idx, HU, rv, e, G, Vpost = mw[0], mw[4], mw[6], mw[7], mw[9], mw[11]
    Dinv, y, h, dxu = mw[12], mw[13], mw[14], mw[15]
    n = Dp.shape[0]
    mv = _valid_rows(H, dz, mask, xm, Vp, mw, r, Sd)
    for t in range(mv):  # diag(S) = sum_i (H U D)_ti^2 + R_tt
        acc = 0.0
        for i in range(n):
            a = HU[t, i] * Dp[i]
            acc += a * a
        Sd[idx[t]] = acc + R[idx[t], idx[t]]
    for i in range(n):
        dx[i] = 0.0
    if mv == 0:
        _no_update(Vp, Dp, Un, Dn)
        return True, 0.0
    if _valid_block_diagonal(R, idx, mv):
        for t in range(mv):
            w = 1.0 / np.sqrt(R[idx[t], idx[t]])
            e[t] = rv[t] * w
            for i in range(n):
                G[t, i] = HU[t, i] * w
    else:  # R = C C^T, L_R^T = C^-1 (eq 6): forward substitution
        C = ew[0]
        for a in range(mv):
            for b in range(a + 1):
                C[a, b] = R[idx[a], idx[b]]
        if not cholesky_inplace(C[:mv, :mv], 0.0):
            return False, 0.0
        for t in range(mv):
            acc = rv[t]
            for i in range(n):
                G[t, i] = HU[t, i]
            for p in range(t):
                c = C[t, p]
                acc -= c * e[p]
                for i in range(n):
                    G[t, i] -= c * G[p, i]
            e[t] = acc / C[t, t]
            for i in range(n):
                G[t, i] /= C[t, t]
    top = 0.0
    for i in range(n):
        top = max(top, Dp[i])
    floor = max(eps * eps * top, np.sqrt(tiny))
    for i in range(n):  # the pre-array [G ; D^-1], transposed (eq 12)
        Dinv[i] = 1.0 / max(Dp[i], floor)
        for t in range(mv):
            X[i, t] = G[t, i]
        for j in range(n):
            X[i, mv + j] = Dinv[i] if j == i else 0.0
    if not svd_right(X[:n], mv + n, d[:n], f[:n], Vt[:n], Mv, wk, perm, eps):
        return False, 0.0
    for i in range(n):  # h = G^T e
        h[i] = 0.0
        dxu[i] = 0.0
    for t in range(mv):
        a = e[t]
        for i in range(n):
            h[i] += a * G[t, i]
    for k in range(n):  # y = D_post^2 V^T G^T e = U_post^T K r (eqs 14-16); dx_u = V y = U_prior^T K r
        y[k] = _dot(Vt[k], h, 0, n) / (d[k] * d[k])
        for i in range(n):
            dxu[i] += y[k] * Vt[k, i]
    nis = 0.0
    for t in range(mv):  # the NIS: the pre-array least-squares residual e - G dx_u ...
        a = e[t] - _dot(G[t], dxu, 0, n)
        nis += a * a
    for i in range(n):  # ... and the prior's, dx_u / D
        a = dxu[i] * Dinv[i]
        nis += a * a
    for k in range(n):  # U_post = U V (eq 13, rows of its transpose), D_post = 1 / s (eq 14), dx = U_post y
        Dn[k] = 1.0 / d[k]
        vk = Vpost[k]
        for l in range(n):
            vk[l] = 0.0
        for i in range(n):
            a = Vt[k, i]
            for l in range(n):
                vk[l] += a * Vp[i, l]
        for l in range(n):
            Un[l, k] = vk[l]
            dx[l] += y[k] * vk[l]
    return True, nis


# --------------------------------------------------------------------------- the batch
def _svd_form_rows(mode, srkf, U, D, x, Phi, s, Q, H, R, dz, mask, eps, tiny, Un, Dn, xn, dx, r, Sd, nis, ok, nchunk):
    """Time update (``mode`` 1; 0: none) and measurement update of every batch row of an SVD form (``srkf``:
    ``svd-srkf``'s, else ``svd-kf``'s), rows in ``nchunk`` chunks (parallel in the parallel variant), each chunk
    allocating its scratch once.

    Parameters
    ----------
    U : (B, n, n), D : (B, n) the factors (``P = U diag(D)^2 U^T``); x : (B, n) the state; Phi, Q : (B, n, n) and
    s : (B, n) the square roots of the fading factors (mode 1); H : (B, m, n); R : (B, m, m); dz : (B, m); mask :
    (B, m) bool, the valid rows (the others are left out whatever they hold); eps, tiny : the dtype's round-off
    and smallest normal number. Outputs: Un, Dn the posterior factors, xn (B, n) the posterior state, dx (B, n)
    the correction ``K r``, r (B, m) the residuals ``dz - H x-`` (0 on masked rows), Sd (B, m) diag(S) (1 on
    masked rows), nis (B,), ok (B,) bool: False where the numpy path must decide (that row's outputs undefined).
    """
    B, m, n = H.shape
    dt = U.dtype
    mx = max(n, m)
    for c in nb.prange(nchunk):
        We = padded_width(mx)
        sw = (np.zeros((mx, padded_width(n + mx)), dt), np.empty(mx, dt), np.empty(mx, dt), np.zeros((mx, We), dt),
              np.empty((mx, mx), dt), np.empty(n + 2 * mx, dt), np.empty(mx, np.int64))
        ew = (np.zeros((mx, We)), np.empty(mx), np.zeros((mx, We)), np.empty(mx), np.empty(We), np.empty(We),
              np.empty(mx, np.int64))
        Wn = padded_width(n)  # Q's eigendecomposition on rows of its own padded width (the rotations' length)
        eq = (np.zeros((n, Wn)), np.empty(n), np.zeros((n, Wn)), np.empty(n), np.empty(Wn), np.empty(Wn),
              np.empty(n, np.int64))
        mw = (np.empty(m, np.int64), np.empty((m, n), np.int64), np.empty((m, n), dt), np.empty(m, np.int64),
              np.empty((m, n), dt), np.empty((m, m), dt), np.empty(m, dt), np.empty(m, dt), np.empty((m, n), dt),
              np.empty((m, n), dt), np.empty((m, n), dt), np.empty((n, n), dt), np.empty(n, dt), np.empty(n, dt),
              np.empty(n, dt), np.empty(n, dt))
        Vp, Dp, xm, T = np.empty((n, n), dt), np.empty(n, dt), np.empty(n, dt), np.empty((n, n), dt)
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            if mode == 1:
                good = _time_row(U[b], D[b], Phi[b], s[b], Q[b], x[b], srkf, eps, sw, eq, Vp, Dp, xm, T)
            else:
                good = True
                for i in range(n):
                    Dp[i] = D[b, i]
                    xm[i] = x[b, i]
                    for l in range(n):
                        Vp[i, l] = U[b, l, i]
            q = 0.0
            if good and srkf:
                good, q = _srkf_update_row(Vp, Dp, xm, H[b], R[b], dz[b], mask[b], eps, tiny, sw, ew, mw, Un[b],
                                           Dn[b], dx[b], r[b], Sd[b])
            elif good:
                good, q = _kf_update_row(Vp, Dp, xm, H[b], R[b], dz[b], mask[b], eps, sw, ew, mw, Un[b], Dn[b], dx[b],
                                         r[b], Sd[b])
            nis[b] = q
            for i in range(n):
                xn[b, i] = xm[i] + dx[b, i]
            ok[b] = good


_svd_serial, _svd_parallel = serial_and_parallel(_svd_form_rows, error_model="numpy")


def svd_fused_update(U, D, x, H, R, dz, mask, srkf, Phi=None, Q=None, fade=None):
    """Compiled time (``Phi`` given) and measurement update of a batch of SVD factors (:func:`_svd_form_rows`).

    Parameters
    ----------
    U : (B, n, n), D : (B, n) the factors, ``P = U diag(D)^2 U^T``; x : (B, n) the error state; H : (B, m, n),
    R : (B, m, m), dz : (B, m), mask : (B, m) bool: a prepared measurement (the masked rows are left out);
    srkf : ``svd-srkf``'s update (eqs 12-16), else ``svd-kf``'s (eq 17); Phi, Q : (B, n, n) the transition and
    process noise of a time update applied first, or None; fade : None, (B,) or (B, n) fading factors
    (``diag(sqrt(fade)) Phi``). Every array in (or cast to) the dtype of ``U``.

    Returns
    -------
    (U, D, x, dx, r, diag S, nis): new arrays, the posterior factors and state, the correction ``K r``, the
    residuals ``dz - H x-`` (0 on masked rows), ``diag(S)`` (1 on masked rows) and the NIS; or None where some
    row must run the numpy path (nothing is modified).
    """
    B, m, n = H.shape
    dt = U.dtype
    c = np.ascontiguousarray
    if Phi is None:
        mode, Phi_, s, Q_ = 0, U, np.ones((B, n), dt), U
    else:
        f = np.ones((B, n)) if fade is None else np.asarray(fade, np.float64)
        s = np.empty((B, n), dt)
        s[...] = np.sqrt(f if f.ndim == 2 else f[:, None])
        mode, Phi_, Q_ = 1, c(np.broadcast_to(Phi, (B, n, n)), dt), c(np.broadcast_to(Q, (B, n, n)), dt)
    Un, Dn, xn, dx = np.empty((B, n, n), dt), np.empty((B, n), dt), np.empty((B, n), dt), np.empty((B, n), dt)
    r, Sd, nis, ok = np.empty((B, m), dt), np.empty((B, m), dt), np.zeros(B, dt), np.empty(B, bool)
    fi = np.finfo(dt)
    kern, nchunk = row_kernel(_svd_serial, _svd_parallel, B)
    kern(mode, bool(srkf), c(U, dt), c(D, dt), c(x, dt), Phi_, s, Q_, c(H, dt), c(R, dt), c(dz, dt), c(mask, bool),
         float(fi.eps), float(fi.tiny), Un, Dn, xn, dx, r, Sd, nis, ok, nchunk)
    if np.count_nonzero(ok) != B:
        return None
    return Un, Dn, xn, dx, r, Sd, nis
