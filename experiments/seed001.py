"""Seed paper 001: per-sample against one-step prediction of P (``+onestep``), time and accuracy
(:func:`run_seed001`)."""
from __future__ import annotations

import dataclasses

import numpy as np

from envs.worlds import make_world
from .claims import _ci_or_none, _ci_pct, _claims_table, _max_dev, _md_header, _md_row, _pct, _rmse, make_claim, \
    paired_change
from .navigation import Run, _chunks, _ok, _say, run_navigation
from .papers import (SEED001_METHODS, SEED001_OUTAGE_BOUND_PCT, SEED001_POSITION_BOUND_PCT, SEED001_SCENARIOS,
                     SEED001_TABLE1_OPERAND_SAVING_PCT, SEED001_TABLE3_DEGRADATION_PCT,
                     SEED001_TABLE4_OUTAGE_DEGRADATION_PCT, SEED001_TABLE6_TIME_S, TIMING_REPEATS)

def run_seed001(seeds, batch_size=50, progress=None, duration_s=None, per_sample_reference: bool = True) -> tuple[dict, str]:
    """Seed 001 comparison. ``ours[scenario][method]`` holds, for ``'per-sample'`` (one predict per IMU
    sample, the paper's standard algorithm; only when ``per_sample_reference``), ``'epoch'`` (the
    navigator's default: per-sample transitions composed exactly, one predict per epoch) and ``'onestep'``
    (``+onestep``, seed 001 eqs 19-20): ``rmse_h_m``, ``rmse_n_m``, ``rmse_e_m``, ``max_h_m``,
    ``rmse_h_outage_m`` (epochs without satellites; None if none), ``filter_time_s``; and
    ``degradation`` (onestep vs epoch, fractions with 95% CIs), ``time_saving`` (1 - t_onestep / t_ref)."""
    ours, claims = {}, []
    modes = (["per-sample"] if per_sample_reference else []) + ["epoch", "onestep"]
    for scen in SEED001_SCENARIOS:
        parts = _seed001_runs(scen, seeds, batch_size, progress, duration_s, modes)
        ours[scen] = {}
        for m in SEED001_METHODS:
            runs = {mode: Run.concat(parts[(m, mode)]) for mode in modes}
            o, deg, n_deg = _seed001_summary(runs)
            ours[scen][m] = o
            claims += _seed001_claims(scen, m, o, deg, n_deg, len(seeds))
    return _seed001_report(seeds, batch_size, ours, claims)


def _seed001_runs(scen, seeds, batch_size, progress, duration_s, modes) -> dict:
    """``{(method, mode): [Run per seed chunk]}`` of :func:`run_seed001` on ``scen`` (the cheap modes' filter time
    the best of :data:`TIMING_REPEATS` runs)."""
    parts = {(m, mode): [] for m in SEED001_METHODS for mode in modes}
    warm = make_world(scen, seeds[:1], duration_s=3.0)
    for m in SEED001_METHODS:  # first calls out of the timings
        for mode in modes:
            run_navigation(warm, m + "+onestep" if mode == "onestep" else m, per_sample_predict=mode == "per-sample")
    for chunk in _chunks(seeds, batch_size):
        world = make_world(scen, chunk, duration_s=duration_s)
        for m in SEED001_METHODS:
            for mode in modes:
                _say(progress, f"seed001: {scen} {m} {mode} on {len(chunk)} episodes")
                meth = m + "+onestep" if mode == "onestep" else m
                run = run_navigation(world, meth, per_sample_predict=mode == "per-sample")
                # cheap modes: the best of TIMING_REPEATS runs (same estimate each time) against load spikes
                for _ in range(0 if mode == "per-sample" else TIMING_REPEATS - 1):
                    t = run_navigation(world, meth).filter_time_s
                    run = dataclasses.replace(run, filter_time_s=min(run.filter_time_s, t))
                parts[(m, mode)].append(run)
    return parts


