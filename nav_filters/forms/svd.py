"""SVD-based Kalman-filter forms: ``svd-srkf`` and ``svd-kf``.

Both forms keep the covariance only through its singular value decomposition

    ``P = U diag(D)^2 U^T``,  U (B, n, n) orthogonal,  D (B, n) >= 0 (singular values of the square root),

so that P is symmetric positive semi-definite *by construction*, whatever the
word length (seed paper 000, eq 4). Every factor is refreshed by a batched thin
SVD (``np.linalg.svd(..., full_matrices=False)``) of a stacked "pre-array" ``A``
with ``A^T A`` equal to the wanted covariance (or its inverse): with
``A = W diag(s) V^T``, ``A^T A = V diag(s)^2 V^T``, so V and s are the new U and D.
The left factor W is never used.

``svd-srkf`` (:class:`SvdSquareRootKF`)
    Wang, Libert & Manneback (1992), as in seed paper 000 eqs 4-16: the time
    update factors ``Phi P Phi^T + Q`` (eqs 9-11, Q by Cholesky, eq 7), the
    measurement update factors the posterior *information* matrix
    ``P^-1 + H^T R^-1 H`` (eqs 12-14, ``R^-1 = L_R L_R^T`` eq 6), the gain is
    ``K = U D^2 U^T H^T R^-1`` (eq 15).
``svd-kf`` (:class:`SvdKalmanFilter`)
    Kulikova & Tsyganova (2017), IET Control Theory Appl. 11(15), summarized in
    seed paper 000 eq 17: Q and R are factored by their SVD (no Cholesky), the
    innovation covariance ``S = H P H^T + R`` is factored by an SVD of its
    pre-array, the gain follows from those factors, and the posterior factors
    come from an SVD of the factored Joseph form, eq 17.

Time update (both forms, seed 000 eqs 8-11): with a square root ``Q = L_Q L_Q^T``
the pre-array is ``[D U^T Phi^T ; L_Q^T]`` (2n x n). (Eq 9 of the seed paper
prints ``D U^T Phi``; the transpose of Phi is what makes ``A^T A = Phi P Phi^T + Q``.)

Notes
-----
* Q may be only positive *semi*-definite (zero rows for states with no process
  noise). ``svd-srkf`` tries the Cholesky factor (eq 7) and, when it fails, falls
  back to the SVD factor ``U_Q diag(sqrt(s_Q))``, which is also an exact ``L_Q``
  with ``L_Q L_Q^T = Q``. A diagonal Q (checked cheaply: counting non-zeros) is
  factored by ``sqrt`` of its diagonal, a Q broadcast over the batch (stride 0)
  is factored once, and an unchanged Q (compared by value) reuses its factor.
  Negative eigenvalues beyond round-off (their magnitudes summing to more than
  ``10 n eps max(s_Q)``) raise ``ValueError`` naming ``Q``.
* The SVD of a symmetric PSD matrix (Q, R, P0) is its eigendecomposition; it is
  computed with ``np.linalg.svd`` and validated by ``sum(s) - trace = 2 sum|lambda_-|``
  (see :func:`_sym_svd_factor`).
* The square root of ``R^-1`` in ``svd-srkf`` (eq 6) is ``L_R = C^-T`` where
  ``R = C C^T`` is the Cholesky factor of R: ``L_R L_R^T = R^-1`` exactly, without
  forming ``R^-1``. A diagonal R (detected by counting non-zeros) uses
  ``L_R = diag(1/sqrt(r))``.
"""
from __future__ import annotations

import numpy as np

from .base import FilterForm, UpdateResult, symmetrize
from .svd_rows import svd_fused_update

_PSD_TOL = 10.0  # negative eigenvalues summing to at most _PSD_TOL * n * eps * max|lambda| count as round-off


# --------------------------------------------------------------------------- helpers
def _batched_base(M, B, n, name, dtype):
    """Validate a (B, n, n) (or broadcastable (n, n) / (1, n, n)) matrix and return its distinct rows.

    Returns
    -------
    (B or 1, n, n) array in ``dtype``: a stride-0 broadcast over the batch (one Q for all rows) is
    collapsed to its single row, so it is validated and factored once.

    Raises
    ------
    ValueError
        wrong shape or non-finite entries (names ``name``).
    """
    M = np.asarray(M)
    if M.ndim == 2:
        M = M[None]
    if M.ndim != 3 or M.shape[1:] != (n, n) or M.shape[0] not in (1, B):
        raise ValueError(f"{name} must have shape ({B}, {n}, {n}), got {M.shape}")
    if M.shape[0] > 1 and M.strides[0] == 0:
        M = M[:1]
    M = M.astype(dtype, copy=False)
    if not np.all(np.isfinite(M)):
        raise ValueError(f"{name} contains non-finite values")
    return M


