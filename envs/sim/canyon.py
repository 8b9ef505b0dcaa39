"""The street canyon: its configuration (:class:`UrbanCanyon`) and its blockage and reflection geometry along one
row's drive (:func:`canyon_visibility`), used by the GNSS stages (:mod:`envs.sim.gnss_stages`) and by the urban
zones' own canyons (:mod:`envs.sim.events`). It imports neither, so that the world's GNSS modules import one way:
``canyon`` <- ``events`` <- ``gnss_stages`` <- ``gnss``."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .constellation import _check_pair, _check_real


def _check_intervals(owner: str, name: str, value, with_scale: bool) -> None:
    """A tuple of (t0_s, t1_s) or (t0_s, t1_s, scale) with t1 >= t0 and scale >= 0."""
    n = 3 if with_scale else 2
    if not isinstance(value, tuple):
        raise ValueError(f"{owner}.{name} must be a tuple of {n}-tuples, got {type(value).__name__}")
    for k, iv in enumerate(value):
        if not isinstance(iv, tuple) or len(iv) != n:
            raise ValueError(f"{owner}.{name}[{k}] must be a {n}-tuple, got {iv!r}")
        _check_real(owner, f"{name}[{k}].t0_s", iv[0], lo=None)
        _check_real(owner, f"{name}[{k}].t1_s", iv[1], lo=None)
        if iv[1] < iv[0]:
            raise ValueError(f"{owner}.{name}[{k}]: t1 < t0 in {iv!r}")
        if with_scale:
            _check_real(owner, f"{name}[{k}].scale", iv[2], lo=0.0)


def in_intervals(t: np.ndarray, intervals) -> np.ndarray:
    """Boolean (M,) : ``t`` lies in any half-open interval ``[t0, t1)``."""
    out = np.zeros(t.shape, dtype=bool)
    for iv in intervals:
        out |= (t >= iv[0]) & (t < iv[1])
    return out


@dataclass(frozen=True)
class UrbanCanyon:
    """Street-canyon blockage along the drive.

    The vehicle drives along the middle of a straight street of width ``w``
    (the street follows the vehicle heading). A wall of height ``h`` at the
    lateral distance ``w/2`` blocks a satellite at elevation ``el`` and
    azimuth ``alpha`` relative to the heading when::

        tan(el) < h |sin alpha| / (w / 2)

    (across the street, ``|sin alpha| = 1``: ``el < atan(h / (w/2))``; along
    the street nothing is blocked). The street is cut into blocks of
    ``block_length_m`` of driven distance; each block side is lined by a
    building with probability ``blockage_probability`` (else a gap / cross
    street) of height ``U(building_height_m)``. A blocked satellite is still
    tracked, via a reflection off the opposite facade, with probability
    ``nlos_probability`` per (block, satellite): it is then flagged NLOS with
    the excess path of a specular reflection off a wall at distance ``w/2``
    on the other side, ``w cos(el) |sin alpha|`` [m] (the classic two-ray
    geometry, cf. Groves 2nd ed. ch. 10 on multipath / NLOS), plus the NLOS noise factor of
    :class:`~envs.sim.gnss.NlosConfig` (3 if no NLOS bursts are configured).

    Parameters
    ----------
    street_width_m : float
        Street width (facade to facade) [m], > 0.
    building_height_m : (float, float)
        Range of building heights [m], 0 <= min <= max.
    block_length_m : float
        Driven distance per building block [m], > 0.
    blockage_probability : float
        Probability that a block side has a building, in [0, 1].
    nlos_probability : float
        Probability that a blocked satellite is received by reflection, in [0, 1].
    intervals : tuple of (t0_s, t1_s)
        Time intervals [s since start, half-open] where the canyon applies;
        empty = the whole run.
    """

    street_width_m: float = 20.0
    building_height_m: tuple = (10.0, 40.0)
    block_length_m: float = 50.0
    blockage_probability: float = 0.8
    nlos_probability: float = 0.3
    intervals: tuple = ()

    def __post_init__(self):
        o = "UrbanCanyon"
        _check_real(o, "street_width_m", self.street_width_m, lo=0.0, lo_open=True)
        _check_pair(o, "building_height_m", self.building_height_m, lo=0.0)
        _check_real(o, "block_length_m", self.block_length_m, lo=0.0, lo_open=True)
        _check_real(o, "blockage_probability", self.blockage_probability, lo=0.0, hi=1.0)
        _check_real(o, "nlos_probability", self.nlos_probability, lo=0.0, hi=1.0)
        _check_intervals(o, "intervals", self.intervals, with_scale=False)


def canyon_visibility(t, v_e, heading, el, az, cfg: UrbanCanyon, g: np.random.Generator):
    """Street-canyon visibility of one row (see :class:`UrbanCanyon`; :func:`canyon_visibility_rows` with one row).

    Parameters
    ----------
    t : (M,) [s]; v_e : (M, 3) [m/s]; heading : (M,) [rad]; el, az : (M, S) [rad].

    Returns
    -------
    blocked : (M, S) bool (not received at all); reflected : (M, S) bool
    (received as NLOS); excess_m : (M, S) reflection excess path [m].
    """
    blocked, refl, excess = canyon_visibility_rows(t, v_e[None], heading[None], el[None], az[None], cfg, [g])
    return blocked[0], refl[0], excess[0]


def canyon_visibility_rows(t, v_e, heading, el, az, cfg: UrbanCanyon, gens, within=None, active=None):
    """Street-canyon visibility of B rows (see :class:`UrbanCanyon`), each row's buildings drawn from its own
    generator ``gens[i]``: the building heights (K, 2), their presence (K, 2) and the reflection draws (K, S) of
    the row's K blocks, in this order; the geometry vectorized over the rows and evaluated only on the elements
    inside the canyon's epochs (and ``active``), the same operations per element as for a row alone, so a row's
    result does not depend on the others.

    Parameters
    ----------
    t : (M,) [s]; v_e : (B, M, 3) [m/s]; heading : (B, M) [rad]; el, az : (B, M, S) [rad];
    gens : B numpy.random.Generator; within : (B, M) bool or None: the epochs where each row's canyon applies,
    in place of ``cfg.intervals`` (the urban zones' canyon windows, :func:`envs.sim.events.zone_effects_rows`);
    active : (B, M, S) bool or None: the only elements evaluated (the others are returned not blocked, not
    reflected; the urban zones pass the satellites above the mask, the only ones they change).

    Returns
    -------
    blocked : (B, M, S) bool (not received at all); reflected : (B, M, S) bool
    (received as NLOS); excess_m : (B, M, S) reflection excess path [m].
    """
    B, M, S = el.shape
    speed = np.linalg.norm(v_e, axis=-1)                                        # (B, M)
    dist = np.zeros((B, M))
    np.cumsum(0.5 * (speed[:, 1:] + speed[:, :-1]) * np.diff(t), axis=1, out=dist[:, 1:])
    blk = np.floor(dist / cfg.block_length_m).astype(np.int64)                 # (B, M) block of each epoch
    K = blk.max(axis=1) + 1 if M else np.ones(B, np.int64)
    Kx = int(K.max(initial=1))
    h = np.zeros((B, Kx, 2))                                                    # building heights, 0 in gaps
    reflect = np.zeros((B, Kx, S), dtype=bool)
    for i, g in enumerate(gens):
        k = int(K[i])
        heights = g.uniform(cfg.building_height_m[0], cfg.building_height_m[1], size=(k, 2))
        present = g.random((k, 2)) < cfg.blockage_probability
        reflect[i, :k] = g.random((k, S)) < cfg.nlos_probability
        h[i, :k] = np.where(present, heights, 0.0)
    if within is None and cfg.intervals:
        within = np.broadcast_to(in_intervals(t, cfg.intervals), (B, M))
    # the evaluated epochs ep (flat into (B, M); all without ``within``), each with its (row, block) bk
    ep = None if within is None else np.flatnonzero(within)
    bk = (np.arange(B * M) // max(M, 1)) * Kx + blk.reshape(-1)
    el2, az2, hd = el.reshape(B * M, S), az.reshape(B * M, S), heading.reshape(-1)
    if ep is not None:
        el2, az2, hd, bk = el2[ep], az2[ep], hd[ep], bk[ep]
    sa = np.sin(az2 - hd[:, None])                                              # > 0: right side
    h2 = h.reshape(B * Kx, 2)[bk]                                               # [left, right] of each epoch
    h_side = np.where(sa > 0.0, h2[:, 1:2], h2[:, 0:1])
    under = np.tan(np.clip(el2, -1.5, 1.5)) * (0.5 * cfg.street_width_m) < h_side * np.abs(sa)
    if active is not None:
        under &= active.reshape(B * M, S) if ep is None else active.reshape(B * M, S)[ep]
    refl2 = under & reflect.reshape(B * Kx, S)[bk]
    excess2 = np.zeros(under.shape)
    excess2[refl2] = cfg.street_width_m * np.cos(el2[refl2]) * np.abs(sa[refl2])   # the reflected few only
    if ep is None:
        return (under & ~refl2).reshape(B, M, S), refl2.reshape(B, M, S), excess2.reshape(B, M, S)
    blocked, refl, excess = np.zeros((B, M, S), dtype=bool), np.zeros((B, M, S), dtype=bool), np.zeros((B, M, S))
    blocked.reshape(B * M, S)[ep] = under & ~refl2
    refl.reshape(B * M, S)[ep] = refl2
    excess.reshape(B * M, S)[ep] = excess2
    return blocked, refl, excess
