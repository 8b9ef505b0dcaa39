"""A recorded IMU CSV replayed through a dataset spec (issue 12; envs.datasets.recorded_imu).

The round trip writes a simulated world's own ideal IMU as a "recorded" CSV (sensor axes rotated against the
body, another column order, g and deg/s), loads it through a spec and checks the ImuData equals the original;
the error tests check that a bad file or key is named with its line and column.
"""
import dataclasses
import math

import numpy as np
import pytest

from earth import dcm_from_euler
from envs.datasets.errors import DatasetFormatError, shared_data_dir
from envs.datasets.recorded_imu import read_imu_csv, recorded_imu_data, resample_rates
from envs.datasets.spec import DatasetSpecError, load_dataset_spec
from envs.sim.imu import IMU_GRADES
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world

WEEK, TOW0 = 2268, 302400.0
MOUNT_DEG = (10.0, -5.0, 90.0)
G0 = 9.80665
HEADER = "gz_dps,ax_g,TOW,gy_dps,Week,az_g,gx_dps,ay_g"
SPEC = """name = "rec"
[gnss]
format = "rinex"
obs = "o.23O"
nav = ["n.nav"]
[truth]
format = "static"
position_ecef = [4157198.4, 671195.1, 4774772.0]
[imu]
source = "recorded"
grade = "tactical"
rate_hz = 100.0
file = "imu.csv"
accel_unit = "g"
gyro_unit = "deg/s"
mounting = [{m}]
{extra}
[imu.columns]
week = "Week"
tow = "TOW"
fx = "ax_g"
fy = "ay_g"
fz = "az_g"
wx = "gx_dps"
wy = "gy_dps"
wz = "gz_dps"
"""


def _write(tmp_path, t, f_b, w_b, extra=""):
    """The IMU CSV of body-frame rates (f_b, w_b) seen by a sensor mounted at MOUNT_DEG, and its spec."""
    C_bs = dcm_from_euler(*np.radians(MOUNT_DEG))
    f_s, w_s = f_b @ C_bs, w_b @ C_bs                      # C_bs^T x, row-wise
    rows = [HEADER]
    for k in range(t.size):
        ax, ay, az = f_s[k] / G0
        gx, gy, gz = np.degrees(w_s[k])
        rows.append(",".join(repr(float(v)) for v in (gz, ax, TOW0 + t[k], gy, WEEK, az, gx, ay)))
    (tmp_path / "imu.csv").write_text("# recorded IMU\n" + "\n".join(rows) + "\n")
    p = tmp_path / "rec.toml"
    p.write_text(SPEC.format(m=", ".join(map(str, MOUNT_DEG)), extra=extra))
    return load_dataset_spec(p)


@pytest.fixture(scope="module")
def world():
    return generate_world(get_scenario("open-sky", duration_s=20.0), [3])


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_round_trip_recovers_the_ideal_imu(tmp_path, world, dtype):
    tr = world.truth
    spec = _write(tmp_path, tr.t, tr.f_b[0], tr.w_b[0])
    assert spec.imu.source == "recorded" and spec.imu.grade == "tactical" and spec.imu.file == tmp_path / "imu.csv"
    imu = recorded_imu_data(spec.imu, WEEK, TOW0 + tr.t, batch_size=2, dtype=dtype)
    assert imu.f_b.shape == (2, tr.t.size, 3) and imu.f_b.dtype == dtype and imu.dt == pytest.approx(0.01)
    tol = dict(rtol=0, atol=1e-11) if dtype == np.float64 else dict(rtol=1e-6, atol=1e-6)
    # sample 0 has no interval before it (the navigator never uses it): compared from 1 on
    np.testing.assert_allclose(imu.f_b[:, 1:], np.broadcast_to(tr.f_b[0, 1:], (2, tr.t.size - 1, 3)), **tol)
    np.testing.assert_allclose(imu.w_b[:, 1:], np.broadcast_to(tr.w_b[0, 1:], (2, tr.t.size - 1, 3)),
                               **(dict(rtol=0, atol=1e-14) if dtype == np.float64 else tol))
    assert imu.gyro_bias is None and imu.accel_bias is None and imu.gyro_scale_misalignment is None
    assert imu.accel_scale_misalignment is None and imu.bias_steps is None and imu.rough is None
    assert imu.grade is IMU_GRADES["tactical"]
    # without the mounting the sensor axes are taken as the body's: the answer is wrong
    nomount = dataclasses.replace(spec.imu, options=tuple((k, v) for k, v in spec.imu.options if k != "mounting"))
    assert np.abs(recorded_imu_data(nomount, WEEK, TOW0 + tr.t).f_b[0, 1:] - tr.f_b[0, 1:]).max() > 1.0