def _seed001_summary(runs) -> tuple[dict, dict, dict]:
    """One method's ``ours`` entry from its runs per mode, with the degradations of onestep against epoch
    (``{name: (change, ci)}``) and the episodes behind each."""
    o = {}
    for mode, r in runs.items():
        ok = ~r.diverged
        h = np.hypot(r.pos_ned[ok][..., 0], r.pos_ned[ok][..., 1])
        out = r.outage[ok]
        o[mode] = {"rmse_h_m": _rmse(h), "rmse_n_m": _rmse(r.pos_ned[ok][..., 0]),
                   "rmse_e_m": _rmse(r.pos_ned[ok][..., 1]), "max_h_m": float(h.max()) if h.size else float("nan"),
                   "rmse_h_outage_m": _rmse(h[out]) if out.any() else None,
                   "filter_time_s": r.filter_time_s, "diverged": int(r.diverged.sum())}
    e, s = runs["epoch"], runs["onestep"]
    ok = _ok(e, s)
    he = np.hypot(e.pos_ned[ok][..., 0], e.pos_ned[ok][..., 1])
    hs = np.hypot(s.pos_ned[ok][..., 0], s.pos_ned[ok][..., 1])
    deg = {"rmse_h": paired_change(hs, he), "rmse_n": paired_change(s.pos_ned[ok][..., 0], e.pos_ned[ok][..., 0]),
           "rmse_e": paired_change(s.pos_ned[ok][..., 1], e.pos_ned[ok][..., 1])}
    deg["max_h"] = (float(hs.max() / he.max() - 1.0), None) if he.size else (float("nan"), None)
    out = e.outage[ok]
    if out.any():
        # RMS of the drift during outages, paired by episode (epochs of one episode's outages)
        w = out.astype(float)
        cnt = np.maximum(w.sum(1), 1)
        ms_s, ms_e = (hs ** 2 * w).sum(1) / cnt, (he ** 2 * w).sum(1) / cnt
        keep = w.sum(1) > 0
        deg["rmse_h_outage"] = paired_change(np.sqrt(ms_s[keep])[:, None], np.sqrt(ms_e[keep])[:, None])
    n_deg = {k: int(keep.sum()) if k == "rmse_h_outage" else int(ok.sum()) for k in deg}
    o["degradation"] = {k: {"change": v[0], "ci95": _ci_or_none(v[1], n_deg[k]), "episodes": n_deg[k]}
                        for k, v in deg.items()}
    if "per-sample" in runs:
        ps = runs["per-sample"]
        okp = _ok(ps, e)
        o["per_sample_vs_epoch_max_dev_m"] = _max_dev(ps.pos_ned[okp], e.pos_ned[okp])
    o["time_saving"] = {f"vs_{ref}": 1.0 - s.filter_time_s / runs[ref].filter_time_s
                        for ref in runs if ref != "onestep"}
    return o, deg, n_deg


