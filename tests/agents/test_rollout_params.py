"""run_policy_episodes records the parameter values the policy set (EpisodeLog.params, the actions plot)."""
import numpy as np

from agents.rollout import env_class, run_policy_episodes
from envs.episodes import concat_logs


class Constant:
    def __init__(self, a):
        self.a = a

    def reset(self, B):
        self.B = B

    def act(self, obs):
        return np.tile(self.a, (obs.shape[0], 1))


def test_params_are_the_actions_in_parameter_units():
    spec = env_class("GnssIns/SageHusa-v1").PARAMS[0]
    log = run_policy_episodes("GnssIns/SageHusa-v1", {"episode_length_s": 5.0}, Constant(np.array([0.25])), [3, 4])
    assert set(log.params) == {spec.name}
    v = log.params[spec.name]
    assert v.shape == log.horizontal_error.shape
    np.testing.assert_allclose(v, spec.to_value(np.array(0.25)))
    both = concat_logs([log, log])
    assert both.params[spec.name].shape == (4, v.shape[1])
    assert concat_logs([log, type(log)(**{**log.__dict__, "params": None})]).params is None