def _is_diagonal(M) -> bool:
    """True when every off-diagonal entry of the (..., n, n) matrices is zero (one pass, no copy of M)."""
    return np.count_nonzero(M) == np.count_nonzero(np.diagonal(M, axis1=-2, axis2=-1))


def _check_diagonal(d, name):
    """``ValueError`` naming ``name`` if a variance of the diagonal (B', k) is negative beyond round-off;
    returns ``d`` with the round-off negatives clipped to 0."""
    eps = np.finfo(d.dtype).eps
    scale = np.max(np.abs(d), axis=-1, keepdims=True)
    bad = d < -_PSD_TOL * d.shape[-1] * eps * scale
    if bad.any():
        b, j = np.argwhere(bad)[0]
        raise ValueError(f"{name} must be positive semi-definite: batch row {b} has diagonal entry {j} = "
                         f"{float(d[b, j]):.3e}")
    return np.maximum(d, 0)


def _sym_svd_factor(M, name):
    """SVD of a symmetric PSD matrix, ``M = U_M diag(s) U_M^T``, validated.

    Used for Q and R by ``svd-kf`` (Kulikova & Tsyganova 2017: "SVD of Q and R instead of Cholesky", seed
    000 sec 4.1 item 1), for P0 (seed 000 eq 4) and as ``svd-srkf``'s fallback square root of a PSD Q whose
    Cholesky factorization fails. Computed by ``np.linalg.svd`` (LAPACK gesdd): for a symmetric PSD matrix
    the SVD is the eigendecomposition (and gesdd avoids the multi-threaded slowdown of numpy's batched
    ``eigh`` for k >= 26 seen with OpenBLAS on a loaded machine).

    Validation without eigenvalues: for symmetric M, ``sum(s) - trace(M) = 2 * sum |negative eigenvalues|``
    (the nuclear norm is the sum of ``|lambda|``, the trace the sum of ``lambda``), so an indefinite M is
    recognized whatever the multiplicity of its singular values.

    Parameters
    ----------
    M : (B', k, k) symmetric.
    name : argument name for the error message.

    Returns
    -------
    U_M : (B', k, k) orthogonal; s : (B', k) singular values = eigenvalues (>= 0).

    Raises
    ------
    ValueError
        the negative eigenvalues of a row sum to more than ``10 k eps max(s)`` in magnitude.
    """
    U, s, _ = np.linalg.svd(M)
    neg = 0.5 * (np.sum(s, -1) - np.trace(M, axis1=-2, axis2=-1))
    tol = _PSD_TOL * M.shape[-1] * np.finfo(M.dtype).eps * np.max(s, -1)
    bad = neg > tol
    if bad.any():
        b = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} must be symmetric positive semi-definite: in batch row {b} its negative "
                         f"eigenvalues sum to {-float(neg[b]):.3e} (largest singular value {float(s[b].max()):.3e})")
    return U, s


