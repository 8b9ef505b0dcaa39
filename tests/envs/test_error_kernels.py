"""The GNSS error stages' compiled kernels (envs.sim.error_kernels) against the numpy chains they replaced, and
the receiver stage's buffers.

The chains below are the stages' arithmetic as it was written in numpy (one ufunc per operation, left to right;
the NLOS bursts row by row). The kernels evaluate the same IEEE operations and searches in the same order, so the
two must agree bit for bit: on every channel, with the nominal or a variance-model sigma, with or without the
reported-sigma mismatch, for any split of the rows over threads; for the bursts, on rows with different numbers
of cycles and bursts that start before or end after the epochs.
"""
from __future__ import annotations

import numpy as np
import pytest

from envs.sim.buffers import WorldBuffers
from envs.sim.error_kernels import nlos_burst_rows
from envs.sim.gnss import NlosConfig
from envs.sim.gnss_stages import _nlos_burst_rows, _nlos_bursts
from envs.sim.receiver import _MIN_EL_SIGMA, iono_obliquity, tropo_mapping
from envs.sim.error_kernels import measurement_rows, receiver_tail_rows
from envs.sim.row_threads import run_row_ranges
from envs.sim.world import generate_world

SIGMAS = (0.6, 0.05, 0.12, 0.4)  # pr, prr, zenith tropo, zenith iono


def _inputs(seed, B=13, M=17, C=9):
    rng = np.random.default_rng(seed)
    el = rng.uniform(-0.1, 1.5, (B, M, C))
    mask = rng.random((B, M, C)) < 0.8
    nlos = mask & (rng.random((B, M, C)) < 0.3)
    return dict(
        el=el, mask=mask, tropo_z=rng.normal(0, 0.1, (M, B)).T,     # a transposed view, as the stage passes it
        iono_ch=rng.normal(0, 0.5, (B, M, C)),
        pr_bias=np.where(nlos, rng.uniform(0, 40, (B, M, C)), 0.0),
        prr_bias=np.where(nlos, rng.normal(0, 0.3, (B, M, C)), 0.0),
        code_mult=rng.uniform(1, 5, (B, M, C)), doppler_mult=rng.uniform(1, 5, (B, M, C)),
        code_z=rng.standard_normal((B, M, C)), rate_z=rng.standard_normal((B, M, C)),
        code_rep=rng.uniform(0.5, 2, (B, M)), doppler_rep=rng.uniform(0.5, 2, (B, M)),
        variance=rng.uniform(0.1, 30, (B, M, C)))


def _chain(d, nominal, rep):
    """The numpy chain of ``receiver_errors`` before the kernel."""
    sp, sr, st, si = SIGMAS
    el, mask = d["el"], d["mask"]
    s_el = np.sin(np.maximum(el, _MIN_EL_SIGMA))
    m_t, f_i = tropo_mapping(el), iono_obliquity(el)
    sig_pr_code = sp / s_el
    sig_prr = sr / s_el
    pr_white = d["code_mult"] * sig_pr_code
    prr_white = d["doppler_mult"] * sig_prr
    pr_err = (m_t * d["tropo_z"][..., None] + f_i * d["iono_ch"] + d["pr_bias"] + pr_white * d["code_z"])
    prr_err = d["prr_bias"] + prr_white * d["rate_z"]
    atm_var = (m_t * st) ** 2 + (f_i * si) ** 2
    pr_sigma = np.sqrt(sig_pr_code**2 + (m_t * st) ** 2 + (f_i * si) ** 2)
    if not nominal:
        pr_sigma = np.sqrt(d["variance"])
    pr_var_true = np.where(mask, pr_white**2 + atm_var + d["pr_bias"]**2, 1.0)
    prr_var_true = np.where(mask, prr_white**2 + d["prr_bias"]**2, 1.0)
    if rep:
        pr_sigma = pr_sigma * d["code_rep"][..., None]
        sig_prr = sig_prr * d["doppler_rep"][..., None]
    return pr_err, prr_err, pr_sigma, sig_prr, pr_var_true, prr_var_true