def _seed001_claims(scen, m, o, deg, n_deg, n_seeds) -> list:
    """The claims of method ``m`` on ``scen``: time saving (Table 6), horizontal RMSE degradation (Table 3) and,
    with outages, the drift (Table 4)."""
    claims = []
    ref = "per-sample" if "vs_per-sample" in o["time_saving"] else "epoch"
    paper_save = float(np.mean([v[2] for v in SEED001_TABLE6_TIME_S.values()])) / 100
    ch = o["time_saving"][f"vs_{ref}"]
    v = "reproduced" if ch >= paper_save - 0.10 else "not reproduced"
    why = "" if v == "reproduced" else _why_time(o, m)
    claims.append(make_claim(f"time:{scen}:{m}", f"{m} on {scen}: total filter time saving vs {ref}",
                             "001 Table 6", f"-{100 * paper_save:.1f}% time", f"{-100 * ch:+.1f}% time", None,
                             v, why, episodes=n_seeds))
    if "epoch" != ref:
        che = o["time_saving"]["vs_epoch"]
        claims.append(make_claim(f"time-epoch:{scen}:{m}", f"{m} on {scen}: total filter time saving vs our "
                                 f"exact epoch composition (navigator default)", "001 Table 6",
                                 f"-{100 * paper_save:.1f}% time", f"{-100 * che:+.1f}% time", None,
                                 "reproduced" if che >= paper_save - 0.10 else "not reproduced",
                                 "" if che >= paper_save - 0.10 else _why_time(o, m), episodes=n_seeds))
    chd, cid = deg["rmse_h"]
    v = "reproduced" if cid[1] < SEED001_POSITION_BOUND_PCT / 100 else "not reproduced"
    claims.append(make_claim(f"acc:{scen}:{m}", f"{m} on {scen}: horizontal RMSE degradation < 2%",
                             "001 Table 3, sec 3.2", "< +2% (N, E RMS +0.00%)", chd, cid, v,
                             "" if v == "reproduced" else "the upper CI bound of the degradation exceeds 2%",
                             episodes=n_deg["rmse_h"]))
    if "rmse_h_outage" in deg:
        chd, cid = deg["rmse_h_outage"]
        v = "reproduced" if max(abs(cid[0]), abs(cid[1])) < SEED001_OUTAGE_BOUND_PCT / 100 else "not reproduced"
        claims.append(make_claim(f"drift:{scen}:{m}", f"{m} on {scen}: RMS drift during outages within 1%",
                                 "001 Table 4", f"{SEED001_TABLE4_OUTAGE_DEGRADATION_PCT['rms']:+.2f}%", chd,
                                 cid, v, "" if v == "reproduced" else "the CI of the drift change leaves +-1%",
                                 episodes=n_deg["rmse_h_outage"]))
    return claims


