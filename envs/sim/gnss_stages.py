"""The stages of :func:`envs.sim.gnss.simulate_gnss`, in the order it runs them.

1. :func:`sky_geometry`: each row's GPS time and the elevation, azimuth and transmission time of all S
   satellites at all M epochs (:class:`Sky`);
2. :func:`canyon_and_bursts`: visibility above the mask, street-canyon blockage and reflections, NLOS bursts;
3. :func:`random_events`: the random events of :mod:`envs.sim.events` (bursts, mismatch, regimes, zones);
4. :func:`scheduled_events`: outages, the interval event bits, re-acquisition (2-4 fill
   :class:`SatelliteEvents`, per satellite);
5. :func:`allocate_channels`: the visible satellites on the C channels by elevation, C/N0 (:class:`Channels`);
6. :func:`channel_ranging`: ephemeris at transmission time, true range and rate on the tracked channels;
7. :func:`channel_noise`: each channel's NLOS state and true noise multipliers;
8. :func:`receiver_errors`: clock, atmosphere residuals, white noise, reported sigmas, true variances.

Row ``i`` draws only from the fixed child streams of its own generator (:func:`_row_children`; indices
``_SUB_*``), each stage from its own streams, so the stages may run in any grouping without changing a draw.
Stages 1 and 6 run compiled row kernels on threads (:mod:`envs.sim.geometry_kernels`); the others are vectorized
over rows and epochs except the per-row draws.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from earth.wgs84 import ecef_to_geodetic

from . import events as ev
from .buffers import empty
from .canyon import canyon_visibility_rows, in_intervals
from .constellation import Constellation
from .error_kernels import channel_noise_rows, nlos_burst_rows, receiver_tail_rows
from .geometry_kernels import channel_order_rows, ranging_rows, sky_rows
from .receiver import _MIN_EL_SIGMA, CN0_JITTER_DB, _gauss_markov_rows, iono_obliquity, simulate_clock, tropo_mapping
from .rng import ChildStreams, row_normals
from .rng import entropy_words as _entropy_words  # noqa: F401  (re-exported by envs.sim.gnss)
from .row_threads import run_row_ranges

GPS_WEEK_S = 604_800.0
"""Seconds in a GPS week: ``t0_gps`` is drawn uniformly in [0, GPS_WEEK_S)."""

# fixed child-stream indices of a row's generator inside simulate_gnss: a component
# added later gets a new index and never shifts another component's draws.
_SUB_SKY, _SUB_CLOCK, _SUB_TROPO, _SUB_IONO, _SUB_CODE, _SUB_RATE, _SUB_NLOS, _SUB_CANYON = range(8)
# issue 16 (random events): SeedSequence.spawn keys its children by index, so spawning more
# children leaves the first 8 streams, and every pre-existing draw, unchanged (tested).
(_SUB_BURSTS, _SUB_MISMATCH, _SUB_REGIME, _SUB_REGIME_NLOS, _SUB_ZONES, _SUB_ZONE_GEOM, _SUB_ZONE_SAT,
 _SUB_CN0) = range(8, 16)
_SUB_CN0_SCATTER = 16      # issue 36: the recorded-like C/N0 scatter (events.cn0), drawn only when configured
_N_SUB = 17


def _row_children(rng: np.random.Generator) -> ChildStreams:
    """Fixed child generators of one row (one per component), drawn from that row's generator only.

    One draw of 4 integers from ``rng`` is the entropy; child ``k`` (``0 .. _N_SUB-1``) is the ``k``-th
    child of ``SeedSequence(entropy)`` (built lazily, see :class:`envs.sim.rng.ChildStreams`).
    """
    entropy = rng.integers(0, 2**63, size=4, dtype=np.int64)
    return ChildStreams([int(x) for x in entropy], _N_SUB)


class _Child:
    """Child ``k`` of each row's streams, ``_Child(subs, k)[i] = subs[i][k]``: built only for the rows that
    index it (a generator costs ~10 us to build)."""

    __slots__ = ("_subs", "_k")

    def __init__(self, subs, k: int):
        self._subs, self._k = subs, k

    def __getitem__(self, i: int) -> np.random.Generator:
        return self._subs[i][self._k]


def _nlos_bursts(t: np.ndarray, n_sats: int, cfg: NlosConfig, g: np.random.Generator):
    """Per-satellite NLOS bursts of one row (alternating renewal process, see :class:`~envs.sim.gnss.NlosConfig`):
    :func:`_nlos_burst_rows` with one row.

    Returns
    -------
    active : (M, S) bool; bias_m : (M, S) [m]; rate_mps : (M, S) [m/s].
    """
    active, bias, rate = _nlos_burst_rows(t, n_sats, cfg, [g])
    return active[0], bias[0], rate[0]


def _nlos_burst_rows(t: np.ndarray, n_sats: int, cfg: NlosConfig, gens):
    """Per-satellite NLOS bursts of B rows, each drawn from its own generator ``gens[i]``: passes of ``n_cyc``
    cycles per satellite (gaps ``Exp(1 / rate_hz)``, durations ``U(duration_s)``, biases ``U(bias_m)``, rates
    ``N(0, rate_sigma_mps^2)``, in this order) until every satellite's cycles pass the last epoch (almost always
    one pass); then mapped onto the epochs by :func:`~envs.sim.error_kernels.nlos_burst_rows`.

    Returns
    -------
    active : (B, M, S) bool; bias_m : (B, M, S) [m]; rate_mps : (B, M, S) [m/s].
    """
    M, B = t.size, len(gens)
    shape = (B, M, n_sats)
    if cfg.rate_hz <= 0.0 or B == 0:
        return np.zeros(shape, dtype=bool), np.zeros(shape), np.zeros(shape)
    d_lo, d_hi = cfg.duration_s
    t_begin = t[0] - d_hi                                  # a burst may already run at t[0]
    span = t[-1] - t_begin
    mean_cycle = 1.0 / cfg.rate_hz + 0.5 * (d_lo + d_hi)
    n_exp = span / mean_cycle
    n_cyc = int(math.ceil(n_exp + 6.0 * math.sqrt(n_exp) + 3.0))
    rows = []
    for g in gens:
        draws = []
        end = np.full(n_sats, t_begin)
        while True:                                        # almost always one pass
            gp = g.exponential(1.0 / cfg.rate_hz, size=(n_cyc, n_sats))
            du = g.uniform(d_lo, d_hi, size=(n_cyc, n_sats))
            bs = g.uniform(cfg.bias_m[0], cfg.bias_m[1], size=(n_cyc, n_sats))
            draws.append((gp, du, bs, cfg.rate_sigma_mps * g.standard_normal((n_cyc, n_sats))))
            end = end + np.sum(gp + du, axis=0)
            if np.all(end > t[-1]):
                break
        rows.append(draws)
    K = np.array([len(d) * n_cyc for d in rows], dtype=np.int64)
    cycles = np.zeros((4, B, int(K.max()), n_sats))       # gaps, durations, biases, rates
    for i, draws in enumerate(rows):
        for p, d in enumerate(draws):
            cycles[:, i, p * n_cyc:(p + 1) * n_cyc] = d
    active, bias, rate = np.empty(shape, dtype=bool), np.empty(shape), np.empty(shape)
    nlos_burst_rows(np.ascontiguousarray(t, dtype=np.float64), float(t_begin), K, *cycles, active, bias, rate)
    return active, bias, rate


# =============================================================================
# stage results
# =============================================================================
@dataclass
class Sky:
    """The sky of B rows over M epochs, all S satellites (:func:`sky_geometry`).

    Attributes
    ----------
    t0_gps : (B,) GPS time of ``t = 0`` per row [s].
    t_tx : (B, M, S) transmission time [s]; el, az : (B, M, S) elevation, azimuth [rad]; a satellite below the
    local horizon: :data:`~envs.sim.geometry_kernels.BELOW_HORIZON_EL` and 0 (never visible: the elevation mask is
    >= 0 deg; its angles are not formed).
    """

    t0_gps: np.ndarray
    t_tx: np.ndarray
    el: np.ndarray
    az: np.ndarray


@dataclass
class SatelliteEvents:
    """What the degradations do to each satellite and epoch (:func:`canyon_and_bursts`, :func:`random_events`,
    :func:`scheduled_events`); the stages fill it in that order.

    Attributes
    ----------
    visible : (B, M, S) bool, above the mask and not blocked (canyon, zones, outages).
    nlos, nlos_bias, nlos_rate : (B, M, S) NLOS flag, pseudorange bias [m], rate error [m/s] of the canyon
        reflections and NLOS bursts.
    code_mult, doppler_mult : (B, M) true code / Doppler sigma multipliers of the random bursts and regimes.
    code_rep, doppler_rep : (B, M) reported-sigma factors of the mismatch, or None without one.
    bits : (B, M) uint16 event bits.
    zone : None, or ``(nlos, bias, rate, att)`` (B, M, S) each: the NLOS of the zones and regimes (they replace
        the others on a channel) and the C/N0 loss [dB] of the zones.
    reacq : (B, M, S) re-acquisition noise multiplier, or None.
    """

    visible: np.ndarray
    nlos: np.ndarray
    nlos_bias: np.ndarray
    nlos_rate: np.ndarray
    code_mult: np.ndarray
    doppler_mult: np.ndarray
    bits: np.ndarray
    code_rep: np.ndarray | None = None
    doppler_rep: np.ndarray | None = None
    zone: tuple | None = None
    reacq: np.ndarray | None = None


@dataclass
class Channels:
    """The tracked satellites on the receiver's C channels (:func:`allocate_channels`).

    Attributes
    ----------
    sel : (B, M, C) satellite index of each channel (0 on the padding when C > S).
    mask : (B, M, C) bool, the channel tracks a satellite.
    el, az : (B, M, C) [rad]; cn0 : (B, M, C) C/N0 before the NLOS and zone losses [dB-Hz].
    flat_sel : (B, M, C) flat index into a (B, M, S) array (:meth:`gather`).
    nlos_deficit : (B, M, C) C/N0 loss of an NLOS channel [dB] (:class:`envs.sim.events.Cn0Scatter`), or None:
        the constant :data:`envs.sim.events.NLOS_DEFICIT_DB`.
    """

    sel: np.ndarray
    mask: np.ndarray
    el: np.ndarray
    az: np.ndarray
    cn0: np.ndarray
    flat_sel: np.ndarray
    nlos_deficit: np.ndarray | None = None

    def gather(self, a: np.ndarray, rows: slice = slice(None)) -> np.ndarray:
        """(B, M, S) per-satellite array -> (B, M, C) per-channel array (``a[b, k, sel[b, k, c]]``), or the
        ``rows`` (a slice) of it."""
        return np.take(a, self.flat_sel[rows])


@dataclass
class Ranging:
    """Ephemeris at transmission time and true range / rate on the tracked channels (:func:`channel_ranging`;
    zeros on the others): sat_pos, sat_vel (B, M, C, 3) [m, m/s], rho, rho_dot (B, M, C) [m, m/s]."""

    sat_pos: np.ndarray
    sat_vel: np.ndarray
    rho: np.ndarray
    rho_dot: np.ndarray


@dataclass
class ChannelNoise:
    """The NLOS state and the true white-noise multipliers of each channel (:func:`channel_noise`).

    Attributes
    ----------
    nlos : (B, M, C) bool; pr_bias, prr_bias : (B, M, C) NLOS pseudorange bias [m] and rate error [m/s] (0 off
    NLOS); code_mult, doppler_mult : (B, M, C) multipliers of the nominal code / Doppler sigma.
    """

    nlos: np.ndarray
    pr_bias: np.ndarray
    prr_bias: np.ndarray
    code_mult: np.ndarray
    doppler_mult: np.ndarray


@dataclass
class ReceiverErrors:
    """The errors and sigmas of each channel (:func:`receiver_errors`): clock bias_m, drift_mps (B, M) [m, m/s];
    pr_err, prr_err (B, M, C) [m, m/s]; the reported pr_sigma, prr_sigma and the true pr_var_true, prr_var_true
    (B, M, C) (see :class:`envs.sim.gnss.GnssData`)."""

    bias_m: np.ndarray
    drift_mps: np.ndarray
    pr_err: np.ndarray
    prr_err: np.ndarray
    pr_sigma: np.ndarray
    prr_sigma: np.ndarray
    pr_var_true: np.ndarray
    prr_var_true: np.ndarray


# =============================================================================
# stages
# =============================================================================
def sky_geometry(t, r_e, constellation: Constellation, subs, t0_gps=None) -> Sky:
    """Stage 1: the GPS time of each row and the transmission time, elevation and azimuth of all satellites
    (:func:`envs.sim.geometry_kernels.sky_rows`, row ranges on threads; the result does not depend on the split).

    Parameters
    ----------
    t : (M,) epochs [s]; r_e : (B, M, 3) receiver ECEF position [m]; subs : B rows' child streams
    (:func:`_row_children`); t0_gps : (B,) or None: drawn ``U[0, GPS_WEEK_S)`` from each row's sky stream.
    """
    B, M = r_e.shape[:2]
    if t0_gps is None:
        t0_gps = np.array([s[_SUB_SKY].uniform(0.0, GPS_WEEK_S) for s in subs])
    S = constellation.n_sats
    t_rx = t0_gps[:, None] + t[None, :]                     # (B, M)
    t_tx, el_all, az_all = (np.empty((B, M, S)) for _ in range(3))
    consts = constellation.kernel_constants()
    trig = [np.empty((B, M)) for _ in range(4)]             # sin / cos of the receiver's latitude and longitude

    def rows(r0, r1):  # those too per range of rows (numpy's elementwise ufuncs: the same bits as one call)
        lat, lon, _ = ecef_to_geodetic(r_e[r0:r1])
        for out, f, x in zip(trig, (np.sin, np.cos, np.sin, np.cos), (lat, lat, lon, lon)):
            f(x, out=out[r0:r1])
        sky_rows(r0, r1, t_rx, r_e, *trig, *consts, t_tx, el_all, az_all)

    run_row_ranges(rows, B)
    return Sky(t0_gps=t0_gps, t_tx=t_tx, el=el_all, az=az_all)


def canyon_and_bursts(t, v_e, heading, sky: Sky, mask_deg: float, events, subs) -> SatelliteEvents:
    """Stage 2: visibility above the elevation mask, the street canyon's blockage and reflections and the NLOS
    bursts (:class:`~envs.sim.canyon.UrbanCanyon`, :class:`~envs.sim.gnss.NlosConfig`), per row from its canyon and
    NLOS streams; the other fields start neutral (multipliers 1, no bits)."""
    B, M, S = sky.el.shape
    visible = sky.el >= math.radians(mask_deg)
    nlos_sat = np.zeros((B, M, S), dtype=bool)
    nlos_bias_sat = np.zeros((B, M, S))
    nlos_rate_sat = np.zeros((B, M, S))
    if events.canyon is not None:
        blocked, refl, nlos_bias_sat = canyon_visibility_rows(t, v_e, heading, sky.el, sky.az, events.canyon,
                                                              [s[_SUB_CANYON] for s in subs])
        visible &= ~blocked
        nlos_sat |= refl
    if events.nlos is not None:
        act, bias, nlos_rate_sat = _nlos_burst_rows(t, S, events.nlos, [s[_SUB_NLOS] for s in subs])
        nlos_sat |= act
        np.maximum(nlos_bias_sat, bias, out=nlos_bias_sat)
    return SatelliteEvents(visible=visible, nlos=nlos_sat, nlos_bias=nlos_bias_sat, nlos_rate=nlos_rate_sat,
                           code_mult=np.ones((B, M)), doppler_mult=np.ones((B, M)),
                           bits=np.zeros((B, M), dtype=np.uint16))


EVENT_RANGE_ROWS = 32
"""Fewest rows per range of the events' row ranges on threads (the urban zones, :func:`_zone_rows`; the
re-acquisition transient; :func:`channel_noise`), from twice as many rows on: numpy arithmetic on whole arrays of
rows, which releases the GIL."""


def random_events(t, v_e, heading, sky: Sky, sat: SatelliteEvents, events, subs) -> None:
    """Stage 3: the random events of :mod:`envs.sim.events` into ``sat`` (in place), each from its own child
    stream and drawn only when configured: bursts of the true noise, reported-sigma mismatch, noise regimes
    (with their NLOS) and urban zones (blockage, NLOS, C/N0 loss), in this order."""
    B, M, S = sky.el.shape
    new_nlos = events.zones is not None or (events.regimes is not None
                                            and any(r.nlos_fraction > 0 for r in events.regimes.regimes))
    if new_nlos:                                           # NLOS of the zones / regimes, and their C/N0 loss
        nlos2_sat = np.zeros((B, M, S), dtype=bool)
        bias2_sat = np.zeros((B, M, S))
        rate2_sat = np.zeros((B, M, S))
        att_sat = np.zeros((B, M, S))
    visible, bits = sat.visible, sat.bits
    if events.bursts is not None:
        for i in range(B):
            c, d, act, _ = ev.draw_bursts(t, events.bursts, subs[i][_SUB_BURSTS])
            sat.code_mult[i] *= c
            sat.doppler_mult[i] *= d
            bits[i] |= np.where(act, ev.NOISE, 0).astype(np.uint16)
    if events.mismatch is not None:
        sat.code_rep, sat.doppler_rep = np.ones((B, M)), np.ones((B, M))
        for i in range(B):
            fp, fd = ev.draw_mismatch(t, events.mismatch, subs[i][_SUB_MISMATCH])
            sat.code_rep[i], sat.doppler_rep[i] = fp, fd
            bits[i] |= np.where((fp != 1.0) | (fd != 1.0), ev.MISMATCH, 0).astype(np.uint16)
    if events.regimes is not None:
        rg = events.regimes
        sc = np.array([[r.code_scale, r.doppler_scale] for r in rg.regimes])
        for i in range(B):
            regime, _ = ev.draw_regimes(t, rg, subs[i][_SUB_REGIME])
            sat.code_mult[i] *= sc[regime, 0]
            sat.doppler_mult[i] *= sc[regime, 1]
            bits[i] |= np.where(regime > 0, ev.REGIME, 0).astype(np.uint16)
            if new_nlos:
                nl, bi, ra = ev.regime_nlos(t, regime, sky.el[i], rg, subs[i][_SUB_REGIME_NLOS])
                nl &= visible[i]
                nlos2_sat[i] |= nl
                bias2_sat[i] = np.where(nl, bi, bias2_sat[i])
                rate2_sat[i] = np.where(nl, ra, rate2_sat[i])
    if events.zones is not None:
        run_row_ranges(lambda r0, r1: _zone_rows(r0, r1, t, v_e, heading, sky, sat, events.zones, subs, nlos2_sat,
                                                 bias2_sat, rate2_sat, att_sat), B, min_rows=EVENT_RANGE_ROWS)
    if new_nlos:                                           # the regimes' NLOS carry the measured C/N0 deficit too
        att_sat = np.where(nlos2_sat & (att_sat == 0.0), ev.NLOS_DEFICIT_DB, att_sat)
        sat.zone = (nlos2_sat, bias2_sat, rate2_sat, att_sat)


def _zone_rows(r0: int, r1: int, t, v_e, heading, sky: Sky, sat: SatelliteEvents, zones, subs, nlos2, bias2, rate2,
               att) -> None:
    """The urban zones of rows ``r0 .. r1-1`` (:func:`~envs.sim.events.draw_zone_schedule` per row,
    :func:`~envs.sim.events.zone_effects_rows` over them) into those rows of ``sat.visible``, ``sat.bits`` and the
    zones' NLOS arrays ``nlos2``, ``bias2``, ``rate2`` and C/N0 loss ``att`` (B, M, S), in place."""
    sl = slice(r0, r1)
    rows = subs[r0:r1]
    sched = [ev.draw_zone_schedule(t, zones, s[_SUB_ZONES]) for s in rows]
    kind = np.array([k for k, _, _ in sched])                                         # (rows, M)
    visible = sat.visible[sl]
    blocked, nl, bi, ra, at = ev.zone_effects_rows(
        t, kind, np.array([z for _, z, _ in sched]), [w for _, _, w in sched], sky.el[sl], sky.az[sl], v_e[sl],
        None if heading is None else heading[sl], zones, _Child(rows, _SUB_ZONE_GEOM), _Child(rows, _SUB_ZONE_SAT),
        active=visible)      # the zones change only what is visible: the other elements are left out
    visible &= ~blocked
    nl &= visible
    nlos2[sl] |= nl
    np.copyto(bias2[sl], bi, where=nl)
    np.copyto(rate2[sl], ra, where=nl)
    np.copyto(att[sl], np.where(visible, at, 0.0))
    zb = np.zeros(kind.shape, dtype=np.uint16)
    zb[kind == ev.ZONE_CANYON] = ev.NLOS_ZONE
    zb[kind == ev.ZONE_TREES] = ev.NLOS_ZONE | ev.TREES
    zb[kind == ev.ZONE_OVERPASS] = ev.OVERPASS
    sat.bits[sl] |= zb


