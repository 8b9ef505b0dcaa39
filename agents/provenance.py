"""What an eval.py method is and what it was trained on: short readable labels and training records.

A method's full spec (``tuned:runs/main/tuning.json``, ``ppo:runs/{scenario}/ppo-s*/model.zip``) stays
the key of the tables and of results.json; plots and the results note show a short label
(:func:`short_labels`: ``tuned b=0.944``, ``ppo (3 seeds)``, ``oracle: schedule``) and state what each
tuned or learned method was trained on (:func:`training_record`, read from the ``tuning.json`` of
``train.py tune`` or the ``config.json`` beside a model of ``train.py rl``).
"""
from __future__ import annotations

import json
import re
from pathlib import Path

from .policies import ALGOS

MAX_LABEL = 28
"""Longest short label [characters]; longer ones are cut with an ellipsis."""

_ORACLE_SHORT = {"oracle-schedule": "schedule", "best-per-episode": "best per episode",
                 "crossfit-schedule": "crossfit schedule"}
"""Oracle kinds in short labels (within :data:`MAX_LABEL` with the ``oracle: `` prefix)."""
_BRACKETS = re.compile(r"\[[^\]]*\]")


def _kind_path(label: str) -> tuple[str, str]:
    """(prefix, rest) of a ``prefix:rest`` spec, ``('', label)`` without a prefix."""
    if ":" in label and not label.startswith("oracle: "):
        k, rest = label.split(":", 1)
        return k, rest
    return "", label


def _read_json(path: Path) -> dict | None:
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None
    return d if isinstance(d, dict) else None


def _env_defaults(env_id: str | None, env_kwargs: dict) -> tuple[str | None, float | None]:
    """(scenario name, episode length [s]) of an env id with ``env_kwargs`` (None where unknown)."""
    if not env_id:
        return env_kwargs.get("scenario"), env_kwargs.get("episode_length_s")
    try:
        from .rollout import env_class
        cfg = env_class(env_id).config_from(dict(env_kwargs))
    except (ValueError, TypeError):
        return env_kwargs.get("scenario"), env_kwargs.get("episode_length_s")
    scen = cfg.scenario if isinstance(cfg.scenario, str) else getattr(cfg.scenario, "name", str(cfg.scenario))
    return scen, float(cfg.episode_length_s)


def training_record(label: str, scenario: str) -> dict | None:
    """What the tuned or learned method ``label`` was trained on, evaluated on ``scenario``.

    Parameters
    ----------
    label : a method label of eval.py (``tuned:<tuning.json>``, ``<algo>:<model.zip>``; ``{scenario}`` in the
        path stands for ``scenario``).
    scenario : the evaluated scenario.

    Returns
    -------
    dict or None : None for a method that is not trained (a filter, an oracle, a rule) or whose record is
    missing; else ``{"kind": "tuned" | "policy", "file", "env", "scenario", "episode_length_s"}`` plus, for
    ``tuned``: ``"param", "best", "episodes"`` (training episodes per grid value); for ``policy``:
    ``"algo", "timesteps", "seed", "n_envs"``. ``scenario`` / ``episode_length_s`` are those of the
    training env (the env's defaults where its kwargs name none).
    """
    kind, path = _kind_path(label)
    if kind == "tuned":
        f = Path(path.replace("{scenario}", scenario))
        t = _read_json(f)
        if t is None or "param" not in t:
            return None
        scen, length = _env_defaults(t.get("env"), t.get("env_kwargs") or {})
        return {"kind": "tuned", "file": str(f), "env": t.get("env"), "scenario": scen, "episode_length_s": length,
                "param": t["param"], "best": t.get("best"), "episodes": len(t.get("train_seeds", []))}
    if kind.lower() in ALGOS:
        f = Path(path.replace("{scenario}", scenario)).parent / "config.json"
        c = _read_json(f)
        if c is None:
            return None
        scen, length = _env_defaults(c.get("env"), c.get("env_kwargs") or {})
        return {"kind": "policy", "file": str(f), "env": c.get("env"), "scenario": scen,
                "episode_length_s": length, "algo": c.get("algo", kind.lower()), "timesteps": c.get("n_timesteps"),
                "seed": c.get("seed"), "n_envs": c.get("n_envs")}
    return None


