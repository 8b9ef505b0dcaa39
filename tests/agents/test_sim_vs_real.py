"""Simulated urban channels against smartLoc (agents/sim_vs_real.py): the KS distance, the band split, the NLOS
runs, the extraction on a short simulated world and on the recording, the note."""
import numpy as np
import pytest
from scipy.stats import ks_2samp

from agents.sim_vs_real import (BANDS_DEG, FEATURES, LABEL_THRESHOLD_M, _row_dwells, band_index, calibration,
                                channel_sample,
                                cn0_fit, compare, feature_values, ks_distance, main, nlos_runs, separability)
from envs.datasets.errors import shared_data_dir
from envs.worlds import make_world

SMARTLOC = shared_data_dir() / "smartloc" / "Berlin_Potsdamer_Platz_Input.txt"
needs_smartloc = pytest.mark.skipif(not SMARTLOC.is_file(), reason=f"smartLoc recording not found at {SMARTLOC} "
                                                                   "(../shared/data or NAVGYM_DATA_DIR)")


def test_ks_distance_is_scipys_and_bounded():
    rng = np.random.default_rng(0)
    for a, b in ((rng.normal(size=300), rng.normal(0.3, 2.0, size=170)),
                 (rng.integers(20, 50, 400).astype(float), rng.integers(25, 45, 90).astype(float))):   # ties
        assert ks_distance(a, b) == pytest.approx(ks_2samp(a, b).statistic, abs=1e-12)
    x = rng.normal(size=50)
    assert ks_distance(x, x.copy()) == 0.0
    assert ks_distance(x, x + 100.0) == 1.0
    assert np.isnan(ks_distance(x, []))
    assert ks_distance([0, 0, 1, 1], [0, 1, 1, 1]) == pytest.approx(0.25)   # 0/1: the difference of the shares


def test_band_split():
    el = np.array([-1.0, 0.0, 14.99, 15.0, 30.0, 44.9, 45.0, 89.0, 90.0, 91.0])
    np.testing.assert_array_equal(band_index(el), [-1, 0, 0, 1, 2, 2, 3, 3, 3, -1])
    assert band_index(np.zeros((2, 3))).shape == (2, 3)
    assert len(BANDS_DEG) == 4


def test_nlos_runs_on_a_hand_made_sequence():
    present = np.array([1, 1, 1, 1, 0, 1, 1, 1, 1, 1, 1], bool)
    nlos = np.array([1, 1, 0, 1, 1, 1, 0, 1, 1, 1, 1], bool)   # index 4: NLOS flag but not tracked: ends a run
    starts, lengths = nlos_runs(present, nlos)
    np.testing.assert_array_equal(starts, [0, 3, 5, 7])
    np.testing.assert_array_equal(lengths, [2, 1, 1, 4])   # the last run is cut by the end and counts as it is
    assert nlos_runs(np.ones(3, bool), np.zeros(3, bool))[0].size == 0


def test_dwell_follows_the_satellite_across_channels():
    """A satellite moving from channel 0 to channel 1 stays one run; runs of two satellites are separate."""
    prn = np.array([[5, 7], [5, 7], [7, 5], [7, 5], [7, 5]])
    mask = np.ones((5, 2), bool)
    nlos = np.array([[1, 0], [1, 1], [1, 1], [0, 0], [0, 1]], bool)   # prn 5: epochs 0-2 and 4; prn 7: 1-2
    el = np.full((5, 2), 20.0)
    el[:, 1] = 50.0
    dur, elev = _row_dwells(prn, mask, nlos, el, 0.5)
    assert sorted(zip(dur, elev)) == sorted([(1.5, (20 + 20 + 50) / 3), (0.5, 50.0), (1.0, (50 + 20) / 2)])


def test_cn0_fit_recovers_a_line():
    el = np.linspace(5, 85, 50)
    a, b = cn0_fit(el, 38.0 + 7.0 * np.sin(np.radians(el)))
    assert (a, b) == (pytest.approx(38.0), pytest.approx(7.0))


@pytest.fixture(scope="module")
def short_urban():
    world = make_world("urban", [1, 2], duration_s=45.0)
    return world, channel_sample(world)


def test_extraction_on_a_short_simulated_world(short_urban):
    """Every valid channel-epoch is taken; the label is the simulator's flag (its NLOS share); the epoch counts are
    the mask's; every NLOS channel-epoch lies in exactly one run."""
    world, s = short_urban
    g = world.gnss
    assert s.nlos.size == g.mask.sum() and s.true_error_m is not None and s.systems == ("G",)
    assert s.nlos.mean() == pytest.approx(g.nlos[g.mask].mean()) and 0 < s.nlos.mean() < 1
    np.testing.assert_array_equal(s.sats_per_epoch[:, -1], g.mask.sum(-1).ravel())
    np.testing.assert_array_equal(s.sats_per_epoch[:, :-1].sum(1), s.sats_per_epoch[:, -1])   # 15 deg mask
    assert s.epoch_s == 1.0 and s.dwell_s.sum() == pytest.approx(s.nlos.sum() * s.epoch_s)
    np.testing.assert_allclose(np.sort(s.cn0_dbhz), np.sort(g.cn0_dbhz[g.mask]))
    assert np.median(np.abs(s.residual_m - s.true_error_m)) < 2.0   # the robust clock finds the true one
    assert feature_values(s, "nlos_share", None).mean() == pytest.approx(s.nlos.mean())