def scheduled_events(t, sat: SatelliteEvents, events) -> None:
    """Stage 4: the scheduled events into ``sat`` (in place): full outages, the event bits of the noise-scale and
    canyon intervals, and the re-acquisition transient (after every blockage is known)."""
    M = t.size
    if events.outages:
        in_out = in_intervals(t, events.outages)
        sat.visible &= ~in_out[None, :, None]
        sat.bits |= np.where(in_out, ev.OUTAGE, 0).astype(np.uint16)[None]
    for iv in events.noise_scale:
        if iv[2] != 1.0:
            sat.bits |= np.where((t >= iv[0]) & (t < iv[1]), ev.NOISE, 0).astype(np.uint16)[None]
    if events.canyon is not None:
        in_c = in_intervals(t, events.canyon.intervals) if events.canyon.intervals else np.ones(M, bool)
        sat.bits |= np.where(in_c, ev.NLOS_ZONE, 0).astype(np.uint16)[None]
    if events.reacquisition is not None:   # each row on its own (row ranges on threads: the same bits)
        sat.reacq = np.empty(sat.visible.shape)

        def reacq_rows(r0, r1):
            sat.reacq[r0:r1] = ev.reacquisition_multiplier(t, sat.visible[r0:r1], events.reacquisition)

        run_row_ranges(reacq_rows, sat.visible.shape[0], min_rows=EVENT_RANGE_ROWS)


