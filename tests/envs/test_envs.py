"""The registered tuning environments: checkers, determinism, snapshot, vector == single, SB3 smoke, bad input."""
import json
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)
from envs import ENV_IDS

FAST = dict(episode_length_s=8.0)
SNAPSHOT = Path(__file__).parent / "snapshots" / "sagehusa_seed0.json"


@pytest.mark.parametrize("env_id", sorted(ENV_IDS))
def test_gymnasium_and_sb3_checkers(env_id):
    from gymnasium.utils.env_checker import check_env as gym_check
    from stable_baselines3.common.env_checker import check_env as sb3_check
    env = gym.make(env_id, **FAST)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        gym_check(env.unwrapped, skip_render_check=True)
        sb3_check(env, warn=True)
    msgs = [str(w.message) for w in caught]
    # justified: SB3 recommends a symmetric [-1, 1] *observation*, ours has physical bounds per feature
    allowed = ("normaliz", "symmetric")
    unexpected = [m for m in msgs if not any(a in m.lower() for a in allowed)]
    assert not unexpected, unexpected


def _rollout(env, seed, actions):
    obs, info = env.reset(seed=seed)
    out = [(obs.copy(), 0.0, False, False, info)]
    for a in actions:
        o, r, te, tr, inf = env.step(a)
        out.append((o.copy(), r, te, tr, inf))
        if te or tr:
            break
    return out


@pytest.mark.parametrize("env_id", sorted(ENV_IDS))
def test_seeded_determinism_full_episode(env_id):
    rng = np.random.default_rng(0)
    e1, e2 = gym.make(env_id, **FAST), gym.make(env_id, **FAST)
    acts = rng.uniform(-1, 1, size=(20,) + e1.action_space.shape).astype(np.float32)
    a, b = _rollout(e1, 123, acts), _rollout(e2, 123, acts)
    assert len(a) == len(b) == 9 and a[-1][3]  # 8 epochs, truncated at the end
    for (o1, r1, t1, u1, i1), (o2, r2, t2, u2, i2) in zip(a, b):
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2 and t1 == t2 and u1 == u2
        assert i1.keys() == i2.keys() and all(np.all(i1[k] == i2[k]) for k in i1 if k != "episode_metrics")
    assert "episode_metrics" in a[-1][4] and a[-1][4]["episode_metrics"]["rmse_h_m"] > 0
    c = _rollout(gym.make(env_id, **FAST), 124, acts)
    assert not np.array_equal(a[1][0], c[1][0])


@pytest.mark.parametrize("old", sorted(envs.OUTDATED_ENV_IDS))
def test_outdated_v0_ids_make_the_current_env_with_gymnasiums_warning(old):
    """``-v0`` of the three scalar envs stays makeable: Gymnasium warns that it is out of date and names v1, and
    it builds v1's environment (the same episode for the same seed and actions); v1 itself does not warn."""
    from gymnasium.envs.registration import parse_env_id
    new = envs.OUTDATED_ENV_IDS[old]
    assert new in ENV_IDS and old not in ENV_IDS and envs.is_env_id(old) and envs.current_env_id(old) == new
    (ns, name, v_old), (ns1, name1, v_new) = parse_env_id(old), parse_env_id(new)
    assert (ns, name) == (ns1, name1) and (v_old, v_new) == (0, 1)
    with pytest.warns(DeprecationWarning, match=rf"{old} is out of date.*upgrading to version `v1`"):
        e_old = gym.make(old, **FAST)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)  # the current id: no out-of-date warning
        e_new = gym.make(new, **FAST)
    assert e_old.spec.id == old and type(e_old.unwrapped) is type(e_new.unwrapped)
    acts = np.random.default_rng(1).uniform(-1, 1, size=(3,) + e_new.action_space.shape).astype(np.float32)
    for (o1, r1, *_), (o2, r2, *_) in zip(_rollout(e_old, 7, acts), _rollout(e_new, 7, acts)):
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2
    with pytest.warns(DeprecationWarning, match=rf"{old} is out of date"):
        v = gym.make_vec(old, num_envs=2, vectorization_mode="vector_entry_point", **FAST)
    assert type(v.unwrapped) is type(gym.make_vec(new, num_envs=2, vectorization_mode="vector_entry_point",
                                                    **FAST).unwrapped)


