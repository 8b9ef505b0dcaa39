"""Damaged and mismatched files given to eval.py and train.py (issue 13): one line naming the file, exit code 2,
never a traceback. Table-driven, run in-process (``main(argv)``; an exception other than ``SystemExit(2)``
is the traceback a user would have seen)."""
import importlib.util
import json
import os
import shutil
from pathlib import Path

import pytest

from envs.datasets.errors import shared_data_dir

ROOT = Path(__file__).resolve().parents[2]


def _script(name):
    spec = importlib.util.spec_from_file_location(f"navgym_{name}_script", ROOT / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A model folder as train.py rl writes it (untrained PPO, VecNormalize, config.json) and damaged copies."""
    import gymnasium as gym
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

    import envs  # noqa: F401
    root = tmp_path_factory.mktemp("cli_files")
    good = root / "good"
    good.mkdir()
    venv = VecNormalize(DummyVecEnv([lambda: gym.make("GnssIns/SageHusa-v1", episode_length_s=6.0)]))
    PPO("MlpPolicy", venv, n_steps=16, batch_size=16, seed=0, device="cpu").save(good / "model.zip")
    venv.save(str(good / "vecnormalize.pkl"))
    (good / "config.json").write_text(json.dumps({"env": "GnssIns/SageHusa-v1", "algo": "ppo",
                                                  "env_kwargs": {"episode_length_s": 6.0}}))
    zipb = (good / "model.zip").read_bytes()

    def copy(name, **changes):
        d = root / name
        shutil.copytree(good, d)
        for f, content in changes.items():
            f = f.replace("_", ".", 1) if f in ("model_zip", "config_json", "vecnormalize_pkl") else f
            if content is None:
                (d / f).unlink()
            else:
                (d / f).write_bytes(content)
        return d / "model.zip"

    rng = __import__("numpy").random.default_rng(0)
    f = {
        "good": good / "model.zip",
        "junk": copy("junk", model_zip=rng.bytes(5000)),
        "truncated": copy("truncated", model_zip=zipb[: len(zipb) // 2]),
        "bad_vecnormalize": copy("badvn", vecnormalize_pkl=b"not a pickle\x00\xff"),
        "wrong_vecnormalize": None,
        "no_config": copy("nocfg", config_json=None),
        "unknown_env": copy("unkenv", config_json=json.dumps({"env": "GnssIns/Nope-v0", "env_kwargs": {}}).encode()),
        "garbage_config": copy("badcfg", config_json=b"\xff\xfe garbage"),
        "bad_env_kwarg": copy("badkw", config_json=json.dumps({"env": "GnssIns/SageHusa-v1",
                                                               "env_kwargs": {"scenaro": "x"}}).encode()),
        "no_algo": copy("noalgo", config_json=json.dumps({"env": "GnssIns/SageHusa-v1",
                                                          "env_kwargs": {"episode_length_s": 6.0}}).encode()),
        "other_env": copy("otherenv", config_json=json.dumps({"env": "GnssIns/MASTKF-v1", "env_kwargs": {}}).encode()),
    }
    other = VecNormalize(DummyVecEnv([lambda: gym.make("GnssIns/MASTKF-v1", episode_length_s=6.0)]))
    other.save(str(root / "other_vecnormalize.pkl"))  # statistics of another observation size
    f["wrong_vecnormalize"] = copy("wrongvn", vecnormalize_pkl=(root / "other_vecnormalize.pkl").read_bytes())
    (root / "tuning_garbage.json").write_bytes(rng.bytes(300))
    f["tuning_garbage"] = root / "tuning_garbage.json"
    (root / "tuning_list.json").write_text("[1, 2]")
    f["tuning_list"] = root / "tuning_list.json"
    (root / "afile").write_text("x")
    f["afile"] = root / "afile"
    (root / "hp_unknown.yml").write_text("GnssIns/SageHusa-v1:\n  n_steps: 16\n  learning_ratee: 0.1\n")
    f["hp_unknown"] = root / "hp_unknown.yml"
    (root / "hp_garbage.yml").write_bytes(b"\xff\xfe: [\n")
    f["hp_garbage"] = root / "hp_garbage.yml"
    (root / "hp_kwargs.yml").write_text("GnssIns/SageHusa-v1:\n  env_kwargs: [1, 2]\n")
    f["hp_kwargs"] = root / "hp_kwargs.yml"
    (root / "hp_steps.yml").write_text("GnssIns/SageHusa-v1:\n  n_timesteps: lots\n")
    f["hp_steps"] = root / "hp_steps.yml"
    for name, text in (("hp_float_steps", "n_steps: 64.5"), ("hp_negative_steps", "n_steps: -5"),
                       ("hp_gamma_text", "gamma: high"), ("hp_gamma_range", "gamma: 1.5"),
                       ("hp_batch_one", "batch_size: 1"), ("hp_huge", "n_timesteps: 1.0e+30"),
                       ("hp_kwargs_type", "policy_kwargs: [64, 64]")):
        (root / f"{name}.yml").write_text(f"GnssIns/SageHusa-v1:\n  {text}\n")
        f[name] = root / f"{name}.yml"
    (root / "notedir").mkdir()
    f["notedir"] = root / "notedir"
    reach = shared_data_dir() / "instinct_tckf_static"
    if (reach / "reach-m2-01_raw_202306291111.nav").is_file():
        (root / "late_truth.csv").write_text("gps_week,tow_s,x_m,y_m,z_m\n" + "".join(
            f"2268,{390000 + i}.0,4157198.0,671195.0,4774772.0\n" for i in range(10)))  # an hour after the recording
        (root / "late.toml").write_text(
            f'name = "late"\n[gnss]\nformat = "rinex"\nobs = "{reach / "reach-m2-01_raw_202306291111.23O"}"\n'
            f'nav = ["{reach / "reach-m2-01_raw_202306291111.nav"}"]\nsystems = ["G"]\ninterval_s = 1.0\n'
            f'[truth]\nformat = "navgym-csv"\nfile = "{root / "late_truth.csv"}"\n[imu]\nsource = "synthesized"\n')
        f["late_spec"], f["late_truth"] = root / "late.toml", root / "late_truth.csv"
    src = shared_data_dir() / "smartloc"
    if src.is_dir():
        dd = root / "damaged_data" / "smartloc"
        shutil.copytree(src, dd)
        inp = dd / "Berlin_Potsdamer_Platz_Input.txt"
        b = inp.read_bytes()
        inp.write_bytes(b[: len(b) // 2] + b"\x07\x00garbage" + b[len(b) // 2:])
        f["damaged_data"] = root / "damaged_data"
        f["damaged_input"] = inp
        dd = root / "implausible_data" / "smartloc"  # well-formed, one pseudorange 1e7 times too long
        shutil.copytree(src, dd)
        inp = dd / "Berlin_Potsdamer_Platz_Input.txt"
        lines = inp.read_text().split("\n")
        i = [j for j, ln in enumerate(lines) if ln.startswith("pseudorange3")][5000]
        t = lines[i].split()
        t[2] = repr(float(t[2]) * 1e7)
        lines[i] = " ".join(t)
        inp.write_text("\n".join(lines))
        f["implausible_data"] = root / "implausible_data"
        f["implausible_input"] = inp
    f["out"] = root / "out"
    return f


E = ["--scenario", "seed000-sim", "--episodes", "1", "--no-plots"]
# (script, argv with {key} for fixture files, the file the message must name, text it must contain)
PROBES = [
    ("eval", ["--methods", "kf,ppo:{junk}", *E], "junk", "cannot load it as a ppo model"),
    ("eval", ["--methods", "kf,ppo:{truncated}", *E], "truncated", "cannot load it as a ppo model"),
    ("eval", ["--methods", "kf,ppo:{bad_vecnormalize}", *E], "bad_vecnormalize~vecnormalize.pkl",
     "not a VecNormalize file"),
    ("eval", ["--methods", "kf,ppo:{wrong_vecnormalize}", *E], "wrong_vecnormalize~vecnormalize.pkl",
     "do not fit the model's observations"),
    ("eval", ["--methods", "kf,ppo:{no_config}", *E], "no_config", "no config.json beside the model"),
    ("eval", ["--methods", "kf,ppo:{unknown_env}", *E], "unknown_env~config.json",
     "unknown environment id 'GnssIns/Nope-v0'"),
    ("eval", ["--methods", "kf,ppo:{garbage_config}", *E], "garbage_config~config.json", "not a JSON file"),
    ("eval", ["--methods", "kf,ppo:{bad_env_kwarg}", *E], "bad_env_kwarg~config.json",
     "unknown environment argument(s) ['scenaro']"),
    ("eval", ["--methods", "kf,sac:{good}", *E], "good", "trained with 'ppo'"),
    ("eval", ["--methods", "kf,sac:{no_algo}", *E], "no_algo", "cannot load it as a sac model; it holds a "
                                                                  "ActorCriticPolicy"),
    ("eval", ["--methods", "kf,ppo:{other_env}", *E], "other_env", "the model observes"),
    ("eval", ["--methods", "kf,tuned:{tuning_garbage}", *E], "tuning_garbage", "not a tuning result file"),
    ("eval", ["--methods", "kf,tuned:{tuning_list}", *E], "tuning_list", "not a tuning result file"),
    ("eval", ["--methods", "kf", *E, "--out", "{afile}"], "afile", "is a file, not a directory"),
    ("eval", ["--methods", "kf", *E, "--out", "{afile}/sub"], "afile", "cannot write there"),
    ("eval", ["--experiment", "seed000", "--out", "{afile}/sub"], "afile", "cannot write there"),
    ("eval", ["--methods", "kf", "--scenario", "smartloc-potsdamer-platz", "--episodes", "1", "--no-plots"],
     "damaged_input", "is not a number"),
    ("train", ["tune", "--env-kwargs", "scenario=smartloc-potsdamer-platz", "episode_length_s=10", "--n-train", "1",
               "--grid-size", "2"], "damaged_input", "is not a number"),
    ("train", ["rl", "--config", "{hp_unknown}", "--timesteps", "32"], "hp_unknown",
     "unknown hyperparameter(s) 'learning_ratee' for ppo"),
    ("train", ["rl", "--config", "{hp_garbage}", "--timesteps", "32"], "hp_garbage", "not valid YAML"),
    ("train", ["rl", "--config", "{hp_kwargs}", "--timesteps", "32"], "hp_kwargs", "env_kwargs must be a mapping"),
    ("train", ["rl", "--config", "{hp_steps}"], "hp_steps", "n_timesteps must be a whole number"),
    ("train", ["rl", "--timesteps", "32", "--out", "{afile}/sub"], "afile", "cannot write there"),
    ("train", ["tune", "--n-train", "1", "--grid-size", "2", "--out", "{afile}/sub"], "afile", "cannot write there"),
    ("train", ["zupt", "--model", "mlp", "--out", "{afile}/sub"], "afile", "cannot write there"),
    ("train", ["zupt", "--model", "mlp", "--seed", "-1"], None, "--seed must be >= 0"),
    # the "front door" probes: checked up front, one line (SB3's AssertionError, a traceback after the run, or
    # silently accepted before)
    ("train", ["rl", "--config", "{hp_float_steps}", "--timesteps", "32"], "hp_float_steps",
     "n_steps must be int for ppo (stable-baselines3's signature), got 64.5"),
    ("train", ["rl", "--config", "{hp_negative_steps}", "--timesteps", "32"], "hp_negative_steps",
     "n_steps must be >= 1, got -5"),
    ("train", ["rl", "--config", "{hp_gamma_text}", "--timesteps", "32"], "hp_gamma_text", "gamma must be float"),
    ("train", ["rl", "--config", "{hp_gamma_range}", "--timesteps", "32"], "hp_gamma_range",
     "gamma must be in [0.0, 1.0], got 1.5"),
    ("train", ["rl", "--config", "{hp_batch_one}", "--timesteps", "32"], "hp_batch_one", "batch_size must be >= 2"),
    ("train", ["rl", "--config", "{hp_kwargs_type}", "--timesteps", "32"], "hp_kwargs_type",
     "policy_kwargs must be dict"),
    ("train", ["rl", "--config", "{hp_huge}"], "hp_huge", "n_timesteps must be at most 1e+10"),
    ("train", ["rl", "--timesteps", "1e30"], None, "--timesteps must be a whole number of steps <= 1e+10"),
    ("train", ["rl", "--timesteps", "100.5"], None, "--timesteps must be a whole number of steps"),
    ("train", ["rl", "--env", "GnssIns/STKF-v1", "--env-kwargs", "method=ma-stkf"], None,
     "method 'ma-stkf' runs another adaptive law (MeasurementAdaptiveSTKF) than this env's 'stkf'"),
    ("train", ["tune", "--env", "GnssIns/STKF-v1", "--env-kwargs", "method=ma-stkf"], None,
     "'ma-stkf' has its own env: GnssIns/MASTKF-v1"),
    ("train", ["rl", "--env-kwargs", "divergence_bound_m=1e-9"], None, "divergence_bound_m must be >= 50 m"),
    ("eval", ["--methods", "kf", *E, "--note", "{afile}/note.md"], "afile", "is a file, not a directory"),
    ("eval", ["--methods", "kf", *E, "--note", "{notedir}"], "notedir", "is a directory; give the note's file name"),
    ("eval", ["--methods", "kf", "--scenario", "{late_spec}", "--episodes", "1", "--no-plots"], "late_truth",
     "no overlap"),
    ("eval", ["--methods", "kf", "--scenario", "smartloc-potsdamer-platz", "--episodes", "1", "--no-plots"],
     "implausible_input", "is impossible: its satellite"),
]


@pytest.mark.parametrize("script, argv, culprit, msg", PROBES,
                         ids=[f"{s}-{i}-{m[:30]}" for i, (s, _, _, m) in enumerate(PROBES)])
def test_bad_file_one_line_naming_it_exit_2(files, script, argv, culprit, msg, capsys, monkeypatch):
    if "smartloc" in " ".join(argv):
        if "damaged_data" not in files:
            pytest.skip(f"no smartLoc data under {shared_data_dir()}")
        data = "implausible_data" if culprit == "implausible_input" else "damaged_data"
        monkeypatch.setenv("NAVGYM_DATA_DIR", str(files[data]))
    if any("{late" in a for a in argv) and "late_spec" not in files:
        pytest.skip(f"no Reach M2 RINEX data under {shared_data_dir()}")
    args = [a.format(**{k: v for k, v in files.items() if v is not None}) for a in argv]
    if "--out" not in args:
        args += ["--out", str(files["out"] / f"{script}{len(os.listdir(files['out'].parent))}")]
    mod = _script(script)
    capsys.readouterr()
    with pytest.raises(SystemExit) as exc:
        mod.main(args)
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err, "no message"
    line = err[-1]
    assert line.startswith(f"{script}.py: error: ") and msg in line, line
    if culprit is not None:
        key, _, leaf = culprit.partition("~")
        path = Path(files[key])
        named = path.parent / leaf if leaf else path
        assert str(named) in line, line
