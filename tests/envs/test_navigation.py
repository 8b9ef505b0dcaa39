"""The foundation's acceptance properties: the simulated world and the tightly coupled navigator together.

Integration scheme under test: the IMU samples are interval means (Simpson
quadrature of the analytic trajectory); the ECEF mechanization rotates the
attitude by the exact Earth-rate matrix and ``exp_so3(w dt)``, resolves the
velocity increment at the mid-interval attitude, evaluates gravity and Coriolis
at predicted midpoints and integrates position by the trapezoid rule
(:func:`nav_filters.ins.mechanize`).
"""
import numpy as np
import pytest
from scipy.stats import chi2

from envs.episodes import run_episodes
from envs.metrics import summarize
from envs.sim.gnss import GnssEvents, ReceiverConfig
from envs.sim.imu import IMU_GRADES, Vibration
from envs.sim.rng import row_generators
from envs.sim.scenarios import Scenario, get_scenario
from envs.sim.trajectory import generate_truth
from envs.sim.world import generate_world
from nav_filters.ins import mechanize


def test_perfect_imu_keeps_the_ins_on_the_truth_for_600_s():
    """Noise- and bias-free IMU on the seed003-sim motion (and an urban drive): < 0.5 m after 600 s."""
    motions = [get_scenario("seed003-sim").drive] + get_scenario("urban").motions(row_generators([3], "trajectory"))
    tr = generate_truth(motions, 600.0, 100.0)
    r, v, C = tr.r_e[:, 0].copy(), tr.v_e[:, 0].copy(), tr.C_eb[:, 0].copy()
    worst = 0.0
    for k in range(1, tr.t.size):
        r, v, C = mechanize(r, v, C, tr.f_b[:, k], tr.w_b[:, k], 0.01)
        if k % 1000 == 0:
            worst = max(worst, np.linalg.norm(r - tr.r_e[:, k], axis=1).max())
    assert tr.speed[0].mean() * 600 > 5000  # it really drove: > 5 km with turns, stops, accelerations
    assert worst < 0.5
    assert np.abs(v - tr.v_e[:, -1]).max() < 1e-3


def test_open_sky_industrial_rmse_band():
    w = generate_world("open-sky", [11, 12, 13, 14])
    s = summarize(run_episodes(w, "kf"))
    assert w.scenario.imu_grade == "industrial" and w.scenario.duration_s == 300
    assert 0.5 <= s["rmse_h_m"] <= 3.0, s
    assert s["diverged"] == 0


def _end_of_outage_error(grade, seeds):
    scen = get_scenario("outage", imu_grade=grade, duration_s=140.0, events=GnssEvents(outages=((60.0, 120.0),)))
    log = run_episodes(generate_world(scen, seeds), "kf")
    h = log.horizontal_error
    i_end = np.searchsorted(log.t, 120.0) - 1  # last epoch inside the outage
    i_rec = np.searchsorted(log.t, 135.0)     # 15 s after it
    assert log.n_used[:, i_end].sum() == 0 and log.n_used[:, i_rec].min() > 0
    return np.median(h[:, i_end]), np.median(h[:, i_rec]), np.median(h[:, np.searchsorted(log.t, 55.0)])


def test_outage_drift_matches_the_imu_grade_and_recovers():
    seeds = list(range(100, 108))
    tac_end, tac_rec, tac_before = _end_of_outage_error("tactical", seeds)
    con_end, con_rec, _ = _end_of_outage_error("consumer", seeds)
    assert tac_end < 10.0, tac_end
    assert con_end > 3 * tac_end, (con_end, tac_end)
    assert tac_end > 2 * tac_before  # the outage really drifts
    for rec in (tac_rec, con_rec):  # recovered to the open-sky level 15 s after the outage
        assert rec < 3.0, rec


def test_nees_and_nis_consistent_in_a_matched_scenario():
    """20 Monte Carlo runs where the filter's model is the truth's: ANEES and NIS inside 95% chi-square bands."""
    g = IMU_GRADES["tactical"]
    scen = get_scenario("open-sky", duration_s=120.0, imu_grade="tactical", vibration=Vibration.none(),
                        receiver=ReceiverConfig(tropo_zenith_sigma_m=0.0, iono_zenith_sigma_m=0.0))
    import envs.sim.imu as imu_mod
    matched = g.replace(name="matched", gyro_scale_sigma=0.0, accel_scale_sigma=0.0, gyro_misalignment_sigma=0.0,
                        accel_misalignment_sigma=0.0)
    imu_mod.IMU_GRADES["matched-test"] = matched
    try:
        scen = scen.replace(imu_grade="matched-test")
        N = 20
        log = run_episodes(generate_world(scen, list(range(N))), "kf")
    finally:
        del imu_mod.IMU_GRADES["matched-test"]
    settled = log.t >= 10.0
    anees = np.mean(log.nees_pv[:, settled], 0)  # ensemble average at each epoch: chi2(6N)/N
    lo, hi = chi2.ppf([0.025, 0.975], 6 * N) / N
    assert lo < np.mean(anees) < hi, (np.mean(anees), lo, hi)
    assert np.mean((anees > lo) & (anees < hi)) > 0.85  # and at >85% of the epochs individually
    dof = log.n_used[:, settled].sum()
    lo, hi = chi2.ppf([0.025, 0.975], dof) / dof
    nis_per_dof = log.nis[:, settled].sum() / dof
    # NIS samples of consecutive epochs are nearly independent: a +-5% band around the chi-square one
    assert 0.95 * lo < nis_per_dof < 1.05 * hi, nis_per_dof


