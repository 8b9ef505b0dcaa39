"""A learned policy gives each row the same actions whatever the batch it runs in (issue 13: eval.py
--batch-size 1 and 64 differed by up to 5e-7 relative through batched torch inference)."""
import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from agents.policies import Sb3Policy
from agents.rollout import run_policy_episodes

KW = {"scenario": "urban", "episode_length_s": 30.0}


@pytest.fixture(scope="module", params=["ppo", "recurrentppo"])
def policy(request):
    from agents.policies import algo_class
    env = gym.make("GnssIns/SageHusa-v1", **KW)
    policy_name = "MlpLstmPolicy" if request.param == "recurrentppo" else "MlpPolicy"
    model = algo_class(request.param)(policy_name, env, n_steps=16, batch_size=16, seed=3, device="cpu")
    return Sb3Policy(model, request.param, env_id="GnssIns/SageHusa-v1", env_kwargs=KW)


def test_actions_do_not_depend_on_the_batch(policy):
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(64, policy.model.observation_space.shape[0])).astype(np.float32)
    policy.reset(64)
    batched = policy.act(obs)
    single = []
    for i in range(64):
        policy.reset(1)
        single.append(policy.act(obs[i:i + 1]))
    np.testing.assert_array_equal(batched, np.concatenate(single))
    assert np.ptp(batched) > 0  # the rows do differ: the comparison is not vacuous


def test_episodes_are_bit_identical_run_together_or_one_by_one(policy):
    seeds = [5, 6, 7]
    together = run_policy_episodes("GnssIns/SageHusa-v1", KW, policy, seeds)
    for i, s in enumerate(seeds):
        alone = run_policy_episodes("GnssIns/SageHusa-v1", KW, policy, [s])
        np.testing.assert_array_equal(together.pos_err_ned[i], alone.pos_err_ned[0])
