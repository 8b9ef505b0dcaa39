"""benchmarks/bench_worlds.py: --draw-floor (the IMU's normal draws counted on the world's own streams) and --cores."""
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))


def test_counted_draws_leave_the_world_unchanged_and_match_the_noise_model():
    """Counting does not change a bit of the world; the count covers at least the white noise and the bias
    instability of both sensors (3 axes each: 12 normals per IMU sample) on every row; the floor runs."""
    import bench_worlds as bw
    from envs.sim.scenarios import get_scenario
    from envs.sim.imu import IMU_GRADES
    scen, B, dur = "urban", 2, 5.0
    plain = bw._make_world(scen, list(range(B)), dur, np.dtype("float64"))
    counts, counted = bw._count_imu_normals(scen, B, dur, "float64")
    assert np.array_equal(plain.imu.f_b, counted.imu.f_b) and np.array_equal(plain.imu.w_b, counted.imu.w_b)
    assert np.array_equal(plain.gnss.pr, counted.gnss.pr, equal_nan=True)
    g = IMU_GRADES[get_scenario(scen, duration_s=dur).imu_grade]
    assert g.gyro_arw > 0 and g.accel_vrw > 0 and g.gyro_bias_instability > 0 and g.accel_bias_instability > 0
    n = plain.truth.t.shape[0]
    assert counts.get("SFC64", 0) >= 12 * n * B    # the IMU's child streams are SFC64
    f = bw.draw_floor(scen, B, dur, reps=1)
    assert f["normals_per_sample"] >= 12 and f["ms_per_row"] > 0 and f["threads"] >= 1


def test_counted_draws_of_rows_together_are_the_sum_of_each_row_alone():
    """From OVERLAP_ROWS rows on the world runs the GNSS stages beside the IMU: the count must still hold the IMU's
    draws only, the sum of what each row draws alone."""
    import bench_worlds as bw
    from envs.sim.world import OVERLAP_ROWS
    B, dur = OVERLAP_ROWS, 5.0
    together, _ = bw._count_imu_normals("urban", B, dur, "float64")
    alone: dict = {}
    for i in range(B):
        for name, c in bw._count_imu_normals("urban", 1, dur, "float64", seed0=i)[0].items():
            alone[name] = alone.get(name, 0) + c
    assert together == alone


def test_cores_are_each_stages_cpu_time_over_its_wall_time(monkeypatch):
    """``--cores`` on fake clocks: a stage that spends 1 s wall and 2 s CPU per call is 2.00 cores busy; the rest of
    the world (1 s wall, 1 s CPU per draw) is 1.00; the world's total is (1 + 2) / (1 + 1) = 1.50 cores."""
    import types

    import bench_worlds as bw

    clocks = {"wall": 0.0, "cpu": 0.0}
    fake_time = types.SimpleNamespace(perf_counter=lambda: clocks["wall"], process_time=lambda: clocks["cpu"])
    stage_mod = types.ModuleType("fake_stage_mod")

    def imu_stage():
        clocks["wall"] += 1.0
        clocks["cpu"] += 2.0

    stage_mod.simulate_imu = imu_stage
    monkeypatch.setitem(sys.modules, "fake_stage_mod", stage_mod)
    # every stage of the real table, all but imu in a module that does not exist (a tree that lacks them)
    monkeypatch.setattr(bw, "_WRAPPED", {s: ((("fake_stage_mod", "simulate_imu"),) if s == "imu" else
                                             (("no_such_module_navgym", "f"),)) for s in bw._WRAPPED})
    monkeypatch.setattr(bw, "time", fake_time)

    def fake_world(scenario, seeds, duration_s, dtype, buffers=None, for_reset=True):
        stage_mod.simulate_imu()  # looked up at call time: the wrapped stage
        clocks["wall"] += 1.0
        clocks["cpu"] += 1.0
        return types.SimpleNamespace(truth=types.SimpleNamespace(t=np.zeros(11)))

    monkeypatch.setattr(bw, "_make_world", fake_world)
    r = bw.bench_cell("x", 1, 0.1, reps=3, cores=True)
    assert r["cores"]["imu"] == pytest.approx(2.0) and r["cores"]["rest"] == pytest.approx(1.0)
    assert r["cores"]["total"] == pytest.approx(1.5)
    assert r["imu"] == pytest.approx(1.0) and r["total"] == pytest.approx(2.0)  # wall seconds per row
    assert r["trajectory"] is None and r["cores"]["trajectory"] is None  # a stage this "tree" lacks
