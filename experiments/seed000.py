"""Seed paper 000: kf and the SVD, adaptive and information forms in float32 arithmetic (:func:`run_seed000`)."""
from __future__ import annotations

import math

import numpy as np

from envs.metrics import MIN_CI_EPISODES, no_ci_text
from envs.sim.scenarios import get_scenario
from envs.sim.world import generate_world
from envs.episodes import run_episodes
from .claims import _claims_table, _max_dev, _md_header, _rmse, _smaller, make_claim, paired_change, verdict
from .navigation import _dur, _ok, _run_variants
from .papers import (SEED000_EVENTS, SEED000_EXTRA_METHODS, SEED000_MAX_ERROR_M, SEED000_METHODS,
                     SEED000_TABLE2_RMSE_M, SEED000_URBAN_METHODS)

def _enu(ned):
    return np.stack([ned[..., 1], ned[..., 0], -ned[..., 2]], -1)


def run_seed000(seeds, batch_size=50, progress=None, duration_s=None) -> tuple[dict, str]:
    """Seed 000 comparison (module table). ``ours[method]`` holds ``rmse_enu_m`` (E, N, U),
    ``rmse_ecef_m`` (X, Y, Z), ``rmse_h_m``, ``rmse_3d_m``, ``max_3d_m``, ``max_h_m``,
    ``max_dev_from_kf_m`` (largest position difference to float32 kf over all epochs), ``diverged``,
    ``filter_time_per_epoch_s``; ``ours['kf (float64)']`` the same for kf in float64, and
    ``ours['<m> (extra)']`` for :data:`SEED000_EXTRA_METHODS` (float32)."""
    scen = get_scenario("seed000-sim", events=SEED000_EVENTS, **_dur(duration_s))
    variants = ([(m, m, "float32") for m in SEED000_METHODS] + [("kf (float64)", "kf", "float64")]
                + [(f"{m} (extra)", m, "float32") for m in SEED000_EXTRA_METHODS])
    warm = generate_world(get_scenario(scen, duration_s=2.0), seeds[:1])
    for _, m, dt in variants:  # first calls (imports, numba cache, BLAS start-up) out of the timings
        run_episodes(warm, m, dtype=dt)
    runs = _run_variants(scen, seeds, batch_size, variants, progress, "seed000")
    ours = _seed000_ours(runs, math.ceil(len(seeds) / batch_size))
    claims = _seed000_claims(runs, ours)
    claims += _seed000_urban(seeds, batch_size, progress, duration_s, ours)
    return _seed000_report(seeds, ours, claims)


def _seed000_ours(runs, n_chunks) -> dict:
    """``ours[label]`` of :func:`run_seed000` from the runs of each variant (``n_chunks`` batched navigators)."""
    kf = runs["kf"]
    ours = {}
    for label, r in runs.items():
        ok = ~r.diverged
        enu = _enu(r.pos_ned[ok])
        ecef = r.pos_ecef[ok]
        h = np.hypot(enu[..., 0], enu[..., 1])
        d3 = np.linalg.norm(enu, axis=-1)
        both = ok & ~kf.diverged
        ours[label] = {
            "rmse_enu_m": [_rmse(enu[..., i]) for i in range(3)],
            "rmse_ecef_m": [_rmse(ecef[..., i]) for i in range(3)],
            "rmse_h_m": _rmse(h), "rmse_3d_m": _rmse(d3),
            "max_3d_m": float(d3.max()) if d3.size else float("nan"),
            "max_h_m": float(h.max()) if h.size else float("nan"),
            "max_dev_from_kf_m": _max_dev(r.pos_ned[both], kf.pos_ned[both]),
            "diverged": int(r.diverged.sum()),
            # wall time per epoch of one batched navigator (all rows of a chunk together)
            "filter_time_per_epoch_s": r.filter_time_s / (r.t.size * n_chunks),
        }
    return ours


