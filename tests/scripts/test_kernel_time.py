"""benchmarks/kernel_time.py (``bench_envs.py --kernel-time``) counts every call of a navgym kernel made through a
module name, with its time, and puts the kernels back afterwards."""
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
from numba.core.dispatcher import Dispatcher

import nav_filters.measurements as meas

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from kernel_time import kernel_share, timed_kernels  # noqa: E402


def test_kernel_calls_are_counted_and_the_kernels_restored():
    u = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [-1.0, -1.0, -1.0]]) / [[1], [1], [1], [np.sqrt(3)]]
    u = np.repeat(u[None], 2, 0)  # two rows, four satellites of a non-degenerate geometry
    mask = np.ones((2, 4), bool)
    want = meas.dop(u, mask)
    totals, calls = defaultdict(float), defaultdict(int)
    with timed_kernels(totals, calls):
        assert not isinstance(meas._dop_kernel, Dispatcher)  # wrapped
        np.testing.assert_array_equal(meas.dop(u, mask), want)  # the same results through the wrapper
        meas.dop(u, mask)
    assert calls["measurements._dop_kernel"] == 2 and totals["measurements._dop_kernel"] > 0
    assert isinstance(meas._dop_kernel, Dispatcher)  # put back


def test_an_env_step_is_mostly_accounted_for():
    import gymnasium as gym

    import envs  # noqa: F401
    env = gym.make("GnssIns/SageHusa-v1", episode_length_s=20.0)
    env.reset(seed=0)
    acts = np.zeros((4, 1), np.float32)
    for a in acts:
        env.step(a)
    step, per = kernel_share(env, acts)
    inside = sum(t for t, _ in per.values())
    assert 0 < inside < step
    assert per["sage_husa_rows.satellite_epoch"][1] == 1.0  # the law's fused epoch: one call per step
    assert per["imu_lanes._propagate_lanes_serial"][1] == 1.0  # the IMU kernel (serial at B = 1)
