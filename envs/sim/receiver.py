"""The receiver and its own error models: clock, residual atmosphere, code and Doppler noise levels.

:class:`ClockModel` and :func:`simulate_clock` (the two-state receiver clock), :func:`_gauss_markov` (the
first-order Gauss-Markov process of the tropospheric and ionospheric residuals), :class:`ReceiverConfig`
(channels, elevation mask, noise levels, atmosphere residual sizes, the reported-sigma model) and the
mapping functions :func:`tropo_mapping`, :func:`iono_obliquity`. :func:`envs.sim.gnss.simulate_gnss`
draws the measurements with them (its module docstring states the measurement model); everything here is
re-exported there.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.signal import lfilter

from earth.wgs84 import C_LIGHT

from .constellation import _check_int, _check_real
from .error_kernels import gauss_markov_rows
from .sigma_models import SigmaModel

__all__ = ["ClockModel", "ReceiverConfig", "simulate_clock", "tropo_mapping", "iono_obliquity", "CN0_JITTER_DB"]

CN0_JITTER_DB = 1.0
"""Sigma of the receiver's C/N0 estimate per epoch [dB] (assumption: a 1 s C/N0 estimator at 35-45 dB-Hz)."""
_MIN_EL_SIGMA = math.radians(1.0)
"""The 1/sin(el) sigma model is evaluated at max(el, 1 deg) (finite at a 0-deg mask)."""


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


def _uniform_steps(dt: np.ndarray) -> bool:
    """Whether the steps ``dt`` (M - 1,) are equal to rtol 1e-9: ``np.allclose(dt, dt[0], rtol=1e-9, atol=0)``."""
    return bool(np.all(np.abs(dt - dt[0]) <= 1e-9 * abs(dt[0])))


def _gm_steps(dt: np.ndarray, tau: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Per step ``dt`` (M - 1,) of a Gauss-Markov process (:func:`_gauss_markov`): the transition ``a =
    exp(-dt / tau)`` and the innovation scale ``sigma sqrt(1 - exp(-2 dt / tau))``."""
    return np.exp(-dt / tau), sigma * np.sqrt(-np.expm1(-2.0 * dt / tau))


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
    a, c = _gm_steps(dt, tau, sigma)
    e = c.reshape((-1,) + (1,) * (z.ndim - 1)) * z[1:]
    if _uniform_steps(dt):
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


def _gauss_markov_rows(t: np.ndarray, tau: float, sigma: float, z: np.ndarray) -> np.ndarray:
    """:func:`_gauss_markov` of each row of ``z`` (R, M, L) along its time axis 1, as a new C-ordered (R, M, L)
    array: the same values bit for bit, without transposing the rows' draws to time-first. Uniform steps run the
    compiled recursion (:func:`~envs.sim.error_kernels.gauss_markov_rows`), others :func:`_gauss_markov`."""
    z = np.ascontiguousarray(z, dtype=np.float64)
    M = z.shape[1]
    dt = np.diff(t)
    if M == 1 or not _uniform_steps(dt):
        return np.ascontiguousarray(_gauss_markov(t, tau, sigma, z.transpose(1, 0, 2)).transpose(1, 0, 2))
    a, c = _gm_steps(dt, tau, sigma)
    a0 = float(a[0])
    out = np.empty(z.shape)
    gauss_markov_rows(z, float(sigma), a0, c, out)
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
