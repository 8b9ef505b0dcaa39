"""Random world events (issue 16): envs.sim.events, the oracle truth in GnssData, ImuEvents, the new scenarios."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from earth.units import dph, mg
from envs.sim import events as ev
from envs.sim.gnss import (_N_SUB, _SUB_BURSTS, _SUB_MISMATCH, _SUB_REGIME, _SUB_ZONES, GnssData, GnssEvents,
                           ReceiverConfig, UrbanCanyon, _entropy_words, _row_children, simulate_gnss)
from envs.sim.imu import IMU_GRADES, ImuEvents, simulate_imu
from envs.sim.rng import row_generators
from envs.sim.scenarios import SCENARIOS, Scenario, get_scenario
from envs.sim.world import generate_world
from tests.envs.test_gnss import CON, _driving, _sim, _static

NEW = ("urban-transition", "noise-mismatch", "regime-switch")
T300 = np.arange(1.0, 301.0)
NO_ATM = ReceiverConfig(tropo_zenith_sigma_m=0.0, iono_zenith_sigma_m=0.0)


def _child(seed, sub):
    """The child stream ``sub`` of row seed ``seed`` exactly as simulate_gnss derives it."""
    return _row_children(row_generators([seed], "gnss")[0])[sub]


def _chi2_ok(x, alpha=1e-4):
    """Mean of N unit chi-square(1) samples inside the two-sided (1 - alpha) chi-square(N) band."""
    n = x.size
    lo, hi = stats.chi2.ppf([alpha / 2, 1 - alpha / 2], n) / n
    return lo <= x.mean() <= hi, (lo, x.mean(), hi, n)


# ----------------------------------------------------------------------------- streams
def test_more_children_leave_the_first_eight_streams_unchanged():
    assert _N_SUB > 8
    entropy = [12345, 678, 9, 10]
    old = [np.random.default_rng(s) for s in np.random.SeedSequence(entropy).spawn(8)]
    new = [np.random.default_rng(s) for s in np.random.SeedSequence(entropy).spawn(_N_SUB)]
    for a, b in zip(old, new):
        np.testing.assert_array_equal(a.standard_normal(50), b.standard_normal(50))
    # and _row_children draws the same entropy as before (4 integers from the row generator)
    g1, g2 = row_generators([3], "gnss")[0], row_generators([3], "gnss")[0]
    ent = g2.integers(0, 2**63, size=4, dtype=np.int64)
    ref = np.random.SeedSequence([int(x) for x in ent]).spawn(8)
    for a, s in zip(_row_children(g1)[:8], ref):
        np.testing.assert_array_equal(a.random(20), np.random.default_rng(s).random(20))


def test_row_children_built_on_demand_equal_the_spawned_list():
    """_row_children builds each child on first use (any order) from the entropy's uint32 words: the same
    streams as ``SeedSequence(entropy).spawn(_N_SUB)``, also for entropy words of 0, 1, 2^32 - 1, 2^32, ..."""
    for seed in (0, 3, 123456):
        g1, g2 = row_generators([seed], "gnss")[0], row_generators([seed], "gnss")[0]
        kids = _row_children(g1)
        ent = [int(x) for x in g2.integers(0, 2**63, size=4, dtype=np.int64)]
        ref = np.random.SeedSequence(ent).spawn(_N_SUB)
        assert len(kids) == _N_SUB
        for k in (11, 0, 15, 3, 11):                      # any order; a repeated index returns the same generator
            assert kids[k] is kids[k]
        for k in range(_N_SUB):
            np.testing.assert_array_equal(kids[k].random(20), np.random.default_rng(ref[k]).random(20))
        assert g1.random() == g2.random()                  # one draw of 4 integers from the row generator
    for ent in ([0, 1, 2**32 - 1, 2**32], [2**63 - 1, 2**32 + 1, 5, 0], [2**40, 7, 2**33, 2**62]):
        words = _entropy_words(ent)
        for k in (0, 9, 15):
            np.testing.assert_array_equal(np.random.SeedSequence(words, spawn_key=(k,)).generate_state(4),
                                          np.random.SeedSequence(ent, spawn_key=(k,)).generate_state(4))


# ----------------------------------------------------------------------------- event draws
def test_event_draws_reproducible_and_differ_between_seeds():
    draws = {
        "bursts": lambda g: ev.draw_bursts(T300, ev.RandomBursts(rate_hz=0.03), g)[3],
        "mismatch": lambda g: tuple(np.r_[ev.draw_mismatch(T300, ev.SigmaMismatch(), g)]),
        "regimes": lambda g: tuple(ev.draw_regimes(T300, ev.NoiseRegimes(), g)[1]),
        "zones": lambda g: ev.draw_zone_schedule(T300, ev.UrbanZones(), g)[2],
    }
    for name, f in draws.items():
        a = [f(np.random.default_rng(s)) for s in range(6)]
        b = [f(np.random.default_rng(s)) for s in range(6)]
        assert a == b, name
        assert len({repr(x) for x in a}) == 6, f"{name}: seeds must give different events"
    # nothing at a fixed clock time: first zone starts spread over the open-sky range
    first = [ev.draw_zone_schedule(T300, ev.UrbanZones(), np.random.default_rng(s))[2][0][0] for s in range(40)]
    assert np.std(first) > 5.0 and 21.0 <= min(first) and max(first) <= 61.0


def test_random_bursts_statistics():
    cfg = ev.RandomBursts(rate_hz=0.02, duration_s=(5.0, 60.0), scale=(3.0, 20.0), joint=False)
    g = np.random.default_rng(1)
    counts, lengths, sc, sd = [], [], [], []
    for _ in range(400):
        code, dop, act, win = ev.draw_bursts(T300, cfg, g)
        counts.append(len(win))
        for t0, t1, a, b in win:
            lengths.append(t1 - t0), sc.append(a), sd.append(b)
            inside = (T300 >= t0) & (T300 < t1)
            assert np.all(act[inside]) and np.all(code[inside] >= a * (1 - 1e-12))
        assert np.all(code[~act] == 1.0) and np.all(dop[~act] == 1.0)
    assert abs(np.mean(counts) - 0.02 * 300) < 4 * math.sqrt(6.0 / 400)          # Poisson mean
    assert abs(np.var(counts) / np.mean(counts) - 1.0) < 0.25                      # Poisson dispersion
    lengths, sc, sd = map(np.asarray, (lengths, sc, sd))
    assert 5.0 <= lengths.min() and lengths.max() <= 60.0 and abs(lengths.mean() - 32.5) < 2.0
    assert 3.0 <= sc.min() and sc.max() <= 20.0
    assert abs(np.mean(np.log(sc)) - 0.5 * (math.log(3) + math.log(20))) < 0.05    # log-uniform
    assert abs(np.corrcoef(np.log(sc), np.log(sd))[0, 1]) < 0.1                    # separate draws
    _, _, _, win = ev.draw_bursts(T300, dataclasses.replace(cfg, joint=True), np.random.default_rng(2))
    assert all(a == b for _, _, a, b in win)


def test_sigma_mismatch_segments_and_factors():
    t = np.arange(0.0, 20000.0)
    cfg = ev.SigmaMismatch(segment_s=(20.0, 90.0), pr_factor=(0.25, 4.0), prr_factor=(0.5, 2.0), p_honest=0.3)
    fp, fd = ev.draw_mismatch(t, cfg, np.random.default_rng(4))
    for f, (lo, hi) in ((fp, cfg.pr_factor), (fd, cfg.prr_factor)):
        change = np.flatnonzero(np.diff(f) != 0) + 1
        seg = np.diff(change)
        vals = f[np.r_[0, change]]
        wrong = vals[1:-1] != 1.0                 # consecutive honest segments merge into one run
        assert seg.min() >= 20 and seg[wrong].max() <= 91
        assert np.all((vals == 1.0) | ((vals >= lo) & (vals <= hi)))
        assert abs(np.mean(vals == 1.0) - 0.3) < 0.08
    assert not np.array_equal(fp != 1.0, fd != 1.0), "code and Doppler have their own segments"


def test_noise_regimes_dwell_and_occupancy():
    t = np.arange(0.0, 60000.0, 0.1)
    cfg = ev.NoiseRegimes()
    reg, sw = ev.draw_regimes(t, cfg, np.random.default_rng(5))
    change = np.flatnonzero(np.diff(reg) != 0) + 1
    # every switch changes the regime; a dwell shorter than the 0.1 s grid may hide one (rare)
    assert 0.98 * sw.size <= change.size <= sw.size
    assert np.all(np.abs(t[change][:, None] - sw[None, :]).min(axis=1) < 0.1 + 1e-9)
    bounds = np.r_[0, change, t.size]
    for k, r in enumerate(cfg.regimes):
        d = 0.1 * np.array([b - a for a, b in zip(bounds[:-1], bounds[1:]) if reg[a] == k])[1:-1]
        assert abs(d.mean() - r.mean_dwell_s) < 4 * r.mean_dwell_s / math.sqrt(d.size) + 1.0, r.name
    occ = np.bincount(reg, minlength=3) / reg.size
    dwell = np.array([r.mean_dwell_s for r in cfg.regimes])
    np.testing.assert_allclose(occ, dwell / dwell.sum(), atol=0.03)


def test_reacquisition_multiplier_rule():
    t = np.arange(0.0, 40.0)
    vis = np.ones((40, 3), bool)
    vis[:, 1] = False
    vis[25:, 1] = True        # satellite 1 rises at 25 s: never tracked before, no transient
    vis[10:15, 0] = False     # satellite 0 lost 5 s: transient from 15 s
    vis[20, 2] = False        # satellite 2 lost one epoch (1 s = min_gap): transient from 21 s
    cfg = ev.Reacquisition(scale=5.0, duration_s=10.0, min_gap_s=1.0)
    m = ev.reacquisition_multiplier(t, vis, cfg)
    np.testing.assert_allclose(m[15:25, 0], 5.0 ** (1.0 - np.arange(10) / 10.0))
    assert np.all(m[25:, 0] == 1.0) and np.all(m[:15, 0] == 1.0)
    assert np.all(m[:, 1] == 1.0)
    assert m[21, 2] == 5.0 and m[30, 2] == 5.0 ** 0.1 and m[31, 2] == 1.0
    vis_out = vis.copy()
    vis_out[30, :] = False    # a full outage: the rising satellite 1 re-acquires too
    m2 = ev.reacquisition_multiplier(t, vis_out, cfg)
    assert m2[31, 1] == 5.0 and m2[31, 0] == 5.0
    batch = np.stack([vis, vis_out, ~vis])              # rows of a batch are independent
    mb = ev.reacquisition_multiplier(t, batch, cfg)
    for i in range(3):
        np.testing.assert_array_equal(mb[i], ev.reacquisition_multiplier(t, batch[i], cfg))


def test_renewal_segment_index_is_searchsorted_per_column():
    t = np.concatenate([[0.0, 0.5], np.arange(1.0, 120.0, 1.0), [120.25]])
    for length_s, n in (((2.0, 20.0), 7), ((20.0, 90.0), 1), ((1.0, 1.0), 3)):
        idx, starts, K = ev._renewal(t, length_s, np.random.default_rng(4), n=n)
        lengths = np.random.default_rng(4).uniform(length_s[0], length_s[1], size=(K, n))
        ends = t[0] + np.cumsum(lengths, axis=0)
        ref = np.stack([np.searchsorted(ends[:, j], t, side="right") for j in range(n)], axis=1)
        np.testing.assert_array_equal(idx, np.minimum(ref, K - 1))
        np.testing.assert_array_equal(starts, ends - lengths)


def test_segment_index_of_many_rows_is_searchsorted_per_column():
    """_segment_index (compiled merge) over R rows equals per column the count of ends at or before each epoch,
    np.searchsorted(..., side="right"), capped at K - 1, and its ends are t[0] + np.cumsum bit for bit: with
    ends falling exactly on epochs, zero lengths, segments that end before the last epoch and one column; negative
    lengths are refused."""
    t = np.concatenate([[0.0, 0.5], np.arange(1.0, 60.0, 1.0), [60.25]])
    rng = np.random.default_rng(9)
    cases = [rng.uniform(0.5, 9.0, (5, 12, 7)), np.ones((3, 70, 2)), rng.uniform(0.1, 0.6, (4, 6, 3)),
             rng.uniform(2.0, 30.0, (2, 30, 1))]
    cases[1][:, 3:5] = 0.0                                       # zero lengths: equal ends
    for lengths in cases:
        R, K, n = lengths.shape
        idx, ends = ev._segment_index(t, lengths)
        want_ends = t[0] + np.cumsum(lengths, axis=1)
        np.testing.assert_array_equal(ends.view(np.uint64), want_ends.view(np.uint64))
        for r in range(R):
            for j in range(n):
                ref = np.minimum(np.searchsorted(want_ends[r, :, j], t, side="right"), K - 1)
                np.testing.assert_array_equal(idx[r, :, j], ref, err_msg=f"{lengths.shape} {r} {j}")
    with pytest.raises(ValueError, match="segment lengths must be >= 0"):
        ev._segment_index(t, -np.ones((1, 3, 2)))


def test_zone_effects_rows_equal_each_row_alone():
    """zone_effects_rows over 8 rows gives what zone_effects gives for each row alone, bit for bit (the rows'
    draws from their own streams, their canyon windows, zone counts and segment indices kept apart), with the
    canyon geometry (rows with and without a canyon window) and without a heading; with ``active``, the same on
    the active elements and nothing elsewhere."""
    t = np.arange(1.0, 91.0)
    B, S = 8, 9
    cfg = ev.UrbanZones(open_s=(5.0, 40.0), weights=(0.35, 0.35, 0.3))
    _, v, h = _driving(B, t)
    rng = np.random.default_rng(5)
    el = rng.uniform(-0.1, 1.5, (B, t.size, S))
    az = rng.uniform(-math.pi, math.pi, (B, t.size, S))
    sched = [ev.draw_zone_schedule(t, cfg, np.random.default_rng(100 + i)) for i in range(B)]
    canyon = [any(k == ev.ZONE_CANYON for _, _, k in w) for _, _, w in sched]
    assert any(canyon) and not all(canyon)
    assert len({len(w) for _, _, w in sched}) > 1
    kind, zid = np.array([s[0] for s in sched]), np.array([s[1] for s in sched])
    for heading in (h, None):
        def gens(base):
            return [np.random.default_rng(base + i) for i in range(B)]
        rows = ev.zone_effects_rows(t, kind, zid, [s[2] for s in sched], el, az, v, heading, cfg, gens(200),
                                    gens(300))
        for i in range(B):
            one = ev.zone_effects(t, *sched[i], el[i], az[i], v[i], None if heading is None else heading[i], cfg,
                                  np.random.default_rng(200 + i), np.random.default_rng(300 + i))
            for a, b in zip(rows, one):
                np.testing.assert_array_equal(a[i], b)
        assert rows[0].any() and rows[1].any()
    blocked_geom = rows[0]
    with_geom = ev.zone_effects_rows(t, kind, zid, [s[2] for s in sched], el, az, v, h, cfg, gens(200), gens(300))
    assert (with_geom[0] & ~blocked_geom).any()         # the canyon walls block more than the overpasses alone
    act = el > 0.3                                      # only these elements evaluated: the others left out
    part = ev.zone_effects_rows(t, kind, zid, [s[2] for s in sched], el, az, v, h, cfg, gens(200), gens(300),
                                active=act)
    for a, b in zip(part, with_geom):
        np.testing.assert_array_equal(a, np.where(act, b, np.zeros_like(b)))
        assert b[~act].any() and a[act].any()


# ----------------------------------------------------------------------------- oracle truth
def _all_events(**kw):
    base = dict(bursts=ev.RandomBursts(rate_hz=0.02), mismatch=ev.SigmaMismatch(),
                regimes=ev.NoiseRegimes(), zones=ev.UrbanZones(), reacquisition=ev.Reacquisition(),
                outages=((150.0, 170.0),), noise_scale=((60.0, 80.0, 4.0),))
    base.update(kw)
    return GnssEvents(**base)


def test_pr_var_true_is_chi_square_consistent():
    r, v, h = _driving(6, T300)
    g = _sim(T300, r, v, h, receiver=NO_ATM, events=_all_events(), seeds=list(range(10, 16)))
    m = g.mask
    clean = m & ~g.nlos
    dirty = m & g.nlos
    assert clean.sum() > 5000 and dirty.sum() > 200
    for err, var, bias in ((g.pr_error_m, g.pr_var_true, g.pr_bias_m), (g.prr_error_mps, g.prr_var_true, g.prr_bias_mps)):
        ok, info = _chi2_ok(err[clean] ** 2 / var[clean])
        assert ok, info
        assert np.all(bias[clean] == 0.0)
        assert np.all(var[dirty] >= bias[dirty] ** 2)
        ok, info = _chi2_ok((err[dirty] - bias[dirty]) ** 2 / (var[dirty] - bias[dirty] ** 2))
        assert ok, info
        assert np.all(var[~m] == 1.0) and np.all(np.isfinite(var))
    # the multipliers make the truth non-trivial: the reported sigma is far from it on many channels
    ratio = g.pr_var_true[clean] / g.pr_sigma[clean] ** 2
    assert np.mean((ratio > 4) | (ratio < 0.25)) > 0.2


def test_pr_var_true_atmosphere_term_is_the_reported_one():
    """Clean open sky: the truth is exactly the reported variance (white + nominal atmosphere)."""
    r, v, h = _driving(2, T300)
    g = _sim(T300, r, v, h)
    m = g.mask
    np.testing.assert_allclose(g.pr_var_true[m], g.pr_sigma[m] ** 2, rtol=1e-12)
    np.testing.assert_allclose(g.prr_var_true[m], g.prr_sigma[m] ** 2, rtol=1e-12)
    assert np.all(g.event_mask == 0) and g.event_mask.dtype == np.uint16
    # with a mismatch the reported sigma is the truth times the drawn factor, and nothing else moves
    gm = _sim(T300, r, v, h, events=GnssEvents(mismatch=ev.SigmaMismatch()))
    fp, fd = ev.draw_mismatch(T300, ev.SigmaMismatch(), _child(0, _SUB_MISMATCH))
    np.testing.assert_allclose(gm.pr_sigma[0][m[0]], (g.pr_sigma[0] * fp[:, None])[m[0]], rtol=1e-12)
    np.testing.assert_allclose(gm.prr_sigma[0][m[0]], (g.prr_sigma[0] * fd[:, None])[m[0]], rtol=1e-12)
    for name in ("pr_error_m", "prr_error_mps", "pr_var_true", "mask", "pr"):
        np.testing.assert_array_equal(getattr(gm, name), getattr(g, name), err_msg=name)
    np.testing.assert_array_equal(gm.event_mask[0] & ev.MISMATCH > 0, (fp != 1.0) | (fd != 1.0))


def test_switching_an_event_on_keeps_the_other_draws():
    r, v, h = _driving(2, T300)
    base = _sim(T300, r, v, h, events=GnssEvents(zones=ev.UrbanZones()))
    more = _sim(T300, r, v, h, events=GnssEvents(zones=ev.UrbanZones(), bursts=ev.RandomBursts(rate_hz=0.03)))
    for name in ("mask", "nlos", "pr_bias_m", "cn0_dbhz", "pr_sigma"):
        np.testing.assert_array_equal(getattr(more, name), getattr(base, name), err_msg=name)
    quiet = (more.event_mask & ev.NOISE) == 0
    np.testing.assert_array_equal(more.pr_error_m[quiet], base.pr_error_m[quiet])
    assert not np.array_equal(more.pr_error_m[~quiet], base.pr_error_m[~quiet])


def test_event_mask_matches_configured_windows():
    r, v, h = _driving(2, T300)
    events = GnssEvents(outages=((50.0, 80.0),), noise_scale=((100.0, 120.0, 3.0), (130.0, 140.0, 1.0)),
                        canyon=UrbanCanyon(intervals=((200.0, 230.0),)),
                        bursts=ev.RandomBursts(rate_hz=0.02), zones=ev.UrbanZones())
    g = _sim(T300, r, v, h, events=events, seeds=[21, 22])
    t = T300
    for i, seed in enumerate((21, 22)):
        bm = g.event_mask[i]
        np.testing.assert_array_equal(bm & ev.OUTAGE > 0, (t >= 50) & (t < 80))
        assert np.all(g.n_used()[i][(t >= 50) & (t < 80)] == 0)
        _, _, act, win = ev.draw_bursts(t, events.bursts, _child(seed, _SUB_BURSTS))
        assert len(win) > 0
        np.testing.assert_array_equal(bm & ev.NOISE > 0, act | ((t >= 100) & (t < 120)))
        kind, _, _ = ev.draw_zone_schedule(t, events.zones, _child(seed, _SUB_ZONES))
        zone = (kind == ev.ZONE_CANYON) | (kind == ev.ZONE_TREES)
        np.testing.assert_array_equal(bm & ev.NLOS_ZONE > 0, zone | ((t >= 200) & (t < 230)))
        np.testing.assert_array_equal(bm & ev.TREES > 0, kind == ev.ZONE_TREES)
        np.testing.assert_array_equal(bm & ev.OVERPASS > 0, kind == ev.ZONE_OVERPASS)
        # zone NLOS only inside the zones (the old canyon interval has its own reflections)
        outside = ~zone & ~((t >= 200) & (t < 230))
        assert not g.nlos[i][outside].any()


def test_regime_bits_and_scales():
    r, v, h = _static([48.0, 48.0], T300.size) + (None,)
    cfg = ev.NoiseRegimes(regimes=(ev.NoiseRegime("a", 1.0, 1.0, 0.0, 50.0), ev.NoiseRegime("b", 6.0, 2.0, 0.0, 50.0)))
    g = _sim(T300, r, v, None, receiver=NO_ATM, events=GnssEvents(regimes=cfg), seeds=[3, 4])
    g0 = _sim(T300, r, v, None, receiver=NO_ATM, seeds=[3, 4])
    for i, seed in enumerate((3, 4)):
        reg, _ = ev.draw_regimes(T300, cfg, _child(seed, _SUB_REGIME))
        assert 0 < reg.mean() < 1
        np.testing.assert_array_equal(g.event_mask[i] & ev.REGIME > 0, reg == 1)
        m = g.mask[i]
        k = np.where(reg == 1, 6.0, 1.0)[:, None]
        kd = np.where(reg == 1, 2.0, 1.0)[:, None]
        np.testing.assert_allclose(g.pr_var_true[i][m], (g0.pr_var_true[i] * k**2)[m], rtol=1e-12)
        np.testing.assert_allclose(g.prr_var_true[i][m], (g0.prr_var_true[i] * kd**2)[m], rtol=1e-12)
        np.testing.assert_allclose(g.pr_error_m[i][m], (g0.pr_error_m[i] * k)[m], rtol=1e-9, atol=1e-12)


def test_reacquisition_after_outage_in_simulation():
    r, v = _static([30.0], T300.size)
    events = GnssEvents(outages=((100.0, 130.0),), reacquisition=ev.Reacquisition(scale=5.0, duration_s=10.0))
    g = _sim(T300, r, v, receiver=NO_ATM, events=events, seeds=[8])
    g0 = _sim(T300, r, v, receiver=NO_ATM, events=GnssEvents(outages=((100.0, 130.0),)), seeds=[8])
    m = g.mask[0]
    ratio = np.where(m, g.pr_var_true[0] / g0.pr_var_true[0], np.nan)
    k = np.flatnonzero(T300 == 130.0)[0]
    np.testing.assert_allclose(ratio[k:k + 10][m[k:k + 10]],
                               np.broadcast_to((5.0 ** (1 - np.arange(10) / 10.0))[:, None] ** 2, (10, m.shape[1]))[m[k:k + 10]])
    assert np.nanmax(ratio[k + 10:]) == 1.0 and np.nanmax(ratio[:100]) == 1.0
    bits = g.event_mask[0] & ev.REACQUISITION > 0
    np.testing.assert_array_equal(np.flatnonzero(bits), np.arange(k, k + 10))


def test_urban_zone_physics():
    t = np.arange(1.0, 601.0)
    r, v, h = _driving(8, t, speed=10.0)
    g = _sim(t, r, v, h, events=GnssEvents(zones=ev.UrbanZones()), seeds=list(range(30, 38)))
    m, el, cn0 = g.mask, g.elevation, g.cn0_dbhz
    canyon = ((g.event_mask & ev.NLOS_ZONE) > 0) & ((g.event_mask & ev.TREES) == 0)
    trees = (g.event_mask & ev.TREES) > 0
    over = (g.event_mask & ev.OVERPASS) > 0
    open_ = g.event_mask == 0
    assert over.any() and trees.any() and canyon.any()
    n = g.n_used()
    assert n[over].mean() < 0.3 * n[open_].mean()                        # almost total blockage
    assert n[canyon].mean() < n[open_].mean()                             # street-canyon blockage
    c = m & canyon[..., None]
    low, high = c & (el < math.radians(30)), c & (el > math.radians(50))
    assert g.nlos[low].mean() > g.nlos[high].mean() + 0.15                # low elevation: more NLOS
    # bias magnitude: log-normal with median 16.4 m / sin(el) (in the canyon; >= the reflection geometry)
    nl = c & g.nlos
    x = np.log(np.abs(g.pr_bias_m[nl]) * np.sin(el[nl]))
    assert abs(np.median(x) - math.log(ev.BIAS_SIN_MEDIAN_M)) < 0.25
    assert abs(np.mean(g.pr_bias_m[nl] > 0) - ev.BIAS_POSITIVE_FRACTION) < 0.05
    # C/N0: LOS follows the smartLoc line, NLOS ~11 dB below, trees attenuate
    lo_ = m & open_[..., None]
    resid = cn0[lo_] - ev.cn0_los(el[lo_])
    assert abs(resid.mean()) < 0.1 and abs(resid.std() - 1.0) < 0.1
    assert abs(np.mean(ev.cn0_los(el[nl]) - cn0[nl]) - ev.NLOS_DEFICIT_DB) < 0.3
    tr = m & trees[..., None] & ~g.nlos
    assert 5.0 < np.mean(ev.cn0_los(el[tr]) - cn0[tr]) < 9.0               # U(2, 12) dB foliage
    # weaker signal -> more true noise: 10^(loss/20) on the white sigma (no atmosphere term here)
    gna = _sim(t, r, v, h, receiver=NO_ATM, events=GnssEvents(zones=ev.UrbanZones()), seeds=list(range(30, 38)))
    g0 = _sim(t, r, v, h, receiver=NO_ATM, seeds=list(range(30, 38)))
    both = tr & g0.mask
    loss = ev.cn0_los(el[both]) - cn0[both]
    jitter_free = np.sqrt(gna.pr_var_true[both] / g0.pr_var_true[both])
    np.testing.assert_allclose(20 * np.log10(jitter_free), loss, atol=5 * 1.0)  # C/N0 jitter 1 dB
    assert np.corrcoef(20 * np.log10(jitter_free), loss)[0, 1] > 0.9


def test_dual_frequency_receiver_has_small_atmosphere():
    rx = ReceiverConfig.dual_frequency()
    assert rx.iono_zenith_sigma_m == 0.1 and rx.tropo_zenith_sigma_m == 0.12
    r, v = _static([45.0], 200)
    t = np.arange(1.0, 201.0)
    a = _sim(t, r, v, receiver=rx, seeds=[1])
    b = _sim(t, r, v, seeds=[1])
    np.testing.assert_array_equal(a.mask, b.mask)
    m = a.mask
    assert np.all(a.pr_sigma[m] < b.pr_sigma[m])
    # the atmosphere part of the error (same code-noise draws: minus the atmosphere-free receiver's error)
    c = _sim(t, r, v, receiver=NO_ATM, seeds=[1])
    atm_a, atm_b = (a.pr_error_m - c.pr_error_m)[m], (b.pr_error_m - c.pr_error_m)[m]
    assert np.sqrt(np.mean(atm_a**2)) < 0.5 * np.sqrt(np.mean(atm_b**2))


def test_gnss_data_rows_with_optional_truth():
    r, v, h = _driving(3, T300[:20])
    g = _sim(T300[:20], r, v, h, events=_all_events())
    sub = g.rows(1)
    assert sub.pr_var_true.shape == (1, 20, 16) and sub.event_mask.shape == (1, 20)
    np.testing.assert_array_equal(sub.pr_var_true[0], g.pr_var_true[1])
    rec = dataclasses.replace(g, pr_var_true=None, prr_var_true=None, pr_bias_m=None, prr_bias_mps=None,
                              event_mask=None, cn0_dbhz=None)
    assert rec.rows(slice(0, 2)).pr_var_true is None and rec.rows(2).shape == (1, 20, 16)
    assert GnssData(**{f.name: getattr(rec, f.name) for f in dataclasses.fields(GnssData)
                       if f.default is dataclasses.MISSING}).event_mask is None


# ----------------------------------------------------------------------------- IMU events
def _imu(events, seeds=(0, 1), grade="industrial", n=30001, rate=100.0, speed=10.0):
    B = len(seeds)
    f = np.zeros((B, n, 3))
    f[..., 2] = -9.8
    w = np.zeros((B, n, 3))
    from envs.sim.imu import Vibration
    return simulate_imu(f, w, rate, grade, row_generators(list(seeds), "imu"), speed=np.full((B, n), speed),
                        vibration=Vibration(), vibration_rngs=row_generators(list(seeds), "vibration"),
                        events=events, workers=1), f, w


def test_imu_bias_steps_and_rough_road():
    evs = ImuEvents(gyro_step_rate_hz=0.02, accel_step_rate_hz=0.02, rough_rate_hz=0.01)
    on, f, w = _imu(evs)
    off, _, _ = _imu(None)
    t_end = np.arange(f.shape[1]) * 0.01
    for i in range(2):
        steps, rough = on.bias_steps[i], on.rough[i]
        assert len(steps) > 0 and len(rough) > 0
        gsum = np.zeros((f.shape[1], 3))
        asum = np.zeros((f.shape[1], 3))
        for ts, sensor, axis, size in steps:
            lo, hi = (dph(10.0), dph(50.0)) if sensor == "gyro" else (mg(1.0), mg(5.0))
            assert lo <= abs(size) <= hi and 0 <= ts <= 300.0
            (gsum if sensor == "gyro" else asum)[t_end > ts, axis] += size
        np.testing.assert_allclose(on.gyro_bias[i] - off.gyro_bias[i], gsum, atol=1e-15)
        np.testing.assert_allclose(on.accel_bias[i] - off.accel_bias[i], asum, atol=1e-13)
        smooth = np.ones(f.shape[1], bool)
        for t0, t1, fac in rough:
            assert 2.0 <= fac <= 5.0 and 10.0 - 1e-9 <= t1 - t0 <= 40.0 or t1 == 300.0
            smooth &= ~((t_end > t0) & (t_end <= t1))
        # outside rough segments the output is the event-free output plus the steps, bit for bit
        np.testing.assert_allclose(on.w_b[i][smooth], (off.w_b[i] + gsum)[smooth], rtol=0, atol=1e-15)
        np.testing.assert_allclose(on.f_b[i][smooth], (off.f_b[i] + asum)[smooth], rtol=0, atol=1e-13)
        t0, t1, fac = max(rough, key=lambda x: x[1] - x[0])
        inside = (t_end > t0) & (t_end <= t1)
        ratio = np.std(np.diff(on.w_b[i][inside], axis=0)) / np.std(np.diff(off.w_b[i][inside], axis=0))
        assert abs(ratio / fac - 1.0) < 0.05
    # draws differ between seeds, are reproducible, and row i of a batch is the single run
    again, _, _ = _imu(evs)
    assert again.bias_steps == on.bias_steps and on.bias_steps[0] != on.bias_steps[1]
    single, _, _ = _imu(evs, seeds=(1,))
    assert single.bias_steps[0] == on.bias_steps[1] and single.rough[0] == on.rough[1]
    np.testing.assert_array_equal(single.f_b[0], on.f_b[1])


# ----------------------------------------------------------------------------- scenarios
@pytest.mark.parametrize("name", NEW)
def test_new_scenarios_registered_and_row_equals_single_run(name):
    scen = get_scenario(name, duration_s=120.0)
    assert SCENARIOS[name].duration_s == 300.0 and SCENARIOS[name].gnss_rate_hz == 1.0
    assert SCENARIOS[name].imu_rate_hz == 100.0 and SCENARIOS[name].imu_grade == "industrial"
    batch = generate_world(scen, [5, 7, 9])
    one = generate_world(scen, [7])
    for f in dataclasses.fields(GnssData):
        a, b = getattr(batch.gnss, f.name), getattr(one.gnss, f.name)
        if f.name in ("t",):
            np.testing.assert_array_equal(a, b)
        else:
            np.testing.assert_array_equal(a[1:2], b, err_msg=f.name)
    np.testing.assert_array_equal(batch.imu.f_b[1:2], one.imu.f_b)
    np.testing.assert_array_equal(batch.imu.w_b[1:2], one.imu.w_b)
    if batch.imu.bias_steps is not None:
        assert batch.imu.bias_steps[1] == one.imu.bias_steps[0]
    # random events differ between seeds
    em = batch.gnss.event_mask
    assert em.any() and not (np.array_equal(em[0], em[1]) and np.array_equal(em[1], em[2]))


def test_new_scenarios_carry_their_events():
    w = generate_world("noise-mismatch", [0, 1, 2])
    em = w.gnss.event_mask
    assert (em & ev.MISMATCH).any() and (em & ev.IMU_EVENT).any() and not (em & (ev.NLOS_ZONE | ev.REGIME)).any()
    t = w.gnss.t
    for i in range(3):
        steps = [s[0] for s in w.imu.bias_steps[i]]
        for ts in steps:
            assert np.all(em[i][(t >= ts) & (t < ts + 5.0)] & ev.IMU_EVENT)
        for t0, t1, _ in w.imu.rough[i]:
            assert np.all(em[i][(t > t0) & (t <= t1)] & ev.ROUGH_ROAD)
    assert w.scenario.receiver.iono_zenith_sigma_m <= 0.2
    w = generate_world("regime-switch", [0, 1, 2])
    assert (w.gnss.event_mask & ev.REGIME).any() and w.scenario.receiver.iono_zenith_sigma_m <= 0.2
    w = generate_world("urban-transition", [0, 1, 2])
    em = w.gnss.event_mask
    assert (em & ev.NLOS_ZONE).any() and (em & ev.REACQUISITION).any()
    zone_count = [np.sum(np.diff((em[i] & (ev.NLOS_ZONE | ev.OVERPASS) > 0).astype(int)) == 1) for i in range(3)]
    assert min(zone_count) >= 2, zone_count                                # several zones per 300 s
    assert 0.2 < np.mean(em & (ev.NLOS_ZONE | ev.OVERPASS) > 0) < 0.8         # and open sky between them


def test_seed003_reacquisition_after_outages():
    w = generate_world(get_scenario("seed003-sim", duration_s=330.0), [0])
    em, t = w.gnss.event_mask[0], w.gnss.t
    np.testing.assert_array_equal(em & ev.OUTAGE > 0, (t >= 100) & (t < 300))
    np.testing.assert_array_equal(np.flatnonzero(em & ev.REACQUISITION), np.flatnonzero((t >= 300) & (t < 310)))


@pytest.mark.parametrize("make, field", [
    (lambda: ev.RandomBursts(rate_hz=-1.0), "RandomBursts.rate_hz"),
    (lambda: ev.RandomBursts(duration_s=(0.0, 5.0)), "RandomBursts.duration_s"),
    (lambda: ev.RandomBursts(scale=(5.0, 3.0)), "RandomBursts.scale"),
    (lambda: ev.RandomBursts(joint=1), "RandomBursts.joint"),
    (lambda: ev.SigmaMismatch(p_honest=1.5), "SigmaMismatch.p_honest"),
    (lambda: ev.SigmaMismatch(pr_factor=(0.0, 2.0)), "SigmaMismatch.pr_factor"),
    (lambda: ev.NoiseRegime("x", code_scale=0.0), "NoiseRegime.code_scale"),
    (lambda: ev.NoiseRegime("", 1.0), "NoiseRegime.name"),
    (lambda: ev.NoiseRegimes(regimes=(ev.NoiseRegime("a"),)), "NoiseRegimes.regimes"),
    (lambda: ev.NoiseRegimes(regimes=(ev.NoiseRegime("a"), "b")), "NoiseRegimes.regimes[1]"),
    (lambda: ev.UrbanZones(weights=(0.0, 0.0, 0.0)), "UrbanZones.weights"),
    (lambda: ev.UrbanZones(overpass_pass_probability=2.0), "UrbanZones.overpass_pass_probability"),
    (lambda: ev.UrbanZones(canyon="street"), "UrbanZones.canyon"),
    (lambda: ev.Reacquisition(scale=0.5), "Reacquisition.scale"),
    (lambda: ev.Reacquisition(duration_s=0.0), "Reacquisition.duration_s"),
    (lambda: ImuEvents(rough_scale=(0.5, 2.0)), "ImuEvents.rough_scale"),
    (lambda: ImuEvents(gyro_step_rate_hz=-1.0), "ImuEvents.gyro_step_rate_hz"),
    (lambda: GnssEvents(zones=ev.RandomBursts()), "GnssEvents.zones"),
    (lambda: GnssEvents(reacquisition=5.0), "GnssEvents.reacquisition"),
    (lambda: Scenario(name="x", imu_events="rough"), "Scenario.imu_events"),
])
def test_validation_names_the_field(make, field):
    with pytest.raises(ValueError, match=field.replace("[", r"\[").replace("]", r"\]")):
        make()


def test_combine_keeps_the_last_random_event():
    a = GnssEvents(bursts=ev.RandomBursts(rate_hz=0.01), zones=ev.UrbanZones())
    b = GnssEvents(bursts=ev.RandomBursts(rate_hz=0.05), reacquisition=ev.Reacquisition())
    c = a.combine(b)
    assert c.bursts.rate_hz == 0.05 and c.zones is not None and c.reacquisition is not None


# ----------------------------------------------------------------------------- smartLoc-measured constants
def test_zone_constants_are_the_measured_smartloc_statistics():
    from envs.datasets.errors import shared_data_dir
    if not (shared_data_dir() / "smartloc").is_dir():
        pytest.skip("smartLoc data folder absent (../shared/data/smartloc or $NAVGYM_DATA_DIR)")
    from envs.datasets.smartloc_stats import urban_error_statistics
    s = urban_error_statistics()
    assert s.n_measurements > 10_000
    assert abs(s.cn0_los_a - ev.CN0_LOS_A) < 0.1 and abs(s.cn0_los_b - ev.CN0_LOS_B) < 0.1
    assert abs(s.nlos_deficit_db - ev.NLOS_DEFICIT_DB) < 0.5
    assert abs(s.p_nlos_a - ev.P_NLOS_A) < 0.01 and abs(s.p_nlos_b - ev.P_NLOS_B) < 0.01
    assert abs(s.bias_sin_median_m - ev.BIAS_SIN_MEDIAN_M) < 0.1 and abs(s.bias_sigma_ln - ev.BIAS_SIGMA_LN) < 0.01
    assert abs(s.bias_positive_fraction - ev.BIAS_POSITIVE_FRACTION) < 0.01
    assert ev.UrbanZones().segment_s[0] >= 0.5 * s.nlos_mean_run_s


def test_cn0_scatter_and_zone_calibration_fields_are_validated():
    with pytest.raises(ValueError, match="Cn0Scatter.gm_tau_s"):
        ev.Cn0Scatter(gm_tau_s=0.0)
    with pytest.raises(ValueError, match="Cn0Scatter.white_sigma_db"):
        ev.Cn0Scatter(white_sigma_db=-1.0)
    with pytest.raises(ValueError, match=r"UrbanZones.nlos_bias\[0\]"):
        ev.UrbanZones(nlos_bias=(0.0, 1.0))
    with pytest.raises(ValueError, match="UrbanZones.nlos_probability must be a pair"):
        ev.UrbanZones(nlos_probability=(1.0,))
    with pytest.raises(ValueError, match="GnssEvents.cn0 must be a Cn0Scatter"):
        GnssEvents(cn0=3.0)


def _scatter_by_its_draws(t, S, C, cfg, g):
    """The C/N0 scatter of one row as its docstring draws it: four standard_normal calls, one per part."""
    from envs.sim.receiver import _gauss_markov
    M = t.size
    offset = cfg.offset_sigma_db * g.standard_normal(S)
    gm = _gauss_markov(t, cfg.gm_tau_s, cfg.gm_sigma_db, g.standard_normal((M, S)))
    deficit = cfg.nlos_deficit_db + _gauss_markov(t, cfg.gm_tau_s, cfg.nlos_deficit_sigma_db,
                                                  g.standard_normal((M, S)))
    return offset[None, :] + gm, deficit, cfg.white_sigma_db * g.standard_normal((M, C))


def test_cn0_scatter_of_many_rows_is_the_scatter_row_by_row():
    """cn0_scatter_rows from each row's normals drawn in one call (row_normals) gives the scatter of each row drawn
    part by part from the same stream, bit for bit, and so does cn0_scatter (also at one epoch and with more
    channels than satellites)."""
    from envs.sim.rng import ChildStreams, row_normals
    cfg = ev.Cn0Scatter()
    for M, S, C in ((40, 9, 6), (1, 5, 8)):
        t = np.arange(float(M)) * 0.5
        ref = [_scatter_by_its_draws(t, S, C, cfg, ChildStreams([7 + b, 3], 2)[1]) for b in range(4)]
        one = [ev.cn0_scatter(t, S, C, cfg, ChildStreams([7 + b, 3], 2)[1]) for b in range(4)]
        z = row_normals([ChildStreams([7 + b, 3], 2) for b in range(4)], 1, (ev.cn0_scatter_draws(M, S, C),))
        got = ev.cn0_scatter_rows(t, S, C, cfg, z)
        for i, name in enumerate(("los", "deficit", "white")):
            assert got[i].shape == (4,) + ref[0][i].shape, name
            np.testing.assert_array_equal(got[i], np.stack([r[i] for r in ref]), err_msg=name)
            np.testing.assert_array_equal(np.stack([r[i] for r in one]), got[i], err_msg=name)


def test_cn0_scatter_draws_its_model():
    """Offset + Gauss-Markov + white: the LOS scatter's variance and its autocorrelation at lag 1 s and 30 s, and
    the NLOS deficit's mean and spread (many satellites, one long row)."""
    cfg = ev.Cn0Scatter()
    t = np.arange(3000.0)
    los, deficit, white = ev.cn0_scatter(t, 400, 12, cfg, np.random.default_rng(5))
    assert los.shape == deficit.shape == (3000, 400) and white.shape == (3000, 12)
    var = cfg.offset_sigma_db ** 2 + cfg.gm_sigma_db ** 2
    assert los.var() == pytest.approx(var, rel=0.08)
    assert white.std() == pytest.approx(cfg.white_sigma_db, rel=0.03)
    for lag in (1, 30):
        c = np.mean((los[lag:] * los[:-lag])) / var
        want = (cfg.offset_sigma_db ** 2 + cfg.gm_sigma_db ** 2 * np.exp(-lag / cfg.gm_tau_s)) / var
        assert c == pytest.approx(want, abs=0.06)
    assert deficit.mean() == pytest.approx(cfg.nlos_deficit_db, abs=0.1)
    assert deficit.std() == pytest.approx(cfg.nlos_deficit_sigma_db, rel=0.03)
