"""Information-filter forms: ``if`` (information matrix and vector) and ``svd-if`` (its SVD form).

Both hold the *information* ``Y = P^-1`` and the information vector ``y = Y x``
(seed paper 000, eqs 25-28) instead of the covariance; the error-state estimate
``x`` and the covariance ``P`` are derived on demand (and cached until the next
predict / update). The shared pieces live here and are reused by the square-root
information filter (:mod:`nav_filters.forms.srif`):

* :class:`InformationForm` keeps the interface's ``x`` consistent with the
  information vector: reading ``form.x`` solves for it, assigning ``form.x``
  (as ``take_correction`` does with zeros) resets the information vector to
  ``Y x``;
* :func:`process_noise_factor` factors a positive *semi*-definite ``Q = G G^T``
  (seed 000 eq 40), so a process noise with zero rows (noise-free states) needs
  no ``Q^-1``;
* :func:`whiten_measurement` applies ``R^-1/2`` to ``H`` and ``dz`` (seed 000
  eq 41 as corrected below);
* :func:`innovation_statistics` gives NIS and ``diag(S)`` from ``H P H^T``.

Corrections to the printed equations of seed paper 000, section 4.2
-------------------------------------------------------------------
Checked by re-deriving each step from ``P- = Phi P Phi^T + Q`` (eq 30) and
``Y+ = Y- + H^T R^-1 H`` (eq 28) with ``Y = U D^2 U^T`` (eq 29):

* eq 26 (and eq 46): ``(I - A Q)^-1`` must be ``(I + A Q)^-1``
  (``Y- = (A^-1 + Q)^-1 = (I + A Q)^-1 A`` and ``y- = Y- Phi x``; scalar check:
  ``a / (1 + a q)``, not ``a / (1 - a q)``);
* eq 46 also prints ``Phi^-1`` where eq 26 has ``Phi^-T``, and defines
  ``A = Phi^-1 Y Phi^-1``: both need the transpose, ``A = Phi^-T Y Phi^-1``;
* eq 33 prints a 2x2 block matrix ``[[D^-1, U^T Phi], [D_Q, U_Q^T]]``; the
  pre-array is the 2x1 stack of products ``[D^-1 U^T Phi^T ; D_Q U_Q^T]``
  (its Gram matrix is ``Phi U D^-2 U^T Phi^T + U_Q D_Q^2 U_Q^T = P-``);
* eq 43 (the algorithm's time update) prints ``D U^T Phi``: with ``D`` the
  pre-array's Gram matrix is ``Phi^T Y Phi``, not ``P-``; it must be
  ``D^-1 U^T Phi^T`` as derived in eqs 31-33 (eqs 44-45 are then right);
* eq 41 prints ``R^-1 = D_R U_R^T H``; the factorization is
  ``R^-1 = U_R D_R^2 U_R^T``, whose square root ``D_R U_R^T`` whitens ``H``
  in eqs 36 / 47 (which are right);
* eq 50: the left side needs ``D^2`` (``U D^2 U^T x = Y x``), and the last term
  ``H^T D_R U_R^T H z`` must be ``H^T U_R D_R^2 U_R^T z = H^T R^-1 z`` (eq 27).
"""
from __future__ import annotations

import numpy as np

from .base import FilterForm, UpdateResult, symmetrize


