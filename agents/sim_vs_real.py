"""The simulated urban channels against smartLoc's: per elevation band, two-sample Kolmogorov-Smirnov distances of
the per-channel features (``scripts/sim_vs_real.sh`` writes ``docs/sim-vs-real.md``; issue 36, the measurement
before any scenario change).

A per-satellite policy learns from what a channel looks like (C/N0, elevation, residuals, how long a bad state
lasts). It transfers to a recording only where the simulated distributions of those features resemble the
recorded ones. This module measures, for every valid channel-epoch of a world:

* elevation [deg], C/N0 [dB-Hz];
* the truth residual ``e`` [m]: the pseudorange minus the range from the truth and a robust per-epoch, per-system
  receiver clock (:func:`envs.datasets.truth_check.truth_errors`: the lower-tail clock). The *same* estimator
  runs on both sides: on a recording it is all there is; on a simulated world (``pr_error_m`` + the true clock)
  it is compared with the simulator's true error in the note, which shows the estimator's own error;
* the label: simulated, the simulator's NLOS / multipath flag (``GnssData.nlos``); recorded, NLOS-like when
  ``|e| > LABEL_THRESHOLD_M`` (3 m, the real-data oracle's exclusion threshold
  :data:`~envs.datasets.truth_check.ORACLE_THRESHOLD_M`: several times a line-of-sight code error; the
  recording has no NLOS label). The share ``|e| > 3 m`` is also reported for both sides by the same rule;

per epoch the satellites in view (all, and per band), and per satellite the NLOS dwell times: the durations of
uninterrupted runs of epochs in which the satellite is tracked and labelled NLOS (a run ends where the satellite
is lost; runs cut by the end of the recording count as they are). Bands: :data:`BANDS_DEG` by elevation (a
dwell time by its run's mean elevation).

The features (:data:`FEATURES`): C/N0 of LOS and of NLOS channels, the C/N0 residual about each data set's own
least-squares line against ``sin(el)`` (fitted to all its channels, and to its LOS channels for the LOS ones),
``|e|`` of LOS and NLOS channels, the NLOS share, the share ``|e| > 3 m``, dwell times, satellites per epoch.
The distance is the two-sample KS statistic ``D = sup_x |F_sim(x) - F_real(x)|`` (0: the same empirical law;
1: disjoint samples; for a 0/1 feature it is the difference of the shares). The samples are correlated in time
(5 Hz recording, 1 Hz simulation), so no p-value is given: D is the effect size.

Usage: ``python -m agents.sim_vs_real [--seeds 16] [--seed 0] [--out docs/sim-vs-real.md]``
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from envs.outputs import write_atomic

SIM_SCENARIOS = ("urban", "urban-transition", "urban-smartloc")
"""The simulated scenarios compared with the recording."""
RECORDING = "smartloc-potsdamer-platz"
"""The recorded data set (dataset spec name)."""
BANDS_DEG = ((0.0, 15.0), (15.0, 30.0), (30.0, 45.0), (45.0, 90.0))
"""Elevation bands [deg], lower edge included, upper excluded (90 included in the last)."""
LABEL_THRESHOLD_M = 3.0
"""``|e|`` above which a recorded channel is labelled NLOS-like [m]."""
DWELL_GRID_S = 1.0
"""Time grid of the dwell times [s]: a recording's epochs are decimated to it (every 5th of smartLoc's 0.2 s), so
that both sides count runs at one resolution (the simulation's GNSS epoch)."""
CALIBRATION_LAGS_S = (1.0, 5.0, 30.0)
"""Lags of the LOS C/N0 scatter's autocorrelation in :func:`calibration` [s]."""


@dataclass(frozen=True)
class ChannelSample:
    """The channel-epochs of one world (every batch row pooled).

    Attributes
    ----------
    name : the world's scenario name.
    elevation_deg, cn0_dbhz, residual_m : (N,) elevation [deg], C/N0 [dB-Hz], truth residual ``e`` [m] of each
        valid channel-epoch.
    nlos : (N,) bool label (module docstring).
    true_error_m : (N,) the simulator's true error ``pr_error_m`` [m], or None for a recording.
    sats_per_epoch : (E, len(BANDS_DEG) + 1) int, satellites in view per epoch in each band, last column all.
    dwell_s, dwell_elevation_deg : (R,) duration [s] and mean elevation [deg] of each NLOS run, on the
        :data:`DWELL_GRID_S` grid.
    epoch_s : median epoch interval [s].
    systems : the GNSS system letters seen (:data:`nav_filters.measurements.SYSTEMS`).
    """

    name: str
    elevation_deg: np.ndarray
    cn0_dbhz: np.ndarray
    residual_m: np.ndarray
    nlos: np.ndarray
    true_error_m: np.ndarray | None
    sats_per_epoch: np.ndarray
    dwell_s: np.ndarray
    dwell_elevation_deg: np.ndarray
    epoch_s: float
    systems: tuple = ()


def ks_distance(a, b) -> float:
    """Two-sample Kolmogorov-Smirnov statistic ``sup_x |F_a(x) - F_b(x)|`` of the empirical CDFs.

    Parameters
    ----------
    a, b : (Na,), (Nb,) samples (any unit, the same for both); NaNs are dropped.

    Returns
    -------
    float in [0, 1]; NaN when either sample is empty.
    """
    a = np.sort(np.asarray(a, np.float64).ravel())
    b = np.sort(np.asarray(b, np.float64).ravel())
    a, b = a[~np.isnan(a)], b[~np.isnan(b)]
    if a.size == 0 or b.size == 0:
        return math.nan
    x = np.concatenate([a, b])
    fa = np.searchsorted(a, x, side="right") / a.size
    fb = np.searchsorted(b, x, side="right") / b.size
    return float(np.max(np.abs(fa - fb)))


def band_index(elevation_deg) -> np.ndarray:
    """Index into :data:`BANDS_DEG` of each elevation (any shape, [deg]); -1 below 0 deg or above 90 deg."""
    el = np.asarray(elevation_deg, np.float64)
    out = np.full(el.shape, -1, np.int64)
    for i, (lo, hi) in enumerate(BANDS_DEG):
        top = el <= hi if i == len(BANDS_DEG) - 1 else el < hi
        out[(el >= lo) & top] = i
    return out


def nlos_runs(present, nlos) -> tuple[np.ndarray, np.ndarray]:
    """Runs of consecutive epochs in which one satellite is tracked and labelled NLOS.

    Parameters
    ----------
    present : (M,) bool, the satellite is tracked at the epoch; nlos : (M,) bool, labelled NLOS there.

    Returns
    -------
    (starts, lengths) : (R,) int epoch index of each run's first epoch and its length [epochs].
    """
    on = np.asarray(present, bool) & np.asarray(nlos, bool)
    edges = np.diff(np.concatenate([[0], on.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return starts, stops - starts


def _row_dwells(prn, mask, nlos, elevation_deg, epoch_s):
    """``(durations [s], mean elevations [deg])`` of the NLOS runs of every satellite of one row ((M, C) inputs)."""
    dur, elev = [], []
    for k in np.unique(prn[mask]):
        sel = mask & (prn == k)
        present = sel.any(1)
        lab = (sel & nlos).any(1)
        el = np.where(sel, elevation_deg, 0.0).sum(1) / np.maximum(sel.sum(1), 1)
        for s, n in zip(*nlos_runs(present, lab)):
            dur.append(n * epoch_s)
            elev.append(float(el[s:s + n].mean()))
    return dur, elev


def channel_sample(world, name: str | None = None) -> ChannelSample:
    """The :class:`ChannelSample` of a world: a simulated one (labels: its NLOS flag) or a replayed recording
    (labels: ``|e| > LABEL_THRESHOLD_M``; only its first row, the recording)."""
    from envs.datasets.truth_check import _rows, truth_errors
    from nav_filters.measurements import MAX_PRN, SYSTEMS
    g = world.gnss
    simulated = g.pr_var_true is not None
    cols = {k: [] for k in ("el", "cn0", "res", "nlos", "true")}
    counts, dwell, dwell_el, systems = [], [], [], set()
    epoch_s = float(np.median(np.diff(np.asarray(g.t, np.float64)))) if len(g.t) > 1 else 1.0
    for b in _rows(world):
        e, ok = truth_errors(world, b)
        el = np.degrees(np.asarray(g.elevation[b], np.float64))
        lab = np.asarray(g.nlos[b], bool) if simulated else np.abs(np.nan_to_num(e)) > LABEL_THRESHOLD_M
        lab = lab & ok
        cols["el"].append(el[ok])
        cols["cn0"].append(np.asarray(g.cn0_dbhz[b], np.float64)[ok])
        cols["res"].append(e[ok])
        cols["nlos"].append(lab[ok])
        cols["true"].append(np.asarray(g.pr_error_m[b], np.float64)[ok])
        band = np.where(ok, band_index(el), -1)
        counts.append(np.stack([(band == i).sum(1) for i in range(len(BANDS_DEG))] + [ok.sum(1)], 1))
        step = max(1, int(round(DWELL_GRID_S / epoch_s)))
        d, de = _row_dwells(np.asarray(g.prn[b])[::step], ok[::step], lab[::step], el[::step], epoch_s * step)
        dwell += d
        dwell_el += de
        systems |= {SYSTEMS[int(k)] for k in np.unique((np.asarray(g.prn[b])[ok] - 1) // MAX_PRN)}
    cat = {k: np.concatenate(v) for k, v in cols.items()}
    return ChannelSample(name=name or world.scenario.name, elevation_deg=cat["el"], cn0_dbhz=cat["cn0"],
                         residual_m=cat["res"], nlos=cat["nlos"], true_error_m=cat["true"] if simulated else None,
                         sats_per_epoch=np.concatenate(counts), dwell_s=np.asarray(dwell, np.float64),
                         dwell_elevation_deg=np.asarray(dwell_el, np.float64), epoch_s=epoch_s,
                         systems=tuple(x for x in SYSTEMS if x in systems))


def cn0_fit(elevation_deg, cn0_dbhz) -> tuple[float, float]:
    """``(a, b)`` of the least-squares line ``cn0 = a + b sin(el)`` [dB-Hz] ((N,) inputs, el in deg); NaNs with
    fewer than 2 samples."""
    s = np.sin(np.radians(np.asarray(elevation_deg, np.float64)))
    if s.size < 2:
        return math.nan, math.nan
    (a, b), *_ = np.linalg.lstsq(np.c_[np.ones(s.size), s], np.asarray(cn0_dbhz, np.float64), rcond=None)
    return float(a), float(b)


def _cn0_residual(s: ChannelSample, which) -> np.ndarray:
    a, b = cn0_fit(s.elevation_deg[which], s.cn0_dbhz[which])
    return s.cn0_dbhz - (a + b * np.sin(np.radians(s.elevation_deg)))


FEATURES = (
    # key, label, unit
    ("cn0_los", "C/N0, LOS", "dB-Hz"),
    ("cn0_nlos", "C/N0, NLOS", "dB-Hz"),
    ("cn0_res_all", "C/N0 about own fit, all channels", "dB"),
    ("cn0_res_los", "C/N0 about own LOS fit, LOS", "dB"),
    ("err_los", "abs residual, LOS", "m"),
    ("err_nlos", "abs residual, NLOS", "m"),
    ("nlos_share", "NLOS share (label)", "0/1"),
    ("over_3m", "share abs residual > 3 m", "0/1"),
    ("dwell", "NLOS dwell time", "s"),
    ("sats", "satellites per epoch", "count"),
)
"""The compared features: (key, label, unit)."""


def feature_values(s: ChannelSample, key: str, band: int | None) -> np.ndarray:
    """The values of feature ``key`` (:data:`FEATURES`) of sample ``s`` in elevation band ``band`` (an index into
    :data:`BANDS_DEG`, or None for all elevations), (n,) in the feature's unit."""
    if key == "sats":
        return s.sats_per_epoch[:, -1 if band is None else band].astype(np.float64)
    if key == "dwell":
        sel = np.ones(s.dwell_s.size, bool) if band is None else band_index(s.dwell_elevation_deg) == band
        return s.dwell_s[sel]
    sel = np.ones(s.nlos.size, bool) if band is None else band_index(s.elevation_deg) == band
    los, nl = sel & ~s.nlos, sel & s.nlos
    if key == "cn0_los":
        return s.cn0_dbhz[los]
    if key == "cn0_nlos":
        return s.cn0_dbhz[nl]
    if key == "cn0_res_all":
        return _cn0_residual(s, np.ones(s.nlos.size, bool))[sel]
    if key == "cn0_res_los":
        return _cn0_residual(s, ~s.nlos)[los]
    if key == "err_los":
        return np.abs(s.residual_m[los])
    if key == "err_nlos":
        return np.abs(s.residual_m[nl])
    if key == "nlos_share":
        return s.nlos[sel].astype(np.float64)
    if key == "over_3m":
        return (np.abs(s.residual_m[sel]) > LABEL_THRESHOLD_M).astype(np.float64)
    raise ValueError(f"unknown feature {key!r}; known: {[f[0] for f in FEATURES]}")


def _stats(x) -> tuple:
    x = np.asarray(x, np.float64)
    if x.size == 0:
        return 0, math.nan, math.nan, math.nan
    return int(x.size), float(x.mean()), float(np.median(x)), float(x.std())


def compare(sim: ChannelSample, real: ChannelSample) -> list[dict]:
    """One row per feature and band (bands, then all elevations): ``{"feature", "band", "sim": (n, mean, median,
    std), "real": (...), "ks"}`` (KS distance, NaN where a side is empty)."""
    rows = []
    for key, label, unit in FEATURES:
        for band in list(range(len(BANDS_DEG))) + [None]:
            a, b = feature_values(sim, key, band), feature_values(real, key, band)
            rows.append({"feature": key, "label": label, "unit": unit, "band": band, "sim": _stats(a),
                         "real": _stats(b), "ks": ks_distance(a, b)})
    return rows


def band_label(band: int | None) -> str:
    """``'15-30'`` (deg) of a band index, ``'all'`` for None."""
    return "all" if band is None else "{:g}-{:g}".format(*BANDS_DEG[band])


def _f(x, nd=2) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{nd}f}"


def summary_lines(rows: list[dict]) -> list[str]:
    """One line per feature: the largest KS distance over the bands and where, and the all-elevation one."""
    out = []
    for key, label, unit in FEATURES:
        mine = [r for r in rows if r["feature"] == key]
        banded = [r for r in mine if r["band"] is not None and not math.isnan(r["ks"])]
        every = next(r for r in mine if r["band"] is None)
        if not banded:
            out.append(f"- {label}: no band holds both samples (all elevations: D = {_f(every['ks'])}).")
            continue
        worst = max(banded, key=lambda r: r["ks"])
        if unit == "0/1":
            sides = f"sim {_f(worst['sim'][1])}, smartLoc {_f(worst['real'][1])}"
        else:
            sides = (f"sim median {_f(worst['sim'][2])}, std {_f(worst['sim'][3])}; smartLoc median "
                     f"{_f(worst['real'][2])}, std {_f(worst['real'][3])}")
        out.append(f"- {label} [{unit}]: largest D = {worst['ks']:.2f} at {band_label(worst['band'])} deg "
                   f"({sides}); all elevations D = {_f(every['ks'])}.")
    return out


def table_lines(rows: list[dict]) -> list[str]:
    """The Markdown table of :func:`compare`'s rows."""
    lines = ["| feature | band [deg] | sim n | sim mean | sim median | sim std | real n | real mean | real median | "
             "real std | KS D |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        (sn, sm, smed, ss), (rn, rm, rmed, rs) = r["sim"], r["real"]
        lines.append(f"| {r['label']} [{r['unit']}] | {band_label(r['band'])} | {sn} | {_f(sm)} | {_f(smed)} | "
                     f"{_f(ss)} | {rn} | {_f(rm)} | {_f(rmed)} | {_f(rs)} | {_f(r['ks'])} |")
    return lines


def labelling_check(s: ChannelSample) -> str:
    """How well the robust-clock residual recovers a simulated world's true error (a line of the note)."""
    d = np.abs(s.residual_m - s.true_error_m)
    return (f"robust-clock residual minus the true error: median {np.median(d):.2f} m, 95th percentile "
            f"{np.percentile(d, 95):.2f} m; LOS channels (flag) with true |error| > 3 m: "
            f"{100 * np.mean(np.abs(s.true_error_m[~s.nlos]) > LABEL_THRESHOLD_M):.0f}%")


def fit_line(s: ChannelSample) -> str:
    """The C/N0 elevation fits of a sample (a line of the note)."""
    a, b = cn0_fit(s.elevation_deg[~s.nlos], s.cn0_dbhz[~s.nlos])
    aa, ba = cn0_fit(s.elevation_deg, s.cn0_dbhz)
    return (f"C/N0 = {a:.1f} + {b:.1f} sin(el) dB-Hz on LOS channels, {aa:.1f} + {ba:.1f} sin(el) on all; "
            f"NLOS share {100 * s.nlos.mean():.0f}% of {s.nlos.size} channel-epochs, "
            f"{s.sats_per_epoch.shape[0]} epochs, epoch interval {s.epoch_s:.1f} s, systems {'+'.join(s.systems)}")


def headline_lines(measured: dict) -> list[str]:
    """The C/N0 scatter per band: std of the C/N0 about each data set's own LOS fit (LOS channels) and about its
    fit to all channels, simulated scenarios beside smartLoc, with the KS distances of the LOS residuals."""
    real, sims = measured["real"], measured["sims"]
    names = list(sims)
    lines = ["| band [deg] | " + " | ".join(f"LOS std {n}" for n in names) + " | LOS std smartLoc | "
             + " | ".join(f"all std {n}" for n in names) + " | all std smartLoc | "
             + " | ".join(f"LOS KS D {n}" for n in names) + " |",
             "|---" * (3 * len(names) + 3) + "|"]
    for band in list(range(len(BANDS_DEG))) + [None]:
        los = [feature_values(x, "cn0_res_los", band) for x in [*sims.values(), real]]
        every = [feature_values(x, "cn0_res_all", band) for x in [*sims.values(), real]]
        std = [_f(_stats(v)[3], 1) for v in los + every]
        ks = [_f(ks_distance(v, los[-1])) for v in los[:-1]]
        lines.append(f"| {band_label(band)} | " + " | ".join(std + ks) + " |")
    return lines


def separability(s: ChannelSample, band: int | None) -> float:
    """KS distance between the LOS and the NLOS channels' C/N0 below the data set's own LOS line (``C/N0 - (a + b
    sin el)``, fitted to its LOS channels) in ``band``: 1 when a C/N0 threshold separates the labels perfectly."""
    sel = np.ones(s.nlos.size, bool) if band is None else band_index(s.elevation_deg) == band
    r = _cn0_residual(s, ~s.nlos)
    return ks_distance(r[sel & ~s.nlos], r[sel & s.nlos])


def separability_lines(measured: dict) -> list[str]:
    """Per band, :func:`separability` of each simulated scenario and of smartLoc (a Markdown table)."""
    samples = {**measured["sims"], "smartLoc": measured["real"]}
    lines = ["| band [deg] | " + " | ".join(samples) + " |", "|---" * (len(samples) + 1) + "|"]
    for band in list(range(len(BANDS_DEG))) + [None]:
        lines.append(f"| {band_label(band)} | " + " | ".join(_f(separability(x, band)) for x in samples.values())
                     + " |")
    return lines


def recording_lines(real: ChannelSample) -> list[str]:
    """What the recording's labels depend on: the NLOS-like share at other thresholds, and the grid its dwell
    times are counted on."""
    shares = ", ".join(f"{100 * np.mean(np.abs(real.residual_m) > t):.0f}% (> {t:g} m)" for t in (3.0, 5.0, 10.0))
    return [f"smartLoc labels: channel-epochs with |residual| above a threshold {shares}. Dwell times on both "
            f"sides are counted on a {DWELL_GRID_S:g} s grid (smartLoc's {real.epoch_s:.1f} s epochs decimated), "
            "the simulation's epoch: a threshold label flickers about 3 m at 5 Hz, and a run counted at the "
            "recording's own rate would be cut by every flicker."]


def calibration(world) -> dict:
    """The recording's channel statistics that calibrate ``urban-smartloc`` (:data:`envs.sim.events.SMARTLOC3_*`),
    with the 3 m label of :func:`channel_sample` on its first row.

    Returns
    -------
    dict: ``p_nlos`` (a, b) of the least-squares line ``a - b sin(el)`` of the 0/1 label; ``bias`` (median of
    ``|e| sin(el)`` [m], log-sigma) of the NLOS-like channels; ``positive`` their share of positive residuals;
    ``share`` the NLOS-like share; ``stay`` / ``enter`` the probabilities that a tracked satellite is NLOS-like
    :data:`DWELL_GRID_S` later given NLOS-like / LOS-like now; ``los_line`` (a, b) and ``los_std`` [dB] of the LOS
    C/N0 about its line; ``acf`` {lag [s]: autocorrelation of that scatter, same satellite, both LOS};
    ``nlos_mean`` / ``nlos_std`` [dB] of the NLOS-like C/N0 about the LOS line; ``los_rms_by_cn0`` the RMS ``|e|``
    [m] of the LOS channels in the lowest and highest quartile of their C/N0 scatter.
    """
    from envs.datasets.truth_check import truth_errors
    g = world.gnss
    e, ok = truth_errors(world, 0)
    el = np.asarray(g.elevation[0], np.float64)
    cn0 = np.asarray(g.cn0_dbhz[0], np.float64)
    prn = np.asarray(g.prn[0])
    dt = float(np.median(np.diff(np.asarray(g.t, np.float64))))
    ae = np.abs(np.nan_to_num(e))
    nl, los = ok & (ae > LABEL_THRESHOLD_M), ok & (ae <= LABEL_THRESHOLD_M)
    s = np.sin(np.maximum(el, 0.0))
    a, b = np.linalg.lstsq(np.stack([np.ones(ok.sum()), s[ok]], 1), nl[ok].astype(float), rcond=None)[0]
    x = ae[nl] * s[nl]
    la, lb = np.linalg.lstsq(np.stack([np.ones(los.sum()), s[los]], 1), cn0[los], rcond=None)[0]
    r = cn0 - (la + lb * s)
    out = {"p_nlos": (float(a), float(-b)), "bias": (float(np.median(x)), float(np.std(np.log(x)))),
           "positive": float(np.mean(np.nan_to_num(e)[nl] > 0)), "share": float(nl[ok].mean()),
           "los_line": (float(la), float(lb)), "los_std": float(r[los].std()),
           "nlos_mean": float(r[nl].mean()), "nlos_std": float(r[nl].std())}
    lo, hi = np.percentile(r[los], [25, 75])
    out["los_rms_by_cn0"] = tuple(float(np.sqrt(np.mean(ae[los & m] ** 2))) for m in (r <= lo, r >= hi))
    # per satellite: epoch -> (C/N0 scatter, label)
    sats: dict = {}
    for k, c in zip(*np.nonzero(ok)):
        sats.setdefault(int(prn[k, c]), {})[int(k)] = (r[k, c], bool(nl[k, c]))
    acf = {}
    for lag_s in CALIBRATION_LAGS_S:
        L = int(round(lag_s / dt))
        pairs = [(v, d[k + L][0]) for d in sats.values() for k, (v, n) in d.items()
                 if not n and k + L in d and not d[k + L][1]]
        acf[lag_s] = float(np.corrcoef(np.asarray(pairs).T)[0, 1])
    out["acf"] = acf
    L = int(round(DWELL_GRID_S / dt))
    moves = np.asarray([(n, d[k + L][1]) for d in sats.values() for k, (v, n) in d.items() if k + L in d], bool)
    out["stay"] = float(moves[moves[:, 0], 1].mean())
    out["enter"] = float(moves[~moves[:, 0], 1].mean())
    return out


def calibration_lines(cal: dict) -> list[str]:
    """:func:`calibration` as the note's lines."""
    acf = ", ".join(f"{v:.2f} at {k:g} s" for k, v in cal["acf"].items())
    return [f"- NLOS-like probability {cal['p_nlos'][0]:.2f} - {cal['p_nlos'][1]:.2f} sin(el) (share "
            f"{100 * cal['share']:.0f}%); |e| sin(el) of NLOS-like channels: median {cal['bias'][0]:.1f} m, "
            f"log-sigma {cal['bias'][1]:.2f}, {100 * cal['positive']:.0f}% positive.",
            f"- A satellite NLOS-like now is NLOS-like {DWELL_GRID_S:g} s later with probability "
            f"{cal['stay']:.2f}; LOS-like now, with {cal['enter']:.2f}.",
            f"- LOS C/N0 = {cal['los_line'][0]:.1f} + {cal['los_line'][1]:.1f} sin(el) dB-Hz, scatter std "
            f"{cal['los_std']:.1f} dB, autocorrelation {acf}; NLOS-like C/N0 {-cal['nlos_mean']:.1f} dB below that "
            f"line, std {cal['nlos_std']:.1f} dB.",
            f"- LOS |e| RMS in the lowest / highest quartile of the C/N0 scatter: {cal['los_rms_by_cn0'][0]:.2f} / "
            f"{cal['los_rms_by_cn0'][1]:.2f} m (the scatter barely changes the error: `urban-smartloc` lets it "
            "change the reported C/N0 only)."]


def measure(seeds: list, scenarios=SIM_SCENARIOS) -> dict:
    """``{"real": ChannelSample, "sims": {scenario: ChannelSample}}``: smartLoc (:data:`RECORDING`) and each
    simulated scenario at full length over ``seeds``."""
    from envs.worlds import make_world
    world = make_world(RECORDING, [0])
    return {"real": channel_sample(world, RECORDING), "calibration": calibration(world),
            "sims": {sc: channel_sample(make_world(sc, seeds), sc) for sc in scenarios}}


def format_note(measured: dict, seeds: list, elapsed: float, command: str) -> str:
    """The Markdown of docs/sim-vs-real.md."""
    real = measured["real"]
    lines = ["# Simulated urban channels against smartLoc", "",
             f"Generated by `{command}` ({time.strftime('%Y-%m-%d')}, {elapsed:.0f} s): {len(seeds)} episodes "
             f"(seeds {seeds[0]}..{seeds[-1]}) of each simulated scenario at full length, against the smartLoc "
             f"recording `{RECORDING}` (`agents/sim_vs_real.py`, module docstring). Per valid channel-epoch: "
             "C/N0, elevation, the truth residual with the robust per-epoch, per-system clock "
             "(`envs.datasets.truth_check.truth_errors`, the same estimator on both sides) and a label: the "
             f"simulator's NLOS flag; on smartLoc NLOS-like when |residual| > {LABEL_THRESHOLD_M:g} m. Bands by "
             "elevation (a dwell time by its run's mean elevation); `KS D`: two-sample Kolmogorov-Smirnov "
             "distance (0 the same empirical law, 1 disjoint; for a share, the difference of the shares). Samples "
             "are correlated in time, so no p-values. `mean` of a 0/1 feature is its share.", "",
             f"smartLoc: {fit_line(real)}.", ""] + recording_lines(real) + [
             "", "## Calibration of `urban-smartloc`", "",
             "What the recording's channels do, with the 3 m label (`agents.sim_vs_real.calibration`); "
             "`envs.sim.events.SMARTLOC3_*` hold these figures rounded (the test re-measures them), and "
             "`urban-smartloc` is built from them (`envs/sim/scenarios.py`).", ""] + calibration_lines(
                 measured["calibration"]) + [
             "", "## Headline: C/N0 scatter about each data set's own elevation fit [dB]", "",
             "Standard deviation of C/N0 minus the data set's least-squares line against sin(el): `LOS`: LOS "
             "channels about the line fitted to them; `all`: every channel about the line fitted to all; KS D of "
             "the LOS residuals against smartLoc's.", ""] + headline_lines(measured) + [
             "", "How well C/N0 alone separates a data set's NLOS channels from its LOS ones: KS distance between the "
             "two labels' C/N0 about the data set's own LOS line (1: one C/N0 threshold separates them "
             "perfectly).", ""] + separability_lines(measured) + [""]
    for sc, sim in measured["sims"].items():
        rows = compare(sim, real)
        lines += [f"## {sc} vs smartLoc", "", f"Simulated: {fit_line(sim)}; {labelling_check(sim)}.", "",
                  "Largest distances:", ""] + summary_lines(rows) + [""] + table_lines(rows) + [""]
    return "\n".join(lines) + "\n"


def main(argv=None):
    p = argparse.ArgumentParser(description="simulated urban channels against smartLoc: docs/sim-vs-real.md")
    p.add_argument("--seeds", type=int, default=16, help="episodes per simulated scenario (default 16)")
    p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--out", default="docs/sim-vs-real.md")
    a = p.parse_args(argv)
    if a.seeds < 1 or a.seed < 0:
        sys.exit(f"sim_vs_real: --seeds must be >= 1 and --seed >= 0, got {a.seeds} and {a.seed}")
    from envs.datasets.errors import shared_data_dir
    if not (shared_data_dir() / "smartloc" / "Berlin_Potsdamer_Platz_Input.txt").is_file():
        sys.exit(f"sim_vs_real: the smartLoc recording is not in {shared_data_dir() / 'smartloc'} "
                 f"(set NAVGYM_DATA_DIR)")
    seeds = list(range(a.seed, a.seed + a.seeds))
    t0 = time.time()
    measured = measure(seeds)
    command = "python -m agents.sim_vs_real" + ("" if a.seeds == 16 else f" --seeds {a.seeds}") + \
        ("" if a.seed == 0 else f" --seed {a.seed}") + ("" if a.out == "docs/sim-vs-real.md" else f" --out {a.out}")
    write_atomic(a.out, format_note(measured, seeds, time.time() - t0, command))
    print(f"wrote {a.out}")


if __name__ == "__main__":  # pragma: no cover
    main()
