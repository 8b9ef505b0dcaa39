"""Method specifications of eval.py: what to run for each name in ``--methods``.

=============================  ===================================================================
spec                           meaning
=============================  ===================================================================
``kf``, ``svd-akf+onestep``    a filter method (the list is below) with its own rule and defaults; ``+onestep``
                               propagates the covariance only at measurement epochs, ``+fde`` adds fault
                               detection and exclusion
``sage-husa[b=0.995]``         an adaptive method with parameters fixed at the given values
``kf[zupt=lstm]``              zero-velocity aiding by a detector (``none``, ``truth``, ``shoe``, ``are``,
                               ``mag``, ``mv``, ``mlp``, ``lstm``); ``zupt_weights=<file>`` for own weights;
                               combines with parameters: ``sage-husa[b=0.99,zupt=shoe]``
``tuned:<tuning.json>``        the optimized fixed parameter written by ``train.py tune``
``<algo>:<model.zip>``         a learned policy (``ppo``, ``sac``, ``td3``, ``recurrentppo``) trained by
                               ``train.py rl``; its env and env kwargs come from ``config.json`` beside it
``oracle-r``, ``oracle-r:<m>``  an oracle: ``kf`` (or filter method ``m``) given the simulator's true
                               per-satellite, per-epoch variances (:func:`envs.worlds.oracle_r_world`);
                               simulated worlds only
``oracle-nlos-excluded``       an oracle: ``kf`` with every NLOS channel removed
``learned-r:<model.pt>``       the supervised per-satellite noise model of ``train.py learned-r``
                               (:mod:`agents.learned_r`) as the fixed policy of ``GnssIns/SatelliteR-v0``: each
                               channel's variance inflated to the predicted one (never below x1); option
                               ``[method=<m>]`` (default ``kf``), e.g. ``learned-r:runs/lr/model.pt[method=kf-fde]``;
                               the path may be the run folder
``rule:<env id>``              the hand-designed causal rule :class:`agents.policies.ReactiveRule` (low b while
                               the satellites look degraded); options ``[b_low=0.5,b_high=0.9999,nis=9,ema=3,
                               hold=5]``
``oracle-schedule:<env id>``   an oracle (:mod:`agents.oracles`): the hindsight-greedy schedule of the env's
                               parameters; options ``[segment_s=10,lookahead_s=20,n=7]`` (and
                               ``method=<m>`` for every oracle of the env's knob: its filter method, e.g.
                               ``sage-husa+fde``)
``best-per-episode:<env id>``  an oracle: the best constant action of each episode; option ``[n=7]``
``crossfit-schedule:<env id>`` an oracle: one shared schedule fitted on the other half of the episodes;
                               options ``[segment_s=10,lookahead_s=20,n=7]``
=============================  ===================================================================

An oracle knows the truth: it runs with the env's default method on the eval worlds (their seeds,
scenario and episode length) and bounds what a policy in the env's action space could reach. Its label
is ``'oracle: <spec>'`` (:func:`is_oracle_label`); it is never a method a user could run. ``n`` is the
number of candidate values per action component (:func:`agents.oracles.action_grid`).

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
from nav_filters.registry import parse_method

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
        kw.update(_eval_env_kwargs(world, dtype))
        return run_policy_episodes(self.policy.env_id, kw, self.policy, world.seeds)


ORACLE_KINDS = {"oracle-schedule": ("segment_s", "lookahead_s", "n", "method"), "best-per-episode": ("n", "method"),
                "crossfit-schedule": ("segment_s", "lookahead_s", "n", "method")}
"""Oracle spec prefixes and the options each accepts (``method``: the env's filter method, e.g. ``sage-husa+fde``:
the knob's oracle on top of fault exclusion; default the env's)."""
ORACLE_LABEL_PREFIX = "oracle: "
_ORACLE_SPEC = re.compile(r"^(?P<env>[^\[\]]+?)(?:\[(?P<p>[^\]]*)\])?$")


def is_oracle_label(label: str) -> bool:
    """Whether a method label is an oracle's (``'oracle: ...'`` here; ``'oracle-r...'``: the R oracle)."""
    return label.startswith("oracle")