def _kernel(d, nominal, rep, workers=1):
    el = d["el"]
    out = [np.full(el.shape, np.nan) for _ in range(6)]
    if not nominal:
        np.sqrt(d["variance"], out=out[2])
    s_el = np.sin(np.maximum(el, _MIN_EL_SIGMA))
    run_row_ranges(lambda r0, r1: receiver_tail_rows(
        r0, r1, tropo_mapping(el), iono_obliquity(el), d["tropo_z"], d["iono_ch"], s_el, d["pr_bias"],
        d["prr_bias"], d["code_mult"], d["doppler_mult"], d["code_z"], d["rate_z"], d["mask"], *SIGMAS, nominal,
        d["code_rep"], d["doppler_rep"], rep, *out), el.shape[0], workers=workers, min_rows=2)
    return out


@pytest.mark.parametrize("nominal", [True, False])
@pytest.mark.parametrize("rep", [False, True])
def test_kernel_equals_the_numpy_chain_bit_for_bit(nominal, rep):
    d = _inputs(3)
    want = _chain(d, nominal, rep)
    for workers in (1, 3):
        got = _kernel(d, nominal, rep, workers)
        for name, g, w in zip(("pr_err", "prr_err", "pr_sigma", "prr_sigma", "pr_var_true", "prr_var_true"),
                              got, want):
            np.testing.assert_array_equal(g, w, err_msg=f"{name}, workers {workers}")


def test_kernel_writes_only_its_rows():
    d = _inputs(4)
    el = d["el"]
    out = [np.full(el.shape, np.nan) for _ in range(6)]
    receiver_tail_rows(3, 7, tropo_mapping(el), iono_obliquity(el), d["tropo_z"], d["iono_ch"],
                       np.sin(np.maximum(el, _MIN_EL_SIGMA)), d["pr_bias"], d["prr_bias"], d["code_mult"],
                       d["doppler_mult"], d["code_z"], d["rate_z"], d["mask"], *SIGMAS, True, d["code_rep"],
                       d["doppler_rep"], False, *out)
    for o in out:
        assert np.isfinite(o[3:7]).all() and np.isnan(o[:3]).all() and np.isnan(o[7:]).all()


@pytest.mark.parametrize("scenario", ["noise-burst", "urban"])
def test_world_buffers_give_the_receiver_stage_the_same_bits(scenario):
    """Worlds drawn through one WorldBuffers equal worlds drawn without; a world still held is not overwritten by
    the next draw, and once nobody holds it the next draw reuses its receiver arrays."""
    names = ("pr", "prr", "pr_sigma", "prr_sigma", "pr_error_m", "prr_error_mps", "pr_var_true", "prr_var_true")
    seeds = [[0, 1, 2], [5, 6, 7]]
    fresh = [generate_world(scenario, s) for s in seeds]
    buf = WorldBuffers()
    held = generate_world(scenario, seeds[0], buffers=buf)
    keep = {n: getattr(held.gnss, n).copy() for n in names}
    nxt = generate_world(scenario, seeds[1], buffers=buf)            # drawn while the first is held
    assert not np.shares_memory(held.gnss.pr_error_m, nxt.gnss.pr_error_m)
    for n in names:
        np.testing.assert_array_equal(getattr(held.gnss, n), keep[n], err_msg=n)
    address = nxt.gnss.pr_error_m.__array_interface__["data"][0]
    del held, nxt
    again = generate_world(scenario, seeds[0], buffers=buf)          # nobody holds the arrays: reused
    assert again.gnss.pr_error_m.__array_interface__["data"][0] == address
    for w, f in ((again, fresh[0]), (generate_world(scenario, seeds[1], buffers=buf), fresh[1])):
        for n in names:
            np.testing.assert_array_equal(getattr(w.gnss, n), getattr(f.gnss, n), err_msg=n)