CHANNEL_RANGE_ROWS = 32
"""Fewest rows per range of :func:`allocate_channels`'s row ranges on threads (from twice as many rows on)."""


def allocate_channels(sky: Sky, visible, n_channels: int, subs, t=None, cn0_cfg=None) -> Channels:
    """Stage 5: the visible satellites on the C channels by elevation, descending (stable), and each channel's
    C/N0: :func:`envs.sim.events.cn0_los` plus the jitter, drawn per satellite from the row's C/N0 stream, or,
    with ``cn0_cfg`` (:class:`envs.sim.events.Cn0Scatter`, epochs ``t`` (M,) [s]), its scatter
    (:func:`envs.sim.events.cn0_scatter`, from the row's C/N0-scatter stream) and NLOS deficit. The rows run in
    ranges on threads (:func:`_channel_rows`, from 2 :data:`CHANNEL_RANGE_ROWS` rows on: the same bits)."""
    B, M, S = sky.el.shape
    C = n_channels
    e = np.empty
    ch = Channels(sel=e((B, M, C), np.intp), mask=e((B, M, C), bool), el=e((B, M, C)), az=e((B, M, C)),
                  cn0=e((B, M, C)), flat_sel=e((B, M, C), np.int64),
                  nlos_deficit=None if cn0_cfg is None else e((B, M, C)))
    run_row_ranges(lambda r0, r1: _channel_rows(r0, r1, sky, visible, subs, t, cn0_cfg, ch), B,
                   min_rows=CHANNEL_RANGE_ROWS)
    return ch


