"""Random GNSS events of an episode: noise bursts, reported-sigma mismatch, noise regimes, urban zones, re-acquisition.

Every event here is drawn per episode from the row's own generator (a child
stream of :func:`envs.sim.gnss.simulate_gnss`, one per event kind), at random
times: nothing happens at a fixed clock time, so no time schedule can
memorize it. The configurations are frozen dataclasses (validated, the
``ValueError`` names the field); the draw functions work on one row and are
vectorized over the M epochs (and the S satellites).

Event bits
----------
:attr:`envs.sim.gnss.GnssData.event_mask` (B, M) ``uint16`` ORs these bits
of the events active at each epoch (for plots and error analysis; the filter
never sees them):

=================  =====  ======================================================================
bit                value  set where
=================  =====  ======================================================================
``OUTAGE``         1      inside a configured full outage (:attr:`GnssEvents.outages`)
``NOISE``          2      the *true* code / Doppler noise is scaled by an interval or a random
                          burst (:class:`RandomBursts`, :attr:`GnssEvents.noise_scale` != 1)
``MISMATCH``       4      the *reported* sigma is wrong (:class:`SigmaMismatch` factor != 1)
``NLOS_ZONE``      8      inside an urban zone: street canyon or tree cover
                          (:class:`UrbanZones`), or a configured :class:`UrbanCanyon` interval
``OVERPASS``       16     under an overpass (almost total blockage)
``IMU_EVENT``      32     an IMU bias step or a vibration-regime change within the last
                          :attr:`envs.sim.imu.ImuEvents.flag_window_s` (set by the world)
``REACQUISITION``  64     a tracked channel is inside its re-acquisition transient (:class:`Reacquisition`)
``REGIME``         128    a noise regime other than the first (nominal) one (:class:`NoiseRegimes`)
``TREES``          256    under tree cover (also sets ``NLOS_ZONE``)
``ROUGH_ROAD``     512    an IMU vibration regime (rough road) is active (set by the world)
=================  =====  ======================================================================

Urban-zone parameters measured on smartLoc
------------------------------------------
The zone model's NLOS probability, bias distribution and C/N0 model are the
statistics of the recorded smartLoc Potsdamer Platz pseudoranges
(:mod:`envs.datasets.smartloc_stats`; ``tests/envs/test_events.py`` re-measures
them and checks these constants):

* LOS C/N0 ``39.2 + 6.2 sin(el)`` dB-Hz (:data:`CN0_LOS_A`, :data:`CN0_LOS_B`);
* NLOS C/N0 deficit 11 dB (:data:`NLOS_DEFICIT_DB`);
* NLOS probability in a dense canyon ``0.88 - 0.71 sin(el)`` (:data:`P_NLOS_A`, :data:`P_NLOS_B`);
* NLOS bias log-normal, median ``16.4 m / sin(el)``, log-sigma 0.70
  (:data:`BIAS_SIN_MEDIAN_M`, :data:`BIAS_SIGMA_LN`), positive in 92 % of cases
  (:data:`BIAS_POSITIVE_FRACTION`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .canyon import UrbanCanyon, canyon_visibility_rows
from .constellation import _check_pair as _pair, _check_real
from .error_kernels import segment_index_rows
from .receiver import _gauss_markov

__all__ = [
    "OUTAGE", "NOISE", "MISMATCH", "NLOS_ZONE", "OVERPASS", "IMU_EVENT", "REACQUISITION", "REGIME", "TREES",
    "ROUGH_ROAD", "EVENT_BITS", "RandomBursts", "SigmaMismatch", "NoiseRegime", "NoiseRegimes", "UrbanZones",
    "Reacquisition", "Cn0Scatter", "cn0_scatter", "cn0_scatter_draws", "cn0_scatter_rows", "cn0_los",
    "nlos_probability", "draw_bursts", "draw_mismatch", "draw_regimes", "draw_zone_schedule",
    "reacquisition_multiplier", "zone_effects", "zone_effects_rows", "regime_nlos", "nlos_bias", "ZONE_OPEN",
    "ZONE_CANYON", "ZONE_TREES", "ZONE_OVERPASS",
]

OUTAGE, NOISE, MISMATCH, NLOS_ZONE, OVERPASS, IMU_EVENT, REACQUISITION, REGIME, TREES, ROUGH_ROAD = (
    1 << k for k in range(10))
EVENT_BITS = {"OUTAGE": OUTAGE, "NOISE": NOISE, "MISMATCH": MISMATCH, "NLOS_ZONE": NLOS_ZONE, "OVERPASS": OVERPASS,
              "IMU_EVENT": IMU_EVENT, "REACQUISITION": REACQUISITION, "REGIME": REGIME, "TREES": TREES,
              "ROUGH_ROAD": ROUGH_ROAD}
"""Name -> bit of :attr:`GnssData.event_mask` (module table)."""

ZONE_OPEN, ZONE_CANYON, ZONE_TREES, ZONE_OVERPASS = range(4)
"""Zone kinds of :func:`draw_zone_schedule` (per epoch)."""

# ---- smartLoc Potsdamer Platz statistics (envs/datasets/smartloc_stats.py, measured; rounded)
CN0_LOS_A = 39.2
"""LOS C/N0 at the horizon [dB-Hz] (smartLoc, least squares against sin(el))."""
CN0_LOS_B = 6.2
"""LOS C/N0 slope against sin(el) [dB-Hz] (smartLoc)."""
NLOS_DEFICIT_DB = 11.0
"""Median C/N0 of LOS-like minus NLOS-like measurements [dB] (smartLoc)."""
P_NLOS_A = 0.88
P_NLOS_B = 0.71
"""NLOS-like probability ``P_NLOS_A - P_NLOS_B sin(el)`` of a received signal in a dense canyon (smartLoc)."""
BIAS_SIN_MEDIAN_M = 16.4
"""Median of ``|bias| sin(el)`` of NLOS-like measurements [m] (smartLoc; log-normal)."""
BIAS_SIGMA_LN = 0.70
"""Log-sigma of the NLOS bias (smartLoc)."""
BIAS_POSITIVE_FRACTION = 0.92
"""Share of positive NLOS-like residuals (smartLoc; a reflected path is longer)."""

# ---- smartLoc with the 3 m label of agents.sim_vs_real (|truth residual| > 3 m, robust per-system clock of
# envs.datasets.truth_check), measured by agents.sim_vs_real.calibration (docs/sim-vs-real.md, "Calibration";
# tests/agents/test_sim_vs_real.py re-measures them when the data are present). Used by ``urban-smartloc``.
SMARTLOC3_P_NLOS = (1.02, 0.56)
"""``(a, b)``: NLOS-like probability ``a - b sin(el)`` with the 3 m label (least squares on the 0/1 label)."""
SMARTLOC3_BIAS = (10.9, 0.97)
"""``(median of |e| sin(el) [m], log-sigma)`` of the 3 m label's NLOS-like residuals."""
SMARTLOC3_SEGMENT_S = (2.0, 6.0)
"""NLOS segment length range [s]: independent segments of mean length L with NLOS share p stay NLOS from one
second to the next with probability ``1 - (1 - p) / L``; smartLoc's 0.93 at its NLOS share 0.70 gives L = 4 s."""
SMARTLOC3_CN0 = dict(offset_sigma_db=3.0, gm_sigma_db=3.0, gm_tau_s=3.0, white_sigma_db=1.4,
                     nlos_deficit_db=7.2, nlos_deficit_sigma_db=4.9)
