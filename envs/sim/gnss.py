"""The simulated GNSS world: receiver clock, pseudoranges, pseudorange rates, degradations.

Everything is batched over a leading axis ``B`` (one row per independent run)
and vectorized over the ``M`` epochs; row ``i`` draws its random numbers only
from its own generator ``rngs[i]`` (see :mod:`envs.sim.rng`), so a run with
``B = 1`` and a seed equals row ``i`` of any larger batch with that seed.

Measurement model (Groves 2nd ed. ch. 8 pseudo-range and pseudo-range-rate models, single-frequency code and
Doppler after the broadcast satellite clock, Klobuchar and tropospheric model
corrections have been applied; their residuals are simulated)::

    pr  = rho + b_r + m_T(el) T_z + F_I(el) I_j + B_nlos + s(t) k_nlos sigma_pr(el) n
    prr = rho_dot + d_r + D_nlos                + s(t) k_nlos sigma_prr(el) n'

* ``rho``, ``rho_dot``: geometric range and range rate with the Sagnac
  correction from :func:`earth.ranging.range_and_rate` (the very function the
  tightly coupled filter uses to predict them), the satellite at the
  *transmission* time.
* ``b_r``, ``d_r``: receiver clock bias [m] and drift [m/s], the two-state
  clock process of :class:`ClockModel`.
* ``T_z``: residual zenith tropospheric delay [m], one first-order
  Gauss-Markov process per row (common to all satellites), mapped with the
  RTCA DO-229 mapping function ``m_T = 1.001 / sqrt(0.002001 + sin^2 el)``
  (= 1/sin(el) above ~15 deg, finite at the horizon).
* ``I_j``: residual vertical ionospheric delay after the Klobuchar model [m],
  one first-order Gauss-Markov process per satellite (different pierce
  points), mapped with the Klobuchar obliquity factor
  ``F_I = 1 + 16 (0.53 - el/pi)^3`` (IS-GPS-200 20.3.3.5.2.5, el in semicircles).
* ``B_nlos``, ``D_nlos``: non-line-of-sight / multipath errors (bursts and
  urban-canyon reflections, :class:`NlosConfig`, :class:`UrbanCanyon`).
* ``n``, ``n'``: white unit Gaussian noise; ``sigma_pr(el) = pr_sigma_m /
  sin(el)`` and ``sigma_prr(el) = prr_sigma_mps / sin(el)`` (code tracking
  noise plus multipath grows as the signal gets weaker near the horizon);
  ``s(t)`` the :attr:`GnssEvents.noise_scale` multiplier and ``k_nlos`` the
  NLOS extra-noise factor (1 outside bursts). The random events of
  :mod:`envs.sim.events` multiply ``s(t) k_nlos`` further (code and Doppler
  separately): random bursts and noise regimes per epoch, the zone / NLOS
  C/N0 loss ``10^(loss/20)`` (replacing ``k_nlos`` on their NLOS channels)
  and the re-acquisition transient per channel; zone and regime NLOS
  channels carry the smartLoc-measured log-normal bias instead of the burst
  / canyon one.

The sigmas the receiver *reports* (:attr:`GnssData.pr_sigma`,
:attr:`GnssData.prr_sigma`) are nominal: they never see ``s(t)`` nor NLOS (an
adaptive filter has to discover them), and ``pr_sigma`` includes the nominal
atmospheric residuals::

    pr_sigma^2  = (pr_sigma_m / sin el)^2 + (m_T tropo_zenith_sigma_m)^2 + (F_I iono_zenith_sigma_m)^2
    prr_sigma   = prr_sigma_mps / sin el

both times the :class:`~envs.sim.events.SigmaMismatch` factor when one is
configured. A :attr:`ReceiverConfig.sigma_model` other than ``'receiver'``
replaces the first line by its model of the channel's elevation and reported
C/N0 (:mod:`envs.sim.sigma_models`). The oracle truth :attr:`GnssData.pr_var_true` is the same sum
with the true (multiplied) white sigma and the NLOS bias squared added.

Satellite clock and ephemeris errors are assumed corrected (residuals of a few
decimetres are part of ``pr_sigma_m``). Satellite positions in :class:`GnssData`
are those an ephemeris gives at the true transmission time.

Precision: all computation is float64; ``dtype=np.float32`` casts the outputs
at the end. A float32 pseudorange of ~2.2e7 m has a resolution of 2 m (ulp),
so float32 consumers should form innovations ``pr - rho_hat`` carefully.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numba as nb
import numpy as np
from scipy.signal import lfilter

from earth.ranging import range_and_rate
from earth.wgs84 import C_LIGHT, OMEGA_IE, ecef_to_geodetic

from . import events as ev
from .constellation import Constellation, _check_int, _check_pair, _check_real
from .events import NoiseRegimes, RandomBursts, Reacquisition, SigmaMismatch, UrbanZones
from .sigma_models import SigmaModel

__all__ = [
    "Constellation", "ClockModel", "ReceiverConfig", "NlosConfig", "UrbanCanyon", "GnssEvents",
    "GnssData", "simulate_clock", "simulate_gnss", "tropo_mapping", "iono_obliquity", "EVENT_PRESETS",
    "GPS_WEEK_S", "RandomBursts", "SigmaMismatch", "NoiseRegimes", "UrbanZones", "Reacquisition",
]

GPS_WEEK_S = 604_800.0
"""Seconds in a GPS week: ``t0_gps`` is drawn uniformly in [0, GPS_WEEK_S)."""

# fixed child-stream indices of a row's generator inside simulate_gnss: a component
# added later gets a new index and never shifts another component's draws.
_SUB_SKY, _SUB_CLOCK, _SUB_TROPO, _SUB_IONO, _SUB_CODE, _SUB_RATE, _SUB_NLOS, _SUB_CANYON = range(8)
# issue 16 (random events): SeedSequence.spawn keys its children by index, so spawning more
# children leaves the first 8 streams, and every pre-existing draw, unchanged (tested).
(_SUB_BURSTS, _SUB_MISMATCH, _SUB_REGIME, _SUB_REGIME_NLOS, _SUB_ZONES, _SUB_ZONE_GEOM, _SUB_ZONE_SAT,
 _SUB_CN0) = range(8, 16)
_N_SUB = 16
CN0_JITTER_DB = 1.0
"""Sigma of the receiver's C/N0 estimate per epoch [dB] (assumption: a 1 s C/N0 estimator at 35-45 dB-Hz)."""
_MIN_EL_SIGMA = math.radians(1.0)
"""The 1/sin(el) sigma model is evaluated at max(el, 1 deg) (finite at a 0-deg mask)."""
_CHUNK_ELEMS = 50_000
"""Satellite-epochs per vectorized geometry block and tracked channels per ranging block (cache-sized; results
do not depend on it)."""


# =============================================================================
# validation helpers
# =============================================================================
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


def _in_intervals(t: np.ndarray, intervals) -> np.ndarray:
    """Boolean (M,) : ``t`` lies in any half-open interval ``[t0, t1)``."""
    out = np.zeros(t.shape, dtype=bool)
    for iv in intervals:
        out |= (t >= iv[0]) & (t < iv[1])
    return out