def _channel_rows(r0: int, r1: int, sky: Sky, visible, subs, t, cn0_cfg, ch: Channels) -> None:
    """:func:`allocate_channels` of rows ``r0 .. r1-1`` into those rows of ``ch``'s arrays (the C/N0 scatter of
    ``cn0_cfg`` by :func:`~envs.sim.events.cn0_scatter_rows` from the rows' scatter streams, the numbers
    :func:`~envs.sim.events.cn0_scatter` draws row by row)."""
    sl = slice(r0, r1)
    _, M, S = sky.el.shape
    C = ch.sel.shape[-1]
    channel_order_rows(r0, r1, visible, sky.el, ch.sel)
    sel = ch.sel[sl]
    # one flat index into (B, M, S) arrays serves every gather (one np.take instead of take_along_axis)
    flat_sel = ch.flat_sel[sl]
    flat_sel[...] = sel + (S * np.arange(r0 * M, r1 * M)).reshape(r1 - r0, M, 1)
    local = flat_sel - r0 * M * S  # the same into these rows' (r1 - r0, M, S) arrays
    ch.mask[sl] = np.take(visible[sl], local)
    ch.el[sl] = np.take(sky.el[sl], local)
    ch.az[sl] = np.take(sky.az[sl], local)
    if C > S:
        ch.mask[sl, ..., S:] = False
    if cn0_cfg is None:
        cn0_z = row_normals(subs[r0:r1], _SUB_CN0, (M, S))                         # C/N0 jitter, per satellite
        ch.cn0[sl] = ev.cn0_los(ch.el[sl]) + CN0_JITTER_DB * np.take(cn0_z, local)
        return
    z = row_normals(subs[r0:r1], _SUB_CN0_SCATTER, (ev.cn0_scatter_draws(M, S, C),))
    los, deficit, white = ev.cn0_scatter_rows(t, S, C, cn0_cfg, z)
    ch.cn0[sl] = ev.cn0_los(ch.el[sl]) + np.take(los, local) + white
    ch.nlos_deficit[sl] = np.take(deficit, local)


