"""train.py sweep with ``search: optuna`` on the local backend: Optuna's TPE sampler, seeded from the sweep
file, proposes the configurations (the same ones on a rerun in a fresh folder); each one is a run folder and
a row of the sweep table; a rerun keeps finished configurations and tells the sampler their results; a bad
search field is one line naming the file and the field."""
import csv
import json
import sys

import pytest

pytest.importorskip("optuna", reason="Optuna is not installed (pip install 'navgym[distributed]')")

import train  # noqa: E402
from agents.sweep import load_sweep  # noqa: E402

SWEEP = """envs: [GnssIns/SageHusa-v1]
scenarios: [seed000-sim]
timesteps: 256
env_kwargs: {episode_length_s: 6}
hyperparams: {n_steps: 16}
search: optuna
num_samples: 3
search_seed: 7
random:
  learning_rate: {loguniform: [1.0e-4, 1.0e-3]}
  batch_size: {choice: [32, 64]}
  gamma: {uniform: [0.9, 0.99]}
  n_epochs: {randint: [1, 2]}
run_dir: "{algo}{hp}-s{seed}"
"""


def sweep(config, out):
    """``train.py sweep`` (local backend); the rows of sweep.csv."""
    train.main(["sweep", "--config", str(config), "--out", str(out)])
    return list(csv.DictReader(open(out / "sweep.csv")))


@pytest.fixture(scope="module")
def first(tmp_path_factory):
    d = tmp_path_factory.mktemp("optuna")
    (d / "sweep.yml").write_text(SWEEP)
    return d, sweep(d / "sweep.yml", d / "a")


def test_three_trials_write_table_and_run_folders(first):
    d, rows = first
    assert [r["status"] for r in rows] == ["done"] * 3 and [r["config_id"] for r in rows] == ["0", "1", "2"]
    assert len({r["searched"] for r in rows}) == 3
    for r in rows:
        run = d / "a" / r["run_dir"]
        for f in ("model.zip", "config.json", "hyperparams.yml", "trial.json"):
            assert (run / f).is_file(), f
        trial = json.loads((run / "trial.json").read_text())["trial"]
        hp = json.loads((run / "config.json").read_text())["hyperparameters"]
        for k, v in trial["searched"].items():  # the proposed values are the ones trained with
            assert hp[k] == v, k
        assert 1e-4 <= hp["learning_rate"] <= 1e-3 and hp["batch_size"] in (32, 64) and 0.9 <= hp["gamma"] <= 0.99
        assert hp["n_epochs"] in (1, 2)
        assert float(r["eval_mean_reward_last"]) == pytest.approx(
            json.loads((run / "config.json").read_text())["eval_mean_reward_last"])
    md = (d / "a" / "sweep.md").read_text()
    assert "Optuna's TPE sampler (seed 7)" in md and "## Best trial per group" in md


def test_rerun_in_a_fresh_folder_proposes_the_same_configurations(first):
    d, rows = first
    again = sweep(d / "sweep.yml", d / "b")
    assert [r["searched"] for r in again] == [r["searched"] for r in rows]
    other = d / "other.yml"
    other.write_text((d / "sweep.yml").read_text().replace("search_seed: 7", "search_seed: 8"))
    from agents.optuna_search import prepare_study, search_space
    study, _, _ = prepare_study(load_sweep(other), d / "empty")
    assert study.ask(search_space(load_sweep(other))).params != json.loads(
        (d / "a" / rows[0]["run_dir"] / "trial.json").read_text())["trial"]["searched"]


def test_resume_keeps_finished_trials_and_tells_the_sampler(first, monkeypatch):
    import shutil
    import agents.training as training
    from agents.optuna_search import prepare_study
    d, rows = first
    shutil.copytree(d / "a", d / "c")
    (d / "c" / rows[1]["run_dir"] / "model.zip").unlink()  # configuration 1 was interrupted
    cfg = load_sweep(d / "sweep.yml")
    study, recorded, n_ask = prepare_study(cfg, d / "c")
    assert [(r.config_id, r.value is not None) for r in recorded] == [(0, True), (1, False), (2, True)]
    assert n_ask == 1
    from optuna.trial import TrialState
    done = study.get_trials(states=(TrialState.COMPLETE,))
    assert [t.value for t in done] == pytest.approx([float(rows[0]["eval_mean_reward_last"]),
                                                     float(rows[2]["eval_mean_reward_last"])])
    assert len(study.get_trials(states=(TrialState.WAITING,))) == 1  # the interrupted one, proposed first again
    trained = []
    orig = training.train_rl
    monkeypatch.setattr(training, "train_rl", lambda *a, **k: trained.append(a[2]) or orig(*a, **k))
    again = sweep(d / "sweep.yml", d / "c")
    assert [r["status"] for r in again] == ["kept", "kept", "done"]  # only the interrupted one trains again
    assert [str(p) for p in trained] == [str(d / "c" / rows[1]["run_dir"])]
    assert sorted(r["searched"] for r in again) == sorted(r["searched"] for r in rows)
    trained.clear()
    assert [r["status"] for r in sweep(d / "sweep.yml", d / "c")] == ["kept"] * 3 and trained == []


