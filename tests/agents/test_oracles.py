"""Branching in the env core (copy_rows, clone) and the hindsight oracles built on it (agents.oracles).

Small on purpose (2-4 episodes of 20-40 s): each property is checked on few rows, exactly.
"""
import numpy as np
import pytest

from agents.rollout import env_class, run_policy_episodes
from envs.core import TuningCore
from envs.gnss_ins_env import make_config


def _core(env_id, B, **kw):
    cls = env_class(env_id)
    cfg = make_config(cls.DEFAULTS, {"scenario": "noise-burst", "episode_length_s": 30.0, **kw})
    return TuningCore(cfg, cls.PARAMS, B)


def _step_all(core, actions):
    """Step with (B, k) actions; the step's arrays that must match between branches."""
    r = core.step(actions)
    out = {"obs": r.obs, "reward": r.reward, "terminated": r.terminated, "truncated": r.truncated}
    out.update({f"info:{k}": np.asarray(v) for k, v in r.info.items()})
    return out


def _row(d, b):
    return {k: v[b] for k, v in d.items()}


@pytest.mark.parametrize("env_id, kw", [
    ("GnssIns/SageHusa-v1", {}),
    ("GnssIns/SageHusa-v1", {"method": "svd-asrkf", "reward": "advantage", "history": 3}),
    ("GnssIns/STKF-v1", {}),
    ("GnssIns/MASTKF-v1", {"zupt": "truth"}),
    ("GnssIns/STKF-v1", {"scenario": "seed003-sim", "episode_length_s": 40.0}),  # odometer rows (world array)
])
def test_core_copy_rows_continues_bit_identically(env_id, kw):
    """Rows 0 <- 1 and 2 <- 0 (overlapping, different worlds) continue exactly like the uncopied rows."""
    seeds = [101, 102, 103]
    core, ref = _core(env_id, 3, **kw), _core(env_id, 3, **kw)
    core.reset_rows(np.arange(3), seeds)
    ref.reset_rows(np.arange(3), seeds)
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (core.M, 3, core.k))  # per epoch, per world
    n0 = 12
    for j in range(n0):
        _step_all(core, acts[j])
        _step_all(ref, acts[j])
    core.copy_rows([0, 2], [1, 0])
    perm = np.array([1, 1, 0])  # the world each row of `core` now carries
    assert core.seeds == [seeds[p] for p in perm]
    for j in range(n0, core.M):
        a, b = _step_all(core, acts[j][perm]), _step_all(ref, acts[j])
        for row in range(3):
            for k in a:
                np.testing.assert_array_equal(a[k][row], b[k][perm[row]], err_msg=f"epoch {j} row {row} {k}")
    np.testing.assert_array_equal(core.est_track, ref.est_track[perm])
    assert core.episode_metrics(range(3)) == [ref.episode_metrics([p])[0] for p in perm]


def test_clone_is_an_independent_snapshot():
    core = _core("GnssIns/SageHusa-v1", 2)
    core.reset_rows(np.arange(2), [5, 6])
    for _ in range(5):
        core.step(np.zeros((2, 1)))
    snap = core.clone()
    assert snap.f is core.f  # the world is shared, not copied
    later = [_step_all(core, np.full((2, 1), 0.3)) for _ in range(4)]
    np.testing.assert_array_equal(snap.t, [5, 5])  # the snapshot did not move with the core
    again = [_step_all(snap, np.full((2, 1), 0.3)) for _ in range(4)]
    for a, b in zip(later, again):
        for k in a:
            np.testing.assert_array_equal(a[k], b[k])
    snap.copy_rows([0], [1])  # copying rows of the snapshot leaves the original alone
    assert core.seeds == [5, 6] and snap.seeds == [6, 6]
    assert not np.array_equal(core.f[0], core.f[1])


def test_copy_rows_refuses_stateful_zupt_detectors():
    core = _core("GnssIns/SageHusa-v1", 2, zupt="shoe")
    core.reset_rows(np.arange(2), [1, 2])
    with pytest.raises(ValueError, match="'shoe' zero-velocity detector.*needs zupt='none'"):
        core.copy_rows([0], [1])
    with pytest.raises(RuntimeError, match="reset"):
        _core("GnssIns/SageHusa-v1", 2).copy_rows([0], [1])


# --------------------------------------------------------------------------- oracles
from agents.oracles import (action_grid, best_per_episode, crossfit_schedule, episode_rmse,  # noqa: E402
                            greedy_schedule, resolve_grid)
from agents.policies import ConstantPolicy, ScheduledPolicy  # noqa: E402

SH = "GnssIns/SageHusa-v1"
KW = {"scenario": "noise-burst", "episode_length_s": 30.0}
BOUND = 1000.0