def channel_ranging(r_e, v_e, sky: Sky, ch: Channels, constellation: Constellation, buffers=None) -> Ranging:
    """Stage 6: ephemeris at transmission time and true range / rate on the tracked channels only (zeros on the
    others): :func:`envs.sim.geometry_kernels.ranging_rows` (range and rate as
    :func:`earth.ranging.range_and_rate`), row ranges on threads; the outputs from ``buffers``
    (:class:`envs.sim.buffers.WorldBuffers`) when given."""
    B, M, C = ch.mask.shape
    t_tx_ch = ch.gather(sky.t_tx)
    sat_pos = empty(buffers, "gnss.sat_pos", (B, M, C, 3), np.float64)
    sat_vel = empty(buffers, "gnss.sat_vel", (B, M, C, 3), np.float64)
    rho = empty(buffers, "gnss.rho", (B, M, C), np.float64)
    rho_dot = empty(buffers, "gnss.rho_dot", (B, M, C), np.float64)
    consts = constellation.kernel_constants()
    r_e, v_e = np.ascontiguousarray(r_e, dtype=np.float64), np.ascontiguousarray(v_e, dtype=np.float64)
    run_row_ranges(lambda r0, r1: ranging_rows(r0, r1, t_tx_ch, ch.sel, ch.mask, r_e, v_e, *consts, sat_pos, sat_vel,
                                               rho, rho_dot), B)
    return Ranging(sat_pos=sat_pos, sat_vel=sat_vel, rho=rho, rho_dot=rho_dot)


