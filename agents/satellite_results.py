"""The per-satellite results note (docs/results-satellite.md), assembled from eval.py's per-scenario outputs.

``scripts/results_satellite.sh`` runs one ``eval.py`` per scenario, each with the scenario's best hand-designed
method as the reference and ``oracle-r`` among the methods, then calls this module, which reads only those
``results.json`` files, the training runs' ``config.json`` and the shipped ``pretrained/`` config: nothing in
the note is typed by hand. Sections: the summary (per scenario the reference, each learned method's paired
difference and its share of the gap to oracle-r, with 95% CIs), the goals of issue "per-satellite agent"
checked against those figures, the training budget, the shipped policy, then each scenario's eval note.

Goals (the ``GOAL_*`` constants): on ``urban``, ``urban-transition`` and ``regime-switch`` a learned method at least 20%
better than the reference with a 95% CI that excludes 0 and a share of the gap of at least 50%; on
``open-sky`` within 2% of the reference (the CI's upper end at most +2%); on the smartLoc recording at most
6.4 m horizontal RMSE.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

GOAL_BEAT = ("urban", "urban-transition", "regime-switch")
GOAL_BEAT_REL, GOAL_BEAT_SHARE = -0.20, 0.50
GOAL_PLACEBO, GOAL_PLACEBO_REL = "open-sky", 0.02
GOAL_REAL_M = 6.4


def _load(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as e:
        raise ValueError(f"{path}: unreadable ({e})") from None


def short_label(spec: str) -> str:
    """A learned row's name in the summary: ``learned-r``, ``ppo SatelliteR`` / ``ppo SatelliteSageHusa`` (from
    the run folder), the spec itself otherwise."""
    if spec.startswith("learned-r"):
        return "learned-r"
    if spec.startswith("ppo:"):
        if "satellite-sage-husa" in spec:
            return "ppo SatelliteSageHusa (3 seeds)" if "*" in spec else "ppo SatelliteSageHusa"
        if "satellite-r" in spec:
            return "ppo SatelliteR (3 seeds)" if "*" in spec else "ppo SatelliteR"
    return spec


def learned_rows(res: dict, s: str) -> list[dict]:
    """The learned rows of scenario ``s`` in one eval's results.json: the pooled row of each seed group and each
    single learned method (learned-r), with RMSE, paired difference to the reference and the gap share."""
    gap = res.get("gap_to_oracle_r", {}).get(s, {}).get("methods", {})
    groups = res.get("seed_groups", {}).get(s, {})
    members = {m for g in groups.values() for m in g["members"]}
    rows = []
    for spec, g in groups.items():
        gl = next((v for k, v in gap.items() if k.startswith(spec + " (pooled")), {})
        rows.append({"name": short_label(spec), "rmse": g["rmse_h_m"], "per_seed": g["rmse_h_per_seed_m"],
                     **g["paired_vs_reference"], "share": gl.get("share"), "share_ci": gl.get("share_ci95"),
                     "share_note": gl.get("note")})
    for lab, r in res["scenarios"][s].items():
        if lab.startswith("learned-r") and lab not in members:
            gl = gap.get(lab, {})
            rows.append({"name": short_label(lab), "rmse": r["rmse_h_m"], "per_seed": None,
                         **r["paired_vs_reference"], "share": gl.get("share"), "share_ci": gl.get("share_ci95"),
                         "share_note": gl.get("note")})
    return rows


def _ref_rmse(res: dict, s: str) -> float:
    return res["scenarios"][s][res["config"]["reference_labels"][s]]["rmse_h_m"]


def _oracle_r(res: dict, s: str) -> float | None:
    r = res["scenarios"][s].get("oracle-r")
    return None if r is None else r["rmse_h_m"]


def best_hand_designed(res: dict, s: str) -> tuple[str, float]:
    """The lowest-RMSE row of scenario ``s`` that is neither learned nor an oracle (its label, RMSE)."""
    rows = {lab: r["rmse_h_m"] for lab, r in res["scenarios"][s].items()
            if not (lab.startswith(("ppo:", "learned-r", "oracle")) or r.get("oracle"))
            and r["rmse_h_m"] is not None}
    lab = min(rows, key=rows.get)
    return lab, rows[lab]


def _pct(x):
    return "-" if x is None else f"{100 * x:+.1f}%"


def _ci_pct(v, ci, note=None):
    if v is None:
        return note or "-"
    return f"{_pct(v)} [{_pct(ci[0])}, {_pct(ci[1])}]" if ci else f"{_pct(v)} ({note or 'no CI'})"


def gap_share_text(share, ci, note) -> str:
    """A gap share (:func:`envs.metrics.headroom_share`) with its CI as table text; where the gap's own CI includes
    0 the ratio is unbounded and only the reason is shown (a ratio to a gap near 0 means nothing). Used by this
    note and by eval.py's gap table."""
    if share is not None and ci is None and note and "includes 0" in note:
        return "not defined: the gap's 95% CI includes 0"
    return _ci_pct(share, ci, note)


