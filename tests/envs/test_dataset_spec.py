"""Dataset spec files (issue 12): loading and validation, routing through make_world / EnvConfig / eval.py,
multiple navigation files, and the no-silent-drop rules.

Tests that read ``../shared/data`` skip with a reason when it is absent (a fresh clone); the validation tests
use specs written to a temporary folder and always run.
"""
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from envs.datasets.errors import shared_data_dir
from envs.datasets.spec import (SHIPPED_SPECS, SPEC_DIR, DatasetSpecError, ReplayScenario, dataset_spec_of,
                                load_dataset_spec)

DATA = shared_data_dir()
REACH = DATA / "instinct_tckf_static"
OBS = REACH / "reach-m2-01_raw_202306291111.23O"
NAV = REACH / "reach-m2-01_raw_202306291111.nav"
needs_smartloc = pytest.mark.skipif(not (DATA / "smartloc" / "Berlin_Potsdamer_Platz_Input.txt").is_file(),
                                    reason=f"smartLoc data not found in {DATA / 'smartloc'} (../shared/data is "
                                           f"absent in a fresh clone; CI has it)")
needs_reach = pytest.mark.skipif(not NAV.is_file(), reason=f"Reach M2 RINEX files not found in {REACH} "
                                                           f"(../shared/data is absent in a fresh clone)")

REACH_SPEC = """
name = "{name}"
[gnss]
format = "rinex"
obs = "{obs}"
nav = [{nav}]
systems = {systems}
interval_s = 1.0
{gnss_extra}
[corrections]
iono = {iono}
tropo = true
[truth]
format = "static"
position_llh = [48.7806647, 9.1714960, 330.08]
"""


def reach_spec(folder: Path, name="reach-test", obs=None, nav=None, systems='["G"]', iono="true",
               gnss_extra="") -> Path:
    nav = nav or [NAV]
    text = REACH_SPEC.format(name=name, obs=obs or OBS, nav=", ".join(f'"{p}"' for p in nav), systems=systems,
                             iono=iono, gnss_extra=gnss_extra)
    p = folder / f"{name}.toml"
    p.write_text(text)
    return p


# ------------------------------------------------------------------------------------------------ the spec
def test_shipped_specs_load_and_resolve_into_the_data_folder(monkeypatch, tmp_path):
    from envs.worlds import REPLAY_SCENARIOS, scenario_names
    assert REPLAY_SCENARIOS == tuple(SHIPPED_SPECS) and set(SHIPPED_SPECS) <= set(scenario_names())
    for name, file in SHIPPED_SPECS.items():
        spec = load_dataset_spec(SPEC_DIR / file)
        assert spec.name == name and spec.gnss.obs.is_absolute()
        assert spec.gnss.obs.parent.parent == shared_data_dir().resolve()
        assert dataset_spec_of(name) == spec
    s = load_dataset_spec(SPEC_DIR / SHIPPED_SPECS["instinct-reach-static"])
    assert s.gnss.format == "rinex" and s.gnss.systems == ("G",) and s.gnss.signals == (("G", ("C1C",)),)
    assert s.truth.format == "static" and s.corrections.iono and s.imu.grade == "industrial"
    monkeypatch.setenv("NAVGYM_DATA_DIR", str(tmp_path))           # the variable moves every path
    moved = load_dataset_spec(SPEC_DIR / SHIPPED_SPECS["instinct-reach-static"])
    assert moved.gnss.obs == tmp_path / "instinct_tckf_static" / s.gnss.obs.name
    assert moved.gnss.nav == (tmp_path / "instinct_tckf_static" / s.gnss.nav[0].name,)


def test_spec_round_trip_relative_paths_and_defaults(tmp_path):
    (tmp_path / "sub").mkdir()
    p = tmp_path / "sub" / "mine.toml"
    p.write_text('name = "mine"\n[gnss]\nformat = "rinex"\nobs = "../a.24O"\nnav = "b.24N"\n'
                 'systems = ["G", "E"]\nsignals = { E = ["C1C"] }\n'
                 '[truth]\nformat = "navgym-csv"\nfile = "t.csv"\n[imu]\ngrade = "consumer"\nrate_hz = 200\n')
    s = load_dataset_spec(p)
    assert s.gnss.obs == (tmp_path / "a.24O").resolve() and s.gnss.nav == ((tmp_path / "sub" / "b.24N"),)
    assert s.truth.file == tmp_path / "sub" / "t.csv"
    assert dict(s.gnss.signals) == {"G": ("C1C",), "E": ("C1C",)}              # G: the default code
    assert (s.gnss.elevation_mask_deg, s.gnss.sigma0_m, s.gnss.interval_s) == (10.0, 1.5, None)
    assert s.corrections.iono and s.corrections.tropo and (s.imu.grade, s.imu.rate_hz) == ("consumer", 200.0)
    assert load_dataset_spec(p) == s and hash(load_dataset_spec(p)) == hash(s)       # frozen, hashable
    sc = s.scenario(duration_s=30.0)
    assert isinstance(sc, ReplayScenario) and sc.dataset is s and sc.duration_s == 30.0
    assert sc.imu_rate_hz == 200.0 and sc.imu_grade == "consumer" and sc.name == "mine"


