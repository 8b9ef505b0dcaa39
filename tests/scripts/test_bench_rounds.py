"""benchmarks/bench_envs.py ``--rounds N`` without ``--compare``: every cell N times, all cells in turn per round,
each row the median with the range of the N."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_envs  # noqa: E402


def test_rounds_run_the_cells_in_turn_and_print_median_and_range(monkeypatch, capsys):
    order = []
    rates = {("sage-husa", 1): [100.0, 300.0, 200.0], ("sage-husa", 16): [10.0, 30.0, 20.0],
             ("stkf", 1): [5.0, 7.0, 6.0], ("stkf", 16): [1.0, 3.0, 2.0]}

    def fake_cell(root, kind, method, B, steps, episode_s, scenario, transition, stat):
        assert kind == "rate" and transition == "fused" and stat == "mean" and steps == 3
        k = sum(1 for o in order if o == (method, B))
        order.append((method, B))
        return [0.5, rates[(method, B)][k], 1.0 + k]

    monkeypatch.setattr(bench_envs, "_run_cell", fake_cell)
    bench_envs.main(["--rounds", "3", "--methods", "sage-husa", "stkf", "--batches", "1", "16", "--transitions",
                     "fused", "--steps", "3", "--no-profile", "--no-headline"])
    # round by round: every cell once per round, in the same order
    assert order == [("sage-husa", 1), ("sage-husa", 16), ("stkf", 1), ("stkf", 16)] * 3
    rows = {tuple(line.split()[:3]): line.split() for line in capsys.readouterr().out.splitlines()
            if line.endswith(tuple("0123456789")) and line.split()[1] == "fused"}
    assert rows[("sage-husa", "fused", "1")][4] == "200"          # median steps/s
    assert rows[("sage-husa", "fused", "1")][-1] == "100-300"     # lowest-highest of the rounds
    assert rows[("stkf", "fused", "16")][4] == "2" and rows[("stkf", "fused", "16")][-1] == "1-3"
    assert rows[("stkf", "fused", "16")][6] == "2.00"             # median CPU ms/step (1, 2, 3)