# =============================================================================
# receiver clock
# =============================================================================
@dataclass(frozen=True)
class ClockModel:
    """Receiver clock: two-state (bias, drift) random process in metres.

    Power-law model of the oscillator's fractional frequency (Allan-variance
    coefficients ``h_alpha``) reduced to the two-state model of Brown & Hwang
    (*Introduction to Random Signals and Applied Kalman Filtering*, 4th ed.,
    ch. 9, receiver clock model) and Groves 2nd ed. ch. 9 (clock phase / frequency PSDs
    ``S_cphi``, ``S_cf``); the flicker term ``h_-1`` is omitted, as in the
    two-state model::

        q_bias  = h_0 / 2 * c^2            [m^2/s]    (white frequency -> bias random walk)
        q_drift = 2 pi^2 h_-2 * c^2        [m^2/s^3]  (random-walk frequency -> drift random walk)

    Defaults are Brown & Hwang's typical TCXO Allan coefficients (the values
    Kaplan & Hegarty, *Understanding GPS*, 2nd ed., also quote for a TCXO):
    ``h_0 = 2e-19 s``, ``h_-2 = 2e-20 1/s``, giving
    ``q_bias = 0.009 m^2/s`` and ``q_drift = 0.036 m^2/s^3`` (Groves quotes
    0.01 and 0.04 as typical TCXO values).

    Parameters
    ----------
    h0 : float
        White-frequency Allan coefficient ``h_0`` [s], >= 0.
    h_minus2 : float
        Random-walk-frequency Allan coefficient ``h_-2`` [1/s], >= 0.
    init_bias_sigma_m : float
        Standard deviation of the initial clock bias [m], Gaussian, zero mean.
        Default 1e5 m (0.33 ms: a receiver keeps its clock within ~1 ms of GPS time).
    init_drift_sigma_mps : float
        Standard deviation of the initial clock drift [m/s], Gaussian, zero
        mean. Default 100 m/s (0.33 ppm, a TCXO's frequency offset).
    """

    h0: float = 2e-19
    h_minus2: float = 2e-20
    init_bias_sigma_m: float = 1e5
    init_drift_sigma_mps: float = 100.0

    def __post_init__(self):
        o = "ClockModel"
        for name in ("h0", "h_minus2", "init_bias_sigma_m", "init_drift_sigma_mps"):
            _check_real(o, name, getattr(self, name), lo=0.0)

    @classmethod
    def tcxo(cls, **kw) -> "ClockModel":
        """Temperature-compensated crystal (Brown & Hwang: h0 = 2e-19, h-2 = 2e-20)."""
        return cls(h0=2e-19, h_minus2=2e-20, **kw)

    @classmethod
    def ocxo(cls, **kw) -> "ClockModel":
        """Oven-controlled crystal (Brown & Hwang: h0 = 2e-25, h-2 = 6e-25)."""
        return cls(h0=2e-25, h_minus2=6e-25, **kw)

    @classmethod
    def ideal(cls) -> "ClockModel":
        """A perfect clock: zero bias and drift at all times."""
        return cls(h0=0.0, h_minus2=0.0, init_bias_sigma_m=0.0, init_drift_sigma_mps=0.0)

    @property
    def q_bias(self) -> float:
        """Bias random-walk PSD ``h_0 / 2 c^2`` [m^2/s]."""
        return 0.5 * self.h0 * C_LIGHT**2

    @property
    def q_drift(self) -> float:
        """Drift random-walk PSD ``2 pi^2 h_-2 c^2`` [m^2/s^3]."""
        return 2.0 * math.pi**2 * self.h_minus2 * C_LIGHT**2

    def discrete_Q(self, dt):
        """Exact discrete process noise of the two-state clock over ``dt``.

        Integrated random walk (Brown & Hwang 4th ed. ch. 9): ``Q = int_0^dt Phi(s) diag(q_b, q_d) Phi(s)^T ds``
        with ``Phi(s) = [[1, s], [0, 1]]``::

            Q = [[q_b dt + q_d dt^3/3, q_d dt^2/2],
                 [q_d dt^2/2,          q_d dt    ]]

        Parameters
        ----------
        dt : (...,) array_like, time step [s], >= 0.

        Returns
        -------
        (..., 2, 2) float64 [m^2, m^2/s; m^2/s, m^2/s^2].
        """
        dt = np.asarray(dt, dtype=np.float64)
        qb, qd = self.q_bias, self.q_drift
        Q = np.empty(dt.shape + (2, 2))
        Q[..., 0, 0] = qb * dt + qd * dt**3 / 3.0
        Q[..., 0, 1] = Q[..., 1, 0] = qd * dt**2 / 2.0
        Q[..., 1, 1] = qd * dt
        return Q


