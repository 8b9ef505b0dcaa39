"""Damaged copies of the recorded-data files (issue 13): every loader refuses them at load time with a
DatasetFormatError naming the file (and the line or record), never loading part of the data.

The copies are made in a tmp dir from ../shared/data (skipped with a reason when it is absent): truncated at
50% and 10% of the bytes, 64 random bytes or 64 printable garbage characters inserted, 16 bytes overwritten,
the other file type, empty; smartLoc also cut at a line end and with a duplicated line.
"""
import shutil
from pathlib import Path

import numpy as np
import pytest

from envs.datasets.errors import DatasetFormatError, shared_data_dir
from envs.datasets.rinex import load_nav, load_obs
from envs.datasets.smartloc import load_smartloc
from envs.datasets.truth_csv import load_truth_csv
from envs.datasets.validate import scan_rinex_nav, scan_rinex_obs

DATA = shared_data_dir()
REACH = DATA / "instinct_tckf_static"
OBS = REACH / "reach-m2-01_raw_202306291111.23O"
NAV = REACH / "reach-m2-01_raw_202306291111.nav"
SMARTLOC = DATA / "smartloc"
needs_reach = pytest.mark.skipif(not NAV.is_file(), reason=f"Reach M2 RINEX files not found in {REACH}")
needs_smartloc = pytest.mark.skipif(not (SMARTLOC / "Berlin_Potsdamer_Platz_Input.txt").is_file(),
                                    reason=f"smartLoc data not found in {SMARTLOC}")

GARBAGE = b"#@!garbage-line-noise~" * 3