BASE = ('name = "x"\n[gnss]\nformat = "rinex"\nobs = "o.24O"\nnav = ["n.24N"]\n{gnss}\n'
        '[truth]\nformat = "static"\nposition_ecef = [4157198.4, 671195.1, 4774772.0]\n{rest}')


@pytest.mark.parametrize("gnss, rest, key, words", [
    ("", "[extra]\n", "extra", "unknown key"),
    ("colour = 1", "", "gnss.colour", "unknown key"),
    ('systems = ["G", "R"]', "", "gnss.systems", "GLONASS"),
    ('systems = ["G", "G"]', "", "gnss.systems", "twice"),
    ('elevation_mask_deg = "ten"', "", "gnss.elevation_mask_deg", "finite number"),
    ("sigma0_m = 0", "", "gnss.sigma0_m", "> 0"),
    ('signals = { G = ["C5Q"] }', "", "gnss.signals.G", "band 1"),
    ('signals = { G = ["L1C"] }', "", "gnss.signals.G", "code observable"),
    ('signals = { E = ["C1C"] }', "", "gnss.signals.E", "not in gnss.systems"),
    ("", '[imu]\nsource = "recorded"\n', "imu.grade", "data-sheet grade"),
    ("", '[imu]\nfile = "imu.csv"\n', "imu.file", "recorded IMU only"),
    ("", '[imu]\ngrade = "magic"\n', "imu.grade", "must be one of"),
    ("", '[corrections]\niono = "yes"\n', "corrections.iono", "true or false"),
])
def test_bad_spec_names_the_file_and_the_key(tmp_path, gnss, rest, key, words):
    p = tmp_path / "bad.toml"
    p.write_text(BASE.format(gnss=gnss, rest=rest))
    with pytest.raises(DatasetSpecError, match=words) as ei:
        load_dataset_spec(p)
    assert ei.value.key == key and str(ei.value).startswith(f"{p}: {key}: ")


@pytest.mark.parametrize("text, key", [
    ('name = "x"\n[truth]\nformat = "static"\n', "gnss"),
    ('name = "a b"\n', "name"),
    ('name = "x"\n[gnss]\nformat = "rinex"\nobs = "o"\nnav = []\n', "gnss.nav"),
    ('name = "x"\n[gnss]\nformat = "rinex"\nobs = "o"\nnav = ["n"]\n[truth]\nformat = "gpx"\n', "truth.format"),
    ('name = "x"\n[gnss]\nformat = "rinex"\nobs = "o"\nnav = ["n"]\n[truth]\nformat = "static"\n'
     'position_llh = [1, 2, 3]\nposition_ecef = [1, 2, 3]\n', "truth.position_ecef"),
    ('name = "x"\n[gnss]\nformat = "smartloc"\nobs = "a_Input.txt"\nnav = ["n"]\n', "gnss.nav"),
    ('name = "x"\n[gnss]\nformat = "smartloc"\nobs = "a_Input.txt"\n[truth]\nformat = "smartloc"\n'
     'file = "b_GT.txt"\n', "truth.file"),
    ('name = "x"\n[gnss]\nformat = "rinex"\nobs = "${HOME}/o"\nnav = ["n"]\n', "gnss.obs"),
    ('name = = "x"\n', "(syntax)"),
])
def test_bad_spec_sections(tmp_path, text, key):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(DatasetSpecError) as ei:
        load_dataset_spec(p)
    assert ei.value.key == key and str(p) in str(ei.value)


def test_missing_spec_file_and_plain_replay_scenario_refused(tmp_path):
    from envs.sim.scenarios import get_scenario
    from envs.worlds import make_world
    with pytest.raises(FileNotFoundError, match="nope.toml"):
        make_world(str(tmp_path / "nope.toml"), [1])
    # a plain Scenario that describes a recording would build a simulated world: refused
    fake = get_scenario("urban").replace(name="smartloc-potsdamer-platz")
    with pytest.raises(ValueError, match="simulated world"):
        make_world(fake, [1])
    from envs.config import EnvConfig
    with pytest.raises(ValueError, match="EnvConfig.scenario"):
        EnvConfig(scenario=fake)
    # a ReplayScenario handed to the simulator itself is refused too
    from envs.sim.world import generate_world
    replay = load_dataset_spec(SPEC_DIR / SHIPPED_SPECS["instinct-reach-static"]).scenario(duration_s=10.0)
    with pytest.raises(ValueError, match="replays a recorded data set"):
        generate_world(replay, [1])


