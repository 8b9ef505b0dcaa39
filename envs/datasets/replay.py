"""Replay recorded GNSS epochs through the navigator: a :class:`~envs.sim.world.World` built from real data.

A replay world has exactly the fields of a simulated one, so
:func:`envs.episodes.run_episodes`, the environments and ``eval.py`` run it
like any other (they only have to pass ``gnss.prr is None`` through to
:meth:`~nav_filters.navigator.Navigator.update_gnss`, which then stacks
pseudorange rows only):

* ``truth`` and the *synthesized* IMU: the recording's reference trajectory
  as a smoothing spline with the consistent ideal IMU
  (:mod:`envs.datasets.spline_truth`), corrupted by
  :func:`envs.sim.imu.simulate_imu` with the chosen grade and the vehicle
  vibration model, from each row's seed (streams ``"imu"`` and
  ``"vibration"``, as in :func:`envs.sim.world.generate_world`). The IMU is
  synthetic; the GNSS errors are the recorded ones, identical in every row;
* ``gnss``: the recorded pseudoranges as :class:`~envs.sim.gnss.GnssData`
  (rows are read-only broadcast views of one recording). Without Doppler
  (smartLoc) ``prr``, ``prr_sigma`` and ``prr_error_mps`` are ``None`` and the
  measurement vector has pseudorange rows only; RINEX epochs with Doppler
  (:mod:`envs.datasets.doppler`) give ``prr`` and ``prr_error_mps`` against
  the reference velocity and drift. ``nlos`` is
  all False (unknown). ``clock_bias_m`` / ``clock_drift_mps`` are a
  *reference* clock, not a truth: see :func:`reference_clock`. ``t0_gps`` is
  NaN where the recording has no absolute time (smartLoc);
* ``epoch_idx``: each epoch at the IMU sample nearest to its time stamp (the
  update happens up to half an IMU interval, 5 ms at 100 Hz, away from the
  measurement time: <= 5 cm at smartLoc's 10 m/s);
* ``init``: truth plus errors drawn from the scenario's
  :class:`~envs.sim.scenarios.InitialErrors` (stream ``"init"``), as for a
  simulated world; the clock from the reference clock.

The :class:`~envs.sim.scenarios.Scenario` of a replay world is a descriptor
only: ``imu_rate_hz``, ``imu_grade``, ``vibration``, ``receiver.clock`` (the
filter's clock model: a TCXO) and ``initial`` are used; its ``drive``,
``constellation``, ``events`` describe nothing (``drive='urban'`` is a
placeholder) and ``gnss_rate_hz`` is the nominal rate (the recorded epochs
are irregular: smartLoc 0.2 or 0.3 s apart).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import numpy as np
from scipy.interpolate import make_smoothing_spline

from earth import C_en, ecef_to_geodetic, euler_from_dcm
from earth.ranging import range_and_rate

from ..sim.gnss import ClockModel, GnssData, ReceiverConfig
from ..sim.imu import IMU_GRADES, Vibration, simulate_imu
from ..sim.rng import as_seeds, row_generators
from ..sim.scenarios import InitialErrors, Scenario
from ..sim.world import World, initial_estimate
from .epochs import GnssEpochs
from .smartloc import POTSDAMER_PLATZ, load_smartloc, smartloc_dir
from .spline_truth import SplineFit, fit_positions, truth_from_fit

__all__ = ["SMARTLOC_SCENARIO", "RINEX_SCENARIO", "reference_clock", "gnss_data_from_epochs", "replay_world",
           "interval_means", "smartloc_scenario", "load_smartloc_world", "load_rinex_world"]

SMARTLOC_SCENARIO = "smartloc-potsdamer-platz"
RINEX_SCENARIO = "rinex"


def reference_clock(epochs: GnssEpochs, r_e, v_e=None, lam: float | None = 10.0):
    """A reference receiver clock (bias and drift) of recorded epochs, from the known receiver positions.

    Recorded data have no true clock. Per epoch, with the position fixed at
    the reference ``r_e``, the clock bias is the median of ``pr - rho`` over
    the channels whose C/N0 is at least the epoch's median C/N0 (strong
    signals: fewer NLOS; the median resists the remaining ones); the series is
    then smoothed by a cubic smoothing spline in time (Reinsch 1967), whose
    derivative is the drift; epochs without a valid channel get the spline's
    value. The default ``lam = 10`` (time in s, bias in m) passes periods
    longer than ~20 s at 5 Hz: on smartLoc the per-epoch medians still carry
    metres of NLOS noise, and generalized cross-validation (``lam=None``, 1 s
    slower) keeps a drift wandering between -77 and -22 m/s, not what a TCXO
    does in 5 minutes (with ``lam = 10``: between -54 and -44 m/s). The reference
    includes the common-mode part of the recorded errors; it is what the
    initial clock estimate is drawn around and what ``pr_error_m`` is
    relative to.

    Parameters
    ----------
    epochs : GnssEpochs (M epochs, at least 5).
    r_e : (M, 3) receiver ECEF position at the epochs [m]; v_e : (M, 3) or None (zero) [m/s].
    lam : smoothing parameter (> 0), or None for generalized cross-validation.

    Returns
    -------
    bias : (M,) [m]; drift : (M,) [m/s].
    """
    r_e = np.asarray(r_e, np.float64)
    M = epochs.n_epochs
    if r_e.shape != (M, 3):
        raise ValueError(f"r_e must have shape ({M}, 3), got {r_e.shape}")
    if M < 5:
        raise ValueError(f"reference_clock needs at least 5 epochs, got {M}")
    v_e = np.zeros_like(r_e) if v_e is None else np.asarray(v_e, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho, _, _ = range_and_rate(epochs.sat_pos, epochs.sat_vel, r_e, v_e)
    d = np.where(epochs.mask, epochs.pr - rho, np.nan)
    cn = np.where(epochs.mask, epochs.cn0, np.nan)
    has = epochs.mask.any(-1)
    if has.sum() < 5:
        raise ValueError(f"reference_clock needs at least 5 epochs with a valid channel, got {int(has.sum())}")
    d, cn = d[has], cn[has]
    strong = cn >= np.nanmedian(cn, axis=-1, keepdims=True)
    raw = np.nanmedian(np.where(strong, d, np.nan), axis=-1)
    spl = make_smoothing_spline(epochs.t[has], raw, lam=lam)
    return spl(epochs.t), spl.derivative()(epochs.t)


def gnss_data_from_epochs(epochs: GnssEpochs, r_e, batch_size: int, clock_bias_m, clock_drift_mps,
                          t_offset: float = 0.0, v_e=None) -> GnssData:
    """Recorded epochs as the simulated receiver's :class:`GnssData` (module docstring): pseudoranges, and
    pseudorange rates where the epochs carry them (``prr_error_mps`` against ``v_e`` and the reference drift).

    Parameters
    ----------
    epochs : GnssEpochs (M epochs, C channels).
    r_e : (M, 3) reference receiver position at the epochs [m] (azimuths, ``pr_error_m``).
    batch_size : B rows (read-only broadcast views of the one recording).
    clock_bias_m, clock_drift_mps : (M,) reference clock [m], [m/s].
    t_offset : subtracted from the epoch times (the world's time origin) [s].
    v_e : (M, 3) reference receiver velocity at the epochs [m/s] (None: zero).
    """
    M, C = epochs.mask.shape
    r_e = np.asarray(r_e, np.float64)
    if r_e.shape != (M, 3):
        raise ValueError(f"r_e must have shape ({M}, 3), got {r_e.shape}")
    v_e = np.zeros_like(r_e) if v_e is None else np.asarray(v_e, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        rho, rho_dot, u = range_and_rate(epochs.sat_pos, epochs.sat_vel, r_e, v_e)
    lat, lon, _ = ecef_to_geodetic(r_e)
    u_n = (np.swapaxes(C_en(lat, lon), -1, -2)[:, None] @ np.nan_to_num(u)[..., None])[..., 0]
    az = np.mod(np.arctan2(u_n[..., 1], u_n[..., 0]), 2 * np.pi)
    m = epochs.mask
    bias = np.asarray(clock_bias_m, np.float64)
    drift = np.asarray(clock_drift_mps, np.float64)
    err = np.where(m, epochs.pr - np.nan_to_num(rho) - bias[:, None], 0.0)
    B = batch_size
    prr = prr_sigma = prr_err = None
    if epochs.prr is not None:
        prr, prr_sigma = np.where(m, epochs.prr, 0.0), np.where(m, epochs.prr_sigma, 0.0)
        prr_err = np.where(m, prr - np.nan_to_num(rho_dot) - drift[:, None], 0.0)

    def bc(x):
        if x is None:
            return None
        x = np.asarray(x)
        return np.broadcast_to(x[None], (B,) + x.shape)

    return GnssData(t=epochs.t - t_offset, t0_gps=np.full(B, np.nan if epochs.t0_gps is None else
                                                          epochs.t0_gps + t_offset),
                    sat_pos=bc(epochs.sat_pos), sat_vel=bc(epochs.sat_vel), pr=bc(epochs.pr), prr=bc(prr),
                    pr_sigma=bc(np.where(m, epochs.pr_sigma, 0.0)), prr_sigma=bc(prr_sigma), mask=bc(m),
                    prn=bc(np.where(m, epochs.sat_keys() + 1, -1)), elevation=bc(np.where(m, epochs.elevation, 0.0)),
                    azimuth=bc(np.where(m, az, 0.0)), clock_bias_m=bc(bias), clock_drift_mps=bc(drift),
                    nlos=bc(np.zeros((M, C), bool)), pr_error_m=bc(err), prr_error_mps=bc(prr_err),
                    cn0_dbhz=bc(np.where(m, epochs.cn0, 0.0)))  # the simulator-truth fields stay None


def replay_world(scenario: Scenario, epochs: GnssEpochs, fit: SplineFit, seeds, dtype=np.float64,
                 min_speed_mps: float = 1.0, recorded_imu=None, odometry=None) -> World:
    """A :class:`World` replaying ``epochs`` along the reference trajectory ``fit`` (module docstring).

    Parameters
    ----------
    scenario : the descriptor (imu_rate_hz, imu_grade, vibration, receiver.clock, initial are used).
    epochs : recorded epochs; those outside the reference span ``[fit.t0, fit.t1]`` are dropped.
    fit : the reference trajectory.
    seeds : int or B non-negative ints (IMU noise, vibration and initial errors per row).
    dtype : float dtype of the IMU samples.
    min_speed_mps : see :func:`~envs.datasets.spline_truth.truth_from_fit`.
    recorded_imu : None (the IMU is synthesized from the truth) or a callable ``(t, B, dtype) -> (imu,
        C_eb)`` of the grid times ``t`` (N,) [s, the epochs' time origin]: the recorded
        :class:`~envs.sim.imu.ImuData` and the reference attitude (N, 3, 3) body -> ECEF, which replaces the
        spline's (:mod:`envs.datasets.recorded_imu`); the truth's ideal ``f_b`` / ``w_b`` are then unknown
        (NaN), as no ideal IMU exists for the recorded sensor's axes.
    odometry : None, or recorded wheel odometry with a ``frd_at(t)`` method (forward speed and yaw rate about
        body z, FRD, at the recording's times ``t``: :meth:`envs.datasets.smartloc.SmartLocOdometry.frd_at`):
        the world's ``odometer`` is the speed at each epoch, its ``odometer_yaw_rate`` the yaw rate averaged
        over the epoch's IMU interval (:func:`interval_means` of the rate at the IMU samples' midpoints, where
        the samples' own interval means are centred).
    """
    if not isinstance(scenario, Scenario):
        raise ValueError(f"scenario must be a Scenario, got {type(scenario).__name__}")
    seeds = as_seeds(seeds)
    B = len(seeds)
    rate = scenario.imu_rate_hz
    truth = truth_from_fit(fit, rate, batch_size=B, min_speed_mps=min_speed_mps)
    t_last = fit.t0 + truth.t[-1]
    epochs = epochs.window(fit.t0, t_last + 0.5 / rate)
    idx = np.rint((epochs.t - fit.t0) * rate).astype(np.int64)
    idx = np.minimum(idx, truth.t.size - 1)
    if np.any(np.diff(idx) <= 0):
        raise ValueError(f"imu_rate_hz = {rate} puts two GNSS epochs on one IMU sample: raise the IMU rate")
    r_ep = fit.position(epochs.t)
    bias, drift = reference_clock(epochs, r_ep, fit.velocity(epochs.t))
    gnss = gnss_data_from_epochs(epochs, r_ep, B, bias, drift, t_offset=fit.t0, v_e=fit.velocity(epochs.t))
    if recorded_imu is None:
        imu = simulate_imu(truth.f_b, truth.w_b, rate, IMU_GRADES[scenario.imu_grade],
                           row_generators(seeds, "imu"), engine_on=truth.engine_on, speed=truth.speed,
                           vibration=scenario.vibration, dtype=dtype, vibration_rngs=row_generators(seeds, "vibration"))
    else:
        imu, C_eb = recorded_imu(fit.t0 + truth.t, B, dtype)
        truth = _with_attitude(truth, np.asarray(C_eb, np.float64))
    init = initial_estimate(scenario, truth, gnss, row_generators(seeds, "init"))
    odo = yaw = None
    if odometry is not None:
        speed = odometry.frd_at(epochs.t)[0]
        yaw = interval_means(odometry.frd_at(fit.t0 + truth.t - 0.5 / rate)[1], idx)
        odo, yaw = (np.broadcast_to(x[None], (B, x.size)) for x in (speed, yaw))
    return World(scenario=scenario, seeds=seeds, truth=truth, imu=imu, gnss=gnss, epoch_idx=idx, init=init,
                 odometer=odo, odometer_yaw_rate=yaw)


def interval_means(x, epoch_idx) -> np.ndarray:
    """Means of the samples ``x`` (N,) over each epoch's IMU interval: samples ``epoch_idx[j-1] + 1 ..
    epoch_idx[j]`` (from sample 1 for ``j = 0``: what the navigator integrates before the epoch's update),
    NaN where the interval is empty. Returns (M,)."""
    x = np.asarray(x, np.float64)
    idx = np.asarray(epoch_idx, np.int64)
    cs = np.concatenate([[0.0], np.cumsum(x)])
    prev = np.concatenate([[0], idx[:-1]])
    n = idx - prev
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, (cs[idx + 1] - cs[prev + 1]) / n, np.nan)


def _with_attitude(truth, C_eb):
    """``truth`` with the attitude ``C_eb`` (N, 3, 3) (heading and pitch in the local NED frame) and its
    ideal IMU unknown (NaN)."""
    B, N = truth.batch_size, truth.t.size
    lat, lon, _ = ecef_to_geodetic(truth.r_e[0])
    rpy = euler_from_dcm(np.swapaxes(C_en(lat, lon), -1, -2) @ C_eb)

    def bc(x):
        return np.broadcast_to(np.asarray(x, np.float64)[None], (B,) + np.shape(x))

    nan = bc(np.full((N, 3), np.nan))
    return dataclasses.replace(truth, C_eb=bc(C_eb), heading=bc(rpy[:, 2]), pitch=bc(rpy[:, 1]), f_b=nan, w_b=nan)


def smartloc_scenario(imu_grade: str = "industrial", imu_rate_hz: float = 100.0, duration_s: float = 282.8,
                      start=(52.5046, 13.3737, 76.0), vibration: Vibration | None = None,
                      initial: InitialErrors | None = None, clock: ClockModel | None = None,
                      odometer=None) -> Scenario:
    """The descriptor :class:`Scenario` of the smartLoc Potsdamer Platz replay (module docstring); ``odometer``:
    the model of its recorded wheel odometry, or None."""
    return Scenario(name=SMARTLOC_SCENARIO, duration_s=duration_s, imu_rate_hz=imu_rate_hz, gnss_rate_hz=5.0,
                    imu_grade=imu_grade, drive="urban", start=tuple(start),
                    vibration=Vibration() if vibration is None else vibration,
                    receiver=ReceiverConfig(clock=ClockModel.tcxo() if clock is None else clock),
                    initial=InitialErrors() if initial is None else initial, odometer=odometer,
                    description="replay: smartLoc Berlin Potsdamer Platz recorded GPS+GLONASS pseudoranges "
                                "(urban), IMU synthesized from the SPAN ground truth")


def load_smartloc_world(seeds, imu_grade: str = "industrial", imu_rate_hz: float = 100.0, folder=None,
                        name: str = POTSDAMER_PLATZ, systems=(1, 4), min_elevation_deg: float = 0.0,
                        min_cn0_dbhz: float = 0.0, vibration: Vibration | None = None,
                        initial: InitialErrors | None = None, duration_s: float | None = None, dtype=np.float64,
                        data=None, sigma_model=None, odometer=None) -> World:
    """The ``smartloc-potsdamer-platz`` replay world for ``seeds`` (B rows, one IMU-noise draw each).

    Parameters
    ----------
    seeds : int or sequence of B non-negative ints.
    imu_grade : a key of :data:`envs.sim.imu.IMU_GRADES` (the synthesized IMU).
    imu_rate_hz : IMU rate [Hz] (100: every recorded epoch lands within 5 ms of an IMU sample).
    folder, name : the smartLoc folder (default ``../shared/data/smartloc``) and recording stem.
    systems, min_elevation_deg, min_cn0_dbhz : measurement selection (:meth:`SmartLocData.epochs`).
    vibration, initial : scenario overrides (defaults: :class:`Vibration`, :class:`InitialErrors`).
    duration_s : replay only the first ``duration_s`` seconds (>= 2 s); None: the whole recording.
    dtype : float dtype of the IMU samples.
    data : an already loaded :class:`~envs.datasets.smartloc.SmartLocData` (skips reading the files).
    sigma_model : an :class:`envs.sim.sigma_models.SigmaModel` for the pseudorange sigma the filter is told
        (None or ``'receiver'``: the recorded variance).
    odometer : None, or an :class:`envs.sim.odometer.OdometerModel` (the sigmas the filter assumes): the
        recorded wheel odometry (``odom3`` rows) becomes the world's ``odometer`` (forward speed at the epochs)
        and ``odometer_yaw_rate`` (:func:`replay_world`), fused with the NHC by every filter loop, as a
        simulated scenario's odometer (a dataset spec's ``[odometry]``).

    Returns
    -------
    World (``gnss.prr`` is None: run the navigator on pseudoranges only).
    """
    if imu_grade not in IMU_GRADES:
        raise ValueError(f"imu_grade {imu_grade!r} is unknown; known: {sorted(IMU_GRADES)}")
    data = _load_smartloc_cached(folder, name) if data is None else data
    gt = data.ground_truth
    keep = np.ones(gt.t.size, bool)
    if duration_s is not None:
        if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float)) or not duration_s >= 2.0:
            raise ValueError(f"duration_s must be a number >= 2 s or None, got {duration_s!r}")
        keep = gt.t <= gt.t[0] + duration_s
    fit = fit_positions(gt.t[keep], gt.r_e[keep])
    lat, lon, h = ecef_to_geodetic(gt.r_e[0])
    scen = smartloc_scenario(imu_grade, imu_rate_hz, duration_s=max(fit.t1 - fit.t0, 1.0),
                             start=(math.degrees(lat), math.degrees(lon), float(h)), vibration=vibration,
                             initial=initial, odometer=odometer)
    ep = data.epochs(systems=systems, min_elevation_deg=min_elevation_deg, min_cn0_dbhz=min_cn0_dbhz)
    if sigma_model is not None:
        ep = ep.with_sigma_model(sigma_model, data.input_path)
    if odometer is not None and data.odometry.t.size < 2:
        raise ValueError(f"{data.input_path}: recorded odometry requested but the file has "
                         f"{data.odometry.t.size} odom3 rows")
    return replay_world(scen, ep, fit, seeds, dtype=dtype, odometry=None if odometer is None else data.odometry)


def _load_smartloc_cached(folder, name):
    """:func:`load_smartloc` memoized on the files' paths, sizes and modification times (environment resets)."""
    folder = smartloc_dir() if folder is None else Path(folder)
    key = []
    for suffix in ("_Input.txt", "_GT.txt"):
        p = (folder / f"{name}{suffix}").resolve()
        st = p.stat() if p.is_file() else None
        key.append((str(p), None if st is None else (st.st_size, st.st_mtime_ns)))
    return _cached(tuple(key), str(folder), name)


@functools.lru_cache(maxsize=4)
def _cached(key, folder, name):
    data = load_smartloc(folder, name)
    for part in (data.pseudoranges, data.odometry, data.ground_truth):   # shared: make it read-only
        for v in vars(part).values():
            if isinstance(v, np.ndarray):
                v.flags.writeable = False
    return data


def load_rinex_world(obs_path, nav_path, truth_csv, seeds, imu_grade: str = "industrial", systems=("G",),
                     imu_rate_hz: float = 100.0, interval_s: float | None = None, elevation_mask_deg: float = 10.0,
                     sigma0_m: float = 1.5, vibration: Vibration | None = None,
                     initial: InitialErrors | None = None, dtype=np.float64, name: str = RINEX_SCENARIO) -> World:
    """A replay world from a RINEX observation file, its navigation file and a truth CSV (generic RINEX scenario).

    The same as a dataset spec (:mod:`envs.datasets.spec`) with ``gnss.format = "rinex"``, one navigation
    file, the default codes of :data:`envs.datasets.rinex.SIGNALS`, both atmosphere corrections, a
    ``navgym-csv`` truth (GPS week, time of week, ECEF; :mod:`envs.datasets.truth_csv`) and no Doppler
    (pseudoranges only), built by :func:`envs.datasets.dataset_world.world_from_spec`. Epochs outside the
    truth's time span are dropped (one printed line).

    Parameters
    ----------
    obs_path, nav_path : RINEX 3 observation and navigation files.
    truth_csv : the reference trajectory.
    seeds : int or B non-negative ints.
    imu_grade : a key of :data:`envs.sim.imu.IMU_GRADES`.
    systems : RINEX system letters; default GPS only: the navigator has one receiver-clock state, so with
        several systems their inter-system biases (a few metres for a u-blox receiver: Galileo -4 m, BeiDou
        +9 m against GPS on the Reach M2 file) act as measurement errors.
    imu_rate_hz, interval_s, elevation_mask_deg, sigma0_m : rates and the measurement model.
    vibration, initial : scenario overrides; dtype : IMU sample dtype; name : the scenario name.
    """
    from .dataset_world import world_from_spec
    from .rinex import SIGNALS, _check_systems
    from .spec import DatasetSpec, GnssSpec, ImuSpec, TruthSpec, replay_scenario

    if imu_grade not in IMU_GRADES:
        raise ValueError(f"imu_grade {imu_grade!r} is unknown; known: {sorted(IMU_GRADES)}")
    systems = _check_systems(systems)
    obs_path = Path(obs_path)
    gnss = GnssSpec(format="rinex", obs=obs_path, nav=(Path(nav_path),), systems=systems,
                    signals=tuple((s, SIGNALS[s][0]) for s in systems), elevation_mask_deg=elevation_mask_deg,
                    sigma0_m=sigma0_m, interval_s=interval_s, doppler=False)
    spec = DatasetSpec(name=name, path=obs_path, gnss=gnss, truth=TruthSpec("navgym-csv", Path(truth_csv)),
                       imu=ImuSpec("synthesized", imu_grade, float(imu_rate_hz)),
                       description=f"{obs_path.name}, truth {Path(truth_csv).name}, IMU synthesized ({imu_grade})")
    scen = replay_scenario(spec).replace(vibration=Vibration() if vibration is None else vibration,
                                         initial=InitialErrors() if initial is None else initial)
    return world_from_spec(scen, seeds, dtype=dtype)