def test_outdated_ids_warn_where_the_core_is_built_without_gym_make():
    """``train.py tune``, eval.py's policies, rules and oracles take an env's class from its id
    (:func:`agents.rollout.env_class`): an out-of-date id says there, once, which version runs."""
    from agents.rollout import env_class
    with pytest.warns(FutureWarning, match=r"GnssIns/STKF-v0 is out of date: it runs GnssIns/STKF-v1"):
        assert env_class("GnssIns/STKF-v0") is env_class("GnssIns/STKF-v1")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env_class("GnssIns/SatelliteR-v0")  # current: per-satellite ids stay at v0


def _snapshot_rollout():
    # the recorded snapshot is of the exact per-sample composition (the reference eval.py runs)
    env = gym.make("GnssIns/SageHusa-v1", exact_transition=True, fused_update=False, **FAST)
    obs, _ = env.reset(seed=0)
    rec = {"obs0": obs.tolist(), "steps": []}
    for a in (-1.0, -0.5, 0.0, 0.5, 1.0):
        o, r, te, tr, info = env.step(np.array([a], np.float32))
        rec["steps"].append({"obs": o.tolist(), "reward": r, "b": info["b"]})
    return rec


def test_snapshot_seeded_reset_and_5_steps():
    """Regenerate after an intended change of the physics: python -c 'import tests.envs.test_envs as t; t.write_snapshot()'."""
    rec = _snapshot_rollout()
    ref = json.loads(SNAPSHOT.read_text())
    np.testing.assert_allclose(rec["obs0"], ref["obs0"], rtol=1e-5, atol=1e-6)
    for s, r in zip(rec["steps"], ref["steps"]):
        np.testing.assert_allclose(s["obs"], r["obs"], rtol=1e-5, atol=1e-6)
        assert s["reward"] == pytest.approx(r["reward"], rel=1e-6, abs=1e-6)
        assert s["b"] == pytest.approx(r["b"], rel=1e-12)


def write_snapshot():
    SNAPSHOT.write_text(json.dumps(_snapshot_rollout(), indent=1))


@pytest.mark.parametrize("env_id", ["GnssIns/SageHusa-v1", "GnssIns/MASTKF-v1", "GnssIns/SatelliteR-v0",
                                    "GnssIns/SatelliteSageHusa-v0"])
def test_vector_rows_equal_single_envs_across_autoreset(env_id):
    n, seed = 3, 40
    kw = dict(episode_length_s=4.0)
    venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kw)
    assert venv.metadata["autoreset_mode"] == gym.vector.AutoresetMode.SAME_STEP
    rng = np.random.default_rng(1)
    acts = rng.uniform(-1, 1, size=(7, n) + venv.single_action_space.shape).astype(np.float32)
    obs, _ = venv.reset(seed=seed)
    vec = [obs]
    vrew, vfinal = [], []
    for a in acts:
        o, r, te, tr, info = venv.step(a)
        vec.append(o)
        vrew.append(r)
        vfinal.append(info.get("final_obs"))
    for i in range(n):
        env = gym.make(env_id, **kw)
        o, _ = env.reset(seed=seed + i)
        np.testing.assert_array_equal(o, vec[0][i])
        for t, a in enumerate(acts):
            o, r, te, tr, _ = env.step(a[i])
            assert r == pytest.approx(vrew[t][i], rel=1e-12, abs=1e-12)
            if te or tr:
                np.testing.assert_array_equal(o, vfinal[t][i])
                o, _ = env.reset()  # the row's own RNG draws the next world, as in the vector env
            np.testing.assert_array_equal(o, vec[t + 1][i])