""":class:`Cn0Scatter` of smartLoc: LOS C/N0 scatter about the elevation line 4.5 dB, autocorrelation 0.74 / 0.54 /
0.45 at 1 / 5 / 30 s (a constant per satellite carrying 45% of the variance, a 3 s Gauss-Markov 45%, white 10%);
NLOS C/N0 7.2 dB below the LOS line with a 6.7 dB scatter (4.9 dB on top of the LOS scatter)."""


# =============================================================================
# validation helpers
# =============================================================================
def _log_uniform(g: np.random.Generator, rng: tuple, size=None):
    """Log-uniform draws in ``[rng[0], rng[1]]`` (one uniform each)."""
    lo, hi = math.log(rng[0]), math.log(rng[1])
    return np.exp(g.uniform(lo, hi, size=size))


def _renewal(t: np.ndarray, length_s: tuple, g: np.random.Generator, n: int = 1):
    """Piecewise-constant segments from ``t[0]``: lengths ``U(length_s)``; segment index per epoch.

    Draws a fixed count ``K = ceil(span / min_length) + 1`` of lengths per
    column (``n`` columns), so the number of draws does not depend on the
    realization. Returns ``(idx (M, n) int64, starts (K, n), K)``.
    """
    K = _renewal_count(t, length_s)
    lengths = g.uniform(length_s[0], length_s[1], size=(K, n))
    idx, ends = _segment_index(t, lengths[None])
    return idx[0], ends[0] - lengths, K


def _renewal_count(t: np.ndarray, length_s: tuple) -> int:
    """The number K of segment lengths :func:`_renewal` draws per column: ``ceil(span / min_length) + 1``."""
    return int(math.ceil(float(t[-1] - t[0]) / length_s[0])) + 1


def _segment_index(t: np.ndarray, lengths: np.ndarray):
    """Segment index per epoch of R rows of n columns of consecutive segments from ``t[0]``.

    Parameters
    ----------
    t : (M,) increasing epochs [s]; lengths : (R, K, n) segment lengths [s].

    Returns
    -------
    idx : (R, M, n) int64, the segment of each epoch (at most K - 1); ends : (R, K, n) the segments' ends [s]
    (compiled: :func:`~envs.sim.error_kernels.segment_index_rows`).
    """
    R, K, n = lengths.shape
    lengths = np.ascontiguousarray(lengths, dtype=np.float64)
    if not (lengths >= 0.0).all():
        raise ValueError("segment lengths must be >= 0")
    idx = np.empty((R, t.size, n), dtype=np.int64)
    ends = np.empty((R, K, n))
    segment_index_rows(np.ascontiguousarray(t, dtype=np.float64), lengths, idx, ends)
    return idx, ends


# =============================================================================
# configurations
# =============================================================================
@dataclass(frozen=True)
class RandomBursts:
    """Random bursts of *true* code / Doppler noise (the reported sigma stays nominal).

    Per episode the number of bursts is Poisson with mean ``rate_hz * T``
    (``T`` the span of the epochs), the start times uniform over the span,
    the lengths ``U(duration_s)``, the sigma multipliers log-uniform in
    ``scale``. ``joint=True``: one multiplier for code and Doppler; else the
    Doppler multiplier is a separate log-uniform draw. Overlapping bursts
    multiply.

    Parameters
    ----------
    rate_hz : float
        Mean bursts per second of episode [1/s], >= 0 (default 1/75 s: 4 per 300 s).
    duration_s : (float, float)
        Burst length range [s], 0 < min <= max (default 5-60 s).
    scale : (float, float)
        Range of the true-noise sigma multiplier, 0 < min <= max (default 3-20).
    joint : bool
        Same multiplier for code and Doppler.
    """

    rate_hz: float = 1.0 / 75.0
    duration_s: tuple = (5.0, 60.0)
    scale: tuple = (3.0, 20.0)
    joint: bool = True

    def __post_init__(self):
        o = "RandomBursts"
        _check_real(o, "rate_hz", self.rate_hz, lo=0.0)
        _pair(o, "duration_s", self.duration_s, lo=0.0, lo_open=True)
        _pair(o, "scale", self.scale, lo=0.0, lo_open=True)
        if not isinstance(self.joint, bool):
            raise ValueError(f"{o}.joint must be a bool, got {self.joint!r}")