def test_batching_changes_nothing_and_seeds_reproduce():
    scen = get_scenario("urban", duration_s=20.0)
    seeds = list(range(1000, 1064))
    big = run_episodes(generate_world(scen, seeds), "kf")
    one = run_episodes(generate_world(scen, [seeds[17]]), "kf")
    again = run_episodes(generate_world(scen, [seeds[17]]), "kf")
    np.testing.assert_array_equal(one.pos_err_ned, again.pos_err_ned)
    # the same arithmetic, but stacked BLAS kernels may round the last bit differently at another B
    np.testing.assert_allclose(big.pos_err_ned[17], one.pos_err_ned[0], rtol=0, atol=1e-6)
    np.testing.assert_allclose(big.nis[17], one.nis[0], rtol=1e-6, atol=1e-9)
    assert not np.allclose(big.pos_err_ned[16], big.pos_err_ned[17])


def test_float32_end_to_end():
    w = generate_world("open-sky", [5, 6], dtype=np.float32)
    assert w.imu.f_b.dtype == np.float32
    log = run_episodes(w, "kf", dtype="float32")
    s = summarize(log)
    assert s["diverged"] == 0 and np.isfinite(s["rmse_h_m"]) and s["rmse_h_m"] < 5.0
    ref = summarize(run_episodes(w, "kf"))
    assert abs(s["rmse_h_m"] - ref["rmse_h_m"]) < 0.2 * ref["rmse_h_m"] + 0.1


@pytest.mark.parametrize("kwargs, field", [
    (dict(gnss_rate_hz=200.0), "gnss_rate_hz"),
    (dict(gnss_rate_hz=3.0), "gnss_rate_hz"),
    (dict(imu_grade="navigation"), "imu_grade"),
    (dict(duration_s=float("nan")), "duration_s"),
    (dict(duration_s=-5.0), "duration_s"),
    (dict(drive="offroad"), "drive"),
    (dict(start=(95.0, 0.0, 0.0)), "start"),
])
def test_bad_scenario_names_the_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Scenario(name="x", **kwargs)


def test_bad_inputs_elsewhere():
    with pytest.raises(ValueError, match="unknown scenario"):
        get_scenario("moon")
    with pytest.raises(ValueError, match="pr_sigma_m"):
        ReceiverConfig(pr_sigma_m=-1.0)
    with pytest.raises(ValueError, match="prr_sigma_mps"):
        ReceiverConfig(prr_sigma_mps=float("nan"))
    with pytest.raises(ValueError, match="gyro_arw"):
        IMU_GRADES["industrial"].replace(gyro_arw=-1.0)
    with pytest.raises(ValueError, match="unknown filter method"):
        run_episodes(generate_world("seed000-sim", [0]), "ukf")
    with pytest.raises(ValueError, match="seeds"):
        generate_world("open-sky", [-1])


def test_zupt_block_fused_with_gnss_pins_a_stopped_vehicle():
    """A ZUPT block fused into the GNSS update (any form, same call) drives the velocity error of a stopped
    vehicle to the ZUPT noise level; without it the GNSS-only velocity error is larger."""
    from nav_filters.constraints import zupt
    from envs.episodes import navigator_for
    scen = get_scenario("seed003-sim", duration_s=30.0)  # stationary for the first 30 s
    w = generate_world(scen, [0, 1, 2])
    errs = {}
    for use_zupt in (False, True):
        nav = navigator_for(w, "kf")
        g, k = w.gnss, 0
        for j, kk in enumerate(w.epoch_idx):
            nav.propagate_epoch(w.imu.f_b[:, k + 1:kk + 1], w.imu.w_b[:, k + 1:kk + 1], 0.01)
            k = kk
            extra = zupt(nav.v, nav.C, 0.01, np.ones(3, bool)) if use_zupt else None
            nav.update_gnss(g.sat_pos[:, j], g.sat_vel[:, j], g.pr[:, j], g.prr[:, j], g.pr_sigma[:, j],
                            g.prr_sigma[:, j], g.mask[:, j], extra=extra)
        errs[use_zupt] = np.abs(nav.v - w.truth.v_e[:, k]).max()
    assert w.truth.speed[:, :k + 1].max() == 0.0
    assert errs[True] < 0.03 and errs[True] < 0.5 * errs[False], errs


@pytest.mark.parametrize("method", ["kf", "svd-kf"])
def test_a_diverged_row_is_parked_and_the_others_go_on(method):
    """Poison one row's state with NaN: it is flagged and frozen; the other rows keep the results of a clean run."""
    from envs.episodes import navigator_for
    w = generate_world("seed000-sim", [0, 1, 2])
    clean = navigator_for(w, method)
    nav = navigator_for(w, method)
    g, k = w.gnss, 0
    for j, kk in enumerate(w.epoch_idx[:10]):
        for n in (clean, nav):
            n.propagate_epoch(w.imu.f_b[:, k + 1:kk + 1], w.imu.w_b[:, k + 1:kk + 1], 0.01)
        k = kk
        if j == 4:
            nav.v[1] = np.nan
        for n in (clean, nav):
            n.update_gnss(g.sat_pos[:, j], g.sat_vel[:, j], g.pr[:, j], g.prr[:, j], g.pr_sigma[:, j],
                          g.prr_sigma[:, j], g.mask[:, j])
    assert nav.diverged.tolist() == [False, True, False] and not clean.diverged.any()
    assert np.all(np.isfinite(nav.covariance))
    np.testing.assert_allclose(nav.r[[0, 2]], clean.r[[0, 2]], rtol=0, atol=1e-6)
