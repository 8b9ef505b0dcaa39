"""The Ray backend on a local Ray with 2 CPUs: eval.py gives the same results.json (timing aside) as the
local backend, tasks run in other processes, a task's exception comes back as itself; train.py sweep on Ray
Tune writes its run folders and tables, reports a failing trial and goes on, and a rerun keeps finished
trials."""
import json
import os
import sys
from pathlib import Path

import pytest

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'navgym[distributed]')")

import eval as eval_cli  # noqa: E402
from agents.backends import RayBackend  # noqa: E402
from envs.json_io import without_timing  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray (2 CPUs) for the module; eval.py and the sweep reuse it instead of starting their own."""
    if ray.is_initialized():
        ray.shutdown()
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this test file
    backend = RayBackend(workers=2)
    yield backend
    backend.close()


def test_eval_ray_equals_local(local_ray, tmp_path):
    common = ["--scenario", "seed000-sim", "--methods", "kf,sage-husa[b=0.99],rule:GnssIns/SageHusa-v1",
              "--episodes", "3", "--batch-size", "2", "--seed", "2", "--no-plots"]
    eval_cli.main([*common, "--out", str(tmp_path / "local")])
    eval_cli.main([*common, "--backend", "ray", "--workers", "2", "--out", str(tmp_path / "ray")])
    a = json.loads((tmp_path / "local" / "results.json").read_text())
    b = json.loads((tmp_path / "ray" / "results.json").read_text())
    assert without_timing(a) == without_timing(b)
    per = a["scenarios"]["seed000-sim"]
    assert set(per) == {"kf", "sage-husa[b=0.99]", "rule:GnssIns/SageHusa-v1"}
    assert all(r["episodes"] == 3 for r in per.values())
    assert ray.is_initialized()  # eval.py used the Ray it found and left it running


def _pid(_):
    return os.getpid()


def _fail(x):
    if x == 2:
        raise FileNotFoundError(f"no file for item {x}")
    return x


def test_map_runs_in_workers_and_reraises_the_task_error(local_ray):
    pids = local_ray.map(_pid, list(range(4)), progress=False)
    assert len(pids) == 4 and os.getpid() not in pids
    assert local_ray.map(_fail, [0, 1], progress=False) == [0, 1]
    with pytest.raises(FileNotFoundError, match="no file for item 2"):
        local_ray.map(_fail, [0, 1, 2, 3], progress=False)


SWEEP = """envs: [GnssIns/SageHusa-v1]
scenarios: [seed000-sim]
timesteps: 256
n_envs: 4
env_kwargs: {episode_length_s: 6}
grid:
  batch_size: [32, 64, 1]   # 1: PPO refuses it, the failing trial