@dataclass(frozen=True)
class SigmaMismatch:
    """The sigma the receiver *reports* is wrong by piecewise-constant factors (the filter never knows).

    Code and Doppler have separate segment sequences from the first epoch,
    lengths ``U(segment_s)``. Each segment is honest (factor 1) with
    probability ``p_honest``, else its factor (multiplying the reported
    *sigma*, so the reported variance is off by its square) is log-uniform in
    ``pr_factor`` / ``prr_factor``. Seed paper 003 sec. 2.2 (eqs 12-14): the
    measurement-noise matrix "is subject to bias" as the environment changes.

    Parameters
    ----------
    segment_s : (float, float)
        Segment length range [s], 0 < min <= max (default 20-90 s).
    pr_factor, prr_factor : (float, float)
        Ranges of the reported/true sigma factor of code and Doppler, 0 < min <= max (default 1/4-4).
    p_honest : float
        Probability that a segment reports the true sigma, in [0, 1] (default 0.2).
    """

    segment_s: tuple = (20.0, 90.0)
    pr_factor: tuple = (0.25, 4.0)
    prr_factor: tuple = (0.25, 4.0)
    p_honest: float = 0.2

    def __post_init__(self):
        o = "SigmaMismatch"
        _pair(o, "segment_s", self.segment_s, lo=0.0, lo_open=True)
        _pair(o, "pr_factor", self.pr_factor, lo=0.0, lo_open=True)
        _pair(o, "prr_factor", self.prr_factor, lo=0.0, lo_open=True)
        _check_real(o, "p_honest", self.p_honest, lo=0.0, hi=1.0)


@dataclass(frozen=True)
class NoiseRegime:
    """One regime of :class:`NoiseRegimes`.

    Parameters
    ----------
    name : str, non-empty.
    code_scale, doppler_scale : float
        True code / Doppler noise sigma multipliers, > 0.
    nlos_fraction : float
        Probability that a satellite is NLOS (piecewise per satellite, see
        :class:`NoiseRegimes`), in [0, 1].
    mean_dwell_s : float
        Mean of the exponential dwell time [s], > 0.
    """

    name: str
    code_scale: float = 1.0
    doppler_scale: float = 1.0
    nlos_fraction: float = 0.0
    mean_dwell_s: float = 60.0

    def __post_init__(self):
        o = "NoiseRegime"
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"{o}.name must be a non-empty str, got {self.name!r}")
        _check_real(o, "code_scale", self.code_scale, lo=0.0, lo_open=True)
        _check_real(o, "doppler_scale", self.doppler_scale, lo=0.0, lo_open=True)
        _check_real(o, "nlos_fraction", self.nlos_fraction, lo=0.0, hi=1.0)
        _check_real(o, "mean_dwell_s", self.mean_dwell_s, lo=0.0, lo_open=True)


def _default_regimes():
    return (NoiseRegime("nominal", 1.0, 1.0, 0.0, 60.0),
            NoiseRegime("degraded", 3.0, 2.5, 0.05, 40.0),
            NoiseRegime("severe", 8.0, 6.0, 0.15, 20.0))


@dataclass(frozen=True)
class NoiseRegimes:
    """Markov-switching noise regimes (a semi-Markov jump process with exponential dwell times).

    The first regime is drawn with the stationary probabilities of the
    process (proportional to the mean dwell times, the jump chain being
    uniform over the other regimes); each dwell is exponential with the
    regime's mean; on leaving, the next regime is uniform over the others.
    In a regime the true code / Doppler sigmas are multiplied by its scales,
    and each satellite is NLOS with probability ``nlos_fraction`` on
    per-satellite segments of length ``U(nlos_segment_s)`` (bias and rate
    error as in the urban zones: log-normal smartLoc bias, ``N(0,
    nlos_rate_sigma_mps^2)`` rate error). The reported sigma stays nominal.

    Parameters
    ----------
    regimes : tuple of NoiseRegime (at least 2); the first is the nominal one (no ``REGIME`` bit).
    nlos_segment_s : (float, float)
        Per-satellite NLOS segment length range [s], 0 < min <= max.
    nlos_rate_sigma_mps : float
        Sigma of the constant pseudorange-rate error of an NLOS segment [m/s], >= 0.
    """

    regimes: tuple = ()
    nlos_segment_s: tuple = (2.0, 20.0)
    nlos_rate_sigma_mps: float = 0.3

    def __post_init__(self):
        o = "NoiseRegimes"
        if self.regimes == ():
            object.__setattr__(self, "regimes", _default_regimes())
        if not isinstance(self.regimes, tuple) or len(self.regimes) < 2:
            raise ValueError(f"{o}.regimes must be a tuple of at least 2 NoiseRegime, got {self.regimes!r}")
        for k, r in enumerate(self.regimes):
            if not isinstance(r, NoiseRegime):
                raise ValueError(f"{o}.regimes[{k}] must be a NoiseRegime, got {type(r).__name__}")
        _pair(o, "nlos_segment_s", self.nlos_segment_s, lo=0.0, lo_open=True)
        _check_real(o, "nlos_rate_sigma_mps", self.nlos_rate_sigma_mps, lo=0.0)


