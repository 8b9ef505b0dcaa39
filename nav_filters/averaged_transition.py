"""Transition and process noise of one GNSS epoch from the *averaged* error dynamics (the fast alternative to
composing them at every IMU sample).

The navigator's default (``NavigatorConfig.exact_transition=True``) composes, at every IMU sample ``i`` of
interval ``h``, ``Phi_i = I + F_i h`` and ``Q_i = G Q_c G^T h`` into ``Phi_acc = Phi_n ... Phi_1`` and
``Q_acc = Phi_n (... (Phi_1 0 Phi_1^T + Q_1) ...) Phi_n^T + Q_n``: two 17 x 17 (sparse-by-dense) products
per sample for ``Phi`` and three for ``Q``, most of the cost of an env step.

With ``exact_transition=False`` the kernel only *integrates* the error dynamics over the samples pending
before a predict (one GNSS epoch, ``T = n h``; the mechanization itself still runs at every sample)::

    A   = sum_i F_i h        ~  int_0^T F(t) dt          (= Fbar T, Fbar the average F)
    S   = sum_i G_i Q_c G_i^T h  ~  int_0^T G Q_c G^T dt  (= Qbar_c T)

and forms, once per epoch, the transition and process noise of the *constant* system with that average
(Fbar, Qbar_c) over ``T``: the exponential and the Van Loan integral, as power series
(Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed., sec 3.2.3:
``Phi = exp(F T)`` and ``Q_d = int_0^T Phi(s) G Q_c G^T Phi(s)^T ds`` for constant F)::

    Phi = exp(A)            = sum_{k=0..K} A^k / k!
    Q   = int_0^T e^{Fbar s} Qbar_c e^{Fbar^T s} ds
        = sum_{k=0..K} N_k / (k + 1)!,   N_0 = S,   N_k = A N_{k-1} + N_{k-1} A^T

(the second because ``d/ds (e^{Fs} X e^{F^T s}) = F (.) + (.) F^T``: the k-th derivative at 0 is
``L^k(X)`` with ``L(X) = F X + X F^T``, and ``T^{k+1} L^k(Qbar_c) = L_A^k(S)``). Neither needs ``T``:
only the two integrals. Computed with the scaled terms ``A^k / k!`` and ``N_k / (k + 1)!`` (each one
sparse-by-dense product with the fixed non-zero pattern of F), ``Q`` exactly symmetric.

Order: F is nearly nilpotent (the chain gyro bias -> attitude -> velocity -> position has length 3; every
longer product carries an Earth-rate ``7.3e-5 /s``, Schuler ``1.2e-3 /s`` or bias-decay ``1/tau`` factor),
so the terms fall off fast after ``k = 3``: with :data:`SERIES_ORDER` ``= 8`` the truncation is at the level
of float64 round-off for ``T`` up to 5 s on the built-in scenarios (measured against ``scipy.linalg.expm``
and Van Loan's block exponential: max |Phi error| 1.3e-15 at ``T = 1`` s, 1.4e-13 at 5 s); ``K = 2``
would drop the whole position <- gyro-bias block (``[a x] C T^3 / 6``, about 1.4 m per rad/s at 1 g).

What is approximated, compared with the per-sample composition:

* the time variation of F inside the epoch (attitude ``C``, specific force ``C f``, gravity gradient):
  replacing ``prod_i exp(F_i h)`` by ``exp(sum_i F_i h)`` drops the commutator terms (Magnus expansion,
  second term ``1/2 int int [F(t1), F(t2)]``), which grow with the turn rate and jerk over the epoch;
* the per-sample Euler step of the default itself: for constant F the composition is ``(I + F h)^n``,
  not ``exp(F T)``; they differ by ``O(h / T)`` relative in the second- and third-order blocks (e.g. position
  <- attitude ``[a x] T^2 / 2 (1 - 1/n)``: 1% at n = 100), a difference that vanishes as ``h -> 0``
  (``tests/nav_filters/test_averaged_transition.py``). The mechanization integrates position by the
  trapezoid rule, whose error propagation is the exponential's, not the Euler product's.

Measured effect (``benchmarks/bench_envs.py --accuracy``, 24 paired episodes per scenario): the horizontal
RMSE of ``sage-husa``, ``stkf`` and ``ma-stkf`` within 0.2% of the exact composition's on every built-in
scenario, the matched-scenario ANEES unchanged; on ``urban`` with GNSS at 0.5, 0.2 and 0.1 Hz (epochs of
2-10 s, turns inside an epoch) ``kf`` and ``sage-husa`` stayed within 0.4%.

:func:`averaged_transition` is the numpy specification; :func:`averaged_transition_into` the compiled
kernel the navigator runs (checked against it in the tests).
"""
from __future__ import annotations