def channel_noise(t, ch: Channels, sat: SatelliteEvents, events) -> ChannelNoise:
    """Stage 7: each channel's NLOS state and true noise multipliers: the NLOS factor ``k_nlos`` (or, for the
    zones' and regimes' NLOS, their C/N0 loss ``10^(att/20)``), the noise-scale intervals, the re-acquisition
    transient, the bursts and regimes. Subtracts the NLOS / zone C/N0 losses from ``ch.cn0`` and sets the
    re-acquisition bit in ``sat.bits`` (in place). Elementwise per channel: the compiled
    :func:`~envs.sim.error_kernels.channel_noise_rows` in row ranges on threads (from 2 :data:`EVENT_RANGE_ROWS`
    rows on: the same bits)."""
    B, M, C = ch.mask.shape
    scale = np.ones(M)
    for iv in events.noise_scale:
        scale = np.where((t >= iv[0]) & (t < iv[1]), scale * iv[2], scale)
    e = np.empty
    out = ChannelNoise(nlos=e((B, M, C), bool), pr_bias=e((B, M, C)), prr_bias=e((B, M, C)), code_mult=e((B, M, C)),
                       doppler_mult=e((B, M, C)))
    none = np.empty(0)
    zone = sat.zone is not None
    zone_flat = [a.reshape(-1) for a in sat.zone] if zone else [np.empty(0, bool), none, none, none]
    att_pow = e((B, M, C)) if zone else np.empty((0, 0, 0))
    epoch_mult = events.bursts is not None or events.regimes is not None   # sat.code_mult, doppler_mult apply
    args = (scale, sat.nlos.reshape(-1), sat.nlos_bias.reshape(-1), sat.nlos_rate.reshape(-1),
            float(events.nlos.noise_factor if events.nlos is not None else 3.0), float(ev.NLOS_DEFICIT_DB),
            ch.nlos_deficit if ch.nlos_deficit is not None else np.empty((0, 0, 0)), zone, *zone_flat, att_pow,
            none if sat.reacq is None else sat.reacq.reshape(-1), ev.REACQUISITION, epoch_mult, sat.code_mult,
            sat.doppler_mult, sat.bits, out.nlos, out.pr_bias, out.prr_bias, out.code_mult, out.doppler_mult)

    def rows(r0, r1):
        if zone:  # the zones' C/N0 loss as a noise factor, by numpy's power (its rounding)
            att_pow[r0:r1] = 10.0 ** (ch.gather(sat.zone[3], slice(r0, r1)) / 20.0)
        channel_noise_rows(r0, r1, ch.flat_sel, ch.mask, ch.cn0, *args)

    run_row_ranges(rows, B, min_rows=EVENT_RANGE_ROWS)
    return out