# ------------------------------------------------------------------------------------- worlds from specs
def _assert_worlds_equal(a, b):
    for part in ("truth", "imu", "gnss", "init"):
        pa, pb = getattr(a, part), getattr(b, part)
        for f in dataclasses.fields(pa):
            x, y = getattr(pa, f.name), getattr(pb, f.name)
            if isinstance(x, np.ndarray):
                np.testing.assert_array_equal(x, y, err_msg=f"{part}.{f.name}")
    np.testing.assert_array_equal(a.epoch_idx, b.epoch_idx)


@needs_smartloc
def test_smartloc_spec_world_equals_the_direct_loader():
    """The shipped smartLoc spec through make_world (and through its ReplayScenario, and EnvConfig) gives
    the very numbers of load_smartloc_world with the same seeds."""
    from envs.config import EnvConfig
    from envs.datasets.replay import load_smartloc_world
    from envs.worlds import make_world
    direct = load_smartloc_world([4, 9], duration_s=60.0)
    by_name = make_world("smartloc-potsdamer-platz", [4, 9], duration_s=60.0)
    _assert_worlds_equal(direct, by_name)
    assert isinstance(by_name.scenario, ReplayScenario) and by_name.scenario.name == "smartloc-potsdamer-platz"
    assert by_name.scenario.duration_s == direct.scenario.duration_s
    _assert_worlds_equal(direct, make_world(by_name.scenario, [4, 9]))          # the scenario replays it
    cfg = EnvConfig(scenario=str(SPEC_DIR / "smartloc-potsdamer-platz.toml"), episode_length_s=60.0)
    assert isinstance(cfg.resolve_scenario(), ReplayScenario)
    _assert_worlds_equal(direct, cfg.make_world([4, 9]))
    assert by_name.gnss.pr_var_true is None                                     # recorded, not simulated


@needs_reach
def test_reach_spec_through_eval_and_gym(tmp_path, capsys):
    pytest.importorskip("georinex")
    import gymnasium as gym

    import envs  # noqa: F401  (registers the ids)
    import eval as eval_cli
    spec = reach_spec(tmp_path, name="reach-eval")
    res = eval_cli.main(["--scenario", str(spec), "--methods", "kf", "--episodes", "1", "--out",
                         str(tmp_path / "out"), "--no-plots"])
    row = res["scenarios"]["reach-eval"]["kf"]
    assert row["episodes"] == 1 and 0.5 < row["rmse_h_m"] < 15.0               # measured 4.4 m (GPS, 1 Hz)
    assert (tmp_path / "out" / "results.json").is_file()
    err = capsys.readouterr().err
    assert "GPS: 1 of 11 satellites observed have no healthy ephemeris" in err and "(G22)" in err
    env = gym.make("GnssIns/SageHusa-v1", scenario=str(spec), episode_length_s=20.0)
    obs, _ = env.reset(seed=3)
    assert isinstance(env.unwrapped.config.resolve_scenario(), ReplayScenario)
    for _ in range(3):
        obs, r, term, trunc, _ = env.step(env.action_space.sample())
        assert np.isfinite(r) and -20.0 < r <= 0.0
    with pytest.raises(SystemExit):
        eval_cli.main(["--scenario", str(spec), "--scenario", str(spec), "--methods", "kf", "--out",
                       str(tmp_path / "o2")])
    assert "given twice" in capsys.readouterr().err


# ----------------------------------------------------------------------- several nav files, silent drops
def _split_nav(folder: Path) -> dict:
    """The Reach nav file split into one file per system (GPS keeps the Klobuchar header lines)."""
    lines = NAV.read_text().splitlines(keepends=True)
    end = next(i for i, ln in enumerate(lines) if "END OF HEADER" in ln) + 1
    head, body = lines[:end], lines[end:]
    recs, cur = {}, None
    for ln in body:
        if ln[:1].strip():
            cur = ln[0]
        recs.setdefault(cur, []).append(ln)
    out = {}
    for letter, rl in recs.items():
        h = [ln for ln in head if letter == "G" or "IONOSPHERIC CORR" not in ln or ln.startswith("GAL")]
        p = folder / f"reach_{letter}.nav"
        p.write_text("".join(h + rl))
        out[letter] = p
    return out


