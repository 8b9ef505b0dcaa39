"""The seed-paper reproduction experiments (the top-level package experiments): structure, the loop they add, the statistics.

The experiments themselves are run at full size by ``eval.py --experiment NAME``
(figures in the issue-3 closing note); here each runs with 2 episodes on
scenarios cut short (``duration_s``) so the file stays within seconds: what is
checked is the documented structure and that the report prints the paper's
figures beside ours, not the figures.
"""
import json
import math

import numpy as np
import pytest

import experiments as X
from envs.episodes import run_episodes
from envs.metrics import MIN_CI_EPISODES, no_ci_text
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world

TOP_KEYS = {"experiment", "episodes", "seed", "episode_seeds", "wall_time_s", "duration_s", "setup", "ours", "paper",
            "claims"}
CLAIM_KEYS = {"id", "claim", "source", "paper", "ours", "ci95", "verdict", "why", "episodes"}
# one figure typed from each paper table (it must appear in the report as printed there)
PAPER_FIGURE = {"seed000": "18.38", "seed001": "108.01", "seed003": "4.2576"}


def _numbers(x, path="results"):
    """Every number in a nested results dict, with its path (None = not applicable, allowed)."""
    if isinstance(x, dict):
        for k, v in x.items():
            yield from _numbers(v, f"{path}.{k}")
    elif isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(x, (float, int, np.floating, np.integer)) and not isinstance(x, bool):
        yield path, float(x)