def _check_times(t) -> np.ndarray:
    """(M,) finite, strictly increasing float64 epochs, else ``ValueError`` naming ``t``."""
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1 or t.size < 1:
        raise ValueError(f"t must be a non-empty 1-D array of epochs [s], got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("t must be finite")
    if t.size > 1 and np.any(np.diff(t) <= 0.0):
        raise ValueError("t must be strictly increasing")
    return t


def _check_rngs(rngs) -> list:
    if isinstance(rngs, np.random.Generator) or not hasattr(rngs, "__len__") or len(rngs) == 0:
        raise ValueError("rngs must be a non-empty list of numpy Generators (one per row)")
    for i, g in enumerate(rngs):
        if not isinstance(g, np.random.Generator):
            raise ValueError(f"rngs[{i}] must be a numpy.random.Generator, got {type(g).__name__}")
    return list(rngs)


def simulate_clock(t, rngs, clock: ClockModel | None = None):
    """Receiver clock bias and drift at the epochs ``t``, exact discrete propagation.

    Two-state model ``x = [b, d]``: ``b_k+1 = b_k + dt_k d_k + w_b``,
    ``d_k+1 = d_k + w_d`` with ``w ~ N(0, Q(dt_k))`` of
    :meth:`ClockModel.discrete_Q` (Brown & Hwang ch. 9). The correlated
    increments are drawn through the 2x2 Cholesky factor of ``Q(dt_k)`` and
    accumulated by cumulative sums (no loop over epochs).

    Per row ``i`` the draws from ``rngs[i]`` are, in this order: 2 standard
    normals (initial bias, drift), then ``(M-1, 2)`` standard normals.

    Parameters
    ----------
    t : (M,) array_like
        Strictly increasing epochs [s].
    rngs : list of B numpy.random.Generator
        One generator per row.
    clock : ClockModel, optional
        Clock parameters (default ``ClockModel()``, a TCXO).

    Returns
    -------
    bias_m : (B, M) float64
        Clock bias expressed as a range [m].
    drift_mps : (B, M) float64
        Clock drift expressed as a range rate [m/s].
    """
    t = _check_times(t)
    rngs = _check_rngs(rngs)
    clock = ClockModel() if clock is None else clock
    if not isinstance(clock, ClockModel):
        raise ValueError(f"clock must be a ClockModel, got {type(clock).__name__}")
    B, M = len(rngs), t.size
    dt = np.diff(t)
    Q = clock.discrete_Q(dt)                                       # (M-1, 2, 2)
    l11 = np.sqrt(Q[:, 0, 0])
    l21 = np.divide(Q[:, 1, 0], l11, out=np.zeros_like(l11), where=l11 > 0.0)
    l22 = np.sqrt(np.maximum(Q[:, 1, 1] - l21 * l21, 0.0))
    z0 = np.empty((B, 2))
    z = np.empty((B, M - 1, 2))
    for i, g in enumerate(rngs):
        z0[i] = g.standard_normal(2)
        z[i] = g.standard_normal((M - 1, 2))
    wb = l11 * z[..., 0]                                           # (B, M-1)
    wd = l21 * z[..., 0] + l22 * z[..., 1]
    drift = np.empty((B, M))
    drift[:, 0] = clock.init_drift_sigma_mps * z0[:, 1]
    drift[:, 1:] = drift[:, :1] + np.cumsum(wd, axis=1)
    bias = np.empty((B, M))
    bias[:, 0] = clock.init_bias_sigma_m * z0[:, 0]
    bias[:, 1:] = bias[:, :1] + np.cumsum(dt * drift[:, :-1] + wb, axis=1)
    return bias, drift


def _gauss_markov(t: np.ndarray, tau: float, sigma: float, z: np.ndarray) -> np.ndarray:
    """Stationary first-order Gauss-Markov process sampled exactly at ``t``.

    ``x_0 = sigma z_0``, ``x_k = a_k x_k-1 + sigma sqrt(1 - a_k^2) z_k``,
    ``a_k = exp(-dt_k / tau)``: the exact discretization of
    ``dx/dt = -x / tau + w`` (first-order Gauss-Markov process, Brown & Hwang
    4th ed. ch. 2; Groves 2nd ed. ch. 3). Uniform steps use ``scipy.signal.lfilter``;
    non-uniform steps a blocked cumulative-product solution (no epoch loop).

    Parameters
    ----------
    t : (M,) strictly increasing epochs [s].
    tau : correlation time [s], > 0.
    sigma : stationary standard deviation.
    z : (M, ...) standard normal draws.

    Returns
    -------
    (M, ...) float64 samples.
    """
    x0 = sigma * z[0]
    if t.size == 1:
        return x0[None].copy() if np.ndim(x0) else np.array([x0])
    dt = np.diff(t)
    a = np.exp(-dt / tau)
    e = sigma * np.sqrt(-np.expm1(-2.0 * dt / tau)).reshape((-1,) + (1,) * (z.ndim - 1)) * z[1:]
    if np.all(np.abs(dt - dt[0]) <= 1e-9 * abs(dt[0])):      # uniform: np.allclose(dt, dt[0], rtol=1e-9, atol=0)
        a0 = float(a[0])
        y, _ = lfilter([1.0], [1.0, -a0], e, axis=0, zi=(a0 * x0)[None])
        return np.concatenate([x0[None], y], axis=0)
    # non-uniform: x_k = P_k (x_prev + sum_j e_j / P_j) within blocks where -log P stays < 600
    la = np.maximum(-dt / tau, -300.0)
    out = np.empty(z.shape)
    out[0] = x0
    cum = np.cumsum(-la)
    block = np.floor(cum / 300.0).astype(np.int64)
    starts = np.flatnonzero(np.r_[True, block[1:] != block[:-1]])
    ends = np.r_[starts[1:], block.size]
    x_prev = x0
    shape = (-1,) + (1,) * (z.ndim - 1)
    for s, f in zip(starts, ends):                       # a few blocks, not epochs
        L = np.cumsum(la[s:f]).reshape(shape)            # log P relative to the block start
        xs = np.exp(L) * (x_prev + np.cumsum(e[s:f] * np.exp(-L), axis=0))
        out[s + 1:f + 1] = xs
        x_prev = xs[-1]
    return out


# =============================================================================
# receiver
# =============================================================================
@dataclass(frozen=True)
class ReceiverConfig:
    """A single-frequency (L1 C/A) receiver and the residual errors it sees.

    Parameters
    ----------
    n_channels : int
        Number of tracking channels C; visible satellites sorted by elevation
        (descending) fill them, the rest are masked out.
    elevation_mask_deg : float
        Elevation mask [deg], in [0, 89].
    pr_sigma_m : float
        Zenith code noise incl. multipath [m], scaled by ``1/sin(el)``
        (0.8 m at zenith -> 4.6 m at 10 deg), >= 0.
    prr_sigma_mps : float
        Zenith pseudorange-rate (Doppler) noise [m/s], scaled by ``1/sin(el)``, >= 0.
    tropo_zenith_sigma_m : float
        Stationary sigma of the residual zenith tropospheric delay [m] (after
        a standard tropo model: ~0.1-0.2 m), >= 0.
    tropo_tau_s : float
        Correlation time of the tropospheric residual [s], > 0.
    iono_zenith_sigma_m : float
        Stationary sigma of the residual vertical ionospheric delay after the
        Klobuchar model [m] (Klobuchar removes ~50 %: ~0.5-1 m left), >= 0.
    iono_tau_s : float
        Correlation time of the ionospheric residual [s], > 0.
    clock : ClockModel
        Receiver clock (default TCXO).
    sigma_model : SigmaModel
        The model of the reported pseudorange sigma (:mod:`envs.sim.sigma_models`); the default
        ``'receiver'`` keeps the nominal model of the module docstring. Another model replaces the nominal
        ``pr_sigma`` by its value at the channel's elevation and reported C/N0 (``cn0_dbhz``: NLOS and zone
        attenuation included); a :class:`~envs.sim.events.SigmaMismatch` factor still multiplies it. The true
        errors do not depend on it.
    """

    n_channels: int = 16
    elevation_mask_deg: float = 10.0
    pr_sigma_m: float = 0.8
    prr_sigma_mps: float = 0.05
    tropo_zenith_sigma_m: float = 0.15
    tropo_tau_s: float = 1800.0
    iono_zenith_sigma_m: float = 0.7
    iono_tau_s: float = 1800.0
    clock: ClockModel = field(default_factory=ClockModel)
    sigma_model: SigmaModel = field(default_factory=SigmaModel)

    def __post_init__(self):
        o = "ReceiverConfig"
        _check_int(o, "n_channels", self.n_channels, lo=1)
        _check_real(o, "elevation_mask_deg", self.elevation_mask_deg, lo=0.0, hi=89.0)
        for name in ("pr_sigma_m", "prr_sigma_mps", "tropo_zenith_sigma_m", "iono_zenith_sigma_m"):
            _check_real(o, name, getattr(self, name), lo=0.0)
        for name in ("tropo_tau_s", "iono_tau_s"):
            _check_real(o, name, getattr(self, name), lo=0.0, lo_open=True)
        if not isinstance(self.clock, ClockModel):
            raise ValueError(f"{o}.clock must be a ClockModel, got {type(self.clock).__name__}")
        if not isinstance(self.sigma_model, SigmaModel):
            raise ValueError(f"{o}.sigma_model must be a SigmaModel, got {type(self.sigma_model).__name__}")

    @classmethod
    def dual_frequency(cls, **kw) -> "ReceiverConfig":
        """A receiver with a small atmosphere residual: dual-frequency (L1/L5) iono-free, SBAS-grade troposphere.

        The first-order ionospheric delay (> 99.9 % of it) cancels in the
        iono-free combination; what is left is the higher-order terms (cm)
        and inter-frequency bias errors: assumption ``iono_zenith_sigma_m =
        0.1`` m (conservative; the SBAS-corrected single-frequency user's
        vertical iono error, after GIVE-level grid corrections, is of the same
        order). The troposphere residual is RTCA DO-229 A.4.2.4's
        ``sigma_tvert = 0.12`` m. The zenith code noise stays 0.8 m
        (assumption: the iono-free combination amplifies the noise by ~2.6 on
        L1/L5, offset by L5's ten times faster chipping rate). With these,
        white-noise mismatch is no longer swamped by the slow atmosphere
        residual (default receiver: 0.7 m iono, 0.15 m tropo zenith).
        """
        base = dict(tropo_zenith_sigma_m=0.12, iono_zenith_sigma_m=0.1)
        base.update(kw)
        return cls(**base)

    @classmethod
    def geodetic(cls, **kw) -> "ReceiverConfig":
        """A geodetic-grade receiver: small code and Doppler noise, a centimetre-level atmosphere residual.

        Zenith code noise incl. multipath 0.1 m (assumption: narrow-correlator
        tracking and a choke-ring antenna; geodetic data sheets quote code
        precisions of a few cm to ~0.25 m), Doppler 0.01 m/s (assumption:
        carrier-aided tracking, mm/s-level precision, multipath left room),
        dual-frequency iono-free with 0.02 m higher-order ionosphere and
        0.02 m zenith troposphere after a network ZTD correction
        (assumptions: cm-level real-time products). The receiver clock stays
        the default TCXO.
        """
        base = dict(pr_sigma_m=0.1, prr_sigma_mps=0.01, tropo_zenith_sigma_m=0.02, iono_zenith_sigma_m=0.02)
        base.update(kw)
        return cls(**base)

    @classmethod
    def ideal(cls, **kw) -> "ReceiverConfig":
        """No noise, no atmospheric residual, a perfect clock (geometry checks)."""
        base = dict(pr_sigma_m=0.0, prr_sigma_mps=0.0, tropo_zenith_sigma_m=0.0,
                    iono_zenith_sigma_m=0.0, clock=ClockModel.ideal())
        base.update(kw)
        return cls(**base)


def tropo_mapping(el):
    """Tropospheric mapping function ``1.001 / sqrt(0.002001 + sin^2 el)`` (RTCA DO-229, A.4.2.4).

    Parameters
    ----------
    el : (...) elevation [rad].

    Returns
    -------
    (...) dimensionless, ~1/sin(el) above 15 deg, 22.4 at the horizon.
    """
    s = np.sin(el)
    return 1.001 / np.sqrt(0.002001 + s * s)


def iono_obliquity(el):
    """Klobuchar obliquity factor ``F = 1 + 16 (0.53 - E)^3``, E = el / pi (IS-GPS-200 20.3.3.5.2.5).

    Parameters
    ----------
    el : (...) elevation [rad].

    Returns
    -------
    (...) dimensionless, 1.0 at zenith, ~3 at the horizon.
    """
    return 1.0 + 16.0 * (0.53 - np.asarray(el) / np.pi) ** 3


# =============================================================================
# degradations
# =============================================================================
@dataclass(frozen=True)
class NlosConfig:
    """Non-line-of-sight / strong-multipath bursts, independent per satellite.

    Each satellite alternates clean intervals, exponentially distributed with
    rate ``rate_hz`` (bursts per second of clean time, a Poisson process), and
    bursts of duration ``U(duration_s)``. During a burst the pseudorange
    carries a constant positive bias ``U(bias_m)`` (the reflected path is
    longer), the rate a constant error ``N(0, rate_sigma_mps^2)``, and both
    white noises are multiplied by ``noise_factor``.

    Parameters
    ----------
    rate_hz : float
        Burst rate per satellite per second of clean time [1/s], >= 0.
    duration_s : (float, float)
        Burst duration range [s], 0 < min <= max.
    bias_m : (float, float)
        Pseudorange bias range [m], 0 <= min <= max.
    rate_sigma_mps : float
        Sigma of the constant pseudorange-rate error of a burst [m/s], >= 0.
    noise_factor : float
        Multiplier of the code and Doppler noise sigma during a burst, >= 1.
    """

    rate_hz: float = 1.0 / 200.0
    duration_s: tuple = (2.0, 20.0)
    bias_m: tuple = (10.0, 80.0)
    rate_sigma_mps: float = 0.3
    noise_factor: float = 3.0

    def __post_init__(self):
        o = "NlosConfig"
        _check_real(o, "rate_hz", self.rate_hz, lo=0.0)
        _check_pair(o, "duration_s", self.duration_s, lo=0.0, lo_open=True)
        _check_pair(o, "bias_m", self.bias_m, lo=0.0)
        _check_real(o, "rate_sigma_mps", self.rate_sigma_mps, lo=0.0)
        _check_real(o, "noise_factor", self.noise_factor, lo=1.0)


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
    :class:`NlosConfig` (3 if no NLOS bursts are configured).

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


@dataclass(frozen=True)
class GnssEvents:
    """Degradations of the GNSS measurements over a run; ``GnssEvents()`` is a clean sky.

    Parameters
    ----------
    outages : tuple of (t0_s, t1_s)
        Full outages [s since start, half-open ``[t0, t1)``]: no satellite tracked.
    noise_scale : tuple of (t0_s, t1_s, scale)
        Multipliers of the *true* code and Doppler noise sigma inside
        ``[t0, t1)`` (overlapping intervals multiply). The sigmas the receiver
        reports stay nominal: an adaptive filter has to notice.
    nlos : NlosConfig or None
        NLOS / multipath bursts (None: none).
    canyon : UrbanCanyon or None
        Street-canyon blockage (None: open sky). Needs the vehicle heading.
    bursts : RandomBursts or None
        Random bursts of the true noise at random times (:mod:`envs.sim.events`).
    mismatch : SigmaMismatch or None
        Piecewise-constant error of the *reported* sigmas.
    regimes : NoiseRegimes or None
        Markov-switching true-noise regimes.
    zones : UrbanZones or None
        Open sky alternating with canyon / tree cover / overpass zones (canyon geometry needs the heading;
        without it only the zones' NLOS probabilities apply).
    reacquisition : Reacquisition or None
        Larger true noise after each (re-)acquisition of a satellite.

    Events compose: :meth:`combine` merges several (intervals concatenate,
    the last non-None ``nlos`` / ``canyon`` / ``bursts`` / ... wins).
    """

    outages: tuple = ()
    noise_scale: tuple = ()
    nlos: NlosConfig | None = None
    canyon: UrbanCanyon | None = None
    bursts: RandomBursts | None = None
    mismatch: SigmaMismatch | None = None
    regimes: NoiseRegimes | None = None
    zones: UrbanZones | None = None
    reacquisition: Reacquisition | None = None

    def __post_init__(self):
        o = "GnssEvents"
        _check_intervals(o, "outages", self.outages, with_scale=False)
        _check_intervals(o, "noise_scale", self.noise_scale, with_scale=True)
        if self.nlos is not None and not isinstance(self.nlos, NlosConfig):
            raise ValueError(f"{o}.nlos must be an NlosConfig or None, got {type(self.nlos).__name__}")
        if self.canyon is not None and not isinstance(self.canyon, UrbanCanyon):
            raise ValueError(f"{o}.canyon must be an UrbanCanyon or None, got {type(self.canyon).__name__}")
        for name, typ in _RANDOM_EVENT_TYPES.items():
            v = getattr(self, name)
            if v is not None and not isinstance(v, typ):
                raise ValueError(f"{o}.{name} must be a {typ.__name__} or None, got {type(v).__name__}")

    # ------------------------------------------------------------- constructors
    @classmethod
    def clean(cls) -> "GnssEvents":
        """Open sky, no event."""
        return cls()

    @classmethod
    def periodic_outages(cls, duration_s: float = 60.0, period_s: float = 180.0,
                         t_start_s: float = 60.0, t_end_s: float = 600.0) -> "GnssEvents":
        """Full outages of ``duration_s`` every ``period_s`` starting at ``t_start_s`` [s] until ``t_end_s`` [s]."""
        _check_real("GnssEvents.periodic_outages", "duration_s", duration_s, lo=0.0, lo_open=True)
        _check_real("GnssEvents.periodic_outages", "period_s", period_s, lo=duration_s)
        _check_real("GnssEvents.periodic_outages", "t_start_s", t_start_s)
        _check_real("GnssEvents.periodic_outages", "t_end_s", t_end_s, lo=t_start_s)
        starts = np.arange(t_start_s, t_end_s, period_s)
        return cls(outages=tuple((float(s), float(min(s + duration_s, t_end_s))) for s in starts))

    @classmethod
    def noise_bursts(cls, scale: float = 5.0, duration_s: float = 30.0, period_s: float = 120.0,
                     t_start_s: float = 60.0, t_end_s: float = 600.0) -> "GnssEvents":
        """Noise sigma multiplied by ``scale`` for ``duration_s`` every ``period_s`` from ``t_start_s`` [s]."""
        o = "GnssEvents.noise_bursts"
        _check_real(o, "scale", scale, lo=0.0)
        _check_real(o, "duration_s", duration_s, lo=0.0, lo_open=True)
        _check_real(o, "period_s", period_s, lo=duration_s)
        _check_real(o, "t_start_s", t_start_s)
        _check_real(o, "t_end_s", t_end_s, lo=t_start_s)
        starts = np.arange(t_start_s, t_end_s, period_s)
        return cls(noise_scale=tuple((float(s), float(min(s + duration_s, t_end_s)), float(scale))
                                     for s in starts))

    @classmethod
    def urban(cls, nlos: NlosConfig | None = None, canyon: UrbanCanyon | None = None) -> "GnssEvents":
        """NLOS bursts and street-canyon blockage with the default parameters."""
        return cls(nlos=NlosConfig() if nlos is None else nlos,
                   canyon=UrbanCanyon() if canyon is None else canyon)

    @classmethod
    def preset(cls, name: str) -> "GnssEvents":
        """Named preset: one of :data:`EVENT_PRESETS` (``ValueError`` otherwise)."""
        if name not in EVENT_PRESETS:
            raise ValueError(f"unknown GnssEvents preset name {name!r}; known: {sorted(EVENT_PRESETS)}")
        return EVENT_PRESETS[name]()

    def combine(self, *others: "GnssEvents") -> "GnssEvents":
        """Merge events: outage / noise intervals concatenate, the last non-None nlos / canyon wins."""
        out = self
        for o in others:
            if not isinstance(o, GnssEvents):
                raise ValueError(f"combine expects GnssEvents, got {type(o).__name__}")
            last = {n: getattr(o, n) if getattr(o, n) is not None else getattr(out, n)
                    for n in ("nlos", "canyon") + tuple(_RANDOM_EVENT_TYPES)}
            out = replace(out, outages=out.outages + o.outages, noise_scale=out.noise_scale + o.noise_scale, **last)
        return out


_RANDOM_EVENT_TYPES = {"bursts": RandomBursts, "mismatch": SigmaMismatch, "regimes": NoiseRegimes,
                       "zones": UrbanZones, "reacquisition": Reacquisition}


EVENT_PRESETS = {
    "clean": GnssEvents.clean,
    "open-sky": GnssEvents.clean,
    "urban": GnssEvents.urban,
    "outage": GnssEvents.periodic_outages,
    "noise-burst": GnssEvents.noise_bursts,
}
"""Named event presets (constructors with default arguments)."""


# =============================================================================
# output
# =============================================================================
@dataclass(frozen=True)
class GnssData:
    """Simulated GNSS measurements of B runs over M epochs on C channels.

    Masked channels (``mask`` False) hold finite zeros and ``prn == -1``.

    Attributes
    ----------
    t : (M,) epoch times [s since start].
    t0_gps : (B,) float64 GPS time of ``t = 0`` per row [s].
    sat_pos : (B, M, C, 3) satellite ECEF position at transmission time [m].
    sat_vel : (B, M, C, 3) satellite ECEF velocity at transmission time [m/s].
    pr : (B, M, C) pseudorange [m].
    prr : (B, M, C) pseudorange rate [m/s].
    pr_sigma : (B, M, C) nominal pseudorange sigma the receiver reports [m].
    prr_sigma : (B, M, C) nominal pseudorange-rate sigma the receiver reports [m/s].
    mask : (B, M, C) bool, valid channel.
    prn : (B, M, C) int64, satellite PRN (index + 1), -1 on empty channels.
    elevation, azimuth : (B, M, C) [rad] (azimuth clockwise from north, [0, 2 pi)).
    clock_bias_m : (B, M) true receiver clock bias [m].
    clock_drift_mps : (B, M) true receiver clock drift [m/s].
    nlos : (B, M, C) bool, the channel carries an NLOS / multipath error.
    pr_error_m : (B, M, C) ``pr - rho - clock_bias`` [m] (atmosphere + NLOS + noise).
    prr_error_mps : (B, M, C) ``prr - rho_dot - clock_drift`` [m/s].
    cn0_dbhz : (B, M, C) C/N0 the receiver reports [dB-Hz] (0 on masked channels); recorded data pass
        their own or None. Simulated: ``cn0_los(el)`` (:func:`envs.sim.events.cn0_los`, smartLoc fit)
        minus the zone / NLOS attenuation, plus ``N(0, CN0_JITTER_DB^2)``.

    Simulator truth for oracles (never used by a filter; None for recorded data):

    pr_var_true : (B, M, C) true variance of each pseudorange error [m^2], as an oracle would give it to a
        Kalman filter: the white-noise variance with every multiplier applied (noise-scale intervals,
        bursts, regimes, NLOS factor, zone attenuation, re-acquisition) + the *nominal* atmosphere
        residual variance exactly as in ``pr_sigma`` (``(m_T sigma_T)^2 + (F_I sigma_I)^2``) + the
        NLOS / multipath bias squared. 1.0 on masked channels.
    prr_var_true : (B, M, C) the same for the pseudorange rate [m^2/s^2]: white variance with every
        multiplier + the NLOS rate error squared. 1.0 on masked channels.
    pr_bias_m : (B, M, C) the NLOS / multipath pseudorange bias [m] (0 on clean and masked channels).
    prr_bias_mps : (B, M, C) the NLOS pseudorange-rate error [m/s].
    event_mask : (B, M) uint16 OR of the :mod:`envs.sim.events` bits active at each epoch
        (``OUTAGE``, ``NOISE``, ``MISMATCH``, ``NLOS_ZONE``, ...; the world adds the IMU bits).
    """

    t: np.ndarray
    t0_gps: np.ndarray
    sat_pos: np.ndarray
    sat_vel: np.ndarray
    pr: np.ndarray
    prr: np.ndarray
    pr_sigma: np.ndarray
    prr_sigma: np.ndarray
    mask: np.ndarray
    prn: np.ndarray
    elevation: np.ndarray
    azimuth: np.ndarray
    clock_bias_m: np.ndarray
    clock_drift_mps: np.ndarray
    nlos: np.ndarray
    pr_error_m: np.ndarray
    prr_error_mps: np.ndarray
    cn0_dbhz: np.ndarray | None = None
    pr_var_true: np.ndarray | None = None
    prr_var_true: np.ndarray | None = None
    pr_bias_m: np.ndarray | None = None
    prr_bias_mps: np.ndarray | None = None
    event_mask: np.ndarray | None = None

    @property
    def shape(self) -> tuple:
        """(B, M, C)."""
        return self.mask.shape

    def n_used(self) -> np.ndarray:
        """Number of valid channels per epoch, (B, M) int64."""
        return self.mask.sum(axis=-1, dtype=np.int64)

    def rows(self, idx) -> "GnssData":
        """The sub-batch of rows ``idx`` (int, slice or index array); ``t`` is shared."""
        if isinstance(idx, (int, np.integer)):
            idx = slice(int(idx), int(idx) + 1)
        def take(name):
            v = getattr(self, name)
            return v if (name == "t" or v is None) else v[idx]
        return GnssData(**{f.name: take(f.name) for f in fields(self)})


# =============================================================================
# simulation
# =============================================================================
class _RowChildren:
    """The ``_N_SUB`` fixed child generators of one row, each built on first use.

    Child ``k`` is ``np.random.default_rng(SeedSequence(entropy).spawn(_N_SUB)[k])``: a spawned child is
    ``SeedSequence(entropy, spawn_key=(k,))``, so building only the children a run uses (a clean sky
    needs 7 of the 16) gives the very same streams at a fraction of the cost (~10 us per child).
    Indexing with an int or a slice returns generators, as a list of all children would.
    """

    __slots__ = ("_words", "_gens")

    def __init__(self, entropy: list):
        self._words = _entropy_words(entropy)
        self._gens = [None] * _N_SUB

    def __len__(self) -> int:
        return _N_SUB

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[j] for j in range(*k.indices(_N_SUB))]
        g = self._gens[k]
        if g is None:
            g = self._gens[k] = np.random.default_rng(
                np.random.SeedSequence(self._words, spawn_key=(range(_N_SUB)[k],)))
        return g


