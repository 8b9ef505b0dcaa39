"""The experiments' episodes: paired seeds, the errors of one method's run (:class:`Run`), and the navigation
loop with the two options :func:`envs.episodes.run_episodes` has no hook for (:func:`run_navigation`)."""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from earth import ecef_to_geodetic
from earth.wgs84 import C_en

from envs.aiding import odometer_rows
from envs.episodes import EpisodeLog, navigator_for, run_episodes, satellite_keys
from envs.sim.odometer import SEED003_ODOMETER, OdometerModel
from envs.sim.odometer import simulate_odometer as _simulate_odometer
from envs.sim.world import World, generate_world

def episode_seeds(seed: int, episodes: int) -> list[int]:
    """Seeds of the paired episodes, as eval.py: episode k gets ``seed * 1_000_003 + k``."""
    return [seed * 1_000_003 + k for k in range(episodes)]


@dataclass(frozen=True)
class Run:
    """Errors of B episodes of one method (arrays batch first, M GNSS epochs).

    Attributes
    ----------
    t : (M,) epoch times [s].
    pos_ned, vel_ned : (B, M, 3) estimate minus truth, NED at the true position [m], [m/s].
    pos_ecef : (B, M, 3) estimate minus truth in ECEF [m].
    outage : (B, M) bool, epochs without any tracked satellite.
    diverged : (B,) bool.
    filter_time_s : navigator wall time (all rows).
    adaptive : per adaptive-state name, the mean over rows and epochs (empty for non-adaptive forms).
    """

    t: np.ndarray
    pos_ned: np.ndarray
    vel_ned: np.ndarray
    pos_ecef: np.ndarray
    outage: np.ndarray
    diverged: np.ndarray
    filter_time_s: float
    adaptive: dict = field(default_factory=dict)

    @staticmethod
    def concat(runs: list["Run"]) -> "Run":
        """Runs of consecutive seed chunks as one run (times add, adaptive means weighted by rows)."""
        if len(runs) == 1:
            return runs[0]
        B = np.array([r.diverged.size for r in runs], float)
        keys = set.intersection(*(set(r.adaptive) for r in runs)) if runs else set()
        ad = {k: float(np.sum([r.adaptive[k] * b for r, b in zip(runs, B)]) / B.sum()) for k in keys}
        return Run(t=runs[0].t, **{f: np.concatenate([getattr(r, f) for r in runs], 0)
                                    for f in ("pos_ned", "vel_ned", "pos_ecef", "outage", "diverged")},
                   filter_time_s=float(sum(r.filter_time_s for r in runs)), adaptive=ad)


def _ned_to_ecef(world: World, ned: np.ndarray) -> np.ndarray:
    lat, lon, _ = ecef_to_geodetic(world.truth.r_e[:, world.epoch_idx])
    return (C_en(lat, lon) @ ned[..., None])[..., 0]


def _from_log(world: World, log: EpisodeLog) -> Run:
    return Run(t=log.t, pos_ned=log.pos_err_ned, vel_ned=log.vel_err_ned,
               pos_ecef=_ned_to_ecef(world, log.pos_err_ned), outage=~world.gnss.mask.any(-1),
               diverged=log.diverged, filter_time_s=log.filter_time_s)


def simulate_odometer(world: World, model: OdometerModel = SEED003_ODOMETER) -> np.ndarray:
    """(B, M) odometer forward-speed readings of ``world`` at the GNSS epochs [m/s] for ``model``
    (:func:`envs.sim.odometer.simulate_odometer`; equal to ``world.odometer`` when ``model`` is the scenario's)."""
    return _simulate_odometer(world.truth.speed[:, world.epoch_idx], world.seeds, model)