def test_resampling_integrates_a_faster_recording(world):
    """200 Hz halves a +- d around each 100 Hz mean come back as the mean; a shifted grid conserves the
    integral of the rates."""
    tr = world.truth
    a = tr.f_b[0, 1:]
    d = np.sin(np.arange(len(a)))[:, None] * np.array([0.3, -0.2, 0.1])
    t200 = np.arange(2 * tr.t.size - 1) * 0.005
    x = np.empty((t200.size, 3))
    x[0] = a[0]
    x[1::2], x[2::2] = a + d, a - d
    np.testing.assert_allclose(resample_rates(t200, x, tr.t)[1:], a, atol=1e-11)
    shifted = tr.t[:-1] + 0.0037
    out = resample_rates(t200, x, shifted)
    # the integral of the piecewise constant recording over (shifted[0], shifted[-1]], interval by interval
    overlap = np.clip(np.minimum(t200[1:], shifted[-1]) - np.maximum(t200[:-1], shifted[0]), 0.0, None)
    np.testing.assert_allclose((out[1:] * 0.01).sum(0), (x[1:] * overlap[:, None]).sum(0), atol=1e-10)
    assert np.abs(out[1:] - a[:-1]).max() > 0.01                # a shifted grid is not the 100 Hz means
    with pytest.raises(ValueError, match="not inside the recorded samples"):
        resample_rates(t200, x, tr.t + 0.5)


def _csv(tmp_path, world, edit):
    tr = world.truth
    spec = _write(tmp_path, tr.t[:50], tr.f_b[0, :50], tr.w_b[0, :50])
    lines = (tmp_path / "imu.csv").read_text().split("\n")
    edit(lines)
    (tmp_path / "imu.csv").write_text("\n".join(lines))
    return spec


def _swap_rows(lines):
    lines[10], lines[11] = lines[11], lines[10]


def _gap(lines):
    del lines[20:40]


def _bad_cell(lines):
    lines[7] = lines[7].replace(",", ",x", 1)


@pytest.mark.parametrize("edit, line, words", [
    (lambda ln: ln.__setitem__(1, HEADER.replace("gz_dps", "yaw_rate")), 2, "'gz_dps' \\(imu.columns.wz\\) is not in"),
    (_swap_rows, 12, "time does not increase"),
    (_gap, 21, "a gap of 0.21 s after line 20: above imu.max_gap_s = 0.1 s"),
    (_bad_cell, 8, "'ax_g': 'x"),
])
def test_bad_csv_names_file_line_and_column(tmp_path, world, edit, line, words):
    spec = _csv(tmp_path, world, edit)
    with pytest.raises(DatasetFormatError, match=words) as ei:
        read_imu_csv(spec.imu, WEEK)
    assert ei.value.path == str(tmp_path / "imu.csv") and ei.value.line == line


def test_gap_limit_is_a_key(tmp_path, world):
    tr = world.truth
    spec = _write(tmp_path, tr.t[:50], tr.f_b[0, :50], tr.w_b[0, :50], extra="max_gap_s = 0.5")
    lines = (tmp_path / "imu.csv").read_text().split("\n")
    _gap(lines)
    (tmp_path / "imu.csv").write_text("\n".join(lines))
    t, f, w = read_imu_csv(spec.imu, WEEK)
    assert t.size == 30 and t[0] == TOW0 and f.shape == w.shape == (30, 3)


