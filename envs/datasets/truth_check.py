"""Recorded pseudoranges against the recording's truth: each one's error, the real-data R oracle, and the replay
consistency check.

A recording has no truth of its measurement errors, but it has a reference trajectory. Against it, each
pseudorange of epoch j and system s leaves ``d = pr - rho(r_truth)`` (the Sagnac-corrected range of
:func:`earth.ranging.range_and_rate`, as the navigator forms it) = the receiver clock of that system + the
pseudorange's own error. NLOS and multipath delays are positive and in a street canyon often the majority, so
the clock is *not* the median of ``d`` (:func:`envs.datasets.replay.reference_clock` takes the median of the
strong channels, which NLOS still biases by metres). :func:`system_clocks` estimates it from below:

1. per epoch and system, the median of the lowest third of ``d`` (at least one value): line-of-sight
   channels lie at the bottom, the delayed ones above;
2. smoothed over time per system by a cubic smoothing spline (``lam``, as the reference clock: a receiver's
   oscillator drifts smoothly; the smoothing also averages the low bias of step 1's order statistic);
3. refined once: per epoch, the mean of the values within ``window_m`` of the smoothed clock, smoothed again.

The pseudorange's error is then ``e = d - c_s(t)`` (:func:`truth_errors`). Two uses:

* :func:`recorded_oracle_world`: ``oracle-r`` on a recording: the filter is told each pseudorange's variance
  ``floor^2 + e^2`` (the analogue of the simulator's true variance, which includes the NLOS bias squared), or,
  with ``exclude``, keeps only the pseudoranges with ``|e| <= threshold_m``. It knows the truth: an oracle,
  never a method a receiver could run, and its floor is only as good as the clock estimate and the truth.
* :func:`replay_consistency`: how consistent the recording is with its truth as the navigator models it: the
  share of pseudoranges within 1.5 m / 3 m, the inter-system clock offset (the navigator has one clock state:
  a constant offset between systems acts as a measurement error), and the constant local east/north/up offset
  of the receiver from the truth that best explains the pseudoranges (a frame, height or lever-arm gap of the
  truth would show there; so do errors that persist per satellite over the recording, such as atmosphere
  residuals: a diagnostic, not a proof).
"""
from __future__ import annotations

import dataclasses

import numpy as np
from scipy.interpolate import make_smoothing_spline

from ..sim.world import World

__all__ = ["system_clocks", "truth_errors", "recorded_oracle_world", "replay_consistency", "ORACLE_FLOOR_M",
           "ORACLE_THRESHOLD_M"]

ORACLE_FLOOR_M = 1.0
"""sigma floor of the recorded R oracle [m]: a line-of-sight code error and the clock estimate's own error."""
ORACLE_THRESHOLD_M = 3.0
"""``|e|`` above which the excluding recorded oracle drops a pseudorange [m]."""


def _rows(world: World) -> list:
    """The batch rows that hold distinct recordings: ``[0]`` for a replay world (one recording broadcast over
    the rows: a zero stride), every row otherwise."""
    pr = np.asarray(world.gnss.pr_error_m)
    return [0] if pr.shape[0] == 1 or pr.strides[0] == 0 else list(range(pr.shape[0]))


