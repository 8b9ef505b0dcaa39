"""Generate a whole batched world at reset: truth, IMU, GNSS and the navigator's initial estimate.

Everything random is drawn per row from the row's seed (:mod:`envs.sim.rng`),
so row i of a batch equals the same seed run alone. Nothing here knows how the
world will be estimated.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np

from earth import C_en, exp_so3

from . import events as ev
from . import row_threads
from .gnss import GnssData, simulate_gnss
from .imu import IMU_GRADES, ImuData, ImuEvents, ImuGrade, simulate_imu
from .odometer import simulate_odometer
from .rng import as_seeds, row_generators
from .scenarios import Scenario, get_scenario
from .trajectory import Truth, generate_truth


@dataclass(frozen=True)
class InitialEstimate:
    """The navigator's initial estimate and the covariance that honestly describes its error.

    Attributes
    ----------
    r_e, v_e : (B, 3) ECEF position [m] and velocity [m/s].
    C_eb : (B, 3, 3) attitude.
    clock_bias_m, clock_drift_mps : (B,).
    pos_cov_e, vel_cov_e, att_cov_e : (B, 3, 3) error covariances in ECEF [m^2, m^2/s^2, rad^2].
    clock_sigma_m, drift_sigma_mps : float.
    """

    r_e: np.ndarray
    v_e: np.ndarray
    C_eb: np.ndarray
    clock_bias_m: np.ndarray
    clock_drift_mps: np.ndarray
    pos_cov_e: np.ndarray
    vel_cov_e: np.ndarray
    att_cov_e: np.ndarray
    clock_sigma_m: float
    drift_sigma_mps: float


@dataclass(frozen=True)
class World:
    """One batch of simulated episodes.

    Attributes
    ----------
    scenario : the scenario it was drawn from; seeds : list of B seeds.
    truth : truth at the IMU rate (N samples); imu : measured IMU (N samples).
    gnss : GNSS epochs (M); epoch_idx : (M,) IMU sample index of each epoch.
    init : the navigator's initial estimate at t = 0.
    odometer : (B, M) odometer forward-speed readings at the GNSS epochs [m/s] when the scenario has an
        odometer (:mod:`envs.sim.odometer`), else None.
    odometer_yaw_rate : (B, M) yaw-rate readings about body z (FRD: down, positive turning right) [rad/s], each
        the mean over the IMU interval that ends at its epoch (samples ``epoch_idx[j-1] + 1 .. epoch_idx[j]``,
        from sample 1 for the first epoch; NaN where that interval is empty), when the odometer reads one
        (recorded odometry, :mod:`envs.datasets.replay`), else None.
    """

    scenario: Scenario
    seeds: list
    truth: Truth
    imu: ImuData
    gnss: GnssData
    epoch_idx: np.ndarray
    init: InitialEstimate
    odometer: np.ndarray | None = None
    odometer_yaw_rate: np.ndarray | None = None

    @property
    def batch_size(self) -> int:
        return len(self.seeds)

    @property
    def imu_grade(self) -> ImuGrade:
        return IMU_GRADES[self.scenario.imu_grade]


def initial_estimate(scen: Scenario, truth: Truth, gnss: GnssData, rngs) -> InitialEstimate:
    ie = scen.initial
    B = truth.batch_size
    at0 = truth.take(np.zeros(1, np.intp))
    r0, v0, C0 = at0.r_e[:, 0].astype(np.float64), at0.v_e[:, 0].astype(np.float64), at0.C_eb[:, 0]
    # truth clock at t = 0, from the first epoch's state and drift
    t1 = gnss.t[0]
    clk0 = gnss.clock_bias_m[:, 0] - gnss.clock_drift_mps[:, 0] * t1
    drift0 = gnss.clock_drift_mps[:, 0]
    Cen = C_en(truth.lat0, truth.lon0)  # (B, 3, 3)
    sp, sv, sa = (np.asarray(x, float) for x in (ie.position_sigma_m, ie.velocity_sigma_mps, ie.attitude_sigma_rad))
    if ie.fixed_ecef:
        dp = np.broadcast_to(sp, (B, 3))
        dv = np.broadcast_to(sv, (B, 3))
        da = np.broadcast_to(sa, (B, 3))
        dclk = np.zeros(B)
        ddr = np.zeros(B)
        pos_cov, vel_cov, att_cov = (np.broadcast_to(np.diag(s ** 2), (B, 3, 3)).copy() for s in (sp, sv, sa))
    else:
        z = np.stack([g.standard_normal(11) for g in rngs])  # fixed draw count per row: B-invariant
        dp = (Cen @ (sp * z[:, 0:3])[..., None])[..., 0]
        dv = (Cen @ (sv * z[:, 3:6])[..., None])[..., 0]
        da = (Cen @ (sa * z[:, 6:9])[..., None])[..., 0]
        dclk = ie.clock_sigma_m * z[:, 9]
        ddr = ie.drift_sigma_mps * z[:, 10]
        pos_cov, vel_cov, att_cov = (Cen @ np.diag(s ** 2) @ Cen.mT for s in (sp, sv, sa))
    # estimate = truth + error; attitude: C_true = (I + [x]) C_est with x = -error rotation
    C_est = exp_so3(da) @ C0
    return InitialEstimate(r_e=r0 + dp, v_e=v0 + dv, C_eb=C_est, clock_bias_m=clk0 + dclk, clock_drift_mps=drift0 + ddr,
                           pos_cov_e=pos_cov, vel_cov_e=vel_cov, att_cov_e=att_cov,
                           clock_sigma_m=max(ie.clock_sigma_m, 1e-3), drift_sigma_mps=max(ie.drift_sigma_mps, 1e-4))


def imu_event_bits(t, imu: ImuData, events: ImuEvents | None) -> np.ndarray:
    """The IMU bits of :attr:`GnssData.event_mask` at the GNSS epochs ``t`` (B, M) uint16.

    ``IMU_EVENT`` where a bias step or the start / end of a rough-road segment
    lies in ``(t - events.flag_window_s, t]``; ``ROUGH_ROAD`` where a rough
    segment covers ``t``. Zeros without events.
    """
    t = np.asarray(t, np.float64)
    B = imu.f_b.shape[0]
    bits = np.zeros((B, t.size), dtype=np.uint16)
    if events is None or imu.bias_steps is None:
        return bits
    w = events.flag_window_s
    for i in range(B):
        changes = [s[0] for s in imu.bias_steps[i]] + [x for r in imu.rough[i] for x in r[:2]]
        for tc in changes:
            bits[i, (t >= tc) & (t < tc + w)] |= ev.IMU_EVENT
        for t0, t1, _ in imu.rough[i]:
            bits[i, (t > t0) & (t <= t1)] |= ev.ROUGH_ROAD
    return bits


OVERLAP_ROWS = row_threads.OVERLAP_ROWS
"""From this many rows on, :func:`generate_world` simulates the IMU on a thread of its own while it simulates the
GNSS receiver (the two draw from separate streams into separate arrays: the same world either way)."""


def _stage_generators(seeds) -> dict:
    """The rows' generators of the stages after the truth (:func:`~envs.sim.rng.row_generators` of the IMU,
    vibration, GNSS and initial-estimate streams), by stream name. Built before any of them draws: the order of
    their construction changes no draw."""
    return {stream: row_generators(seeds, stream) for stream in ("imu", "vibration", "gnss", "init")}


def generate_world(scenario, seeds, dtype=np.float64, buffers=None, for_reset: bool = False) -> World:
    """Draw B episodes of ``scenario`` (name or :class:`Scenario`) from ``seeds`` (B non-negative ints).

    The stages in order: the drives and truth, the IMU and the GNSS receiver (from :data:`OVERLAP_ROWS` rows on,
    the IMU on a thread of its own beside the GNSS stages: the same world), the initial estimate, the odometer.
    The later stages' row generators are built beside the truth from :data:`OVERLAP_ROWS` rows on (Python,
    while the truth's compiled kernels run; no generator draws before the truth is done).

    Parameters
    ----------
    scenario : str or Scenario
    seeds : int or sequence of int, one per row.
    dtype : float dtype of the IMU samples (the truth and GNSS geometry stay float64).
    buffers : :class:`envs.sim.buffers.WorldBuffers` or None: the bulk arrays (truth at the IMU rate, IMU samples
        and error records, the GNSS ranging and receiver arrays) come from it, reused from an earlier draw that
        nobody holds any more (an env core's resets). The world does not depend on it.
    for_reset : bool
        Form only what an env's reset reads (:func:`envs.prepared.world_arrays`): the truth's position, velocity
        and attitude only at sample 0 and the GNSS epochs (``Truth.states_every = samples_per_epoch``, read
        through ``Truth.take``) and no record of the IMU's bias at each sample (``ImuData.gyro_bias``,
        ``accel_bias`` None). The same bits in everything formed. Default False: the whole world.
    """
    scen = get_scenario(scenario)
    if getattr(scen, "dataset", None) is not None:   # envs.datasets.spec.ReplayScenario: never simulate it
        raise ValueError(f"scenario {scen.name!r} replays a recorded data set: build its world with "
                         f"envs.worlds.make_world, not generate_world")
    if scen.odometer is not None and scen.odometer.yaw_rate_sigma_rps is not None:
        raise ValueError(f"Scenario.odometer.yaw_rate_sigma_rps: a simulated odometer reads the forward speed "
                         f"only (the yaw rate comes with recorded odometry); set it to None for {scen.name!r}")
    if not isinstance(for_reset, (bool, np.bool_)):
        raise ValueError(f"for_reset must be a bool, got {for_reset!r}")
    seeds = as_seeds(seeds)
    motions = scen.motions(row_generators(seeds, "trajectory"))
    spe = scen.samples_per_epoch
    truth_args = (motions, scen.duration_s, scen.imu_rate_hz)
    truth_kw = dict(buffers=buffers, states_every=spe if for_reset else 1)
    if len(seeds) < OVERLAP_ROWS:
        truth = generate_truth(*truth_args, **truth_kw)
        gens = _stage_generators(seeds)
    else:   # the other stages' generators (Python) built on a thread of its own while the truth's kernels run
        with ThreadPoolExecutor(max_workers=1) as ex:
            pending = ex.submit(_stage_generators, seeds)
            truth = generate_truth(*truth_args, **truth_kw)
            gens = pending.result()
    imu_args = (truth.f_b, truth.w_b, scen.imu_rate_hz, IMU_GRADES[scen.imu_grade], gens["imu"])
    imu_kw = dict(engine_on=truth.engine_on, speed=truth.speed, vibration=scen.vibration, dtype=dtype,
                  vibration_rngs=gens["vibration"], events=scen.imu_events, buffers=buffers,
                  bias_records=not for_reset)
    epoch_idx = np.arange(spe, truth.t.size, spe)
    at = truth.take(epoch_idx)
    gnss_args = (truth.t[epoch_idx], at.r_e, at.v_e, at.heading, scen.constellation, scen.receiver, scen.events,
                 gens["gnss"])
    if len(seeds) < OVERLAP_ROWS:
        imu = simulate_imu(*imu_args, **imu_kw)
        gnss = simulate_gnss(*gnss_args, buffers=buffers)
    else:       # the IMU's compiled row pass on its threads while this one runs the GNSS stages' Python
        with ThreadPoolExecutor(max_workers=1) as ex:
            pending = ex.submit(simulate_imu, *imu_args, **imu_kw)
            gnss = simulate_gnss(*gnss_args, buffers=buffers)
            imu = pending.result()
    if scen.imu_events is not None:
        gnss = replace(gnss, event_mask=gnss.event_mask | imu_event_bits(gnss.t, imu, scen.imu_events))
    init = initial_estimate(scen, truth, gnss, gens["init"])
    odo = None if scen.odometer is None else simulate_odometer(truth.speed[:, epoch_idx], seeds, scen.odometer)
    return World(scenario=scen, seeds=seeds, truth=truth, imu=imu, gnss=gnss, epoch_idx=epoch_idx, init=init,
                 odometer=odo)