def _entropy_words(entropy: list) -> np.ndarray:
    """The uint32 words ``SeedSequence`` makes of a list of non-negative ints, as a uint32 array.

    ``SeedSequence`` turns each int of its entropy into 32-bit words, least significant first, at
    least one word (0 -> [0]), and takes a uint32 array word for word: ``SeedSequence(words)`` is
    ``SeedSequence(entropy)`` (same pool, same streams; tested), and ~2.5x cheaper to build.
    """
    words = []
    for e in entropy:
        words.append(e & 0xFFFFFFFF)
        e >>= 32
        while e:
            words.append(e & 0xFFFFFFFF)
            e >>= 32
    return np.array(words, dtype=np.uint32)


def _row_children(rng: np.random.Generator) -> _RowChildren:
    """Fixed child generators of one row (one per component), drawn from that row's generator only.

    One draw of 4 integers from ``rng`` is the entropy; child ``k`` (``0 .. _N_SUB-1``) is the ``k``-th
    child of ``SeedSequence(entropy)`` (built lazily, see :class:`_RowChildren`).
    """
    entropy = rng.integers(0, 2**63, size=4, dtype=np.int64)
    return _RowChildren([int(x) for x in entropy])


def _geometry(t_rx: np.ndarray, r_e: np.ndarray, constellation: Constellation, lat: np.ndarray,
              lon: np.ndarray):
    """Transmission time, elevation and azimuth of all satellites (one time chunk).

    The transmission time is ``t_tx = t_rx - tau`` with ``tau = |r_s(t_rx) -
    r_r| / c``, one light-time iteration: ``tau`` is off by < 0.5 us (the
    range changes by <~ 150 m during the ~70 ms flight), i.e. < 2 mm of
    satellite motion, and the ephemeris position at ``t_tx`` is exactly the
    one the pseudorange is generated from, so the data stay self-consistent.

    Elevation and azimuth use the line of sight to ``C_z(OMEGA_IE tau)
    (r_s - v_s tau)`` (Groves eq 8.36 with a first-order satellite back
    propagation; < 2 mm of position, < 1e-9 rad of direction).

    Parameters
    ----------
    t_rx : (B, m) GPS reception time [s]; r_e : (B, m, 3) [m]; lat, lon : (B, m) [rad].

    Returns
    -------
    t_tx, el, az : (B, m, S) [s, rad, rad]
    """
    p, v = constellation.positions_velocities(t_rx)        # (B, m, S, 3)
    d = p - r_e[..., None, :]
    tau = np.sqrt(np.einsum("...i,...i->...", d, d)) / C_LIGHT
    t_tx = t_rx[..., None] - tau
    th = OMEGA_IE * tau
    # elevation / azimuth from the NED components of the (unnormalized) line of sight
    n, e, up = _los_ned(p, v, tau, np.cos(th), np.sin(th), r_e,
                        np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon))
    el = np.arctan2(up, np.hypot(n, e))
    az = _wrap_2pi(np.arctan2(e, n))
    return t_tx, el, az