@dataclass(frozen=True)
class UrbanZones:
    """Open sky alternating at random with urban canyon, tree cover and overpasses along the drive.

    Schedule: from the first epoch, an open-sky stretch of ``U(open_s)``,
    then a zone whose kind is drawn with the weights ``(canyon, trees,
    overpass)`` and whose length is ``U(canyon_s)``, ``U(trees_s)`` or
    ``U(overpass_s)``, then open sky again, and so on (seed paper 000 sec. 1
    and 5.2: signals "blocked by buildings and vegetation in urban areas").

    Inside a zone:

    * **canyon**: the blockage geometry of :class:`~envs.sim.canyon.UrbanCanyon`
      (``canyon``; its ``intervals`` are replaced by the canyon windows); a
      satellite the walls block is lost, or received by reflection (NLOS) with
      the canyon's ``nlos_probability``. A received LOS-geometry satellite is
      NLOS / strong multipath with the smartLoc probability
      ``P_NLOS_A - P_NLOS_B sin(el)`` on per-satellite segments of length
      ``U(segment_s)``.
    * **trees**: nothing blocked; per satellite segment a foliage attenuation
      ``U(trees_attenuation_db)`` (ITU-R P.833 vegetation loss; Goldhirsh &
      Vogel 1998, L-band tree-shadowing fades of 5-15 dB are typical:
      assumption 2-12 dB) and diffuse multipath with ``trees_multipath_scale``
      times the canyon NLOS probability and ``trees_bias_scale`` times its bias.
    * **overpass**: every satellite blocked except, per satellite and
      overpass, with probability ``overpass_pass_probability``.

    An NLOS channel's pseudorange carries the smartLoc log-normal bias (median
    ``16.4 m / sin el``, log-sigma 0.70, positive with probability 0.92), its
    rate a constant ``N(0, nlos_rate_sigma_mps^2)`` error per segment, and
    its C/N0 drops by the measured 11 dB NLOS deficit. The C/N0 of every
    zone channel is ``cn0_los(el) - attenuation`` and its true code / Doppler
    sigmas grow by ``10^(attenuation / 20)`` (DLL / FLL thermal-noise jitter
    scales as ``(C/N0)^-1/2``: Kaplan & Hegarty 2nd ed. sec. 5.6, Groves 2nd
    ed. sec. 9.3.3). The receiver's reported sigma knows none of it.

    Parameters
    ----------
    open_s, canyon_s, trees_s, overpass_s : (float, float)
        Length ranges [s] of the open-sky stretches and of each zone kind, 0 < min <= max.
    weights : (float, float, float)
        Relative probabilities of canyon, trees, overpass, >= 0, not all zero.
    canyon : UrbanCanyon or None
        Canyon geometry (None: the :class:`~envs.sim.canyon.UrbanCanyon` defaults).
    segment_s : (float, float)
        Per-satellite segment length range of the NLOS / attenuation draws [s]
        (smartLoc: the mean NLOS-like run at 5 Hz is 1.4 s, a lower bound since
        threshold crossings of a noisy residual split runs; default 1-5 s).
    trees_attenuation_db : (float, float)
        Foliage attenuation range [dB], >= 0.
    trees_multipath_scale, trees_bias_scale : float
        Tree-cover NLOS probability / bias relative to the canyon's, in [0, 1] / >= 0.
    overpass_pass_probability : float
        Probability that a satellite stays tracked under an overpass, in [0, 1].
    nlos_rate_sigma_mps : float
        Sigma of the NLOS pseudorange-rate error [m/s], >= 0 (the :class:`~envs.sim.gnss.NlosConfig` default).
    nlos_probability : (float, float)
        ``(a, b)`` of the canyon's NLOS probability ``a - b sin(el)`` (default smartLoc's 10 m label,
        ``(P_NLOS_A, P_NLOS_B)``; ``urban-smartloc``: its 3 m label, :data:`SMARTLOC3_P_NLOS`), a in [0, 2].
    nlos_bias : (float, float)
        ``(median of |bias| sin(el) [m], log-sigma)`` of the NLOS bias (default ``(BIAS_SIN_MEDIAN_M,
        BIAS_SIGMA_LN)``), both > 0.
    """

    open_s: tuple = (20.0, 60.0)
    canyon_s: tuple = (20.0, 60.0)
    trees_s: tuple = (10.0, 40.0)
    overpass_s: tuple = (2.0, 6.0)
    weights: tuple = (0.45, 0.35, 0.2)
    canyon: object = None
    segment_s: tuple = (1.0, 5.0)
    trees_attenuation_db: tuple = (2.0, 12.0)
    trees_multipath_scale: float = 0.3
    trees_bias_scale: float = 0.3
    overpass_pass_probability: float = 0.05
    nlos_rate_sigma_mps: float = 0.3
    nlos_probability: tuple = (P_NLOS_A, P_NLOS_B)
    nlos_bias: tuple = (BIAS_SIN_MEDIAN_M, BIAS_SIGMA_LN)

    def __post_init__(self):
        o = "UrbanZones"
        for name in ("nlos_probability", "nlos_bias"):
            v = getattr(self, name)
            if not isinstance(v, tuple) or len(v) != 2:
                raise ValueError(f"{o}.{name} must be a pair of floats, got {v!r}")
        _check_real(o, "nlos_probability[0]", self.nlos_probability[0], lo=0.0, hi=2.0)
        _check_real(o, "nlos_probability[1]", self.nlos_probability[1])
        _check_real(o, "nlos_bias[0]", self.nlos_bias[0], lo=0.0, lo_open=True)
        _check_real(o, "nlos_bias[1]", self.nlos_bias[1], lo=0.0, lo_open=True)
        for name in ("open_s", "canyon_s", "trees_s", "overpass_s", "segment_s"):
            _pair(o, name, getattr(self, name), lo=0.0, lo_open=True)
        if not isinstance(self.weights, tuple) or len(self.weights) != 3:
            raise ValueError(f"{o}.weights must be a (canyon, trees, overpass) tuple, got {self.weights!r}")
        for k, w in enumerate(self.weights):
            _check_real(o, f"weights[{k}]", w, lo=0.0)
        if sum(self.weights) <= 0.0:
            raise ValueError(f"{o}.weights must not all be zero")
        if self.canyon is None:
            object.__setattr__(self, "canyon", UrbanCanyon())
        if not isinstance(self.canyon, UrbanCanyon):
            raise ValueError(f"{o}.canyon must be an UrbanCanyon or None, got {type(self.canyon).__name__}")
        _pair(o, "trees_attenuation_db", self.trees_attenuation_db, lo=0.0)
        _check_real(o, "trees_multipath_scale", self.trees_multipath_scale, lo=0.0, hi=1.0)
        _check_real(o, "trees_bias_scale", self.trees_bias_scale, lo=0.0)
        _check_real(o, "overpass_pass_probability", self.overpass_pass_probability, lo=0.0, hi=1.0)
        _check_real(o, "nlos_rate_sigma_mps", self.nlos_rate_sigma_mps, lo=0.0)


