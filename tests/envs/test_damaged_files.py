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
