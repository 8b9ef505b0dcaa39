"""The pre-existing scenarios' worlds must not change when new world components are added.

``snapshots/world_fingerprints.json`` was written from the code *before* the
random-event / oracle-truth work (issue 16) landed, with::

    cd <repo> && python -c 'import tests.envs.test_world_fingerprints as t; t.write_fingerprints()'

It holds, per scenario and for seeds (0, 1): per-epoch channel sums of the
GNSS errors (``pr_error_m``, ``prr_error_mps``, 12 significant digits), the
valid-channel and NLOS counts, whole-array sums of the other GNSS arrays, and the
IMU errors (``imu - truth``) summed over 10 s blocks per axis. Any change of a
random draw (a shifted stream, an extra draw in an old stream) moves these by
orders of magnitude more than the tolerance; the tolerance only absorbs
last-bit differences of vectorized transcendental functions between CPUs.

``snapshots/world_fingerprints_zones.json`` pins the urban zones' scenarios (``urban-transition``,
``urban-smartloc``) the same way, written from b14a688, before their zone effects were vectorized over rows
(``write_fingerprints(SCENARIOS_ZONES, SNAPSHOT_ZONES)`` run on that tree's ``generate_world``); its totals also
hold the C/N0 and the event bits.

``seed003-sim`` is the one scenario whose world changed on purpose (issue 16:
re-acquisition noise after its two outages): its GNSS fingerprint is compared
on the epochs outside the re-acquisition windows only, and must differ inside.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from envs.sim.world import generate_world

SNAPSHOT = Path(__file__).parent / "snapshots" / "world_fingerprints.json"
SCENARIOS_BEFORE = ("open-sky", "urban", "outage", "noise-burst", "seed000-sim", "seed003-sim")
SNAPSHOT_ZONES = Path(__file__).parent / "snapshots" / "world_fingerprints_zones.json"
SCENARIOS_ZONES = ("urban-transition", "urban-smartloc")
SEEDS = (0, 1)
BLOCK_S = 10.0


def fingerprint(name: str) -> dict:
    """The fingerprint of ``generate_world(name, SEEDS)`` (see the module docstring); JSON-ready."""
    w = generate_world(name, list(SEEDS))
    g, imu, tr = w.gnss, w.imu, w.truth
    spb = int(round(BLOCK_S * w.scenario.imu_rate_hz))
    n = imu.f_b.shape[1] // spb * spb

    def blocks(x):
        x = np.asarray(x, np.float64)[:, :n]
        return x.reshape(x.shape[0], -1, spb, 3).sum(axis=2)

    per_epoch = {k: np.asarray(getattr(g, k), np.float64).sum(axis=-1) for k in ("pr_error_m", "prr_error_mps")}
    counts = {"n_used": g.n_used(), "nlos": g.nlos.sum(axis=-1)}
    totals = {k: float(np.asarray(getattr(g, k), np.float64).sum())
              for k in ("sat_pos", "sat_vel", "azimuth", "elevation", "pr_sigma", "prr_sigma", "clock_bias_m",
                        "clock_drift_mps", "t0_gps")}
    totals["prn"] = float(g.prn.sum())
    totals["cn0_dbhz"] = float(np.where(g.mask, np.asarray(g.cn0_dbhz, np.float64), 0.0).sum())
    totals["event_mask"] = float(np.asarray(g.event_mask, np.float64).sum())
    imu_blocks = {"f_err": blocks(imu.f_b - tr.f_b), "w_err": blocks(imu.w_b - tr.w_b),
                  "gyro_bias": blocks(imu.gyro_bias), "accel_bias": blocks(imu.accel_bias)}
    init = {"r_e": float(np.sum(w.init.r_e)), "v_e": float(np.sum(w.init.v_e)), "C_eb": float(np.sum(w.init.C_eb)),
            "truth_r_e": float(np.sum(tr.r_e[:, ::100]))}
    def r12(x):  # 12 significant digits: far below any draw change, far above last-bit noise
        return [[float(f"{v:.12g}") for v in row] for row in np.atleast_2d(x).reshape(x.shape[0], -1)]

    return {"t": np.asarray(g.t, np.float64).tolist(),
            "per_epoch": {k: r12(v) for k, v in per_epoch.items()},
            "counts": {k: v.astype(int).tolist() for k, v in counts.items()},
            "totals": totals, "imu_blocks": {k: r12(v) for k, v in imu_blocks.items()}, "init": init}


def write_fingerprints(names=SCENARIOS_BEFORE, path=SNAPSHOT) -> None:
    """Regenerate a snapshot (only on purpose: it pins the pre-existing worlds)."""
    path.write_text(json.dumps({n: fingerprint(n) for n in names}, separators=(",", ":")))


def _close(a, b, what, scale):
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    np.testing.assert_allclose(a.reshape(b.shape), b, rtol=1e-9,
                               atol=1e-9 * scale, err_msg=what)


_SCALES = {"pr_error_m": 1.0, "prr_error_mps": 1e-2, "f_err": 1e-2, "w_err": 1e-4,
           "gyro_bias": 1e-4, "accel_bias": 1e-2}


def _reacq_free(t, outages, window_s):
    """Epochs not within ``window_s`` after the end of an outage."""
    t = np.asarray(t)
    keep = np.ones(t.shape, bool)
    for _, t1 in outages:
        keep &= ~((t >= t1) & (t < t1 + window_s))
    return keep


@pytest.mark.parametrize("name", SCENARIOS_BEFORE + SCENARIOS_ZONES)
def test_existing_world_unchanged(name):
    ref = json.loads((SNAPSHOT_ZONES if name in SCENARIOS_ZONES else SNAPSHOT).read_text())[name]
    now = fingerprint(name)
    np.testing.assert_array_equal(now["t"], ref["t"])
    keep = np.ones(len(ref["t"]), bool)
    if name == "seed003-sim":
        from envs.sim.scenarios import SCENARIOS
        ev = SCENARIOS[name].events
        assert ev.reacquisition is not None, "seed003-sim carries re-acquisition noise (issue 16)"
        keep = _reacq_free(ref["t"], ev.outages, ev.reacquisition.duration_s)
        assert (~keep).sum() > 0
        changed = np.asarray(now["per_epoch"]["pr_error_m"])[:, ~keep] - np.asarray(ref["per_epoch"]["pr_error_m"])[:, ~keep]
        assert np.mean(np.abs(changed) > 1e-6) > 0.5, "re-acquisition noise must change the epochs after outages"
    for k, v in ref["per_epoch"].items():
        a, b = np.asarray(now["per_epoch"][k]), np.asarray(v)
        if name == "seed003-sim" and k in ("pr_error_m", "prr_error_mps"):
            a, b = a[:, keep], b[:, keep]
        _close(a, b, f"{name} per-epoch {k}", _SCALES[k])
    for k, v in ref["counts"].items():
        np.testing.assert_array_equal(now["counts"][k], v, err_msg=f"{name} counts {k}")
    for k, v in ref["totals"].items():
        _close(now["totals"][k], v, f"{name} total {k}", abs(v) + 1.0)
    for k, v in ref["imu_blocks"].items():
        _close(now["imu_blocks"][k], v, f"{name} IMU {k}", _SCALES[k])
    for k, v in ref["init"].items():
        _close(now["init"][k], v, f"{name} init {k}", abs(v) + 1.0)
