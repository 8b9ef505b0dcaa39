"""Configuration of the GNSS/INS tuning environments (frozen dataclasses, validated).

The action of an environment sets one or more *parameters* of the running
adaptive filter. Each is described by a :class:`ParamSpec`: its name on the
filter (``form.set_params(name=...)``), its physical range, and the map from
the agent's action ``a`` in [-1, 1] to that range:

=========  ==================================================================
map        parameter value for action ``a``
=========  ==================================================================
``log1m``  ``1 - exp(lerp(log(1 - high), log(1 - low)))`` evaluated at ``-a``,
           i.e. ``log(1 - p)`` is linear in ``a``; ``a = -1 -> low``, ``a = 1 -> high``
           (forgetting factors close to 1: equal action steps = equal memory ratios)
``log``    ``exp(lerp(log low, log high))``: log-uniform scale factors
``linear`` ``lerp(low, high)``
=========  ==================================================================
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .sim.scenarios import Scenario, get_scenario
from .zupt_source import ZUPT_CHOICES, check_zupt_choice  # noqa: F401  (ZUPT_CHOICES re-exported)

REWARDS = ("horizontal", "log", "3d", "advantage")
MAPS = ("log1m", "log", "linear")
MAX_EPISODE_S = 3600.0
"""Longest episode [s]. A world is generated whole at reset, about :data:`WORLD_BYTES_PER_IMU_SAMPLE` per IMU
sample and row (one hour at 100 Hz: ~150 MB per row); longer episodes hang in trajectory generation or
exhaust memory."""
WORLD_BYTES_PER_IMU_SAMPLE = 400
"""Memory of an env row per IMU sample [bytes]: 323 measured for the world's arrays (truth, IMU, GNSS at
1 Hz; ``open-sky`` and ``urban``, 60 s), plus the env core's copies of the IMU samples and the truth."""
MAX_HISTORY = 64
"""Most stacked observation frames (64 x 25 floats per row)."""
MIN_DIVERGENCE_BOUND_M = 50.0
"""Smallest ``divergence_bound_m`` [m]: above the initial position errors of every scenario (``seed000-sim``
starts 10 m off on each ECEF axis, about 14 m horizontally) and the tens of metres a code-based filter wanders in a
street canyon; a bound below it ends healthy episodes at their first epochs as "diverged"."""


@dataclass(frozen=True)
class ParamSpec:
    """One filter parameter driven by one action component (see module docstring)."""

    name: str
    low: float
    high: float
    map: str = "linear"
    default: float = 0.0
    description: str = ""

    def __post_init__(self):
        if self.map not in MAPS:
            raise ValueError(f"ParamSpec.map must be one of {MAPS}, got {self.map!r}")
        for f in ("low", "high", "default"):
            v = getattr(self, f)
            if not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise ValueError(f"ParamSpec.{f} must be a finite number, got {v!r}")
        if not self.low < self.high:
            raise ValueError(f"ParamSpec {self.name}: low ({self.low}) must be < high ({self.high})")
        if not self.low <= self.default <= self.high:
            raise ValueError(f"ParamSpec {self.name}: default {self.default} outside [{self.low}, {self.high}]")
        if self.map == "log1m" and not (self.high < 1.0):
            raise ValueError(f"ParamSpec {self.name}: a log1m parameter needs high < 1, got {self.high}")
        if self.map == "log" and not (self.low > 0):
            raise ValueError(f"ParamSpec {self.name}: a log parameter needs low > 0, got {self.low}")
        # the map's own coordinate u (linear in the action) at a = -1 and its width, once: to_value and
        # to_action interpolate between the end points (Python floats: exact conversions of the same numbers)
        if self.map == "log":
            ends = (np.log(self.low), np.log(self.high))
        elif self.map == "log1m":
            ends = (np.log(1.0 - self.low), np.log(1.0 - self.high))
        else:
            ends = (self.low, self.high)
        object.__setattr__(self, "_origin", float(ends[0]))
        object.__setattr__(self, "_span", float(ends[1] - ends[0]))

    def to_value(self, a):
        """Physical value(s) for action component(s) ``a`` in [-1, 1] (clipped).

        Parameters
        ----------
        a : scalar or array of actions (NaN stays NaN, +-inf clip to +-1).

        Returns
        -------
        float64 array of ``a``'s shape (a ``np.float64`` for a scalar).
        """
        a = np.asarray(a, np.float64)
        one = a.size == 1
        if one:  # a single env: the same IEEE operations on a Python float, bit for bit, without 7 array calls
            x = min(max(a.item(), -1.0), 1.0)  # NaN propagates as in np.maximum / np.minimum
        else:
            x = np.minimum(np.maximum(a, -1.0), 1.0)  # np.clip's values, less overhead
        u = self._origin + 0.5 * (x + 1.0) * self._span
        if self.map != "linear":  # numpy's exp on a float is its array loop's (libm's may differ in the last bit)
            u = np.exp(u) if self.map == "log" else 1.0 - np.exp(u)
        if not one:
            return u
        return np.float64(u) if a.ndim == 0 else np.array(u, np.float64, ndmin=a.ndim)  # every dim is 1

    def to_action(self, value):
        """Inverse of :meth:`to_value`: the action component that gives ``value``."""
        v = np.asarray(value, np.float64)
        if self.map != "linear":
            v = np.log(v) if self.map == "log" else np.log(1.0 - v)
        return 2.0 * ((v - self._origin) / self._span) - 1.0