def _bursts_chain(t, t_begin, gp, du, bs, rs):
    """The NLOS bursts of one row from its cycles (K, S), as the numpy chain mapped them."""
    M, S = t.size, gp.shape[1]
    cyc_end = t_begin + np.cumsum(gp + du, axis=0)
    b_start = cyc_end - du
    i0 = np.searchsorted(t, b_start.ravel(), side="left")
    i1 = np.searchsorted(t, cyc_end.ravel(), side="left")
    sat = np.broadcast_to(np.arange(S), b_start.shape).ravel()
    ident = np.arange(1, b_start.size + 1)
    diff = np.zeros((M + 1, S), dtype=np.int64)
    np.add.at(diff, (i0, sat), ident)
    np.add.at(diff, (i1, sat), -ident)
    burst = np.cumsum(diff[:M], axis=0)
    active = burst > 0
    k = np.maximum(burst - 1, 0)
    return active, np.where(active, bs.ravel()[k], 0.0), np.where(active, rs.ravel()[k], 0.0)


def test_nlos_burst_kernel_equals_the_numpy_chain_row_by_row():
    rng = np.random.default_rng(11)
    t = np.arange(0.0, 90.0, 1.0) + 0.25
    S, K = 7, np.array([9, 4, 13], dtype=np.int64)             # rows of different lengths, padded to 13
    cyc = np.zeros((4, K.size, K.max(), S))
    cyc[0] = rng.exponential(8.0, cyc.shape[1:])
    cyc[1] = rng.uniform(1.0, 6.0, cyc.shape[1:])
    cyc[2] = rng.uniform(10.0, 80.0, cyc.shape[1:])
    cyc[3] = rng.normal(0.0, 0.3, cyc.shape[1:])
    shape = (K.size, t.size, S)
    got = (np.empty(shape, bool), np.full(shape, np.nan), np.full(shape, np.nan))
    nlos_burst_rows(t, -6.0, K, *cyc, *got)
    for b, k in enumerate(K):
        want = _bursts_chain(t, -6.0, *(c[b, :k] for c in cyc))
        assert want[0].any() and not want[0].all()
        for g, w in zip(got, want):
            np.testing.assert_array_equal(g[b], w)


def test_nlos_bursts_of_rows_equal_each_row_alone():
    """Rows drawn together equal each row drawn alone (its own generator), and a zero rate draws nothing."""
    cfg = NlosConfig(rate_hz=0.05, duration_s=(2.0, 9.0), bias_m=(5.0, 60.0), rate_sigma_mps=0.2)
    t = np.arange(1.0, 121.0)
    rows = _nlos_burst_rows(t, 6, cfg, [np.random.default_rng(s) for s in (1, 2, 3)])
    assert rows[0].any()
    for b, s in enumerate((1, 2, 3)):
        for g, w in zip(rows, _nlos_bursts(t, 6, cfg, np.random.default_rng(s))):
            np.testing.assert_array_equal(g[b], w)
    g = np.random.default_rng(0)
    off = _nlos_burst_rows(t, 6, NlosConfig(rate_hz=0.0), [g])
    assert not off[0].any() and not off[1].any() and g.random() == np.random.default_rng(0).random()


def test_gauss_markov_rows_equal_the_lfilter_process_of_each_row():
    """receiver._gauss_markov_rows (compiled lfilter recursion on uniform steps) gives, for each row of (R, M, L)
    draws, receiver._gauss_markov of that row (scipy's lfilter, time axis first) bit for bit: one and many columns,
    a single epoch, and non-uniform steps (its numpy path)."""
    from envs.sim.receiver import _gauss_markov, _gauss_markov_rows
    rng = np.random.default_rng(12)
    uniform = np.arange(1.0, 61.0)
    for t, L in ((uniform, 30), (uniform, 1), (0.2 * uniform, 7), (np.array([3.0]), 4),
                 (np.cumsum(rng.uniform(0.5, 2.0, 40)), 5)):
        z = rng.standard_normal((6, t.size, L))
        got = _gauss_markov_rows(t, 300.0, 0.4, z)
        assert got.shape == z.shape and got.flags.c_contiguous
        for r in range(z.shape[0]):
            want = _gauss_markov(t, 300.0, 0.4, z[r])
            np.testing.assert_array_equal(got[r].view(np.uint64), want.view(np.uint64), err_msg=f"{t.size} {L} {r}")


