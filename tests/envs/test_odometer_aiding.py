"""A scenario's wheel odometer (``Scenario.odometer``; seed003-sim) reaches every loop that runs a filter:
eval.py's run_episodes, the env core, and the seed003 experiment's own loop, with the same rows."""
import numpy as np
import pytest

import experiments as X
from envs.config import EnvConfig
from envs.core import TuningCore
from envs.episodes import run_episodes
from envs.gnss_ins_env import STKF_PARAMS
from envs.sim.odometer import SEED003_ODOMETER, OdometerModel, simulate_odometer
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world


def test_seed003_worlds_carry_the_papers_odometer():
    scen = get_scenario("seed003-sim", duration_s=60.0)
    assert scen.odometer == SEED003_ODOMETER
    w = generate_world(scen, [0, 1, 2])
    assert w.odometer.shape == (3, len(w.epoch_idx))
    np.testing.assert_array_equal(w.odometer, X.simulate_odometer(w, SEED003_ODOMETER))
    # the reading model: speed (1 + scale error) + white noise of the model's size
    resid = w.odometer - w.truth.speed[:, w.epoch_idx] * (1 + SEED003_ODOMETER.scale_error)
    assert 0.5 * SEED003_ODOMETER.noise_mps < resid.std() < 1.5 * SEED003_ODOMETER.noise_mps
    # row i depends on its own seed only; the other streams (the GNSS / IMU worlds) are untouched
    one = generate_world(scen, [2])
    np.testing.assert_array_equal(one.odometer, w.odometer[2:3])
    plain = generate_world(scen.replace(odometer=None), [0, 1, 2])
    assert plain.odometer is None
    np.testing.assert_array_equal(plain.gnss.pr, w.gnss.pr)
    np.testing.assert_array_equal(plain.imu.f_b, w.imu.f_b)
    assert generate_world("open-sky", [0]).odometer is None


def test_bad_odometer_is_a_clear_error():
    with pytest.raises(ValueError, match="Scenario.odometer must be an OdometerModel or None"):
        get_scenario("seed003-sim", odometer=0.1)
    with pytest.raises(ValueError, match="OdometerModel.sigma_mps must be > 0"):
        OdometerModel(sigma_mps=0.0)
    with pytest.raises(ValueError, match=r"speed must be \(B, M\)"):
        simulate_odometer(np.zeros(5), [0])
    with pytest.raises(ValueError, match="2 seeds for 3 rows"):
        simulate_odometer(np.zeros((3, 5)), [0, 1])


def test_run_episodes_fuses_the_odometer_as_the_experiment_does():
    """run_episodes on seed003-sim equals the seed003 experiment's loop with the paper's sensor set, and without
    the odometer its GNSS-only variant; the odometer + NHC hold the 80 s outage's drift far below GNSS only."""
    scen = get_scenario("seed003-sim", duration_s=180.0)
    world = generate_world(scen, [0, 1])
    for method in ("kf", "stkf"):
        log = run_episodes(world, method)
        ref = X.run_navigation(world, method, odometer_model=SEED003_ODOMETER)
        np.testing.assert_allclose(log.pos_err_ned, ref.pos_ned, rtol=0, atol=1e-9)
    gnss_only = run_episodes(generate_world(scen.replace(odometer=None), [0, 1]), "kf")
    np.testing.assert_allclose(gnss_only.pos_err_ned, X.run_navigation(world, "kf").pos_ned, rtol=0, atol=1e-9)
    out = ~world.gnss.mask.any(-1)[0]
    assert out.sum() >= 70
    h = lambda lg: np.hypot(lg.pos_err_ned[:, out, 0], lg.pos_err_ned[:, out, 1])  # noqa: E731
    assert np.sqrt(np.mean(h(run_episodes(world, "kf")) ** 2)) < 0.5 * np.sqrt(np.mean(h(gnss_only) ** 2))


def test_env_core_fuses_the_odometer_like_run_episodes():
    """The STKF env on seed003-sim through its first outage (stepped with the default action) gives the
    errors of run_episodes with the same parameters: the odometer rows reach the env, also in outages."""
    seeds, L = [5, 6], 130.0
    cfg = EnvConfig(scenario="seed003-sim", method="stkf", episode_length_s=L, exact_transition=True,
                    fused_update=False)  # run_episodes' arithmetic
    core = TuningCore(cfg, STKF_PARAMS, len(seeds))
    core.reset_rows(np.arange(len(seeds)), seeds)
    act = np.broadcast_to(core.default_action, (len(seeds), core.k))
    h_core = []
    while not np.any(core.t >= core.M):
        h_core.append(core.step(act).info["horizontal_error_m"])
    params = {p.name: p.to_value(core.default_action[i:i + 1])[0] for i, p in enumerate(STKF_PARAMS)}
    world = generate_world(cfg.resolve_scenario(), seeds)
    log = run_episodes(world, "stkf", params=params)
    np.testing.assert_allclose(log.horizontal_error, np.array(h_core).T, rtol=1e-9, atol=1e-9)
    gnss_only = run_episodes(generate_world(cfg.resolve_scenario().replace(odometer=None), seeds), "stkf",
                             params=params)
    assert not np.allclose(gnss_only.horizontal_error, log.horizontal_error)