@pytest.fixture(scope="module")
def small_runs(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp")
    dur = {"seed000": 12.0, "seed001": 12.0, "seed003": 40.0}
    msgs = []
    return out, msgs, {n: X.run_experiment(n, episodes=2, seed=3, out_dir=out, progress=msgs.append, duration_s=dur[n])
                       for n in X.EXPERIMENTS}


@pytest.mark.parametrize("name", X.EXPERIMENTS)
def test_experiment_structure_and_report(small_runs, name):
    out, msgs, runs = small_runs
    res, report = runs[name]
    assert set(res) == TOP_KEYS
    assert res["experiment"] == name and res["episodes"] == 2 and res["seed"] == 3
    assert res["episode_seeds"] == [3 * 1_000_003, 3 * 1_000_003 + 1]  # eval.py's pairing
    for path, v in _numbers(res):
        assert math.isfinite(v), f"{path} = {v}"
    assert res["claims"], "every experiment states claims"
    for c in res["claims"]:
        assert set(c) == CLAIM_KEYS
        # 2 episodes: below the minimum, no verdict and no CI, in the words of eval.py's tables
        assert c["verdict"] is None and c["ci95"] is None and c["why"] == no_ci_text(), c
        assert c["episodes"] <= 2
    for v in X.VERDICTS:
        assert f"**{v}**" not in report
    assert f"| {no_ci_text()} | |" in report and "No verdicts: n < 10: no CI" in report
    assert "claims reproduced" not in report
    # the report prints the paper's figures and ours side by side
    low = report.lower()
    assert "paper" in low and "ours" in low
    assert PAPER_FIGURE[name] in report
    assert any(name in m for m in msgs)
    # files written, JSON loads and equals the returned structure (NaN-free)
    js = json.loads((out / f"{name}.json").read_text())
    assert set(js) == TOP_KEYS and len(js["claims"]) == len(res["claims"])
    assert all(c["verdict"] is None and c["ci95"] is None for c in js["claims"])
    assert (out / f"{name}.md").read_text() == report


def test_ours_are_computed_and_printed(small_runs):
    """Our figures in the report are the ones in results (not constants): spot-check one per experiment."""
    _, _, runs = small_runs
    r0, rep0 = runs["seed000"]
    assert set(r0["ours"]) == (set(X.SEED000_METHODS) | {"kf (float64)"} | {f"{m} (extra)" for m in X.SEED000_EXTRA_METHODS}
                               | {f"{m} (urban-transition)" for m in X.SEED000_URBAN_METHODS})
    u = r0["ours"]["svd-akf (urban-transition)"]
    assert f"{u['max_3d_m']:.2f}" in rep0
    claim = next(c for c in r0["claims"] if c["id"] == "max-urban:svd-akf<svd-kf")
    assert claim["ours"] == pytest.approx(u["max_3d_m"] / r0["ours"]["svd-kf (urban-transition)"]["max_3d_m"] - 1)
    o = r0["ours"]["svd-kf"]
    assert len(o["rmse_enu_m"]) == 3 and len(o["rmse_ecef_m"]) == 3
    assert f"{o['rmse_3d_m']:.3f}" in rep0
    # the RMSE per axis is consistent with the 3D RMSE (same epochs): sum of squares
    assert np.isclose(np.sum(np.square(o["rmse_enu_m"])), o["rmse_3d_m"] ** 2, rtol=1e-9)
    assert np.isclose(np.sum(np.square(o["rmse_ecef_m"])), o["rmse_3d_m"] ** 2, rtol=1e-9)
    r1, rep1 = runs["seed001"]
    assert set(r1["ours"]) == set(X.SEED001_SCENARIOS)
    for scen, per in r1["ours"].items():
        for m, o in per.items():
            assert {"per-sample", "epoch", "onestep", "degradation", "time_saving"} <= set(o)
            assert f"{o['onestep']['rmse_h_m']:.4f}" in rep1
            assert o["per_sample_vs_epoch_max_dev_m"] < 1e-6  # same estimate, different cost
            assert all(d["ci95"] is None for d in o["degradation"].values())  # 2 episodes: no CI
            assert "n < 10: no CI" in rep1
    r3, rep3 = runs["seed003"]
    assert set(r3["ours"]) == {"gnss+odo+nhc", "gnss-only"}
    for per in r3["ours"].values():
        assert set(per) == set(X.SEED003_METHODS)
        for m, o in per.items():
            assert set(o["rmse"]) == set(X.SEED003_QUANTITIES) == set(o["mad"])
            for q in X.SEED003_QUANTITIES:
                assert o["mad"][q] <= o["rmse"][q] + 1e-12  # mean |e| <= RMS e
            assert f"{o['rmse']['lon_m']:.4f}" in rep3
    assert "lambda" in r3["ours"]["gnss-only"]["stkf"]["adaptive"]


def test_run_navigation_reproduces_run_episodes():
    """With no option the experiments' loop is run_episodes' loop (bit for bit); a predict at every IMU sample
    gives the same estimate to rounding (the navigator composes the per-sample transitions exactly)."""
    world = generate_world(get_scenario("open-sky", duration_s=15.0), [5, 6])
    ref = run_episodes(world, "kf")
    run = X.run_navigation(world, "kf")
    np.testing.assert_array_equal(run.pos_ned, ref.pos_err_ned)
    np.testing.assert_array_equal(run.vel_ned, ref.vel_err_ned)
    ps = X.run_navigation(world, "kf", per_sample_predict=True)
    np.testing.assert_allclose(ps.pos_ned, ref.pos_err_ned, rtol=0, atol=1e-6)  # 1 um: float64 rounding only
    # ECEF errors are the NED errors rotated (lengths agree)
    np.testing.assert_allclose(np.linalg.norm(run.pos_ecef, axis=-1), np.linalg.norm(run.pos_ned, axis=-1),
                               rtol=1e-9, atol=1e-9)


def test_odometer_aiding_bounds_the_outage_drift():
    """seed003-sim cut to 180 s (an 80 s outage from 100 s): odometer + NHC rows must hold the drift far below
    GNSS-only (fails if the rows were ignored, mis-signed or not fused in outages)."""
    world = generate_world(get_scenario("seed003-sim", duration_s=180.0), [0, 1])
    gnss = X.run_navigation(world, "kf")
    odo = X.run_navigation(world, "kf", odometer_model=X.SEED003_ODOMETER)
    out = gnss.outage[0]
    assert out.sum() >= 70 and (gnss.outage == odo.outage).all()
    h = lambda r: np.hypot(r.pos_ned[:, out, 0], r.pos_ned[:, out, 1])  # noqa: E731
    assert np.sqrt(np.mean(h(odo) ** 2)) < 0.5 * np.sqrt(np.mean(h(gnss) ** 2))
    assert not odo.diverged.any()


def test_simulated_odometer():
    world = generate_world(get_scenario("seed003-sim", duration_s=60.0), [0, 1, 2])
    m = X.OdometerModel(scale_error=1e-3, noise_mps=0.0)
    s = X.simulate_odometer(world, m)
    np.testing.assert_allclose(s, world.truth.speed[:, world.epoch_idx] * 1.001, rtol=1e-12)
    noisy = X.simulate_odometer(world)
    assert noisy.shape == s.shape
    # row i depends on its seed only
    np.testing.assert_array_equal(X.simulate_odometer(generate_world(get_scenario("seed003-sim", duration_s=60.0), [2])),
                                  noisy[2:3])
    with pytest.raises(ValueError, match="sigma_mps"):
        X.OdometerModel(sigma_mps=0.0)
    with pytest.raises(ValueError, match="noise_mps"):
        X.OdometerModel(noise_mps=-1.0)


def test_paired_change_and_verdicts():
    rng = np.random.default_rng(0)
    b = rng.normal(size=(20, 50))
    ch, (lo, hi) = X.paired_change(0.9 * b, b)
    assert np.isclose(ch, -0.1) and np.isclose(lo, -0.1) and np.isclose(hi, -0.1)  # exact ratio in every resample
    ch, (lo, hi) = X.paired_change(np.abs(b) * 1.2, np.abs(b), stat="mean_abs")
    assert np.isclose(ch, 0.2) and lo <= ch <= hi
    ch, (lo, hi) = X.paired_change(rng.normal(size=(20, 50)), b)  # independent noise: CI covers 0
    assert lo < 0 < hi
    with pytest.raises(ValueError, match="stat"):
        X.paired_change(b, b, stat="median")
    assert X.verdict(-0.2, -0.15, (-0.2, -0.1)) == "reproduced"
    assert X.verdict(-0.2, -0.05, (-0.08, -0.02)) == "direction only"
    assert X.verdict(-0.2, -0.05, (-0.08, 0.02)) == "not reproduced"
    assert X.verdict(-0.2, 0.05, (0.02, 0.08)) == "not reproduced"
    assert X.verdict(0.3, 0.3, (0.1, 0.5)) == "reproduced"
    assert X.verdict(-0.5, -0.01, (-0.02, -0.005), magnitude=False) == "reproduced"
    assert X.verdict(-0.5, float("nan")) == "not reproduced"


def test_no_verdict_below_the_minimum_episodes():
    """make_claim: from MIN_CI_EPISODES (paired) episodes on, the verdict and CI as given; below, none, with
    eval.py's words (no_ci_text); the report's claims table and closing count say the same."""
    n = MIN_CI_EPISODES
    args = ("c", "svd-kf vs kf", "000 Table 2", -0.2, -0.15, (-0.2, -0.1))
    keep = X.make_claim(*args, X.verdict(-0.2, -0.15, (-0.2, -0.1)), episodes=n)
    assert keep["verdict"] == "reproduced" and keep["ci95"] == [-0.2, -0.1] and keep["why"] == ""
    assert keep["episodes"] == n
    miss = X.make_claim(*args[:5], (0.1, 0.2), "not reproduced", "opposite", episodes=np.int64(n))
    assert miss["verdict"] == "not reproduced" and miss["why"] == "opposite" and miss["ci95"] == [0.1, 0.2]
    few = X.make_claim(*args, "reproduced", episodes=n - 1)
    assert few["verdict"] is None and few["ci95"] is None and few["why"] == no_ci_text() == "n < 10: no CI"
    pt = X.make_claim("m", "max error", "000 sec 5.2.2", -0.4, -0.3, None, "reproduced", episodes=2)
    assert pt["verdict"] is None and pt["why"] == no_ci_text()  # a point-estimate claim too
    table = "\n".join(X._claims_table([keep, few]))
    assert "| -15.0% [-20.0%, -10.0%] | **reproduced** |" in table
    assert "| -15.0% | n < 10: no CI | |" in table and table.count("**") == 2  # one verdict, in bold
    assert X.verdict_summary([keep, miss]) == "1 of 2 claims reproduced."
    assert X.verdict_summary([keep, few]) == "1 of 1 claims reproduced; 1 without a verdict (n < 10: no CI)."
    assert X.verdict_summary([few, pt]).startswith("No verdicts: n < 10: no CI")


def test_verdicts_from_the_minimum_episodes_on():
    """seed000 (scenarios cut to 12 s) with MIN_CI_EPISODES episodes: every claim has its verdict, the paired
    ones their CI, a claim not reproduced says why, and the report counts them."""
    res, report = X.run_experiment("seed000", episodes=MIN_CI_EPISODES, seed=3, duration_s=12.0)
    for c in res["claims"]:
        assert c["episodes"] == MIN_CI_EPISODES and c["verdict"] in X.VERDICTS, c
        assert (c["why"] == "") == (c["verdict"] == "reproduced"), c
        if not c["id"].startswith("max"):  # the maximum-error claims are point estimates
            lo, hi = c["ci95"]
            assert lo <= c["ours"] <= hi
            assert f"{X._ci_pct(c['ci95'])} | **{c['verdict']}** |" in report
    n_rep = sum(c["verdict"] == "reproduced" for c in res["claims"])
    assert f"{n_rep} of {len(res['claims'])} claims reproduced." in report and no_ci_text() not in report


def test_bad_input():
    with pytest.raises(ValueError, match="unknown experiment"):
        X.run_experiment("seed002")
    with pytest.raises(ValueError, match="episodes"):
        X.run_experiment("seed000", episodes=0)
    with pytest.raises(ValueError, match="seed"):
        X.run_experiment("seed000", episodes=1, seed=-1)
    with pytest.raises(ValueError, match="duration_s"):
        X.run_experiment("seed000", episodes=1, duration_s=float("nan"))
    with pytest.raises(ValueError, match="batch_size"):
        X.run_experiment("seed000", episodes=1, batch_size=0)