@nb.njit(cache=True)
def _los_ned(p, v, tau, c, s, r, sl, cl, so, co):
    """NED components of the line of sight of :func:`_geometry`, one pass (numpy's operation order).

    ``d = C_z(OMEGA_IE tau) (r_s - v_s tau) - r_r`` resolved in the local NED frame:
    ``h = cos(lon) d_x + sin(lon) d_y``, ``n = -sin(lat) h + cos(lat) d_z``,
    ``e = -sin(lon) d_x + cos(lon) d_y``, ``up = cos(lat) h + sin(lat) d_z``.

    Parameters
    ----------
    p, v : (B, m, S, 3) satellite ECEF position [m] / velocity [m/s] at the reception time.
    tau : (B, m, S) signal flight time [s]; c, s : (B, m, S) cos / sin of ``OMEGA_IE tau``.
    r : (B, m, 3) receiver ECEF position [m]; sl, cl, so, co : (B, m) sin / cos of latitude and longitude.

    Returns
    -------
    n, e, up : (B, m, S) [m].
    """
    B, m, S = tau.shape
    n = np.empty((B, m, S))
    e = np.empty((B, m, S))
    up = np.empty((B, m, S))
    for b in range(B):
        for j in range(m):
            for k in range(S):
                px = p[b, j, k, 0] - v[b, j, k, 0] * tau[b, j, k]
                py = p[b, j, k, 1] - v[b, j, k, 1] * tau[b, j, k]
                pz = p[b, j, k, 2] - v[b, j, k, 2] * tau[b, j, k]
                dx = c[b, j, k] * px + s[b, j, k] * py - r[b, j, 0]
                dy = -s[b, j, k] * px + c[b, j, k] * py - r[b, j, 1]
                dz = pz - r[b, j, 2]
                h1 = co[b, j] * dx + so[b, j] * dy
                n[b, j, k] = -sl[b, j] * h1 + cl[b, j] * dz
                e[b, j, k] = -so[b, j] * dx + co[b, j] * dy
                up[b, j, k] = cl[b, j] * h1 + sl[b, j] * dz
    return n, e, up


