"""Single-point positioning: weighted least squares on corrected pseudoranges, batched over epochs.

The classical snapshot solution (Groves 2nd ed. sec 9.4.1; Kaplan & Hegarty,
*Understanding GPS*, 2nd ed., sec 2.4.2): per epoch, find the receiver
position ``r`` and one receiver clock bias per satellite system ``b_s`` that
minimize ``sum_j w_j (pr_j - rho_j(r) - b_{s(j)})^2`` with ``w_j = 1 /
sigma_j^2``, by Gauss-Newton iterations on the linearized model (Groves
eqs 9.30-9.35 with a weight matrix)::

    dz_j = pr_j - rho_j(r) - b_{s(j)},   H_j = [-u_j^T, e_{s(j)}^T]
    dx   = (H^T W H)^-1 H^T W dz,        x <- x + dx

``rho`` and the line of sight ``u`` are the Sagnac-corrected range of
:func:`earth.ranging.range_and_rate` (satellite positions at transmission time,
as the navigator uses them). One clock column per system present (an
inter-system bias is then absorbed); a system absent from an epoch gets no
column there. Everything is vectorized over the leading epoch axis.

A solution needs at least ``3 + (systems present)`` satellites; epochs with
fewer are returned with ``valid`` False and NaN position and clocks (the NaN
is flagged, never silent).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from earth.ranging import range_and_rate

__all__ = ["SppSolution", "solve_spp"]


@dataclass(frozen=True)
class SppSolution:
    """Single-point solutions of N epochs.

    Attributes
    ----------
    r_e : (N, 3) ECEF receiver position [m] (NaN where not ``valid``).
    clock_m : (N, S) receiver clock bias of each system [m] (NaN where the system is absent or not ``valid``).
    systems : (S,) system codes of the clock columns.
    residuals : (N, C) post-fit residuals ``pr - rho - b`` [m] (0 on unused channels).
    used : (N, C) bool, channels in the solution.
    n_used : (N,) int; pdop, gdop : (N,) (inf where not valid).
    valid : (N,) bool, enough satellites and converged (last update <= max(tol_m, 1 mm)).
    iterations : int, Gauss-Newton iterations run.
    """

    r_e: np.ndarray
    clock_m: np.ndarray
    systems: np.ndarray
    residuals: np.ndarray
    used: np.ndarray
    n_used: np.ndarray
    pdop: np.ndarray
    gdop: np.ndarray
    valid: np.ndarray
    iterations: int


def _check(name, a, shape):
    if a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")


def solve_spp(sat_pos, pr, mask, sigma=None, system=None, r0=None, max_iter: int = 12, tol_m: float = 1e-4,
              reject_m: float | None = None, max_reject: int = 0) -> SppSolution:
    """Weighted least-squares single-point solutions of N independent epochs (module docstring).

    Parameters
    ----------
    sat_pos : (N, C, 3) satellite ECEF positions at transmission time [m].
    pr : (N, C) corrected pseudoranges [m] (satellite clock, atmosphere removed).
    mask : (N, C) bool, channels to use.
    sigma : (N, C) one-sigma pseudorange errors [m] (weights ``1/sigma^2``); None: equal weights.
    system : (N, C) int system codes (one clock per system); None: one clock.
    r0 : (3,) or (N, 3) initial position [m]; None: the Earth's centre (converges in ~6 iterations).
    max_iter : Gauss-Newton iterations at most; tol_m : stop when every update is below it [m].
    reject_m : optional fault exclusion: after convergence, while the largest
        ``|residual| / sigma * median(sigma)`` of an epoch exceeds ``reject_m`` [m]
        and a spare satellite is left, drop that channel and solve again
        (one satellite per pass, ``max_reject`` passes at most).
    max_reject : int >= 0.

    Returns
    -------
    SppSolution
    """
    sat_pos = np.asarray(sat_pos, np.float64)
    if sat_pos.ndim != 3 or sat_pos.shape[-1] != 3:
        raise ValueError(f"sat_pos must have shape (N, C, 3), got {sat_pos.shape}")
    N, C, _ = sat_pos.shape
    pr = np.asarray(pr, np.float64)
    _check("pr", pr, (N, C))
    mask = np.asarray(mask, bool)
    _check("mask", mask, (N, C))
    sigma = np.ones((N, C)) if sigma is None else np.asarray(sigma, np.float64)
    _check("sigma", sigma, (N, C))
    if np.any(sigma[mask] <= 0) or not np.all(np.isfinite(sigma[mask])):
        raise ValueError("sigma must be finite and > 0 on used channels")
    if not (np.all(np.isfinite(pr[mask])) and np.all(np.isfinite(sat_pos[mask]))):
        raise ValueError("pr and sat_pos must be finite on used channels")
    system = np.ones((N, C), np.int64) if system is None else np.asarray(system, np.int64)
    _check("system", system, (N, C))
    if not isinstance(max_iter, int) or max_iter < 1:
        raise ValueError(f"max_iter must be an int >= 1, got {max_iter!r}")
    if not isinstance(max_reject, int) or max_reject < 0:
        raise ValueError(f"max_reject must be an int >= 0, got {max_reject!r}")
    if reject_m is not None and not (np.isfinite(reject_m) and reject_m > 0):
        raise ValueError(f"reject_m must be a finite number > 0 or None, got {reject_m!r}")
    systems = np.unique(system[mask]) if mask.any() else np.array([1], np.int64)
    onehot = (system[..., None] == systems).astype(np.float64)        # (N, C, S)
    if r0 is None:
        r = np.zeros((N, 3))
    else:
        r = np.broadcast_to(np.asarray(r0, np.float64), (N, 3)).copy()
    used = mask.copy()
    n_pass = 1 + (max_reject if reject_m is not None else 0)
    total_iter = 0
    for _ in range(n_pass):
        r, clk, res, it, step = _gauss_newton(sat_pos, pr, used, sigma, onehot, r, max_iter, tol_m)
        total_iter += it
        if reject_m is None:
            break
        n_sys = (onehot * used[..., None]).any(1).sum(-1)
        spare = used.sum(-1) > 3 + n_sys                              # one more than the minimum
        with np.errstate(invalid="ignore", divide="ignore"):
            med = np.nan_to_num(np.nanmedian(np.where(used, sigma, np.nan), axis=-1), nan=1.0)
            score = np.where(used, np.abs(res) / np.where(used, sigma, 1.0) * med[:, None], -np.inf)
        worst = np.argmax(score, -1)
        drop = spare & (score[np.arange(N), worst] > reject_m)
        if not drop.any():
            break
        used[np.nonzero(drop)[0], worst[drop]] = False
    n_used = used.sum(-1)
    present = (onehot * used[..., None]).any(1)                         # (N, S)
    valid = (n_used >= 3 + present.sum(-1)) & np.all(np.isfinite(r), -1) & (step <= max(tol_m, 1e-3))
    rho, _, u = _ranges(sat_pos, r)
    G = np.where(used[..., None], np.concatenate([-u, onehot], -1), 0.0)
    A = G.mT @ G
    A = A + np.eye(A.shape[-1]) * np.concatenate([np.zeros((N, 3)), ~present], -1)[:, None, :]
    ok = valid
    A_inv = np.full(A.shape, np.nan)
    if ok.any():
        A_inv[ok] = np.linalg.inv(A[ok])
    diag = np.diagonal(A_inv, axis1=1, axis2=2)
    pdop = np.where(ok, np.sqrt(np.abs(diag[:, :3].sum(-1))), np.inf)
    gdop = np.where(ok, np.sqrt(np.abs(diag[:, :3].sum(-1) + np.where(present, diag[:, 3:], 0).sum(-1))), np.inf)
    r = np.where(valid[:, None], r, np.nan)
    clk = np.where(valid[:, None] & present, clk, np.nan)
    res = np.where(used & valid[:, None], res, 0.0)
    return SppSolution(r_e=r, clock_m=clk, systems=systems, residuals=res, used=used & valid[:, None], n_used=n_used,
                       pdop=pdop, gdop=gdop, valid=valid, iterations=total_iter)


def _ranges(sat_pos, r):
    """Sagnac-corrected ranges and lines of sight (empty channels, zeros, may give 0/0: masked by callers)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return range_and_rate(sat_pos, np.zeros_like(sat_pos), r, np.zeros_like(r))