def _sqrt_factor_rows(M, name, cholesky_first):
    """Transposed square root ``L^T`` (rows of the pre-array) of a symmetric PSD matrix, ``L L^T = M``.

    Parameters
    ----------
    M : (B', k, k) symmetric PSD (B' = 1 for a matrix shared by the batch).
    name : argument name for the error message.
    cholesky_first : try ``np.linalg.cholesky`` first (seed 000 eq 7, ``svd-srkf``); otherwise, and when
        Cholesky fails (a PSD but singular M), use the SVD factor ``U_M diag(sqrt(s))`` (Kulikova &
        Tsyganova 2017, ``svd-kf``).

    Returns
    -------
    (B', k', k) ``L^T``. Rows/columns of M that are zero in every batch row are left out before the
    factorization (so a PSD Q whose only singular part is the zero rows of noise-free states still has a
    Cholesky factor), and for a diagonal M only the rows of non-zero variances are kept: k' <= k, the
    dropped rows would add nothing to ``A^T A``.
    """
    if _is_diagonal(M):
        d = _check_diagonal(np.diagonal(M, axis1=-2, axis2=-1), name)
        keep = np.flatnonzero(np.any(d > 0, axis=0))
        k = M.shape[-1]
        Lt = np.zeros(M.shape[:-2] + (keep.size, k), M.dtype)
        Lt[..., np.arange(keep.size), keep] = np.sqrt(d[..., keep])
        return Lt
    k = M.shape[-1]
    nz = np.flatnonzero(np.any(M != 0, axis=(0, -1)))  # states with process noise in some batch row
    if nz.size < k:  # zero rows/columns (clock states without noise): factor the non-zero block only
        sub = _sqrt_factor_rows(M[:, nz][:, :, nz], name, cholesky_first)
        Lt = np.zeros(sub.shape[:-1] + (k,), M.dtype)
        Lt[..., nz] = sub
        return Lt
    if cholesky_first:
        try:
            return np.linalg.cholesky(M).mT
        except np.linalg.LinAlgError:
            pass
    U, d = _sym_svd_factor(M, name)
    return np.sqrt(d)[..., :, None] * U.mT


def svd_time_update(U, D, Phi, LQt):
    """SVD time update of the covariance factors (seed 000 eqs 9-11; Wang, Libert & Manneback 1992).

    Pre-array ``A = [D U^T Phi^T ; L_Q^T]`` ((n + k) x n) with ``A^T A = Phi P Phi^T + Q``; its thin SVD
    ``A = W diag(s) V^T`` gives the predicted factors ``U <- V`` (eq 10), ``D <- s`` (eq 11).

    Parameters
    ----------
    U : (B, n, n), D : (B, n) current factors, ``P = U diag(D)^2 U^T``.
    Phi : (B, n, n) transition; LQt : (B or 1, k, n) ``L_Q^T`` with ``L_Q L_Q^T = Q``.

    Returns
    -------
    U, D : (B, n, n), (B, n) predicted factors.
    """
    B, n = D.shape
    k = LQt.shape[-2]
    A = np.empty((B, n + k, n), D.dtype)
    np.matmul(U.mT, Phi.mT, out=A[:, :n])
    A[:, :n] *= D[:, :, None]
    A[:, n:] = LQt
    _, s, Vt = np.linalg.svd(A, full_matrices=False)
    return Vt.mT, s


def innovation_variance(M, R):
    """Diagonal of ``S = H P H^T + R`` from ``M = D U^T H^T`` (B, n, m): ``sum_i M_ij^2 + R_jj``, (B, m)."""
    return np.sum(M * M, axis=-2) + np.diagonal(R, axis1=-2, axis2=-1)


