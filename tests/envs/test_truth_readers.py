"""Truth readers of dataset specs (issue 12): navgym CSV, static, the generic CSV with a column map (GPS week +
TOW with the 10-bit week, UTC, ECEF or geodetic, NED or ECEF velocity, attitude)."""
import math
from pathlib import Path

import numpy as np
import pytest

from earth import C_en, ecef_to_geodetic, geodetic_to_ecef
from envs.datasets.errors import DatasetFormatError, shared_data_dir
from envs.datasets.spec import DatasetSpecError, TruthSpec, load_dataset_spec
from envs.datasets.truth_csv import write_truth_csv
from envs.datasets.truth_generic_csv import resolve_gps_week, utc_to_gps_seconds
from envs.datasets.truth_readers import read_truth

REACH = shared_data_dir() / "instinct_tckf_static"
VN310 = REACH / "vn310-gnss.csv"
needs_vn310 = pytest.mark.skipif(not VN310.is_file(), reason=f"{VN310} not found (../shared/data is absent in a "
                                                             f"fresh clone)")
STATIC_LLH = (48.7806647, 9.1714960, 330.08)     # the instinct-reach-static spec's truth


def _spec(folder: Path, truth: str) -> Path:
    p = folder / "s.toml"
    p.write_text('name = "s"\n[gnss]\nformat = "rinex"\nobs = "o.23O"\nnav = ["n.nav"]\n[truth]\n' + truth)
    return p


def _track(n=40):
    """A 20 m/s eastward drive near Stuttgart at 10 Hz starting at GPS week 2268, TOW 385962 s."""
    t = 385962.0 + 0.1 * np.arange(n)
    lat0, lon0 = math.radians(48.78), math.radians(9.17)
    r0 = np.asarray(geodetic_to_ecef(lat0, lon0, 330.0))
    v_n = np.array([0.0, 20.0, 0.0])
    v_e = C_en(lat0, lon0) @ v_n
    r = r0 + (t - t[0])[:, None] * v_e
    return t, r, v_e


def test_generic_csv_with_10_bit_week_geodetic_ned_velocity_and_attitude(tmp_path):
    t, r, v_e = _track()
    lat, lon, h = ecef_to_geodetic(r)
    v_n = np.einsum("kji,j->ki", C_en(lat, lon), v_e)                    # NED velocity at each row
    csv = tmp_path / "sim.csv"
    with open(csv, "w") as fh:
        fh.write("# simulator output\nGpsWeek;Tow;Lat;Lon;H;VN;VE;VD;Roll;Pitch;Yaw\n")
        for k in range(t.size):
            fh.write(f"{2268 % 1024};{t[k]:.3f};{math.degrees(lat[k]):.10f};{math.degrees(lon[k]):.10f};"
                     f"{h[k]:.4f};{v_n[k, 0]:.6f};{v_n[k, 1]:.6f};{v_n[k, 2]:.6f};1.0;-2.0;90.0\n")
    spec = load_dataset_spec(_spec(tmp_path, 'format = "csv"\nfile = "sim.csv"\ndelimiter = ";"\n'
                                             '[truth.columns]\nweek = "GpsWeek"\ntow = "Tow"\nlat = "Lat"\n'
                                             'lon = "Lon"\nheight = "H"\nvn = "VN"\nve = "VE"\nvd = "VD"\n'
                                             'roll = "Roll"\npitch = "Pitch"\nyaw = "Yaw"\n'))
    tr = read_truth(spec.truth, 2268, None)                            # week 220 -> 2268 (two rollovers)
    np.testing.assert_allclose(tr.t, t, atol=1e-9)
    assert np.abs(tr.r_e - r).max() < 2e-3                                # 1e-10 deg ~ 1e-5 m, 1e-4 m height
    assert np.abs(tr.v_e - v_e).max() < 1e-5
    np.testing.assert_allclose(tr.rpy[0], np.radians([1.0, -2.0, 90.0]))
    # the same positions through navgym's own CSV
    own = tmp_path / "own.csv"
    write_truth_csv(own, 2268, t, r)
    tr2 = read_truth(TruthSpec("navgym-csv", own), 2268, None)
    np.testing.assert_allclose(tr2.t, tr.t) and np.testing.assert_allclose(tr2.r_e, tr.r_e, atol=2e-3)