def _seed001_report(seeds, batch_size, ours, claims) -> tuple[dict, str]:
    """The results body and the Markdown report of :func:`run_seed001`."""
    paper = {"table6_time_s": {k: list(v) for k, v in SEED001_TABLE6_TIME_S.items()},
             "table1_operand_saving_pct": SEED001_TABLE1_OPERAND_SAVING_PCT,
             "table3_degradation_pct": {k: list(v) for k, v in SEED001_TABLE3_DEGRADATION_PCT.items()},
             "table4_outage_degradation_pct": SEED001_TABLE4_OUTAGE_DEGRADATION_PCT}
    setup = {"scenarios": list(SEED001_SCENARIOS), "methods": list(SEED001_METHODS), "dtype": "float64",
             "modes": {"per-sample": "form.predict at every IMU sample (seed 001's standard algorithm)",
                       "epoch": "navigator default: per-sample Phi_i, Q_i composed exactly in the compiled kernel, "
                                "one predict per epoch (same result as per-sample)",
                       "onestep": "'+onestep': Phi product and summed Q (seed 001 eqs 19-20), one predict per epoch"},
             "time": "wall time of the navigator calls only (mechanization + covariance + GNSS update), all rows "
                     f"batched; epoch / onestep: best of {TIMING_REPEATS} runs, per-sample: one run",
             "time_rule": "a time claim counts as reproduced when our saving is within 10 points of the paper's or above"}
    lines = ["## seed001: one-step prediction of P (seed paper 001)", "",
             f"Setup: {', '.join(f'`{s}`' for s in SEED001_SCENARIOS)}, methods {', '.join(SEED001_METHODS)}, "
             f"float64, {len(seeds)} paired episodes per scenario (one batched navigator per {batch_size}). "
             "Modes: **per-sample** = a form predict at every IMU sample (the paper's standard algorithm); "
             "**epoch** = our navigator's default (the per-sample transitions composed exactly in the compiled "
             "kernel, one predict per epoch: the same estimate); **onestep** = `+onestep` (seed 001 eqs 19-20). "
             "Filter time is the wall time of the navigator calls (mechanization, covariance, GNSS update; epoch and "
             f"onestep: best of {TIMING_REPEATS} runs, per-sample: one run).", "",
             "### Ours", "",
             *_md_header("scenario", "method", "mode", "RMSE h [m]", "RMSE N [m]", "RMSE E [m]", "max h [m]",
                         "RMSE h in outages [m]", "filter time [s]", "div")]
    for scen, per in ours.items():
        for m, o in per.items():
            for mode in ("per-sample", "epoch", "onestep"):
                if mode not in o:
                    continue
                x = o[mode]
                drift = "-" if x["rmse_h_outage_m"] is None else f"{x['rmse_h_outage_m']:.3f}"
                lines.append(_md_row(scen, m, mode, f"{x['rmse_h_m']:.4f}", f"{x['rmse_n_m']:.4f}", f"{x['rmse_e_m']:.4f}",
                                     f"{x['max_h_m']:.3f}", drift, f"{x['filter_time_s']:.2f}", x["diverged"]))
    lines += ["", *_md_header("scenario", "method", "time change vs per-sample", "time change vs epoch",
                              "degradation RMSE h (95% CI)", "degradation max h", "drift in outages (95% CI)",
                              "max pos. diff per-sample vs epoch [m]")]
    for scen, per in ours.items():
        for m, o in per.items():
            d = o["degradation"]
            dr = d.get("rmse_h_outage")
            lines.append(_md_row(scen, m, _pct(-o["time_saving"].get("vs_per-sample", float("nan"))),
                                 _pct(-o["time_saving"]["vs_epoch"]),
                                 f"{_pct(d['rmse_h']['change'], 3)} {_ci_pct(d['rmse_h']['ci95'], 3)}",
                                 _pct(d["max_h"]["change"], 3),
                                 "-" if dr is None else f"{_pct(dr['change'], 3)} {_ci_pct(dr['ci95'], 3)}",
                                 f"{o.get('per_sample_vs_epoch_max_dev_m', float('nan')):.1e}"))
    lines += ["", "### Paper (seed 001, field data, MTi-G and SPAN-FSAS, 21-state loosely coupled KF)", "",
              "Table 6, time consumption: " + "; ".join(f"{k}: standard {a:.2f} s, simplified {b:.2f} s (-{c:.1f}%)"
                                                          for k, (a, b, c) in SEED001_TABLE6_TIME_S.items()), "",
              "Table 1, arithmetic operands per 1 s cycle, multiplication method: "
              + ", ".join(f"{k} -{v:.1f}%" for k, v in SEED001_TABLE1_OPERAND_SAVING_PCT.items()), "",
              "Table 3, position error degradation with GNSS (RMS, max): "
              + ", ".join(f"{k} {a:+.2f}% / {b:+.2f}%" for k, (a, b) in SEED001_TABLE3_DEGRADATION_PCT.items()), "",
              "Table 4, position drift in 60 s outages: "
              + ", ".join(f"{k} {v:+.2f}%" for k, v in SEED001_TABLE4_OUTAGE_DEGRADATION_PCT.items()), "",
              "### Claims: paper vs ours", ""]
    lines += _claims_table(claims)
    return {"setup": setup, "ours": ours, "paper": paper, "claims": claims}, "\n".join(lines)


def _why_time(o, m) -> str:
    ts = o["time_saving"]
    parts = []
    if "vs_per-sample" in ts:
        parts.append(f"against a predict at every IMU sample the saving is {100 * ts['vs_per-sample']:.0f}%")
    parts.append(f"against our navigator's default it is {100 * ts['vs_epoch']:.0f}%: that default already "
                 "composes the per-sample transitions in a compiled kernel and calls the form's predict once "
                 "per epoch, so '+onestep' only removes the per-sample propagation of Q through Phi_i; the "
                 "mechanization, the Phi product and the GNSS update remain")
    return "; ".join(parts)
