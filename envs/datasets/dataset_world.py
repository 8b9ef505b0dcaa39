"""A replay :class:`~envs.sim.world.World` from a dataset spec (issue 12; :mod:`envs.datasets.spec`).

:func:`world_from_spec` builds the world of a :class:`~envs.datasets.spec.ReplayScenario`:

* ``gnss.format = "smartloc"``: exactly :func:`envs.datasets.replay.load_smartloc_world` with the spec's
  selection (same seeds, same numbers as the code path of the name ``smartloc-potsdamer-platz``);
* ``gnss.format = "rinex"``: the observation file, the merged navigation files
  (:func:`envs.datasets.nav_merge.merge_nav`), corrected as in :func:`envs.datasets.rinex.rinex_epochs`
  with the spec's atmosphere switches, the truth from its reader (:mod:`envs.datasets.truth_readers`),
  then :func:`envs.datasets.replay.replay_world`.

What the recording cannot give is never dropped silently (:func:`prepare_rinex`): each case is an error or
one printed summary line, as listed in ``docs/datasets.md``. The parsed RINEX files are cached on disk by
content hash (:mod:`envs.datasets.cache`); the epochs and truth of a spec are kept in memory for the process
(environment resets rebuild worlds often).
"""
from __future__ import annotations

import dataclasses
import functools
import math
import sys
from dataclasses import dataclass

import numpy as np

from earth import ecef_to_geodetic

from ..sim.world import World
from .epochs import SYSTEM_LETTERS, SYSTEM_NAMES, GnssEpochs
from .errors import DatasetFormatError
from .spec import DatasetSpec, ReplayScenario
from .spline_truth import fit_positions
from .truth_readers import TruthTrack, read_truth

__all__ = ["PreparedRecording", "world_from_spec", "prepare_rinex", "report"]


def report(spec: DatasetSpec, message: str) -> None:
    """Print one summary line about ``spec``'s data (a documented, non-fatal drop) to stderr."""
    print(f"navgym dataset {spec.name}: {message}", file=sys.stderr, flush=True)


@dataclass(frozen=True)
class PreparedRecording:
    """The corrected epochs and the truth of a RINEX data set, ready to replay.

    Attributes
    ----------
    epochs : GnssEpochs (``t`` since the first observation epoch, ``t0_gps`` its GPS time of week).
    truth : TruthTrack (GPS time of the observation file's week).
    week_ref : int, the GPS week of the first observation.
    notes : tuple of str, the summary lines printed when it was prepared.
    """

    epochs: GnssEpochs
    truth: TruthTrack
    week_ref: int
    notes: tuple = ()


def world_from_spec(scenario: ReplayScenario, seeds, dtype=np.float64) -> World:
    """The replay world of ``scenario`` (its spec, IMU grade and rate, vibration, pseudorange sigma model
    ``receiver.sigma_model``, initial errors and ``duration_s``: the first ``duration_s`` seconds of the truth)
    for ``seeds`` (B rows)."""
    if not isinstance(scenario, ReplayScenario):
        raise ValueError(f"scenario must be a ReplayScenario, got {type(scenario).__name__}")
    spec = scenario.dataset
    nhc_only = spec.odometry is not None and spec.odometry.source == "nhc"
    if scenario.odometer is not None and spec.gnss.format != "smartloc" and not nhc_only:
        raise ValueError(f"{spec.path}: recorded odometry (scenario.odometer) needs gnss.format = 'smartloc' "
                         f"(its odom3 rows); this data set is {spec.gnss.format!r}")
    if spec.gnss.format == "smartloc":
        if spec.imu.source != "synthesized":
            raise ValueError(f"{spec.path}: imu.source = 'recorded' needs gnss.format = 'rinex' (smartLoc "
                             f"time stamps are not GPS time)")
        world = _smartloc_world(scenario, seeds, dtype)
    else:
        world = _rinex_world(scenario, seeds, dtype)
    if nhc_only:  # no odometer reading (NaN: its row masked), the NHC rows at every epoch
        world = dataclasses.replace(world, odometer=np.full((world.batch_size, world.epoch_idx.size), np.nan))
    r0 = world.truth.r_e[0, 0] if world.truth.r_e.ndim == 3 else world.truth.r_e[0]
    lat, lon, h = ecef_to_geodetic(np.asarray(r0, np.float64))
    scen = dataclasses.replace(scenario, duration_s=float(world.scenario.duration_s),
                               start=(math.degrees(lat), math.degrees(lon), float(h)))
    return dataclasses.replace(world, scenario=scen)