@dataclass(frozen=True)
class Reacquisition:
    """Larger true noise in the first seconds after a satellite is (re-)acquired.

    A satellite re-acquires at epoch ``k > 0`` when it is visible at ``k``,
    not at ``k - 1``, and either it was last visible at least ``min_gap_s``
    before (lock lost, e.g. under an overpass or behind a building) or no
    satellite at all was visible at ``k - 1`` (after a full outage: every
    satellite is acquired afresh). For ``tau = t - t_acq < duration_s`` its
    code and Doppler sigmas are multiplied by ``scale ** (1 - tau /
    duration_s)`` (``scale`` at acquisition, 1 after ``duration_s``): the
    tracking loops re-converge (assumption: x5 decaying over 10 s, a DLL /
    FLL pull-in after a cold re-acquisition). The reported sigma stays nominal.

    Parameters
    ----------
    scale : float
        Sigma multiplier at acquisition, >= 1.
    duration_s : float
        Length of the transient [s], > 0.
    min_gap_s : float
        Shortest loss of lock that triggers a re-acquisition [s], >= 0.
    """

    scale: float = 5.0
    duration_s: float = 10.0
    min_gap_s: float = 1.0

    def __post_init__(self):
        o = "Reacquisition"
        _check_real(o, "scale", self.scale, lo=1.0)
        _check_real(o, "duration_s", self.duration_s, lo=0.0, lo_open=True)
        _check_real(o, "min_gap_s", self.min_gap_s, lo=0.0)


@dataclass(frozen=True)
class Cn0Scatter:
    """Receiver C/N0 that scatters about its elevation line as a recording's does, and an NLOS C/N0 deficit that
    varies (replaces the default 1 dB white jitter, :data:`envs.sim.receiver.CN0_JITTER_DB`, and the constant
    :data:`NLOS_DEFICIT_DB`).

    Reported C/N0 of a channel: ``cn0_los(el) + o_s + x_s(t) + w`` with ``o_s ~ N(0, offset_sigma_db^2)`` one
    constant per satellite and episode (antenna pattern, the receiver's estimator bias), ``x_s`` a first-order
    Gauss-Markov process per satellite (``gm_sigma_db``, ``gm_tau_s``: fading, near-field multipath; Brown &
    Hwang 4th ed. ch. 2) and ``w`` white (``white_sigma_db``, the 1 s C/N0 estimate's noise); an NLOS channel
    loses ``nlos_deficit_db + nlos_deficit_sigma_db y_s(t)`` dB instead, ``y_s`` a unit Gauss-Markov process
    per satellite with the same ``gm_tau_s``. The scatter changes the reported C/N0 only, not the true noise:
    on smartLoc the line-of-sight residual's RMS differs by 14% between the lowest and the highest quartile of
    the C/N0 scatter (1.48 / 1.30 m), far less than the 2x that a -6 dB thermal loss would cause
    (:data:`SMARTLOC3_CN0`).

    The defaults are smartLoc's (:data:`SMARTLOC3_CN0`).

    Parameters
    ----------
    offset_sigma_db, gm_sigma_db, white_sigma_db, nlos_deficit_sigma_db : float
        Standard deviations [dB], >= 0.
    gm_tau_s : float
        Correlation time of the Gauss-Markov parts [s], > 0.
    nlos_deficit_db : float
        Mean C/N0 loss of an NLOS channel [dB], >= 0.
    """

    offset_sigma_db: float = SMARTLOC3_CN0["offset_sigma_db"]
    gm_sigma_db: float = SMARTLOC3_CN0["gm_sigma_db"]
    gm_tau_s: float = SMARTLOC3_CN0["gm_tau_s"]
    white_sigma_db: float = SMARTLOC3_CN0["white_sigma_db"]
    nlos_deficit_db: float = SMARTLOC3_CN0["nlos_deficit_db"]
    nlos_deficit_sigma_db: float = SMARTLOC3_CN0["nlos_deficit_sigma_db"]

    def __post_init__(self):
        o = "Cn0Scatter"
        for name in ("offset_sigma_db", "gm_sigma_db", "white_sigma_db", "nlos_deficit_sigma_db",
                     "nlos_deficit_db"):
            _check_real(o, name, getattr(self, name), lo=0.0)
        _check_real(o, "gm_tau_s", self.gm_tau_s, lo=0.0, lo_open=True)


# =============================================================================
# models and draws (one row)
# =============================================================================
def cn0_los(el):
    """Nominal line-of-sight C/N0 ``CN0_LOS_A + CN0_LOS_B sin(el)`` [dB-Hz] (smartLoc fit), (...) -> (...)."""
    return CN0_LOS_A + CN0_LOS_B * np.sin(np.maximum(el, 0.0))


def nlos_probability(el, line=(P_NLOS_A, P_NLOS_B)):
    """NLOS probability of a received signal in a dense canyon, ``a - b sin(el)`` with ``(a, b) = line``
    (default ``(P_NLOS_A, P_NLOS_B)``, smartLoc's 10 m label), clipped to [0, 1]."""
    return np.clip(line[0] - line[1] * np.sin(np.maximum(el, 0.0)), 0.0, 1.0)


def nlos_bias(el, z, u_sign, sin_median_m=BIAS_SIN_MEDIAN_M, sigma_ln=BIAS_SIGMA_LN):
    """NLOS pseudorange bias [m]: log-normal, median ``sin_median_m / sin(el)``, log-sigma ``sigma_ln``
    (defaults: smartLoc's 10 m label, :data:`BIAS_SIN_MEDIAN_M`, :data:`BIAS_SIGMA_LN`).

    Parameters
    ----------
    el : (...) elevation [rad]; z : (...) standard normals; u_sign : (...) uniforms in [0, 1)
    (positive where ``u_sign < BIAS_POSITIVE_FRACTION``).
    """
    s = np.sin(np.maximum(el, math.radians(5.0)))
    mag = sin_median_m / s * np.exp(sigma_ln * z)
    return np.where(u_sign < BIAS_POSITIVE_FRACTION, mag, -mag)


