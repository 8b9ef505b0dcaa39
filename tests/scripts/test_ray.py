"""The Ray backend on a local Ray with 2 CPUs: eval.py gives the same results.json (timing aside) as the
local backend, tasks run in other processes, a task's exception comes back as itself."""
import json
import os
import sys

import pytest

ray = pytest.importorskip("ray", reason="Ray is not installed (pip install 'navgym[distributed]')")

import eval as eval_cli  # noqa: E402
from agents.backends import RayBackend  # noqa: E402


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray (2 CPUs) for the module; eval.py and the sweep reuse it instead of starting their own."""
    if ray.is_initialized():
        ray.shutdown()
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the workers cannot import this test file
    backend = RayBackend(workers=2)
    yield backend
    backend.close()


def strip_timing(obj):
    """results.json without wall-clock figures (keys naming a time), which differ from run to run."""
    if isinstance(obj, dict):
        return {k: strip_timing(v) for k, v in obj.items() if "time" not in k}
    if isinstance(obj, list):
        return [strip_timing(v) for v in obj]
    return obj


def test_eval_ray_equals_local(local_ray, tmp_path):
    common = ["--scenario", "seed000-sim", "--methods", "kf,sage-husa[b=0.99],rule:GnssIns/SageHusa-v0",
              "--episodes", "3", "--batch-size", "2", "--seed", "2", "--no-plots"]
    eval_cli.main([*common, "--out", str(tmp_path / "local")])
    eval_cli.main([*common, "--backend", "ray", "--workers", "2", "--out", str(tmp_path / "ray")])
    a = json.loads((tmp_path / "local" / "results.json").read_text())
    b = json.loads((tmp_path / "ray" / "results.json").read_text())
    assert strip_timing(a) == strip_timing(b)
    per = a["scenarios"]["seed000-sim"]
    assert set(per) == {"kf", "sage-husa[b=0.99]", "rule:GnssIns/SageHusa-v0"}
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