def _seed000_claims(runs, ours) -> list:
    """Claims (1)-(3) of seed 000 on ``seed000-sim``: the SVD forms below kf, the adaptive / SVD-IF forms per ECEF
    axis against their base (Table 2), the maximum error (sec 5.2.2)."""
    kf = runs["kf"]
    claims = []
    # (1) SVD forms better than KF in 32-bit (sec 5.1.2, Figure 3; qualitative, no figure in a table)
    for m in ("svd-kf", "svd-srkf"):
        ok = _ok(runs[m], kf)
        a = np.linalg.norm(runs[m].pos_ned[ok], axis=-1)
        b = np.linalg.norm(kf.pos_ned[ok], axis=-1)
        ch, ci = paired_change(a, b)
        v = verdict(-1.0, ch, ci, magnitude=False)
        why = _why_forms(ours, m, "kf") if v != "reproduced" else ""
        claims.append(make_claim(f"{m}<kf", f"{m} 3D RMSE below kf (float32)", "000 sec 5.1.2, Fig. 3",
                                 "lower (figure only)", ch, ci, v, why, episodes=ok.sum()))
    # (2) adaptive / SVD-IF per ECEF axis vs their base (Table 2)
    T = SEED000_TABLE2_RMSE_M
    for a_m, b_m in (("svd-asrkf", "svd-srkf"), ("svd-akf", "svd-kf"), ("svd-if", "if")):
        ok = _ok(runs[a_m], runs[b_m])
        for i, ax in enumerate("XYZ"):
            paper = T[a_m][i] / T[b_m][i] - 1.0
            ch, ci = paired_change(runs[a_m].pos_ecef[ok][..., i], runs[b_m].pos_ecef[ok][..., i])
            v = verdict(paper, ch, ci)
            why = ""
            if v == "direction only":
                why = _smaller(ch, paper)
            elif v != "reproduced":
                why = (_why_adaptive(ours, a_m, b_m) if a_m != "svd-if" else _why_forms(ours, a_m, b_m))
            claims.append(make_claim(f"{a_m}<{b_m}:{ax}", f"{a_m} vs {b_m}, RMSE {ax} (ECEF)", "000 Table 2",
                                     paper, ch, ci, v, why, episodes=ok.sum()))
    # (3) maximum error (sec 5.2.2)
    M = SEED000_MAX_ERROR_M
    for a_m, b_m in (("svd-akf", "svd-kf"), ("svd-asrkf", "svd-srkf")):
        paper = M[a_m] / M[b_m] - 1.0
        ch = ours[a_m]["max_3d_m"] / ours[b_m]["max_3d_m"] - 1.0
        v = verdict(paper, ch)
        why = {"reproduced": "", "direction only": _smaller(ch, paper)}.get(v) if v != "not reproduced" else (
            _why_adaptive(ours, a_m, b_m)
            + f"; max 3D error {ours[a_m]['max_3d_m']:.2f} m vs {ours[b_m]['max_3d_m']:.2f} m")
        claims.append(make_claim(f"max:{a_m}<{b_m}", f"{a_m} vs {b_m}, max error", "000 sec 5.2.2",
                                 paper, ch, None, v, why, episodes=_ok(runs[a_m], runs[b_m]).sum()))
    return claims


def _seed000_urban(seeds, batch_size, progress, duration_s, ours) -> list:
    """Claim (4): the maximum-error claim rerun on ``urban-transition``; adds its rows to ``ours``."""
    M = SEED000_MAX_ERROR_M
    claims = []
    # the same maximum-error claim in the setting of the paper's dynamic experiment: a city drive with
    # open sky, tree cover and buildings (sec 5.2.2), which is urban-transition; float32 as in the paper
    u_runs = _run_variants(get_scenario("urban-transition", **_dur(duration_s)), seeds, batch_size,
                           [(m, m, "float32") for m in SEED000_URBAN_METHODS], progress, "seed000 on urban-transition")
    for m, r in u_runs.items():
        d3 = np.linalg.norm(r.pos_ned[~r.diverged], axis=-1)
        ours[f"{m} (urban-transition)"] = {"rmse_3d_m": _rmse(d3), "max_3d_m": float(d3.max()) if d3.size else float("nan"),
                                           "diverged": int(r.diverged.sum())}
    for a_m, b_m in (("svd-akf", "svd-kf"), ("svd-asrkf", "svd-srkf")):
        paper_ch = M[a_m] / M[b_m] - 1.0
        oa, ob = ours[f"{a_m} (urban-transition)"], ours[f"{b_m} (urban-transition)"]
        ch = oa["max_3d_m"] / ob["max_3d_m"] - 1.0
        v = verdict(paper_ch, ch)
        why = "" if v == "reproduced" else (_smaller(ch, paper_ch) if v == "direction only" else
                                            f"max 3D error {oa['max_3d_m']:.2f} m vs {ob['max_3d_m']:.2f} m")
        claims.append(make_claim(f"max-urban:{a_m}<{b_m}", f"{a_m} vs {b_m}, max error on urban-transition",
                                 "000 sec 5.2.2 (its setting)", paper_ch, ch, None, v, why,
                                 episodes=_ok(u_runs[a_m], u_runs[b_m]).sum()))
    return claims