@pytest.mark.parametrize("old, new, key, words", [
    ('gyro_unit = "deg/s"', 'gyro_unit = "rpm"', "imu.gyro_unit", "must be one of rad/s, deg/s"),
    ('accel_unit = "g"', 'accel_unit = "mg"', "imu.accel_unit", "must be one of m/s\\^2, g"),
    ('wz = "gz_dps"\n', "", "imu.columns.wz", "missing"),
    ('week = "Week"\n', "", "imu.columns.week", "incomplete"),
    ('fx = "ax_g"\n', 'fx = "ax_g"\nspeed = "v"\n', "imu.columns.speed", "unknown role"),
    ("mounting = [10.0, -5.0, 90.0]", "mounting = [10.0, 90.0]", "imu.mounting", "roll, pitch, yaw"),
    ('file = "imu.csv"', "max_gap_s = 0\nfile = 'imu.csv'", "imu.max_gap_s", "> 0"),
    ('file = "imu.csv"\n', "", "imu.file", "missing"),
    ('grade = "tactical"\n', "", "imu.grade", "data-sheet grade"),
    ('source = "recorded"\n', "", "imu.file", "recorded IMU only"),
])
def test_bad_imu_keys_name_the_key(tmp_path, old, new, key, words):
    text = SPEC.format(m=", ".join(map(str, MOUNT_DEG)), extra="")
    assert old in text
    p = tmp_path / "bad.toml"
    p.write_text(text.replace(old, new, 1))
    with pytest.raises(DatasetSpecError, match=words) as ei:
        load_dataset_spec(p)
    assert ei.value.key == key and str(ei.value).startswith(f"{p}: {key}: ")


REACH = shared_data_dir() / "instinct_tckf_static"
OBS, NAV = REACH / "reach-m2-01_raw_202306291111.23O", REACH / "reach-m2-01_raw_202306291111.nav"
LLH = (48.7806647, 9.1714960, 330.08)          # the shipped instinct-reach-static truth
RPY_DEG = (1.5, -2.0, 30.0)


@pytest.mark.skipif(not NAV.is_file(), reason=f"Reach M2 RINEX files not found in {REACH} (../shared/data is "
                                              f"absent in a fresh clone)")