@dataclass
class LearnedRMethod(PolicyMethod):
    """``learned-r:<model.pt>[method=<m>]``: the per-satellite noise model (:class:`agents.learned_r.LearnedRPolicy`)
    run through ``GnssIns/SatelliteR-v0`` with filter method ``method`` on the eval worlds. A learned method
    (a :class:`PolicyMethod` for eval.py's tables and plots), trained by ``train.py learned-r``."""

    method: str = "kf"

    def run(self, world, dtype="float64", zupt: str = "none"):
        from .learned_r import ENV_ID, LearnedRPolicy
        kw = _eval_env_kwargs(world, dtype)
        kw.update(zupt=zupt, method=self.method)
        return run_policy_episodes(ENV_ID, kw, LearnedRPolicy.for_env(self.policy, kw), world.seeds)


def parse_learned_r_spec(spec: str) -> LearnedRMethod:
    """A :class:`LearnedRMethod` for ``'learned-r:<path>[method=<m>]'``; a one-line ``ValueError`` /
    ``FileNotFoundError`` naming the culprit for a bad option, method or model file."""
    m = _ORACLE_SPEC.match(spec.split(":", 1)[1].strip())
    if not m or not m.group("env").strip():
        raise ValueError(f"bad learned-r spec {spec!r}: expected 'learned-r:<model.pt>[method=<m>]'")
    path, method = m.group("env").strip(), "kf"
    for item in filter(None, (x.strip() for x in (m.group("p") or "").split(","))):
        k, _, v = (x.strip() for x in item.partition("="))
        if k != "method" or not v:
            raise ValueError(f"unknown option {item!r} in {spec!r}; learned-r takes method=<filter method>")
        try:
            parse_method(v)
        except ValueError as e:
            raise ValueError(f"{spec}: {e}") from None
        method = v
    from .learned_r import load_model
    return LearnedRMethod(spec, "learned-r", path, load_model(path), method)


@dataclass
class OracleMethod:
    """A hindsight oracle of an env's knob (:mod:`agents.oracles`), run on the eval worlds' seeds."""

    label: str
    kind: str
    env_id: str
    options: dict = field(default_factory=dict)
    progress: bool = True
    is_oracle = True

    def run(self, world, dtype="float64", zupt: str = "none"):
        """Run on ``world``'s seeds with the env's default method, ``world``'s scenario and episode length
        (``zupt``: ``'none'`` or ``'truth'``; a detector's stream state cannot be branched). Returns the
        EpisodeLog of the oracle's chosen path (``filter_time_s``: the oracle's whole wall time)."""
        from . import oracles
        kw = _eval_env_kwargs(world, dtype)
        kw["zupt"] = zupt
        opts = dict(self.options)
        if "n" in opts:
            opts["grid"] = opts.pop("n")
        if "method" in opts:
            kw["method"] = opts.pop("method")
        scen = world.scenario.name

        def report(msg, done=False):
            import sys
            print(f"\r[{scen}] {self.label[-40:]:<40s} {msg[:80]:<80s}", end="", file=sys.stderr, flush=True)
        fn = {"oracle-schedule": oracles.greedy_schedule, "best-per-episode": oracles.best_per_episode,
              "crossfit-schedule": oracles.crossfit_schedule}[self.kind]
        self.result = fn(self.env_id, kw, world.seeds, progress=report if self.progress else None, **opts)
        return self.result.log


@dataclass
class RuleMethod:
    """A hand-designed causal rule (:class:`agents.policies.ReactiveRule`) run through the env on the eval worlds."""

    label: str
    env_id: str
    options: dict = field(default_factory=dict)

    def run(self, world, dtype="float64", zupt: str = "none"):
        from envs.core import OBS_FEATURES
        from .policies import ReactiveRule
        from .rollout import env_class
        specs = env_class(self.env_id).PARAMS
        pol = ReactiveRule(specs, len(specs) + len(OBS_FEATURES), **self.options)
        kw = _eval_env_kwargs(world, dtype)
        kw["zupt"] = zupt
        return run_policy_episodes(self.env_id, kw, pol, world.seeds)


RULE_OPTIONS = ("b_low", "b_high", "nis", "ema", "hold")


