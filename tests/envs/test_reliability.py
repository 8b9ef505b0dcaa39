"""Reliability of the environments under demanding use (issue 13): no exception escapes a step, a failure in
one row stays in that row (terminated with ``info["diverged"]`` and a reason), and no live row holds a
covariance that is not positive definite."""
import gymnasium as gym
import numpy as np
import pytest

import envs  # noqa: F401  (registers the ids)


def _live_covariances_pd(core):
    P = np.asarray(core.nav.covariance, np.float64)
    live = ~core.nav.diverged
    return np.linalg.eigvalsh(0.5 * (P + P.mT))[live].min(initial=np.inf) > 0


def _bang_bang_outage(env_id, seed):
    """The configuration of the issue: consumer IMU, ``outage``, actions alternating -1/+1, 8 rows, float32.
    Checks every step's invariants and returns the number of flagged row-steps."""
    env = gym.make_vec(env_id, num_envs=8, vectorization_mode="vector_entry_point", scenario="outage",
                       imu_grade="consumer", dtype="float32")
    env.reset(seed=seed)
    core = env.unwrapped.core
    k = env.single_action_space.shape[0]
    flagged = 0
    for t in range(core.M):
        _, _, term, _, info = env.step(np.full((8, k), 1.0 if t % 2 else -1.0, np.float32))
        assert _live_covariances_pd(core), (seed, t)
        assert np.array_equal(term, info["diverged"])
        reasons = info["diverged_reason"]
        assert all(reasons[term]) and not any(reasons[~term]), (seed, t, reasons)
        flagged += int(term.sum())
    return flagged


MA_STKF_EDGE_SEEDS = (100, 600, 900, 1100)
"""Seeds whose float32 ma-stkf run pushes a row over the edge on some machine: which ones do depends on the
last bits of float32 rounding, which differ between CPUs (numba compiles for the host: FMA contraction, vector
width): seeds 100 and 600 on one machine, 100, 900 and 1100 on an AVX-512 one."""


@pytest.mark.parametrize("env_id", ["GnssIns/MASTKF-v1", "GnssIns/STKF-v1"])
def test_float32_strong_tracking_bang_bang_after_an_outage_keeps_failures_in_their_rows(env_id):
    """Before the fix ma-stkf (seed 100) raised LinAlgError from the Joseph update when GNSS returned (the
    navigator checked S in float64 with the raw R, not the update's float32 S with alpha R), and P became
    non-PD without a flag (ma-stkf seed 200, stkf seed 600). Since the strong-tracking laws fade on state
    events only (issue 16), stkf no longer diverges here (no row of seeds 100-800), so its case checks the
    covariances and flags without exercising the isolation; ma-stkf still pushes a row over the edge on some
    of :data:`MA_STKF_EDGE_SEEDS` (the test needs one, so that it exercises the isolation in the env; the
    isolation itself is tested deterministically in tests/nav_filters/test_failure_isolation.py)."""
    if env_id == "GnssIns/STKF-v1":
        _bang_bang_outage(env_id, 600)
        return
    flagged = [_bang_bang_outage(env_id, s) for s in MA_STKF_EDGE_SEEDS]
    assert sum(flagged) > 0, flagged  # the scenario does push rows over the edge: the test exercises the isolation


SOAK_SCENARIOS = ("urban", "outage", "noise-burst")


@pytest.mark.parametrize("dtype", ["float64", "float32"])
@pytest.mark.parametrize("env_id", sorted(envs.ENV_IDS))
def test_soak_no_exception_no_nonfinite_output_and_every_live_covariance_pd(env_id, dtype):
    """Soak (about 10 s per case on 2 cores): scenarios x bang-bang / uniform actions, 8 rows x 130 steps
    (beyond one 120 s episode, so the automatic resets are exercised), consumer IMU. Per configuration: no
    exception escapes, no NaN/inf in obs/reward/info, every live row's covariance positive definite, every
    diverged row-step carries a reason. ``benchmarks/soak.py`` runs a larger grid and prints the counts."""
    from envs.soak import ACTION_PATTERNS, SoakCounts, soak
    total = SoakCounts()
    for scenario in SOAK_SCENARIOS:
        for actions in ACTION_PATTERNS:
            c = soak(env_id, scenario=scenario, dtype=dtype, actions=actions, num_envs=8, steps=130, seed=7,
                     imu_grade="consumer")
            assert (c.exceptions, c.nonfinite, c.non_pd, c.unexplained) == (0, 0, 0, 0), (scenario, actions, c)
            assert c.row_steps == 8 * 130
            total += c
    if env_id == "GnssIns/MASTKF-v1":
        assert total.flagged > 0  # MA-STKF on outage does diverge: the flagging path is exercised (STKF
        # diverged here too until it faded on state events only, issue 16)


def test_soak_counts_an_escaped_exception_and_a_non_pd_covariance(monkeypatch):
    """The soak's counters can fail: a covariance made indefinite behind the navigator's back is counted as
    non-PD, and an exception out of a step is counted with its configuration."""
    from envs.soak import soak
    from nav_filters.navigator import Navigator

    orig = Navigator.update_gnss

    def indefinite(self, *a, **k):
        out = orig(self, *a, **k)
        form = self.form
        while hasattr(form, "inner"):
            form = form.inner
        form.P = form.P.copy()
        form.P[0, 9, 10] = form.P[0, 10, 9] = 10 * np.sqrt(form.P[0, 9, 9] * form.P[0, 10, 10])
        return out

    monkeypatch.setattr(Navigator, "update_gnss", indefinite)
    c = soak("GnssIns/STKF-v1", scenario="open-sky", dtype="float64", actions="uniform", num_envs=2, steps=3,
             episode_length_s=10.0)
    assert c.non_pd >= 2 and c.exceptions == 0  # counted until the navigator flags the row (then reset)

    def boom(self, *a, **k):
        raise np.linalg.LinAlgError("boom")

    monkeypatch.setattr(Navigator, "update_gnss", boom)
    c = soak("GnssIns/STKF-v1", scenario="open-sky", dtype="float64", actions="uniform", num_envs=2, steps=3,
             episode_length_s=10.0)
    assert c.exceptions == 1 and "LinAlgError: boom" in c.errors[0] and "GnssIns/STKF-v1 open-sky" in c.errors[0]
