"""Run the batched navigator over a generated world: the loop shared by eval.py and the environments.

:func:`navigator_for` turns a scenario into a navigator the way a navigation
engineer would set one up: the process noise comes from the IMU *data sheet*
(the grade the scenario names) and the receiver's nominal clock model, the
initial covariance from the stated initial uncertainty. The filter never sees
the truth; the truth is used only to score it (:class:`EpisodeLog`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from earth import ecef_to_geodetic
from earth.wgs84 import C_en
from nav_filters.error_model import BA, BG, CLK, DRIFT, N_STATES, POS, VEL, ATT, ProcessNoise
from nav_filters.navigator import Navigator, NavigatorConfig

from .sim.world import World
from .aiding import odometer_rows, with_rows
from .zupt_source import STILL_SPEED_MPS, ZuptSource


def satellite_keys(gnss) -> np.ndarray:
    """(B, M, C) int64 satellite keys of a world's channels (:func:`nav_filters.measurements.satellite_key`),
    -1 on empty channels.

    ``GnssData.prn`` is ``key + 1``: a simulated constellation is one GPS-like system (key = PRN - 1), a
    recording encodes system and PRN (:meth:`envs.datasets.epochs.GnssEpochs.sat_keys`)."""
    prn = np.asarray(gnss.prn)
    return np.where(np.asarray(gnss.mask) & (prn >= 1), prn - 1, -1).astype(np.int64)


def process_noise_for(world: World) -> ProcessNoise:
    """Filter process noise from the scenario's IMU grade (data-sheet values) and clock model."""
    g = world.imu_grade
    clock = world.scenario.receiver.clock
    return ProcessNoise.from_imu_specs(
        arw=max(g.gyro_arw, 1e-7), vrw=max(g.accel_vrw, 1e-6),
        gyro_bias_instability=max(g.gyro_bias_instability, 1e-9), gyro_bias_tau_s=g.gyro_bias_tau_s,
        accel_bias_instability=max(g.accel_bias_instability, 1e-8), accel_bias_tau_s=g.accel_bias_tau_s,
        clock_q_bias=clock.q_bias, clock_q_drift=clock.q_drift)


def initial_covariance(world: World, dtype=np.float64) -> np.ndarray:
    """(B, 17, 17) diagonal P0 matching the scenario's initial uncertainty and the IMU grade."""
    init, g = world.init, world.imu_grade
    B = world.batch_size
    P0 = np.zeros((B, N_STATES, N_STATES))
    P0[:, ATT, ATT] = init.att_cov_e
    P0[:, VEL, VEL] = init.vel_cov_e
    P0[:, POS, POS] = init.pos_cov_e
    bg = np.hypot(g.gyro_bias_turn_on_sigma, g.gyro_bias_instability) * np.ones(3)
    ba = np.hypot(g.accel_bias_turn_on_sigma, g.accel_bias_instability) * np.ones(3)
    if g.gyro_bias_fixed is not None:
        bg = np.maximum(bg, np.abs(np.asarray(g.gyro_bias_fixed)))
    if g.accel_bias_fixed is not None:
        ba = np.maximum(ba, np.abs(np.asarray(g.accel_bias_fixed)))
    idx = np.arange(N_STATES)
    P0[:, idx[BG], idx[BG]] = np.square(np.maximum(bg, 1e-7))
    P0[:, idx[BA], idx[BA]] = np.square(np.maximum(ba, 1e-5))
    P0[:, CLK, CLK] = init.clock_sigma_m ** 2
    P0[:, DRIFT, DRIFT] = init.drift_sigma_mps ** 2
    # a zero initial sigma (e.g. perfectly known) would make P0 singular: floor the diagonal
    P0[:, idx, idx] = np.maximum(P0[:, idx, idx], 1e-12)
    P0 = P0.astype(dtype)
    return P0


def navigator_for(world: World, method: str = "kf", dtype="float64", **config) -> Navigator:
    """A :class:`Navigator` initialized from the world's initial estimate (truth + initial errors)."""
    cfg = NavigatorConfig(method=method, noise=process_noise_for(world), dtype=str(np.dtype(dtype)), **config)
    i = world.init
    return Navigator(cfg, i.r_e, i.v_e, i.C_eb, initial_covariance(world, dtype), i.clock_bias_m, i.clock_drift_mps)