# --------------------------------------------------------------------------- base of both forms
class _SvdForm(FilterForm):
    """Shared state of the SVD forms: factors ``U`` (B, n, n), ``D`` (B, n) with ``P = U D^2 U^T``."""

    name = "svd-base"
    _cholesky_q = False  # factor Q by Cholesky first (svd-srkf, eq 7) or by its SVD (svd-kf)
    HAS_FUSED = True
    """The fused path (:meth:`FilterForm.set_fused`): the time and measurement updates of :mod:`.svd_rows`."""

    def _init_uncertainty(self, P0):
        """Seed 000 eq 4: ``P0 = U D^2 U^T`` (SVD of the symmetric PSD P0); ``ValueError`` naming P0 if indefinite."""
        U, lam = _sym_svd_factor(P0, "P0")
        self.U = U
        self.D = np.sqrt(lam)
        self.last_correction = np.zeros_like(self.x)
        self._q_cache = None  # (Q, L_Q^T) of the last predict: a cache keyed by the value of Q, not row state
        self._p_cache = None  # (U, D, P): the covariance of these factors (:attr:`covariance`)

    @property
    def covariance(self):
        """(B, n, n) ``P = (U D)(U D)^T``, symmetric PSD by construction.

        Formed once per state: kept with the factor arrays it came from, and formed again when ``U`` or ``D`` is
        another array (every update and :meth:`copy_rows` assign new ones) or after :meth:`replace_rows` (which
        writes rows of them in place). An adaptive law's step reads it three or four times (the plan, the commit,
        the feedback), each of which formed it before. Callers must not write into it (nor into any form's).
        """
        c = self._p_cache
        if c is not None and c[0] is self.U and c[1] is self.D:
            return c[2]
        UD = self.U * self.D[:, None, :]
        P = symmetrize(UD @ UD.mT)
        self._p_cache = (self.U, self.D, P)
        return P

    def replace_rows(self, rows, other) -> None:
        """:meth:`FilterForm.replace_rows`, then the covariance of the old rows dropped (formed again on access)."""
        super().replace_rows(rows, other)
        self._p_cache = None

    def predict(self, Phi, Q):
        """Time update ``x <- Phi x`` (seed 000 eq 8) and the SVD factor update, eqs 9-11.

        Parameters
        ----------
        Phi : (B, n, n) finite transition matrix.
        Q : (B, n, n) symmetric positive semi-definite process noise (a (n, n) or stride-0 broadcast Q is
            factored once for the whole batch).

        Raises
        ------
        ValueError
            non-finite Phi or Q, wrong shapes, or Q with a negative eigenvalue beyond round-off.
        """
        B, n = self.batch_size, self.n
        Phi = np.broadcast_to(_batched_base(Phi, B, n, "Phi", self.dtype), (B, n, n))
        LQt = self._q_factor(_batched_base(Q, B, n, "Q", self.dtype))
        self.x = (Phi @ self.x[..., None])[..., 0]
        self.U, self.D = svd_time_update(self.U, self.D, Phi, LQt)

    def _q_factor(self, Qb):
        """``L_Q^T`` of the (B or 1, n, n) process noise, reused while Q is unchanged (compared by value).

        A caller that passes the same constant Q at every step pays one comparison instead of a factorization
        (eq 7, or the SVD of Q for ``svd-kf``); a Q changed in place is detected by the comparison.
        """
        cache = self._q_cache
        if cache is not None and cache[0].shape == Qb.shape and np.array_equal(cache[0], Qb):
            return cache[1]
        LQt = _sqrt_factor_rows(symmetrize(Qb), "Q", cholesky_first=self._cholesky_q)
        self._q_cache = (Qb.copy(), LQt)
        return LQt

    def _update(self, dz, H, R, mask):
        """Measurement update on prepared arrays: the compiled :func:`~.svd_rows.svd_fused_update` on the fused
        path (where it decides every row), else the numpy recursion (:meth:`_update_reference`)."""
        if self.fused:
            out = svd_fused_update(self.U, self.D, self.x, H, R, dz, mask, self._cholesky_q)
            if out is not None:
                return self._commit_fused(out, mask)
        return self._update_reference(dz, H, R, mask)

    def _predicted_update(self, Phi, Q, dz, H, R, mask, fade=None, prior=None):
        """:meth:`FilterForm.predicted_update` on prepared arrays. Fused path: the time update (eqs 8-11, Q's square
        root formed per row) and the measurement update in one compiled call (:func:`~.svd_rows.svd_fused_update`;
        ``prior`` is not needed); where it leaves a row to numpy, the numpy predict and update, committing nothing
        if they raise (an adaptive law retries a failed epoch). Off: the generic predict, then update."""
        if not self.fused:
            return super()._predicted_update(Phi, Q, dz, H, R, mask, fade, prior)
        B, n = self.batch_size, self.n
        Phi = _batched_base(Phi, B, n, "Phi", self.dtype)
        Q = _batched_base(Q, B, n, "Q", self.dtype)
        out = svd_fused_update(self.U, self.D, self.x, H, R, dz, mask, self._cholesky_q, Phi=Phi, Q=Q, fade=fade)
        if out is not None:
            return self._commit_fused(out, mask)
        saved = self.x, self.U, self.D, self.last_correction
        try:
            if fade is not None:
                f = np.asarray(fade, np.float64)
                Phi = np.sqrt(f if f.ndim == 2 else f[:, None]).astype(self.dtype)[:, :, None] * Phi
            self.predict(Phi, Q)
            return self._update_reference(dz, H, R, mask)
        except Exception:
            self.x, self.U, self.D, self.last_correction = saved
            raise

    def _commit_fused(self, out, mask):
        """Commit the outputs of :func:`~.svd_rows.svd_fused_update` and pack the :class:`UpdateResult`."""
        self.U, self.D, self.x, self.last_correction, r, ivar, nis = out
        n_used = mask.sum(-1)
        return UpdateResult(nis=nis, n_used=n_used, innovation=r, innovation_var=ivar, applied=n_used > 0)

    def _finish(self, r, dx, nis, ivar, mask):
        """Apply the state correction ``dx = K r`` and pack the :class:`UpdateResult`."""
        self.x = self.x + dx
        self.last_correction = dx
        n_used = mask.sum(-1)
        return UpdateResult(nis=nis, n_used=n_used, innovation=r, innovation_var=ivar, applied=n_used > 0)


