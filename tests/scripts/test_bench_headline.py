"""benchmarks/bench_envs.py's end-to-end headline: the resets' wall and CPU shares, the cores busy and the CPU bound,
computed from the cells' own figures (fake cells with known values; no env runs)."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_envs  # noqa: E402


def test_cpu_bound_is_cores_times_rows_per_cpu_second():
    # 2 cores, 1024 rows per step, 100 CPU ms per step: 2 x 1024 / 0.1 s
    assert bench_envs.cpu_bound(1024, 100.0, 2) == pytest.approx(20480.0)
    assert bench_envs.cpu_bound(1, 0.5, 1) == pytest.approx(2000.0)
    assert 1 <= bench_envs.usable_cpus()


def test_headline_prints_the_cpu_columns_from_the_cells(monkeypatch, capsys):
    # e2e cell: 8000 env-steps/s, resets 60% of the wall time, 160 CPU ms per batched step, resets 50% of the CPU
    def fake_cell(root, kind, method, B, steps, episode_s, scenario, transition, stat="mean"):
        if kind == "e2e":
            return [8000.0, 0.6, 160.0, 0.5]
        return [1.0, 30000.0, 60.0]

    monkeypatch.setattr(bench_envs, "_run_cell", fake_cell)
    monkeypatch.setattr(bench_envs, "usable_cpus", lambda: 2)
    bench_envs.main(["--headline-only", "--methods", "sage-husa", "--e2e-batches", "1024"])
    row = [line.split() for line in capsys.readouterr().out.splitlines() if line.startswith("sage-husa")][0]
    # method B e2e step-only resets reset-CPU cores-busy bound
    assert row[1:6] == ["1024", "8000", "30000", "60%", "50%"]
    # cores busy: 0.160 CPU s per step x 8000 / 1024 steps per s = 1.25; bound: 2 x 1024 / 0.160 s = 12800
    assert row[6] == "1.25" and row[7] == "12800"


def test_small_batches_time_enough_episodes_to_hold_a_pause_at_its_share():
    # at least 40 row-episodes per cell, and never fewer than the two automatic resets of the large batches
    assert [bench_envs.e2e_episodes(B) for B in (1, 16, 20, 64, 1024)] == [40, 3, 2, 2, 2]


def test_the_warm_up_at_b1_lasts_until_the_worlds_are_drawn_16_resets_ahead():
    from envs.gnss_ins_env import make_config
    from envs.worlds_ahead import WorldsAhead
    ahead = WorldsAhead(make_config({"method": "sage-husa"}, {"episode_length_s": 60.0}))
    covered = 0  # resets whose worlds the draws so far cover (the first is the seeded reset before episode 1)
    while ahead.depth(1) < 16:
        covered += ahead.depth(1)
        ahead._draws += 1
    # the first draw of 16 is at reset covered + 1; the untimed part ends with the reset after its last episode
    assert covered + 1 == bench_envs.e2e_warmup_episodes(1) + 1
    assert bench_envs.e2e_warmup_episodes(1024) == 1
