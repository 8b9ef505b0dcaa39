"""Recorded wheel odometry as aiding (a dataset spec's ``[odometry]``; smartLoc ``odom3`` rows): the spec, the
readings carried into the replay world at the right epochs with the FRD sign, and their rows in every filter
loop (run_episodes, the env core), as a simulated odometer's."""
import math

import numpy as np
import pytest

from envs.datasets.errors import shared_data_dir
from envs.datasets.replay import interval_means
from envs.datasets.spec import (SHIPPED_SPECS, SPEC_DIR, DatasetSpecError, OdometrySpec, dataset_spec_of,
                                load_dataset_spec)
from envs.sim.odometer import OdometerModel

DATA = shared_data_dir()
ODO = "smartloc-potsdamer-platz-odometry"
ODO_SPEC = SPEC_DIR / SHIPPED_SPECS[ODO]
needs_smartloc = pytest.mark.skipif(not (DATA / "smartloc" / "Berlin_Potsdamer_Platz_Input.txt").is_file(),
                                    reason=f"smartLoc data not found in {DATA / 'smartloc'} (../shared/data is "
                                           f"absent in a fresh clone; CI has it)")


# ------------------------------------------------------------------------------------------------ the spec
def test_shipped_odometry_spec():
    s = load_dataset_spec(ODO_SPEC)
    assert s.name == ODO and dataset_spec_of(ODO) == s and s.imu.grade == "consumer"
    assert s.odometry == OdometrySpec("recorded", 0.1, 0.1, True, 0.3)
    sc = s.scenario()
    assert sc.imu_grade == "consumer"
    assert sc.odometer == OdometerModel(scale_error=0.0, noise_mps=0.0, sigma_mps=0.1, nhc_sigma_mps=0.1,
                                        yaw_rate_sigma_rps=math.radians(0.3))
    assert load_dataset_spec(SPEC_DIR / SHIPPED_SPECS["smartloc-potsdamer-platz"]).scenario().odometer is None
    from envs.worlds import REPLAY_SCENARIOS
    assert ODO in REPLAY_SCENARIOS


def _odometry_spec(tmp_path, table: str, base=ODO_SPEC):
    text = base.read_text()
    text = text[:text.index("[odometry]")] if "[odometry]" in text else text
    p = tmp_path / "odo.toml"
    p.write_text(text + table if table.startswith("[") else table + text)   # a top-level key: before any table
    return p


@pytest.mark.parametrize("table, key, words", [
    ('[odometry]\nsource = "can-bus"\n', "odometry.source", "must be one of recorded"),
    ("[odometry]\nspeed_sigma_mps = 0.1\n", "odometry.source", "missing"),
    ('[odometry]\nsource = "recorded"\nspeed_sigma_mps = -0.1\n', "odometry.speed_sigma_mps", "must be > 0"),
    ('[odometry]\nsource = "recorded"\nnhc_sigma_mps = 0\n', "odometry.nhc_sigma_mps", "must be > 0"),
    ('[odometry]\nsource = "recorded"\nyaw_rate = false\nyaw_rate_sigma_dps = 0.2\n', "odometry.yaw_rate_sigma_dps",
     "yaw_rate = true only"),
    ('[odometry]\nsource = "recorded"\nwheel_base_m = 2.7\n', "odometry.wheel_base_m", "unknown key"),
    ('odometry = "recorded"\n', "odometry", r"must be a \[odometry\] section"),
])
def test_bad_odometry_section_names_the_key(tmp_path, table, key, words):
    p = _odometry_spec(tmp_path, table)
    with pytest.raises(DatasetSpecError, match=words) as ei:
        load_dataset_spec(p)
    assert ei.value.key == key and str(ei.value).startswith(f"{p}: {key}: ")


def test_odometry_needs_a_smartloc_recording(tmp_path):
    p = _odometry_spec(tmp_path, '[odometry]\nsource = "recorded"\n', base=SPEC_DIR / "instinct-reach-static.toml")
    with pytest.raises(DatasetSpecError, match="smartLoc files only") as ei:
        load_dataset_spec(p)
    assert ei.value.key == "odometry.source"
    s = load_dataset_spec(_odometry_spec(tmp_path, '[odometry]\nsource = "recorded"\nyaw_rate = false\n'))
    assert s.odometry.model().yaw_rate_sigma_rps is None                      # speed + NHC only


