"""Square-root information filter ``srif`` (seed paper 002, section 4), batched QR, may start from zero information.

State: an upper-triangular square-root information matrix ``R_inf`` (B, n, n)
with ``Y = P^-1 = R_inf^T R_inf`` (seed 002 writes ``I = xi xi^T``, i.e.
``R_inf = xi^T``) and the square-root information vector ``z = R_inf x`` (B, n).
The estimate solves ``R_inf x = z``; ``P = R_inf^-1 R_inf^-T``.

Zero information (``P0 = infinity``, seed 002 sec 4(3), last paragraph) is
allowed in two ways:

* ``SquareRootInformationFilter(P0)`` with ``np.inf`` on the diagonal of
  ``P0`` for the states with no prior information (their off-diagonal entries
  must be 0): those rows of ``R_inf`` start at zero. This also works through
  ``make_form`` and the navigator.
* :meth:`SquareRootInformationFilter.from_information` ``(R0, z0)`` with any
  square root ``R0`` of the prior information (``np.zeros((B, n, n))`` for
  none at all).

While a row's information is singular:

* ``covariance``: for a state ``i`` that the information does not determine
  (``e_i`` not in the row space of ``R_inf``, i.e. the variance of ``x_i`` is
  infinite), ``P[i, i] = inf`` and ``P[i, j] = P[j, i] = 0`` for ``j != i``;
  the entries among determined states are ``e_i^T Y^+ e_j``, the limit of a
  covariance filter started from ``P0 = s I`` as ``s -> infinity``. Never NaN.
* ``x``: the minimum-norm least-squares solution of ``R_inf x = z`` in
  column-equilibrated coordinates (determined states get their unique value;
  the components of undetermined states carry no information);
* ``UpdateResult.innovation_var`` is ``inf`` on rows that see an undetermined
  direction, and ``nis`` is the least-squares residual ``||e||^2`` of the QR
  (below), whose dof is then smaller than ``n_used``.

Rank decisions are made on the column-equilibrated ``R_inf`` (invariant to the
units of the states): a row is treated as full rank when every
``|R_ii| > rank_rtol * ||R[:, i]||``; otherwise its numerical rank comes from the
singular values of the equilibrated matrix (``s > rank_rtol * s_max``) and a
state counts as undetermined when its unit vector has a null-space component
above ``sqrt(eps)``.
"""
from __future__ import annotations

import numpy as np

from .base import check_dtype, symmetrize
from .information import (InformationForm, check_transition, cholesky_or_raise, invert_transition,
                          process_noise_factor, update_result, whiten_measurement)