def test_reset_without_a_seed_continues_every_rows_stream_as_the_single_env():
    """``reset()`` after ``reset(seed=s)`` gives row i the next world of its stream, the single env's ``reset()``
    after ``reset(seed=s + i)``; the same again in a second vector env (reproducible, as SB3's evaluation env
    reset at every evaluation needs)."""
    kw = dict(episode_length_s=3.0)
    venvs = [gym.make_vec("GnssIns/SageHusa-v1", num_envs=3, vectorization_mode="vector_entry_point", **kw)
             for _ in range(2)]
    got = []
    for venv in venvs:
        _, first = venv.reset(seed=7)
        obs, info = venv.reset()
        _, third = venv.reset()
        got.append((obs, info["seed"], third["seed"]))
        assert len({*first["seed"], *info["seed"], *third["seed"]}) == 9  # each reset: new worlds
    np.testing.assert_array_equal(got[0][0], got[1][0])
    np.testing.assert_array_equal(got[0][1], got[1][1])
    env = gym.make("GnssIns/SageHusa-v1", **kw)
    for i in range(3):
        env.reset(seed=7 + i)
        o, info = env.reset()
        assert info["seed"] == got[0][1][i] and env.reset()[1]["seed"] == got[0][2][i]
        np.testing.assert_array_equal(o, got[0][0][i])
    _, info = venvs[0].reset(seed=7)  # a seed starts the streams again
    assert list(info["seed"]) == [env.reset(seed=7 + i)[1]["seed"] for i in range(3)]


def test_world_seeds_are_apart_from_evaluation_seeds():
    """Training worlds come from [2**30, 2**31): never one of eval.py's episode seeds (< 2**30)."""
    from envs.core import TRAINING_WORLD_SEEDS
    venv = gym.make_vec("GnssIns/SageHusa-v1", num_envs=4, vectorization_mode="vector_entry_point",
                        episode_length_s=2.0)
    _, info = venv.reset(seed=0)
    env = gym.make("GnssIns/SageHusa-v1", episode_length_s=2.0)
    seeds = [env.reset(seed=s)[1]["seed"] for s in range(20)]
    assert list(info["seed"]) == seeds[:4]  # row i of the vector env = single env seeded i
    assert all(TRAINING_WORLD_SEEDS[0] <= s < TRAINING_WORLD_SEEDS[1] for s in seeds)
    assert len(set(seeds)) == len(seeds)


def test_sb3_ppo_trains_on_the_vector_env():
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import Logger
    from envs.sb3 import make_sb3_vec_env
    venv = make_sb3_vec_env("GnssIns/SageHusa-v1", n_envs=4, seed=0, episode_length_s=6.0)
    model = PPO("MlpPolicy", venv, n_steps=32, batch_size=64, n_epochs=1, seed=0, device="cpu")
    model.set_logger(Logger(None, []))  # SB3's default logger leaves an empty SB3-<time> folder in the temp dir
    model.learn(total_timesteps=256)
    obs = venv.reset()
    act, _ = model.predict(obs, deterministic=True)
    assert act.shape == (4, 1) and np.all(np.isfinite(act))
    # an episode end reaches SB3 with the terminal observation
    dones_seen = 0
    for _ in range(7):
        obs, rew, done, infos = venv.step(act)
        for d, inf in zip(done, infos):
            if d:
                dones_seen += 1
                assert inf["terminal_observation"].shape == obs.shape[1:] and inf["TimeLimit.truncated"]
    assert dones_seen == 4


def test_render_modes():
    env = gym.make("GnssIns/SageHusa-v1", render_mode="rgb_array", **FAST)
    env.reset(seed=1)
    for _ in range(3):
        env.step(env.action_space.sample())
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8 and img.std() > 0
    env = gym.make("GnssIns/STKF-v1", render_mode="ansi", **FAST)
    env.reset(seed=1)
    env.step(env.action_space.sample())
    assert "err_h=" in env.render()


def test_bad_input_is_a_clear_error():
    env = gym.make("GnssIns/SageHusa-v1", **FAST)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="NaN"):
        env.step(np.array([np.nan], np.float32))
    with pytest.raises(ValueError, match="shape"):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(ValueError, match="unknown scenario"):
        gym.make("GnssIns/SageHusa-v1", scenario="moon")
    with pytest.raises(ValueError, match="unknown filter method"):
        gym.make("GnssIns/SageHusa-v1", method="ukf")
    with pytest.raises(ValueError, match="no adjustable parameters"):
        gym.make("GnssIns/SageHusa-v1", method="kf", **FAST).reset(seed=0)
    with pytest.raises(ValueError, match="unknown environment argument"):
        gym.make("GnssIns/SageHusa-v1", scenaro="urban")
    with pytest.raises(ValueError, match="reward"):
        gym.make("GnssIns/SageHusa-v1", reward="profit")
    # out-of-range actions are clipped (documented), not an error
    _, _, _, _, info = env.step(np.array([7.0], np.float32))
    assert info["b"] == pytest.approx(0.9999)
