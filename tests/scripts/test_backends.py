"""Backends without Ray: argument errors and the one-line install hint when Ray is missing; the local trial
runner reports a failing trial and goes on."""
import sys
from pathlib import Path

import pytest

import eval as eval_cli
from agents.backends import LocalBackend, TrialOutcome, check_backend_args

ROOT = Path(__file__).resolve().parents[2]


def _no_ray(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # 'import ray' raises ImportError


def test_backend_ray_without_ray_says_how_to_install(monkeypatch, capsys, tmp_path):
    _no_ray(monkeypatch)
    with pytest.raises(SystemExit) as e:
        eval_cli.main(["--scenario", "seed000-sim", "--methods", "kf", "--episodes", "1", "--backend", "ray",
                       "--out", str(tmp_path)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "pip install 'navgym[distributed]'" in err
    assert not (tmp_path / "results.json").exists()


@pytest.mark.parametrize("args, msg", [
    (("--address", "auto"), "--address joins a Ray cluster: it needs --backend ray"),
    (("--workers", "2"), "--workers sets the number of Ray workers: it needs --backend ray"),
    (("--backend", "ray", "--workers", "0"), "--workers must be >= 1, got 0"),
])
def test_backend_argument_errors(args, msg, capsys, tmp_path):
    with pytest.raises(SystemExit) as e:
        eval_cli.main(["--scenario", "seed000-sim", "--episodes", "1", *args, "--out", str(tmp_path)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert msg in err and len(err.splitlines()) == 1


def test_experiment_with_ray_backend_is_refused(capsys, tmp_path):
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'navgym[distributed]')")
    with pytest.raises(SystemExit) as e:
        eval_cli.main(["--experiment", "seed000", "--backend", "ray", "--out", str(tmp_path)])
    assert e.value.code == 2 and "--experiment runs here only" in capsys.readouterr().err


def test_check_backend_args_names_the_backend():
    with pytest.raises(ValueError, match="--backend must be one of local, ray, got 'dask'"):
        check_backend_args("dask")


def _trial(c):
    if c["x"] < 0:
        raise ValueError(f"x must be >= 0, got {c['x']}")
    return {"y": 2 * c["x"]}


def test_local_trials_report_a_failure_and_go_on(tmp_path):
    out = LocalBackend().run_trials(_trial, [{"x": 1}, {"x": -1}, {"x": 3}], storage=tmp_path)
    assert out == [TrialOutcome({"x": 1}, {"y": 2}, None),
                   TrialOutcome({"x": -1}, None, "ValueError: x must be >= 0, got -1"),
                   TrialOutcome({"x": 3}, {"y": 6}, None)]


def _closed_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]  # nothing listens there once the socket is closed


@pytest.mark.parametrize("script", ["eval", "train"])
def test_ray_address_where_no_cluster_answers_is_one_line_within_seconds(script, capsys, tmp_path):
    """``ray.init`` retried such an address for over 400 s without a word; the address is probed up front."""
    import time
    pytest.importorskip("ray", reason="Ray is not installed (pip install 'navgym[distributed]')")
    import train as train_cli
    addr = f"127.0.0.1:{_closed_port()}"
    out = tmp_path / "out"
    argv = (["--scenario", "seed000-sim", "--methods", "kf", "--episodes", "1"] if script == "eval" else
            ["sweep", "--config", str(ROOT / "configs" / "sweep.yml")]) + ["--backend", "ray", "--address", addr, "--out", str(out)]
    t0 = time.perf_counter()
    with pytest.raises(SystemExit) as e:
        (eval_cli if script == "eval" else train_cli).main(argv)
    assert e.value.code == 2 and time.perf_counter() - t0 < 30
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"{script}.py: error: --address '{addr}': no Ray cluster answers")
    assert not out.exists()  # refused before anything was created


def test_progress_eta_leaves_out_the_first_batch(capsys):
    """The first batch pays numba's compilation on a first run (minutes): the bar gives no ETA before it ends and
    counts its rate, ETA and elapsed time from there, so a slow first batch does not inflate the estimate."""
    import time

    from agents.backends import LocalBackend

    def fn(x):
        time.sleep(1.2 if x == 0 else 0.05)
        return x
    assert LocalBackend().map(fn, [0, 1, 2, 3], desc="eval") == [0, 1, 2, 3]
    frames = [f for f in capsys.readouterr().err.replace("\n", "\r").split("\r") if "eval" in f]
    before = [f for f in frames if " 0/4 " in f]
    assert before and all("ETA after the first batch" in f for f in before)
    assert any(" 1/4 [00:00<?" in f for f in frames)  # the clock restarted when the first batch ended
    assert " 4/4 [00:00<00:00" in frames[-1]  # 1.35 s in all, 0.15 s after the first batch


def test_trial_progress_lines_name_the_trial_and_leave_the_first_out_of_the_eta(capsys):
    import itertools

    from agents.backends import LocalBackend, TrialProgress
    clock = itertools.count(0.0, 50.0)  # each reading of the clock: 50 s later
    p = TrialProgress(4, describe=lambda c: f"lr={c['lr']}", metric="m", workers=2, prefix="sweep: trial",
                      clock=lambda: next(clock))
    p.start("a", {"lr": 0.1})                               # t = 0
    first = p.end("a", result={"m": -1.5})                  # t = 50: 50 s
    p.start("b", {"lr": 0.2})                               # t = 100
    p.start("c", {"lr": 0.3})                               # t = 150
    second = p.end("c", error="ValueError: bad\nmore")      # t = 200: 50 s
    assert first == "sweep: trial 1/4 done: lr=0.1: m -1.5 in 50 s; ETA 75 s"  # 3 left x 50 s / 2 workers
    assert second == "sweep: trial 3/4 failed: lr=0.3: ValueError: bad in 50 s; ETA 50 s"
    err = capsys.readouterr().err
    assert "sweep: trial 2/4 started: lr=0.2" in err and first in err

    def fn(c):
        if c == 2:
            raise ValueError("two")
        return {"m": c}
    out = LocalBackend().run_trials(fn, [1, 2], storage="unused", progress=TrialProgress(2, str, "m"))
    assert [o.error for o in out] == [None, "ValueError: two"]
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("trial ")]
    assert [ln.split(" in ")[0] for ln in lines] == ["trial 1/2 started: 1", "trial 1/2 done: 1: m 1",
                                                     "trial 2/2 started: 2", "trial 2/2 failed: 2: ValueError: two"]