def _seed000_report(seeds, ours, claims) -> tuple[dict, str]:
    """The results body and the Markdown report of :func:`run_seed000`."""
    T, M = SEED000_TABLE2_RMSE_M, SEED000_MAX_ERROR_M
    paper = {"table2_rmse_xyz_m": {k: list(v) for k, v in T.items()}, "max_error_m": dict(M)}
    setup = {"scenario": "seed000-sim", "events": {"noise_scale": [list(x) for x in SEED000_EVENTS.noise_scale]},
             "dtype": "float32 (filter arithmetic); 'kf (float64)' is the reference row", "frames": "ENU and ECEF",
             "verdicts": "reproduced: CI on the paper's side of zero and at least half the paper's change; direction "
                         "only: CI on the paper's side, smaller change; max error: point estimate (no CI); none "
                         f"below {MIN_CI_EPISODES} episodes ({no_ci_text()})"}
    lines = [f"## seed000: SVD, adaptive and information forms in float32 (seed paper 000)", "",
             f"Setup: `seed000-sim` (60 s, 20 m/s, 90-deg turns at 15 s and 45 s, IMU 100 Hz, GNSS 2 Hz, Table 1 "
             f"biases and initial errors) with a fluctuating GNSS quality: true code/Doppler noise x5 during "
             f"{', '.join(f'[{a:g}, {b:g})' for a, b, _ in SEED000_EVENTS.noise_scale)} s (reported sigmas nominal). "
             f"Filter arithmetic float32 (navigation state float64). {len(seeds)} paired episodes. "
             f"Errors: ENU (east, north, up) at the true position, and ECEF X/Y/Z (the axes of the paper's Table 2).", "",
             "### Ours", "",
             *_md_header("method", "RMSE E [m]", "RMSE N [m]", "RMSE U [m]", "RMSE X [m]", "RMSE Y [m]", "RMSE Z [m]",
                         "RMSE 3D [m]", "max 3D [m]", "max h [m]", "max dev. from kf [m]", "ms/epoch", "div")]
    for label, o in ours.items():
        if "rmse_enu_m" not in o:
            continue
        e, x = o["rmse_enu_m"], o["rmse_ecef_m"]
        lines.append(f"| {label} | {e[0]:.3f} | {e[1]:.3f} | {e[2]:.3f} | {x[0]:.3f} | {x[1]:.3f} | {x[2]:.3f} | "
                     f"{o['rmse_3d_m']:.3f} | {o['max_3d_m']:.2f} | {o['max_h_m']:.2f} | {o['max_dev_from_kf_m']:.2e} | "
                     f"{1e3 * o['filter_time_per_epoch_s']:.3f} | {o['diverged']} |")
    lines += ["", "`kf (float64)`: the same kf in float64 arithmetic (rounding-free reference). "
              + " ".join(f"`{m} (extra)`: not in the paper's list (kf + Sage-Husa adaptation of Q and R, the law that "
                         f"can follow a measurement-noise fluctuation); no claim attached." for m in SEED000_EXTRA_METHODS)
              + " `max dev. from kf`: largest position difference to float32 kf over all epochs and episodes.",
              "", f"The same {len(seeds)} seeds on `urban-transition` (the setting of the paper's dynamic experiment: a "
              "city drive through open sky, tree cover and buildings; NLOS/multipath biases the receiver does not "
              "report), float32:", "", *_md_header("method", "RMSE 3D [m]", "max 3D [m]", "div")]
    lines += [f"| {m} | {ours[f'{m} (urban-transition)']['rmse_3d_m']:.3f} | "
              f"{ours[f'{m} (urban-transition)']['max_3d_m']:.2f} | {ours[f'{m} (urban-transition)']['diverged']} |"
              for m in SEED000_URBAN_METHODS]
    lines += ["", "### Paper (seed 000; a static and a dynamic physical experiment, not its simulation, whose "
              "results are given only as figures)", "",
              "Table 2, position RMSE in 32-bit, ECEF [m] (static experiment; no KF column):", "",
              "| method | X | Y | Z |", "|---|---|---|---|"]
    for k, v in T.items():
        lines.append(f"| {k} | {v[0]:.2f} | {v[1]:.2f} | {v[2]:.2f} |")
    lines += ["", "Sec 5.2.2, maximum error of the dynamic experiment [m]: "
              + ", ".join(f"{k} {v:.2f}" for k, v in M.items()), "",
              "### Claims: paper vs ours (relative changes; ours are paired over episodes)", ""]
    lines += _claims_table(claims)
    lines += ["", "Absolute values are not comparable (the paper's Table 2 is a real static recording with "
              "18 m Y-axis RMSE from uncompensated atmosphere; ours is the simulation); the claims compare "
              "relative changes."]
    return {"setup": setup, "ours": ours, "paper": paper, "claims": claims}, "\n".join(lines)


def _why_forms(ours, a, b) -> str:
    dev = max(ours[a]["max_dev_from_kf_m"], ours[b]["max_dev_from_kf_m"])
    d64 = ours["kf (float64)"]["max_dev_from_kf_m"]
    if dev < 0.01:
        return (f"float32 rounding does not matter at this conditioning: {a} and {b} positions stay within "
                f"{dev:.1e} m of float32 kf (kf float32 vs float64: {d64:.1e} m), so there is no rounding-error "
                f"growth for the SVD form to remove")
    return f"the forms differ (up to {dev:.2f} m from kf) but not in the paper's direction"


def _why_adaptive(ours, a, b) -> str:
    from nav_filters.registry import FORMS
    dev = ours[a]["max_dev_from_kf_m"]
    cfg = getattr(FORMS.get(a), "config", None)
    if cfg is not None and getattr(cfg, "adapt_r", False):
        what = (f"{a} adapts Q (seed 000 eqs 21-22) and R ({cfg.r_mode} mode), but in this 60 s open-sky run the "
                f"reported noise is right: there is nothing to adapt to, and the estimates' sampling noise costs")
    else:
        what = (f"{a} adapts Q only (R stays the reported one, seed 000 eqs 21-22) while the fluctuation here is "
                f"in the measurement noise")
    return f"{what}; its positions stay within {dev:.2f} m of kf, and the RMSE change is not significantly in the paper's direction"