@needs_reach
def test_several_nav_files_merge_to_the_mixed_one(tmp_path):
    pytest.importorskip("georinex")
    from envs.datasets.nav_merge import merge_nav
    from envs.datasets.rinex import load_nav
    parts = _split_nav(tmp_path)
    assert set(parts) == {"G", "R", "E", "C"}
    whole = load_nav(NAV, week_ref=2268)
    navs = [load_nav(parts[k], week_ref=2268) for k in ("E", "C", "G", "R")]
    assert navs[0].iono_alpha is None                              # a Galileo file has no Klobuchar
    merged = merge_nav(navs + [navs[2]])                           # a repeated file adds nothing
    key = lambda e: sorted(zip(e.system, e.prn, e.toe, e.af0))     # noqa: E731
    assert merged.ephemeris.size == whole.ephemeris.size == 34 and key(merged.ephemeris) == key(whole.ephemeris)
    np.testing.assert_array_equal(merged.iono_alpha, whole.iono_alpha)
    assert any("GLONASS" in s for s in merged.skipped)
    with pytest.raises(ValueError, match="different GPS weeks"):
        merge_nav([navs[0], load_nav(parts["G"], week_ref=2267)])


@needs_reach
@pytest.mark.filterwarnings("error::RuntimeWarning")  # a missing signal is our error, not a numpy warning
def test_galileo_with_its_own_nav_file_and_every_drop_rule(tmp_path, capsys):
    """GPS + Galileo from two nav files replays with both systems; a system without ephemeris, a missing
    Klobuchar model and a missing signal are errors; a satellite without ephemeris is one printed line."""
    pytest.importorskip("georinex")
    from envs.datasets.dataset_world import prepare_rinex
    parts = _split_nav(tmp_path)
    ok = load_dataset_spec(reach_spec(tmp_path, "two-navs", nav=[parts["G"], parts["E"]], systems='["G", "E"]'))
    rec = prepare_rinex(ok)
    used = {int(s) for s in np.unique(rec.epochs.system[rec.epochs.mask])}
    assert used == {1, 8} and "reach_G.nav + reach_E.nav" in rec.epochs.source
    assert "(G22)" in capsys.readouterr().err                                     # printed once
    prepare_rinex(ok)
    assert capsys.readouterr().err == ""                                          # memoized: not again
    # Galileo observed, only the GPS nav file: error naming the system and the files
    gal = load_dataset_spec(reach_spec(tmp_path, "no-gal-eph", nav=[parts["G"]], systems='["G", "E"]'))
    with pytest.raises(ValueError, match=r"Galileo: \d+ satellites observed but no Galileo ephemeris.*reach_G.nav"):
        prepare_rinex(gal)
    # a Galileo nav file only, ionosphere on: no Klobuchar model -> error; off -> it runs
    noiono = load_dataset_spec(reach_spec(tmp_path, "no-klob", nav=[parts["E"]], systems='["E"]'))
    with pytest.raises(ValueError, match="Klobuchar.*corrections.iono = false"):
        prepare_rinex(noiono)
    off = load_dataset_spec(reach_spec(tmp_path, "no-klob-off", nav=[parts["E"]], systems='["E"]', iono="false"))
    assert prepare_rinex(off).epochs.mask.any()
    # a signal the file does not have: every GPS satellite lacks it -> error naming the system
    nosig = load_dataset_spec(reach_spec(tmp_path, "no-sig", gnss_extra='signals = { G = ["C1W"] }'))
    with pytest.raises(ValueError, match="no GPS satellite with a C1W observation"):
        prepare_rinex(nosig)
    assert "GPS: 11 satellites observed without C1W: dropped" in capsys.readouterr().err


def test_a_spec_without_imu_section_says_the_default_it_takes_once(tmp_path, capsys):
    """The [imu] section decides the filter's process noise: its absence is a documented default, said in one line
    (once per spec file and process), never taken silently; a spec with the section says nothing."""
    from envs.datasets.spec import ImuSpec
    p = tmp_path / "noimu.toml"
    p.write_text(BASE.format(gnss="", rest=""))
    s = load_dataset_spec(p)
    load_dataset_spec(p)
    err = capsys.readouterr().err.strip().splitlines()
    assert s.imu == ImuSpec() and len(err) == 1, err
    assert err[0] == (f"navgym dataset x: {p.resolve()} has no [imu] section: the IMU is synthesized from the truth, "
                      "industrial grade at 100 Hz (the documented default; add an [imu] section to choose)")
    q = tmp_path / "withimu.toml"
    q.write_text(BASE.format(gnss="", rest='[imu]\ngrade = "industrial"\n'))
    assert load_dataset_spec(q).imu == s.imu and capsys.readouterr().err == ""