@pytest.fixture(scope="module")
def greedy():
    return greedy_schedule(SH, KW, [21, 22, 23], segment_s=10.0, lookahead_s=10.0, grid=5)


def _same_log(a, b):
    for f in ("pos_err_ned", "nis", "n_sats", "zupt", "diverged"):
        np.testing.assert_array_equal(getattr(a, f), getattr(b, f), err_msg=f)


def test_replaying_a_greedy_schedule_reproduces_its_errors_bit_for_bit(greedy):
    E, M, k = greedy.actions.shape
    assert (E, M, k) == (3, 30, 1) and greedy.grid.shape == (5, 1)
    assert np.all(np.isin(greedy.actions, greedy.grid))
    # the actions are constant within a segment (10 epochs) and are the recorded choices
    seg = greedy.details["segment_epochs"]
    assert seg == 10 and greedy.details["lookahead_epochs"] == 10
    np.testing.assert_array_equal(greedy.actions[:, ::seg, 0], greedy.grid[greedy.details["choices"], 0])
    replay = run_policy_episodes(SH, KW, ScheduledPolicy(greedy.actions), greedy.seeds)
    _same_log(replay, greedy.log)
    # cost: K x (segment + lookahead) / segment episode-equivalents, the last lookahead cut at the end
    assert greedy.details["episode_equivalents"] == pytest.approx(5 * (20 + 20 + 10) / 30)


def test_each_greedy_choice_is_the_best_branch_over_segment_and_lookahead(greedy):
    """Independently of the search: replay the chosen prefix, then each candidate constant from the segment's
    start; the chosen candidate has the lowest squared error over segment + lookahead."""
    E, M, _ = greedy.actions.shape
    K, seg, look = greedy.grid.shape[0], 10, 10
    for i in (1, 2):  # the middle segment (full lookahead) and the last one (none left)
        s0 = i * seg
        acts = np.repeat(greedy.actions, K, axis=0)
        acts[:, s0:] = np.tile(greedy.grid, (E, 1))[:, None, :]
        log = run_policy_episodes(SH, KW, ScheduledPolicy(acts), np.repeat(greedy.seeds, K))
        h = np.minimum(log.horizontal_error, BOUND)[:, s0:min(s0 + seg + look, M)]
        cost = np.sum(h ** 2, axis=1).reshape(E, K)
        np.testing.assert_allclose(greedy.details["branch_cost_m2"][:, i], cost, rtol=1e-9)
        chosen = greedy.details["choices"][:, i]
        assert np.all(cost[np.arange(E), chosen] <= cost.min(1) * (1 + 1e-12))


def test_best_per_episode_is_no_worse_than_any_constant_of_its_grid():
    seeds = [31, 32]
    kw = {"scenario": "noise-burst", "episode_length_s": 20.0}
    res = best_per_episode(SH, kw, seeds, grid=5)
    assert res.actions.shape == (2, 20, 1)
    assert np.all(res.actions == res.actions[:, :1])  # constant over each episode
    const = np.array([episode_rmse(run_policy_episodes(SH, kw, ConstantPolicy(a), seeds), BOUND)
                      for a in res.grid])  # (K, E)
    best = res.rmse_h_m(BOUND)
    assert np.all(best <= const.min(0) * (1 + 1e-12))
    np.testing.assert_allclose(best, const.min(0), rtol=1e-12)
    np.testing.assert_array_equal(res.actions[:, 0], res.grid[const.argmin(0)])
    _same_log(run_policy_episodes(SH, kw, ScheduledPolicy(res.actions), seeds), res.log)


def test_crossfit_scores_each_half_with_the_schedule_fitted_on_the_other():
    kw = {"scenario": "noise-burst", "episode_length_s": 20.0}
    a = crossfit_schedule(SH, kw, [41, 42, 43, 44], segment_s=10.0, lookahead_s=10.0, grid=3)
    b = crossfit_schedule(SH, kw, [51, 52, 43, 44], segment_s=10.0, lookahead_s=10.0, grid=3)
    assert a.details["halves"] == [[0, 1], [2, 3]]
    # new episodes in the first half leave the schedule fitted on the second half unchanged ...
    np.testing.assert_array_equal(a.details["schedules"]["second"], b.details["schedules"]["second"])
    # ... and that schedule (and only it) scores the first half; the first half's fit scores the second
    for r in (a, b):
        np.testing.assert_array_equal(r.actions[:2], np.broadcast_to(r.details["schedules"]["second"], (2, 20, 1)))
        np.testing.assert_array_equal(r.actions[2:], np.broadcast_to(r.details["schedules"]["first"], (2, 20, 1)))
    alone = run_policy_episodes(SH, kw, ScheduledPolicy(a.actions[:2]), [41, 42])
    np.testing.assert_array_equal(a.log.pos_err_ned[:2], alone.pos_err_ned)
    # a pooled fit is one schedule: its choice per segment minimizes the cost summed over the half
    for name, cost in a.details["fit_branch_cost_m2"].items():
        assert np.array_equal(a.details["choices"][name], cost.sum(0).argmin(1))