# --------------------------------------------------------------------------- svd-srkf
class SvdSquareRootKF(_SvdForm):
    """``svd-srkf``: SVD-based square-root KF of Wang, Libert & Manneback (1992), seed 000 eqs 4-16.

    State: error-state estimate ``x`` (B, n) and the factors ``U`` (B, n, n), ``D`` (B, n) of
    ``P = U diag(D)^2 U^T``. The measurement update works on the information matrix
    ``P^-1 = U D^-2 U^T``; a singular value of exactly 0 (a state known perfectly) is floored at
    ``eps^2 max(D)`` (or ``sqrt(tiny)``) before it is inverted, so the update stays finite.

    Attributes
    ----------
    U, D : covariance factors. last_correction : (B, n) ``K (dz - H x)`` of the last update
        (seed 000 eq 16's increment, the ``K dz`` of eq 19).
    """

    name = "svd-srkf"
    _cholesky_q = True

    def _update_reference(self, dz, H, R, mask):
        """Measurement update, seed 000 eqs 6 and 12-16 (numpy specification of the fused path's
        :func:`~.svd_rows._srkf_update_row`).

        With ``L_R L_R^T = R^-1`` (eq 6), ``G = L_R^T H U`` (m x n) and ``e = L_R^T r`` (whitened residual
        ``r = dz - H x``), the pre-array ``[G ; D^-1]`` ((m + n) x n) has SVD ``W diag(s) V^T`` (eq 12);
        the posterior factors are ``U <- U V`` (eq 13), ``D <- 1/s`` (eq 14). The gain of eq 15 is applied to
        the residual without forming K: ``K r = U D^2 U^T H^T L_R L_R^T r = U D^2 (G V)^T e`` (eq 16).

        NIS is the Bayesian least-squares cost at its minimum,
        ``r^T S^-1 r = |e - G dx_u|^2 + |dx_u / D_prior|^2`` with ``dx_u = U_prior^T K r`` (the residual of
        the pre-array least-squares problem; no inverse of S, and no difference of squared norms).

        Parameters/returns: see :meth:`FilterForm.update` (arrays already prepared).
        """
        B, m = dz.shape
        dt = self.dtype
        U, D = self.U, self.D
        r = dz - (H @ self.x[..., None])[..., 0]
        HU = H @ U  # (B, m, n)
        if _is_diagonal(R):
            w = 1 / np.sqrt(np.diagonal(R, axis1=1, axis2=2))  # L_R^T = diag(1/sqrt(r))
            G = HU * w[..., None]
            e = r * w
        else:
            try:
                C = np.linalg.cholesky(R)  # R = C C^T, L_R = C^-T  =>  L_R L_R^T = R^-1 (eq 6)
            except np.linalg.LinAlgError:
                raise ValueError("R must be symmetric positive definite on the valid rows") from None
            Ci = np.linalg.inv(C)  # lower triangular L_R^T
            G = Ci @ HU
            e = (Ci @ r[..., None])[..., 0]
        eps = np.finfo(dt).eps
        floor = np.maximum(eps * eps * D.max(-1, keepdims=True), np.sqrt(np.finfo(dt).tiny))
        Dinv = 1 / np.maximum(D, floor)
        n = self.n
        A = np.zeros((B, m + n, n), dt)
        A[:, :m] = G
        A[:, m + np.arange(n), np.arange(n)] = Dinv
        _, s, Vt = np.linalg.svd(A, full_matrices=False)  # eq 12
        V = Vt.mT
        D_post = 1 / s  # eq 14
        GV = G @ V  # L_R^T H U_post
        y = D_post**2 * (GV.mT @ e[..., None])[..., 0]  # U_post^T K r
        dxu = (V @ y[..., None])[..., 0]  # U_prior^T K r
        self.U = U @ V  # eq 13
        self.D = D_post
        dx = (self.U @ y[..., None])[..., 0]  # eqs 15-16
        post_res = e - (GV @ y[..., None])[..., 0]
        nis = np.sum(post_res**2, -1) + np.sum((dxu * Dinv) ** 2, -1)
        ivar = innovation_variance((HU * D[:, None, :]).mT, R)
        return self._finish(r, dx, nis, ivar, mask)


