"""Ctrl-C (SIGINT to the whole foreground process group, as a terminal sends it): one line, exit status 130, no
traceback (the world prefetch workers of train.py rl included); the rl run folder says it is incomplete and keeps
best/ and checkpoints/; eval.py leaves no empty folder."""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.skipif(os.name != "posix", reason="process groups and SIGINT: POSIX")


def _children(pid: int) -> set[int]:
    """The pids of ``pid``'s child processes (Linux /proc; empty elsewhere)."""
    out = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out |= {int(x) for x in (task / "children").read_text().split()}
        except OSError:
            pass
    return out


def _ctrl_c(cmd, ready, settle_s: float):
    """Run ``cmd`` in a process group of its own; once ``ready()`` and ``settle_s`` later, SIGINT to the group.
    Returns (exit status, stderr, the children the process had then)."""
    # a shell starts its background jobs with SIGINT ignored, and an ignored signal stays ignored across exec: with
    # Python's handler installed here while the child is forked, the child starts with SIGINT at its default, as
    # from a terminal, however this test run was started
    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        p = subprocess.Popen([sys.executable, *cmd], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True, start_new_session=True)
    finally:
        signal.signal(signal.SIGINT, before)
    t0 = time.time()
    while not ready() and p.poll() is None and time.time() - t0 < 600:
        time.sleep(0.2)
    assert p.poll() is None, p.stderr.read()[-2000:]
    time.sleep(settle_s)
    kids = _children(p.pid)
    os.killpg(p.pid, signal.SIGINT)
    _, err = p.communicate(timeout=120)
    return p.returncode, err, kids


def _gone(pids, timeout_s=10.0) -> bool:
    t0 = time.time()
    while time.time() - t0 < timeout_s:
        if not any(Path(f"/proc/{q}").exists() and "zombie" not in Path(f"/proc/{q}/status").read_text()
                   for q in pids):
            return True
        time.sleep(0.2)
    return False


def test_ctrl_c_during_train_rl_is_one_line_and_marks_the_run_incomplete(tmp_path):
    out = tmp_path / "run"
    rc, err, kids = _ctrl_c(["train.py", "rl", "--quick", "--timesteps", "200000", "--no-progress", "--out", str(out)],
                            lambda: (out / "INCOMPLETE").exists(), 12.0)
    assert rc == 130, err[-3000:]
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err[-3000:]
    lines = err.strip().splitlines()
    assert lines[-1].startswith(f"train.py: interrupted: {out} is incomplete: training interrupted (Ctrl-C) at step ")
    assert len(lines) == 1, err[-3000:]
    marker = (out / "INCOMPLETE").read_text()
    assert "interrupted (Ctrl-C) at step" in marker and "model.zip not written" in marker
    import json
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["status"] == "interrupted" and 0 <= cfg["completed_timesteps"] < 200000
    assert not (out / "model.zip").exists()
    for d in ("best", "checkpoints"):  # what the training wrote before the Ctrl-C stays
        assert (out / d).is_dir()
    assert _gone(kids), "a world prefetch worker outlived the run"


def test_ctrl_c_during_eval_is_one_line_and_leaves_no_empty_folder(tmp_path):
    out = tmp_path / "ev"
    rc, err, _ = _ctrl_c(["eval.py", "--scenario", "seed000-sim", "--methods", "kf,stkf", "--episodes", "300",
                          "--batch-size", "1", "--no-plots", "--out", str(out)], out.exists, 2.0)
    assert rc == 130 and "Traceback" not in err, err[-3000:]
    assert err.strip().splitlines()[-1] == "eval.py: interrupted (Ctrl-C); no results written"
    assert not out.exists()