# --------------------------------------------------------------------------- helpers
def check_transition(Phi, Q, batch_size, n, dtype):
    """Validate a batched transition and return ``Phi``, ``Q`` as ``dtype`` arrays.

    Parameters
    ----------
    Phi, Q : (B, n, n) transition and (PSD) process-noise covariance.

    Raises
    ------
    ValueError
        wrong shape or non-finite entries (names ``Phi`` or ``Q``).
    """
    out = []
    for name, a in (("Phi", Phi), ("Q", Q)):
        a = np.asarray(a, dtype)
        if a.shape != (batch_size, n, n):
            raise ValueError(f"{name} must have shape ({batch_size}, {n}, {n}), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"{name} contains non-finite values")
        out.append(a)
    return out[0], out[1]


def invert_transition(Phi):
    """``Phi^-1`` (B, n, n), ``ValueError`` naming ``Phi`` if a row's transition is singular."""
    try:
        Phi_inv = np.linalg.inv(Phi)
    except np.linalg.LinAlgError:
        raise ValueError("Phi must be invertible for the information forms (time update uses Phi^-1)") from None
    if not np.all(np.isfinite(Phi_inv)):
        raise ValueError("Phi must be invertible for the information forms (time update uses Phi^-1)")
    return Phi_inv


def process_noise_factor(Q):
    """Square-root factor ``G`` (B, n, r) with ``G G^T = Q`` for a positive semi-definite ``Q``.

    Seed paper 000, eq 40 factors ``Q = U_Q D_Q^2 U_Q^T`` (SVD = eigendecomposition
    of a symmetric PSD matrix) and uses ``G = U_Q D_Q``; every form here only needs
    *some* ``G`` with ``G G^T = Q`` (the pre-arrays' Gram matrices are what
    matter), so the cheapest sound factor is taken:

    1. the rows/columns of ``Q`` that are zero in every batch row (noise-free
       states) are dropped, so they become zero rows of ``G`` and no ``Q^-1`` is
       ever needed;
    2. a diagonal remainder gives ``G = diag(sqrt(q))`` (no decomposition);
    3. otherwise a Cholesky factor of the remainder (``r`` = number of kept
       states), and only if that is singular (a PSD ``Q`` of lower rank) the
       eigendecomposition of eq 40, ``G = U_Q D_Q`` with rounding-level negative
       eigenvalues clipped to zero.

    Parameters
    ----------
    Q : (B, n, n) symmetric positive semi-definite (same units as P).

    Raises
    ------
    ValueError
        ``Q`` has a negative diagonal entry or an eigenvalue below
        ``-sqrt(eps) * max|eigenvalue|`` (not positive semi-definite).
    """
    B, n, _ = Q.shape
    idx = np.arange(n)
    diag = Q[:, idx, idx]
    if np.any(diag < 0):
        raise ValueError("Q must be positive semi-definite (negative diagonal entry)")
    nz = np.any(Q != 0, axis=0)
    keep = np.flatnonzero(nz.any(0) | nz.any(1))
    r = keep.size
    G = np.zeros((B, n, r), Q.dtype)
    if r == 0:
        return G
    Qk = Q[:, keep][:, :, keep]
    off = Qk.copy()
    off[:, np.arange(r), np.arange(r)] = 0
    if not np.any(off):
        G[:, keep, np.arange(r)] = np.sqrt(diag[:, keep])
        return G
    Qk = symmetrize(Qk)
    try:
        G[:, keep] = np.linalg.cholesky(Qk)
        return G
    except np.linalg.LinAlgError:
        pass
    lam, V = np.linalg.eigh(Qk)
    scale = np.max(np.abs(lam), axis=-1, keepdims=True)
    if np.any(lam < -np.sqrt(np.finfo(Q.dtype).eps) * scale):
        raise ValueError("Q must be positive semi-definite (it has a clearly negative eigenvalue)")
    G[:, keep] = V * np.sqrt(np.maximum(lam, 0))[:, None, :]
    return G


def whiten_measurement(dz, H, R):
    """Whitened measurement ``R^-1/2 dz``, ``R^-1/2 H`` (seed 000 eq 41 corrected; seed 002 sec 4(3)).

    With ``R = L L^T`` (Cholesky; ``L = diag(sqrt(r))`` for a diagonal ``R``)
    the whitened rows ``L^-1 H`` have unit noise, so ``(L^-1 H)^T (L^-1 H) =
    H^T R^-1 H``. Masked rows (``H = 0``, ``dz = 0``, ``R = 1``) stay zero.

    Parameters
    ----------
    dz : (B, m); H : (B, m, n); R : (B, m, m) prepared by :func:`~nav_filters.forms.base.prepare_measurement`.

    Returns
    -------
    dz_w : (B, m); H_w : (B, m, n)
    """
    m = R.shape[-1]
    idx = np.arange(m)
    off = R.copy()
    off[:, idx, idx] = 0
    if not np.any(off):
        w = 1.0 / np.sqrt(R[:, idx, idx])
        return dz * w, H * w[..., None]
    L = np.linalg.cholesky(R)
    sol = np.linalg.solve(L, np.concatenate([dz[..., None], H], axis=-1))
    return sol[..., 0], sol[..., 1:]


def innovation_statistics(HPHt, R, r):
    """NIS ``r^T S^-1 r`` and ``diag(S)`` of ``S = H P H^T + R`` (one Cholesky factorization of S).

    Parameters
    ----------
    HPHt, R : (B, m, m); r : (B, m) innovations ``dz - H x``.

    Returns
    -------
    nis : (B,); s_diag : (B, m)
    """
    S = symmetrize(HPHt) + R
    L = np.linalg.cholesky(S)
    w = np.linalg.solve(L, r[..., None])[..., 0]
    return np.sum(w * w, axis=-1), np.diagonal(S, axis1=1, axis2=2).copy()


def cholesky_or_raise(P0, name="P0"):
    """Lower Cholesky factor of (B, n, n) ``P0``; ``ValueError`` naming it if not positive definite."""
    try:
        return np.linalg.cholesky(P0)
    except np.linalg.LinAlgError:
        raise ValueError(f"{name} must be positive definite for the information forms") from None


def update_result(nis, mask, r, s_diag):
    """The :class:`UpdateResult` of an update on prepared rows ``mask`` (B, m)."""
    n_used = mask.sum(-1)
    return UpdateResult(nis=nis, n_used=n_used, innovation=r, innovation_var=s_diag, applied=n_used > 0)


# --------------------------------------------------------------------------- shared base
class InformationForm(FilterForm):
    """Base of the forms whose state is information; ``x`` is derived from it.

    Subclasses implement ``_solve_state()`` (the (B, n) estimate from the stored
    information) and ``_set_state(x)`` (reset the information vector so that it
    encodes ``x``, and cache ``x`` with :meth:`_keep_x` when reading it back
    would return it), and call :meth:`_changed` after every predict / update.

    ``form.x`` is computed on first access after a change and cached *read-only*
    (writing into it could not reach the information vector); assign
    ``form.x = ...`` instead, which resets the information vector.
    :meth:`take_correction` returns a writable copy and resets the information
    vector to zero.
    """

    _ready = False

    @property
    def x(self) -> np.ndarray:
        if self._x is None:
            x = self._solve_state()
            x.flags.writeable = False
            self._x = x
        return self._x

    @x.setter
    def x(self, value):
        value = np.array(value, dtype=self.dtype)
        value.flags.writeable = False
        if self._ready:
            self._set_state(value)
        else:
            self._x = value  # holds x0 until _init_uncertainty has run

    def _keep_x(self, x):
        """Cache ``x`` (read-only) as the current estimate after ``_set_state`` encoded it exactly."""
        x = np.asarray(x)
        x.flags.writeable = False
        self._x = x

    def _changed(self):
        """Drop the derived quantities (x, covariance, factor views) after a state change."""
        self._x = None
        self._cache = {}

    def replace_rows(self, rows, other) -> None:
        """Copy batch rows from ``other`` (base-class behaviour), then drop the derived caches of all rows.

        The cached x / covariance / factor views are derived from the information arrays, so they
        are recomputed from the copied rows instead of being copied or left stale.
        """
        super().replace_rows(rows, other)
        self._changed()

    _ROW_COPY_SKIP = frozenset({"_cache"})

    def copy_rows(self, dst, src) -> None:
        """Copy rows ``src`` to ``dst`` (base-class behaviour, the cached x included), then drop the other
        derived caches (covariance, factor views), which are recomputed from the copied information."""
        super().copy_rows(dst, src)
        self._cache = {}

    def take_correction(self) -> np.ndarray:
        x = np.array(self.x)
        self.x = np.zeros_like(x)
        return x

    def _solve_state(self):  # pragma: no cover - abstract
        raise NotImplementedError

    def _set_state(self, x):  # pragma: no cover - abstract
        raise NotImplementedError


# --------------------------------------------------------------------------- if
class InformationFilter(InformationForm):
    """``if``: information matrix ``Y = P^-1`` and information vector ``y = Y x``.

    Time update (seed 000 eqs 25-26, in the symmetric Joseph-like form; ``eq 26``
    with its sign corrected, see the module docstring). With
    ``M = Phi^-T Y Phi^-1`` (the paper's ``A``) and ``Q = G G^T``
    (:func:`process_noise_factor`, so a singular ``Q`` is fine):

    ``J = M G (I_r + G^T M G)^-1``,  ``L = I - J G^T = (I + M Q)^-1``,
    ``Y- = L M L^T + J J^T``  (= ``M - J G^T M``, eq 25 by Woodbury with
    ``Q^-1`` replaced by ``I_r`` in the factored noise space),
    ``y- = L Phi^-T y``      (eq 26, corrected).

    The sum of two PSD terms keeps ``Y-`` symmetric positive semi-definite
    whatever the rounding, where the subtraction ``M - J G^T M`` can lose it
    when ``Q`` dominates; ``I_r + G^T M G`` has eigenvalues >= 1, so its solve
    is well conditioned even for zero information (``M = 0`` gives ``Y- = 0``).

    Measurement update (eqs 27-28): ``Y+ = Y- + H^T R^-1 H``,
    ``y+ = y- + H^T R^-1 dz`` with the model ``dz = H x + v``.

    Derived: ``x = Y^-1 y`` and ``P = Y^-1`` by a Cholesky factorization of
    ``Y`` (LU fallback if rounding made ``Y`` indefinite, so the navigator can
    flag the row instead of crashing). NIS and ``diag(S)`` come from
    ``H P- H^T = C^T C`` with ``C = L_Y^-1 H^T`` (same factorization).

    Accuracy: every derived quantity goes through an inversion of ``Y``, so its
    relative error is ~ ``cond(Y) * eps`` (Cholesky is insensitive to the
    diagonal scaling of the state, so this is the condition number of the
    correlation structure, not of the units).
    """

    name = "if"

    def _init_uncertainty(self, P0):
        x0 = self._x
        Linv = np.linalg.inv(cholesky_or_raise(P0))
        self.Y = symmetrize(Linv.mT @ Linv)
        self._changed()
        self._set_state(x0)
        self._ready = True

    # -- derived ------------------------------------------------------------------
    def _chol_inv(self):
        """Cached ``L_Y^-1`` (B, n, n) with ``Y = L_Y L_Y^T``, or None if Y is not positive definite."""
        if "Linv" not in self._cache:
            try:
                self._cache["Linv"] = np.linalg.inv(np.linalg.cholesky(self.Y))
            except np.linalg.LinAlgError:
                self._cache["Linv"] = None
        return self._cache["Linv"]

    def _solve_state(self):
        Linv = self._chol_inv()
        if Linv is None:
            return np.linalg.solve(self.Y, self.y[..., None])[..., 0]
        return (Linv.mT @ (Linv @ self.y[..., None]))[..., 0]

    def _set_state(self, x):
        self.y = (self.Y @ x[..., None])[..., 0]
        self._keep_x(x)

    @property
    def covariance(self):
        if "P" not in self._cache:
            Linv = self._chol_inv()
            self._cache["P"] = symmetrize(np.linalg.inv(self.Y) if Linv is None else Linv.mT @ Linv)
        return self._cache["P"]

    # -- recursion ----------------------------------------------------------------
    def predict(self, Phi, Q):
        """Information time update (seed 000 eqs 25-26 corrected; see the class docstring)."""
        Phi, Q = check_transition(Phi, Q, self.batch_size, self.n, self.dtype)
        Phi_inv = invert_transition(Phi)
        G = process_noise_factor(Q)
        M = symmetrize(Phi_inv.mT @ self.Y @ Phi_inv)
        u = (Phi_inv.mT @ self.y[..., None])[..., 0]
        if G.shape[-1] == 0:
            self.Y, self.y = M, u
        else:
            MG = M @ G
            S = G.mT @ MG
            r = S.shape[-1]
            S[:, np.arange(r), np.arange(r)] += 1
            J = MG @ np.linalg.inv(S)  # S = I + G^T M G is SPD with eigenvalues >= 1: inverse well conditioned
            L = -(J @ G.mT)
            L[:, np.arange(self.n), np.arange(self.n)] += 1
            self.Y = symmetrize(L @ M @ L.mT + J @ J.mT)
            self.y = (L @ u[..., None])[..., 0]
        self._changed()

    def _update(self, dz, H, R, mask):
        """Information measurement update (seed 000 eqs 27-28)."""
        Linv = self._chol_inv()
        if Linv is not None:
            x = (Linv.mT @ (Linv @ self.y[..., None]))[..., 0]
            C = Linv @ H.mT
            HPHt = C.mT @ C
        else:  # Y lost definiteness to rounding: LU solves, S's Cholesky then tells the navigator
            x = np.linalg.solve(self.Y, self.y[..., None])[..., 0]
            HPHt = H @ np.linalg.solve(self.Y, H.mT)
        r = dz - (H @ x[..., None])[..., 0]
        nis, s_diag = innovation_statistics(HPHt, R, r)
        dz_w, H_w = whiten_measurement(dz, H, R)
        self.Y = symmetrize(self.Y + H_w.mT @ H_w)
        self.y = self.y + (H_w.mT @ dz_w[..., None])[..., 0]
        self._changed()
        return update_result(nis, mask, r, s_diag)


# --------------------------------------------------------------------------- svd-if
class SvdInformationFilter(InformationForm):
    """``svd-if``: the information matrix in SVD factors, ``Y = U D^2 U^T`` (seed 000 eq 29), and ``y = Y x``.

    Stored: ``U`` (B, n, n) orthogonal, ``D`` (B, n) > 0, ``y`` (B, n). The
    covariance is ``P = U D^-2 U^T`` (eq 32) and ``x = U D^-2 U^T y``: no matrix
    is ever inverted, only diagonal ``D``.

    Time update, the corrected eqs 43-45 (module docstring): with
    ``Q = U_Q D_Q^2 U_Q^T`` (eq 40), the thin SVD

    ``[D^-1 U^T Phi^T ; D_Q U_Q^T] = U* [D* ; 0] V*^T``   (2n x n pre-array)

    gives ``P- = V* D*^2 V*^T``, hence ``U- = V*`` (eq 44), ``D- = D*^-1``
    (eq 45). The information vector (eq 46, corrected to
    ``y- = (I + A Q)^-1 Phi^-T y``) is evaluated as the identical
    ``y- = Y- Phi x = U- D-^2 U-^T Phi (U D^-2 U^T y)``, which needs neither
    ``Phi^-1`` nor a solve with ``I + A Q``.

    Measurement update, eqs 47-49 with ``R^-1/2`` the whitening factor
    (eq 41 corrected): the thin SVD

    ``[D- U-^T ; R^-1/2 H] = U* [D* ; 0] V*^T``   ((n + m) x n pre-array)

    gives ``Y+ = V* D*^2 V*^T``: ``U+ = V*`` (eq 48), ``D+ = D*`` (eq 49), and
    ``y+ = y- + H^T R^-1 dz`` (eq 50 corrected).
    """

    name = "svd-if"

    def _init_uncertainty(self, P0):
        x0 = self._x
        cholesky_or_raise(P0)  # positive definiteness, with a clear error
        lam, V = np.linalg.eigh(P0)  # P0 = V diag(lam) V^T  =>  Y0 = V diag(1/lam) V^T (eq 39)
        self.U = V
        self.D = 1.0 / np.sqrt(lam)
        self._changed()
        self._set_state(x0)
        self._ready = True

    def _solve_state(self):
        Uty = (self.U.mT @ self.y[..., None])[..., 0]
        return (self.U @ (Uty / self.D ** 2)[..., None])[..., 0]

    def _set_state(self, x):
        Utx = (self.U.mT @ x[..., None])[..., 0]
        self.y = (self.U @ (Utx * self.D ** 2)[..., None])[..., 0]
        self._keep_x(x)

    @property
    def covariance(self):
        if "P" not in self._cache:
            S = self.U / self.D[:, None, :]
            self._cache["P"] = symmetrize(S @ S.mT)
        return self._cache["P"]

    def predict(self, Phi, Q):
        """SVD-IF time update (seed 000 eqs 43-46, corrected; see the class docstring)."""
        Phi, Q = check_transition(Phi, Q, self.batch_size, self.n, self.dtype)
        G = process_noise_factor(Q)  # G^T = D_Q U_Q^T
        x_pred = (Phi @ self.x[..., None])[..., 0]
        pre = np.concatenate([(self.U.mT @ Phi.mT) / self.D[..., None], G.mT], axis=1)
        _, s, Vt = np.linalg.svd(pre, full_matrices=False)
        if not np.all(s > 0):
            raise np.linalg.LinAlgError("svd-if: predicted covariance lost rank (D- would be infinite)")
        self.U, self.D = Vt.mT, 1.0 / s
        self._changed()
        self._set_state(x_pred)

    def _update(self, dz, H, R, mask):
        """SVD-IF measurement update (seed 000 eqs 47-50, corrected)."""
        x = self.x
        C = (self.U.mT @ H.mT) / self.D[..., None]  # D^-1 U^T H^T, so H P H^T = C^T C
        r = dz - (H @ x[..., None])[..., 0]
        nis, s_diag = innovation_statistics(C.mT @ C, R, r)
        dz_w, H_w = whiten_measurement(dz, H, R)
        pre = np.concatenate([self.D[..., None] * self.U.mT, H_w], axis=1)
        _, s, Vt = np.linalg.svd(pre, full_matrices=False)
        self.U, self.D = Vt.mT, s
        self.y = self.y + (H_w.mT @ dz_w[..., None])[..., 0]
        self._changed()
        return update_result(nis, mask, r, s_diag)