eval: {episodes: 2, baselines: [kf]}
"""


def run_sweep_cli(d, *extra):
    """``train.py sweep`` on ``d/sweep.yml`` into ``d/out`` (exit 1: a trial failed); the rows of sweep.csv."""
    import csv
    import train
    with pytest.raises(SystemExit) as e:
        train.main(["sweep", "--config", str(d / "sweep.yml"), "--out", str(d / "out"), "--backend", "ray", *extra])
    assert e.value.code == 1  # the batch_size=1 trial failed; the tables are written first
    return list(csv.DictReader(open(d / "out" / "sweep.csv")))


@pytest.fixture(scope="module")
def sweep(local_ray, tmp_path_factory):
    """A 3-trial sweep on Ray Tune: two PPO runs of 256 steps and one that fails (its console output in
    ``d / "console.txt"``)."""
    import contextlib
    import io
    d = tmp_path_factory.mktemp("sweep")
    (d / "sweep.yml").write_text(SWEEP)
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        rows = run_sweep_cli(d, "--workers", "2")
    (d / "console.txt").write_text(buf.getvalue())
    return d, rows


def test_sweep_on_ray_is_quiet_with_a_line_per_trial_naming_its_hyperparameters(sweep):
    d, rows = sweep
    text = (d / "console.txt").read_text()
    assert "Configuration for experiment" not in text and "Trial status" not in text  # Tune's tables: quiet
    for v in (32, 64, 1):
        started = [ln for ln in text.splitlines() if ln.startswith("sweep: trial ") and f"batch_size={v}" in ln]
        assert len(started) == 2 and "started: GnssIns/SageHusa-v1 seed000-sim ppo seed 0" in started[0], started
        assert (" failed: " if v == 1 else " done: ") in started[1]
    done = [ln for ln in text.splitlines() if " done: " in ln]
    assert all("eval_mean_reward_last " in ln and "/3 " in ln for ln in done)


def test_sweep_writes_run_folders_and_tables(sweep):
    import shlex
    import subprocess
    d, rows = sweep
    out = d / "out"
    assert [r["status"] for r in rows] == ["done", "done", "error"]
    assert [r["searched"] for r in rows] == ["batch_size=32", "batch_size=64", "batch_size=1"]
    for r in rows[:2]:
        run = out / r["run_dir"]
        for f in ("model.zip", "config.json", "best/best_model.zip", "hyperparams.yml", "trial.json"):
            assert (run / f).is_file(), f
        cfg = json.loads((run / "config.json").read_text())
        assert f"batch_size={cfg['hyperparameters']['batch_size']}" == r["searched"]  # the searched value is used
        assert cfg["n_timesteps"] == 256 and cfg["env_kwargs"]["scenario"] == "seed000-sim"
        assert float(r["eval_mean_reward_last"]) == pytest.approx(cfg["eval_mean_reward_last"])
    md = (out / "sweep.md").read_text()
    best = max(rows[:2], key=lambda r: float(r["eval_mean_reward_last"]))
    assert f"| {best['run_dir']} |" in md.split("## Best trial per group")[1]
    cmd = next(line for line in md.splitlines() if line.startswith("python "))
    assert f"ppo:{out / best['run_dir'] / 'model.zip'}" in cmd
    p = subprocess.run([sys.executable, *shlex.split(cmd)[1:], "--no-plots"], cwd=str(ROOT), capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]


def test_failing_trial_is_reported_and_the_sweep_goes_on(sweep):
    d, rows = sweep
    bad = rows[2]
    assert bad["eval_mean_reward_last"] == "" and "ValueError" in bad["error"] and "batch_size" in bad["error"]
    rec = json.loads((d / "out" / bad["run_dir"] / "trial.json").read_text())
    assert rec["status"] == "error" and "Traceback" in rec["traceback"]
    assert f"`{bad['run_dir']}`: ValueError" in (d / "out" / "sweep.md").read_text()


def test_resume_does_not_redo_finished_trials(sweep):
    d, rows = sweep
    out = d / "out"
    mtime = {r["run_dir"]: (out / r["run_dir"] / "model.zip").stat().st_mtime_ns for r in rows[:2]}
    # the second trial was interrupted: its record says running
    rec_path = out / rows[1]["run_dir"] / "trial.json"
    rec_path.write_text(json.dumps({**json.loads(rec_path.read_text()), "status": "running"}))
    again = run_sweep_cli(d)
    assert [r["status"] for r in again] == ["kept", "done", "error"]
    assert (out / rows[0]["run_dir"] / "model.zip").stat().st_mtime_ns == mtime[rows[0]["run_dir"]]
    assert (out / rows[1]["run_dir"] / "model.zip").stat().st_mtime_ns > mtime[rows[1]["run_dir"]]
    assert again[0]["eval_mean_reward_last"] == rows[0]["eval_mean_reward_last"]


OPTUNA_SWEEP = """envs: [GnssIns/SageHusa-v1]
scenarios: [seed000-sim]
timesteps: 256
n_envs: 4
env_kwargs: {episode_length_s: 6}
search: optuna
num_samples: 2
search_seed: 3
random:
  learning_rate: {loguniform: [1.0e-4, 1.0e-3]}
  batch_size: {choice: [32, 64]}
eval: {episodes: 2, baselines: [kf]}
"""


def test_optuna_sweep_on_ray_tune_proposes_what_the_local_one_does_and_resumes(local_ray, tmp_path):
    """OptunaSearch on Ray Tune: the TPE sampler seeded from the sweep file proposes the same configurations as
    the local ask / tell loop (both are startup draws); a rerun tells the sampler both and trains nothing."""
    import csv
    import train
    pytest.importorskip("optuna")
    (tmp_path / "sweep.yml").write_text(OPTUNA_SWEEP)
    tables = {}
    for backend in ("ray", "local"):
        train.main(["sweep", "--config", str(tmp_path / "sweep.yml"), "--out", str(tmp_path / backend),
                    "--backend", backend])
        tables[backend] = list(csv.DictReader(open(tmp_path / backend / "sweep.csv")))
    ray_rows = tables["ray"]
    assert [r["status"] for r in ray_rows] == ["done", "done"] and [r["config_id"] for r in ray_rows] == ["0", "1"]
    assert [r["searched"] for r in ray_rows] == [r["searched"] for r in tables["local"]]
    for r in ray_rows:
        assert (tmp_path / "ray" / r["run_dir"] / "model.zip").is_file()
    assert any((tmp_path / "ray" / "tune").iterdir())  # the Tune experiment
    mtime = [(tmp_path / "ray" / r["run_dir"] / "model.zip").stat().st_mtime_ns for r in ray_rows]
    train.main(["sweep", "--config", str(tmp_path / "sweep.yml"), "--out", str(tmp_path / "ray"), "--backend", "ray"])
    again = list(csv.DictReader(open(tmp_path / "ray" / "sweep.csv")))
    assert [r["status"] for r in again] == ["kept", "kept"]
    assert [r["eval_mean_reward_last"] for r in again] == [r["eval_mean_reward_last"] for r in ray_rows]
    assert [(tmp_path / "ray" / r["run_dir"] / "model.zip").stat().st_mtime_ns for r in ray_rows] == mtime