def test_yaw_rate_odometer_is_recorded_only_and_interval_means_by_hand():
    from envs.sim.scenarios import get_scenario
    from envs.sim.world import generate_world
    with pytest.raises(ValueError, match="OdometerModel.yaw_rate_sigma_rps must be > 0"):
        OdometerModel(yaw_rate_sigma_rps=0.0)
    scen = get_scenario("seed003-sim", duration_s=10.0, odometer=OdometerModel(yaw_rate_sigma_rps=0.01))
    with pytest.raises(ValueError, match="a simulated odometer reads the forward speed only"):
        generate_world(scen, [0])
    # samples 1..2, 3..5, none (two epochs on one sample is refused elsewhere; here: an empty interval), 6
    np.testing.assert_allclose(interval_means([9.0, 1.0, 3.0, 2.0, 4.0, 6.0, 7.0], [0, 2, 5, 6]),
                               [np.nan, 2.0, 4.0, 7.0])


# ------------------------------------------------------------------------------------------- the world
@needs_smartloc
def test_recorded_speed_and_yaw_rate_reach_the_world_at_the_epochs_in_frd():
    from earth.wgs84 import OMEGA_IE
    from envs.datasets.replay import _load_smartloc_cached
    from envs.worlds import make_world
    w = make_world(ODO, [0, 1], duration_s=120.0)
    od = _load_smartloc_cached(None, "Berlin_Potsdamer_Platz").odometry
    t0 = _load_smartloc_cached(None, "Berlin_Potsdamer_Platz").ground_truth.t[0]
    ep, M = w.epoch_idx, len(w.epoch_idx)
    assert w.odometer.shape == w.odometer_yaw_rate.shape == (2, M)
    np.testing.assert_array_equal(w.odometer[0], w.odometer[1])               # the recording, in every row
    t_rec = w.gnss.t + t0                                                      # the recording's time stamps
    np.testing.assert_allclose(w.odometer[0], np.interp(t_rec, od.t, od.velocity[:, 0]), rtol=0, atol=1e-12)
    # the yaw rate: the recorded z turn rate (about UP) with its sign flipped, averaged over each epoch's
    # IMU interval (the sample midpoints), by a plain loop
    rate = w.scenario.imu_rate_hz
    t_mid = w.truth.t + t0 - 0.5 / rate
    assert np.isnan(w.odometer_yaw_rate[0, 0]) and ep[0] == 0                  # no interval before epoch 0
    for j in (1, 2, M // 2, M - 1):
        k = np.arange(ep[j - 1] + 1, ep[j] + 1)
        want = np.mean(-np.interp(t_mid[k], od.t, od.turn_rate[:, 2]))
        assert abs(w.odometer_yaw_rate[0, j] - want) < 1e-12
    # against the SPAN truth: the speed within centimetres, the yaw rate with the truth's sign (FRD, down)
    assert np.median(np.abs(w.odometer[0] - w.truth.speed[0, ep])) < 0.1
    C_be = np.swapaxes(w.truth.C_eb[0], -1, -2)
    yaw_truth = interval_means((w.truth.w_b[0] - C_be @ np.array([0.0, 0.0, OMEGA_IE]))[:, 2], ep)
    ok = np.isfinite(yaw_truth) & np.isfinite(w.odometer_yaw_rate[0]) & (w.truth.speed[0, ep] > 3.0)
    assert np.corrcoef(w.odometer_yaw_rate[0, ok], yaw_truth[ok])[0, 1] > 0.9
    assert np.median(np.abs(w.odometer_yaw_rate[0, ok] - yaw_truth[ok])) < math.radians(0.5)
    # the spec without [odometry]: no readings
    assert make_world("smartloc-potsdamer-platz", [0], duration_s=20.0).odometer is None


# ------------------------------------------------------------------------------------------ the filters
@needs_smartloc
def test_run_episodes_fuses_speed_nhc_and_yaw_rate_rows(monkeypatch):
    import envs.episodes as E
    from envs.worlds import make_world
    w = make_world(ODO, [0], duration_s=30.0)
    seen = []
    real = E.odometer_rows

    def spy(nav, speed, model, yaw=None, w_raw=None, dt=None):
        block = real(nav, speed, model, yaw, w_raw, dt)
        seen.append((np.array(speed), None if yaw is None else np.array(yaw), block))
        return block

    monkeypatch.setattr(E, "odometer_rows", spy)
    E.run_episodes(w, "kf")
    assert len(seen) == len(w.epoch_idx)
    for j, (speed, yaw, (dz, H, R, rm)) in enumerate(seen):
        np.testing.assert_array_equal(speed, w.odometer[:, j])
        np.testing.assert_array_equal(yaw, w.odometer_yaw_rate[:, j])
        if j == 0:                                                  # no IMU interval yet: speed + NHC only
            assert dz.shape == (1, 3)
            continue
        assert dz.shape == (1, 4) and rm.all()                       # odometer, 2 NHC, yaw rate
        assert H[0, 3, 11] == -1.0                                   # the z gyro-bias column (BG = 9:12)
        n = w.epoch_idx[j] - w.epoch_idx[j - 1]
        arw2 = max(1e-7, w.imu_grade.gyro_arw) ** 2
        np.testing.assert_allclose(R[0, 3], math.radians(0.3) ** 2 + arw2 * w.scenario.imu_rate_hz / n, rtol=1e-9)
    # the yaw-rate row's innovation stays near the sensor noise once the gyro bias is learnt
    late = np.array([s[2][0][0, 3] for s in seen[len(seen) // 2:]])
    assert np.median(np.abs(late)) < math.radians(1.0)


@needs_smartloc
def test_kf_with_recorded_odometry_on_the_recording():
    """kf runs on the whole recording with the consumer IMU and the odometry; the aiding lowers its error
    against the same IMU without it, and a yaw rate of the wrong sign (about UP instead of FRD down) is worse
    than the right one."""
    import dataclasses
    from envs.episodes import run_episodes
    from envs.worlds import make_world
    w = make_world(ODO, [0])
    rmse = lambda log: float(np.sqrt(np.mean(log.horizontal_error ** 2)))  # noqa: E731
    log = run_episodes(w, "kf")
    assert not log.diverged.any() and np.isfinite(log.pos_err_ned).all()
    plain = run_episodes(make_world("smartloc-potsdamer-platz", [0], imu_grade="consumer"), "kf")
    assert rmse(log) < 0.9 * rmse(plain)
    flipped = run_episodes(dataclasses.replace(w, odometer_yaw_rate=-w.odometer_yaw_rate), "kf")
    assert rmse(flipped) > rmse(log) + 1.0


@needs_smartloc
def test_env_core_fuses_the_recorded_odometry_like_run_episodes():
    from envs.config import EnvConfig
    from envs.core import TuningCore
    from envs.episodes import run_episodes
    from envs.gnss_ins_env import STKF_PARAMS
    seeds = [3]
    cfg = EnvConfig(scenario=ODO, method="stkf", episode_length_s=40.0, exact_transition=True,
                    fused_update=False)
    core = TuningCore(cfg, STKF_PARAMS, 1)
    core.reset_rows(np.arange(1), seeds)
    assert np.isfinite(core.odo_yaw[0, 1:]).all() and np.isnan(core.odo_yaw[0, 0])
    act = np.broadcast_to(core.default_action, (1, core.k))
    h_core = []
    while not np.any(core.t >= core.M):
        h_core.append(core.step(act).info["horizontal_error_m"])
    params = {p.name: p.to_value(core.default_action[i:i + 1])[0] for i, p in enumerate(STKF_PARAMS)}
    world = cfg.make_world(seeds)
    log = run_episodes(world, "stkf", params=params)
    np.testing.assert_allclose(log.horizontal_error, np.array(h_core).T, rtol=1e-9, atol=1e-9)


# ------------------------------------------------------------------------------------------------ NHC alone
NHC = "smartloc-potsdamer-platz-nhc"


def test_nhc_only_spec_and_its_errors(tmp_path):
    s = dataset_spec_of(NHC)
    assert s.odometry == OdometrySpec("nhc", OdometrySpec().speed_sigma_mps, 0.1, False, OdometrySpec().yaw_rate_sigma_dps)
    assert s.imu.grade == "industrial" and s.scenario().odometer.yaw_rate_sigma_rps is None
    for key in ("speed_sigma_mps = 0.2", "yaw_rate = true", "yaw_rate_sigma_dps = 0.3"):
        p = _odometry_spec(tmp_path, f'[odometry]\nsource = "nhc"\n{key}\n')
        with pytest.raises(DatasetSpecError, match="source = 'recorded' only"):
            load_dataset_spec(p)


@needs_smartloc
def test_nhc_only_world_has_no_odometer_reading_and_fuses_the_two_nhc_rows():
    """source = 'nhc': every epoch's odometer reading is missing (its row masked) and the two NHC rows are used,
    in run_episodes as for a simulated odometer."""
    from envs.episodes import run_episodes
    from envs.worlds import make_world
    w = make_world(NHC, [0], duration_s=20.0)
    assert w.odometer is not None and np.isnan(w.odometer).all() and w.odometer_yaw_rate is None
    assert w.scenario.odometer is not None
    plain = make_world("smartloc-potsdamer-platz", [0], duration_s=20.0)
    a, b = run_episodes(w, "kf"), run_episodes(plain, "kf")
    np.testing.assert_array_equal(a.n_used - b.n_used, 2)