def test_generic_csv_utc_ecef_and_leap_seconds(tmp_path):
    t, r, v_e = _track(10)
    gps_ns = (np.datetime64("1980-01-06", "ns") + np.int64(2268) * 604_800 * 10**9
              + (t * 1e9).astype(np.int64).astype("timedelta64[ns]"))
    utc = gps_ns - np.timedelta64(18, "s")                                 # 2023: GPS - UTC = 18 s
    csv = tmp_path / "utc.csv"
    csv.write_text("time,X,Y,Z,VX,VY,VZ\n" + "".join(
        f"{str(u).replace('T', ' ')}Z,{p[0]:.4f},{p[1]:.4f},{p[2]:.4f},{v_e[0]},{v_e[1]},{v_e[2]}\n"
        for u, p in zip(utc, r)))
    spec = load_dataset_spec(_spec(tmp_path, 'format = "csv"\nfile = "utc.csv"\n[truth.columns]\nutc = "time"\n'
                                             'x = "X"\ny = "Y"\nz = "Z"\nvx = "VX"\nvy = "VY"\nvz = "VZ"\n'))
    tr = read_truth(spec.truth, 2268, None)
    np.testing.assert_allclose(tr.t, t, atol=1e-6)
    assert np.abs(tr.r_e - r).max() < 1e-3 and np.allclose(tr.v_e, v_e) and tr.rpy is None
    # leap seconds: 17 s up to the end of 2016, 18 s from 2017-01-01 (GPS week 1930 starts 2017-01-01)
    w = 1929
    a = utc_to_gps_seconds(np.array(["2016-12-31T23:59:59", "2017-01-01T00:00:00"], "datetime64[ns]"), w)
    assert a[1] - a[0] == 2.0 and a[1] == 604800.0 + 18.0


def test_10_bit_week_resolution():
    np.testing.assert_array_equal(resolve_gps_week([220, 221], None, 2268), [2268, 2269])
    np.testing.assert_array_equal(resolve_gps_week([220], [2], 2268), [2268])
    np.testing.assert_array_equal(resolve_gps_week([2268], None, 2268), [2268])      # a full week as it is
    np.testing.assert_array_equal(resolve_gps_week([1023], None, 1024), [1023])      # across a rollover
    np.testing.assert_array_equal(resolve_gps_week([0], None, 1023), [1024])
    with pytest.raises(DatasetFormatError, match="more than one week"):
        resolve_gps_week([220], None, 2300)                               # no rollover puts 220 near 2300
    with pytest.raises(DatasetFormatError, match="more than one week"):
        resolve_gps_week([220], [1], 2268)                                # the cycle column says 1244


@pytest.mark.parametrize("cols, key, words", [
    ('tow = "t"\nlat = "a"\nlon = "b"\nheight = "c"\n', "truth.columns.week", "incomplete"),
    ('week = "w"\ntow = "t"\n', "truth.columns", "position columns are missing"),
    ('week = "w"\ntow = "t"\nutc = "u"\nx = "x"\ny = "y"\nz = "z"\n', "truth.columns", "not both"),
    ('week = "w"\ntow = "t"\nx = "x"\ny = "y"\nz = "z"\nspeed = "s"\n', "truth.columns.speed", "unknown role"),
    ('week = "w"\ntow = "t"\nx = "x"\ny = "y"\nz = "z"\nvn = "n"\n', "truth.columns.ve", "incomplete"),
])
def test_bad_column_maps_name_the_key(tmp_path, cols, key, words):
    with pytest.raises(DatasetSpecError, match=words) as ei:
        load_dataset_spec(_spec(tmp_path, 'format = "csv"\nfile = "f.csv"\n[truth.columns]\n' + cols))
    assert ei.value.key == key


def test_bad_csv_cells_name_file_line_and_column(tmp_path):
    t, r, _ = _track(6)
    body = "".join(f"2268,{tt},{p[0]},{p[1]},{p[2]}\n" for tt, p in zip(t, r))
    spec_txt = ('format = "csv"\nfile = "f.csv"\n[truth.columns]\nweek = "W"\ntow = "T"\nx = "X"\ny = "Y"\n'
                'z = "Z"\n')
    spec = load_dataset_spec(_spec(tmp_path, spec_txt))
    f = tmp_path / "f.csv"
    cases = [("W,T,X,Y,Zed\n" + body, 1, "'Z'.*not in the header"),
             ("W,T,X,Y,Z\n" + body.replace(f"{r[2][1]}", "abc", 1), 4, "'Y': 'abc' is not a number"),
             ("W,T,X,Y,Z\n" + body.replace(f"{t[3]}", "1e9", 1), 5, "'T': time of week"),
             ("W,T,X,Y,Z\n" + body.replace(f"{t[4]},", f"{t[2]},", 1), 6, "time does not increase"),
             ("W,T,X,Y,Z\n" + body[:-1], 7, "truncated")]
    for text, line, words in cases:
        f.write_text(text)
        with pytest.raises(DatasetFormatError, match=words) as ei:
            read_truth(spec.truth, 2268, None)
        assert ei.value.path == str(f) and ei.value.line == line, text[:40]