def _share_text(r: dict) -> str:
    return gap_share_text(r["share"], r["share_ci"], r["share_note"])


def summary_table(results: dict) -> list[str]:
    """Markdown lines: one row per (scenario, learned method)."""
    lines = ["| scenario | reference (best hand-designed) | RMSE h [m] | learned method | RMSE h [m] (per seed) | "
             "vs reference (95% CI) | share of the gap to oracle-r closed (95% CI) | oracle-r [m] |",
             "|" + "---|" * 8]
    for s, res in results.items():
        ref = res["config"]["reference_labels"][s]
        rref = res["scenarios"][s][ref]["rmse_h_m"]
        for r in learned_rows(res, s):
            rel_ci = [c / rref for c in r["diff_rmse_h_ci95_m"]] if r.get("diff_rmse_h_ci95_m") else None
            seeds = "" if not r["per_seed"] else " (" + " / ".join(f"{x:.2f}" for x in r["per_seed"]) + ")"
            oracle = _oracle_r(res, s)
            lines.append(f"| {s} | {ref} | {rref:.2f} | {r['name']} | {r['rmse']:.2f}{seeds} | "
                         f"{_ci_pct(r['rel_diff'], rel_ci)} | {_share_text(r)}"
                         f" | {'-' if oracle is None else f'{oracle:.2f}'} |")
    return lines


def goal_lines(results: dict) -> list[str]:
    """One line per goal: met or missed, by how much, from the summary's figures (the best learned row)."""
    out = []
    for s in GOAL_BEAT:
        if s not in results:
            out.append(f"- {s}: not evaluated")
            continue
        rows = learned_rows(results[s], s)
        rref = _ref_rmse(results[s], s)
        b = min(rows, key=lambda r: r["rel_diff"])
        sig = b["diff_rmse_h_ci95_m"] is not None and b["diff_rmse_h_ci95_m"][1] < 0
        met = b["rel_diff"] <= GOAL_BEAT_REL and sig and (b["share"] or -1) >= GOAL_BEAT_SHARE
        out.append(f"- {s}: {'met' if met else 'missed'}. Best learned: {b['name']} {_pct(b['rel_diff'])} against "
                   f"the reference ({rref:.2f} m; goal {_pct(GOAL_BEAT_REL)}, CI "
                   f"{'excludes' if sig else 'does not exclude'} 0), share of the gap "
                   f"{_share_text(b)} (goal {100 * GOAL_BEAT_SHARE:.0f}%).")
    if GOAL_PLACEBO in results:
        s = GOAL_PLACEBO
        rows = learned_rows(results[s], s)
        for r in rows:
            hi = None if not r["diff_rmse_h_ci95_m"] else r["diff_rmse_h_ci95_m"][1] / _ref_rmse(results[s], s)
            met = hi is not None and hi <= GOAL_PLACEBO_REL
            out.append(f"- {s}, {r['name']}: {'met' if met else 'missed'} ({_pct(r['rel_diff'])}, CI upper end "
                       f"{_pct(hi)}; goal within {_pct(GOAL_PLACEBO_REL)}).")
    real = {s: res for s, res in results.items() if s.startswith("smartloc")}
    if real:
        best = min(((r["rmse"], r["name"], s) for s, res in real.items() for r in learned_rows(res, s)))
        out.append(f"- smartLoc: {'met' if best[0] <= GOAL_REAL_M else 'missed'}. Best learned: {best[1]} on {best[2]}"
                   f" {best[0]:.2f} m (goal <= {GOAL_REAL_M} m; missed by {max(0.0, best[0] - GOAL_REAL_M):.2f} m).")
    return out


def budget_lines(config_paths, runs_root: Path) -> list[str]:
    """The training budget of every run of the given sweep configs, from the runs' own config.json."""
    import yaml
    lines = ["| config | run | env steps | wall time [min] | env-steps/s | last eval reward |", "|" + "---|" * 6]
    for cp in config_paths:
        cfg = yaml.safe_load(Path(cp).read_text())
        root = runs_root / Path(cp).stem.replace("_", "-")
        for run in sorted(root.glob("*/*/config.json")):
            c = _load(run)
            lines.append(f"| {cp} | {run.parent.relative_to(root)} | {c.get('n_timesteps', cfg.get('timesteps'))} | "
                         f"{c.get('wall_time_s', float('nan')) / 60:.1f} | {c.get('env_steps_per_s', float('nan')):.0f} | "
                         f"{c.get('eval_mean_reward_last', float('nan')):.0f} |")
    return lines


