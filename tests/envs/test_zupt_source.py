"""Zero-velocity aiding in eval.py's loop (run_episodes) is the environments' aiding (TuningCore)."""
import numpy as np
import pytest

from envs.config import EnvConfig
from envs.core import TuningCore
from envs.episodes import run_episodes
from envs.gnss_ins_env import SAGE_HUSA_PARAMS
from envs.worlds import make_world
from envs.zupt_source import ZuptSource


@pytest.mark.parametrize("zupt", ["truth", "shoe"])
def test_run_episodes_zupt_equals_the_environment_core(zupt):
    # seed003-sim starts with ~30 s at rest: both loops must constrain the same epochs and agree on the errors
    seeds, L = [3, 4], 45.0
    cfg = EnvConfig(scenario="seed003-sim", method="sage-husa", episode_length_s=L, zupt=zupt, exact_transition=True,
                    fused_update=False)  # run_episodes' arithmetic
    core = TuningCore(cfg, SAGE_HUSA_PARAMS, len(seeds))
    core.reset_rows(np.arange(len(seeds)), seeds)
    act = np.broadcast_to(core.default_action, (len(seeds), core.k))
    b = SAGE_HUSA_PARAMS[0].to_value(core.default_action[:1])[0]
    h_core, z_core = [], []
    while not np.any(core.t >= core.M):
        r = core.step(act)
        h_core.append(r.info["horizontal_error_m"])
        z_core.append(r.info["zupt"])
    world = make_world(cfg.resolve_scenario(), seeds)
    log = run_episodes(world, "sage-husa", params={"b": b}, zupt=zupt)
    np.testing.assert_array_equal(log.zupt, np.array(z_core).T)
    assert 20 <= log.zupt[0].sum() <= 35  # ~30 s stationary at 1 Hz
    np.testing.assert_allclose(log.horizontal_error, np.array(h_core).T, rtol=1e-9, atol=1e-9)
    plain = run_episodes(world, "sage-husa", params={"b": b})
    assert not plain.zupt.any()
    # while standing, the ZUPTs hold the error below the unaided filter's
    still = log.zupt[0]
    assert np.sqrt(np.mean(log.horizontal_error[0, still] ** 2)) < np.sqrt(np.mean(plain.horizontal_error[0, still] ** 2))


def test_bad_zupt_choice_is_a_clear_error():
    world = make_world("seed003-sim", [3])
    with pytest.raises(ValueError, match="zupt must be one of"):
        run_episodes(world, "kf", zupt="glrt")
    with pytest.raises(ValueError, match="weights file"):
        ZuptSource("lstm", 100.0, "/nonexistent/lstm.pt")
    with pytest.raises(ValueError, match="only for zupt='mlp' or 'lstm'"):
        ZuptSource("shoe", 100.0, "x.pt")
