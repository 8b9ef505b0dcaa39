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

from dataclasses import dataclass, fields, replace

import numpy as np

from . import gnss_stages as stages
from .buffers import empty
from .canyon import UrbanCanyon, _check_intervals
from .constellation import Constellation, _check_pair, _check_real
from .error_kernels import measurement_rows
from .events import Cn0Scatter, NoiseRegimes, RandomBursts, Reacquisition, SigmaMismatch, UrbanZones
# the receiver's models and the stages' stream indices live in their own modules (re-exported here)
from .gnss_stages import (_N_SUB, _SUB_BURSTS, _SUB_CANYON, _SUB_CLOCK, _SUB_CN0, _SUB_CODE,  # noqa: F401
                          _SUB_IONO, _SUB_MISMATCH, _SUB_NLOS, _SUB_RATE, _SUB_REGIME, _SUB_REGIME_NLOS, _SUB_SKY,
                          _SUB_TROPO, _SUB_ZONE_GEOM, _SUB_ZONE_SAT, _SUB_ZONES, GPS_WEEK_S,
                          _entropy_words, _nlos_bursts, _row_children)
from .receiver import (CN0_JITTER_DB, ClockModel, ReceiverConfig, _check_rngs, _check_times,  # noqa: F401
                       _gauss_markov, iono_obliquity, simulate_clock, tropo_mapping)
from .row_threads import run_row_ranges

__all__ = [
    "Constellation", "ClockModel", "ReceiverConfig", "NlosConfig", "UrbanCanyon", "GnssEvents",
    "GnssData", "simulate_clock", "simulate_gnss", "tropo_mapping", "iono_obliquity", "EVENT_PRESETS",
    "GPS_WEEK_S", "RandomBursts", "SigmaMismatch", "NoiseRegimes", "UrbanZones", "Reacquisition",
]


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
    cn0 : Cn0Scatter or None
        C/N0 scattering about its elevation line as a recording's does (None: 1 dB white jitter and a constant
        NLOS deficit).

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
    cn0: Cn0Scatter | None = None

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
                       "zones": UrbanZones, "reacquisition": Reacquisition, "cn0": Cn0Scatter}


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
def _check_inputs(t, r_e, v_e, heading, constellation, receiver, events, rngs, t0_gps, dtype):
    """The arguments of :func:`simulate_gnss` checked and converted (``ValueError`` naming the argument):
    returns ``(t, r_e, v_e, heading, rngs, t0_gps, dtype)``."""
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
    if t0_gps is not None:
        t0_gps = np.asarray(t0_gps, dtype=np.float64)
        if t0_gps.shape != (B,):
            raise ValueError(f"t0_gps must have shape (B,) = {(B,)}, got {t0_gps.shape}")
        if not np.all(np.isfinite(t0_gps)):
            raise ValueError("t0_gps must be finite")
    return t, r_e, v_e, heading, rngs, t0_gps, dtype


def _gnss_data(t, sky, ch, rng, noise, err, bits, dtype, buffers=None) -> GnssData:
    """The stages' results as :class:`GnssData`: pseudoranges and rates formed (into ``buffers`` when given) and
    the masked channels set to finite zeros in every channel array, in place, by the compiled
    :func:`~envs.sim.error_kernels.measurement_rows` in row ranges on threads, then one cast (``sat_pos`` /
    ``sat_vel``, evaluated on the tracked channels only, and the NLOS biases, since ``nlos`` implies ``mask``,
    are zero there already)."""
    mask = ch.mask
    pr = empty(buffers, "gnss.pr", mask.shape, np.float64)
    prr = empty(buffers, "gnss.prr", mask.shape, np.float64)
    run_row_ranges(lambda r0, r1: measurement_rows(r0, r1, mask, rng.rho, err.bias_m, err.pr_err, rng.rho_dot,
                                                   err.drift_mps, err.prr_err, pr, prr, err.pr_sigma,
                                                   err.prr_sigma, ch.el, ch.az, ch.cn0), mask.shape[0])

    def cast(a):
        return a.astype(dtype, copy=False)

    prn = np.where(mask, ch.sel + 1, -1).astype(np.int64)
    return GnssData(
        t=t.astype(dtype),
        t0_gps=sky.t0_gps.copy(),
        sat_pos=cast(rng.sat_pos), sat_vel=cast(rng.sat_vel),
        pr=cast(pr), prr=cast(prr), pr_sigma=cast(err.pr_sigma), prr_sigma=cast(err.prr_sigma),
        mask=mask, prn=prn, elevation=cast(ch.el), azimuth=cast(ch.az),
        clock_bias_m=cast(err.bias_m), clock_drift_mps=cast(err.drift_mps),
        nlos=noise.nlos, pr_error_m=cast(err.pr_err), prr_error_mps=cast(err.prr_err),
        cn0_dbhz=cast(ch.cn0), pr_var_true=cast(err.pr_var_true), prr_var_true=cast(err.prr_var_true),
        pr_bias_m=cast(noise.pr_bias), prr_bias_mps=cast(noise.prr_bias), event_mask=bits,
    )


def simulate_gnss(t, r_e, v_e, heading, constellation: Constellation, receiver: ReceiverConfig,
                  events: GnssEvents, rngs, t0_gps=None, dtype=np.float64, buffers=None) -> GnssData:
    """Simulate pseudoranges and pseudorange rates of B receivers over M epochs.

    See the module docstring for the measurement model. The stages
    (:mod:`envs.sim.gnss_stages`, each vectorized over time): satellite
    geometry of all satellites (chunked over time), visibility and the
    degradations (elevation mask, urban canyon, NLOS bursts, random events,
    outages), channel allocation by elevation, ranging on the tracked
    channels, the channels' NLOS state and noise multipliers, then the error
    processes (clock, troposphere, ionosphere, white noise) and sigmas.

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
    buffers : :class:`envs.sim.buffers.WorldBuffers` or None
        The (B, M, C) arrays of the ranging and receiver stages and the pseudoranges and rates are taken from
        it (reused across draws when nobody holds them), else allocated.

    Returns
    -------
    GnssData
    """
    t, r_e, v_e, heading, rngs, t0_gps, dtype = _check_inputs(t, r_e, v_e, heading, constellation, receiver,
                                                               events, rngs, t0_gps, dtype)
    subs = [stages._row_children(g) for g in rngs]
    sky = stages.sky_geometry(t, r_e, constellation, subs, t0_gps)
    sat = stages.canyon_and_bursts(t, v_e, heading, sky, receiver.elevation_mask_deg, events, subs)
    stages.random_events(t, v_e, heading, sky, sat, events, subs)
    stages.scheduled_events(t, sat, events)
    ch = stages.allocate_channels(sky, sat.visible, receiver.n_channels, subs, t, events.cn0)
    rng = stages.channel_ranging(r_e, v_e, sky, ch, constellation, buffers)
    noise = stages.channel_noise(t, ch, sat, events)
    err = stages.receiver_errors(t, ch, noise, sat, receiver, subs, buffers)
    return _gnss_data(t, sky, ch, rng, noise, err, sat.bits, dtype, buffers)