def run_navigation(world: World, method: str = "kf", dtype="float64", per_sample_predict: bool = False,
                   odometer_model: OdometerModel | None = None) -> Run:
    """The loop of :func:`envs.episodes.run_episodes` with two options it has no hook for.

    Parameters
    ----------
    world : the generated world (B rows).
    method : filter method name (DESIGN.md section 4; ``+onestep`` allowed).
    dtype : filter arithmetic.
    per_sample_predict : hand the form one ``predict`` per IMU sample (the "standard algorithm" of seed
        paper 001, sec 2.1, eqs 1-2 at the INS rate) instead of the navigator's one composed prediction
        per epoch. Same result in exact arithmetic as the default; different cost.
    odometer_model : if given, fuse an odometer forward-speed row and the two NHC rows
        (:mod:`nav_filters.constraints`) at every GNSS epoch, also during GNSS outages (seed paper 003's
        SINS/GNSS/ODO sensor set, with the odometer in velocity form; :func:`envs.aiding.odometer_rows`).
        ``world.odometer`` (the scenario's own sensor set, which :func:`envs.episodes.run_episodes` and the
        envs fuse) is not read: the experiment compares the two sensor sets on the same worlds.

    Returns
    -------
    :class:`Run`; ``filter_time_s`` counts only the navigator calls.
    """
    nav = navigator_for(world, method, dtype)
    imu, gnss, truth = world.imu, world.gnss, world.truth
    keys = satellite_keys(gnss)
    ep = world.epoch_idx
    B, M = world.batch_size, len(ep)
    dt = 1.0 / world.scenario.imu_rate_hz
    odo = None if odometer_model is None else simulate_odometer(world, odometer_model)
    err = np.zeros((B, M, 3))
    verr = np.zeros((B, M, 3))
    has_state = hasattr(nav.form, "adaptive_state")
    sums: dict = {}
    busy = 0.0
    k = 0
    for j in range(M):
        t0 = time.perf_counter()
        if ep[j] > k:
            if per_sample_predict:
                for i in range(k + 1, ep[j] + 1):
                    nav.propagate(imu.f_b[:, i], imu.w_b[:, i], dt)
                    nav.flush_prediction()
            else:
                nav.propagate_epoch(imu.f_b[:, k + 1:ep[j] + 1], imu.w_b[:, k + 1:ep[j] + 1], dt)
            k = ep[j]
        extra = None
        if odo is not None:
            extra = odometer_rows(nav, odo[:, j], odometer_model)
        prr = None if gnss.prr is None else gnss.prr[:, j]
        prr_sigma = None if gnss.prr_sigma is None else gnss.prr_sigma[:, j]
        nav.update_gnss(gnss.sat_pos[:, j], gnss.sat_vel[:, j], gnss.pr[:, j], prr, gnss.pr_sigma[:, j], prr_sigma,
                        gnss.mask[:, j], extra=extra, sat_keys=keys[:, j])
        busy += time.perf_counter() - t0
        err[:, j] = nav.r - truth.r_e[:, k]
        verr[:, j] = nav.v - truth.v_e[:, k]
        if has_state and not nav.diverged.all():
            for name, v in nav.form.adaptive_state().items():
                sums[name] = sums.get(name, 0.0) + float(np.mean(v[~nav.diverged]))
    lat, lon, _ = ecef_to_geodetic(truth.r_e[:, ep])
    Cne = np.swapaxes(C_en(lat, lon), -1, -2)
    pos_ned = (Cne @ err[..., None])[..., 0]
    vel_ned = (Cne @ verr[..., None])[..., 0]
    div = nav.diverged | ~np.isfinite(pos_ned).all((1, 2))
    return Run(t=truth.t[ep], pos_ned=pos_ned, vel_ned=vel_ned, pos_ecef=err, outage=~gnss.mask.any(-1),
               diverged=div, filter_time_s=busy, adaptive={n: s / M for n, s in sums.items()})


def _chunks(seeds, batch_size):
    return [seeds[i:i + batch_size] for i in range(0, len(seeds), batch_size)]


def _run_variants(scenario, seeds, batch_size, variants, progress, tag) -> dict:
    """``{label: Run}`` of each ``(label, method, dtype)`` of ``variants`` on the paired worlds of ``scenario``
    and ``seeds`` (generated ``batch_size`` at a time; progress lines start with ``tag``)."""
    parts = {label: [] for label, _, _ in variants}
    for chunk in _chunks(seeds, batch_size):
        world = generate_world(scenario, chunk)
        for label, m, dt in variants:
            _say(progress, f"{tag}: {label} ({dt}) on {len(chunk)} episodes")
            parts[label].append(_from_log(world, run_episodes(world, m, dtype=dt)))
    return {k: Run.concat(v) for k, v in parts.items()}


def _ok(run: Run, *others: Run) -> np.ndarray:
    ok = ~run.diverged
    for o in others:
        ok &= ~o.diverged
    return ok


def _dur(duration_s) -> dict:
    return {} if duration_s is None else {"duration_s": float(duration_s)}


def _say(progress, msg):
    if progress is not None:
        progress(msg)
