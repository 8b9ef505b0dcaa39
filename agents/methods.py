"""Method specifications of eval.py: what to run for each name in ``--methods``.

=============================  ===================================================================
spec                           meaning
=============================  ===================================================================
``kf``, ``svd-akf+onestep``    a filter method of DESIGN.md section 4 with its own rule and defaults
``sage-husa[b=0.995]``         an adaptive method with parameters fixed at the given values
``kf[zupt=lstm]``              zero-velocity aiding by a detector (``none``, ``truth``, ``shoe``, ``are``,
                               ``mag``, ``mv``, ``mlp``, ``lstm``); ``zupt_weights=<file>`` for own weights;
                               combines with parameters: ``sage-husa[b=0.99,zupt=shoe]``
``tuned:<tuning.json>``        the optimized fixed parameter written by ``train.py tune``
``<algo>:<model.zip>``         a learned policy (``ppo``, ``sac``, ``td3``, ``recurrentppo``) trained by
                               ``train.py rl``; its env and env kwargs come from ``config.json`` beside it
=============================  ===================================================================

In a file path, ``{scenario}`` stands for the scenario being evaluated (a policy and a tuned parameter
per scenario: ``tuned:runs/{scenario}/tuning.json``) and a glob pattern expands to every matching file
(``ppo:runs/{scenario}/ppo-s*/model.zip``: the models of several training seeds, pooled by eval.py).

Every method runs on the same episode seeds, so episode k of every method sees the same world.
"""
from __future__ import annotations

import glob
import re
from dataclasses import dataclass, field

from envs.episodes import run_episodes
from envs.zupt_source import check_zupt_choice
from nav_filters.forms import parse_method

from .policies import ALGOS, Sb3Policy
from .rollout import run_policy_episodes
from .tuning import load_tuning

_PARAMS = re.compile(r"^(?P<m>[^\[\]]+)\[(?P<p>[^\]]*)\]$")


@dataclass
class FilterMethod:
    """A filter method (optionally with fixed parameters)."""

    label: str
    method: str
    params: dict = field(default_factory=dict)
    zupt: str | None = None
    zupt_weights: str | None = None

    def run(self, world, dtype="float64", zupt: str = "none"):
        """Run on ``world``; ``zupt`` is the aiding used when the spec names none."""
        return run_episodes(world, self.method, dtype=dtype, params=self.params or None,
                            zupt=self.zupt or zupt, zupt_weights=self.zupt_weights)


@dataclass
class PolicyMethod:
    """A learned policy run through its environment on the eval worlds."""

    label: str
    algo: str
    path: str
    policy: Sb3Policy

    def run(self, world, dtype="float64", zupt: str = "none"):
        """Run on ``world``; ``zupt`` is the aiding used when the policy's env kwargs name none."""
        if self.policy.env_id is None:
            raise ValueError(f"{self.path}: no config.json beside the model naming its environment")
        kw = dict(self.policy.env_kwargs)
        kw.setdefault("zupt", zupt)
        kw.update(scenario=world.scenario.name if world.scenario.name in _replay() else world.scenario,
                  episode_length_s=float(world.scenario.duration_s), dtype=dtype)
        return run_policy_episodes(self.policy.env_id, kw, self.policy, world.seeds)


def _replay():
    from envs.worlds import REPLAY_SCENARIOS
    return REPLAY_SCENARIOS


def parse_method_spec(spec: str):
    """A :class:`FilterMethod` or :class:`PolicyMethod` for an eval.py method spec (``ValueError`` /
    ``FileNotFoundError`` with a one-line message for a bad one)."""
    spec = spec.strip()
    if ":" in spec:
        kind, path = spec.split(":", 1)
        if kind == "tuned":
            t = load_tuning(path)
            params = dict(t.get("fixed", {}))
            params[t["param"]] = t["best"]
            return FilterMethod(spec, t["method"], params)
        if kind.lower() in ALGOS:
            return PolicyMethod(spec, kind.lower(), path, Sb3Policy.load(path, kind.lower()))
        raise ValueError(f"unknown method prefix {kind!r} in {spec!r}; use 'tuned:' or one of {', '.join(ALGOS)}")
    m = _PARAMS.match(spec)
    if m:
        method = m.group("m")
        parse_method(method)
        params, aiding = {}, {}
        for item in filter(None, (x.strip() for x in m.group("p").split(","))):
            if "=" not in item:
                raise ValueError(f"bad parameter {item!r} in {spec!r}: expected name=value")
            k, v = (x.strip() for x in item.split("=", 1))
            if k in ("zupt", "zupt_weights"):
                aiding[k] = v
                continue
            try:
                params[k] = float(v)
            except ValueError:
                raise ValueError(f"bad value {v!r} for {k!r} in {spec!r}") from None
        if aiding:
            check_zupt_choice(aiding.get("zupt", "none"), aiding.get("zupt_weights"), owner=f"{spec}: zupt")
        return FilterMethod(spec, method, params, **aiding)
    parse_method(spec)
    return FilterMethod(spec, spec)


def expand_method_spec(spec: str, scenario: str) -> list:
    """The methods of one eval.py spec on ``scenario`` (module docstring: ``{scenario}`` and glob patterns).

    Labels keep ``{scenario}`` so that a row names the same method on every scenario; a pattern gives one
    method per matching file, sorted by path. ``FileNotFoundError`` when a pattern matches nothing.
    """
    spec = spec.strip()
    if ":" not in spec:
        return [parse_method_spec(spec)]
    kind, path = spec.split(":", 1)
    concrete = path.replace("{scenario}", scenario)
    if any(c in concrete for c in "*?["):
        files = sorted(glob.glob(concrete))
        if not files:
            raise FileNotFoundError(f"no file matches {concrete!r} (method {spec!r})")
    else:
        files = [concrete]
    out = []
    for f in files:
        m = parse_method_spec(f"{kind}:{f}")
        if "{scenario}" in path:
            m.label = f"{kind}:{f.replace(scenario, '{scenario}')}"
        out.append(m)
    return out