def test_replay_world_with_a_recorded_imu(tmp_path):
    """The Reach RINEX with a static truth that has an attitude, and the ideal IMU of that static body recorded
    by a sensor mounted upside down: the world carries the recorded samples, the truth's attitude, and the
    filter holds the position."""
    from earth import OMEGA_IE, C_en, geodetic_to_ecef, gravity_ecef
    from envs.episodes import run_episodes
    from envs.worlds import make_world
    lat, lon = math.radians(LLH[0]), math.radians(LLH[1])
    r = np.asarray(geodetic_to_ecef(lat, lon, LLH[2]), np.float64)
    C_eb = C_en(lat, lon) @ dcm_from_euler(*np.radians(RPY_DEG))
    f_b = C_eb.T @ -gravity_ecef(r)
    w_b = C_eb.T @ np.array([0.0, 0.0, OMEGA_IE])
    C_bs = dcm_from_euler(math.pi, 0.0, 0.0)                 # sensor z up
    tow0 = 385962.094
    tt = tow0 - 1.0 + 0.1 * np.arange(640)
    (tmp_path / "truth.csv").write_text("week,tow,lat,lon,h,roll,pitch,yaw\n" + "".join(
        f"{WEEK},{float(t)!r},{LLH[0]},{LLH[1]},{LLH[2]},{RPY_DEG[0]},{RPY_DEG[1]},{RPY_DEG[2]}\n" for t in tt))
    ti = tow0 - 0.5 + 0.01 * np.arange(6200)
    f_s, w_s = C_bs.T @ f_b, C_bs.T @ w_b
    (tmp_path / "imu.csv").write_text("utc_unused,week,tow,wx,wy,wz,fx,fy,fz\n" + "".join(
        f"-,{WEEK},{float(t)!r}," + ",".join(repr(float(v)) for v in (*w_s, *f_s)) + "\n" for t in ti))
    p = tmp_path / "rec.toml"
    p.write_text(f'name = "reach-recorded"\n[gnss]\nformat = "rinex"\nobs = "{OBS}"\nnav = ["{NAV}"]\n'
                 f'systems = ["G"]\n[truth]\nformat = "csv"\nfile = "truth.csv"\n[truth.columns]\nweek = "week"\n'
                 f'tow = "tow"\nlat = "lat"\nlon = "lon"\nheight = "h"\nroll = "roll"\npitch = "pitch"\n'
                 f'yaw = "yaw"\n[imu]\nsource = "recorded"\ngrade = "industrial"\nfile = "imu.csv"\n'
                 f'mounting = [180.0, 0.0, 0.0]\n[imu.columns]\nweek = "week"\ntow = "tow"\nfx = "fx"\n'
                 f'fy = "fy"\nfz = "fz"\nwx = "wx"\nwy = "wy"\nwz = "wz"\n')
    world = make_world(str(p), [0, 1])
    N = world.truth.t.size
    assert N > 5000 and world.imu.f_b.shape == (2, N, 3) and world.imu.gyro_bias is None
    np.testing.assert_allclose(world.imu.f_b[:, 1:], np.broadcast_to(f_b, (2, N - 1, 3)), atol=1e-9)
    np.testing.assert_allclose(world.imu.w_b[:, 1:], np.broadcast_to(w_b, (2, N - 1, 3)), atol=1e-15)
    np.testing.assert_allclose(world.truth.C_eb, np.broadcast_to(C_eb, (2, N, 3, 3)), atol=1e-9)
    assert np.isnan(world.truth.f_b).all()
    log = run_episodes(world, "kf")
    err = np.asarray(log.pos_err_ned)
    rmse = float(np.sqrt(np.nanmean(np.sum(err[..., :2] ** 2, -1))))
    print(f"kf horizontal RMSE with the recorded (ideal, static) IMU: {rmse:.2f} m")
    assert rmse < 10.0


@pytest.mark.skipif(not (REACH / "vn310-imu.csv").is_file() or not NAV.is_file(),
                    reason=f"VN-310 / Reach files not found in {REACH} (../shared/data is absent in a fresh clone)")
def test_shipped_vn310_spec_replays_the_recorded_imu():
    """envs/datasets/specs/instinct-reach-vn310.toml end to end: the replay is the 33 s the 50 Hz VN-310 log
    covers, its samples are the log's (the grid is the log's own stamps where they are 20 ms apart), and the
    filters run on it."""
    from envs.datasets.spec import SPEC_DIR
    from envs.episodes import run_episodes
    from envs.worlds import make_world
    spec = load_dataset_spec(SPEC_DIR / "instinct-reach-vn310.toml")
    assert spec.imu.source == "recorded" and spec.imu.rate_hz == 50.0
    world = make_world(str(spec.path), [0, 1])
    assert 31.0 < world.scenario.duration_s < 33.1 and world.imu.gyro_bias is None
    t, f, w = read_imu_csv(spec.imu, 2268)
    mean_f = f.mean(0)
    # at rest the recorded specific force is -g in the body: about 9.80 m/s^2, z down
    assert abs(np.linalg.norm(mean_f) - 9.80) < 0.02 and mean_f[2] < -9.7
    np.testing.assert_allclose(world.imu.f_b[0, 1:].mean(0), mean_f, atol=2e-3)
    log = run_episodes(world, "kf")
    e = np.asarray(log.pos_err_ned)
    rmse = float(np.sqrt(np.mean(np.sum(e[..., :2] ** 2, -1))))
    print(f"instinct-reach-vn310 kf horizontal RMSE {rmse:.2f} m")
    assert np.isfinite(e).all() and rmse < 10.0