def test_action_grids():
    from envs.gnss_ins_env import MASTKF_PARAMS, SAGE_HUSA_PARAMS
    np.testing.assert_array_equal(action_grid(SAGE_HUSA_PARAMS)[:, 0], np.linspace(-1, 1, 7))
    g2 = action_grid(MASTKF_PARAMS, 3)
    assert g2.shape == (9, 2) and len({tuple(r) for r in g2}) == 9  # the full product
    np.testing.assert_array_equal(resolve_grid([-1, 0.5], SAGE_HUSA_PARAMS), [[-1.0], [0.5]])
    with pytest.raises(ValueError, match="grid must be an int or an array"):
        resolve_grid(np.zeros((2, 3)), MASTKF_PARAMS)
    with pytest.raises(ValueError, match="within"):
        resolve_grid([2.0], SAGE_HUSA_PARAMS)
    with pytest.raises(ValueError, match="n .* must be an int >= 2"):
        action_grid(SAGE_HUSA_PARAMS, 1)


@pytest.mark.parametrize("call, msg", [
    (lambda: greedy_schedule(SH, KW, [1], segment_s=0.0), "segment_s must be a positive"),
    (lambda: greedy_schedule(SH, KW, [1], lookahead_s=-1.0), "lookahead_s must be a non-negative"),
    (lambda: greedy_schedule(SH, {**KW, "zupt": "shoe"}, [1]), "zupt='none'"),
    (lambda: greedy_schedule(SH, KW, []), "seeds is empty"),
    (lambda: crossfit_schedule(SH, KW, [1]), "at least 2 seeds"),
    (lambda: greedy_schedule("GnssIns/Nope-v0", KW, [1]), "unknown environment id"),
])
def test_oracle_input_errors(call, msg):
    with pytest.raises(ValueError, match=msg):
        call()


def test_scheduled_policy_checks_its_schedule():
    p = ScheduledPolicy(np.zeros((2, 3, 1)))
    with pytest.raises(ValueError, match="2 episodes, the batch 3"):
        p.reset(3)
    p.reset(2)
    for _ in range(3):
        p.act(np.zeros((2, 14)))
    with pytest.raises(ValueError, match="has 3 epochs"):
        p.act(np.zeros((2, 14)))
    with pytest.raises(ValueError, match="shape"):
        ScheduledPolicy(np.zeros((2, 3)))


def test_reactive_rule_lowers_b_while_the_satellites_look_degraded_and_holds_it():
    from agents.methods import RuleMethod, parse_method_spec
    from agents.policies import ReactiveRule
    from envs.core import OBS_FEATURES
    from envs.gnss_ins_env import SAGE_HUSA_PARAMS
    names = [f[0] for f in OBS_FEATURES]
    k, F = 1, 1 + len(OBS_FEATURES)
    rule = ReactiveRule(SAGE_HUSA_PARAMS, F, b_low=0.9, b_high=0.9999, nis=9.0, ema=3.0, hold=2)
    rule.reset(2)
    spec = SAGE_HUSA_PARAMS[0]
    obs = np.zeros((2, 2 * F), np.float32)  # history 2: the rule reads the newest frame
    obs[1, F + k + names.index("nis_pr_sat_max")] = 50.0
    obs[0, k + names.index("nis_pr_sat_max")] = 50.0  # an old frame: ignored
    b = [spec.to_value(rule.act(obs)[:, 0])]
    obs[:] = 0
    for _ in range(3):
        b.append(spec.to_value(rule.act(obs)[:, 0]))
    b = np.array(b)
    # the action is float32: b comes back to float32 resolution of the action (1 - b relative ~1e-6)
    np.testing.assert_allclose(1 - b[:, 0], 1e-4, rtol=1e-5)
    np.testing.assert_allclose(1 - b[:3, 1], 0.1, rtol=1e-5)  # the degraded epoch, then held 2 epochs
    np.testing.assert_allclose(1 - b[3, 1], 1e-4, rtol=1e-5)
    m = parse_method_spec("rule:GnssIns/SageHusa-v1[b_low=0.92,hold=3]")
    assert isinstance(m, RuleMethod) and m.options == {"b_low": 0.92, "hold": 3}
    for bad, msg in (("rule:GnssIns/SageHusa-v1[q=1]", "unknown option"),
                     ("rule:GnssIns/SageHusa-v1[b_low=0.2]", "b_low must lie"),
                     ("rule:GnssIns/STKF-v1", "Sage-Husa forgetting factor")):
        with pytest.raises(ValueError, match=msg):
            parse_method_spec(bad)