def build_note(runs: Path, scenarios: list[str], configs: list[str], pretrained: Path, runs_root: Path,
               diagnostics: dict | None = None) -> str:
    """The whole note as Markdown (``diagnostics``: :mod:`agents.channel_diagnostics`'s JSON, optional)."""
    results = {s: _load(runs / s / "results.json") for s in scenarios}
    lines = ["# Per-satellite learned methods against the best hand-designed method", "",
             "Generated by `bash scripts/results_satellite.sh` from the eval.py runs under "
             f"`{runs}/<scenario>/`. Every learned method here was trained in simulation on `urban-smartloc` only "
             "and runs zero-shot on the other scenarios and on the smartLoc recording. The reference of each "
             "scenario is its best hand-designed method, fixed before any learned method ran (docs/headroom.md, "
             "docs/headroom-urban-smartloc.md, docs/real-data.md); all hand-designed methods are in each "
             "scenario's table below, so a better one would show. Share of the gap = (reference - method) / "
             "(reference - oracle-r); oracle-r knows every satellite's true variance and is the floor of the "
             "SatelliteR action space.", "", "## Summary", "", *summary_table(results), "", "## Goals", "",
             *goal_lines(results), ""]
    if diagnostics:
        from .channel_diagnostics import table
        first = next(iter(diagnostics.values()))
        lines += ["## Channel by channel", "",
                  f"Each method closed loop on {first['episodes']} held-out {first['scenario']} worlds, its action "
                  "read as a variance inflation and scored against the simulator's truth "
                  "(`python -m agents.channel_diagnostics`): how well it tells NLOS channels from clean ones.", "",
                  *table(diagnostics), ""]
    lines += ["## Training budget", "", *budget_lines(configs, runs_root), ""]
    pc = pretrained / "satellite-r" / "config.json"
    if pc.is_file():
        c = _load(pc)
        p = c.get("pretrained", {})
        lines += ["## Shipped policy", "",
                  f"`{pc.parent}/` ({c.get('env')}, method {c.get('env_kwargs', {}).get('method')}) is "
                  f"`{p.get('source')}`, picked by {p.get('criterion')} (the training run's own evaluation "
                  "seeds, never these episodes) among: "
                  + ", ".join(f"`{k}` {v:.0f}" for k, v in p.get("candidates", {}).items()) + ".", ""]
    for s in scenarios:
        note = (runs / s / "NOTE.md").read_text().splitlines()
        lab, r = best_hand_designed(results[s], s)
        lines += [f"## {s}", "", f"Best hand-designed row in this run: {lab} ({r:.2f} m).", ""]
        lines += [x.replace("## ", "### ", 1) if x.startswith("## ") else x for x in note[1:]]
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> Path:
    p = argparse.ArgumentParser(prog="python -m agents.satellite_results", description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="the note's path (docs/results-satellite.md)")
    p.add_argument("--runs", required=True, help="folder with one eval.py output folder per scenario")
    p.add_argument("--scenarios", nargs="+", required=True, metavar="SCENARIO[:REFERENCE]",
                   help="the scenarios, in order (a ':reference' suffix is ignored: the runs name theirs)")
    p.add_argument("--configs", nargs="+", default=[], help="the training sweep configs (for the budget)")
    p.add_argument("--pretrained", default="pretrained", help="the shipped models' folder")
    p.add_argument("--runs-root", default="runs", help="where the sweeps wrote their runs")
    p.add_argument("--diagnostics", default=None, metavar="JSON",
                   help="agents.channel_diagnostics output: adds the per-channel section")
    args = p.parse_args(argv)
    from envs.outputs import write_atomic
    try:
        text = build_note(Path(args.runs), [s.split(":", 1)[0] for s in args.scenarios], args.configs,
                          Path(args.pretrained), Path(args.runs_root),
                          None if args.diagnostics is None else _load(Path(args.diagnostics)))
    except (ValueError, KeyError, FileNotFoundError) as e:
        p.exit(2, f"agents.satellite_results: {e}\n")
    write_atomic(args.out, text + "\n")
    print(f"wrote {args.out}")
    return Path(args.out)


if __name__ == "__main__":
    main()
