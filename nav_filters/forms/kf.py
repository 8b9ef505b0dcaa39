"""Conventional error-state Kalman filter with the Joseph-form update (``kf``).

The reference form: every other form of the family must reproduce its state and
covariance in float64 (seed paper 000, eqs 5-8 for the standard recursion).

Speed: :meth:`KalmanFilter._update` runs the Joseph update in one compiled
(numba) call per batch, :func:`joseph_update` (Cholesky of S, two triangular
solves for the gain, structural zeros of H and R skipped; parallel over rows for
B >= 64). :meth:`KalmanFilter._update_reference` is the same recursion in numpy
(the readable specification); ``tests/nav_filters/test_kf_form.py`` asserts
their agreement.

Fused path (``set_fused(True)``, ``NavigatorConfig.fused_update``): :func:`fused_update`
runs the time update and the Joseph update in one kernel over row chunks, with the
masked rows left out and ``K H`` formed on H's non-zero columns only (an adaptive law
hands it its deferred prediction and the prior it formed: :meth:`KalmanFilter.predicted_update`).
Same equations, different rounding; ``tests/nav_filters/test_fused_update.py`` checks
it against ``predict`` + :meth:`KalmanFilter._update_reference`.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels import PARALLEL_MIN_BATCH  # noqa: F401  (imported from here by tests)
from ..kernels import padded_width, row_chunks, row_kernel, row_nonzeros as _row_nonzeros, serial_and_parallel
from .base import FilterForm, UpdateResult, symmetrize


def innovation_covariance(P, H, R):
    """``S = H P H^T + R`` and ``P H^T``; shapes (B, m, m), (B, n, m)."""
    PHt = P @ H.mT
    return H @ PHt + R, PHt


def nis_and_gain(S, PHt, dz):
    """Gain ``K = P H^T S^-1`` and NIS ``dz^T S^-1 dz`` by one Cholesky factorization of S.

    Returns
    -------
    K : (B, n, m); nis : (B,)
    """
    L = np.linalg.cholesky(S)
    # S^-1 = L^-T L^-1; solve with the (small) batched triangular factor.
    Linv = np.linalg.inv(L)
    Sinv = Linv.mT @ Linv
    K = PHt @ Sinv
    w = Linv @ dz[..., None]
    nis = np.sum(w[..., 0] ** 2, axis=-1)
    return K, nis


@nb.njit(cache=True, error_model="numpy")
def _residual_and_hp(dz_i, nzc_row, nzv_row, cnt, x, P, hp_row):
    """One measurement row: ``hp_row += h P`` (n,) over h's non-zeros (:func:`_row_nonzeros`); returns the
    residual ``dz_i - h x``."""
    s = dz_i
    for t in range(cnt):
        l = nzc_row[t]
        h = nzv_row[t]
        s -= h * x[l]
        for k in range(hp_row.shape[0]):
            hp_row[k] += h * P[l, k]
    return s


@nb.njit(cache=True, error_model="numpy")
def _cholesky_lower(L, m):
    """``S = L L^T`` in place on the lower triangle of ``L[:m, :m]`` (which holds S); False at the first pivot
    that is not positive (the rest of L is then undefined)."""
    for j in range(m):
        d = L[j, j]
        for p in range(j):
            d -= L[j, p] * L[j, p]
        if not d > 0:
            return False
        d = np.sqrt(d)
        L[j, j] = d
        for i in range(j + 1, m):
            s = L[i, j]
            for p in range(j):
                s -= L[i, p] * L[j, p]
            L[i, j] = s / d
    return True


@nb.njit(cache=True, error_model="numpy")
def _gain_solve(L, r, HP, Y, w, m, n):
    """With ``S = L L^T`` (:func:`_cholesky_lower`, first m rows): ``w = L^-1 r``, ``Y = L^-1 HP`` (forward), then
    ``Y <- L^-T Y = S^-1 H P = K^T`` (backward, in place). Returns the NIS ``w^T w = r^T S^-1 r``.
    ``r`` (>= m,), ``HP`` / ``Y`` (>= m, n), ``w`` (>= m,) scratch."""
    q = 0.0
    for i in range(m):
        s = r[i]
        for p in range(i):
            s -= L[i, p] * w[p]
        w[i] = s / L[i, i]
        q += w[i] * w[i]
        for k in range(n):
            Y[i, k] = HP[i, k]
        for p in range(i):
            lip = L[i, p]
            if lip != 0:
                for k in range(n):
                    Y[i, k] -= lip * Y[p, k]
        for k in range(n):
            Y[i, k] /= L[i, i]
    for i in range(m - 1, -1, -1):
        for p in range(i + 1, m):
            lpi = L[p, i]
            if lpi != 0:
                for k in range(n):
                    Y[i, k] -= lpi * Y[p, k]
        for k in range(n):
            Y[i, k] /= L[i, i]
    return q


def _joseph_rows(P, x, H, R, dz, Pn, xn, r, Sd, nis, ok):
    """Joseph-form update of every batch row (seed 000 eqs 7-8 with the Joseph covariance of eq 17).

    Per row b (P symmetric, as every form keeps it)::

        r  = dz - H x                       HP = H P           S = HP H^T + R   (lower triangle)
        S  = L L^T (Cholesky)               w = L^-1 r         nis = w^T w
        K^T = L^-T L^-1 HP                  x+ = x + K r
        A  = I - K H                        P+ = sym(A P A^T + K R K^T)

    Products skip the structural zeros of H and R (a GNSS row of H has 4 non-zeros of 17).

    Parameters
    ----------
    P : (B, n, n); x : (B, n); H : (B, m, n); R : (B, m, m); dz : (B, m) (prepared: masked rows neutral).
    Pn, xn : outputs (B, n, n), (B, n); r : (B, m) residual ``dz - H x``; Sd : (B, m) diag(S);
    nis : (B,); ok : (B,) bool, False where S is not positive definite (that row's outputs are undefined).
    """
    B, m, n = H.shape
    for b in nb.prange(B):
        dt = P.dtype
        HP = np.zeros((m, n), dt)
        L = np.zeros((m, m), dt)
        Y = np.empty((m, n), dt)
        w = np.empty(m, dt)
        At = np.zeros((n, n), dt)
        AP = np.zeros((n, n), dt)
        X = np.zeros((n, n), dt)
        KRt = np.zeros((m, n), dt)
        # column indices / values of the non-zeros of each row of H
        nzc = np.empty((m, n), np.int64)
        nzv = np.empty((m, n), dt)
        cnt = np.zeros(m, np.int64)
        for i in range(m):
            cnt[i] = _row_nonzeros(H[b, i], nzc[i], nzv[i])
        for i in range(m):
            r[b, i] = _residual_and_hp(dz[b, i], nzc[i], nzv[i], cnt[i], x[b], P[b], HP[i])
        # S = HP H^T + R (lower triangle) and its Cholesky factor, in place in L
        for i in range(m):
            for j in range(i + 1):
                s = R[b, i, j]
                for t in range(cnt[j]):
                    s += HP[i, nzc[j, t]] * nzv[j, t]
                L[i, j] = s
            Sd[b, i] = L[i, i]
        good = _cholesky_lower(L, m)
        ok[b] = good
        if not good:
            continue
        nis[b] = _gain_solve(L, r[b], HP, Y, w, m, n)
        # x+ = x + K r
        for k in range(n):
            xn[b, k] = x[b, k]
        for i in range(m):
            ri = r[b, i]
            for k in range(n):
                xn[b, k] += Y[i, k] * ri
        # A^T = I - H^T K^T
        for k in range(n):
            At[k, k] = 1.0
        for i in range(m):
            for t in range(cnt[i]):
                l = nzc[i, t]
                h = nzv[i, t]
                for k in range(n):
                    At[l, k] -= h * Y[i, k]
        # AP = A P, X = AP A^T
        for k in range(n):
            for l in range(n):
                a = At[l, k]
                if a != 0:
                    for j in range(n):
                        AP[k, j] += a * P[b, l, j]
        for k in range(n):
            for l in range(n):
                a = AP[k, l]
                for j in range(n):
                    X[k, j] += a * At[l, j]
        # X += K R K^T  (KRt = (K R)^T = R^T K^T)
        for j in range(m):
            for i in range(m):
                rij = R[b, i, j]
                if rij != 0:
                    for k in range(n):
                        KRt[j, k] += rij * Y[i, k]
        for k in range(n):
            for j in range(m):
                a = KRt[j, k]
                for l in range(n):
                    X[k, l] += a * Y[j, l]
        for k in range(n):
            for l in range(n):
                Pn[b, k, l] = 0.5 * (X[k, l] + X[l, k])


_joseph_serial, _joseph_parallel = serial_and_parallel(_joseph_rows)


def joseph_update(P, x, H, R, dz):
    """Compiled Joseph-form update of a batch (see :func:`_joseph_rows`; seed 000 eqs 7-8, 17).

    Parameters
    ----------
    P : (B, n, n) symmetric covariance; x : (B, n); H : (B, m, n); R : (B, m, m); dz : (B, m), all prepared
        (masked rows neutral) and of one float dtype.

    Returns
    -------
    P_new, x_new, r (= dz - H x), diag(S), nis : new arrays in the dtype of P.

    Raises
    ------
    numpy.linalg.LinAlgError
        ``S`` is not positive definite on some row (as ``np.linalg.cholesky`` does); nothing is returned.
    """
    B, m, n = H.shape
    dt = P.dtype
    args = [np.ascontiguousarray(a, dt) for a in (P, x, H, R, dz)]
    Pn = np.empty((B, n, n), dt)
    xn = np.empty((B, n), dt)
    r = np.empty((B, m), dt)
    Sd = np.empty((B, m), dt)
    nis = np.zeros(B, dt)
    ok = np.empty(B, bool)
    kern = _joseph_parallel if row_chunks(B) > 1 else _joseph_serial  # (serial inside serial_rows too)
    kern(*args, Pn, xn, r, Sd, nis, ok)
    if np.count_nonzero(ok) != B:  # = not ok.all(), cheaper
        raise np.linalg.LinAlgError("Matrix is not positive definite")
    return Pn, xn, r, Sd, nis


class KalmanFilter(FilterForm):
    """``kf``: covariance form, Joseph update ``P = (I-KH) P (I-KH)^T + K R K^T``.

    Time update (seed 000 eqs 5-6): ``x = Phi x``, ``P = Phi P Phi^T + Q``.
    Measurement update (eqs 7-8 with the Joseph form of eq 17):
    ``K = P H^T (H P H^T + R)^-1``, ``x = x + K (dz - H x)``.
    """

    name = "kf"
    HAS_FUSED = True

    def _init_uncertainty(self, P0):
        self.P = P0

    @property
    def covariance(self):
        return self.P

    def predict(self, Phi, Q):
        Phi = np.asarray(Phi, self.dtype)
        self.x = (Phi @ self.x[..., None])[..., 0]
        self.P = symmetrize(Phi @ self.P @ Phi.mT + np.asarray(Q, self.dtype))

    def _update(self, dz, H, R, mask):
        if self.fused:
            P, x, r, Sd, nis = fused_update(self.P, self.x, H, R, dz, mask)
        else:
            P, x, r, Sd, nis = joseph_update(self.P, self.x, H, R, dz)
        self.P, self.x = P, x
        n_used = mask.sum(-1)
        return UpdateResult(nis=nis, n_used=n_used, innovation=r, innovation_var=Sd, applied=n_used > 0)

    def direct_epoch_ready(self) -> bool:
        """Whether :meth:`direct_epoch` can run the next update (the navigator's compiled GNSS epoch,
        :meth:`~nav_filters.navigator.Navigator._direct_gnss_epoch`): the fused path on, this class itself."""
        return self.fused and type(self) is KalmanFilter

    def direct_epoch(self, Phi, Q, prior, dz, H, R, mask, keys) -> UpdateResult:
        """:meth:`take_prediction` ``(Phi, Q)`` then :meth:`update` ``(dz, H, R, mask)`` on a measurement the caller
        prepared (:func:`~nav_filters.forms.base.prepare_measurement`'s arrays, R (B, m, m)): the same steps on the
        same arrays, without the layers in between (the adaptive laws' :meth:`~nav_filters.adaptive.base.
        AdaptiveLaw.direct_epoch` contract; ``prior``, which the navigator does not form for the kf, and ``keys`` are
        not used). Where some row's ``S`` is not
        positive definite it raises ``LinAlgError`` after the time update, as :meth:`update` would after
        :meth:`predict`."""
        self.predict(Phi, Q)
        return self._update(dz, H, R, mask)

    def _predicted_update(self, Phi, Q, dz, H, R, mask, fade=None, prior=None):
        """Fused path (:func:`fused_update`: one kernel, nothing committed when it raises); else the generic
        predict-then-update of :meth:`FilterForm._predicted_update`."""
        if not self.fused:
            return super()._predicted_update(Phi, Q, dz, H, R, mask, fade, prior)
        B, n = self.batch_size, self.n
        Q = np.asarray(Q, self.dtype)
        Q = Q if Q.shape == (B, n, n) else np.broadcast_to(Q, (B, n, n))
        P, x, r, Sd, nis = fused_update(self.P, self.x, H, R, dz, mask, Phi=Phi, Q=Q, fade=fade, prior=prior)
        self.P, self.x = P, x
        n_used = mask.sum(-1)
        return UpdateResult(nis=nis, n_used=n_used, innovation=r, innovation_var=Sd, applied=n_used > 0)

    def _update_reference(self, dz, H, R, mask):
        """Numpy specification of :meth:`_update` (same equations; agreement test)."""
        P = self.P
        S, PHt = innovation_covariance(P, H, R)
        r = dz - (H @ self.x[..., None])[..., 0]
        K, nis = nis_and_gain(S, PHt, r)
        self.x = self.x + (K @ r[..., None])[..., 0]
        I_KH = np.eye(self.n, dtype=self.dtype) - K @ H
        self.P = symmetrize(I_KH @ P @ I_KH.mT + K @ R @ K.mT)
        n_used = mask.sum(-1)
        return UpdateResult(nis=nis, n_used=n_used, innovation=r,
                            innovation_var=np.diagonal(S, axis1=1, axis2=2).copy(), applied=n_used > 0)


# ----------------------------------------------------------------------------- fused predict + update
@nb.njit(cache=True, inline="always")
def _prior_row(Phi, P, T, C):
    """``C = Phi P Phi^T`` (n, n) of one row, exactly symmetric: ``T = Phi P`` over Phi's non-zero entries (a
    transition of the 17-state model is 60% zeros), then the lower triangle of ``T Phi^T``, mirrored. ``T`` is
    scratch (n, n)."""
    n = P.shape[0]
    for i in range(n):
        for j in range(n):
            T[i, j] = 0.0
        for k in range(n):
            a = Phi[i, k]
            if a != 0:
                for j in range(n):
                    T[i, j] += a * P[k, j]
    for i in range(n):
        for j in range(i + 1):
            acc = T[i, 0] * Phi[j, 0]
            for k in range(1, n):
                acc += T[i, k] * Phi[j, k]
            C[i, j] = acc
    for i in range(n):
        for j in range(i + 1, n):
            C[i, j] = C[j, i]


def _prior_rows(Phi, P, out, nchunk):
    """:func:`_prior_row` of every batch row into ``out`` (B, n, n), in ``nchunk`` chunks of rows."""
    B, n = P.shape[0], P.shape[1]
    for c in nb.prange(nchunk):
        T = np.empty((n, n), P.dtype)
        for b in range(c * B // nchunk, (c + 1) * B // nchunk):
            _prior_row(Phi[b], P[b], T, out[b])


_prior_serial, _prior_parallel = serial_and_parallel(_prior_rows)


def transition_prior(Phi, P):
    """Compiled ``sym(Phi P Phi^T)`` of a batch (the predicted covariance before process noise, seed 000 eq 6):
    a new (B, n, n) array in the dtype of ``P``, exactly symmetric. ``Phi`` (B, n, n) is cast to that dtype.
    Equal to ``symmetrize(Phi @ P @ Phi.mT)`` to round-off (test: ``tests/nav_filters/test_fused_update.py``);
    parallel over rows from :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows."""
    dt = P.dtype
    out = np.empty(P.shape, dt)
    kern, nchunk = row_kernel(_prior_serial, _prior_parallel, P.shape[0])
    kern(np.ascontiguousarray(Phi, dt), np.ascontiguousarray(P), out, nchunk)
    return out


@nb.njit(cache=True, inline="always", error_model="numpy")
def _predicted_row(b, mode, P, x, Phi, s, Q, prior, Pm, T, C, xm):
    """The time update of :func:`_fused_rows` for row ``b`` into ``Pm`` (n, >= n) and ``xm`` (n,): mode 0 the
    posterior as it is; mode 1 ``sym(D Phi P Phi^T D + Q)``, mode 2 ``sym(D prior D + Q)``, and ``x- = D Phi x``
    (``D = diag(s[b])``); ``T``, ``C`` (n, n) scratch."""
    n = xm.shape[0]
    if mode == 0:
        for i in range(n):
            xm[i] = x[b, i]
            for j in range(n):
                Pm[i, j] = P[b, i, j]
        return
    if mode == 1:
        _prior_row(Phi[b], P[b], T, C)
    else:
        for i in range(n):
            for j in range(n):
                C[i, j] = prior[b, i, j]
    for i in range(n):
        for j in range(i + 1):
            v = 0.5 * ((s[b, i] * s[b, j] * C[i, j] + Q[b, i, j])
                       + (s[b, j] * s[b, i] * C[j, i] + Q[b, j, i]))
            Pm[i, j] = v
            Pm[j, i] = v
    for i in range(n):
        acc = 0.0
        for k in range(n):
            acc += Phi[b, i, k] * x[b, k]
        xm[i] = s[b, i] * acc


@nb.njit(cache=True, inline="always", error_model="numpy")
def _innovation_row(b, H, R, dz, mask, xm, Pm, r, Sd, idx, nzc, nzv, cnt, HP, L, rv):
    """The valid rows of row ``b`` (``idx``; the non-zeros of their H rows in ``nzc``, ``nzv``, ``cnt``), their
    residuals ``dz - H x-`` (into ``rv`` and ``r[b]``; 0 and ``Sd = 1`` on the masked rows), ``HP = H P-`` and the
    lower triangle of ``S = HP H^T + R`` (diagonal into ``Sd[b]``) factored in place in ``L``. Returns
    ``(mv, good)``: the number of valid rows and whether S is positive definite."""
    m = mask.shape[1]
    W = HP.shape[1]
    mv = 0
    for i in range(m):
        if mask[b, i]:
            idx[mv] = i
            cnt[mv] = _row_nonzeros(H[b, i], nzc[mv], nzv[mv])
            mv += 1
        else:
            r[b, i] = 0.0
            Sd[b, i] = 1.0
    for t in range(mv):
        i = idx[t]
        for k in range(W):
            HP[t, k] = 0.0
        sres = _residual_and_hp(dz[b, i], nzc[t], nzv[t], cnt[t], xm, Pm, HP[t])
        r[b, i] = sres
        rv[t] = sres
    for t in range(mv):
        for u in range(t + 1):
            acc = R[b, idx[t], idx[u]]
            for q in range(cnt[u]):
                acc += HP[t, nzc[u, q]] * nzv[u, q]
            L[t, u] = acc
        Sd[b, idx[t]] = L[t, t]
    return mv, _cholesky_lower(L, mv)


@nb.njit(cache=True, inline="always", error_model="numpy")
def _joseph_row(b, R, mv, idx, nzc, nzv, cnt, Pm, Y, KHt, cols, pos, AP, KRt, X, Pn):
    """The Joseph covariance of :func:`_fused_rows` for row ``b`` into ``Pn[b]``, from ``P-`` (``Pm``) and
    ``K^T`` (``Y``, the valid rows): ``A = I - K H`` is non-trivial only in the ``nc`` columns of H that hold a
    non-zero (8 of 17 for GNSS rows): ``KHt = (K H)^T`` on those columns, ``AP = P- - K H P-``,
    ``X = AP A^T = AP - (AP)[:, cols] KHt`` (whole rows), ``X += K R K^T`` with ``KRt = (K R)^T``; the upper
    triangle of X, mirrored (exactly symmetric). ``pos`` (n,) is -1 on entry and on return."""
    n = Pm.shape[0]
    W = Pm.shape[1]
    nc = 0
    for t in range(mv):
        for q in range(cnt[t]):
            l = nzc[t, q]
            if pos[l] < 0:
                pos[l] = nc
                cols[nc] = l
                for k in range(W):
                    KHt[nc, k] = 0.0
                nc += 1
            ci = pos[l]
            h = nzv[t, q]
            for k in range(W):
                KHt[ci, k] += h * Y[t, k]
    for k in range(n):
        for j in range(W):
            AP[k, j] = Pm[k, j]
        for ci in range(nc):
            a = KHt[ci, k]
            if a != 0:
                l = cols[ci]
                for j in range(W):
                    AP[k, j] -= a * Pm[l, j]
    for k in range(n):
        for j in range(W):
            X[k, j] = AP[k, j]
        for ci in range(nc):
            a = AP[k, cols[ci]]
            if a != 0:
                for j in range(W):
                    X[k, j] -= a * KHt[ci, j]
    for ci in range(nc):
        pos[cols[ci]] = -1
    for t in range(mv):       # KRt = (K R)^T = R^T K^T over the valid rows
        for k in range(W):
            KRt[t, k] = 0.0
        for u in range(mv):
            ru = R[b, idx[u], idx[t]]
            if ru != 0:
                for k in range(W):
                    KRt[t, k] += ru * Y[u, k]
    for k in range(n):
        for t in range(mv):
            a = Y[t, k]
            if a != 0:
                for j in range(W):
                    X[k, j] += a * KRt[t, j]
    for k in range(n):
        for j in range(k, n):
            Pn[b, k, j] = X[k, j]
            Pn[b, j, k] = X[k, j]


def _fused_rows(P, x, Phi, s, Q, prior, mode, H, R, dz, mask, Pn, xn, r, Sd, nis, ok, nchunk):
    """Fused time and Joseph measurement update of every batch row (the fast path, ``fused_update=True``).

    The same recursion as :meth:`KalmanFilter.predict` followed by :func:`_joseph_rows` on the prepared
    measurement, in one pass per row and with the scratch of a chunk of rows allocated once (no allocation
    per row), and with the masked measurement rows left out of every product instead of neutralized
    (a masked row has ``H = 0``, ``dz = 0``, unit variance and changes nothing, DESIGN.md sec 2). Per row b,
    ``D = diag(s)``::

        mode 0:  P- = P,                                       x- = x          (no time update)
        mode 1:  P- = sym(D Phi P Phi^T D + Q),                x- = D Phi x    (seed 000 eqs 5-6)
        mode 2:  P- = sym(D prior D + Q), prior = sym(Phi P Phi^T) given,   x- = D Phi x
        r  = dz - H x-   (valid rows; 0 on masked rows)        HP = H P-       S = HP H^T + R   (valid rows)
        S  = L L^T       w = L^-1 r,  nis = w^T w              K^T = L^-T L^-1 HP
        x+ = x- + K r    P+ = A P- A^T + K R K^T,  A = I - K H   (Joseph, seed 000 eq 17), with
                         A P- = P- - (K H) P-   and   A P- A^T = A P- - (A P-) (K H)^T
                         where K H is non-zero only in the columns of H's non-zeros (8 of 17 for GNSS rows);
                         the upper triangle computed and mirrored (exactly symmetric)

    Parameters
    ----------
    P : (B, n, n); x : (B, n); Phi : (B, n, n) (modes 1, 2); s : (B, n) the square roots of the fading
    factors (modes 1, 2); Q : (B, n, n) (modes 1, 2); prior : (B, n, n) (mode 2); mode : 0, 1 or 2;
    H : (B, m, n); R : (B, m, m); dz : (B, m); mask : (B, m) bool (the valid rows; the others may hold
    anything finite); all float arrays of one dtype.
    Pn, xn : outputs (B, n, n), (B, n); r : (B, m) residual ``dz - H x-`` (0 on masked rows); Sd : (B, m)
    diag(S) (1 on masked rows); nis : (B,); ok : (B,) bool, False where S is not positive definite (that
    row's outputs are undefined). nchunk : number of row chunks (each allocates its scratch once).

    The scratch matrices of n columns are padded with zeros to ``W`` columns (:func:`~nav_filters.kernels.padded_width`)
    and their row operations run over all W, the triangular ones over whole rows (vectorized, no scalar remainder):
    the same bits.
    """
    B, m, n = H.shape
    dt = P.dtype
    for c in nb.prange(nchunk):
        lo = c * B // nchunk
        hi = (c + 1) * B // nchunk
        W = padded_width(n)
        Pm = np.zeros((n, W), dt)
        T = np.empty((n, n), dt)
        C = np.empty((n, n), dt)
        xm = np.empty(n, dt)
        xp = np.zeros(W, dt)      # x+
        HP = np.zeros((m, W), dt)
        L = np.empty((m, m), dt)
        Y = np.zeros((m, W), dt)
        w = np.empty(m, dt)
        rv = np.empty(m, dt)
        AP = np.zeros((n, W), dt)
        X = np.zeros((n, W), dt)
        KRt = np.zeros((m, W), dt)
        idx = np.empty(m, np.int64)
        KHt = np.zeros((n, W), dt)
        cols = np.empty(n, np.int64)
        pos = np.full(n, -1, np.int64)
        nzc = np.empty((m, n), np.int64)
        nzv = np.empty((m, n), dt)
        cnt = np.empty(m, np.int64)
        for b in range(lo, hi):
            _predicted_row(b, mode, P, x, Phi, s, Q, prior, Pm, T, C, xm)
            mv, good = _innovation_row(b, H, R, dz, mask, xm, Pm, r, Sd, idx, nzc, nzv, cnt, HP, L, rv)
            ok[b] = good
            if not good:
                continue
            # ---- w = L^-1 r, Y = L^-1 HP (forward), K^T = L^-T Y (backward, in place)
            nis[b] = _gain_solve(L, rv, HP, Y, w, mv, W)
            # ---- x+ = x- + K r
            for k in range(n):
                xp[k] = xm[k]
            for t in range(mv):
                a = rv[t]
                for k in range(W):
                    xp[k] += Y[t, k] * a
            for k in range(n):
                xn[b, k] = xp[k]
            _joseph_row(b, R, mv, idx, nzc, nzv, cnt, Pm, Y, KHt, cols, pos, AP, KRt, X, Pn)


_fused_serial, _fused_parallel = serial_and_parallel(_fused_rows, error_model="numpy")


def fused_update(P, x, H, R, dz, mask, Phi=None, Q=None, fade=None, prior=None):
    """Compiled fused time + Joseph measurement update of a batch (see :func:`_fused_rows`).

    Parameters
    ----------
    P : (B, n, n) symmetric covariance; x : (B, n); H : (B, m, n); R : (B, m, m); dz : (B, m);
    mask : (B, m) bool, the valid measurement rows (the others are left out whatever they hold).
    Phi, Q : (B, n, n) transition and process noise of a time update applied first (None: no time update);
    fade : None, (B,) or (B, n) fading factors ``lambda >= 1``: ``P- = D Phi P Phi^T D + Q``,
        ``D = diag(sqrt(lambda))`` (seed 003 eq 23; per state with (B, n));
    prior : (B, n, n) ``sym(Phi P Phi^T)`` when the caller already has it (then ``P`` is not read).
    All in one float dtype (that of ``P``).

    Returns
    -------
    P_new, x_new, r (= dz - H x-, 0 on masked rows), diag(S) (1 on masked rows), nis : new arrays.

    Raises
    ------
    numpy.linalg.LinAlgError
        ``S`` is not positive definite on some row; nothing is returned (the inputs are not modified).
    """
    B, m, n = H.shape
    dt = P.dtype
    c = np.ascontiguousarray
    if Phi is None:
        mode, Phi_, s, Q_, pri = 0, P, np.ones((B, n), dt), P, P
    else:
        f = np.ones((B, n)) if fade is None else np.asarray(fade, np.float64)
        s = np.empty((B, n), dt)
        s[...] = np.sqrt(f if f.ndim == 2 else f[:, None])  # the (B, n) scales of P, cast to the filter dtype
        mode, Phi_, Q_ = (1 if prior is None else 2), c(Phi, dt), c(Q, dt)
        pri = P if prior is None else c(prior, dt)
    Pn = np.empty((B, n, n), dt)
    xn = np.empty((B, n), dt)
    r = np.empty((B, m), dt)
    Sd = np.empty((B, m), dt)
    nis = np.zeros(B, dt)
    ok = np.empty(B, bool)
    kern, nchunk = row_kernel(_fused_serial, _fused_parallel, B)
    kern(c(P, dt), c(x, dt), Phi_, s, Q_, pri, mode, c(H, dt), c(R, dt), c(dz, dt), c(mask, bool),
         Pn, xn, r, Sd, nis, ok, nchunk)
    if np.count_nonzero(ok) != B:  # = not ok.all(), cheaper
        raise np.linalg.LinAlgError("Matrix is not positive definite")
    return Pn, xn, r, Sd, nis