def parse_rule_spec(spec: str) -> RuleMethod:
    """A :class:`RuleMethod` for ``'rule:<env id>[opt=value,...]'``; one-line ``ValueError`` otherwise."""
    _, rest = spec.split(":", 1)
    m = _ORACLE_SPEC.match(rest.strip())
    if not m:
        raise ValueError(f"bad rule spec {spec!r}: expected 'rule:<env id>[option=value,...]'")
    env_id = m.group("env").strip()
    from envs.core import OBS_FEATURES
    from .policies import ReactiveRule
    from .rollout import env_class
    specs = env_class(env_id).PARAMS
    opts = {}
    for item in filter(None, (x.strip() for x in (m.group("p") or "").split(","))):
        k, _, v = (x.strip() for x in item.partition("="))
        if k not in RULE_OPTIONS:
            raise ValueError(f"unknown option {k!r} in {spec!r}; rule takes {', '.join(RULE_OPTIONS)}")
        try:
            opts[k] = int(v) if k == "hold" else float(v)
        except ValueError:
            raise ValueError(f"bad value {v!r} for {k!r} in {spec!r}") from None
    ReactiveRule(specs, len(specs) + len(OBS_FEATURES), **opts)  # validates
    return RuleMethod(spec, env_id, opts)


def _eval_env_kwargs(world, dtype) -> dict:
    """Env kwargs that make the env core run ``world``: its scenario (a recording by name) and length, with
    the filter arithmetic of every eval.py row: the exact per-sample composition of the transition and the
    form's own update (``exact_transition=True, fused_update=False``, the navigator's default that the filter
    rows and ``tuned:`` run), whatever a policy was trained with (the envs' fast default is for training)."""
    return {"scenario": world.scenario.name if world.scenario.name in _replay() else world.scenario,
            "episode_length_s": float(world.scenario.duration_s), "dtype": dtype,
            "exact_transition": True, "fused_update": False}


def parse_oracle_spec(spec: str) -> OracleMethod:
    """An :class:`OracleMethod` for ``'<kind>:<env id>[opt=value,...]'`` (module docstring); ``ValueError``
    with a one-line message naming the culprit for an unknown env id or option, or a bad value."""
    kind, rest = spec.split(":", 1)
    m = _ORACLE_SPEC.match(rest.strip())
    if not m:
        raise ValueError(f"bad oracle spec {spec!r}: expected '{kind}:<env id>[option=value,...]'")
    env_id = m.group("env").strip()
    from .rollout import env_class
    env_class(env_id)
    known = ORACLE_KINDS[kind]
    opts = {}
    for item in filter(None, (x.strip() for x in (m.group("p") or "").split(","))):
        if "=" not in item:
            raise ValueError(f"bad option {item!r} in {spec!r}: expected name=value")
        k, v = (x.strip() for x in item.split("=", 1))
        if k not in known:
            raise ValueError(f"unknown option {k!r} in {spec!r}; {kind} takes {', '.join(known)}")
        if k == "method":
            from envs.core import check_method_has_params
            try:
                check_method_has_params(v, env_class(env_id).PARAMS, env_class(env_id).DEFAULTS["method"])
            except ValueError as e:
                raise ValueError(f"{spec}: {e}") from None
            opts[k] = v
            continue
        try:
            val = int(v) if k == "n" else float(v)
        except ValueError:
            raise ValueError(f"bad value {v!r} for {k!r} in {spec!r}") from None
        if (k == "n" and val < 2) or (k == "segment_s" and not val > 0) or (k == "lookahead_s" and not val >= 0) \
                or val != val or val in (float("inf"), float("-inf")):
            need = {"n": "an int >= 2", "segment_s": "a positive number", "lookahead_s": "a number >= 0"}[k]
            raise ValueError(f"bad value {v!r} for {k!r} in {spec!r}: must be {need}")
        opts[k] = val
    return OracleMethod(ORACLE_LABEL_PREFIX + spec, kind, env_id, opts)


@dataclass
class OracleRMethod:
    """A filter method on the world with the true measurement variances (or without its NLOS channels)."""

    label: str
    method: str = "kf"
    exclude_nlos: bool = False
    is_oracle = True

    def run(self, world, dtype="float64", zupt: str = "none"):
        from envs.worlds import oracle_r_world
        return run_episodes(oracle_r_world(world, self.exclude_nlos), self.method, dtype=dtype, zupt=zupt)


ORACLE_R_NAMES = ("oracle-r", "oracle-nlos-excluded")


def _replay():
    from envs.worlds import REPLAY_SCENARIOS
    return REPLAY_SCENARIOS