def test_static_truth_attitude_key(tmp_path):
    p = tmp_path / "s.toml"
    p.write_text(SPEC.format(m="0, 0, 0", extra="").replace(
        "position_ecef = [4157198.4, 671195.1, 4774772.0]\n",
        "position_ecef = [4157198.4, 671195.1, 4774772.0]\nattitude_rpy_deg = [1, 2]\n"))
    with pytest.raises(DatasetSpecError, match="roll, pitch, yaw") as ei:
        load_dataset_spec(p)
    assert ei.value.key == "truth.attitude_rpy_deg"


@pytest.mark.skipif(not (REACH / "vn310-imu.csv").is_file() or not NAV.is_file(),
                    reason=f"VN-310 / Reach files not found in {REACH} (../shared/data is absent in a fresh clone)")
def test_recorded_imu_needs_the_truth_attitude(tmp_path):
    from envs.datasets.spec import SPEC_DIR
    from envs.worlds import make_world
    text = (SPEC_DIR / "instinct-reach-vn310.toml").read_text()
    p = tmp_path / "noatt.toml"
    p.write_text(text.replace("attitude_rpy_deg = [3.90, -1.81, 0.0]\n", "").replace(
        'name = "instinct-reach-vn310"', 'name = "vn310-no-attitude"'))
    with pytest.raises(ValueError, match="needs the truth's attitude"):
        make_world(str(p), [0])


@pytest.mark.skipif(not (REACH / "vn310-imu.csv").is_file() or not NAV.is_file(),
                    reason=f"VN-310 / Reach files not found in {REACH} (../shared/data is absent in a fresh clone)")
def test_check_command_reads_the_recorded_imu(tmp_path, capsys):
    from envs.datasets.check import main
    from envs.datasets.spec import SPEC_DIR
    spec = SPEC_DIR / "instinct-reach-vn310.toml"
    assert main(["check", str(spec)]) == 0
    assert "IMU: recorded vn310-imu.csv: 1638 rows over 33.0 s" in capsys.readouterr().out
    p = tmp_path / "gap.toml"                          # the log's 0.29 s steps are refused at the default limit
    p.write_text(spec.read_text().replace("max_gap_s = 0.3\n", ""))
    assert main(["check", str(p)]) == 1
    assert "above imu.max_gap_s = 0.1 s" in capsys.readouterr().err


def test_utc_time_base_and_comment_lines(tmp_path, world):
    """The same samples stamped in UTC (GPS - UTC = 18 s in 2023) read back to the same GPS times."""
    tr = world.truth
    spec = _write(tmp_path, tr.t[:40], tr.f_b[0, :40], tr.w_b[0, :40])
    t_gps, f, w = read_imu_csv(spec.imu, WEEK)
    start = np.datetime64("1980-01-06T00:00:00", "ns") + np.timedelta64(WEEK * 604800, "s")
    lines = (tmp_path / "imu.csv").read_text().split("\n")
    out = [lines[0], lines[1].replace("TOW", "utc").replace(",Week", ",spare")]
    for ln, t in zip(lines[2:], t_gps):
        cells = ln.split(",")
        utc = start + np.timedelta64(int(round((t - 18.0) * 1e9)), "ns")
        cells[2], cells[4] = str(utc), "0"
        out.append(",".join(cells))
    (tmp_path / "imu.csv").write_text("\n".join(out) + "\n")
    p = tmp_path / "utc.toml"
    p.write_text(spec.path.read_text().replace('week = "Week"\ntow = "TOW"\n', 'utc = "utc"\n'))
    t2, f2, w2 = read_imu_csv(load_dataset_spec(p).imu, WEEK)
    np.testing.assert_allclose(t2, t_gps, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(f2, f)
    np.testing.assert_array_equal(w2, w)
