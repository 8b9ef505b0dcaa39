"""Recorded pseudorange epochs of one receiver: the common structure of every recorded-data loader.

A loader (smartLoc text files, RINEX observation + navigation files) reduces
its input to :class:`GnssEpochs`: per epoch, the tracked satellites on ``C``
padded channels with their ECEF positions at *transmission* time (in the ECEF
frame of that time, as a broadcast ephemeris gives them: the Sagnac rotation
is left to :func:`earth.ranging.range_and_rate`, exactly as for the simulated
receiver) and pseudoranges from which the satellite clock, group delays and
the atmospheric delays have been removed; only the receiver clock (one common
bias per epoch and system) and the residual errors (noise, multipath, NLOS,
model residuals) remain. :mod:`envs.datasets.replay` turns them into the
simulated receiver's :class:`~envs.sim.gnss.GnssData`.

System codes are the bit codes of the smartLoc files (and of u-blox /
RTKLIB): GPS 1, SBAS 2, GLONASS 4, Galileo 8, QZSS 16, BeiDou 32.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np
from scipy.interpolate import make_interp_spline

__all__ = ["SYS_GPS", "SYS_SBAS", "SYS_GLONASS", "SYS_GALILEO", "SYS_QZSS", "SYS_BEIDOU", "SYSTEM_LETTERS",
           "SYSTEM_NAMES", "GnssEpochs", "pack_epochs", "satellite_velocities"]

SYS_GPS, SYS_SBAS, SYS_GLONASS, SYS_GALILEO, SYS_QZSS, SYS_BEIDOU = 1, 2, 4, 8, 16, 32
SYSTEM_LETTERS = {"G": SYS_GPS, "S": SYS_SBAS, "R": SYS_GLONASS, "E": SYS_GALILEO, "J": SYS_QZSS, "C": SYS_BEIDOU}
"""RINEX satellite-system letter -> system code."""
SYSTEM_NAMES = {SYS_GPS: "GPS", SYS_SBAS: "SBAS", SYS_GLONASS: "GLONASS", SYS_GALILEO: "Galileo",
                SYS_QZSS: "QZSS", SYS_BEIDOU: "BeiDou"}


@dataclass(frozen=True)
class GnssEpochs:
    """Pseudorange epochs of one receiver on ``C`` padded channels (``M`` epochs).

    Empty channels (``mask`` False) hold finite zeros, ``sat_id == -1`` and ``system == 0``.

    Attributes
    ----------
    t : (M,) float64 epoch (reception) times [s], strictly increasing; the
        origin is the loader's (smartLoc: its own time stamps; RINEX: seconds
        since the first epoch, with ``t0_gps`` the GPS time of ``t = 0``).
    sat_pos : (M, C, 3) satellite ECEF position at transmission time [m].
    sat_vel : (M, C, 3) satellite ECEF velocity at transmission time [m/s].
    pr : (M, C) corrected pseudorange [m] (satellite clock, group delay and
        atmosphere removed; the receiver clock remains).
    pr_sigma : (M, C) one-sigma pseudorange error the source reports or the
        loader's model gives [m].
    mask : (M, C) bool, valid channel.
    sat_id : (M, C) int64 satellite number within its system (smartLoc:
        GPS PRN, GLONASS 300 + slot), -1 on empty channels.
    system : (M, C) int64 system code (:data:`SYS_GPS`, ...), 0 on empty channels.
    elevation : (M, C) elevation [rad] (smartLoc: as recorded; RINEX: from
        the receiver's approximate position).
    cn0 : (M, C) carrier-to-noise density [dB-Hz] (0 where unknown).
    t0_gps : float or None, GPS time of ``t = 0`` [s of the GPS week]; None
        where the source gives only relative times (smartLoc).
    source : str, where the epochs come from (for messages and tables).
    prr : (M, C) pseudorange rate [m/s] (satellite clock drift removed; the receiver clock drift remains;
        :mod:`envs.datasets.doppler`), or None where the source has no Doppler.
    prr_sigma : (M, C) its one-sigma error [m/s] (> 0 on valid channels), or None with ``prr``.
    """

    t: np.ndarray
    sat_pos: np.ndarray
    sat_vel: np.ndarray
    pr: np.ndarray
    pr_sigma: np.ndarray
    mask: np.ndarray
    sat_id: np.ndarray
    system: np.ndarray
    elevation: np.ndarray
    cn0: np.ndarray
    t0_gps: float | None = None
    source: str = ""
    prr: np.ndarray | None = None
    prr_sigma: np.ndarray | None = None

    def __post_init__(self):
        M = np.shape(self.t)[0] if np.ndim(self.t) == 1 else -1
        if M < 1:
            raise ValueError(f"GnssEpochs.t must be a non-empty 1-D array, got shape {np.shape(self.t)}")
        if not np.all(np.diff(self.t) > 0):
            raise ValueError("GnssEpochs.t must be strictly increasing")
        C = np.shape(self.mask)[1] if np.ndim(self.mask) == 2 else -1
        shapes = {"sat_pos": (M, C, 3), "sat_vel": (M, C, 3), "pr": (M, C), "pr_sigma": (M, C), "mask": (M, C),
                  "sat_id": (M, C), "system": (M, C), "elevation": (M, C), "cn0": (M, C)}
        for name, shape in shapes.items():
            a = getattr(self, name)
            if np.shape(a) != shape:
                raise ValueError(f"GnssEpochs.{name} must have shape {shape}, got {np.shape(a)}")
            if name not in ("mask",) and not np.all(np.isfinite(a)):
                raise ValueError(f"GnssEpochs.{name} must be finite (empty channels hold zeros)")
        if np.any(self.pr_sigma[self.mask] <= 0):
            raise ValueError("GnssEpochs.pr_sigma must be > 0 on valid channels")
        if (self.prr is None) != (self.prr_sigma is None):
            raise ValueError("GnssEpochs.prr and prr_sigma are given together or not at all")
        if self.prr is not None:
            for name in ("prr", "prr_sigma"):
                a = getattr(self, name)
                if np.shape(a) != (M, C) or not np.all(np.isfinite(a)):
                    raise ValueError(f"GnssEpochs.{name} must be a finite ({M}, {C}) array, got shape {np.shape(a)}")
            if np.any(self.prr_sigma[self.mask] <= 0):
                raise ValueError("GnssEpochs.prr_sigma must be > 0 on valid channels")

    def sat_keys(self) -> np.ndarray:
        """(M, C) int64 satellite keys (:func:`nav_filters.measurements.satellite_key`: system and PRN, unique
        across systems), -1 on empty channels. A GLONASS ``sat_id`` above 300 is smartLoc's ``300 + slot``."""
        from nav_filters.measurements import SYSTEMS, satellite_key
        letters = {code: letter for letter, code in SYSTEM_LETTERS.items()}
        sysi = np.zeros(self.system.shape, np.int64)
        for code, letter in letters.items():
            sysi[self.system == code] = SYSTEMS.index(letter)
        prn = np.where((self.system == SYS_GLONASS) & (self.sat_id > 300), self.sat_id - 300, self.sat_id)
        unknown = self.mask & ~np.isin(self.system, list(letters))
        if unknown.any():
            raise ValueError(f"{self.source or 'GnssEpochs'}: unknown system code(s) "
                             f"{np.unique(self.system[unknown]).tolist()}")
        return satellite_key(sysi, np.where(self.mask, prn, -1))

    @property
    def n_epochs(self) -> int:
        """M."""
        return self.t.shape[0]

    @property
    def n_channels(self) -> int:
        """C."""
        return self.mask.shape[1]

    def n_used(self) -> np.ndarray:
        """(M,) int64 valid channels per epoch."""
        return self.mask.sum(-1, dtype=np.int64)

    def keep(self, keep) -> "GnssEpochs":
        """A copy whose mask is ``mask & keep`` ((M, C) bool); dropped channels are zeroed."""
        keep = np.asarray(keep, bool)
        if keep.shape != self.mask.shape:
            raise ValueError(f"keep must have shape {self.mask.shape}, got {keep.shape}")
        mask = self.mask & keep
        off = ~mask
        out = {}
        for f in fields(self):
            a = getattr(self, f.name)
            if f.name in ("t", "t0_gps", "source", "mask") or a is None:
                continue
            a = np.array(a, copy=True)
            a[off] = -1 if f.name == "sat_id" else 0
            out[f.name] = a
        return replace(self, mask=mask, **out)

    def with_sigma_model(self, model, source=None) -> "GnssEpochs":
        """A copy whose ``pr_sigma`` is ``model``'s (an :class:`envs.sim.sigma_models.SigmaModel`) at the recorded
        elevation and C/N0 (:func:`envs.sim.sigma_models.model_pr_sigma`); itself for ``'receiver'``.

        Raises ``ValueError`` naming ``source`` (default :attr:`source`) when a C/N0 model meets a valid
        channel without a C/N0 (0 dB-Hz: a RINEX file without the ``S`` observable of the code used).
        """
        from ..sim.sigma_models import model_pr_sigma
        if model.name == "receiver":
            return self
        sigma = model_pr_sigma(model, self.pr_sigma, self.mask, self.elevation, self.cn0,
                               str(source) if source is not None else self.source)
        return replace(self, pr_sigma=sigma)

    def window(self, t0: float, t1: float) -> "GnssEpochs":
        """The epochs with ``t0 <= t <= t1`` (times unchanged)."""
        sel = (self.t >= t0) & (self.t <= t1)
        if not sel.any():
            raise ValueError(f"no epoch in [{t0}, {t1}] (epochs span [{self.t[0]}, {self.t[-1]}])")
        out = {f.name: getattr(self, f.name)[sel] for f in fields(self)
               if f.name not in ("t0_gps", "source") and getattr(self, f.name) is not None}
        return replace(self, **out)


def pack_epochs(t_rows, sys_rows, id_rows, columns: dict, what: str = "rows") -> tuple[np.ndarray, np.ndarray, dict]:
    """Group measurement rows by epoch time onto padded channels.

    Rows with equal ``t`` form one epoch; channels keep the rows' order within
    the epoch. A satellite ((system, id) pair) may appear once per epoch.

    Parameters
    ----------
    t_rows : (K,) epoch time of each row [s]; sys_rows, id_rows : (K,) int.
    columns : name -> (K, ...) per-row values to pack.
    what : name of the rows for error messages.

    Returns
    -------
    t : (M,) unique times; index : (M, C) row index (-1 on empty channels);
    packed : name -> (M, C, ...) with zeros on empty channels.
    """
    t_rows = np.asarray(t_rows, np.float64)
    order = np.argsort(t_rows, kind="stable")
    t, first, counts = np.unique(t_rows[order], return_index=True, return_counts=True)
    M, C = t.size, int(counts.max())
    slot = np.arange(t_rows.size) - np.repeat(first, counts)
    ep = np.repeat(np.arange(M), counts)
    index = np.full((M, C), -1, np.int64)
    index[ep, slot] = order
    key = np.asarray(sys_rows, np.int64) * 100_000 + np.asarray(id_rows, np.int64)
    kk = np.where(index >= 0, key[np.maximum(index, 0)], -1)
    srt = np.sort(kk, axis=1)
    dup = (srt[:, 1:] == srt[:, :-1]) & (srt[:, 1:] >= 0)
    if dup.any():
        j = int(np.argmax(dup.any(1)))
        raise ValueError(f"{what}: a satellite appears twice in the epoch at t = {t[j]!r} s")
    valid = index >= 0
    packed = {}
    for name, col in columns.items():
        col = np.asarray(col)
        out = col[np.maximum(index, 0)]
        out[~valid] = 0
        packed[name] = out
    return t, index, packed


def satellite_velocities(t, sat_pos, sat_key, mask) -> np.ndarray:
    """Satellite ECEF velocities by differentiating each satellite's track of recorded positions.

    For sources that give satellite positions but no velocities (smartLoc).
    Each satellite's positions over the epochs it is tracked are interpolated
    by a cubic spline in time (not-a-knot) and differentiated. The orbit is
    smooth on these time scales: the interpolation error of a cubic through
    points ``h`` apart is ``~ h^4 |r''''| / 384`` with ``|r''''| ~ n^4 a <= 2e-8
    m/s^4`` for GNSS orbits, below 1 mm even across a 100 s tracking gap, and
    its derivative below 1e-4 m/s. A satellite seen at exactly two epochs gets
    the chord velocity; one seen at a single epoch gets zero (its velocity is
    unknown; it matters only for pseudorange rates, which such sources lack).

    Parameters
    ----------
    t : (M,) epoch times [s]; sat_pos : (M, C, 3) [m]; sat_key : (M, C) int
        satellite identity (equal keys = same satellite); mask : (M, C) bool.

    Returns
    -------
    (M, C, 3) float64 [m/s], zero on empty channels.
    """
    t = np.asarray(t, np.float64)
    vel = np.zeros(np.shape(sat_pos), np.float64)
    keys = np.unique(np.asarray(sat_key)[mask])
    for k in keys:  # loop over satellites (tens), vectorized over its epochs
        m_idx, c_idx = np.nonzero(mask & (sat_key == k))
        if m_idx.size < 2:
            continue
        tt, pp = t[m_idx], sat_pos[m_idx, c_idx]
        if m_idx.size == 2:
            vel[m_idx, c_idx] = (pp[1] - pp[0]) / (tt[1] - tt[0])
            continue
        spl = make_interp_spline(tt, pp, k=3, axis=0)
        vel[m_idx, c_idx] = spl.derivative()(tt)
    return vel