def _smartloc_world(scenario: ReplayScenario, seeds, dtype) -> World:
    from .replay import load_smartloc_world
    g, odo = scenario.dataset.gnss, scenario.dataset.odometry
    return load_smartloc_world(seeds, imu_grade=scenario.imu_grade, imu_rate_hz=scenario.imu_rate_hz,
                               folder=g.obs.parent, name=g.obs.name[:-len("_Input.txt")],
                               systems=tuple(SYSTEM_LETTERS[s] for s in g.systems),
                               min_elevation_deg=g.elevation_mask_deg, min_cn0_dbhz=g.min_cn0_dbhz,
                               vibration=scenario.vibration, initial=scenario.initial,
                               duration_s=scenario.duration_s, dtype=dtype,
                               sigma_model=scenario.receiver.sigma_model,
                               odometer=scenario.odometer if odo is not None and odo.source == "recorded" else None)


def _rinex_world(scenario: ReplayScenario, seeds, dtype) -> World:
    from .replay import replay_world
    spec = scenario.dataset
    rec = prepare_rinex(spec)
    ep, tr = rec.epochs.with_sigma_model(scenario.receiver.sigma_model, spec.gnss.obs), rec.truth
    t = tr.t - ep.t0_gps
    inside, recorded = np.ones(t.size, bool), None
    if spec.imu.source == "recorded":
        inside, recorded = _recorded_imu(spec, rec, t)
    keep = inside & (t <= t[inside][0] + scenario.duration_s)
    if keep.sum() < 5:
        raise ValueError(f"{spec.path}: duration_s = {scenario.duration_s} keeps {int(keep.sum())} truth rows; "
                         f"at least 5 are needed")
    fit = _fit(spec, t[keep], tr.r_e[keep])
    world = replay_world(scenario, ep, fit, seeds, dtype=dtype, recorded_imu=recorded)
    return dataclasses.replace(world, scenario=dataclasses.replace(scenario, duration_s=max(fit.t1 - fit.t0, 1.0)))


def _recorded_imu(spec: DatasetSpec, rec: PreparedRecording, t: np.ndarray):
    """The truth rows inside the recorded IMU's span, and the ``recorded_imu`` callable of
    :func:`envs.datasets.replay.replay_world`: the recorded samples on the grid, the attitude linearly
    interpolated from the truth's roll, pitch, yaw (yaw unwrapped)."""
    from earth import C_en, dcm_from_euler
    from .recorded_imu import recorded_imu_data
    tr = rec.truth
    if tr.rpy is None:
        raise ValueError(f"{spec.truth.file or spec.path}: imu.source = 'recorded' needs the truth's attitude "
                         f"(roll, pitch, yaw columns of a 'csv' truth): the filter's initial attitude and the "
                         f"attitude of the recorded sensor come from it")
    samples = _imu_samples(spec, rec.week_ref)
    lo, hi = samples[0][0] - rec.epochs.t0_gps, samples[0][-1] - rec.epochs.t0_gps
    half = 0.5 / spec.imu.rate_hz                    # the grid may end up to half a sample past the last row
    inside = (t >= lo) & (t <= hi - half)
    if inside.sum() < 5:
        raise ValueError(f"{spec.imu.file}: the recorded IMU spans [{lo:.2f}, {hi:.2f}] s after the first "
                         f"observation, the truth [{t[0]:.2f}, {t[-1]:.2f}] s: fewer than 5 truth rows in common")
    if not inside.all():
        report(spec, f"{int((~inside).sum())} of {t.size} truth rows lie outside the recorded IMU's span: "
                     f"not replayed")
    rpy = np.array(tr.rpy, np.float64)
    rpy[:, 2] = np.unwrap(rpy[:, 2])

    def recorded(t_grid, B, dtype):
        imu = recorded_imu_data(spec.imu, rec.week_ref, rec.epochs.t0_gps + t_grid, B, dtype, samples=samples)
        from earth import ecef_to_geodetic
        a = np.stack([np.interp(t_grid, t, rpy[:, j]) for j in range(3)], -1)
        r = np.stack([np.interp(t_grid, t, tr.r_e[:, j]) for j in range(3)], -1)
        lat, lon, _ = ecef_to_geodetic(r)
        return imu, C_en(lat, lon) @ dcm_from_euler(a[:, 0], a[:, 1], a[:, 2])

    return inside, recorded


