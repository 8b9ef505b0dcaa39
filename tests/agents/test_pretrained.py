"""The shipped models (pretrained/) load and run on a fresh clone, and agents.pretrained picks by its own
held-out figure."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
PRETRAINED = ROOT / "pretrained"


def test_shipped_policy_and_learned_r_run_in_eval(tmp_path):
    """The issue's command on a fresh clone, shortened to 2 episodes: eval.py runs the shipped per-satellite
    policy (trained on urban-smartloc, 16 channels) and the shipped learned-r on urban-transition beside kf-huber
    (the method the policy acts on) and oracle-r; every row is finite, and the policy changes kf-huber's
    errors (it acts: the shipped weights are not the x1 start)."""
    out = tmp_path / "r"
    p = subprocess.run([sys.executable, str(ROOT / "eval.py"), "--scenario", "urban-transition", "--methods",
                        "kf-huber,learned-r:pretrained/learned-r/model.pt,ppo:pretrained/satellite-r/model.zip,oracle-r",
                        "--episodes", "2", "--no-plots", "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                       timeout=600)
    assert p.returncode == 0, p.stderr
    per = json.loads((out / "results.json").read_text())["scenarios"]["urban-transition"]
    ppo, ref = per["ppo:pretrained/satellite-r/model.zip"], per["kf-huber"]
    for r in per.values():
        assert np.isfinite(r["rmse_h_m"]) and r["diverged"] == 0
    assert abs(ppo["rmse_h_m"] - ref["rmse_h_m"]) > 1e-3
    assert "learned-r:pretrained/learned-r/model.pt" in per


def test_shipped_policy_files_and_choice():
    """pretrained/satellite-r holds the three files; its config names the env, a per-satellite id, and the run it
    came from is the candidate with the highest training-time evaluation reward."""
    from agents.policies import Sb3Policy
    d = PRETRAINED / "satellite-r"
    assert {p.name for p in d.iterdir()} >= {"model.zip", "vecnormalize.pkl", "config.json"}
    cfg = json.loads((d / "config.json").read_text())
    p = cfg["pretrained"]
    assert p["criterion"] == "max eval_mean_reward_last"
    assert p["source"] == max(p["candidates"], key=p["candidates"].get)
    pol = Sb3Policy.load(d / "model.zip", "ppo")
    assert pol.env_id.startswith("GnssIns/Satellite") and pol.env_kwargs["scenario"] == "urban-smartloc"


def _fake_run(root: Path, name: str, reward, status="complete"):
    d = root / name
    d.mkdir(parents=True)
    (d / "model.zip").write_bytes(b"zip " + name.encode())
    (d / "config.json").write_text(json.dumps({"env": "E", "eval_mean_reward_last": reward, "status": status}))
    return d


def test_pick_policy_by_training_eval_reward(tmp_path):
    """The highest last evaluation reward wins; incomplete runs and NaN figures are not candidates; the copy
    carries the source and every candidate's figure; no run with a figure is one clear error."""
    from agents import pretrained as pt
    _fake_run(tmp_path, "ppo-s0", -10.0)
    _fake_run(tmp_path, "ppo-s1", -5.0)
    _fake_run(tmp_path, "ppo-s2", -1.0, status="running")
    _fake_run(tmp_path, "ppo-s3", float("nan"))
    run, figs = pt.pick_policy([str(tmp_path / "ppo-s*")])
    assert run.name == "ppo-s1" and set(figs) == {str(tmp_path / "ppo-s0"), str(tmp_path / "ppo-s1")}
    written = pt.ship(run, tmp_path / "out", pt.POLICY_FILES, "max eval_mean_reward_last", figs)
    assert [w.name for w in written] == ["model.zip", "config.json"]  # no vecnormalize.pkl in that run
    assert (tmp_path / "out" / "model.zip").read_bytes() == b"zip ppo-s1"
    c = json.loads((tmp_path / "out" / "config.json").read_text())
    assert c["env"] == "E" and c["pretrained"]["source"] == str(run)
    with pytest.raises(ValueError, match="no complete run"):
        pt.pick_policy([str(tmp_path / "ppo-s2")])
    with pytest.raises(ValueError, match="no run folder matches"):
        pt.pick_policy([str(tmp_path / "nothing*")])


def test_pick_learned_r_by_validation_nll(tmp_path):
    from agents import pretrained as pt
    for name, nll in (("a", 4.8), ("b", 4.7), ("c", 4.9)):
        d = tmp_path / name
        d.mkdir()
        (d / "model.pt").write_bytes(b"x")
        (d / "metrics.json").write_text(json.dumps({"val": {"nll_m": nll}, "test": {"nll_m": 0.0}}))
    run, figs = pt.pick_learned_r([str(tmp_path / "*")])
    assert run.name == "b" and len(figs) == 3
    with pytest.raises(ValueError, match="missing"):
        pt.ship(run, tmp_path / "out", pt.LEARNED_R_FILES, "min val.nll_m", figs)  # no config.json in b