def _solve(A, b, solvable):
    """``A^-1 b`` per epoch; an epoch whose ``A`` is singular (degenerate geometry) gets a zero step and leaves
    ``solvable`` (in place) instead of failing every epoch with ``LinAlgError``."""
    try:
        return np.linalg.solve(A, b[..., None])[..., 0]
    except np.linalg.LinAlgError:
        dx = np.zeros_like(b)
        for n in np.flatnonzero(solvable):
            try:
                dx[n] = np.linalg.solve(A[n], b[n])
            except np.linalg.LinAlgError:
                solvable[n] = False
        return dx


def _gauss_newton(sat_pos, pr, used, sigma, onehot, r, max_iter, tol_m):
    """Gauss-Newton iterations of the weighted least squares (Groves eqs 9.30-9.35, weighted)."""
    N, C, S = onehot.shape
    w = np.divide(1.0, np.square(sigma), out=np.zeros_like(sigma), where=used)
    present = (onehot * used[..., None]).any(1)
    pin = np.concatenate([np.zeros((N, 3)), ~present], -1)              # pin absent clock columns
    clk = np.zeros((N, S))
    n_min = 3 + present.sum(-1)
    solvable = used.sum(-1) >= n_min
    it = 0
    step = np.full(N, np.inf)
    for it in range(1, max_iter + 1):
        rho, _, u = _ranges(sat_pos, r)
        dz = pr - rho - np.einsum("ncs,ns->nc", onehot, clk)
        H = np.where(used[..., None], np.concatenate([-u, onehot], -1), 0.0)  # (N, C, 3 + S)
        Hw = H * w[..., None]
        A = Hw.mT @ H + np.eye(3 + S) * pin[:, None, :]
        b = (Hw.mT @ np.where(used, dz, 0.0)[..., None])[..., 0]
        solvable &= np.isfinite(A).all((-2, -1)) & np.isfinite(b).all(-1)   # an epoch whose iterates diverged
        A[~solvable] = np.eye(3 + S)
        b[~solvable] = 0.0
        dx = _solve(A, b, solvable)
        r = r + dx[:, :3]
        clk = clk + dx[:, 3:]
        step = np.linalg.norm(dx[:, :3], axis=-1)
        if np.all(step[solvable] < tol_m):
            break
    rho, _, _ = _ranges(sat_pos, r)
    res = pr - rho - np.einsum("ncs,ns->nc", onehot, clk)
    r = np.where(solvable[:, None], r, np.nan)
    return r, clk, res, it, np.where(solvable, step, np.inf)