def _wrap_2pi(x: np.ndarray) -> np.ndarray:
    """``np.mod(x, 2 pi)`` for ``x`` in [-pi, pi] (arctan2's range), without its fmod.

    There ``fmod(x, 2 pi) = x``: np.mod adds ``2 pi`` to a negative ``x`` and turns ``-0.0`` into ``+0.0``
    (``x + 0.0`` does the same), so the result is the same to the bit.
    """
    return np.where(x < 0.0, x + 2.0 * np.pi, x + 0.0)


def _orbit_at(constellation: Constellation, t_sat: np.ndarray, sat_index=None):
    """Positions / velocities of satellite ``s`` at its own time ``t_sat[..., s]``: (..., S) -> (..., S, 3)."""
    if sat_index is None:
        sat_index = np.broadcast_to(np.arange(constellation.n_sats), t_sat.shape)
    # evaluate each (time, satellite) pair: flatten to a trailing axis of length 1
    p, v = constellation.positions_velocities(t_sat, sat_index[..., None])
    return p[..., 0, :], v[..., 0, :]


def _nlos_bursts(t: np.ndarray, n_sats: int, cfg: NlosConfig, g: np.random.Generator):
    """Per-satellite NLOS bursts of one row (alternating renewal process, see :class:`NlosConfig`).

    Returns
    -------
    active : (M, S) bool; bias_m : (M, S) [m]; rate_mps : (M, S) [m/s].
    """
    M = t.size
    active = np.zeros((M, n_sats), dtype=bool)
    bias = np.zeros((M, n_sats))
    rate = np.zeros((M, n_sats))
    if cfg.rate_hz <= 0.0:
        return active, bias, rate
    d_lo, d_hi = cfg.duration_s
    t_begin = t[0] - d_hi                                  # a burst may already run at t[0]
    span = t[-1] - t_begin
    mean_cycle = 1.0 / cfg.rate_hz + 0.5 * (d_lo + d_hi)
    n_exp = span / mean_cycle
    n_cyc = int(math.ceil(n_exp + 6.0 * math.sqrt(n_exp) + 3.0))
    gaps, durs, biases, rates = [], [], [], []
    end = np.full(n_sats, t_begin)
    while True:                                            # almost always one pass
        gp = g.exponential(1.0 / cfg.rate_hz, size=(n_cyc, n_sats))
        du = g.uniform(d_lo, d_hi, size=(n_cyc, n_sats))
        gaps.append(gp), durs.append(du)
        biases.append(g.uniform(cfg.bias_m[0], cfg.bias_m[1], size=(n_cyc, n_sats)))
        rates.append(cfg.rate_sigma_mps * g.standard_normal((n_cyc, n_sats)))
        end = end + np.sum(gp + du, axis=0)
        if np.all(end > t[-1]):
            break
    gp, du = np.concatenate(gaps), np.concatenate(durs)
    bs, rs = np.concatenate(biases), np.concatenate(rates)
    cyc_end = t_begin + np.cumsum(gp + du, axis=0)         # (K, S)
    b_end = cyc_end
    b_start = cyc_end - du
    i0 = np.searchsorted(t, b_start.ravel(), side="left")
    i1 = np.searchsorted(t, b_end.ravel(), side="left")
    sat = np.broadcast_to(np.arange(n_sats), b_start.shape).ravel()
    ident = np.arange(1, b_start.size + 1)
    diff = np.zeros((M + 1, n_sats), dtype=np.int64)
    np.add.at(diff, (i0, sat), ident)                      # bursts of one satellite never overlap
    np.add.at(diff, (i1, sat), -ident)
    burst = np.cumsum(diff[:M], axis=0)                    # 1-based burst id, 0 outside bursts
    active = burst > 0
    k = np.maximum(burst - 1, 0)
    bias = np.where(active, bs.ravel()[k], 0.0)
    rate = np.where(active, rs.ravel()[k], 0.0)
    return active, bias, rate


def _canyon(t, v_e, heading, el, az, cfg: UrbanCanyon, g: np.random.Generator):
    """Street-canyon visibility of one row (see :class:`UrbanCanyon`).

    Parameters
    ----------
    t : (M,) [s]; v_e : (M, 3) [m/s]; heading : (M,) [rad]; el, az : (M, S) [rad].

    Returns
    -------
    blocked : (M, S) bool (not received at all); reflected : (M, S) bool
    (received as NLOS); excess_m : (M, S) reflection excess path [m].
    """
    M, S = el.shape
    speed = np.linalg.norm(v_e, axis=-1)
    dist = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    blk = np.floor(dist / cfg.block_length_m).astype(np.int64)
    K = int(blk.max()) + 1
    heights = g.uniform(cfg.building_height_m[0], cfg.building_height_m[1], size=(K, 2))
    present = g.random((K, 2)) < cfg.blockage_probability
    reflect = g.random((K, S)) < cfg.nlos_probability
    h = np.where(present, heights, 0.0)[blk]                # (M, 2): [left, right]
    sa = np.sin(az - heading[:, None])                      # > 0: right side
    h_side = np.where(sa > 0.0, h[:, 1:2], h[:, 0:1])       # (M, S)
    half_w = 0.5 * cfg.street_width_m
    under = np.tan(np.clip(el, -1.5, 1.5)) * half_w < h_side * np.abs(sa)
    if cfg.intervals:
        under &= _in_intervals(t, cfg.intervals)[:, None]
    refl = under & reflect[blk]
    excess = np.zeros((M, S))
    excess[refl] = cfg.street_width_m * np.cos(el[refl]) * np.abs(sa[refl])   # the reflected few only
    return under & ~refl, refl, excess