# --------------------------------------------------------------------------- svd-kf
class SvdKalmanFilter(_SvdForm):
    """``svd-kf``: SVD-based KF of Kulikova & Tsyganova (2017), seed 000 sec 4.1 and eq 17.

    Q and R are factored by their SVD (``R = U_R D_R U_R^T``), never by Cholesky; the posterior
    covariance factors come from the factored Joseph form (eq 17), so P stays symmetric PSD.

    Attributes
    ----------
    U, D : covariance factors. last_correction : (B, n) ``K (dz - H x)`` of the last update.
    """

    name = "svd-kf"
    _cholesky_q = False

    def _update_reference(self, dz, H, R, mask):
        """Measurement update (Kulikova & Tsyganova 2017, IET CTA 11(15); seed 000 eq 17); numpy specification of
        the fused path's :func:`~.svd_rows._kf_update_row`.

        1. ``R = U_R D_R U_R^T`` (SVD); innovation pre-array ``[D_R^{1/2} U_R^T ; D U^T H^T]`` ((m + n) x m)
           with SVD ``W diag(sig) V_S^T``, so ``S = H P H^T + R = V_S diag(sig)^2 V_S^T``.
        2. Gain ``K = P H^T S^-1 = U D M V_S diag(sig)^-2 V_S^T`` with ``M = D U^T H^T`` (n x m).
        3. Posterior pre-array of the Joseph form (eq 17)
           ``[D U^T (I - K H)^T ; D_R^{1/2} U_R^T K^T]`` ((n + m) x n), whose Gram matrix is
           ``(I-KH) P (I-KH)^T + K R K^T``; its SVD gives ``U <- V``, ``D <- s``.

        NIS ``= |diag(sig)^-1 V_S^T r|^2`` from the innovation factors (no inverse of S);
        ``innovation_var = diag(S)``.
        """
        B, m = dz.shape
        dt = self.dtype
        n = self.n
        U, D = self.U, self.D
        r = dz - (H @ self.x[..., None])[..., 0]
        M = D[:, :, None] * (U.mT @ H.mT)  # (B, n, m) = D U^T H^T
        A = np.empty((B, m + n, m), dt)
        diagonal_R = _is_diagonal(R)
        if diagonal_R:
            sqrt_r = np.sqrt(np.diagonal(R, axis1=1, axis2=2))  # U_R = I, D_R^{1/2} = sqrt(r)
            A[:, :m] = 0
            A[:, np.arange(m), np.arange(m)] = sqrt_r
        else:
            UR, dR = _sym_svd_factor(symmetrize(R), "R")
            if np.any(dR <= 0):
                raise ValueError("R must be symmetric positive definite on the valid rows")
            sqrtR_t = np.sqrt(dR)[..., :, None] * UR.mT  # D_R^{1/2} U_R^T
            A[:, :m] = sqrtR_t
        A[:, m:] = M
        _, sig, VSt = np.linalg.svd(A, full_matrices=False)  # S = V_S sig^2 V_S^T
        f = (VSt @ r[..., None])[..., 0] / sig  # whitened innovation: NIS = |f|^2
        nis = np.sum(f * f, -1)
        MV = M @ VSt.mT  # (B, n, m)
        UD = U * D[:, None, :]
        K = UD @ ((MV / (sig * sig)[:, None, :]) @ VSt)  # P H^T S^-1
        dx = (UD @ (MV @ (f / sig)[..., None]))[..., 0]  # K r
        A2 = np.empty((B, n + m, n), dt)
        np.subtract(UD.mT, M @ K.mT, out=A2[:, :n])  # D U^T (I - K H)^T
        if diagonal_R:
            np.multiply(sqrt_r[:, :, None], K.mT, out=A2[:, n:])  # D_R^{1/2} K^T
        else:
            np.matmul(sqrtR_t, K.mT, out=A2[:, n:])  # D_R^{1/2} U_R^T K^T
        _, s, Vt = np.linalg.svd(A2, full_matrices=False)  # eq 17 factored
        self.U, self.D = Vt.mT, s
        ivar = innovation_variance(M, R)
        return self._finish(r, dx, nis, ivar, mask)


__all__ = ["SvdSquareRootKF", "SvdKalmanFilter", "svd_time_update", "innovation_variance"]
