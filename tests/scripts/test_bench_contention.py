"""benchmarks/bench_contention.py: the competing process is started and always killed, every cell runs idle and
then busy (inside the load), the table gives each busy figure's ratio to its idle one, a layer's environment
reaches the cell's process, and a real cell runs (tiny: B = 64, 4 s episodes)."""
import sys
from contextlib import contextmanager
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_contention as bc  # noqa: E402


def test_the_competing_process_runs_and_is_killed_also_on_an_exception():
    with bc.competing_load(1) as procs:
        assert len(procs) == 1 and procs[0].poll() is None  # running
    assert procs[0].returncode is not None  # killed and reaped
    with pytest.raises(KeyboardInterrupt):
        with bc.competing_load(2) as procs:
            assert all(p.poll() is None for p in procs)
            raise KeyboardInterrupt
    assert all(p.returncode is not None for p in procs)


def test_cells_run_idle_then_busy_and_the_table_gives_the_ratios():
    args = bc.parse_args(["--policies", "always", "auto", "--kinds", "e2e", "--layers", "workqueue", "--batch",
                          "256"])
    log, busy = [], []

    @contextmanager
    def fake_load(n):
        busy.append(True)
        yield []
        busy.pop()

    rates = {("default", "always"): (1000.0, 200.0), ("default", "auto"): (990.0, 600.0),
             ("workqueue", "always"): (950.0, 700.0)}

    def fake_run(spec, layer):
        assert spec["B"] == 256 and spec["kind"] == "e2e" and spec["episode_s"] == 60.0
        log.append((layer, spec["policy"], "busy" if busy else "idle"))
        gov = {"policy": spec["policy"], "active": spec["policy"] == "auto", "preferred": "serial", "switches": 1,
               "probes": 4}
        return {"rate": rates[(layer, spec["policy"])][bool(busy)], "cpu_ms": 1.0,
                "layer": "omp" if layer == "default" else layer, "governor": gov}

    out = bc.measure(args, run=fake_run, load=fake_load, log=open("/dev/null", "w"))
    assert log == [("default", "always", "idle"), ("default", "always", "busy"), ("default", "auto", "idle"),
                   ("default", "auto", "busy"), ("workqueue", "always", "idle"), ("workqueue", "always", "busy")]
    lines = bc.table(args, out)
    rows = {tuple(c.strip() for c in line.split("|")[1:3]): [c.strip() for c in line.split("|")[1:-1]]
            for line in lines if line.startswith("| ") and "env-steps" not in line}
    assert rows[("default (omp)", "always")][5:9] == ["1,000", "200", "0.20", "0.20"]
    assert rows[("default (omp)", "auto")][5:10] == ["990", "600", "0.61", "0.60", "serial (switches: 1, probes: 4)"]
    assert rows[("workqueue", "always")][7:9] == ["0.74", "0.74"]
    assert lines[-1] == ("target (busy >= 0.5 x idle in every cell): 2 of 3 cells meet it; below: default (omp) "
                         "always end to end sage-husa")


def test_bad_arguments_are_one_clear_error(capsys):
    for argv, msg in ((["--batch", "16"], "--batch must be at least 64"),
                      (["--steps", "50"], "must fit in one 60 s episode"),
                      (["--methods", "nope"], "invalid choice: 'nope'")):
        with pytest.raises(SystemExit):
            bc.parse_args(argv)
        assert msg in capsys.readouterr().err


def test_a_real_cell_in_this_process_and_a_layer_in_a_fresh_one():
    import numba
    res = bc.cell_main(dict(method="sage-husa", B=64, kind="e2e", policy="auto", episode_s=4.0,
                            scenario="noise-burst", steps=1))
    assert res["rate"] > 0 and res["governor"]["policy"] == "auto"
    assert res["governor"]["active"] == (numba.get_num_threads() > 1)
    if res["governor"]["active"]:
        # every step of the run went through the governor: the untimed first episode (4 steps), then 2 x 4 + 5
        assert res["governor"]["units"] == 4 + 2 * 4 + 5
    res = bc.run_cell(dict(method="sage-husa", B=64, kind="step", policy="always", episode_s=14.0,
                           scenario="noise-burst", steps=1), "workqueue")
    assert "error" not in res, res
    assert res["rate"] > 0 and res["layer"] == "workqueue" and not res["governor"]["active"]