def cn0_scatter(t, S: int, C: int, cfg: Cn0Scatter, g: np.random.Generator):
    """The C/N0 scatter of one row (see :class:`Cn0Scatter`).

    Draw order: S offset normals, (M, S) Gauss-Markov normals, (M, S) deficit normals, (M, C) white normals.

    Returns
    -------
    los_db : (M, S) per-satellite offset + Gauss-Markov part [dB]; deficit_db : (M, S) NLOS loss [dB];
    white_db : (M, C) per-channel white part [dB].
    """
    z = g.standard_normal((1, cn0_scatter_draws(t.size, S, C)))  # the four draws in one call: the same numbers
    los, deficit, white = cn0_scatter_rows(t, S, C, cfg, z)
    return los[0], deficit[0], white[0]


def cn0_scatter_draws(M: int, S: int, C: int) -> int:
    """The normals :func:`cn0_scatter` draws for one row (M epochs, S satellites, C channels), in its order."""
    return S + 2 * M * S + M * C


def cn0_scatter_rows(t, S: int, C: int, cfg: Cn0Scatter, z: np.ndarray):
    """:func:`cn0_scatter` of B rows at once from their normals ``z`` (B, :func:`cn0_scatter_draws`), each row's in
    its draw order (what its generator's ``standard_normal`` gives, e.g. :func:`envs.sim.rng.row_normals`): offset
    ``offset_sigma_db z``, the Gauss-Markov processes (:func:`~envs.sim.receiver._gauss_markov`, one call over
    every row's columns), the white part ``white_sigma_db z``.

    Returns
    -------
    los_db : (B, M, S); deficit_db : (B, M, S); white_db : (B, M, C) [dB], as :func:`cn0_scatter` per row.
    """
    M = t.size
    B = z.shape[0]
    k = (S, S + M * S, S + 2 * M * S)
    offset = cfg.offset_sigma_db * z[:, :k[0]]
    gm = _gauss_markov(t, cfg.gm_tau_s, cfg.gm_sigma_db, z[:, k[0]:k[1]].reshape(B, M, S).transpose(1, 0, 2))
    deficit = cfg.nlos_deficit_db + _gauss_markov(t, cfg.gm_tau_s, cfg.nlos_deficit_sigma_db,
                                                  z[:, k[1]:k[2]].reshape(B, M, S).transpose(1, 0, 2))
    white = cfg.white_sigma_db * z[:, k[2]:].reshape(B, M, C)
    return offset[:, None, :] + gm.transpose(1, 0, 2), deficit.transpose(1, 0, 2), white


def draw_bursts(t: np.ndarray, cfg: RandomBursts, g: np.random.Generator):
    """Random true-noise bursts of one row (see :class:`RandomBursts`).

    Draw order: the Poisson count ``n``, then ``n`` starts, ``n`` lengths,
    ``n`` code scales, ``n`` Doppler scales (only if not ``joint``).

    Returns
    -------
    code_scale, doppler_scale : (M,) sigma multipliers; active : (M,) bool;
    windows : tuple of (t0, t1, code_scale, doppler_scale).
    """
    span = float(t[-1] - t[0]) + (float(t[1] - t[0]) if t.size > 1 else 1.0)
    n = int(g.poisson(cfg.rate_hz * span))
    starts = g.uniform(t[0], t[0] + span, size=n)
    lengths = g.uniform(cfg.duration_s[0], cfg.duration_s[1], size=n)
    sc = _log_uniform(g, cfg.scale, size=n)
    sd = sc if cfg.joint else _log_uniform(g, cfg.scale, size=n)
    code = np.ones(t.size)
    dop = np.ones(t.size)
    active = np.zeros(t.size, dtype=bool)
    for k in range(n):
        w = (t >= starts[k]) & (t < starts[k] + lengths[k])
        code[w] *= sc[k]
        dop[w] *= sd[k]
        active |= w
    windows = tuple((float(starts[k]), float(starts[k] + lengths[k]), float(sc[k]), float(sd[k])) for k in range(n))
    return code, dop, active, windows


def draw_mismatch(t: np.ndarray, cfg: SigmaMismatch, g: np.random.Generator):
    """Reported/true sigma factors of one row (see :class:`SigmaMismatch`).

    Draw order: code segments (lengths, honest uniforms, factors), then Doppler.

    Returns
    -------
    pr_factor, prr_factor : (M,) factors multiplying the reported sigmas.
    """
    out = []
    for rng in (cfg.pr_factor, cfg.prr_factor):
        idx, _, K = _renewal(t, cfg.segment_s, g)
        honest = g.random(K) < cfg.p_honest
        fac = np.where(honest, 1.0, _log_uniform(g, rng, size=K))
        out.append(fac[idx[:, 0]])
    return out[0], out[1]


def draw_regimes(t: np.ndarray, cfg: NoiseRegimes, g: np.random.Generator):
    """Regime index per epoch of one row (see :class:`NoiseRegimes`).

    Draw order: the first regime (one uniform), then blocks of 64 (dwell
    exponential, next-regime uniform) pairs until the span is covered.

    Returns
    -------
    regime : (M,) int64 index into ``cfg.regimes``; switches : (K,) switch times [s].
    """
    R = len(cfg.regimes)
    dwell = np.array([r.mean_dwell_s for r in cfg.regimes])
    p0 = dwell / dwell.sum()
    cur = int(np.searchsorted(np.cumsum(p0), g.random(), side="right"))
    cur = min(cur, R - 1)
    t_now = float(t[0])
    states, switches = [cur], []
    while t_now <= t[-1]:
        e = g.standard_exponential(64)
        u = g.integers(0, R - 1, size=64)
        for k in range(64):
            t_now += e[k] * dwell[cur]
            if t_now > t[-1]:
                break
            cur = int(u[k] + (u[k] >= cur))          # uniform over the other regimes
            states.append(cur)
            switches.append(t_now)
    sw = np.asarray(switches)
    regime = np.asarray(states)[np.searchsorted(sw, t, side="right")]
    return regime.astype(np.int64), sw