import numba as nb
import numpy as np

from .kernels import F_NONZERO, N, padded_width, row_kernel, serial_and_parallel

SERIES_ORDER = 8
"""Highest power ``K`` of the series for ``exp(A)`` and the Van Loan integral (see the module docstring)."""


def averaged_transition(F_int, Qc_int, order: int = SERIES_ORDER):
    """Transition and process noise of the constant system with the averaged dynamics (numpy specification).

    Parameters
    ----------
    F_int : (B, 17, 17) ``A = int F dt`` over the interval [dimensionless and mixed SI units].
    Qc_int : (B, 17, 17) symmetric ``S = int G Q_c G^T dt`` over the interval (the summed per-sample
        process noise ``sum_i Q_i`` of seed paper 001's one-step prediction).
    order : highest power ``K`` of the series (>= 1).

    Returns
    -------
    Phi : (B, 17, 17) ``sum_{k<=K} A^k / k!``.
    Q : (B, 17, 17) ``sum_{k<=K} N_k / (k+1)!``, ``N_0 = (S + S^T) / 2``, ``N_k = A N_{k-1} + N_{k-1} A^T``;
        exactly symmetric.
        Both in the floating dtype of ``F_int`` (float64 for integer input).
    """
    A = np.asarray(F_int)
    if not np.issubdtype(A.dtype, np.floating):
        A = A.astype(np.float64)
    S = np.asarray(Qc_int, dtype=A.dtype)
    if A.ndim != 3 or A.shape[1:] != (N, N):
        raise ValueError(f"F_int must have shape (B, {N}, {N}), got {A.shape}")
    if S.shape != A.shape:
        raise ValueError(f"Qc_int must have the shape of F_int {A.shape}, got {S.shape}")
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)) or order < 1:
        raise ValueError(f"order must be an int >= 1, got {order!r}")
    Phi = np.broadcast_to(np.eye(N, dtype=A.dtype), A.shape).copy()
    term = Phi.copy()
    M = 0.5 * (S + S.mT)
    Q = M.copy()
    for k in range(1, order + 1):
        term = (A @ term) / k                     # A^k / k!
        Phi += term
        X = A @ M
        M = (X + X.mT) / (k + 1)                  # N_k / (k + 1)!
        Q += M
    return Phi, Q


@nb.njit(cache=True, inline="always")
def _pattern_product_add(av, ia, ja, src, out):
    """``out += A src`` over whole rows, ``A`` the sparse matrix with the values ``av`` at rows ``ia``, columns
    ``ja`` (in that order: the same sums as over all columns with the zeros skipped)."""
    for p in range(av.shape[0]):
        a = av[p]
        o = out[ia[p]]
        x = src[ja[p]]
        for c in range(o.shape[0]):
            o[c] += a * x[c]


