"""benchmarks/bench_worlds.py --draw-floor: the IMU's normal draws counted on the world's own streams."""
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))


def test_counted_draws_leave_the_world_unchanged_and_match_the_noise_model():
    """Counting does not change a bit of the world; the count covers at least the white noise and the bias
    instability of both sensors (3 axes each: 12 normals per IMU sample) on every row; the floor runs."""
    import bench_worlds as bw
    from envs.sim.scenarios import get_scenario
    from envs.sim.imu import IMU_GRADES
    scen, B, dur = "urban", 2, 5.0
    plain = bw._make_world(scen, list(range(B)), dur, np.dtype("float64"))
    count, counted = bw._count_imu_normals(scen, B, dur, "float64")
    assert np.array_equal(plain.imu.f_b, counted.imu.f_b) and np.array_equal(plain.imu.w_b, counted.imu.w_b)
    assert np.array_equal(plain.gnss.pr, counted.gnss.pr, equal_nan=True)
    g = IMU_GRADES[get_scenario(scen, duration_s=dur).imu_grade]
    assert g.gyro_arw > 0 and g.accel_vrw > 0 and g.gyro_bias_instability > 0 and g.accel_bias_instability > 0
    n = plain.truth.t.shape[0]
    assert count >= 12 * n * B
    f = bw.draw_floor(scen, B, dur, reps=1)
    assert f["normals_per_sample"] >= 12 and f["ms_per_row"] > 0 and f["threads"] >= 1
