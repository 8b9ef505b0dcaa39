"""Environment arguments and actions that a demanding user gets wrong (issue 13): each is a ValueError at
construction (or at the step) naming the argument, never a hang, a silent conversion or a late failure."""
import re

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401
from envs.config import MAX_EPISODE_S, MAX_HISTORY
from envs.core import MAX_BATCH
from envs.worlds import scenario_names

FAST = dict(episode_length_s=5.0)


@pytest.mark.parametrize("kwargs, msg", [
    (dict(episode_length_s=1e9), f"episode_length_s must be <= {MAX_EPISODE_S:g} s, got 1000000000.0 (the episode's "
                                 "world is generated whole at reset: about 4e+04 GB per env row at 100 Hz)"),
    (dict(episode_length_s=True), "episode_length_s must be a positive finite number, got True"),
    (dict(divergence_bound_m=False), "divergence_bound_m must be a positive finite number, got False"),
    (dict(gnss_rate_hz=True), "gnss_rate_hz must be a positive finite number, got True"),
    (dict(history=True), f"history must be an int in [1, {MAX_HISTORY}]"),
    (dict(history=10**6), f"history must be an int in [1, {MAX_HISTORY}] (stacked frames), got 1000000"),
    (dict(history=2.0), "history must be an int"),
    (dict(method="kf"), "method 'kf' does not take the parameter(s) b this env sets (it has no adjustable "
                        "parameters); methods that do: sage-husa, sage-husa-group, sage-husa-r, svd-akf, svd-asrkf"),
    (dict(method="ma-stkf"), "method 'ma-stkf' runs another adaptive law (MeasurementAdaptiveSTKF) than this env's "
                             "'sage-husa' (SageHusa)"),
    (dict(divergence_bound_m=1e-9), "EnvConfig.divergence_bound_m must be >= 50 m (a smaller bound ends healthy "
                                    "episodes at their first epochs as diverged), got 1e-09"),
    (dict(method="stkf+onestep"), "method 'stkf+onestep' does not take the parameter(s) b this env sets (its "
                                  "parameters: rho, softening)"),
    (dict(scenario="mars"), "unknown scenario 'mars'; known: " + ", ".join(scenario_names())),
])
def test_bad_argument_fails_at_construction_naming_it(kwargs, msg):
    with pytest.raises(ValueError) as e:
        gym.make("GnssIns/SageHusa-v1", **kwargs)
    assert msg in str(e.value)


def test_unknown_scenario_lists_the_recorded_data_sets_too():
    with pytest.raises(ValueError, match="smartloc-potsdamer-platz"):
        gym.make("GnssIns/STKF-v1", scenario="potsdam")


def test_method_of_another_env_fails_at_construction_not_at_reset():
    with pytest.raises(ValueError, match="methods that do: ma-stkf"):
        gym.make_vec("GnssIns/MASTKF-v1", num_envs=2, vectorization_mode="vector_entry_point", method="sage-husa")
    gym.make("GnssIns/MASTKF-v1", method="ma-stkf+onestep", **FAST)  # its own method, with the suffix, is fine


@pytest.mark.parametrize("env_id, method", [("GnssIns/STKF-v1", "ma-stkf"), ("GnssIns/SageHusa-v1", "ma-stkf+fde")])
def test_a_method_of_another_law_is_refused_even_when_it_has_a_parameter_of_that_name(env_id, method):
    """ma-stkf takes a 'softening' and a 'b' too, with another meaning: the env would tune the wrong knob."""
    for make in (lambda: gym.make(env_id, method=method, **FAST),
                 lambda: gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point", method=method)):
        with pytest.raises(ValueError, match=rf"method '{re.escape(method)}' runs another adaptive law "
                                             r"\(MeasurementAdaptiveSTKF\).*has its own env: GnssIns/MASTKF-v1"):
            make()
    gym.make("GnssIns/STKF-v1", method="stkf+fde", **FAST)                 # the env's own law, with suffixes
    gym.make("GnssIns/SageHusa-v1", method="svd-asrkf+onestep", **FAST)


@pytest.mark.parametrize("n", [2.7, "3", 10**7, MAX_BATCH + 1, True, 0, -1, None])
def test_num_envs_must_be_an_int_within_limits(n):
    with pytest.raises(ValueError, match=rf"num_envs must be an int in \[1, {MAX_BATCH}\], got {n!r}"):
        gym.make_vec("GnssIns/SageHusa-v1", num_envs=n, vectorization_mode="vector_entry_point", **FAST)


def test_num_envs_accepts_numpy_ints():
    venv = gym.make_vec("GnssIns/SageHusa-v1", num_envs=np.int64(2), vectorization_mode="vector_entry_point", **FAST)
    assert venv.num_envs == 2 and isinstance(venv.num_envs, int)


@pytest.fixture(scope="module")
def venv256():
    venv = gym.make_vec("GnssIns/SageHusa-v1", num_envs=256, vectorization_mode="vector_entry_point", **FAST)
    venv.reset(seed=0)
    return venv


@pytest.mark.parametrize("action, msg", [
    (np.zeros((256, 1), complex), "action must be an array of real numbers, got dtype complex128 (complex: the "
                                  "imaginary part would be dropped)"),
    (np.full((256, 1), "0.5"), "action must be an array of real numbers, got dtype <U3"),
    (np.zeros((256, 1), object), "action must be an array of real numbers, got dtype object"),
    (np.zeros((256, 1), bool), "action must be an array of real numbers, got dtype bool"),
])
def test_non_real_actions_are_rejected(venv256, action, msg):
    with pytest.raises(ValueError) as e:
        venv256.step(action)
    assert str(e.value) == msg


def test_a_nan_action_names_the_rows_in_one_short_line(venv256):
    a = np.zeros((256, 1), np.float32)
    bad = [3, 7, 100, 101, 102, 103, 200]
    a[bad] = np.nan
    a[200] = np.inf
    with pytest.raises(ValueError) as e:
        venv256.step(a)
    msg = str(e.value)
    assert msg == "action contains NaN or inf in 7 of 256 rows (rows 3, 7, 100, 101, 102, ...; row 3: [nan])"
    a[:] = 0
    a[255] = -np.inf
    with pytest.raises(ValueError, match=r"in 1 of 256 rows \(rows 255; row 255: \[-inf\]\)"):
        venv256.step(a)
    venv256.step(np.zeros((256, 1), np.float32))  # the rejected steps changed nothing: the env steps on


def test_single_env_rejects_a_complex_action():
    env = gym.make("GnssIns/SageHusa-v1", **FAST)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="real numbers"):
        env.step(np.array([0.5 + 1j]))
    assert env.step(np.array([0.5], np.float32))[4]["diverged_reason"] == ""