def _imu_samples(spec: DatasetSpec, week_ref: int):
    """:func:`envs.datasets.recorded_imu.read_imu_csv` of ``spec``, memoized per process on the spec and the
    file's size and modification time (worlds are rebuilt at every environment reset); read-only arrays."""
    st = spec.imu.file.stat() if spec.imu.file.is_file() else None
    return _imu_samples_cached(spec, int(week_ref), None if st is None else (st.st_size, st.st_mtime_ns))


@functools.lru_cache(maxsize=4)
def _imu_samples_cached(spec, week_ref, stamp):
    from .recorded_imu import read_imu_csv
    out = read_imu_csv(spec.imu, week_ref)
    for a in out:
        a.setflags(write=False)
    return out


@functools.lru_cache(maxsize=8)
def _fit_cached(key, t_bytes, r_bytes):
    t = np.frombuffer(t_bytes, np.float64)
    return fit_positions(t, np.frombuffer(r_bytes, np.float64).reshape(t.size, 3))


def _fit(spec, t, r):
    return _fit_cached(spec, np.ascontiguousarray(t).tobytes(), np.ascontiguousarray(r).tobytes())


def prepare_rinex(spec: DatasetSpec) -> PreparedRecording:
    """The corrected epochs and truth of a RINEX spec, memoized per process on the spec and its files' sizes
    and modification times (the summary lines are printed the first time only)."""
    if spec.gnss.format != "rinex":
        raise ValueError(f"{spec.path}: gnss.format is {spec.gnss.format!r}, not 'rinex'")
    files = [spec.gnss.obs, *spec.gnss.nav] + ([spec.truth.file] if spec.truth.file is not None else [])
    stamp = []
    for p in files:
        st = p.stat() if p.is_file() else None
        stamp.append((str(p), None if st is None else (st.st_size, st.st_mtime_ns)))
    return _prepare_rinex_cached(spec, tuple(stamp))


@functools.lru_cache(maxsize=4)
def _prepare_rinex_cached(spec: DatasetSpec, stamp) -> PreparedRecording:
    from .nav_merge import check_coverage, merge_nav
    from .cache import cached_nav, cached_obs
    from .rinex import rinex_epochs
    g = spec.gnss
    notes = []

    def note(msg):
        notes.append(msg)
        report(spec, msg)

    obs = cached_obs(g.obs, systems=g.systems, interval_s=g.interval_s, signals=dict(g.signals), notes=note,
                     doppler=g.doppler)
    if g.doppler:
        _check_doppler(obs, spec, note)
    nav = merge_nav([cached_nav(p, week_ref=obs.week_ref) for p in g.nav])
    obs = check_coverage(obs, nav, spec, note)
    if spec.corrections.iono and nav.iono_alpha is None:
        raise ValueError(f"{spec.path}: corrections.iono = true but no navigation file "
                         f"({', '.join(p.name for p in g.nav)}) has the GPS Klobuchar coefficients (IONOSPHERIC "
                         f"CORR GPSA / GPSB): add a GPS navigation file to gnss.nav or set corrections.iono = false")
    ep = rinex_epochs(obs, nav, elevation_mask_deg=g.elevation_mask_deg, sigma0_m=g.sigma0_m,
                      iono=spec.corrections.iono, tropo=spec.corrections.tropo,
                      doppler_sigma0_mps=g.doppler_sigma0_mps if g.doppler else None)
    if g.min_cn0_dbhz > 0:
        ep = ep.keep(ep.cn0 >= g.min_cn0_dbhz)
    ep = dataclasses.replace(ep, source=f"RINEX {g.obs.name} + {' + '.join(p.name for p in g.nav)}")
    truth = read_truth(spec.truth, obs.week_ref, (ep.t0_gps, ep.t0_gps + ep.t[-1]))
    t_rel = truth.t - ep.t0_gps
    inside = (ep.t >= t_rel[0]) & (ep.t <= t_rel[-1])
    if not inside.any():
        raise DatasetFormatError(spec.truth.file or spec.path, None, f"the truth spans GPS time of week "
                                 f"[{truth.t[0]:.1f}, {truth.t[-1]:.1f}] s, the observations "
                                 f"[{ep.t0_gps:.1f}, {ep.t0_gps + ep.t[-1]:.1f}] s: no overlap")
    _check_truth_near_spp(spec, ep, truth)
    if not inside.all():
        note(f"{int((~inside).sum())} of {ep.n_epochs} observation epochs lie outside the truth's span "
             f"(GPS time of week [{truth.t[0]:.1f}, {truth.t[-1]:.1f}] s): not replayed")
    empty = ~ep.mask.any(-1) & inside
    if empty.any():
        note(f"{int(empty.sum())} of {int(inside.sum())} epochs have no usable satellite (mask, signals, "
             f"ephemerides)")
    return PreparedRecording(epochs=ep, truth=truth, week_ref=obs.week_ref, notes=tuple(notes))