def test_measurement_rows_equal_the_numpy_lines_bit_for_bit():
    """measurement_rows: ``pr = rho + bias[..., None] + pr_err`` (and the rates), then ``a[~mask] = 0`` in each of
    the nine channel arrays: the same bits as those numpy lines, signed zeros and NaN under the mask included, on
    row ranges of any split; the rows outside its range untouched."""
    rng = np.random.default_rng(8)
    B, M, C = 11, 7, 5
    mask = rng.random((B, M, C)) < 0.6
    rho, rho_dot = rng.uniform(2e7, 2.6e7, (B, M, C)), rng.normal(0.0, 800.0, (B, M, C))
    bias, drift = rng.normal(0.0, 1e4, (B, M)), rng.normal(0.0, 50.0, (B, M))
    chan = {k: rng.normal(size=(B, M, C)) for k in ("pr_err", "prr_err", "pr_sigma", "prr_sigma", "el", "az", "cn0")}
    chan["el"][~mask] = np.nan                                 # whatever lies under the mask is zeroed
    chan["cn0"][~mask] = -0.0
    ref = {k: a.copy() for k, a in chan.items()}
    ref["pr"] = np.add(rho, bias[..., None]) + ref["pr_err"]
    ref["prr"] = np.add(rho_dot, drift[..., None]) + ref["prr_err"]
    for a in ref.values():
        a[~mask] = 0.0
    for split in ((0, B), (0, 4, B), (0, 1, 2, 9, B)):
        got = {k: a.copy() for k, a in chan.items()}
        got["pr"], got["prr"] = np.full((B, M, C), 7.0), np.full((B, M, C), 7.0)
        for r0, r1 in zip(split[:-1], split[1:]):
            measurement_rows(r0, r1, mask, rho, bias, got["pr_err"], rho_dot, drift, got["prr_err"], got["pr"],
                             got["prr"], got["pr_sigma"], got["prr_sigma"], got["el"], got["az"], got["cn0"])
        for k in ref:
            assert got[k].tobytes() == ref[k].tobytes(), (split, k)
    part = {k: a.copy() for k, a in chan.items()}
    pr, prr = np.full((B, M, C), 7.0), np.full((B, M, C), 7.0)
    measurement_rows(3, 5, mask, rho, bias, part["pr_err"], rho_dot, drift, part["prr_err"], pr, prr,
                     part["pr_sigma"], part["prr_sigma"], part["el"], part["az"], part["cn0"])
    outside = np.r_[0:3, 5:B]
    assert (pr[outside] == 7.0).all() and (prr[outside] == 7.0).all()
    for k, a in part.items():
        assert a[outside].tobytes() == chan[k][outside].tobytes(), k
        assert a[3:5].tobytes() == ref[k][3:5].tobytes(), k


