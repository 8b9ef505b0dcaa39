"""Compiled row kernels of the GNSS error stages (:mod:`envs.sim.gnss_stages`).

* :func:`nlos_burst_rows`: the NLOS bursts' epochs, biases and rates of every row and satellite from the row's
  drawn renewal cycles (:func:`envs.sim.gnss_stages.canyon_and_bursts`);
* :func:`segment_index_rows`: the segment index per epoch of renewal processes of consecutive segments (the
  urban zones' and noise regimes' per-satellite segments, :func:`envs.sim.events._segment_index`);
* :func:`gauss_markov_rows`: first-order Gauss-Markov processes on uniform steps along the time axis of rows of
  columns (:func:`envs.sim.receiver._gauss_markov_rows`: the troposphere and ionosphere residuals);
* :func:`receiver_tail_rows`: the channel errors, reported sigmas and true variances of rows ``r0 .. r1-1`` in
  one pass without the GIL, from the per-channel inputs the stage draws and maps with numpy (the mapping
  functions, the Gauss-Markov processes, the white-noise variates) (:func:`envs.sim.gnss_stages.receiver_errors`);
* :func:`measurement_rows`: the pseudoranges and rates of rows ``r0 .. r1-1`` and the untracked channels set to
  zero in every output (:func:`envs.sim.gnss._gnss_data`).

Each replaces a numpy chain: per row and satellite for the bursts (a dozen small operations per row), and of
about 25 temporaries of the (B, M, C) channel shape for the receiver (each a fresh allocation per world, which the
operating system maps and zeroes: at B = 1024 about half of that stage's time). They evaluate the same sums,
products, quotients, square roots and searches in the same order as those chains (no fastmath, no fused
multiply-add: the same roundings), so the worlds stay the same bit for bit (``tests/envs/test_error_kernels.py``
compares each with its chain).
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True)
def nlos_burst_rows(t, t_begin, K, gap, dur, bias_draw, rate_draw, active, bias, rate):
    """Map each row's NLOS burst cycles onto the epochs (alternating renewal process of
    :class:`~envs.sim.gnss.NlosConfig`).

    Row b, satellite s: cycle k ends at ``t_begin + sum_{j <= k} (gap_j + dur_j)`` (a running sum, as
    ``np.cumsum``), its burst spans ``[end - dur_k, end)``; the epochs in it are those from the first
    ``t_i >= start`` to before the first ``t_i >= end`` (``np.searchsorted``, left). Each burst carries its
    identity ``k S + s + 1`` into a difference array whose running sum gives the burst at each epoch (bursts of one
    satellite never overlap), whose drawn bias and rate it takes.

    Parameters
    ----------
    t : (M,) epochs [s]; t_begin : float, start of the first cycle [s].
    K : (B,) int, cycles drawn per row; gap, dur, bias_draw, rate_draw : (B, K_max, S) the cycles' gaps and
        durations [s], bias [m] and rate [m/s] draws (rows beyond ``K[b]`` unused).
    active : (B, M, S) bool; bias, rate : (B, M, S) float64 outputs (0 outside bursts).
    """
    B, M, S = active.shape
    diff = np.zeros(M + 1, np.int64)
    for b in range(B):
        for s in range(S):
            diff[:] = 0
            acc = 0.0
            for k in range(K[b]):
                acc = acc + (gap[b, k, s] + dur[b, k, s])
                end = t_begin + acc
                ident = k * S + s + 1
                diff[np.searchsorted(t, end - dur[b, k, s])] += ident     # side "left"
                diff[np.searchsorted(t, end)] -= ident
            run = 0
            for m in range(M):
                run += diff[m]
                if run > 0:
                    j = run - 1
                    active[b, m, s] = True
                    bias[b, m, s] = bias_draw[b, j // S, j % S]
                    rate[b, m, s] = rate_draw[b, j // S, j % S]
                else:
                    active[b, m, s] = False
                    bias[b, m, s] = 0.0
                    rate[b, m, s] = 0.0


@nb.njit(cache=True, nogil=True)
def segment_index_rows(t, lengths, idx, ends):
    """Segment index per epoch of R rows of n columns of consecutive segments from ``t[0]``.

    Column ``(r, j)``: segment ``k`` ends at ``ends[r, k, j] = t[0] + (lengths[r, 0, j] + ... + lengths[r, k, j])``,
    the running sum taken in order (``t[0] + np.cumsum(lengths, axis=1)``: the same roundings); ``idx[r, i, j]``
    is the number of ends at or before ``t[i]`` (``np.searchsorted(ends[r, :, j], t, side="right")``), at most
    ``K - 1``, by one merge of the increasing epochs with the ends, which are nondecreasing for lengths >= 0.

    Parameters
    ----------
    t : (M,) increasing epochs [s]; lengths : (R, K, n) segment lengths >= 0 [s].
    idx : (R, M, n) int64 output; ends : (R, K, n) float64 output [s].
    """
    R, K, n = lengths.shape
    M = t.shape[0]
    t0 = t[0]
    for r in range(R):
        for j in range(n):
            acc = lengths[r, 0, j]
            ends[r, 0, j] = t0 + acc
            for k in range(1, K):
                acc = acc + lengths[r, k, j]
                ends[r, k, j] = t0 + acc
            k = 0
            for i in range(M):
                while k < K and ends[r, k, j] <= t[i]:
                    k += 1
                idx[r, i, j] = k if k < K else K - 1


@nb.njit(cache=True, nogil=True)
def gauss_markov_rows(z, sigma, a0, c, out):
    """First-order Gauss-Markov processes on uniform steps, one per column of each row, into ``out``.

    Column ``(r, j)``: ``x_0 = sigma z_0``, then ``x_m = a0 x_(m-1) + c_(m-1) z_m`` as ``scipy.signal.lfilter([1],
    [1, -a0], c z[1:], zi=[a0 x_0])`` computes it: its direct form II transposed recursion with the numerator
    padded to ``[1, 0]``, its operations in its order (``y = zi + 1.0 e``, ``zi = e 0.0 - y (-a0)``), so the same
    bits as :func:`envs.sim.receiver._gauss_markov`'s uniform-step path.

    Parameters
    ----------
    z : (R, M, L) standard normal draws, time along axis 1; sigma : stationary standard deviation;
    a0 : ``exp(-dt / tau)``; c : (M - 1,) the innovation scales ``sigma sqrt(1 - exp(-2 dt / tau))``;
    out : (R, M, L) float64 output.
    """
    R, M, L = z.shape
    na = -a0
    zi = np.empty(L)
    for r in range(R):                  # the columns side by side in the inner loop: independent recursions
        for j in range(L):
            x0 = sigma * z[r, 0, j]
            out[r, 0, j] = x0
            zi[j] = a0 * x0
        for m in range(1, M):
            cm = c[m - 1]
            for j in range(L):
                e = cm * z[r, m, j]
                y = zi[j] + 1.0 * e
                zi[j] = e * 0.0 - y * na
                out[r, m, j] = y


@nb.njit(cache=True, nogil=True)
def receiver_tail_rows(r0, r1, m_t, f_i, tropo_z, iono_ch, s_el, pr_bias, prr_bias, code_mult, doppler_mult, code_z,
                       rate_z, mask, pr_sigma_m, prr_sigma_mps, tropo_sigma_m, iono_sigma_m, nominal, code_rep,
                       doppler_rep, rep, pr_err, prr_err, pr_sigma, prr_sigma, pr_var_true, prr_var_true):
    """Errors, sigmas and true variances of the channels of rows ``r0 .. r1-1`` (module docstring of
    :mod:`envs.sim.gnss`), per channel::

        sig_code = sigma_pr / sin(el'),  sig_rate = sigma_prr / sin(el')          (el' = max(el, 5 deg))
        w_pr = code_mult sig_code,       w_prr = doppler_mult sig_rate            (true white sigmas)
        pr_err  = m_t T + F_i I + b_nlos + w_pr z_code                           (T, I: zenith tropo / iono)
        prr_err = b_rate + w_prr z_rate
        pr_sigma  = sqrt(sig_code^2 + (m_t s_T)^2 + (F_i s_I)^2) [x code_rep]     (``nominal``; else the caller's
                                                                                  values in pr_sigma, x code_rep)
        prr_sigma = sig_rate [x doppler_rep]
        pr_var_true  = w_pr^2 + (m_t s_T)^2 + (F_i s_I)^2 + b_nlos^2             (1 on an empty channel)
        prr_var_true = w_prr^2 + b_rate^2                                        (1 on an empty channel)

    Parameters
    ----------
    r0, r1 : the rows written (the outputs' other rows are untouched).
    m_t, f_i : (B, M, C) tropospheric mapping and ionospheric obliquity; tropo_z : (B, M) zenith troposphere
        residual [m]; iono_ch : (B, M, C) zenith ionosphere residual of each channel's satellite [m].
    s_el : (B, M, C) sine of the elevation clipped at the sigma model's floor.
    pr_bias, prr_bias : (B, M, C) NLOS bias [m] and rate error [m/s]; code_mult, doppler_mult : (B, M, C) true
        noise multipliers; code_z, rate_z : (B, M, C) standard normal variates; mask : (B, M, C) bool.
    pr_sigma_m, prr_sigma_mps, tropo_sigma_m, iono_sigma_m : the receiver's zenith sigmas [m, m/s, m, m].
    nominal : bool, pr_sigma from the nominal model (else ``pr_sigma`` holds the variance model's on entry).
    code_rep, doppler_rep : (B, M) reported-sigma mismatch factors, applied when ``rep``.
    pr_err, prr_err, pr_sigma, prr_sigma, pr_var_true, prr_var_true : (B, M, C) float64 outputs.
    """
    M, C = mask.shape[1], mask.shape[2]
    for b in range(r0, r1):
        for k in range(M):
            tz = tropo_z[b, k]
            for c in range(C):
                s = s_el[b, k, c]
                sig_code = pr_sigma_m / s
                sig_rate = prr_sigma_mps / s
                w_pr = code_mult[b, k, c] * sig_code
                w_prr = doppler_mult[b, k, c] * sig_rate
                mt, fi = m_t[b, k, c], f_i[b, k, c]
                pb, rb = pr_bias[b, k, c], prr_bias[b, k, c]
                pr_err[b, k, c] = ((mt * tz + fi * iono_ch[b, k, c]) + pb) + w_pr * code_z[b, k, c]
                prr_err[b, k, c] = rb + w_prr * rate_z[b, k, c]
                ta = mt * tropo_sigma_m
                ia = fi * iono_sigma_m
                if nominal:
                    pr_sigma[b, k, c] = math.sqrt((sig_code * sig_code + ta * ta) + ia * ia)
                if mask[b, k, c]:
                    pr_var_true[b, k, c] = (w_pr * w_pr + (ta * ta + ia * ia)) + pb * pb
                    prr_var_true[b, k, c] = w_prr * w_prr + rb * rb
                else:
                    pr_var_true[b, k, c] = 1.0
                    prr_var_true[b, k, c] = 1.0
                if rep:
                    pr_sigma[b, k, c] = pr_sigma[b, k, c] * code_rep[b, k]
                    sig_rate = sig_rate * doppler_rep[b, k]
                prr_sigma[b, k, c] = sig_rate


@nb.njit(cache=True, nogil=True)
def measurement_rows(r0, r1, mask, rho, bias, pr_err, rho_dot, drift, prr_err, pr, prr, pr_sigma, prr_sigma, el, az,
                     cn0):
    """Rows ``r0 .. r1-1`` of the pseudoranges and rates (B, M, C) of :func:`envs.sim.gnss.simulate_gnss`, and the
    masked channels set to +0 in them and in the error, sigma, elevation, azimuth and C/N0 arrays (in place):
    ``pr = (rho + bias) + pr_err`` and ``prr = (rho_dot + drift) + prr_err`` on a tracked channel (the order of
    numpy's ``np.add(rho, bias[..., None]) + pr_err``; ``bias``, ``drift`` (B, M) the receiver clock [m, m/s]),
    0 on the others. The same bits as those numpy lines followed by ``a[~mask] = 0``."""
    for i in range(r0, r1):
        for j in range(mask.shape[1]):
            b, d = bias[i, j], drift[i, j]
            for c in range(mask.shape[2]):
                if mask[i, j, c]:
                    pr[i, j, c] = (rho[i, j, c] + b) + pr_err[i, j, c]
                    prr[i, j, c] = (rho_dot[i, j, c] + d) + prr_err[i, j, c]
                else:
                    pr[i, j, c] = 0.0
                    prr[i, j, c] = 0.0
                    pr_err[i, j, c] = 0.0
                    prr_err[i, j, c] = 0.0
                    pr_sigma[i, j, c] = 0.0
                    prr_sigma[i, j, c] = 0.0
                    el[i, j, c] = 0.0
                    az[i, j, c] = 0.0
                    cn0[i, j, c] = 0.0


@nb.njit(cache=True, nogil=True)
def channel_noise_rows(r0, r1, flat_sel, mask, cn0, scale, nlos_sat, bias_sat, rate_sat, k_nlos, deficit_db,
                       deficit_ch, zone, nlos2_sat, bias2_sat, rate2_sat, att_sat, att_pow, reacq_sat, reacq_bit,
                       epoch_mult, code_mult, doppler_mult, bits, out_nlos, out_bias, out_rate, out_code,
                       out_doppler):
    """Rows ``r0 .. r1-1`` of the channels' NLOS state and true noise multipliers
    (:func:`envs.sim.gnss_stages.channel_noise`): per channel, from its satellite's entries (``flat_sel`` into the
    flat (B M S) arrays)::

        nlos = nlos_sat & mask;  cn0 -= deficit on NLOS;  m = scale_k * (k_nlos on NLOS, else 1)
                           (deficit: deficit_db, or the channel's own in deficit_ch)
        zones (``zone``):  nlos2 = nlos2_sat & mask; bias, rate <- the zone's on nlos2;
                           m = (m / k_nlos where nlos2 and nlos, else m) * 10^(att / 20);  nlos |= nlos2;
                           cn0 -= att  (and += deficit_db - deficit on nlos2 with a per-channel deficit)
        m_prr = m;  re-acquisition: both times rq (and the epoch's bit where a tracked channel has rq > 1);
        bursts / regimes (``epoch_mult``): m times code_mult, m_prr times doppler_mult (per epoch)
        outputs: nlos, its bias and rate (0 off NLOS), m, m_prr

    the operations of the numpy lines it replaced, in their order (the same bits; one pass instead of some
    fifteen (rows, M, C) temporaries).

    Parameters
    ----------
    flat_sel, mask, cn0 : (B, M, C) (``cn0`` updated in place); scale : (M,) the noise-scale intervals' factor;
    nlos_sat : (B M S,) bool, bias_sat, rate_sat : (B M S,) the canyon / burst NLOS; k_nlos : float;
    deficit_db : the constant NLOS C/N0 deficit [dB]; deficit_ch : (B, M, C) the channels' own deficits where it
    has rows (:class:`envs.sim.events.Cn0Scatter`), else empty; zone : bool; nlos2_sat (bool), bias2_sat, rate2_sat,
    att_sat : (B M S,) the zones' NLOS, bias, rate and C/N0 loss [dB]; att_pow : (B, M, C) ``10^(att / 20)`` of
    the channels (read if ``zone``); reacq_sat : (B M S,) re-acquisition multipliers, or empty; reacq_bit : its
    event bit; epoch_mult : bool; code_mult, doppler_mult : (B, M); bits : (B, M) uint16 event bits (in place);
    out_* : (B, M, C) outputs.
    """
    M, C = mask.shape[1], mask.shape[2]
    per_ch = deficit_ch.shape[0] > 0
    reacq = reacq_sat.shape[0] > 0
    for b in range(r0, r1):
        for j in range(M):
            rose = False
            for c in range(C):
                f = flat_sel[b, j, c]
                tracked = mask[b, j, c]
                nl = nlos_sat[f] and tracked
                nb_ = bias_sat[f]
                nr = rate_sat[f]
                d = deficit_ch[b, j, c] if per_ch else deficit_db
                cn = cn0[b, j, c] - (d if nl else 0.0)
                m = scale[j] * (k_nlos if nl else 1.0)
                if zone:
                    nl2 = nlos2_sat[f] and tracked
                    if nl2:
                        nb_ = bias2_sat[f]
                        nr = rate2_sat[f]
                    m = (m / k_nlos if (nl2 and nl) else m) * att_pow[b, j, c]
                    nl = nl or nl2
                    cn = cn - att_sat[f]
                    if per_ch:
                        cn = cn + ((deficit_db - d) if nl2 else 0.0)
                mp = m
                if reacq:
                    rq = reacq_sat[f]
                    m = m * rq
                    mp = mp * rq
                    rose = rose or (tracked and rq > 1.0)
                if epoch_mult:
                    m = m * code_mult[b, j]
                    mp = mp * doppler_mult[b, j]
                cn0[b, j, c] = cn
                out_nlos[b, j, c] = nl
                out_bias[b, j, c] = nb_ if nl else 0.0
                out_rate[b, j, c] = nr if nl else 0.0
                out_code[b, j, c] = m
                out_doppler[b, j, c] = mp
            if rose:
                bits[b, j] |= reacq_bit