def draw_zone_schedule(t: np.ndarray, cfg: UrbanZones, g: np.random.Generator):
    """Zone kind per epoch of one row (see :class:`UrbanZones`).

    Draw order: pairs (open length, zone kind uniform, zone length uniform)
    in blocks of 32 until the span is covered.

    Returns
    -------
    kind : (M,) int64 (``ZONE_OPEN``, ``ZONE_CANYON``, ``ZONE_TREES``, ``ZONE_OVERPASS``);
    zone_id : (M,) int64 (running zone number, -1 in open sky);
    windows : tuple of (t0, t1, kind).
    """
    w = np.asarray(cfg.weights, float)
    cw = np.cumsum(w / w.sum())
    ranges = {ZONE_CANYON: cfg.canyon_s, ZONE_TREES: cfg.trees_s, ZONE_OVERPASS: cfg.overpass_s}
    t_now = float(t[0])
    windows = []
    while t_now <= t[-1]:
        gap = g.uniform(cfg.open_s[0], cfg.open_s[1], size=32)
        ku = g.random(32)
        lu = g.random(32)
        for k in range(32):
            t_now += gap[k]
            if t_now > t[-1]:
                break
            kind = int(min(np.searchsorted(cw, ku[k], side="right"), 2)) + 1
            lo, hi = ranges[kind]
            t1 = t_now + lo + (hi - lo) * lu[k]
            windows.append((t_now, t1, kind))
            t_now = t1
            if t_now > t[-1]:
                break
    kind = np.full(t.size, ZONE_OPEN, dtype=np.int64)
    zone_id = np.full(t.size, -1, dtype=np.int64)
    for j, (a, b, k) in enumerate(windows):
        sel = (t >= a) & (t < b)
        kind[sel] = k
        zone_id[sel] = j
    return kind, zone_id, tuple(windows)


def reacquisition_multiplier(t: np.ndarray, visible: np.ndarray, cfg: Reacquisition) -> np.ndarray:
    """Sigma multiplier of the re-acquisition transient per (epoch, satellite) (:class:`Reacquisition`).

    Each row of a batch is independent of the others (the rule runs along the epoch axis of each satellite,
    and a full outage is one of that row's epochs without any tracked satellite).

    Parameters
    ----------
    t : (M,) epochs [s]; visible : (..., M, S) bool, the satellite is tracked (one row, or a batch of rows).

    Returns
    -------
    (..., M, S) float64, >= 1 (1 outside transients and where not visible).
    """
    M = visible.shape[-2]
    out = np.ones(visible.shape)
    if M < 2:
        return out
    idx = np.arange(M)[:, None]
    start = np.zeros(visible.shape, dtype=bool)
    start[..., 1:, :] = visible[..., 1:, :] & ~visible[..., :-1, :]
    last_vis = np.maximum.accumulate(np.where(visible, idx, -1), axis=-2)      # last visible epoch <= k
    prev_last = np.full(visible.shape, -1)
    prev_last[..., 1:, :] = last_vis[..., :-1, :]                              # last visible epoch < k
    gap = t[:, None] - t[np.maximum(prev_last, 0)]
    lost = (prev_last >= 0) & (gap >= cfg.min_gap_s)
    after_outage = np.zeros(visible.shape[:-1], dtype=bool)
    after_outage[..., 1:] = ~visible[..., :-1, :].any(axis=-1)
    eligible = start & (lost | after_outage[..., None])
    run_start = np.maximum.accumulate(np.where(start, idx, -1), axis=-2)      # start of the current run
    rs = np.maximum(run_start, 0)
    tau = t[:, None] - t[rs]
    on = visible & (run_start >= 0) & np.take_along_axis(eligible, rs, axis=-2) & (tau < cfg.duration_s)
    out[on] = cfg.scale ** (1.0 - tau[on] / cfg.duration_s)
    return out


def zone_effects(t, kind, zone_id, windows, el, az, v_e, heading, cfg: UrbanZones, g_geom: np.random.Generator,
                 g_sat: np.random.Generator):
    """Per-satellite effects of the urban zones on one row (see :class:`UrbanZones`): :func:`zone_effects_rows`
    of that row alone.

    Parameters
    ----------
    t : (M,) [s]; kind, zone_id, windows : from :func:`draw_zone_schedule`;
    el, az : (M, S) [rad]; v_e : (M, 3) [m/s]; heading : (M,) [rad] or None (no canyon geometry then:
    only the NLOS probability applies); g_geom, g_sat : the row's streams (:func:`zone_effects_rows`).

    Returns
    -------
    blocked, nlos, bias_m, rate_mps, atten_db : (M, S), as :func:`zone_effects_rows`.
    """
    out = zone_effects_rows(t, kind[None], zone_id[None], [windows], el[None], az[None], v_e[None],
                            None if heading is None else heading[None], cfg, [g_geom], [g_sat])
    return tuple(a[0] for a in out)