def describe_training(records: list[dict]) -> str:
    """One phrase for the training records of one method (several: the training seeds of a pooled group).

    ``'trained on noise-burst, 60 s episodes, 24576 steps, seeds 0, 1, 2'``,
    ``'tuned on noise-burst, 300 s episodes, 8 training episodes per value'``.
    """
    r = records[0]
    length = f"{r['episode_length_s']:g} s episodes" if r.get("episode_length_s") else "episodes of unknown length"
    if r["kind"] == "tuned":
        return f"tuned on {r['scenario']}, {length}, {r['episodes']} training episodes per value"
    steps = sorted({x["timesteps"] for x in records if x.get("timesteps") is not None})
    seeds = [str(x["seed"]) for x in records if x.get("seed") is not None]
    scen = sorted({str(x["scenario"]) for x in records})
    lengths = sorted({x["episode_length_s"] for x in records if x.get("episode_length_s")})
    if len(lengths) > 1:
        length = "episodes of " + ", ".join(f"{v:g}" for v in lengths) + " s"
    return (f"trained on {', '.join(scen)}, {length}, "
            f"{'/'.join(str(s) for s in steps) or 'unknown'} steps, seed{'s' if len(seeds) != 1 else ''} "
            f"{', '.join(seeds) or 'unknown'}")


def _cut(s: str) -> str:
    return s if len(s) <= MAX_LABEL else s[:MAX_LABEL - 3] + "..."


def _tail(path: str, n: int) -> str:
    """``path`` in at most ``n`` characters: its last components after ``.../`` when it is longer."""
    if len(path) <= n:
        return path
    parts, out = Path(path).parts, ""
    for part in reversed(parts):
        cand = part if not out else f"{part}/{out}"
        if len(cand) + 4 > n:
            break
        out = cand
    return ".../" + (out or parts[-1][-(n - 4):])


def _value_text(v: float) -> str:
    """``v`` to 3 significant digits, more where 3 would round it onto a different whole number (0.9999 is
    ``0.9999``, not ``1``: a forgetting factor of 1 means no forgetting)."""
    for p in range(3, 10):
        s = f"{v:.{p}g}"
        if float(s) != round(float(s)) or round(float(s)) == v:
            return s
    return repr(v)


def short_label(label: str, scenario: str, n_seeds: int | None = None) -> str:
    """A short readable label of the eval.py method ``label`` on ``scenario``.

    ``tuned:<file>`` -> ``'tuned b=0.944'`` (the value read from the file; ``'tuned (runs/main/tune-urban)'``,
    its folder with ``{scenario}`` resolved, when it cannot be read); ``<algo>:<model.zip>`` -> ``'ppo'``; the
    pooled row of a pattern over ``n_seeds`` training seeds -> ``'ppo (3 seeds)'``, ``'tuned (3 seeds)'``; an
    oracle -> ``'oracle: schedule'``, ``'oracle: true R'``, ...; ``rule:<env id>[...]`` -> ``'rule'`` plus its
    options; ``learned-r:<model.pt>[...]`` -> ``'learned-r'`` plus its options; a filter spec stays as it is.
    At most :data:`MAX_LABEL` characters.
    """
    if label.startswith("oracle: "):
        kind = label.removeprefix("oracle: ").split(":", 1)[0]
        return _cut("oracle: " + _ORACLE_SHORT.get(kind, kind))
    if label == "oracle-nlos-excluded":
        return "oracle: NLOS excluded"
    if label == "oracle-r" or label.startswith("oracle-r:"):
        return _cut("oracle: true R" + (f" ({label.split(':', 1)[1]})" if ":" in label else ""))
    kind, rest = _kind_path(label)
    if kind == "tuned":
        if n_seeds:  # the pooled row of a pattern over several tuning files
            return f"tuned ({n_seeds} seeds)"
        r = training_record(label, scenario)
        if r is None or r.get("best") is None:
            return f"tuned ({_tail(str(Path(rest.replace('{scenario}', scenario)).parent), MAX_LABEL - 8)})"
        return _cut(f"tuned {r['param']}={_value_text(float(r['best']))}")
    if kind.lower() in ALGOS:
        return _cut(kind.lower() + (f" ({n_seeds} seeds)" if n_seeds else ""))
    if kind == "learned-r":
        opts = _BRACKETS.search(rest)
        return _cut("learned-r" + (f" ({n_seeds} seeds)" if n_seeds else "") + (f" {opts.group(0)[1:-1]}" if opts
                                                                                  else ""))
    if kind == "rule":
        opts = _BRACKETS.search(rest)
        return _cut("rule" + (f" {opts.group(0)[1:-1]}" if opts else ""))
    return _cut(label)