@needs_vn310
def test_vn310_gnss_log_through_the_column_map_is_the_static_truth(tmp_path):
    """The VN-310's own log (GpsCycle + 10-bit GpsWeek, lat/lon/alt, NED velocity): 166 fixes at 5 Hz over
    33 s in GPS week 2268; their mean is the instinct-reach-static truth (to its 1e-7 deg rounding)."""
    cols = ('[truth.columns]\nweek = "GpsWeek"\ntow = "GpsTow [s]"\nlat = "GNSS1::PosLla::latitude [deg]"\n'
            'lon = "GNSS1::PosLla::longitude [deg]"\nheight = "GNSS1::PosLla::altitude [m]"\n'
            'vn = "GNSS1::VelNed::N [m/s]"\nve = "GNSS1::VelNed::E [m/s]"\nvd = "GNSS1::VelNed::D [m/s]"\n')
    spec = load_dataset_spec(_spec(tmp_path, f'format = "csv"\nfile = "{VN310}"\n' + cols))
    tr = read_truth(spec.truth, 2268, None)
    assert tr.t.size == 166 and 385980.7 < tr.t[0] < tr.t[-1] < 386014.0
    with_cycle = load_dataset_spec(_spec(tmp_path, f'format = "csv"\nfile = "{VN310}"\n'
                                                   + cols + 'cycle = "GpsCycle"\n'))
    np.testing.assert_array_equal(read_truth(with_cycle.truth, 2268, None).t, tr.t)
    static = np.asarray(geodetic_to_ecef(*np.radians(STATIC_LLH[:2]), STATIC_LLH[2]))
    assert np.linalg.norm(tr.r_e.mean(0) - static) < 0.02
    assert np.abs(tr.v_e).max() < 0.5 and np.linalg.norm(tr.v_e.mean(0)) < 0.05    # static: receiver noise
    st = read_truth(TruthSpec("static", None, (("position_llh", STATIC_LLH),)), 2268, (385962.0, 386023.0))
    assert st.t[0] == 385962.0 and st.t[-1] == 386023.0 and np.all(st.r_e == st.r_e[0])
    assert np.linalg.norm(st.r_e[0] - static) < 1e-6 and not st.v_e.any()


@needs_vn310
def test_epochs_outside_the_truth_are_reported(tmp_path, capsys):
    pytest.importorskip("georinex")
    from envs.datasets.dataset_world import prepare_rinex
    p = tmp_path / "vn.toml"
    p.write_text(f'name = "vn-truth"\n[gnss]\nformat = "rinex"\nobs = "{REACH / "reach-m2-01_raw_202306291111.23O"}"'
                 f'\nnav = ["{REACH / "reach-m2-01_raw_202306291111.nav"}"]\ninterval_s = 1.0\n'
                 f'[truth]\nformat = "csv"\nfile = "{VN310}"\n[truth.columns]\nweek = "GpsWeek"\n'
                 f'cycle = "GpsCycle"\ntow = "GpsTow [s]"\nlat = "GNSS1::PosLla::latitude [deg]"\n'
                 f'lon = "GNSS1::PosLla::longitude [deg]"\nheight = "GNSS1::PosLla::altitude [m]"\n')
    rec = prepare_rinex(load_dataset_spec(p))
    t_gps = rec.epochs.t + rec.epochs.t0_gps
    inside = (t_gps >= rec.truth.t[0]) & (t_gps <= rec.truth.t[-1])
    err = capsys.readouterr().err
    assert f"{int((~inside).sum())} of {rec.epochs.n_epochs} observation epochs lie outside the truth's span" in err
    assert 20 < (~inside).sum() < 40                                       # 61 epochs, truth over 33 s