def parse_method_spec(spec: str):
    """A :class:`FilterMethod`, :class:`PolicyMethod` or :class:`OracleMethod` for an eval.py method spec (``ValueError`` /
    ``FileNotFoundError`` with a one-line message for a bad one)."""
    spec = spec.strip()
    if spec == "oracle-nlos-excluded":
        return OracleRMethod(spec, "kf", exclude_nlos=True)
    if spec == "oracle-r" or spec.startswith("oracle-r:"):
        method = spec.split(":", 1)[1] if ":" in spec else "kf"
        parse_method(method)
        return OracleRMethod(spec, method)
    if ":" in spec:
        kind, path = spec.split(":", 1)
        if kind in ORACLE_KINDS:
            return parse_oracle_spec(spec)
        if kind == "rule":
            return parse_rule_spec(spec)
        if kind == "learned-r":
            return parse_learned_r_spec(spec)
        if kind == "tuned":
            t = load_tuning(path)
            params = dict(t.get("fixed", {}))
            params[t["param"]] = t["best"]
            try:
                parse_method(t["method"])
            except ValueError as e:
                raise ValueError(f"{path}: {e}") from None
            check_method_params(t["method"], params, f"{path}")
            return FilterMethod(spec, t["method"], params)
        if kind.lower() in ALGOS:
            policy = Sb3Policy.load(path, kind.lower())
            check_policy_env(policy, path)
            return PolicyMethod(spec, kind.lower(), path, policy)
        raise ValueError(f"unknown method prefix {kind!r} in {spec!r}; use 'tuned:', 'learned-r:', an oracle "
                         f"({', '.join(ORACLE_KINDS)}) or one of {', '.join(ALGOS)}")
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
        check_method_params(method, params, spec)
        return FilterMethod(spec, method, params, **aiding)
    parse_method(spec)
    return FilterMethod(spec, spec)


def check_policy_env(policy: Sb3Policy, path) -> None:
    """Validate a loaded policy's environment before any work starts: ``config.json`` beside the model must
    name a registered env id and valid env kwargs, and the model's observations must have that env's size;
    ``ValueError`` naming the file otherwise."""
    from pathlib import Path

    from .rollout import env_class
    cfg = Path(path).parent / "config.json"
    if policy.env_id is None:
        raise ValueError(f"{path}: no config.json beside the model naming its environment (train.py rl writes one)")
    try:
        cls = env_class(policy.env_id)
        config = cls.config_from(policy.env_kwargs)
        want = (cls.core_for(config, 1).obs_dim,)
    except ValueError as e:
        raise ValueError(f"{cfg}: {e}") from None
    got = tuple(policy.model.observation_space.shape)
    if got != want:
        raise ValueError(f"{path}: the model observes {got} values, {policy.env_id} with these env kwargs gives {want} "
                         "(trained on an older observation layout?)")


def check_method_params(method: str, params: dict, spec: str) -> None:
    """Validate fixed parameters of a filter method before any work starts: a method without parameters, an
    unknown name, NaN, inf or a value outside the parameter's range raises ``ValueError`` naming the spec."""
    if not params:
        return
    from nav_filters.registry import law_params
    specs = {p.name: p for p in law_params(method)}
    if not specs:
        raise ValueError(f"{spec}: method {method!r} has no parameters to set (got {', '.join(sorted(params))})")
    for k, v in params.items():
        if k not in specs:
            raise ValueError(f"{spec}: unknown parameter {k!r} of {method!r}; known: {', '.join(sorted(specs))}")
        specs[k].check(v, owner=spec)


def expand_method_spec(spec: str, scenario: str) -> list:
    """The methods of one eval.py spec on ``scenario`` (module docstring: ``{scenario}`` and glob patterns).

    Labels keep ``{scenario}`` so that a row names the same method on every scenario; a pattern gives one
    method per matching file, sorted by path. ``FileNotFoundError`` when a pattern matches nothing.
    """
    spec = spec.strip()
    if ":" not in spec or spec.split(":", 1)[0] in tuple(ORACLE_KINDS) + ("oracle-r", "rule"):
        return [parse_method_spec(spec)]
    kind, path = spec.split(":", 1)
    opts = ""
    if kind == "learned-r":  # its options in brackets are not part of a glob pattern
        m = _ORACLE_SPEC.match(path.strip())
        if m and m.group("p") is not None:
            path, opts = m.group("env").strip(), f"[{m.group('p')}]"
    concrete = path.replace("{scenario}", scenario)
    if any(c in concrete for c in "*?["):
        files = sorted(glob.glob(concrete))
        if not files:
            raise FileNotFoundError(f"no file matches {concrete!r} (method {spec!r})")
    else:
        files = [concrete]
    out = []
    for f in files:
        m = parse_method_spec(f"{kind}:{f}{opts}")
        if "{scenario}" in path:
            m.label = f"{kind}:{f.replace(scenario, '{scenario}')}{opts}"
        out.append(m)
    return out