def test_compare_rows_against_itself(short_urban):
    """A sample against itself: every distance 0 where both sides hold values; one row per feature and band."""
    _, s = short_urban
    rows = compare(s, s)
    assert len(rows) == len(FEATURES) * (len(BANDS_DEG) + 1)
    assert all(r["ks"] == 0.0 or (r["sim"][0] == 0 and np.isnan(r["ks"])) for r in rows)
    assert separability(s, None) > 0.9   # the simulator's NLOS C/N0 deficit is nearly a perfect separator
    with pytest.raises(ValueError, match="unknown feature"):
        feature_values(s, "nope", None)


@needs_smartloc
def test_extraction_on_smartloc():
    world = make_world("smartloc-potsdamer-platz", [0])
    s = channel_sample(world, "smartloc")
    assert s.true_error_m is None and s.systems == ("G", "R") and s.sats_per_epoch.shape[0] == world.gnss.t.size
    assert s.nlos.size == 20038
    np.testing.assert_array_equal(s.nlos, np.abs(s.residual_m) > LABEL_THRESHOLD_M)
    assert s.epoch_s == pytest.approx(0.2, abs=1e-3)


def test_main_rejects_bad_arguments_and_missing_data(monkeypatch, tmp_path):
    with pytest.raises(SystemExit, match="--seeds must be >= 1"):
        main(["--seeds", "0"])
    monkeypatch.setenv("NAVGYM_DATA_DIR", str(tmp_path))
    with pytest.raises(SystemExit, match="smartLoc recording is not in"):
        main(["--out", str(tmp_path / "x.md")])
    assert not (tmp_path / "x.md").exists()


@needs_smartloc
def test_main_writes_the_note(tmp_path):
    out = tmp_path / "note.md"
    main(["--seeds", "1", "--seed", "3", "--out", str(out)])
    text = out.read_text()
    assert text.startswith("# Simulated urban channels against smartLoc")
    assert "--seeds 1 --seed 3" in text and "## urban vs smartLoc" in text and "## urban-transition vs smartLoc" in text
    assert text.count("| C/N0, LOS [dB-Hz] |") == 3 * (len(BANDS_DEG) + 1)
    assert "## urban-smartloc vs smartLoc" in text and "## Calibration of `urban-smartloc`" in text


@needs_smartloc
def test_urban_smartloc_constants_are_the_measured_calibration():
    """envs.sim.events.SMARTLOC3_* are the recording's figures (agents.sim_vs_real.calibration), rounded."""
    from envs.sim import events as ev
    cal = calibration(make_world("smartloc-potsdamer-platz", [0]))
    np.testing.assert_allclose(cal["p_nlos"], ev.SMARTLOC3_P_NLOS, atol=0.006)
    assert cal["bias"][0] == pytest.approx(ev.SMARTLOC3_BIAS[0], abs=0.06)
    assert cal["bias"][1] == pytest.approx(ev.SMARTLOC3_BIAS[1], abs=0.006)
    c = ev.SMARTLOC3_CN0
    los_std = np.sqrt(c["offset_sigma_db"] ** 2 + c["gm_sigma_db"] ** 2 + c["white_sigma_db"] ** 2)
    assert los_std == pytest.approx(cal["los_std"], abs=0.1)
    for lag, want in cal["acf"].items():   # the model's autocorrelation at each lag, within 0.05
        model = (c["offset_sigma_db"] ** 2 + c["gm_sigma_db"] ** 2 * np.exp(-lag / c["gm_tau_s"])) / los_std ** 2
        assert model == pytest.approx(want, abs=0.05), lag
    assert c["nlos_deficit_db"] == pytest.approx(-cal["nlos_mean"], abs=0.06)
    assert np.hypot(los_std, c["nlos_deficit_sigma_db"]) == pytest.approx(cal["nlos_std"], abs=0.1)
    lo, hi = ev.SMARTLOC3_SEGMENT_S
    stay = 1.0 - (1.0 - cal["share"]) / (0.5 * (lo + hi))    # independent segments, mean length (lo + hi) / 2
    assert stay == pytest.approx(cal["stay"], abs=0.02)


def test_urban_smartloc_reproduces_the_calibration_it_was_built_from():
    """A simulated urban-smartloc world shows the recording's figures it was built from: NLOS share, how long
    NLOS lasts, the LOS C/N0 scatter and its autocorrelation, the C/N0 separability (8 full episodes)."""
    from envs.sim import events as ev
    s = channel_sample(make_world("urban-smartloc", list(range(8))), "urban-smartloc")
    assert 0.55 < s.nlos.mean() < 0.75                      # smartLoc 0.70 with its 3 m label
    r = s.cn0_dbhz[~s.nlos] - ev.cn0_los(np.radians(s.elevation_deg[~s.nlos]))
    assert 4.0 < r.std() < 5.0                              # smartLoc 4.5 dB
    assert 0.40 < separability(s, None) < 0.65              # smartLoc 0.52; urban 1.00
    assert 3.0 < np.median(s.dwell_s) < 12.0 and 5.0 < s.sats_per_epoch[:, -1].mean() < 9.0