def damage(data: bytes, how: str, other: bytes = b"") -> bytes:
    """The damaged bytes (positions fixed so that the expected line is known)."""
    rng = np.random.default_rng(13)
    mid = len(data) // 2 + 17  # inside a line
    if how == "truncated-50":
        return data[:len(data) // 2]
    if how == "truncated-10":
        return data[:len(data) // 10]
    if how == "inserted-random":
        return data[:mid] + bytes(rng.integers(128, 256, 64, dtype=np.uint8)) + data[mid:]
    if how == "inserted-ascii":
        return data[:mid] + GARBAGE[:64] + data[mid:]
    if how == "overwritten-random":
        return data[:mid] + bytes(rng.integers(128, 256, 16, dtype=np.uint8)) + data[mid + 16:]
    if how == "overwritten-ascii":
        return data[:mid] + GARBAGE[:16] + data[mid + 16:]
    if how == "other-type":
        return other
    if how == "empty":
        return b""
    raise ValueError(how)


DAMAGES = ("truncated-50", "truncated-10", "inserted-random", "inserted-ascii", "overwritten-random",
           "overwritten-ascii", "other-type", "empty")


def _expect(path, fn, *, line_required=True):
    with pytest.raises(DatasetFormatError) as e:
        fn()
    msg = str(e.value)
    assert msg.startswith(str(path)), msg
    assert e.value.path == str(path)
    if line_required:
        assert e.value.line is not None and f"{path}:{e.value.line}: " in msg, msg
    assert "\n" not in msg
    return e.value


@needs_reach
@pytest.mark.parametrize("how", DAMAGES)
def test_damaged_rinex_obs_is_refused_at_load_naming_file_and_line(tmp_path, how):
    p = tmp_path / OBS.name
    p.write_bytes(damage(OBS.read_bytes(), how, other=NAV.read_bytes()))
    err = _expect(p, lambda: load_obs(p), line_required=how != "empty")
    if how == "other-type":
        assert err.line == 1 and "a navigation file" in str(err)
    if how in ("inserted-random", "inserted-ascii", "overwritten-random", "overwritten-ascii"):
        n_before = OBS.read_bytes()[:len(OBS.read_bytes()) // 2 + 17].count(b"\n") + 1
        assert err.line == n_before, str(err)  # the damaged line itself


@needs_reach
@pytest.mark.parametrize("how", DAMAGES)
def test_damaged_rinex_nav_is_refused_at_load_naming_file_and_line(tmp_path, how):
    p = tmp_path / NAV.name
    p.write_bytes(damage(NAV.read_bytes(), how, other=OBS.read_bytes()))
    err = _expect(p, lambda: load_nav(p), line_required=how != "empty")
    if how == "other-type":
        assert err.line == 1 and "an observation file" in str(err)


@needs_reach
def test_rinex_structure_of_the_intact_files_matches_the_parser():
    """The scans of the shared files: 610 epochs of 0.1 s, the navigation records per system as georinex
    reads them (load_obs / load_nav compare the two on every load)."""
    obs = scan_rinex_obs(OBS)
    assert obs.epochs.size == 610 and np.allclose(np.diff(obs.epochs), 0.1, atol=1e-6)
    assert scan_rinex_nav(NAV).records == {"G": 11, "E": 15, "C": 8, "R": 10}


@needs_reach
def test_a_record_cut_between_lines_is_refused(tmp_path):
    """Cut at a line end inside an epoch record / a navigation record: the record announces more lines."""
    lines = OBS.read_bytes().split(b"\n")
    p = tmp_path / "cut.23O"
    p.write_bytes(b"\n".join(lines[:40]) + b"\n")  # epoch at line 26 announces 34 satellites
    err = _expect(p, lambda: load_obs(p))
    assert err.line == 26 and "announces 34 satellites, the file ends after 14" in str(err)
    nl = NAV.read_bytes().split(b"\n")
    q = tmp_path / "cut.nav"
    q.write_bytes(b"\n".join(nl[:14]) + b"\n")  # R18 record (line 13) with 1 of its 3 continuation lines
    err = _expect(q, lambda: load_nav(q))
    assert err.line == 13 and "1 of its 3 continuation lines" in str(err)


@needs_reach
def test_a_repeated_epoch_record_is_refused(tmp_path):
    lines = OBS.read_bytes().split(b"\n")
    rec = lines[25:25 + 35]  # line 26: the first epoch record (34 satellites)
    p = tmp_path / "dup.23O"
    p.write_bytes(b"\n".join(lines[:25 + 35] + rec + lines[25 + 35:]))
    err = _expect(p, lambda: load_obs(p))
    assert err.line == 61 and "does not increase" in str(err)


def _smartloc_copy(tmp_path, which: str, data: bytes) -> Path:
    d = tmp_path / "smartloc"
    shutil.copytree(SMARTLOC, d)
    p = d / f"Berlin_Potsdamer_Platz_{which}.txt"
    p.write_bytes(data)
    return p


@needs_smartloc
@pytest.mark.parametrize("which", ["Input", "GT"])
@pytest.mark.parametrize("how", DAMAGES + ("cut-at-line-end", "duplicated-line"))
def test_damaged_smartloc_is_refused_at_load_naming_file_and_line(tmp_path, which, how):
    src = SMARTLOC / f"Berlin_Potsdamer_Platz_{which}.txt"
    other = SMARTLOC / f"Berlin_Potsdamer_Platz_{'GT' if which == 'Input' else 'Input'}.txt"
    data = src.read_bytes()
    lines = data.split(b"\n")
    if how == "cut-at-line-end":
        bad = b"\n".join(lines[:len(lines) // 2]) + b"\n"
    elif how == "duplicated-line":
        k = len(lines) // 3
        bad = b"\n".join(lines[:k + 1] + [lines[k]] + lines[k + 1:])
    else:
        bad = damage(data, how, other=other.read_bytes())
    p = _smartloc_copy(tmp_path, which, bad)
    err = _expect(p, lambda: load_smartloc(p.parent), line_required=how != "empty")
    if how == "duplicated-line":
        assert err.line == len(lines) // 3 + 2 and ("repeats line" in str(err) or "increasing" in str(err)), str(err)
    if how == "cut-at-line-end":
        assert "truncated" in str(err)


@needs_reach
@pytest.mark.parametrize("how", DAMAGES)
def test_damaged_truth_csv_is_refused(tmp_path, how):
    good = tmp_path / "truth.csv"
    rows = [f"2268,{400000 + i}.0,4157198.0,671195.0,4774772.0" for i in range(10)]
    data = ("gps_week,tow_s,x_m,y_m,z_m\n" + "\n".join(rows) + "\n").encode()
    good.write_bytes(data)
    load_truth_csv(good, 2268)
    p = tmp_path / "bad.csv"
    p.write_bytes(damage(data, how, other=NAV.read_bytes()))
    with pytest.raises(DatasetFormatError) as e:
        load_truth_csv(p, 2268)
    assert str(e.value).startswith(str(p))


# ------------------------------------------------------------------ physically impossible values ("front door")
# A value changed in place keeps every file well-formed: 13 of 132 such copies replayed silently before (a
# pseudorange of 2.35e14 m to an RMSE of 3e13 m, exit status 0). Each must now be refused at load, naming the
# file, the line and the value (envs.datasets.plausibility), through the loaders eval.py, the envs and
# `python -m envs.datasets check` use (load_smartloc, prepare_rinex of a spec, read_imu_csv).
def _tokens(data: bytes, prefix: str, k: int, fn, frac: float = 0.4):
    """Token ``k`` (0: the row type) of the row ``prefix`` at ``frac`` of those rows replaced by ``fn(value)``."""
    lines = data.decode().split("\n")
    i = [j for j, ln in enumerate(lines) if ln.startswith(prefix)][int(frac * sum(ln.startswith(prefix)
                                                                                 for ln in lines))]
    t = lines[i].split()
    t[k] = repr(fn(float(t[k])))
    lines[i] = " ".join(t)
    return "\n".join(lines).encode(), i + 1


def _rotated_truth(data: bytes):
    """Every point3 row turned 0.5 rad about the Earth's axis: the same height, ~1,900 km away."""
    import math
    lines = data.decode().split("\n")
    c, s = math.cos(0.5), math.sin(0.5)
    for i, ln in enumerate(lines):
        if ln.startswith("point3"):
            t = ln.split()
            x, y = float(t[2]), float(t[3])
            t[2], t[3] = repr(c * x - s * y), repr(s * x + c * y)
            lines[i] = " ".join(t)
    return "\n".join(lines).encode(), 1


def _obs_field(data: bytes, k: int, fn):
    """Observation ``k`` (F14.3) of a GPS satellite line a fifth into the epochs replaced by ``fn(value)``."""
    lines = data.decode().split("\n")
    rows = [j for j, ln in enumerate(lines) if ln[:1] == "G" and ln[3 + 16 * k:17 + 16 * k].strip()]
    i = rows[len(rows) // 5]
    a = 3 + 16 * k
    lines[i] = lines[i][:a] + f"{fn(float(lines[i][a:a + 14])):14.3f}" + lines[i][a + 14:]
    return "\n".join(lines).encode(), i + 1


def _nav_field(data: bytes, k: int, f: int, value: float):
    """Field ``f`` of line ``k`` of the fourth GPS navigation record set to ``value`` (D19.12)."""
    import re
    lines = data.decode().split("\n")
    i = [j for j, ln in enumerate(lines) if re.match(r"^G\d\d ", ln)][3] + k
    a = 23 + 19 * f if k == 0 else 4 + 19 * f
    lines[i] = lines[i][:a] + f"{value:19.12E}" + lines[i][a + 19:]
    return "\n".join(lines).encode(), i + 1


def _imu_cell(data: bytes, column: str, value: float):
    lines = data.decode().split("\n")
    k = lines[0].split(",").index(column)
    i = len(lines) // 3
    cells = lines[i].split(",")
    cells[k] = repr(value)
    lines[i] = ",".join(cells)
    return "\n".join(lines).encode(), i + 1


VALUE_DAMAGES = [
    # (id, file, damage(bytes) -> (bytes, line), words of the message, the value it names)
    ("smartloc-pseudorange-x1e7", "Input", lambda d: _tokens(d, "pseudorange3", 2, lambda v: v * 1e7),
     "receiver clock bias beyond 299792 km", "pseudorange 2"),
    ("smartloc-pseudorange-+10000km", "Input", lambda d: _tokens(d, "pseudorange3", 2, lambda v: v + 1e7),
     "but the other pseudoranges of its epoch agree on", "is impossible"),
    ("smartloc-satellite-jump", "Input", lambda d: _tokens(d, "pseudorange3", 4, lambda v: v + 5e6),
     "moves 5000", "position ("),
    ("smartloc-cn0", "Input", lambda d: _tokens(d, "pseudorange3", 10, lambda v: 99.0), "C/N0 must be <= 80",
     "got 99.0"),
    ("smartloc-odometry-speed", "Input", lambda d: _tokens(d, "odom3", 2, lambda v: 5000.0),
     "odom3: velocity must be at most 1000 m/s", "got 5000.0"),
    ("smartloc-odometry-turn", "Input", lambda d: _tokens(d, "odom3", 7, lambda v: 50.0),
     "odom3: turn rate must be at most 10 rad/s", "got 50.0"),
    ("smartloc-truth-jump", "GT", lambda d: _tokens(d, "point3", 2, lambda v: v + 1e5),
     "the ground truth moves 99", "position ("),
    ("smartloc-truth-elsewhere", "GT", _rotated_truth, "from the recording's own single-point solution",
     "point3 rows from ("),
    ("reach-pseudorange-x10", "obs", lambda d: _obs_field(d, 0, lambda v: 10 * v),
     "but the other pseudoranges of the epoch agree on", "C1C pseudorange"),
    ("reach-pseudorange-+10000km", "obs", lambda d: _obs_field(d, 0, lambda v: v + 1e7),
     "but the other pseudoranges of the epoch agree on", "C1C pseudorange"),
    ("reach-doppler", "obs", lambda d: _obs_field(d, 2, lambda v: 1000 * v + 5e4), "receiver clock drift beyond",
     "D1C Doppler"),
    ("reach-nav-crs", "nav", lambda d: _nav_field(d, 1, 1, 1e7), "Crs [m] = 1e+07 is outside", "[-1024, 1024]"),
    ("reach-nav-sqrtA", "nav", lambda d: _nav_field(d, 2, 3, 1000.0), "sqrt(A) [sqrt(m)] = 1000", "[2530, 8192]"),
    ("reach-nav-e", "nav", lambda d: _nav_field(d, 2, 1, 0.9), "eccentricity e = 0.9", "[0, 0.03]"),
    ("reach-nav-af0", "nav", lambda d: _nav_field(d, 0, 0, 1.0), "SV clock bias af0 [s] = 1 is", "0.000976562"),
    ("reach-nav-toe", "nav", lambda d: _nav_field(d, 3, 0, 7e5), "Toe [s of week] = 700000", "[0, 604784]"),
    ("reach-nav-i0", "nav", lambda d: _nav_field(d, 4, 0, 4.0), "i0 [rad] = 4 is", "3.14159"),
    ("reach-nav-idot", "nav", lambda d: _nav_field(d, 5, 0, 1e-3), "IDOT [rad/s] = 0.001", "2.92584e-09"),
    ("reach-nav-cuc", "nav", lambda d: _nav_field(d, 2, 0, 0.1), "Cuc [rad] = 0.1", "6.10352e-05"),
    ("reach-nav-tgd", "nav", lambda d: _nav_field(d, 6, 2, 1e-3), "TGD / BGD [s] = 0.001", "5.96046e-08"),
    ("reach-nav-omega-dot", "nav", lambda d: _nav_field(d, 4, 3, 1e-3), "OMEGA DOT [rad/s] = 0.001", "2.99606e-06"),
    ("reach-nav-delta-n", "nav", lambda d: _nav_field(d, 1, 2, 1e-5), "Delta n [rad/s] = 1e-05", "1.17033e-08"),
    ("reach-static-truth-elsewhere", "spec", None, "from the recording's own single-point solution",
     "truth.position_llh = [78.7806647, 9.171496, 330.08]"),
    ("vn310-accel", "imu", lambda d: _imu_cell(d, "IMU::UncompAccel::Z [m/s^2]", 1.0e4),
     "beyond any navigation IMU's range", "10000.0"),
    ("vn310-gyro", "imu", lambda d: _imu_cell(d, "IMU::UncompGyro::X [rad/s]", 100.0),
     "beyond any navigation IMU's range", "100.0"),
]

REACH_SPEC_TEXT = """name = "reach-damaged"
[gnss]
format = "rinex"
obs = "{obs}"
nav = ["{nav}"]
systems = ["G"]
signals = {{ G = ["C1C"] }}
doppler = true
[truth]
format = "static"
position_llh = [{lat}, 9.1714960, 330.08]
[imu]
source = "synthesized"
"""


def _load_damaged(tmp_path, which: str, damage):
    """(the damaged file, its line, a loader) of one VALUE_DAMAGES row."""
    from envs.datasets.dataset_world import prepare_rinex
    from envs.datasets.spec import SPEC_DIR, load_dataset_spec
    if which in ("Input", "GT"):
        data, line = damage((SMARTLOC / f"Berlin_Potsdamer_Platz_{which}.txt").read_bytes())
        p = _smartloc_copy(tmp_path, which, data)
        return p, line, lambda: load_smartloc(p.parent)
    if which == "imu":
        from envs.datasets.recorded_imu import read_imu_csv
        src = REACH / "vn310-imu.csv"
        data, line = damage(src.read_bytes())
        p = tmp_path / src.name
        p.write_bytes(data)
        text = (SPEC_DIR / "instinct-reach-vn310.toml").read_text().replace("${NAVGYM_DATA_DIR}/instinct_tckf_static/"
                                                                            "vn310-imu.csv", str(p))
        (tmp_path / "s.toml").write_text(text.replace("${NAVGYM_DATA_DIR}", str(DATA)))
        spec = load_dataset_spec(tmp_path / "s.toml")
        return p, line, lambda: read_imu_csv(spec.imu, 2268)
    obs, nav, lat, line = OBS, NAV, 48.7806647, None
    if which in ("obs", "nav"):
        src = OBS if which == "obs" else NAV
        data, line = damage(src.read_bytes())
        p = tmp_path / src.name
        p.write_bytes(data)
        obs, nav = (p, NAV) if which == "obs" else (OBS, p)
    else:
        lat = 78.7806647                                    # 30 deg north: about 3,300 km from the receiver
    spec_path = tmp_path / "reach.toml"
    spec_path.write_text(REACH_SPEC_TEXT.format(obs=obs, nav=nav, lat=lat))
    if which == "spec":
        p, line = spec_path, 11                             # its position_llh line
    return p, line, lambda: prepare_rinex(load_dataset_spec(spec_path))


@pytest.mark.parametrize("which, damage, words, value", [v[1:] for v in VALUE_DAMAGES],
                         ids=[v[0] for v in VALUE_DAMAGES])
def test_an_impossible_value_is_refused_naming_file_line_and_value(tmp_path, which, damage, words, value):
    if which in ("Input", "GT") and not SMARTLOC.is_dir():
        pytest.skip(f"smartLoc data not found in {SMARTLOC}")
    if which not in ("Input", "GT") and not NAV.is_file():
        pytest.skip(f"Reach M2 RINEX files not found in {REACH}")
    path, line, load = _load_damaged(tmp_path, which, damage)
    err = _expect(path, load)
    assert err.line == line, str(err)
    assert words in str(err) and value in str(err), str(err)


@needs_reach
def test_check_names_the_file_of_an_impossible_ephemeris(tmp_path, capsys):
    """`python -m envs.datasets check` failed with "Singular matrix" on a Crs of 1e7 m, naming no file."""
    from envs.datasets.check import main
    path, line, _ = _load_damaged(tmp_path, "nav", lambda d: _nav_field(d, 1, 1, 1e7))
    assert main(["check", str(tmp_path / "reach.toml")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"check: error: {path}:{line}: G32 record: Crs [m] = 1e+07 is outside the range its ICD field "
                   "holds [-1024, 1024]: not a broadcast value"]


def test_the_shipped_recordings_are_plausible():
    """The bounds leave every shipped recording as it was (none of their values is refused)."""
    from envs.datasets.check import check_dataset
    from envs.datasets.spec import SHIPPED_SPECS, dataset_spec_of
    for name in SHIPPED_SPECS:
        spec = dataset_spec_of(name)
        if not spec.gnss.obs.is_file():
            pytest.skip(f"{spec.gnss.obs} not found")
        c = check_dataset(spec)
        assert c.spp_epochs > 0 and c.spp_h_p50_m < 100.0, (name, c)


@needs_smartloc
def test_the_env_refuses_an_impossible_value_naming_file_and_line(tmp_path, monkeypatch):
    import gymnasium as gym

    import envs  # noqa: F401
    data, line = _tokens((SMARTLOC / "Berlin_Potsdamer_Platz_Input.txt").read_bytes(), "pseudorange3", 2,
                         lambda v: v * 1e7)
    p = _smartloc_copy(tmp_path, "Input", data)
    monkeypatch.setenv("NAVGYM_DATA_DIR", str(tmp_path))
    env = gym.make("GnssIns/SageHusa-v1", scenario="smartloc-potsdamer-platz", episode_length_s=10.0)
    err = _expect(p, lambda: env.reset(seed=0))
    assert err.line == line and "receiver clock bias beyond" in str(err)
