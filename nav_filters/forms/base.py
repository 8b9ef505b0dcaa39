"""The one filter interface every Kalman-filter form implements.

A *form* holds the uncertainty of a batch of B error-state filters (the
covariance P, or its SVD / Cholesky / information factors) and the error-state
estimate x, and offers three operations:

``predict(Phi, Q)``
    time update ``x <- Phi x``, ``P <- Phi P Phi^T + Q``;
``update(dz, H, R, mask)``
    measurement update with innovation ``dz = z - h(x_nominal)``, returns an
    :class:`UpdateResult` (NIS, number of rows used);
``take_correction()``
    returns x and resets it to zero (closed-loop error-state feedback).

Masked measurement rows (variable satellite counts, padded to a fixed m) are
neutralized before the form sees them: ``H = 0``, ``dz = 0``, unit variance, so
they change nothing in any form (DESIGN.md section 2).

Shapes: x (B, n), P (B, n, n), Phi and Q (B, n, n), dz (B, m), H (B, m, n),
R either (B, m) (diagonal variances) or (B, m, m), mask (B, m) bool.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..kernels import row_kernel, serial_and_parallel
from ..rows import check_row_pairs, copy_rows_generic

SUPPORTED_DTYPES = (np.float32, np.float64)


@dataclass(frozen=True)
class UpdateResult:
    """Diagnostics of one batched measurement update.

    Attributes
    ----------
    nis : (B,) normalized innovation squared ``dz^T S^-1 dz`` over the used rows.
    n_used : (B,) int, number of measurement rows used (its chi-square dof).
    innovation : (B, m) the (masked) innovations.
    innovation_var : (B, m) diagonal of ``S = H P H^T + R`` (1 on masked rows).
    applied : (B,) bool, False where a row had no measurement (or a form rejected it).
    """

    nis: np.ndarray
    n_used: np.ndarray
    innovation: np.ndarray
    innovation_var: np.ndarray
    applied: np.ndarray


def check_dtype(dtype) -> np.dtype:
    """Return ``np.dtype(dtype)`` if it is float32/float64, else ``ValueError`` naming ``dtype``."""
    dt = np.dtype(dtype)
    if dt.type not in SUPPORTED_DTYPES:
        raise ValueError(f"dtype must be float32 or float64, got {dt}")
    return dt


def prepare_measurement(dz, H, R, mask, dtype):
    """Validate a batched measurement and neutralize its masked rows.

    Compiled in one pass (:func:`_prepare_rows`) for float inputs; any problem found there (or a
    non-float input) falls back to :func:`prepare_measurement_reference`, which raises the error (or
    returns the same arrays). Same parameters, returns and errors as the reference.
    """
    dz = np.asarray(dz)
    H = np.asarray(H)
    R = np.asarray(R)
    if not (dz.ndim == 2 and H.ndim == 3 and H.shape[:2] == dz.shape and R.shape in (dz.shape, dz.shape + dz.shape[1:])
            and dz.dtype.kind == H.dtype.kind == R.dtype.kind == "f"):
        return prepare_measurement_reference(dz, H, R, mask, dtype)
    B, m = dz.shape
    mask = np.ones((B, m), bool) if mask is None else np.asarray(mask, bool)
    if mask.shape != (B, m):
        return prepare_measurement_reference(dz, H, R, mask, dtype)
    dtype = np.dtype(dtype)
    dz_o = np.empty((B, m), dtype)
    H_o = np.empty(H.shape, dtype)
    R_o = np.empty((B, m, m), dtype)
    R3 = R if R.ndim == 3 else R[:, :, None]
    kern, nchunk = row_kernel(_prepare_serial, _prepare_parallel, B)
    ok = np.empty(nchunk, np.bool_)
    kern(dz, H, R3, R.ndim == 3, mask, dz_o, H_o, R_o, ok)
    if np.count_nonzero(ok) != ok.size:  # = not ok.all(), cheaper
        return prepare_measurement_reference(dz, H, R, mask, dtype)
    return dz_o, H_o, R_o, mask


def _prepare_rows(dz, H, R3, full, mask, dz_o, H_o, R_o, ok):
    """One pass of :func:`prepare_measurement_reference` on valid input: masked rows to ``dz = 0``,
    ``H = 0``, unit variance (and zero covariances). The rows are taken in ``ok.size`` chunks (parallel in
    the parallel variant); ``ok[c]`` False (outputs undefined) where the reference would raise on a row of
    chunk c (non-finite dz / H row / variance, or a non-positive variance, on a valid row)."""
    B, m, n = H.shape
    nchunk = ok.size
    for c in nb.prange(nchunk):
        ok[c] = _prepare_chunk(dz, H, R3, full, mask, dz_o, H_o, R_o, c * B // nchunk, (c + 1) * B // nchunk)


_prepare_serial, _prepare_parallel = serial_and_parallel(_prepare_rows)


@nb.njit(cache=True)
def _prepare_chunk(dz, H, R3, full, mask, dz_o, H_o, R_o, lo, hi):
    """Rows ``lo:hi`` of :func:`_prepare_rows`; False at the first invalid value of a valid row."""
    m, n = H.shape[1], H.shape[2]
    for b in range(lo, hi):
        for i in range(m):
            v = mask[b, i]
            d = dz[b, i]
            var = R3[b, i, i] if full else R3[b, i, 0]
            if v:
                if not (np.isfinite(d) and np.isfinite(var) and var > 0):
                    return False
                dz_o[b, i] = d
                for k in range(n):
                    h = H[b, i, k]
                    if not np.isfinite(h):
                        return False
                    H_o[b, i, k] = h
            else:
                dz_o[b, i] = 0
                for k in range(n):
                    H_o[b, i, k] = 0
            for j in range(m):
                if j == i:
                    R_o[b, i, j] = var if v else 1
                elif full and v and mask[b, j]:
                    R_o[b, i, j] = R3[b, i, j]
                else:
                    R_o[b, i, j] = 0
    return True


def check_measurement_shapes(dz: np.ndarray, H: np.ndarray, R: np.ndarray, owner: str = "") -> tuple[int, int]:
    """(B, m) of a batched measurement: dz (B, m), H (B, m, n), R (B, m) variances or (B, m, m);
    ``ValueError`` naming the array (prefixed by ``owner``, e.g. ``'blocks[1] '``) otherwise."""
    if dz.ndim != 2:
        raise ValueError(f"{owner}dz must have shape (B, m), got {dz.shape}")
    B, m = dz.shape
    if H.ndim != 3 or H.shape[:2] != (B, m):
        raise ValueError(f"{owner}H must have shape (B, m, n) = ({B}, {m}, n), got {H.shape}")
    if R.shape not in ((B, m), (B, m, m)):
        raise ValueError(f"{owner}R must have shape (B, m) or (B, m, m) with B={B}, m={m}, got {R.shape}")
    return B, m


def prepare_measurement_reference(dz, H, R, mask, dtype):
    """Validate a batched measurement and neutralize its masked rows (numpy specification).

    Parameters
    ----------
    dz : (B, m) innovations; H : (B, m, n); R : (B, m) variances or (B, m, m);
    mask : (B, m) bool or None (all rows valid).

    Returns
    -------
    dz, H, R_full (B, m, m), mask — copies in ``dtype`` with masked rows set to
    ``dz = 0``, ``H = 0``, ``R = I``.

    Raises
    ------
    ValueError
        wrong shapes, or NaN/inf in a *valid* row of dz, H or R, or a
        non-positive variance on a valid row (names the argument).
    """
    dz = np.asarray(dz)
    H = np.asarray(H)
    R = np.asarray(R)
    B, m = check_measurement_shapes(dz, H, R)
    mask = np.ones((B, m), bool) if mask is None else np.asarray(mask, bool)
    if mask.shape != (B, m):
        raise ValueError(f"mask must have shape ({B}, {m}), got {mask.shape}")
    Rdiag = R if R.ndim == 2 else np.diagonal(R, axis1=1, axis2=2)
    for name, arr in (("dz", dz), ("H", H.reshape(B, m, H.shape[2])), ("R", Rdiag)):
        bad = ~np.isfinite(arr)
        if arr.ndim == 3:
            bad = bad.any(-1)
        bad &= mask
        if bad.any():
            b, j = np.argwhere(bad)[0]
            raise ValueError(f"{name} has a non-finite value on valid measurement row {j} of batch row {b}")
    if (mask & ~(Rdiag > 0)).any():
        b, j = np.argwhere(mask & ~(Rdiag > 0))[0]
        raise ValueError(f"R must be positive on valid rows; row {j} of batch row {b} has variance {Rdiag[b, j]}")
    dz = np.where(mask, dz, 0).astype(dtype)
    H = np.where(mask[..., None], H, 0).astype(dtype)
    if R.ndim == 2:
        Rf = np.zeros((B, m, m), dtype)
        idx = np.arange(m)
        Rf[:, idx, idx] = np.where(mask, R, 1)
    else:
        keep = mask[:, :, None] & mask[:, None, :]
        Rf = np.where(keep, R, 0).astype(dtype)
        idx = np.arange(m)
        Rf[:, idx, idx] = np.where(mask, Rdiag, 1)
    return dz, H, Rf, mask


def check_keys(keys, shape) -> np.ndarray | None:
    """``keys`` as a (B, m) int64 array matching ``shape`` (or None); ``ValueError`` naming ``keys`` otherwise."""
    if keys is None:
        return None
    k = np.asarray(keys)
    if k.shape != tuple(shape) or (k.size and k.dtype.kind not in "iu"):
        raise ValueError(f"keys must be an int array of shape {tuple(shape)} (one per measurement row), "
                         f"got {k.dtype} {k.shape}")
    k = k.astype(np.int64, copy=False)
    if k.size and _min_2d(k) < -1:
        raise ValueError(f"keys must be >= -1 (-1: no identity), got {int(k.min())}")
    return k


@nb.njit(cache=True)
def _min_2d(a):
    """The smallest entry of the non-empty 2-D array ``a`` (= ``a.min()``, without numpy's reduction overhead)."""
    lo = a[0, 0]
    for i in range(a.shape[0]):
        for j in range(a.shape[1]):
            if a[i, j] < lo:
                lo = a[i, j]
    return lo


def symmetrize(P):
    """``(P + P^T) / 2`` over the last two axes."""
    return 0.5 * (P + P.mT)


class FilterForm(ABC):
    """Base class of the batched Kalman-filter forms (see module docstring).

    Parameters
    ----------
    P0 : (B, n, n) initial covariance (symmetric positive definite).
    x0 : (B, n) initial error state, default zeros.
    dtype : float32 or float64 (default: the dtype of P0, or float64).
    """

    name = "base"
    _ROW_COPY_SKIP: frozenset = frozenset()
    """Attributes :meth:`copy_rows` leaves alone (caches that are not per-row state)."""
    HAS_FUSED = False
    """Whether the form has a fused compiled update (:meth:`set_fused`)."""
    fused = False
    """Whether the fused fast path is on (:meth:`set_fused`; ``NavigatorConfig.fused_update``)."""

    def __init__(self, P0, x0=None, dtype=None):
        P0 = np.asarray(P0)
        if P0.ndim != 3 or P0.shape[1] != P0.shape[2]:
            raise ValueError(f"P0 must have shape (B, n, n), got {P0.shape}")
        self.dtype = check_dtype(dtype if dtype is not None else (P0.dtype if P0.dtype.kind == "f" else np.float64))
        if not np.all(np.isfinite(P0)):
            raise ValueError("P0 contains non-finite values")
        B, n, _ = P0.shape
        self.batch_size, self.n = B, n
        x0 = np.zeros((B, n)) if x0 is None else np.asarray(x0)
        if x0.shape != (B, n):
            raise ValueError(f"x0 must have shape ({B}, {n}), got {x0.shape}")
        self.x = x0.astype(self.dtype)
        self._init_uncertainty(symmetrize(P0.astype(self.dtype)))

    # -- to implement ---------------------------------------------------------
    @abstractmethod
    def _init_uncertainty(self, P0):
        """Store the initial covariance (or its factors)."""

    @abstractmethod
    def predict(self, Phi, Q):
        """Time update with transition ``Phi`` (B, n, n) and process noise ``Q`` (B, n, n)."""

    @abstractmethod
    def _update(self, dz, H, R, mask) -> UpdateResult:
        """Measurement update on prepared (masked, validated) arrays."""

    @property
    @abstractmethod
    def covariance(self) -> np.ndarray:
        """(B, n, n) current covariance P."""

    # -- shared ---------------------------------------------------------------
    def take_prediction(self, Phi, Q):
        """:meth:`predict` with arrays the caller hands over and does not touch again (the navigator's fresh
        accumulators): a form that keeps them (an adaptive law defers its prediction) need not copy them. The
        plain forms just predict."""
        return self.predict(Phi, Q)

    def update(self, dz, H, R, mask=None, keys=None) -> UpdateResult:
        """Measurement update ``z = H x + v``, ``v ~ N(0, R)``; see :func:`prepare_measurement`.

        ``keys`` (B, m) int, optional: the identity of each measurement row (satellite and measurement
        type, :func:`nav_filters.measurements.measurement_keys`; -1 for none). The plain forms do not use
        it (validated only); the adaptive laws keep per-satellite noise estimates by it."""
        check_keys(keys, np.shape(dz))
        dz, H, R, mask = prepare_measurement(dz, H, R, mask, self.dtype)
        if H.shape[2] != self.n:
            raise ValueError(f"H must have {self.n} columns, got {H.shape[2]}")
        return self._update(dz, H, R, mask)

    def replace_rows(self, rows, other: "FilterForm") -> None:
        """Overwrite batch rows ``rows`` with the rows of ``other`` (a form of the same class, B' = len(rows)).

        Generic over every form: each per-row array attribute (leading axis B) is copied, and nested
        forms (adaptive laws wrap an inner form) recurse. Forms must therefore keep all per-row state in
        arrays with a leading batch axis (no per-batch Python scalars that differ between rows). Used by
        the environments to reset single rows of a running batch.
        """
        rows = np.asarray(rows, dtype=np.intp)
        if type(other) is not type(self):
            raise ValueError(f"cannot replace rows of a {type(self).__name__} with a {type(other).__name__}")
        if other.batch_size != rows.size:
            raise ValueError(f"other has {other.batch_size} rows, expected {rows.size}")
        for name, value in vars(self).items():
            ov = getattr(other, name, None)
            if isinstance(value, FilterForm):
                value.replace_rows(rows, ov)
            elif (isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == self.batch_size
                  and isinstance(ov, np.ndarray) and ov.shape == (rows.size,) + value.shape[1:]):
                if not value.flags.writeable:
                    value = value.copy()
                    setattr(self, name, value)
                value[rows] = ov

    def copy_rows(self, dst, src) -> None:
        """Copy the state of rows ``src`` to rows ``dst`` of this batch (exact branching; overlap allowed).

        Generic over every form, like :meth:`replace_rows`: each ndarray attribute with leading axis B and
        each dict of such arrays is copied, nested forms recurse (:func:`nav_filters.rows.copy_rows_generic`).
        Afterwards row ``dst[i]`` given the same inputs as row ``src[i]`` continues bit for bit alike.

        Parameters
        ----------
        dst, src : (n,) int row indices (equal lengths; ``ValueError`` otherwise).
        """
        dst, src = check_row_pairs(dst, src, self.batch_size)
        copy_rows_generic(self, dst, src, self.batch_size, skip=self._ROW_COPY_SKIP)

    def set_fused(self, on: bool = True) -> bool:
        """Switch the fused fast path on or off; returns whether it is on (False for a form without one).

        With it on, a form that has one (:attr:`HAS_FUSED`: ``kf``, ``svd-kf``, ``svd-srkf``) runs its time and
        measurement updates through compiled kernels that fuse what the readable numpy recursion does in several
        calls (:func:`nav_filters.forms.kf.fused_update`, :func:`nav_filters.forms.svd_rows.svd_fused_update`):
        same equations, different rounding. Off (the default),
        the form computes exactly as before. Adaptive laws pass it on to their inner form."""
        self.fused = bool(on) and self.HAS_FUSED
        return self.fused

    def predicted_update(self, Phi, Q, dz, H, R, mask=None, fade=None, prior=None) -> UpdateResult:
        """Time update then measurement update in one call: ``predict(D Phi, Q)`` then ``update(dz, H, R, mask)``
        with ``D = diag(sqrt(fade))`` (fade None, (B,) or (B, n) fading factors).

        ``prior`` (B, n, n), optional: ``sym(Phi P Phi^T)`` when the caller already has it (a form with a
        fused kernel then does not recompute it). A form with its fused path on runs both in one compiled
        kernel that commits nothing when it raises; otherwise the two calls run one after the other (a
        failing update then leaves the time update applied)."""
        dz, H, R, mask = prepare_measurement(dz, H, R, mask, self.dtype)
        if H.shape[2] != self.n:
            raise ValueError(f"H must have {self.n} columns, got {H.shape[2]}")
        return self._predicted_update(Phi, Q, dz, H, R, mask, fade, prior)

    def _predicted_update(self, Phi, Q, dz, H, R, mask, fade=None, prior=None) -> UpdateResult:
        """:meth:`predicted_update` on prepared arrays (masked rows neutral); generic: predict, then update."""
        if fade is not None:
            f = np.asarray(fade, np.float64)
            Phi = np.sqrt(f if f.ndim == 2 else f[:, None]).astype(self.dtype)[:, :, None] * np.asarray(Phi, self.dtype)
        self.predict(Phi, Q)
        return self._update(dz, H, R, mask)

    def take_correction(self) -> np.ndarray:
        """Return the error-state estimate (B, n) and reset it to zero (closed-loop feedback)."""
        x = self.x
        self.x = np.zeros(x.shape, x.dtype)
        return x