def _channel_noise_numpy(t, ch, sat, events):
    """The channel-noise stage as it was written in numpy (the specification of channel_noise_rows): the NLOS
    state, its bias and rate, the C/N0 losses and the true noise multipliers of every channel; returns
    ``(nlos, pr_bias, prr_bias, code_mult, doppler_mult, cn0, bits)`` without touching its inputs."""
    from envs.sim import events as ev
    cn0, bits = ch.cn0.copy(), sat.bits.copy()
    scale = np.ones(t.size)
    for iv in events.noise_scale:
        scale = np.where((t >= iv[0]) & (t < iv[1]), scale * iv[2], scale)
    mask = ch.mask
    nlos = ch.gather(sat.nlos) & mask
    nlos_bias, nlos_rate = ch.gather(sat.nlos_bias), ch.gather(sat.nlos_rate)
    k_nlos = events.nlos.noise_factor if events.nlos is not None else 3.0
    deficit = ev.NLOS_DEFICIT_DB if ch.nlos_deficit is None else ch.nlos_deficit
    cn0 -= np.where(nlos, deficit, 0.0)
    noise_mult = scale[None, :, None] * np.where(nlos, k_nlos, 1.0)
    noise_mult_prr = noise_mult
    if sat.zone is not None:
        nlos2_sat, bias2_sat, rate2_sat, att_sat = sat.zone
        nlos2 = ch.gather(nlos2_sat) & mask
        att = ch.gather(att_sat)
        nlos_bias = np.where(nlos2, ch.gather(bias2_sat), nlos_bias)
        nlos_rate = np.where(nlos2, ch.gather(rate2_sat), nlos_rate)
        noise_mult = np.where(nlos2 & nlos, noise_mult / k_nlos, noise_mult) * 10.0 ** (att / 20.0)
        nlos = nlos | nlos2
        cn0 -= att
        if ch.nlos_deficit is not None:
            cn0 += np.where(nlos2, ev.NLOS_DEFICIT_DB - deficit, 0.0)
        noise_mult_prr = noise_mult
    if sat.reacq is not None:
        rq = ch.gather(sat.reacq)
        noise_mult = noise_mult * rq
        noise_mult_prr = noise_mult_prr * rq
        bits |= np.where((mask & (rq > 1.0)).any(axis=-1), ev.REACQUISITION, 0).astype(np.uint16)
    if events.bursts is not None or events.regimes is not None:
        noise_mult = noise_mult * sat.code_mult[:, :, None]
        noise_mult_prr = noise_mult_prr * sat.doppler_mult[:, :, None]
    return (nlos, np.where(nlos, nlos_bias, 0.0), np.where(nlos, nlos_rate, 0.0), noise_mult, noise_mult_prr,
            cn0, bits)


@pytest.mark.parametrize("scenario", ["urban", "urban-smartloc", "regime-switch", "seed003-sim", "noise-burst"])
def test_channel_noise_kernel_equals_the_numpy_chain_bit_for_bit(scenario, monkeypatch):
    """channel_noise (channel_noise_rows in row ranges) against the numpy chain on the stages' own inputs: the
    canyon and NLOS bursts (urban), the zones with the C/N0 scatter's per-channel deficit and re-acquisition
    (urban-smartloc), the noise regimes (regime-switch), re-acquisition alone (seed003-sim), the noise-scale
    intervals (noise-burst); every output, the C/N0 and the event bits bit for bit."""
    import dataclasses

    import envs.sim.gnss_stages as st
    from envs.sim.rng import row_generators
    from tests.envs.test_world_stages import _gnss_inputs, stages_to_channels
    seeds = list(range(40, 110))
    args, _ = _gnss_inputs(scenario, seeds, monkeypatch, duration_s=40.0)
    t, r_e, v_e, heading, con, rec, events = np.asarray(args[0], np.float64), *args[1:7]
    subs = [st._row_children(g) for g in row_generators(seeds, "gnss")]
    _, sat, ch = stages_to_channels(t, r_e, v_e, heading, con, rec, events, subs, events.cn0)
    ref = _channel_noise_numpy(t, ch, sat, events)
    noise = st.channel_noise(t, ch, sat, events)
    mine = (*(getattr(noise, f.name) for f in dataclasses.fields(noise)), ch.cn0, sat.bits)
    for name, a, b in zip(("nlos", "pr_bias", "prr_bias", "code_mult", "doppler_mult", "cn0", "bits"), mine, ref):
        assert a.dtype == b.dtype, name
        np.testing.assert_array_equal(a, b, err_msg=name)
    assert noise.nlos.any() or scenario in ("noise-burst", "seed003-sim", "regime-switch")