@dataclass(frozen=True)
class EpisodeLog:
    """Per-epoch record of B episodes of one method (arrays batch first, M epochs).

    Attributes
    ----------
    t : (M,) epoch times [s].
    pos_err_ned : (B, M, 3) estimate minus truth, NED at the true position [m].
    vel_err_ned : (B, M, 3) [m/s].
    nees_pv : (B, M) NEES of the 6 position/velocity states after the update.
    nis : (B, M) NIS of the update; n_used : (B, M) measurement rows used.
    n_sats : (B, M) satellites used; gdop : (B, M).
    zupt : (B, M) bool, the zero-velocity constraints were applied at the epoch.
    diverged : (B,) bool.
    filter_time_s : wall time spent in the navigator (all B rows).
    params : ``{name: (B, M)}`` the filter parameter values a policy set at each epoch (the action in the
        parameter's units, e.g. the Sage-Husa ``b``), or None for a method with fixed parameters.
    n_excluded : (B, M) int measurement rows the method excluded at each epoch (fault exclusion, IGG-III's
        zero weights), or None for a method that never excludes.
    """

    t: np.ndarray
    pos_err_ned: np.ndarray
    vel_err_ned: np.ndarray
    nees_pv: np.ndarray
    nis: np.ndarray
    n_used: np.ndarray
    n_sats: np.ndarray
    gdop: np.ndarray
    zupt: np.ndarray
    diverged: np.ndarray
    filter_time_s: float
    params: dict | None = None
    n_excluded: np.ndarray | None = None

    @property
    def horizontal_error(self) -> np.ndarray:
        """(B, M) horizontal position error [m]."""
        return np.hypot(self.pos_err_ned[..., 0], self.pos_err_ned[..., 1])

    @property
    def error_3d(self) -> np.ndarray:
        """(B, M) 3D position error [m]."""
        return np.linalg.norm(self.pos_err_ned, axis=-1)