RECEIVER_RANGE_ROWS = 32
"""Fewest rows per range of :func:`receiver_errors`'s row ranges on threads (from twice as many rows on)."""


def receiver_errors(t, ch: Channels, noise: ChannelNoise, sat: SatelliteEvents, receiver, subs,
                    buffers=None) -> ReceiverErrors:
    """Stage 8: the receiver clock, the residual troposphere (one Gauss-Markov process per row) and ionosphere
    (one per satellite), the white code and Doppler noise, the reported sigmas (nominal, or the receiver's
    :attr:`~envs.sim.receiver.ReceiverConfig.sigma_model`, times the mismatch factors) and the true variances
    (the module docstring of :mod:`envs.sim.gnss`), from the rows' clock, troposphere, ionosphere, code and
    Doppler streams. The rows run in ranges on threads (:func:`_receiver_rows`, from 2
    :data:`RECEIVER_RANGE_ROWS` rows on; each row depends only on its own streams and channels: the same bits);
    the (B, M, C) outputs and variates come from ``buffers`` (:class:`envs.sim.buffers.WorldBuffers`) when
    given."""
    M = t.size
    B, C = ch.mask.shape[0], ch.mask.shape[-1]
    shape = (B, M, C)
    draws = (empty(buffers, "gnss.code_z", shape, np.float64), empty(buffers, "gnss.rate_z", shape, np.float64))
    out = [empty(buffers, f"gnss.{name}", shape, np.float64)
           for name in ("pr_err", "prr_err", "pr_sigma", "prr_sigma", "pr_var_true", "prr_var_true")]
    clock = (np.empty((B, M)), np.empty((B, M)))
    run_row_ranges(lambda r0, r1: _receiver_rows(r0, r1, t, ch, noise, sat, receiver, subs, draws, clock, out), B,
                   min_rows=RECEIVER_RANGE_ROWS)
    return ReceiverErrors(*clock, *out)