def short_labels(labels, scenario: str, groups: dict | None = None) -> dict:
    """``{label: short label}`` for the method ``labels`` of one scenario, every short label distinct.

    ``groups`` maps a pooled row's label to its number of seeds (``'ppo (3 seeds)'``); the members of a seed
    group and any other labels whose short forms collide get the name of their run directory (or a running
    number) appended.
    """
    groups = groups or {}
    out = {lab: short_label(lab, scenario, groups.get(lab)) for lab in labels}
    counts: dict = {}
    for s in out.values():
        counts[s] = counts.get(s, 0) + 1
    for lab, s in list(out.items()):
        if counts[s] > 1:
            kind, rest = _kind_path(lab)
            tag = Path(rest.replace("{scenario}", scenario)).parent.name if kind else ""
            out[lab] = _cut(f"{s} {tag}") if tag else s
    seen: dict = {}
    for lab, s in out.items():
        n = seen.get(s, 0)
        seen[s] = n + 1
        if n:
            out[lab] = _cut(s[:MAX_LABEL - 4]) + f" #{n + 1}"
    return out


def training_notes(labels_by_scenario: dict, eval_length_s: dict | None = None, groups: dict | None = None) -> list:
    """Markdown list items: what each tuned or learned method was trained on, against what it is evaluated on.

    Parameters
    ----------
    labels_by_scenario : ``{scenario: [method label, ...]}`` of the evaluation.
    eval_length_s : ``{scenario: evaluated episode length [s]}`` (None: not stated).
    groups : ``{scenario: {spec: [member labels]}}`` of the seed groups: one item per group, its members'
        records together.

    Returns
    -------
    list of str : one item per (method, training record) with the scenarios it was evaluated on, and a
    warning where the training scenario or episode length differs from the evaluated ones; a method without
    a readable record says so. Filters, rules and oracles are not trained and get no item.
    """
    eval_length_s = eval_length_s or {}
    items: dict = {}   # (spec, description) -> [scenarios]
    for s, labels in labels_by_scenario.items():
        grouped = (groups or {}).get(s, {})
        member_of = {m: spec for spec, ms in grouped.items() for m in ms}
        done = set()
        for lab in labels:
            spec = member_of.get(lab, lab)
            if spec in done:
                continue
            done.add(spec)
            kind = _kind_path(spec)[0]
            if kind != "tuned" and kind.lower() not in ALGOS:
                continue
            members = grouped.get(spec, [lab])
            recs = [training_record(m, s) for m in members]
            if any(r is None for r in recs):
                desc, warn = "no training record found (no tuning.json / config.json readable)", ""
                key = (spec, desc, "")
            else:
                desc = describe_training(recs)
                warn = []
                scen = {r["scenario"] for r in recs}
                if scen != {s}:
                    warn.append(f"trained on {', '.join(sorted(map(str, scen)))}")
                lengths = {r["episode_length_s"] for r in recs}
                ev = eval_length_s.get(s)
                if ev is not None and lengths != {float(ev)}:
                    warn.append(f"episodes of {', '.join(f'{v:g}' for v in sorted(x for x in lengths if x))} s")
                key = (spec, desc, "; ".join(warn))
            name = short_label(spec, s, len(members) if len(members) > 1 else None)
            items.setdefault(key + (name,), []).append(s)
    out = []
    for (spec, desc, warn, name), scens in items.items():
        lengths = sorted({eval_length_s[s] for s in scens if s in eval_length_s})
        on = ", ".join(f"`{s}`" for s in scens) + (f" ({', '.join(f'{v:g}' for v in lengths)} s episodes)"
                                                   if lengths else "")
        line = f"- {name} (`{spec}`): {desc}; evaluated on {on}."
        if warn:
            line += f" Note: evaluated outside its training conditions ({warn})."
        out.append(line)
    return out