def zone_effects_rows(t, kind, zone_id, windows, el, az, v_e, heading, cfg: UrbanZones, g_geom, g_sat, active=None):
    """Per-satellite effects of the urban zones on B rows (see :class:`UrbanZones`), each row from its own
    streams; the arithmetic vectorized over the rows, the same operations per element as for a row alone, so a
    row's result does not depend on the others.

    Parameters
    ----------
    t : (M,) [s]; kind, zone_id : (B, M) and windows : B tuples, from :func:`draw_zone_schedule` per row;
    el, az : (B, M, S) [rad]; v_e : (B, M, 3) [m/s]; heading : (B, M) [rad] or None (no canyon geometry then:
    only the NLOS probability applies);
    g_geom : B streams of the canyon buildings (:func:`~envs.sim.canyon.canyon_visibility_rows`; indexed and drawn
    only for a row with a canyon window); g_sat : B streams of the per-satellite draws (order: segment lengths
    (K, S), then per (K, S) the NLOS uniforms, bias normals, bias sign uniforms, rate normals, foliage uniforms,
    then one (Z, S) block of overpass uniforms, Z = the row's number of zones, at least 1);
    active : (B, M, S) bool or None: the only elements evaluated (the others are returned not blocked, not NLOS,
    zero; the GNSS stages pass the satellites above the mask, the only ones the zones change). The draws do not
    depend on it.

    Returns
    -------
    blocked : (B, M, S) bool (lost); nlos : (B, M, S) bool; bias_m : (B, M, S) [m]; rate_mps : (B, M, S) [m/s];
    atten_db : (B, M, S) C/N0 loss [dB] (foliage + NLOS deficit).
    """
    B, M, S = el.shape
    K = _renewal_count(t, cfg.segment_s)
    Z = max([len(w) for w in windows] + [1])
    lengths, u_nlos, z_bias, u_sign, z_rate, u_att = (np.empty((B, K, S)) for _ in range(6))
    u_pass = np.zeros((B, Z, S))
    for i, g in enumerate(g_sat):     # each row's draws in its stream's order
        lengths[i] = g.uniform(cfg.segment_s[0], cfg.segment_s[1], size=(K, S))
        g.random(out=u_nlos[i])
        g.standard_normal(out=z_bias[i])
        g.random(out=u_sign[i])
        g.standard_normal(out=z_rate[i])
        g.random(out=u_att[i])
        u_pass[i, :max(len(windows[i]), 1)] = g.random((max(len(windows[i]), 1), S))
    idx, _ = _segment_index(t, lengths)                                              # (B, M, S)
    blocked, refl = _zone_canyon(t, windows, el, az, v_e, heading, cfg, g_geom, active)
    # the evaluated elements as flat indices e into (B, M, S) (epoch bm = e // S); ki: their segments' draws
    e = np.arange(B * M * S) if active is None else np.flatnonzero(active)
    bm = e // S
    s_e = e - bm * S
    kind_e = kind.reshape(-1)[bm]
    ki = ((bm // M) * K + idx.reshape(-1)[e]) * S + s_e
    el_e = el.reshape(-1)[e]
    u_over = u_pass.reshape(-1)[((bm // M) * Z + np.maximum(zone_id.reshape(-1)[bm], 0)) * S + s_e]
    blocked_e = blocked.reshape(-1)[e] | ((kind_e == ZONE_OVERPASS) & ~(u_over < cfg.overpass_pass_probability))
    p_nlos = nlos_probability(el_e, cfg.nlos_probability)
    p = np.where(kind_e == ZONE_CANYON, p_nlos, np.where(kind_e == ZONE_TREES, cfg.trees_multipath_scale * p_nlos,
                                                         0.0))
    nlos_e = ((u_nlos.reshape(-1)[ki] < p) & ~blocked_e) | refl.reshape(-1)[e]
    n = np.flatnonzero(nlos_e)                                                      # the NLOS few
    bias_n = nlos_bias(el_e[n], z_bias.reshape(-1)[ki[n]], u_sign.reshape(-1)[ki[n]], *cfg.nlos_bias) * np.where(
        kind_e[n] == ZONE_TREES, cfg.trees_bias_scale, 1.0)
    att_e = np.where(nlos_e, NLOS_DEFICIT_DB, 0.0)
    tr = np.flatnonzero(kind_e == ZONE_TREES)
    lo, hi = cfg.trees_attenuation_db
    att_e[tr] = (lo + (hi - lo) * u_att.reshape(-1)[ki[tr]]) + att_e[tr]
    nlos, bias, rate, att = np.zeros((B, M, S), dtype=bool), np.zeros((B, M, S)), np.zeros((B, M, S)), np.zeros(
        (B, M, S))
    blocked.reshape(-1)[e] = blocked_e
    nlos.reshape(-1)[e] = nlos_e
    bias.reshape(-1)[e[n]] = bias_n
    rate.reshape(-1)[e[n]] = cfg.nlos_rate_sigma_mps * z_rate.reshape(-1)[ki[n]]
    att.reshape(-1)[e] = att_e
    return blocked, nlos, bias, rate, att


def _zone_canyon(t, windows, el, az, v_e, heading, cfg: UrbanZones, g_geom, active):
    """The canyon geometry of :func:`zone_effects_rows` within each row's canyon windows: ``(blocked, reflected)``
    (B, M, S) bool (:func:`~envs.sim.canyon.canyon_visibility_rows` on the rows with a canyon window; none without a
    heading)."""
    B, M, S = el.shape
    blocked = np.zeros((B, M, S), dtype=bool)
    refl = np.zeros((B, M, S), dtype=bool)
    rows = [i for i in range(B) if any(k == ZONE_CANYON for _, _, k in windows[i])] if heading is not None else []
    if rows:
        within = np.zeros((len(rows), M), dtype=bool)
        for j, i in enumerate(rows):
            for a, b, k in windows[i]:
                if k == ZONE_CANYON:
                    within[j] |= (t >= a) & (t < b)
        blocked[rows], refl[rows], _ = canyon_visibility_rows(
            t, v_e[rows], heading[rows], el[rows], az[rows], cfg.canyon, [g_geom[i] for i in rows], within=within,
            active=None if active is None else active[rows])
    return blocked, refl


def regime_nlos(t, regime, el, cfg: NoiseRegimes, g: np.random.Generator):
    """Per-satellite NLOS of the noise regimes on one row (see :class:`NoiseRegimes`).

    Draw order: segment lengths (K, S), then per (K, S) NLOS uniforms, bias normals, sign uniforms, rate normals.

    Returns
    -------
    nlos : (M, S) bool; bias_m, rate_mps : (M, S).
    """
    M, S = el.shape
    idx, _, K = _renewal(t, cfg.nlos_segment_s, g, n=S)
    u = g.random((K, S))
    zb = g.standard_normal((K, S))
    us = g.random((K, S))
    zr = g.standard_normal((K, S))
    col = np.arange(S)[None, :]
    frac = np.array([r.nlos_fraction for r in cfg.regimes])[regime][:, None]
    nlos = u[idx, col] < frac
    bias = np.where(nlos, nlos_bias(el, zb[idx, col], us[idx, col]), 0.0)
    rate = np.where(nlos, cfg.nlos_rate_sigma_mps * zr[idx, col], 0.0)
    return nlos, bias, rate
