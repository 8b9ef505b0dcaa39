"""The plain loop a user would otherwise write: filterpy's ``KalmanFilter`` for the same 17-state epoch.

One epoch, as in a navgym env step: 100 ``predict()`` (one per IMU sample at 100 Hz, with a fixed 17 x 17
transition ``I + F h`` and process noise ``G Q_c G^T h`` of the navigator's error model) and one ``update(z)``
with ``m = 20`` measurements (10 satellites, pseudorange and rate). It does *less* than a navgym row-epoch:
no strapdown mechanization, no per-sample F, no ranging model, no adaptive law, no closed-loop feedback.
Timed single-threaded per process (filterpy is one filter per Python object); figures are epochs per wall
second and per CPU second (the per-core figure).

filterpy (PyPI ``filterpy``) is not a navgym dependency: ``pip install -e ".[bench]"``. Without it
:func:`filterpy_rate` returns None and the caller prints a skip line.
"""
from __future__ import annotations

import time

import numpy as np

N_STATES = 17
N_MEAS = 20
SAMPLES_PER_EPOCH = 100


def _epoch_model(seed=0):
    """(Phi, Q, H, R, P0) shaped like one navgym epoch: the error model's transition at 100 Hz on a world's
    first sample, LOS-like pseudorange/rate rows, metre-level R."""
    from envs.episodes import initial_covariance, process_noise_for
    from envs.sim.world import generate_world
    from nav_filters.error_model import transition
    w = generate_world("open-sky", [seed])
    i = w.init
    Phi, Q = transition(i.C_eb, w.imu.f_b[:, 1], i.r_e, process_noise_for(w), 0.01)
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(N_MEAS // 2, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    H = np.zeros((N_MEAS, N_STATES))
    H[: N_MEAS // 2, 6:9] = -u
    H[: N_MEAS // 2, 15] = 1.0
    H[N_MEAS // 2:, 3:6] = -u
    H[N_MEAS // 2:, 16] = 1.0
    R = np.diag(np.r_[np.full(N_MEAS // 2, 9.0), np.full(N_MEAS // 2, 0.01)])
    return Phi[0], Q[0], H, R, initial_covariance(w)[0]


def filterpy_rate(epochs=200, seed=0):
    """``(epochs per wall second, epochs per CPU second)`` of filterpy's predict x100 + update loop, or None
    when filterpy is not installed."""
    try:
        from filterpy.kalman import KalmanFilter
    except ImportError:
        return None
    Phi, Q, H, R, P0 = _epoch_model(seed)
    kf = KalmanFilter(dim_x=N_STATES, dim_z=N_MEAS)
    kf.F, kf.Q, kf.H, kf.R, kf.P = Phi, Q, H, R, P0.copy()
    z = np.random.default_rng(seed + 1).normal(size=N_MEAS)

    def run(n):
        for _ in range(n):
            for _ in range(SAMPLES_PER_EPOCH):
                kf.predict()
            kf.update(z)

    run(5)  # warm-up
    t0, c0 = time.perf_counter(), time.process_time()
    run(epochs)
    return epochs / (time.perf_counter() - t0), epochs / max(time.process_time() - c0, 1e-9)