@dataclass(frozen=True)
class EnvConfig:
    """Constructor arguments of the environments (validated; errors name the field).

    Attributes
    ----------
    scenario : scenario name, dataset spec path (``*.toml``, :mod:`envs.datasets.spec`) or
        :class:`~envs.sim.scenarios.Scenario` (a replay world's ``ReplayScenario`` replays it).
    method : filter method (DESIGN.md section 4, ``+onestep`` allowed); must accept the env's parameters.
    imu_grade : override of the scenario's IMU grade (None: keep).
    episode_length_s : episode length [s] (overrides the scenario duration).
    gnss_rate_hz : override of the scenario's GNSS rate [Hz] (None: keep). One env step = one GNSS epoch.
    reward : ``'horizontal'`` (-horizontal error [m]), ``'log'`` (-ln(error [m] + 0.1)), ``'3d'``
        (-3D error [m]) or ``'advantage'`` (error of a reference filter with fixed default parameters on the
        same data minus the agent's error [m]).
    history : number of stacked observation frames (>= 1).
    zupt : zero-velocity aiding: ``'none'``; ``'truth'`` (the truth is stationary); or a detector run on the
        IMU samples of every epoch (:func:`nav_filters.zupt.make_detector`: ``'shoe'``, ``'are'``, ``'mag'``,
        ``'mv'`` with the shipped tuned constants, ``'mlp'``, ``'lstm'`` with weights). Where the vehicle is
        stationary at an epoch, the ZUPT and zero-heading-rate rows (:func:`nav_filters.zupt.stationary_block`)
        are fused into that epoch's update.
    zupt_weights : weights file of the ``'mlp'`` / ``'lstm'`` detector (None: the shipped default).
    dtype : filter arithmetic, ``'float64'`` or ``'float32'``.
    exact_transition : ``False`` (default): the filter's transition and process noise formed once per epoch
        from the epoch's averaged error dynamics (several times faster); ``True``: composed at every IMU
        sample, the reference (:class:`nav_filters.navigator.NavigatorConfig`'s default, what eval.py runs
        every method with). :mod:`nav_filters.averaged_transition` gives the equations;
        ``benchmarks/bench_envs.py --accuracy`` the paired RMSE of the two on every built-in scenario.
    fused_update : ``True`` (default): the fused compiled predict + Joseph update of ``kf`` (and the compiled
        updates of the SVD forms, ``svd-akf`` / ``svd-asrkf``'s inner forms) and the adaptive laws' fast kernels
        (same equations, different rounding); ``False``: the form computes as the
        navigator's default does. The defaults of the two make the fastest configuration (issue 11).
    divergence_bound_m : horizontal error [m] beyond which an episode terminates as diverged (at least
        :data:`MIN_DIVERGENCE_BOUND_M`).
    """

    scenario: object = "noise-burst"
    method: str = "sage-husa"
    imu_grade: str | None = None
    episode_length_s: float = 120.0
    gnss_rate_hz: float | None = None
    reward: str = "horizontal"
    history: int = 1
    zupt: str = "none"
    zupt_weights: str | None = None
    dtype: str = "float64"
    exact_transition: bool = False
    fused_update: bool = True
    divergence_bound_m: float = 1000.0

    def __post_init__(self):
        if self.reward not in REWARDS:
            raise ValueError(f"EnvConfig.reward must be one of {REWARDS}, got {self.reward!r}")
        check_zupt_choice(self.zupt, self.zupt_weights, owner="EnvConfig.zupt")
        if isinstance(self.history, bool) or not isinstance(self.history, int) or not 1 <= self.history <= MAX_HISTORY:
            raise ValueError(f"EnvConfig.history must be an int in [1, {MAX_HISTORY}] (stacked frames), "
                             f"got {self.history!r}")
        if self.dtype not in ("float64", "float32"):
            raise ValueError(f"EnvConfig.dtype must be 'float64' or 'float32', got {self.dtype!r}")
        if not isinstance(self.exact_transition, (bool, np.bool_)):
            raise ValueError(f"EnvConfig.exact_transition must be a bool, got {self.exact_transition!r}")
        if not isinstance(self.fused_update, (bool, np.bool_)):
            raise ValueError(f"EnvConfig.fused_update must be a bool, got {self.fused_update!r}")
        for f in ("episode_length_s", "divergence_bound_m", "gnss_rate_hz"):
            v = getattr(self, f)
            if f == "gnss_rate_hz" and v is None:
                continue
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"EnvConfig.{f} must be a positive finite number, got {v!r}")
        if self.divergence_bound_m < MIN_DIVERGENCE_BOUND_M:
            raise ValueError(f"EnvConfig.divergence_bound_m must be >= {MIN_DIVERGENCE_BOUND_M:g} m (a smaller bound "
                             f"ends healthy episodes at their first epochs as diverged), got {self.divergence_bound_m!r}")
        if not isinstance(self.method, str):
            raise ValueError(f"EnvConfig.method must be a string, got {self.method!r}")
        scen = self.resolve_scenario()  # validates scenario, imu_grade, gnss_rate_hz
        if self.episode_length_s > MAX_EPISODE_S:
            gb = WORLD_BYTES_PER_IMU_SAMPLE * scen.imu_rate_hz * self.episode_length_s / 1e9
            raise ValueError(f"EnvConfig.episode_length_s must be <= {MAX_EPISODE_S:g} s, got {self.episode_length_s!r} "
                             f"(the episode's world is generated whole at reset: about {gb:.3g} GB per env row at "
                             f"{scen.imu_rate_hz:g} Hz)")

    def make_world(self, seeds, buffers=None, for_reset: bool = False):
        """The world of this config for ``seeds``: the scenario with its overrides (a recording cut to the
        episode length, its IMU synthesized at ``imu_grade``); see :func:`envs.worlds.make_world` (``buffers``:
        its :class:`envs.sim.buffers.WorldBuffers`; ``for_reset``: only what a reset reads of it)."""
        from .worlds import make_world
        return make_world(self.resolve_scenario(), seeds, buffers=buffers, for_reset=for_reset)

    def resolve_scenario(self) -> Scenario:
        """The scenario with this config's overrides applied (a recording: its
        :class:`~envs.datasets.spec.ReplayScenario`, read from its spec, no data loaded)."""
        from .worlds import is_scenario, replay_descriptor, scenario_names
        if not (isinstance(self.scenario, (str, Scenario)) and is_scenario(self.scenario)):
            if isinstance(self.scenario, str):
                raise ValueError(f"EnvConfig.scenario: unknown scenario {self.scenario!r}; known: "
                                 f"{', '.join(scenario_names())} or a dataset spec path (*.toml)")
            raise ValueError(f"EnvConfig.scenario must be a scenario name, a dataset spec path (*.toml) or a "
                             f"Scenario, got {self.scenario!r}")
        try:
            replay = replay_descriptor(self.scenario, self.imu_grade, float(self.episode_length_s))
        except (ValueError, FileNotFoundError) as exc:
            raise ValueError(f"EnvConfig.scenario: {exc}") from exc
        if replay is not None:
            if self.gnss_rate_hz is not None:
                raise ValueError("EnvConfig.gnss_rate_hz cannot be changed for a recorded data set")
            return replay
        over = {"duration_s": float(self.episode_length_s)}
        if self.imu_grade is not None:
            over["imu_grade"] = self.imu_grade
        if self.gnss_rate_hz is not None:
            over["gnss_rate_hz"] = float(self.gnss_rate_hz)
        return get_scenario(self.scenario, **over)

    def replace(self, **kw) -> "EnvConfig":
        return dataclasses.replace(self, **kw)