@pytest.mark.parametrize("extra, msg", [
    ("search: bayes\n", "search: must be one of grid, optuna, got 'bayes'"),
    ("search: optuna\n", "num_samples: search: optuna needs an integer >= 1, got None"),
    ("search: optuna\nnum_samples: 2\nrandom: {learning_rate: {loguniform: [1.0e-3, 1.0e-4]}}\n",
     "random.learning_rate: loguniform needs lo <= hi"),
    ("search: optuna\nnum_samples: 2\nrandom: {gamma: {uniform: [0.9]}}\n", "random.gamma: uniform needs [lo, hi]"),
    ("search: optuna\nnum_samples: 2\nrandom: {net_arch: {choice: [[64], [128]]}}\n",
     "random.net_arch: search: optuna needs choice values that are numbers"),
    ("search: optuna\nnum_samples: 2\ngrid: {gamma: [0.9]}\nrandom: {n_epochs: {randint: [1, 3]}}\n",
     "grid: search: optuna takes its ranges from random"),
    ("search: optuna\nnum_samples: 2\n", "random: search: optuna needs at least one range"),
    ("search: optuna\nnum_samples: 2\nrandom: {gamma: {uniform: [0.9, 0.99]}}\ndirection: up\n",
     "direction: must be one of maximize, minimize, got 'up'"),
    ("num_samples: 2\n", "num_samples: is the number of Optuna trials: it needs search: optuna"),
])
def test_bad_search_fields_are_one_line_naming_file_and_field(tmp_path, capsys, extra, msg):
    p = tmp_path / "sweep.yml"
    p.write_text("envs: [GnssIns/SageHusa-v1]\ntimesteps: 256\n" + extra)
    with pytest.raises(SystemExit) as e:
        train.main(["sweep", "--config", str(p), "--out", str(tmp_path / "out")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and str(p) in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "out").exists()


def test_without_optuna_the_error_says_how_to_install(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "optuna", None)
    p = tmp_path / "sweep.yml"
    p.write_text("envs: [GnssIns/SageHusa-v1]\nsearch: optuna\nnum_samples: 2\n"
                 "random: {gamma: {uniform: [0.9, 0.99]}}\n")
    with pytest.raises(SystemExit) as e:
        train.main(["sweep", "--config", str(p), "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip()
    assert e.value.code == 2 and len(err.splitlines()) == 1
    assert f"{p}: search: optuna needs Optuna" in err and "pip install 'navgym[distributed]'" in err


def test_shipped_optuna_example_is_valid():
    from pathlib import Path
    cfg = load_sweep(Path(__file__).resolve().parents[2] / "configs" / "sweep_optuna.yml")
    assert cfg.search == "optuna" and cfg.num_samples == 12 and set(cfg.random) == {
        "learning_rate", "gamma", "batch_size", "n_epochs"}


def test_a_failing_configuration_is_reported_and_told_as_failed(tmp_path, capsys):
    p = tmp_path / "sweep.yml"
    p.write_text(SWEEP.replace("batch_size: {choice: [32, 64]}", "batch_size: {choice: [1]}")
                 .replace("num_samples: 3", "num_samples: 2"))  # PPO refuses batch_size 1
    with pytest.raises(SystemExit) as e:
        sweep(p, tmp_path / "out")
    assert e.value.code == 1
    rows = list(csv.DictReader(open(tmp_path / "out" / "sweep.csv")))
    assert [r["status"] for r in rows] == ["error", "error"] and all("batch_size" in r["error"] for r in rows)
    rec = json.loads((tmp_path / "out" / rows[0]["run_dir"] / "trial.json").read_text())
    assert rec["status"] == "error" and "Traceback" in rec["traceback"]