def _averaged_transition_into(A, S, Phi, Q, order, nz, nchunk):
    """Compiled :func:`averaged_transition` for every row: writes ``Phi`` and ``Q`` (B, 17, 17), float64.

    ``A`` must be zero outside the pattern ``nz`` (:data:`~nav_filters.kernels.F_NONZERO`): the products
    ``A X`` use only those entries (what the propagation kernel integrates has that pattern).

    The rows run in ``nchunk`` chunks, each with its scratch allocated once. The scratch rows are padded with
    zeros (:func:`~nav_filters.kernels.padded_width`) and the row loops run over the padded width, a run-time
    length read from the array's shape (LLVM fully unrolls constant 17-trip loops and leaves them scalar: numba
    runs no SLP vectorizer); the whole-matrix passes run as one loop over the flat rows (``n w`` long); each of
    the two products loops over the pattern on its own, with the pattern and the row's values read once (faster than
    one loop updating both products and 2-D element passes, the same bits: ``bench_envs.py --compare``). ``1/k``
    multiplies instead of dividing. The same series as the specification, to round-off."""
    B, n = A.shape[0], A.shape[1]
    w = padded_width(n)
    L = n * w
    nnz = nz.shape[0]
    for ch in nb.prange(nchunk):
        term = np.zeros((n, w))   # A^k / k!
        nxt = np.zeros((n, w))
        M = np.zeros((n, w))      # N_k / (k + 1)!
        X = np.zeros((n, w))
        P = np.zeros((n, w))      # the sums
        Qs = np.zeros((n, w))
        # flat views for the whole-matrix passes (one loop of n w: LLVM's widest vector body, little remainder)
        tf = term.ravel()
        nf = nxt.ravel()
        Mf = M.ravel()
        Xf = X.ravel()
        Pf = P.ravel()
        Qf = Qs.ravel()
        ia = np.empty(nnz, np.int64)  # the pattern's rows, columns and this row's values, read once per row
        ja = np.empty(nnz, np.int64)
        av = np.empty(nnz)
        for p in range(nnz):
            ia[p] = nz[p, 0]
            ja[p] = nz[p, 1]
        for b in range(ch * B // nchunk, (ch + 1) * B // nchunk):
            for p in range(nnz):
                av[p] = A[b, ia[p], ja[p]]
            for i in range(n):
                for j in range(n):
                    term[i, j] = 0.0
                    P[i, j] = 0.0
                    m = 0.5 * (S[b, i, j] + S[b, j, i])
                    M[i, j] = m
                    Qs[i, j] = m
                term[i, i] = 1.0
                P[i, i] = 1.0
            for k in range(1, order + 1):
                for q in range(L):
                    nf[q] = 0.0
                    Xf[q] = 0.0
                # the two sparse-by-dense products, each its own loop over the pattern
                _pattern_product_add(av, ia, ja, term, nxt)
                _pattern_product_add(av, ia, ja, M, X)
                rk = 1.0 / k
                for q in range(L):
                    t = nf[q] * rk
                    tf[q] = t
                    Pf[q] += t
                rk1 = 1.0 / (k + 1)
                for i in range(n):
                    for c in range(n):
                        M[i, c] = (X[i, c] + X[c, i]) * rk1   # exactly symmetric
                for q in range(L):
                    Qf[q] += Mf[q]
            for i in range(n):
                for j in range(n):
                    Phi[b, i, j] = P[i, j]
                    Q[b, i, j] = Qs[i, j]


_serial, _parallel = serial_and_parallel(_averaged_transition_into)


def averaged_transition_into(F_int, Qc_int, Phi, Q, order: int = SERIES_ORDER, nz=F_NONZERO):
    """Compiled :func:`averaged_transition` into the float64 buffers ``Phi``, ``Q`` (B, 17, 17); parallel over
    rows from :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows. ``F_int`` (float64, C-contiguous) must vanish
    outside ``nz``."""
    kern, nchunk = row_kernel(_serial, _parallel, F_int.shape[0])
    kern(F_int, Qc_int, Phi, Q, int(order), nz, nchunk)


__all__ = ["SERIES_ORDER", "averaged_transition", "averaged_transition_into"]