def _check_truth_near_spp(spec: DatasetSpec, ep: GnssEpochs, truth: TruthTrack) -> None:
    """The truth against the recording's own single-point solution
    (:func:`envs.datasets.plausibility.check_truth_near_spp`), naming the truth file and its first row, or for a
    static truth the spec file's line of its position key."""
    from .plausibility import check_truth_near_spp
    opts = dict(spec.truth.options)
    if spec.truth.file is None:
        key = next(k for k in ("position_llh", "position_ecef") if k in opts)
        where, line = spec.path, _key_line(spec.path, key)
        value = f"truth.{key} = {list(opts[key])}"
    else:
        where, line = spec.truth.file, None if truth.lines is None else int(truth.lines[0])
        value = f"the truth rows from ({', '.join(f'{x:.3f}' for x in truth.r_e[0])}) m"
    check_truth_near_spp(ep, truth.t - ep.t0_gps, truth.r_e, where, line, value)


def _key_line(path, key: str) -> int | None:
    """The 1-based line of the first ``key = ...`` of a TOML file (None when not found)."""
    import re
    try:
        text = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError):
        return None
    return next((i for i, ln in enumerate(text, start=1) if re.match(rf"\s*{re.escape(key)}\s*=", ln)), None)


def _check_doppler(obs, spec, note) -> None:
    """gnss.doppler = true: an error if no satellite has a Doppler, one line per system with channels that
    have a code but no Doppler (their rate rows get no weight: :data:`envs.datasets.doppler.NO_DOPPLER_SIGMA_MPS`)."""
    from .rinex import _SYSTEM_NAME
    has_pr = np.isfinite(obs.pr)
    has_d = has_pr & np.isfinite(obs.doppler)
    if not has_pr.any():
        return                                       # no code at all: check_coverage names the system
    if not has_d.any():
        raise ValueError(f"{obs.path}: gnss.doppler = true but the file has no Doppler observable for the codes "
                         f"used ({', '.join(sorted({'D' + c[1:] for c in obs.code}))}): set gnss.doppler = false")
    for letter in spec.gnss.systems:
        cols = np.array([str(s)[0] == letter for s in obs.sv])
        miss = int((has_pr[:, cols] & ~has_d[:, cols]).sum())
        if miss:
            note(f"{_SYSTEM_NAME[letter]}: {miss} of {int(has_pr[:, cols].sum())} code observations have no "
                 f"Doppler: their pseudorange rate is not used")


def system_summary(ep: GnssEpochs) -> dict:
    """{system name: number of distinct satellites used} of epochs."""
    out = {}
    for code in np.unique(ep.system[ep.mask]):
        out[SYSTEM_NAMES[int(code)]] = int(np.unique(ep.sat_id[ep.mask & (ep.system == code)]).size)
    return out