class SquareRootInformationFilter(InformationForm):
    """``srif``: Bierman-style square-root information filter by batched Householder QR.

    Time update (seed 002 eq 13 in array form; Bierman's SRIF time update):
    with ``Q = G G^T`` (:func:`~nav_filters.forms.information.process_noise_factor`,
    ``w ~ N(0, I_r)``, so zero-noise states are zero rows of ``G`` and no
    ``Q^-1`` is needed; eq 13's ``Gamma`` and ``Q^-1`` become ``G`` and ``I_r``),
    substitute ``x_k = Phi^-1 (x_{k+1} - G w)`` into ``R_inf x_k = z`` and
    triangularize the data equations of ``(w, x_{k+1})``::

        [ I_r                   0               | 0 ]          [ *  *    | * ]
        [ -R_inf Phi^-1 G    R_inf Phi^-1       | z ]  = Q_h * [ 0  R_-  | z_- ]

    so that ``R_-^T R_- = M - M G (G^T M G + I_r)^-1 G^T M`` with
    ``M = Phi^-T Y Phi^-1``: eq 13, whose printed second term carries a stray
    ``I_{k-1} Phi^-1`` (``M I_{k-1} Phi^-1 Gamma`` instead of ``M Gamma``; the
    printed product is not even dimensionally an information matrix).

    Measurement update (seed 002 sec 4(3); the text's ``R_k^-1 H_k`` must be
    the whitened ``R_k^-1/2 H_k`` for the Gram matrix to be ``H^T R^-1 H``)::

        [ R_inf      z        ]          [ R_+  z_+ ]
        [ R^-1/2 H   R^-1/2 dz]  = Q_h * [ 0    e   ]

    where ``e^2`` is the whitened least-squares residual: with a nonsingular
    prior it equals the innovation NIS ``(dz - H x)^T S^-1 (dz - H x)``.
    Both start from zero information (``R_inf = 0``) without any special case.

    Parameters
    ----------
    P0 : (B, n, n) initial covariance; ``np.inf`` on the diagonal means zero information for that
        state (its row and column must otherwise be 0).
    x0 : (B, n) initial estimate (default 0); its components on zero-information states are ignored.
    dtype : float32 or float64.
    """

    name = "srif"

    def __init__(self, P0, x0=None, dtype=None):
        P0 = np.asarray(P0)
        self._free0 = None
        if P0.ndim == 3 and P0.shape[1] == P0.shape[2] and P0.dtype.kind == "f":
            n = P0.shape[1]
            idx = np.arange(n)
            free = np.isposinf(P0[:, idx, idx])
            if free.any():
                cross = (free[:, :, None] | free[:, None, :]) & ~np.eye(n, dtype=bool)
                if np.any(P0[cross] != 0):
                    raise ValueError("P0: a state with infinite variance (zero information) must have zero "
                                     "covariance with every other state")
                P0 = np.where(free[:, :, None] | free[:, None, :], np.eye(n), P0)
                self._free0 = free
        super().__init__(P0, x0=x0, dtype=dtype)

    @property
    def rank_rtol(self) -> float:
        """Relative tolerance of the rank decisions: ``100 n eps`` of the dtype."""
        return 100 * self.n * float(np.finfo(self.dtype).eps)

    def _init_uncertainty(self, P0):
        x0 = self._x
        # P0 = U U^T with U upper triangular (Cholesky of the index-reversed matrix), so
        # Y0 = U^-T U^-1 and R_inf = U^-1 is upper triangular: no QR needed.
        U = cholesky_or_raise(P0[:, ::-1, ::-1])[:, ::-1, ::-1]
        R = np.triu(np.linalg.inv(U))
        if self._free0 is not None:
            # R_inf is the unique positive-diagonal factor of the block-diagonal Y0, so the placeholder
            # rows of the zero-information states are unit rows: zero them.
            R = np.where(self._free0[:, :, None], 0, R)
        self.R_inf = R
        self._changed()
        self._set_state(x0)
        self._ready = True

    @classmethod
    def from_information(cls, R0, z0=None, dtype=None) -> "SquareRootInformationFilter":
        """Start from a square root of the prior information, ``Y0 = R0^T R0``, and ``z0 = R0 x0``.

        Parameters
        ----------
        R0 : (B, n, n) any square root of the prior information (triangularized here by QR);
            ``np.zeros((B, n, n))`` means no prior information at all (``P0 = infinity``).
        z0 : (B, n) prior square-root information vector (default 0).
        dtype : float32 or float64 (default: R0's float dtype, else float64).
        """
        R0 = np.asarray(R0)
        if R0.ndim != 3 or R0.shape[1] != R0.shape[2]:
            raise ValueError(f"R0 must have shape (B, n, n), got {R0.shape}")
        dt = check_dtype(dtype if dtype is not None else (R0.dtype if R0.dtype.kind == "f" else np.float64))
        if not np.all(np.isfinite(R0)):
            raise ValueError("R0 contains non-finite values")
        B, n, _ = R0.shape
        z0 = np.zeros((B, n)) if z0 is None else np.asarray(z0)
        if z0.shape != (B, n):
            raise ValueError(f"z0 must have shape ({B}, {n}), got {z0.shape}")
        if not np.all(np.isfinite(z0)):
            raise ValueError("z0 contains non-finite values")
        self = cls.__new__(cls)
        self.dtype, self.batch_size, self.n = dt, B, n
        self._free0 = None
        T = np.linalg.qr(np.concatenate([R0, z0[..., None]], axis=-1).astype(dt), mode="r")
        self.R_inf, self.z = np.triu(T[..., :n]), T[..., n]
        self._changed()
        self._ready = True
        return self

    # -- derived ------------------------------------------------------------------
    def _views(self):
        """Cached factor views of the current ``R_inf`` (see the module docstring for the rank rules).

        Returns a dict: ``full`` (B,) bool; ``Rinv`` (B, n, n) ``R_inf^-1`` on full-rank rows (0 elsewhere);
        for the rank-deficient rows ``rows`` (K,) indices, ``c`` (K, n) column scales, ``U``, ``Vt``
        (K, n, n) and ``sinv`` (K, n) of the SVD of ``R_inf diag(1/c)`` (``1/s`` on the numerical range,
        0 on the null space), ``null`` (K, n, n) null-space projector and ``unobs`` (K, n) bool.
        """
        v = self._cache.get("views")
        if v is not None:
            return v
        R, n, dt = self.R_inf, self.n, self.dtype
        tol = self.rank_rtol
        c = np.linalg.norm(R, axis=1)
        d = np.abs(np.diagonal(R, axis1=1, axis2=2))
        full = np.all(d > tol * c, axis=1) & np.all(c > 0, axis=1)
        Rinv = np.zeros_like(R)
        if full.any():
            Rinv[full] = np.triu(np.linalg.inv(R[full]))
        v = {"full": full, "Rinv": Rinv}
        rows = np.flatnonzero(~full)
        if rows.size:
            cs = np.where(c[rows] > 0, c[rows], 1).astype(dt)
            U, s, Vt = np.linalg.svd(R[rows] / cs[:, None, :])
            rng = s > tol * s[:, :1]
            sinv = np.where(rng, 1 / np.where(rng, s, 1), 0).astype(dt)
            Vn = np.where(~rng[..., None], Vt, 0)          # null-space rows of V^T
            null = Vn.mT @ Vn                               # projector onto the null space
            unobs = np.sqrt(np.maximum(np.diagonal(null, axis1=1, axis2=2), 0)) > np.sqrt(np.finfo(dt).eps)
            v.update(rows=rows, c=cs, U=U, Vt=Vt, sinv=sinv, null=null, unobs=unobs)
        self._cache["views"] = v
        return v

    def _solve_state(self):
        v = self._views()
        x = (v["Rinv"] @ self.z[..., None])[..., 0]
        if "rows" in v:
            rows = v["rows"]
            # x_s = V S^+ U^T z in equilibrated coordinates x_s = c * x
            xs = (v["Vt"].mT @ (v["sinv"] * (v["U"].mT @ self.z[rows][..., None])[..., 0])[..., None])[..., 0]
            x[rows] = xs / v["c"]
        return x

    def _set_state(self, x):
        self.z = (self.R_inf @ x[..., None])[..., 0]
        if self._views()["full"].all():  # else x is re-solved: its undetermined components are not kept
            self._keep_x(x)
        else:
            self._x = None

    @property
    def covariance(self):
        """(B, n, n) ``R_inf^-1 R_inf^-T``; ``inf`` diagonal / zero cross terms on undetermined states."""
        P = self._cache.get("P")
        if P is not None:
            return P
        v = self._views()
        P = symmetrize(v["Rinv"] @ v["Rinv"].mT)
        if "rows" in v:
            W = v["Vt"].mT * v["sinv"][:, None, :]          # V S^+
            Pd = (W @ W.mT) / (v["c"][:, :, None] * v["c"][:, None, :])
            un = v["unobs"]
            Pd = np.where(un[:, :, None] | un[:, None, :], 0, Pd)
            idx = np.arange(self.n)
            Pd[:, idx, idx] = np.where(un, np.inf, Pd[:, idx, idx])
            P[v["rows"]] = symmetrize(Pd)
        self._cache["P"] = P
        return P

    def _hpht_diag(self, H):
        """(B, m) ``diag(H P H^T)`` of the current state; ``inf`` where a row of H sees an undetermined direction."""
        v = self._views()
        C = H @ v["Rinv"]
        out = np.sum(C * C, axis=-1)
        if "rows" in v:
            rows = v["rows"]
            Hs = H[rows] / v["c"][:, None, :]
            A = (Hs @ v["Vt"].mT) * v["sinv"][:, None, :]   # H_s V S^+
            hp = np.sum(A * A, axis=-1)
            leak = np.linalg.norm(Hs @ v["null"], axis=-1)
            unseen = leak > np.sqrt(np.finfo(self.dtype).eps) * np.linalg.norm(Hs, axis=-1)
            out[rows] = np.where(unseen, np.inf, hp)
        return out

    # -- recursion ----------------------------------------------------------------
    def predict(self, Phi, Q):
        """SRIF time update by QR (seed 002 eq 13, array form; see the class docstring)."""
        Phi, Q = check_transition(Phi, Q, self.batch_size, self.n, self.dtype)
        Phi_inv = invert_transition(Phi)
        G = process_noise_factor(Q)
        B, n, r = G.shape
        RPi = self.R_inf @ Phi_inv
        A = np.zeros((B, r + n, r + n + 1), self.dtype)
        A[:, np.arange(r), np.arange(r)] = 1
        A[:, r:, :r] = -(RPi @ G)
        A[:, r:, r:r + n] = RPi
        A[:, r:, r + n] = self.z
        T = np.linalg.qr(A, mode="r")
        self.R_inf, self.z = np.triu(T[:, r:, r:r + n]), T[:, r:, r + n].copy()
        self._changed()

    def _update(self, dz, H, R, mask):
        """SRIF measurement update by QR of the whitened data equations (seed 002 sec 4(3))."""
        n = self.n
        x = self.x
        r = dz - (H @ x[..., None])[..., 0]
        s_diag = self._hpht_diag(H) + np.diagonal(R, axis1=1, axis2=2)
        dz_w, H_w = whiten_measurement(dz, H, R)
        A = np.concatenate([np.concatenate([self.R_inf, self.z[..., None]], axis=-1),
                            np.concatenate([H_w, dz_w[..., None]], axis=-1)], axis=1)
        T = np.linalg.qr(A, mode="r")  # (B, n + 1, n + 1): m >= 1 rows are guaranteed by prepare_measurement
        nis = T[:, n, n] ** 2
        self.R_inf, self.z = np.triu(T[:, :n, :n]), T[:, :n, n].copy()
        self._changed()
        return update_result(nis, mask, r, s_diag)