def run_episodes(world: World, method: str = "kf", dtype="float64", progress=None, params: dict | None = None,
                 zupt: str = "none", zupt_weights=None, **config) -> EpisodeLog:
    """Run the navigator over every IMU sample and GNSS epoch of ``world``.

    Parameters
    ----------
    world : the generated world (B rows).
    method : filter method name (DESIGN.md section 4).
    dtype : filter arithmetic, ``'float64'`` or ``'float32'``.
    progress : optional callable ``progress(n_epochs_done)`` called after each epoch.
    params : fixed parameters of an adaptive method, ``{name: scalar or (B,) array}`` (e.g. ``{"b": 0.995}``),
        set once before the first epoch (``ValueError`` for a method without parameters).
    zupt : zero-velocity aiding, a choice of :data:`envs.zupt_source.ZUPT_CHOICES` (``'none'``, ``'truth'``,
        a classical or learned detector); ``zupt_weights``: weights file of ``'mlp'`` / ``'lstm'``.
    **config : further :class:`NavigatorConfig` fields.
    """
    nav = navigator_for(world, method, dtype, **config)
    if params:
        if not hasattr(nav.form, "set_params"):
            raise ValueError(f"method {method!r} has no parameters to set ({sorted(params)})")
        nav.form.set_params(**{k: np.broadcast_to(np.asarray(v, float), (world.batch_size,)).copy()
                               for k, v in params.items()})
    source = ZuptSource(zupt, world.scenario.imu_rate_hz, zupt_weights)
    imu, gnss, truth = world.imu, world.gnss, world.truth
    still = truth.stationary(STILL_SPEED_MPS) if zupt == "truth" else None
    ep = world.epoch_idx
    B, M = world.batch_size, len(ep)
    dt = 1.0 / world.scenario.imu_rate_hz
    err_e = np.zeros((B, M, 3))
    verr_e = np.zeros((B, M, 3))
    nees = np.zeros((B, M))
    nis = np.zeros((B, M))
    n_used = np.zeros((B, M), int)
    n_sats = np.zeros((B, M), int)
    gdop = np.zeros((B, M))
    zflag = np.zeros((B, M), bool)
    excluded = getattr(nav.form, "excluded", None)
    n_excl = None if excluded is None or excluded() is None else np.zeros((B, M), np.int64)
    f_all, w_all = imu.f_b, imu.w_b
    keys = satellite_keys(gnss)
    pv = np.r_[np.arange(VEL.start, VEL.stop), np.arange(POS.start, POS.stop)]
    t0 = time.perf_counter()
    k = 0
    yaw = world.odometer_yaw_rate
    odo_model = world.scenario.odometer if world.odometer is not None else None
    for j in range(M):
        extra = None
        sl = None
        if ep[j] > k:
            sl = slice(k + 1, ep[j] + 1)
            nav.propagate_epoch(f_all[:, sl], w_all[:, sl], dt)
            k = ep[j]
            if source.enabled:
                decisions = source.decide(f_all[:, sl], w_all[:, sl], None if still is None else still[:, sl])
                extra, zflag[:, j] = source.block(nav, w_all[:, sl], decisions, dt)
        if odo_model is not None:  # the scenario's wheel odometer + NHC (+ yaw rate) (envs.aiding)
            extra = with_rows(extra, odometer_rows(nav, world.odometer[:, j], odo_model,
                                                   None if yaw is None else yaw[:, j],
                                                   None if sl is None else w_all[:, sl], dt))
        prr = None if gnss.prr is None else gnss.prr[:, j]  # recorded data may have no Doppler
        prr_sigma = None if gnss.prr_sigma is None else gnss.prr_sigma[:, j]
        res, g = nav.update_gnss(gnss.sat_pos[:, j], gnss.sat_vel[:, j], gnss.pr[:, j], prr,
                                 gnss.pr_sigma[:, j], prr_sigma, gnss.mask[:, j], extra=extra,
                                 sat_keys=keys[:, j])
        err_e[:, j] = nav.r - truth.r_e[:, k]
        verr_e[:, j] = nav.v - truth.v_e[:, k]
        e = np.concatenate([-verr_e[:, j], -err_e[:, j]], 1)
        P = np.asarray(nav.covariance, np.float64)[:, pv][:, :, pv]
        ok = ~nav.diverged & np.isfinite(P).all((1, 2))  # NEES undefined while a state is unobserved
        if ok.any():
            sol = np.linalg.solve(P[ok], e[ok][..., None])[..., 0]
            nees[ok, j] = np.sum(e[ok] * sol, -1)
        nees[~ok, j] = np.nan
        nis[:, j] = res.nis
        n_used[:, j] = res.n_used
        n_sats[:, j] = gnss.mask[:, j].sum(-1)
        gdop[:, j] = g
        if n_excl is not None:
            n_excl[:, j] = excluded()
        if progress is not None:
            progress(j + 1)
    elapsed = time.perf_counter() - t0
    lat, lon, _ = ecef_to_geodetic(truth.r_e[:, ep])
    Cne = np.swapaxes(C_en(lat, lon), -1, -2)
    pos_ned = (Cne @ err_e[..., None])[..., 0]
    vel_ned = (Cne @ verr_e[..., None])[..., 0]
    div = nav.diverged | ~np.isfinite(pos_ned).all((1, 2))
    return EpisodeLog(t=truth.t[ep], pos_err_ned=pos_ned, vel_err_ned=vel_ned, nees_pv=nees, nis=nis,
                      n_used=n_used, n_sats=n_sats, gdop=gdop, zupt=zflag, diverged=div, filter_time_s=elapsed,
                      n_excluded=n_excl)


def concat_logs(logs: list[EpisodeLog]) -> EpisodeLog:
    """One log of the episodes of several logs of the same epochs (batch axis concatenated, times summed)."""
    if len(logs) == 1:
        return logs[0]
    kw = {}
    for f in EpisodeLog.__dataclass_fields__:
        vals = [getattr(log, f) for log in logs]
        if f == "t":
            kw[f] = vals[0]
        elif f == "filter_time_s":
            kw[f] = float(sum(vals))
        elif f == "params":
            kw[f] = (None if any(v is None for v in vals) else
                     {k: np.concatenate([v[k] for v in vals], 0) for k in vals[0]})
        elif f == "n_excluded":
            kw[f] = None if any(v is None for v in vals) else np.concatenate(vals, 0)
        else:
            kw[f] = np.concatenate(vals, 0)
    return EpisodeLog(**kw)
