"""One entry point for worlds by scenario name: simulated presets and replayed recordings alike.

``make_world(name, seeds)`` returns a :class:`envs.sim.world.World` for either a
simulated scenario (:data:`envs.sim.scenarios.SCENARIOS`) or a recorded data set
(:data:`REPLAY_SCENARIOS` by name, or any dataset spec file by its path:
recorded GNSS, IMU synthesized from the recorded ground truth with the chosen
IMU grade; :mod:`envs.datasets.spec`). The simulated world (``envs.sim``)
never imports the dataset loaders; this module sits above both.
"""
from __future__ import annotations

import numpy as np

from .sim.scenarios import SCENARIOS, Scenario
from .sim.world import World, generate_world

REPLAY_SCENARIOS = ("smartloc-potsdamer-platz", "instinct-reach-static", "smartloc-potsdamer-platz-odometry",
                    "smartloc-potsdamer-platz-nhc")
"""Recorded data sets usable by name: the shipped dataset specs (:data:`envs.datasets.spec.SHIPPED_SPECS`;
they need ../shared/data or $NAVGYM_DATA_DIR; see README). Any other spec is usable by its ``.toml`` path."""


def scenario_names() -> list[str]:
    """Every scenario name: simulated presets, then recorded data sets."""
    return sorted(SCENARIOS) + list(REPLAY_SCENARIOS)


def is_scenario(scenario) -> bool:
    """Whether ``scenario`` is a known name, a dataset spec path (``*.toml``) or a Scenario."""
    from .datasets.spec import is_spec_path
    return isinstance(scenario, Scenario) or is_spec_path(scenario) or scenario in scenario_names()


def replay_descriptor(scenario, imu_grade: str | None = None, duration_s: float | None = None):
    """The :class:`~envs.datasets.spec.ReplayScenario` of a recorded data set (a shipped name, a ``.toml`` path
    or a ReplayScenario) with the overrides applied, or None for a simulated scenario (no data is read)."""
    from .datasets.spec import dataset_spec_of, replay_scenario, ReplayScenario
    spec = dataset_spec_of(scenario)
    if spec is None:
        return None
    if isinstance(scenario, ReplayScenario):
        over = {}
        if imu_grade is not None:
            over["imu_grade"] = imu_grade
        if duration_s is not None:
            over["duration_s"] = float(duration_s)
        return scenario.replace(**over) if over else scenario
    return replay_scenario(spec, duration_s, imu_grade)


def make_world(scenario, seeds, dtype=np.float64, imu_grade: str | None = None,
               duration_s: float | None = None, buffers=None, for_reset: bool = False) -> World:
    """A batched world for ``scenario`` and ``seeds``.

    ``scenario`` is a name of :func:`scenario_names`, a dataset spec path (``*.toml``,
    :mod:`envs.datasets.spec`), a :class:`Scenario`, or the
    :class:`~envs.datasets.spec.ReplayScenario` of a replay world (which replays it again; a plain Scenario
    describing a recording raises ``ValueError`` rather than simulating). ``imu_grade`` and ``duration_s``
    override the scenario's (for a recording: the synthesized IMU's grade, and a prefix of the recording).
    ``buffers``: a simulated world's bulk arrays come from this :class:`envs.sim.buffers.WorldBuffers`
    (:func:`envs.sim.world.generate_world`); a replayed world does not use it. ``for_reset``: a simulated world
    forms only what an env's reset reads (:func:`~envs.sim.world.generate_world`); a replayed world is whole
    either way.
    """
    if not isinstance(scenario, (str, Scenario)) and not hasattr(scenario, "__fspath__"):
        raise ValueError(f"scenario must be a name, a dataset spec path or a Scenario, got {scenario!r}")
    replay = replay_descriptor(scenario, imu_grade, duration_s)
    if replay is not None:
        from .datasets.dataset_world import world_from_spec
        return world_from_spec(replay, seeds, dtype=dtype)
    if isinstance(scenario, str) and scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; known: {scenario_names()} or a dataset spec path "
                         f"(*.toml)")
    over = {}
    if imu_grade is not None:
        over["imu_grade"] = imu_grade
    if duration_s is not None:
        over["duration_s"] = float(duration_s)
    from .sim.scenarios import get_scenario
    return generate_world(get_scenario(scenario, **over), seeds, dtype=dtype, buffers=buffers,
                          for_reset=for_reset)


def oracle_r_world(world: World, exclude_nlos: bool = False) -> World:
    """The world with the simulator's true per-satellite, per-epoch variances as the reported ones (oracle R).

    ``pr_sigma = sqrt(pr_var_true)``, ``prr_sigma = sqrt(prr_var_true)`` (white noise with every event's
    multiplier, the nominal atmosphere term, the NLOS / multipath bias squared: :class:`envs.sim.gnss.GnssData`),
    or, with ``exclude_nlos``, the reported sigmas with every NLOS channel removed. A filter run on it is the
    floor of any measurement-noise adaptation; it knows the truth and is never a method a receiver could run.

    A recorded world has no simulator truth of its errors: there the oracle is
    :func:`envs.datasets.truth_check.recorded_oracle_world` (each pseudorange's error against the recording's
    reference trajectory and a robust clock: its variance, or with ``exclude_nlos`` the exclusion of the
    pseudoranges more than 3 m off).

    Raises
    ------
    ValueError
        for a world with neither (no simulator variances, no truth residuals), naming the scenario.
    """
    import dataclasses
    g = world.gnss
    if g.pr_var_true is None or (g.prr is not None and g.prr_var_true is None):
        if g.pr_error_m is not None and g.pr_var_true is None:
            from .datasets.truth_check import recorded_oracle_world
            return recorded_oracle_world(world, exclude=exclude_nlos)
        raise ValueError(f"oracle R needs the simulator's true variances; scenario {world.scenario.name!r} is a "
                         "recorded data set without them")
    if exclude_nlos:
        gnss = dataclasses.replace(g, mask=g.mask & ~g.nlos)
    else:
        gnss = dataclasses.replace(g, pr_sigma=np.sqrt(g.pr_var_true),
                                   prr_sigma=None if g.prr is None else np.sqrt(g.prr_var_true))
    return dataclasses.replace(world, gnss=gnss)
