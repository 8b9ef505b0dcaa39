"""Rotation helpers, batched over any leading axes.

Conventions (fixed once for the whole project):

* ``C_ab`` is the direction-cosine matrix that maps a vector from frame ``b``
  to frame ``a``: ``v_a = C_ab @ v_b``.
* Euler angles are (roll, pitch, yaw) of the body frame ``b`` (x forward,
  y right, z down) relative to the local NED frame ``n``, in the aerospace
  Z-Y-X sequence: ``C_nb = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
* ``skew(v) @ w == cross(v, w)``.
"""
from __future__ import annotations

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Skew-symmetric cross-product matrix.

    Parameters
    ----------
    v : (..., 3) array

    Returns
    -------
    (..., 3, 3) array ``S`` with ``S @ w == np.cross(v, w)``.
    """
    v = np.asarray(v)
    S = np.zeros(v.shape[:-1] + (3, 3), dtype=v.dtype)
    S[..., 0, 1] = -v[..., 2]
    S[..., 0, 2] = v[..., 1]
    S[..., 1, 0] = v[..., 2]
    S[..., 1, 2] = -v[..., 0]
    S[..., 2, 0] = -v[..., 1]
    S[..., 2, 1] = v[..., 0]
    return S


def exp_so3(phi: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (Rodrigues' formula).

    ``exp_so3(phi) = I + a [phi x] + b [phi x]^2`` with
    ``a = sin|phi|/|phi|`` and ``b = (1 - cos|phi|)/|phi|^2``; Taylor series
    below |phi| = 1e-4 rad so that small angles keep full precision.

    Parameters
    ----------
    phi : (..., 3) array, rotation vector [rad].

    Returns
    -------
    (..., 3, 3) rotation matrix.
    """
    phi = np.asarray(phi)
    th2 = np.sum(phi * phi, axis=-1)
    th = np.sqrt(th2)
    small = th < 1e-4
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0 - th2 / 6.0 + th2 * th2 / 120.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - th2 / 24.0 + th2 * th2 / 720.0, (1.0 - np.cos(safe)) / (safe * safe))
    S = skew(phi)
    eye = np.broadcast_to(np.eye(3, dtype=phi.dtype), S.shape)
    return eye + a[..., None, None].astype(phi.dtype) * S + b[..., None, None].astype(phi.dtype) * (S @ S)


def rot_x(a: np.ndarray) -> np.ndarray:
    """Frame-to-frame rotation matrix about x by angle ``a`` [rad], shape (..., 3, 3)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def rot_y(a: np.ndarray) -> np.ndarray:
    """Rotation matrix about y by ``a`` [rad], shape (..., 3, 3)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def rot_z(a: np.ndarray) -> np.ndarray:
    """Rotation matrix about z by ``a`` [rad], shape (..., 3, 3)."""
    a = np.asarray(a, dtype=float)
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def dcm_from_euler(roll, pitch, yaw) -> np.ndarray:
    """``C_nb`` from Z-Y-X Euler angles [rad]; any broadcastable shapes -> (..., 3, 3)."""
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def euler_from_dcm(C_nb: np.ndarray) -> np.ndarray:
    """Z-Y-X Euler angles (roll, pitch, yaw) [rad] of ``C_nb``, shape (..., 3)."""
    C = np.asarray(C_nb)
    roll = np.arctan2(C[..., 2, 1], C[..., 2, 2])
    pitch = -np.arcsin(np.clip(C[..., 2, 0], -1.0, 1.0))
    yaw = np.arctan2(C[..., 1, 0], C[..., 0, 0])
    return np.stack([roll, pitch, yaw], axis=-1)


def log_so3(C: np.ndarray) -> np.ndarray:
    """Rotation vector of a rotation matrix (inverse of :func:`exp_so3`), shape (..., 3).

    Accurate for angles below about 3 rad (the attitude errors this is used on).
    """
    C = np.asarray(C)
    tr = np.clip((np.trace(C, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    th = np.arccos(tr)
    w = np.stack([C[..., 2, 1] - C[..., 1, 2], C[..., 0, 2] - C[..., 2, 0], C[..., 1, 0] - C[..., 0, 1]], -1)
    small = th < 1e-6
    k = np.where(small, 0.5 + th * th / 12.0, th / (2.0 * np.sin(np.where(small, 1.0, th))))
    return w * k[..., None]