def simulate_gnss(t, r_e, v_e, heading, constellation: Constellation, receiver: ReceiverConfig,
                  events: GnssEvents, rngs, t0_gps=None, dtype=np.float64) -> GnssData:
    """Simulate pseudoranges and pseudorange rates of B receivers over M epochs.

    See the module docstring for the measurement model. Steps: satellite
    geometry of all satellites (chunked over time), visibility (elevation
    mask, urban canyon, outages), channel allocation by elevation, then the
    error processes (clock, troposphere, ionosphere, NLOS, white noise), all
    vectorized over time.

    Per row ``i``, ``rngs[i]`` gives one draw of 4 integers that seed fixed
    child streams (0-7: sky epoch, clock, troposphere, ionosphere, code noise,
    Doppler noise, NLOS, canyon; 8-15: random bursts, mismatch, regimes,
    regime NLOS, zone schedule, zone buildings, zone per-satellite draws, C/N0
    jitter): switching an event on or off does not change the other
    components' draws.

    Parameters
    ----------
    t : (M,) array_like
        Strictly increasing epochs [s since start].
    r_e, v_e : (B, M, 3) array_like
        True receiver ECEF position [m] and velocity [m/s] at the epochs.
    heading : (B, M) array_like or None
        Vehicle heading [rad], clockwise from north (NED yaw); needed
        when ``events.canyon`` is set (``events.zones`` without it: no canyon
        blockage geometry, only the zones' NLOS probabilities).
    constellation : Constellation
    receiver : ReceiverConfig
    events : GnssEvents
    rngs : list of B numpy.random.Generator
        One per row (e.g. ``envs.sim.rng.row_generators(seeds, "gnss")``).
    t0_gps : (B,) array_like, optional
        GPS time of ``t = 0`` per row [s]; drawn ``U[0, 604800)`` from each
        row's sky stream if None (a different sky per row).
    dtype : np.float32 or np.float64
        Float type of the outputs (computation is float64; see the module note
        on float32 pseudoranges).

    Returns
    -------
    GnssData
    """
    try:
        ok = np.dtype(dtype) in (np.dtype(np.float32), np.dtype(np.float64))
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"dtype must be np.float32 or np.float64, got {dtype!r}")
    dtype = np.dtype(dtype)
    if not isinstance(constellation, Constellation):
        raise ValueError(f"constellation must be a Constellation, got {type(constellation).__name__}")
    if not isinstance(receiver, ReceiverConfig):
        raise ValueError(f"receiver must be a ReceiverConfig, got {type(receiver).__name__}")
    if not isinstance(events, GnssEvents):
        raise ValueError(f"events must be a GnssEvents, got {type(events).__name__}")
    t = _check_times(t)
    rngs = _check_rngs(rngs)
    B, M = len(rngs), t.size
    r_e = np.asarray(r_e, dtype=np.float64)
    v_e = np.asarray(v_e, dtype=np.float64)
    for name, arr in (("r_e", r_e), ("v_e", v_e)):
        if arr.shape != (B, M, 3):
            raise ValueError(f"{name} must have shape (B, M, 3) = {(B, M, 3)}, got {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} must be finite")
    if heading is not None:
        heading = np.asarray(heading, dtype=np.float64)
        if heading.shape != (B, M):
            raise ValueError(f"heading must have shape (B, M) = {(B, M)}, got {heading.shape}")
        if not np.all(np.isfinite(heading)):
            raise ValueError("heading must be finite")
    elif events.canyon is not None:
        raise ValueError("heading is required when events.canyon is set")

    subs = [_row_children(g) for g in rngs]
    if t0_gps is None:
        t0_gps = np.array([s[_SUB_SKY].uniform(0.0, GPS_WEEK_S) for s in subs])
    else:
        t0_gps = np.asarray(t0_gps, dtype=np.float64)
        if t0_gps.shape != (B,):
            raise ValueError(f"t0_gps must have shape (B,) = {(B,)}, got {t0_gps.shape}")
        if not np.all(np.isfinite(t0_gps)):
            raise ValueError("t0_gps must be finite")

    S, C = constellation.n_sats, receiver.n_channels
    lat, lon, _ = ecef_to_geodetic(r_e)
    t_rx = t0_gps[:, None] + t[None, :]                     # (B, M)

    # ---- geometry of all satellites, chunked over time (bounded memory, cache-sized blocks)
    t_tx = np.empty((B, M, S))
    el_all = np.empty((B, M, S))
    az_all = np.empty((B, M, S))
    chunk = max(1, _CHUNK_ELEMS // (B * S))
    for k0 in range(0, M, chunk):
        sl_ = slice(k0, min(M, k0 + chunk))
        t_tx[:, sl_], el_all[:, sl_], az_all[:, sl_] = _geometry(
            t_rx[:, sl_], r_e[:, sl_], constellation, lat[:, sl_], lon[:, sl_])

    # ---- visibility
    mask_rad = math.radians(receiver.elevation_mask_deg)
    visible = el_all >= mask_rad
    nlos_sat = np.zeros((B, M, S), dtype=bool)
    nlos_bias_sat = np.zeros((B, M, S))
    nlos_rate_sat = np.zeros((B, M, S))
    if events.canyon is not None:
        for i in range(B):
            blocked, refl, excess = _canyon(t, v_e[i], heading[i], el_all[i], az_all[i], events.canyon,
                                            subs[i][_SUB_CANYON])
            visible[i] &= ~blocked
            nlos_sat[i] |= refl
            nlos_bias_sat[i] = excess
    if events.nlos is not None:
        for i in range(B):
            act, bias, rate = _nlos_bursts(t, S, events.nlos, subs[i][_SUB_NLOS])
            nlos_sat[i] |= act
            nlos_bias_sat[i] = np.maximum(nlos_bias_sat[i], bias)
            nlos_rate_sat[i] = rate
    # issue-16 events: each from its own child stream, drawn only when configured
    n_ep = np.ones((B, M)), np.ones((B, M))                  # per-epoch true code / Doppler sigma multipliers
    rep_fac = np.ones((B, M)), np.ones((B, M))               # reported-sigma factors (mismatch)
    bits = np.zeros((B, M), dtype=np.uint16)
    new_nlos = events.zones is not None or (events.regimes is not None
                                            and any(r.nlos_fraction > 0 for r in events.regimes.regimes))
    if new_nlos:                                           # NLOS of the zones / regimes, and their C/N0 loss
        nlos2_sat = np.zeros((B, M, S), dtype=bool)
        bias2_sat = np.zeros((B, M, S))
        rate2_sat = np.zeros((B, M, S))
        att_sat = np.zeros((B, M, S))
    if events.bursts is not None:
        for i in range(B):
            c, d, act, _ = ev.draw_bursts(t, events.bursts, subs[i][_SUB_BURSTS])
            n_ep[0][i] *= c
            n_ep[1][i] *= d
            bits[i] |= np.where(act, ev.NOISE, 0).astype(np.uint16)
    if events.mismatch is not None:
        for i in range(B):
            fp, fd = ev.draw_mismatch(t, events.mismatch, subs[i][_SUB_MISMATCH])
            rep_fac[0][i], rep_fac[1][i] = fp, fd
            bits[i] |= np.where((fp != 1.0) | (fd != 1.0), ev.MISMATCH, 0).astype(np.uint16)
    if events.regimes is not None:
        rg = events.regimes
        sc = np.array([[r.code_scale, r.doppler_scale] for r in rg.regimes])
        for i in range(B):
            regime, _ = ev.draw_regimes(t, rg, subs[i][_SUB_REGIME])
            n_ep[0][i] *= sc[regime, 0]
            n_ep[1][i] *= sc[regime, 1]
            bits[i] |= np.where(regime > 0, ev.REGIME, 0).astype(np.uint16)
            if new_nlos:
                nl, bi, ra = ev.regime_nlos(t, regime, el_all[i], rg, subs[i][_SUB_REGIME_NLOS])
                nl &= visible[i]
                nlos2_sat[i] |= nl
                bias2_sat[i] = np.where(nl, bi, bias2_sat[i])
                rate2_sat[i] = np.where(nl, ra, rate2_sat[i])
    if events.zones is not None:
        for i in range(B):
            kind, zid, windows = ev.draw_zone_schedule(t, events.zones, subs[i][_SUB_ZONES])
            blocked, nl, bi, ra, att = ev.zone_effects(
                t, kind, zid, windows, el_all[i], az_all[i], v_e[i], None if heading is None else heading[i],
                events.zones, subs[i][_SUB_ZONE_GEOM], subs[i][_SUB_ZONE_SAT])
            visible[i] &= ~blocked
            nl &= visible[i]
            nlos2_sat[i] |= nl
            bias2_sat[i] = np.where(nl, bi, bias2_sat[i])
            rate2_sat[i] = np.where(nl, ra, rate2_sat[i])
            att_sat[i] = np.where(visible[i], att, 0.0)
            zb = np.zeros(M, dtype=np.uint16)
            zb[kind == ev.ZONE_CANYON] = ev.NLOS_ZONE
            zb[kind == ev.ZONE_TREES] = ev.NLOS_ZONE | ev.TREES
            zb[kind == ev.ZONE_OVERPASS] = ev.OVERPASS
            bits[i] |= zb
    if new_nlos:                                           # the regimes' NLOS carry the measured C/N0 deficit too
        att_sat = np.where(nlos2_sat & (att_sat == 0.0), ev.NLOS_DEFICIT_DB, att_sat)
    if events.outages:
        in_out = _in_intervals(t, events.outages)
        visible &= ~in_out[None, :, None]
        bits |= np.where(in_out, ev.OUTAGE, 0).astype(np.uint16)[None]
    for iv in events.noise_scale:
        if iv[2] != 1.0:
            bits |= np.where((t >= iv[0]) & (t < iv[1]), ev.NOISE, 0).astype(np.uint16)[None]
    if events.canyon is not None:
        in_c = _in_intervals(t, events.canyon.intervals) if events.canyon.intervals else np.ones(M, bool)
        bits |= np.where(in_c, ev.NLOS_ZONE, 0).astype(np.uint16)[None]
    reacq_sat = None
    if events.reacquisition is not None:
        reacq_sat = ev.reacquisition_multiplier(t, visible, events.reacquisition)

    # ---- channel allocation: visible satellites by elevation, descending
    key = np.where(visible, el_all, -np.inf)
    order = np.argsort(-key, axis=-1, kind="stable")
    if C <= S:
        sel = order[..., :C].copy()
    else:
        sel = np.concatenate([order, np.zeros((B, M, C - S), dtype=order.dtype)], axis=-1)
    # one flat index into (B, M, S) arrays serves every gather (one np.take instead of take_along_axis)
    flat_sel = sel + (S * np.arange(B * M)).reshape(B, M, 1)

    def gather(a):
        """(B, M, S) per-satellite array -> (B, M, C) per-channel array (``a[b, k, sel[b, k, c]]``)."""
        return np.take(a, flat_sel)

    mask = gather(visible)
    if C > S:
        mask[..., S:] = False

    el, az = gather(el_all), gather(az_all)
    cn0_z = np.stack([s[_SUB_CN0].standard_normal((M, S)) for s in subs])     # C/N0 jitter, per satellite
    cn0 = ev.cn0_los(el) + CN0_JITTER_DB * gather(cn0_z)
    del el_all, az_all, key, order, cn0_z
    # ---- ephemeris at transmission time and true range / rate, on the tracked channels only (the
    # others are zeroed at the end; every formula is elementwise, so a value does not depend on which
    # channels are evaluated with it), in blocks of _CHUNK_ELEMS channels
    t_tx_ch = gather(t_tx)
    del t_tx
    sat_pos = np.zeros((B, M, C, 3))
    sat_vel = np.zeros((B, M, C, 3))
    rho = np.zeros((B, M, C))
    rho_dot = np.zeros((B, M, C))
    tracked = np.flatnonzero(mask)                          # flat (b, k, c) index of the tracked channels
    for k0 in range(0, tracked.size, _CHUNK_ELEMS):
        ch = tracked[k0:k0 + _CHUNK_ELEMS]
        epoch = ch // C                                    # flat (b, k) index
        sp, sv = _orbit_at(constellation, t_tx_ch.reshape(-1)[ch], sel.reshape(-1)[ch])
        sat_pos.reshape(-1, 3)[ch], sat_vel.reshape(-1, 3)[ch] = sp, sv
        rho_ch, rho_dot_ch, _ = range_and_rate(sp[:, None], sv[:, None], r_e.reshape(-1, 3)[epoch],
                                               v_e.reshape(-1, 3)[epoch])
        rho.reshape(-1)[ch], rho_dot.reshape(-1)[ch] = rho_ch[:, 0], rho_dot_ch[:, 0]

    # ---- error processes
    clock = receiver.clock
    bias_m, drift_mps = simulate_clock(t, [s[_SUB_CLOCK] for s in subs], clock)
    s_el = np.sin(np.maximum(el, _MIN_EL_SIGMA))
    m_t, f_i = tropo_mapping(el), iono_obliquity(el)
    # the Gauss-Markov processes of all rows in one call each (time axis first; columns are independent)
    tropo_z = _gauss_markov(t, receiver.tropo_tau_s, receiver.tropo_zenith_sigma_m,
                            np.stack([s[_SUB_TROPO].standard_normal(M) for s in subs], axis=1)).T
    iono_sat = _gauss_markov(t, receiver.iono_tau_s, receiver.iono_zenith_sigma_m,   # one process per satellite
                             np.stack([s[_SUB_IONO].standard_normal((M, S)) for s in subs], axis=1))
    iono_ch = gather(iono_sat.transpose(1, 0, 2))
    del iono_sat
    code_z = np.stack([s[_SUB_CODE].standard_normal((M, C)) for s in subs])
    rate_z = np.stack([s[_SUB_RATE].standard_normal((M, C)) for s in subs])
    nlos = gather(nlos_sat) & mask
    nlos_bias, nlos_rate = gather(nlos_bias_sat), gather(nlos_rate_sat)
    del nlos_sat, nlos_bias_sat, nlos_rate_sat
    k_nlos = events.nlos.noise_factor if events.nlos is not None else 3.0
    cn0 -= np.where(nlos, ev.NLOS_DEFICIT_DB, 0.0)
    scale = np.ones(M)
    for iv in events.noise_scale:
        scale = np.where((t >= iv[0]) & (t < iv[1]), scale * iv[2], scale)
    noise_mult = scale[None, :, None] * np.where(nlos, k_nlos, 1.0)
    noise_mult_prr = noise_mult
    if new_nlos:                                           # zone / regime NLOS replace the old ones on a channel
        nlos2 = gather(nlos2_sat) & mask
        att = gather(att_sat)
        nlos_bias = np.where(nlos2, gather(bias2_sat), nlos_bias)
        nlos_rate = np.where(nlos2, gather(rate2_sat), nlos_rate)
        noise_mult = np.where(nlos2 & nlos, noise_mult / k_nlos, noise_mult) * 10.0 ** (att / 20.0)
        nlos = nlos | nlos2
        cn0 -= att
        noise_mult_prr = noise_mult
        del nlos2_sat, bias2_sat, rate2_sat, att_sat
    if reacq_sat is not None:
        rq = gather(reacq_sat)
        noise_mult = noise_mult * rq
        noise_mult_prr = noise_mult_prr * rq
        bits |= np.where((mask & (rq > 1.0)).any(axis=-1), ev.REACQUISITION, 0).astype(np.uint16)
    if events.bursts is not None or events.regimes is not None:
        noise_mult = noise_mult * n_ep[0][..., None]
        noise_mult_prr = noise_mult_prr * n_ep[1][..., None]
    sig_pr_code = receiver.pr_sigma_m / s_el
    sig_prr = receiver.prr_sigma_mps / s_el
    pr_bias = np.where(nlos, nlos_bias, 0.0)
    prr_bias = np.where(nlos, nlos_rate, 0.0)
    pr_white = noise_mult * sig_pr_code
    prr_white = noise_mult_prr * sig_prr
    pr_err = (m_t * tropo_z[..., None] + f_i * iono_ch + pr_bias + pr_white * code_z)
    prr_err = prr_bias + prr_white * rate_z
    pr = rho + bias_m[..., None] + pr_err
    prr = rho_dot + drift_mps[..., None] + prr_err
    atm_var = (m_t * receiver.tropo_zenith_sigma_m) ** 2 + (f_i * receiver.iono_zenith_sigma_m) ** 2
    pr_sigma = np.sqrt(sig_pr_code**2 + (m_t * receiver.tropo_zenith_sigma_m) ** 2
                       + (f_i * receiver.iono_zenith_sigma_m) ** 2)
    if receiver.sigma_model.name != "receiver":             # a variance model replaces the nominal sigma
        with np.errstate(over="ignore"):
            pr_sigma = np.sqrt(receiver.sigma_model.variance(el, cn0))
    pr_var_true = np.where(mask, pr_white**2 + atm_var + pr_bias**2, 1.0)
    prr_var_true = np.where(mask, prr_white**2 + prr_bias**2, 1.0)
    if events.mismatch is not None:
        pr_sigma = pr_sigma * rep_fac[0][..., None]
        sig_prr = sig_prr * rep_fac[1][..., None]

    # ---- masked channels: finite zeros (in place, then one cast); sat_pos / sat_vel (evaluated on the
    # tracked channels only) and the NLOS biases (nlos implies mask) are zero there already
    off = ~mask

    def z(a):
        a[off] = 0.0
        return a.astype(dtype, copy=False)

    def zero_already(a):
        return a.astype(dtype, copy=False)

    prn = np.where(mask, sel + 1, -1).astype(np.int64)
    return GnssData(
        t=t.astype(dtype),
        t0_gps=t0_gps.copy(),
        sat_pos=zero_already(sat_pos), sat_vel=zero_already(sat_vel),
        pr=z(pr), prr=z(prr), pr_sigma=z(pr_sigma), prr_sigma=z(sig_prr),
        mask=mask, prn=prn, elevation=z(el), azimuth=z(az),
        clock_bias_m=bias_m.astype(dtype, copy=False), clock_drift_mps=drift_mps.astype(dtype, copy=False),
        nlos=nlos, pr_error_m=z(pr_err), prr_error_mps=z(prr_err),
        cn0_dbhz=z(cn0), pr_var_true=pr_var_true.astype(dtype), prr_var_true=prr_var_true.astype(dtype),
        pr_bias_m=zero_already(pr_bias), prr_bias_mps=zero_already(prr_bias), event_mask=bits,
    )