def _channels(world: World, b: int = 0):
    """``(t (M,), d (M, C) = pr - rho(truth) [m], mask (M, C), system index (M, C))`` of row ``b``."""
    g = world.gnss
    if g.pr_error_m is None or g.clock_bias_m is None:
        raise ValueError(f"scenario {world.scenario.name!r}: no truth residuals (not a replay world)")
    mask = np.asarray(g.mask[b])
    d = np.where(mask, np.asarray(g.pr_error_m[b]) + np.asarray(g.clock_bias_m[b])[:, None], np.nan)
    system = np.where(mask, (np.asarray(g.prn[b]) - 1) // 64, -1)
    return np.asarray(g.t, np.float64), d, mask, system


def system_clocks(t, d, system, lam: float = 10.0, window_m: float = 3.0) -> dict:
    """The receiver clock of each system at every epoch (module docstring, steps 1-3).

    Parameters
    ----------
    t : (M,) epoch times [s]; d : (M, C) ``pr - rho(truth)`` [m] (NaN on unused channels);
    system : (M, C) int system index (-1 unused); lam : smoothing parameter of the splines (time in s);
    window_m : half-width of the refinement window [m].

    Returns
    -------
    {system index: (M,) clock [m]} for every system with at least 5 epochs (others are left out).
    """
    out = {}
    for s in np.unique(system[system >= 0]):
        sel = system == s
        low = np.full(t.size, np.nan)
        for j in np.flatnonzero(sel.any(1)):
            v = np.sort(d[j, sel[j]])
            low[j] = np.median(v[:max(1, int(np.ceil(v.size / 3)))])
        has = np.isfinite(low)
        if has.sum() < 5:
            continue
        c = make_smoothing_spline(t[has], low[has], lam=lam)(t)
        near = sel & (np.abs(d - c[:, None]) <= window_m)
        ref = np.where(near.any(1), np.nansum(np.where(near, d, 0.0), 1) / np.maximum(near.sum(1), 1), np.nan)
        has = np.isfinite(ref)
        out[int(s)] = make_smoothing_spline(t[has], ref[has], lam=lam)(t) if has.sum() >= 5 else c
    return out


def truth_errors(world: World, b: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(e, mask)``: (M, C) each pseudorange's error against the truth and its system's clock
    (:func:`system_clocks`) [m] in row ``b``, NaN where not used (or its system has too few epochs for a clock)."""
    t, d, mask, system = _channels(world, b)
    clocks = system_clocks(t, d, system)
    e = np.full(d.shape, np.nan)
    for s, c in clocks.items():
        sel = system == s
        e[sel] = (d - c[:, None])[sel]
    return e, mask & np.isfinite(e)


def recorded_oracle_world(world: World, exclude: bool = False, floor_m: float = ORACLE_FLOOR_M,
                          threshold_m: float = ORACLE_THRESHOLD_M) -> World:
    """The replay world with each pseudorange's truth error as its variance (``floor^2 + e^2``), or with
    ``exclude`` only the pseudoranges with ``|e| <= threshold_m`` (module docstring). An oracle."""
    g = world.gnss
    B = np.shape(g.mask)[0]
    rows = _rows(world)
    out = []
    for b in rows:
        e, ok = truth_errors(world, b)
        if exclude:
            out.append(ok & (np.abs(np.nan_to_num(e)) <= threshold_m))
        else:
            out.append(np.where(ok, np.sqrt(floor_m ** 2 + np.nan_to_num(e) ** 2), np.asarray(g.pr_sigma[b])))
    a = np.broadcast_to(out[0], (B,) + out[0].shape) if len(rows) == 1 else np.stack(out)
    return dataclasses.replace(world, gnss=dataclasses.replace(g, **{"mask" if exclude else "pr_sigma": a}))


def replay_consistency(world: World, k_m: float = 2.0, iterations: int = 60) -> dict:
    """The replay consistency check (module docstring), of the world's first row (a replay world's recording).

    A robust fit (Cauchy weights, scale ``k_m``) of the truth residuals ``d`` by a clock per epoch, one constant
    offset per system against the first (the inter-system bias) and, in a second fit, also a constant
    east/north/up position ``o`` of the receiver relative to the truth: ``d = c_j + b_s - u^T o`` (``u`` the
    local line of sight towards the satellite).

    Returns
    -------
    dict: ``within_1_5m``, ``within_3m`` (shares of the pseudoranges, clock and biases fitted, no offset),
    ``system_bias_m`` ({system index: bias against the first system}), ``offset_enu_m`` (the fitted receiver
    position relative to the truth, east, north, up [m]), ``within_1_5m_offset`` / ``within_3m_offset`` (with it), ``lower_clock_within_3m`` (the
    share within 3 m of :func:`system_clocks`, the oracle's clock).
    """
    t, d, mask, system = _channels(world)
    g = world.gnss
    el, az = np.asarray(g.elevation[0]), np.asarray(g.azimuth[0])
    u = np.stack([np.cos(el) * np.sin(az), np.cos(el) * np.cos(az), np.sin(el)], -1)   # local east, north, up
    systems = [int(s) for s in np.unique(system[mask])]
    e, ok = truth_errors(world)

    def fit(with_offset):
        off, bias, clk = np.zeros(3), np.zeros(len(systems)), np.nanmin(d, 1)
        for _ in range(iterations):
            b = np.zeros(d.shape)
            for i, s in enumerate(systems):
                b[system == s] = bias[i]
            geo = u @ off
            r = np.where(mask, d - clk[:, None] - b + geo, 0.0)
            w = np.where(mask, 1.0 / (1.0 + (r / k_m) ** 2), 0.0)
            clk = np.sum(w * np.nan_to_num(d - b + geo), 1) / np.maximum(w.sum(1), 1e-12)
            y = (d - clk[:, None])[mask]
            cols = [(system == s)[mask].astype(float) for s in systems[1:]]
            if with_offset:
                cols += [-u[..., 0][mask], -u[..., 1][mask], -u[..., 2][mask]]
            if cols:
                A, sw = np.stack(cols, 1), np.sqrt(w[mask])
                sol = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)[0]
                bias[1:] = sol[:len(systems) - 1]
                if with_offset:
                    off = sol[len(systems) - 1:]
        b = np.zeros(d.shape)
        for i, s in enumerate(systems):
            b[system == s] = bias[i]
        r = (d - clk[:, None] - b + u @ off)[mask]
        return bias, off, float(np.mean(np.abs(r) <= 1.5)), float(np.mean(np.abs(r) <= 3.0))

    bias, _, in15, in3 = fit(False)
    _, off, in15o, in3o = fit(True)
    return {"within_1_5m": in15, "within_3m": in3, "system_bias_m": {s: float(b) for s, b in zip(systems, bias)},
            "offset_enu_m": [float(x) for x in off], "within_1_5m_offset": in15o, "within_3m_offset": in3o,
            "lower_clock_within_3m": float(np.mean(np.abs(e[ok]) <= 3.0)) if ok.any() else float("nan")}
