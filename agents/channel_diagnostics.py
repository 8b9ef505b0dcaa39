"""What a per-satellite method does channel by channel: how well its action separates NLOS from clean channels.

A per-satellite method on ``GnssIns/SatelliteR-v0`` (a PPO policy or ``learned-r``) runs closed loop on held-out
simulated worlds (:func:`agents.learned_r.collect_channel_data` with the method acting); each valid channel and
epoch is one sample of its action, read as a log variance inflation ``s = ln(10) log10_inflation(a)`` (the env's
map, :data:`envs.satellite_env.INFLATION_SPEC`: -1: x1, 1: x10^4), scored against the simulator's truth by :func:`agents.learned_r.heldout_metrics`:

| figure | meaning |
|---|---|
| ``auc_nlos`` | probability that an NLOS channel gets a larger inflation than a clean one (0.5: blind) |
| ``spearman_true_var`` | rank correlation of the inflation with the true variance ratio |
| ``nll_m`` | Gaussian NLL of the true pseudorange errors under the inflated variances (``nll_true_var_m``: the floor) |
| ``mean_log10_inflation_los`` / ``_nlos`` | the mean action as log10 inflation on clean / NLOS channels |

Usage::

    python -m agents.channel_diagnostics --out results/x/channel_diagnostics.json \\
        --method 'ppo SatelliteR=ppo:pretrained/satellite-r/model.zip' \\
        --method 'learned-r=learned-r:pretrained/learned-r/model.pt'

The worlds are those of ``train.py learned-r``'s test split (seeds 880000 + k), never a training world.
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

SEED_BASE = 880_000


def load_method(spec: str):
    """``(policy, env_kwargs)`` of ``'ppo:<model.zip>'`` (its run's env kwargs: the method it acts on) or
    ``'learned-r:<model.pt>'`` (on ``kf``, eval.py's default); ``ValueError`` for anything else."""
    if spec.startswith("ppo:"):
        from .policies import Sb3Policy
        pol = Sb3Policy.load(spec[4:], "ppo")
        if pol.env_id != "GnssIns/SatelliteR-v0":
            raise ValueError(f"{spec}: acts on {pol.env_id}, not GnssIns/SatelliteR-v0 (its action is no inflation)")
        kw = {k: v for k, v in pol.env_kwargs.items() if k not in ("scenario", "episode_length_s")}
        return pol, kw
    if spec.startswith("learned-r:"):
        from .learned_r import LearnedRPolicy, load_model
        kw = {"method": "kf"}
        return LearnedRPolicy.for_env(load_model(spec[len("learned-r:"):]), kw), kw
    raise ValueError(f"{spec!r}: expected 'ppo:<model.zip>' or 'learned-r:<model.pt>'")


def method_diagnostics(spec: str, scenario: str = "urban-smartloc", episodes: int = 16,
                       episode_length_s: float = 300.0) -> dict:
    """The figures of the module docstring for one method spec over ``episodes`` held-out worlds of
    ``scenario`` (all in one batch), plus ``env_kwargs``, ``episodes`` and ``scenario``."""
    from .learned_r import collect_channel_data, heldout_metrics
    pol, kw = load_method(spec)
    data = collect_channel_data(scenario, [SEED_BASE + k for k in range(episodes)], episode_length_s,
                                policy=pol, env_kwargs=kw)
    from envs.satellite_env import INFLATION_SPEC
    l10 = INFLATION_SPEC.to_value(data["action"])  # the env's own map: log10 inflation in [0, 4]
    m = heldout_metrics(math.log(10) * l10, data)
    nl = data["nlos"]
    m.update(mean_log10_inflation_los=float(l10[~nl].mean()) if (~nl).any() else None,
             mean_log10_inflation_nlos=float(l10[nl].mean()) if nl.any() else None,
             env_kwargs=kw, episodes=episodes, scenario=scenario)
    return m


def table(diag: dict) -> list[str]:
    """Markdown lines of ``{name: method_diagnostics(...)}``."""
    lines = ["| method | acts on | NLOS AUC | Spearman with true variance | NLL [nats] (true variances) | "
             "mean log10 inflation, clean / NLOS |", "|" + "---|" * 6]
    for name, m in diag.items():
        lines.append(f"| {name} | {m['env_kwargs'].get('method', 'kf')} | {m['auc_nlos']:.3f} | "
                     f"{m['spearman_true_var']:.3f} | {m['nll_m']:.2f} ({m['nll_true_var_m']:.2f}) | "
                     f"{m['mean_log10_inflation_los']:.2f} / {m['mean_log10_inflation_nlos']:.2f} |")
    return lines


def main(argv=None) -> dict:
    p = argparse.ArgumentParser(prog="python -m agents.channel_diagnostics", description=__doc__.split("\n")[0])
    p.add_argument("--out", required=True, help="the JSON file to write")
    p.add_argument("--method", action="append", required=True, metavar="NAME=SPEC",
                   help="a method to diagnose: 'ppo:<model.zip>' (a GnssIns/SatelliteR-v0 policy) or "
                        "'learned-r:<model.pt>'")
    p.add_argument("--scenario", default="urban-smartloc")
    p.add_argument("--episodes", type=int, default=16)
    p.add_argument("--episode-length-s", type=float, default=300.0)
    args = p.parse_args(argv)
    from envs.json_io import dumps
    from envs.outputs import write_atomic
    diag = {}
    try:
        for item in args.method:
            name, sep, spec = item.partition("=")
            if not sep:
                raise ValueError(f"--method {item!r}: expected NAME=SPEC")
            diag[name] = method_diagnostics(spec, args.scenario, args.episodes, args.episode_length_s)
    except (ValueError, FileNotFoundError) as e:
        p.exit(2, f"agents.channel_diagnostics: {e}\n")
    write_atomic(Path(args.out), dumps(diag, indent=2) + "\n")
    print("\n".join(table(diag)))
    return diag


if __name__ == "__main__":
    main()