def _receiver_rows(r0: int, r1: int, t, ch: Channels, noise: ChannelNoise, sat: SatelliteEvents, receiver, subs,
                   draws, clock, out) -> None:
    """:func:`receiver_errors` of rows ``r0 .. r1-1``, into rows ``r0 .. r1-1`` of ``draws`` (the code and rate
    variates, (B, M, C)), ``clock`` (bias and drift, (B, M)) and ``out`` (the six (B, M, C) outputs); the
    per-channel arithmetic in the compiled :func:`~envs.sim.error_kernels.receiver_tail_rows`."""
    sl = slice(r0, r1)
    M = t.size
    S = sat.visible.shape[-1]
    C = ch.mask.shape[-1]
    rows = subs[r0:r1]
    el = ch.el[sl]
    clock[0][sl], clock[1][sl] = simulate_clock(t, [s[_SUB_CLOCK] for s in rows], receiver.clock)
    s_el = np.sin(np.maximum(el, _MIN_EL_SIGMA))
    m_t, f_i = tropo_mapping(el), iono_obliquity(el)
    # the Gauss-Markov processes of the rows in one call each (columns are independent)
    tropo_z = _gauss_markov_rows(t, receiver.tropo_tau_s, receiver.tropo_zenith_sigma_m,
                                 row_normals(rows, _SUB_TROPO, (M, 1)))[:, :, 0]
    iono_sat = _gauss_markov_rows(t, receiver.iono_tau_s, receiver.iono_zenith_sigma_m,   # one per satellite
                                  row_normals(rows, _SUB_IONO, (M, S)))
    iono_ch = np.take(iono_sat, ch.flat_sel[sl] - r0 * M * S)  # Channels.gather of the rows
    del iono_sat
    code_z = row_normals(rows, _SUB_CODE, (M, C), out=draws[0][sl])
    rate_z = row_normals(rows, _SUB_RATE, (M, C), out=draws[1][sl])
    part = [o[sl] for o in out]
    nominal = receiver.sigma_model.name == "receiver"
    if not nominal:                                          # a variance model replaces the nominal sigma
        with np.errstate(over="ignore"):
            np.sqrt(receiver.sigma_model.variance(el, ch.cn0[sl]), out=part[2])
    rep = sat.code_rep is not None                           # the reported-sigma mismatch
    no_rep = np.ones((1, 1))
    code_rep, doppler_rep = (sat.code_rep[sl], sat.doppler_rep[sl]) if rep else (no_rep, no_rep)
    receiver_tail_rows(
        0, r1 - r0, m_t, f_i, tropo_z, iono_ch, s_el, noise.pr_bias[sl], noise.prr_bias[sl], noise.code_mult[sl],
        noise.doppler_mult[sl], code_z, rate_z, ch.mask[sl], float(receiver.pr_sigma_m), float(receiver.prr_sigma_mps),
        float(receiver.tropo_zenith_sigma_m), float(receiver.iono_zenith_sigma_m), nominal, code_rep, doppler_rep,
        rep, *part)
