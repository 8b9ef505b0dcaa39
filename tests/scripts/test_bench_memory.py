"""benchmarks/bench_memory.py: the world caches' bytes count each array once (views by their base, the thread's
shared bulk arrays once for all envs), a cell runs its layout, and bad arguments get one clear error."""
import sys
import threading
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_memory  # noqa: E402


def _core(buffers: dict, parts: list):
    ahead = SimpleNamespace(_parts={(i,): SimpleNamespace(arrays=p) for i, p in enumerate(parts)})
    return SimpleNamespace(world_buffers=SimpleNamespace(_arrays=buffers), worlds_ahead=ahead)


def test_cache_bytes_counts_every_array_once():
    def run():  # a thread of its own: its shared bulk arrays are empty
        big = np.zeros((4, 1000))  # 32,000 bytes
        other = np.zeros(500)  # 4,000 bytes
        a = _core({"x": big}, [{"f": big[:2], "w": big[2:]}, {"g": other}])
        b = _core({}, [{"f": big[1:3].T}])  # another env holding a view of the same array
        return bench_memory.cache_bytes([a]), bench_memory.cache_bytes([a, b]), bench_memory.cache_bytes([b])

    out = []
    t = threading.Thread(target=lambda: out.append(run()))
    t.start()
    t.join()
    assert out == [(36_000, 36_000, 32_000)]


def test_a_cell_runs_its_layout():
    got = bench_memory.run_cell("vector-2", 1, 3.0, "noise-burst")
    assert got["layout"] == "vector-2" and got["rows"] == 2
    assert got["caches"] > 0 and got["end"] > 0 and got["peak"] >= got["end"] - 1.0
    with pytest.raises(ValueError, match="unknown layout 'pool-3'"):
        bench_memory.run_cell("pool-3", 1, 3.0, "noise-burst")


@pytest.mark.parametrize("argv,match", [(["--episodes", "0"], "--episodes must be >= 1"),
                                        (["--compare", "/nonexistent"], "not a navgym source tree")])
def test_bad_arguments_get_one_clear_error(argv, match, capsys):
    with pytest.raises(SystemExit):
        bench_memory.main(argv)
    assert match in capsys.readouterr().err
