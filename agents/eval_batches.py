"""eval.py's paired episode batches as independent units of work for a backend (:mod:`agents.backends`).

A batch is one method on one chunk of episode seeds of one scenario. It carries only what builds its world
(scenario name and seeds) and the method: the world is generated where the batch runs, and what travels
back is the method's :class:`envs.episodes.EpisodeLog` of those episodes (per-episode, per-epoch errors;
never the world). Episode k of every method sees the same world because the world is a function of the
seeds alone, so the batches of one chunk can run on different machines and still be paired; the logs are
the same on every backend.

A process keeps the last world it generated (:func:`world_for`), so the methods of one chunk run in one
process (the local backend, or a Ray worker that receives them in turn) generate it once.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from envs.episodes import EpisodeLog, concat_logs


@dataclass(frozen=True)
class EvalBatch:
    """One method on one chunk of paired episodes.

    Attributes
    ----------
    scenario : scenario name (or recorded-data spec) the world is generated from.
    seeds : the chunk's episode seeds (tuple of int).
    method : a method of :mod:`agents.methods` (``label`` and ``run(world, dtype=, zupt=)``).
    dtype : filter arithmetic, ``'float64'`` or ``'float32'``.
    zupt : zero-velocity aiding of a method that names none.
    track : also return row 0's true horizontal track (the trajectory plot) and the scenario's duration.
    events : also return the chunk's event mask (the plots shade the scenario's event windows).
    """

    scenario: str
    seeds: tuple
    method: Any
    dtype: str = "float64"
    zupt: str = "none"
    track: bool = False
    events: bool = False

    def describe(self) -> str:
        """``'<scenario> <method label> seeds a-b'`` for progress lines."""
        label = self.method.label
        label = label if len(label) <= 40 else "..." + label[-37:]
        return f"{self.scenario} {label} seeds {self.seeds[0]}-{self.seeds[-1]}"


@dataclass(frozen=True)
class BatchResult:
    """What a batch sends back.

    Attributes
    ----------
    log : the method's EpisodeLog of the batch's episodes, (B, M, ...) arrays.
    track : (M, 2) row 0's true north/east track from its start [m], or None.
    events : (B, M) int event bits of the chunk's worlds (``GnssData.event_mask``; None for a recording or
        when not asked for).
    duration_s : the scenario's episode length [s] (with ``track``), or None.
    """

    log: EpisodeLog
    track: np.ndarray | None
    events: np.ndarray | None = None
    duration_s: float | None = None


_LAST_WORLD: dict = {}


def world_for(scenario: str, seeds) -> Any:
    """The world of ``scenario`` and ``seeds`` (:func:`envs.worlds.make_world`); the last one is kept per
    process. A recorded scenario without its data raises ``FileNotFoundError`` naming the scenario."""
    from envs.worlds import make_world
    key = (scenario, tuple(int(s) for s in seeds))
    if _LAST_WORLD.get("key") != key:
        _LAST_WORLD.clear()
        try:
            world = make_world(scenario, list(key[1]))
        except FileNotFoundError as e:
            raise FileNotFoundError(f"scenario {scenario!r} needs a recorded data set: {e}") from None
        _LAST_WORLD.update(key=key, world=world)
    return _LAST_WORLD["world"]


def clear_world_cache() -> None:
    """Forget the kept world (frees its memory)."""
    _LAST_WORLD.clear()


def truth_track(world) -> np.ndarray:
    """(M, 2) row 0's true horizontal track (north, east) [m] at the epochs, from its start."""
    from earth import C_en, ecef_to_geodetic
    r = world.truth.r_e[0, world.epoch_idx]
    lat, lon, _ = ecef_to_geodetic(world.truth.r_e[0, 0])
    d = (C_en(lat, lon).T @ (r - world.truth.r_e[0, 0]).T).T
    return d[:, :2]


def run_eval_batch(batch: EvalBatch) -> BatchResult:
    """Generate the batch's world from its seeds and run the method on it."""
    world = world_for(batch.scenario, batch.seeds)
    log = batch.method.run(world, dtype=batch.dtype, zupt=batch.zupt)
    return BatchResult(log=log, track=truth_track(world) if batch.track else None,
                       events=world.gnss.event_mask if batch.events else None,
                       duration_s=float(world.scenario.duration_s) if batch.track else None)


def plan_batches(methods_by_scenario: dict, seeds, batch_size: int, dtype: str = "float64",
                 zupt: str = "none") -> list[EvalBatch]:
    """Every (scenario, chunk of ``batch_size`` seeds, method) batch, scenario-major then chunk then method
    (the methods of a chunk in turn, so a process generates each world once). Oracles run without their
    own progress lines (the backend's bar counts batches)."""
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    seeds = [int(s) for s in seeds]
    out = []
    for s, methods in methods_by_scenario.items():
        for c0 in range(0, len(seeds), batch_size):
            chunk = tuple(seeds[c0:c0 + batch_size])
            for i, m in enumerate(methods):
                if getattr(m, "progress", False):
                    m = dataclasses.replace(m, progress=False)
                out.append(EvalBatch(s, chunk, m, dtype, zupt, track=(c0 == 0 and i == 0), events=(i == 0)))
    return out


def gather(batches: list[EvalBatch], results: list[BatchResult]) -> tuple[dict, dict]:
    """``({scenario: {label: EpisodeLog over all chunks}}, {scenario: track})`` from the batches and their
    results (in the order of :func:`plan_batches`)."""
    logs: dict = {}
    tracks: dict = {}
    for b, r in zip(batches, results, strict=True):
        logs.setdefault(b.scenario, {}).setdefault(b.method.label, []).append(r.log)
        if r.track is not None:
            tracks[b.scenario] = r.track
    return {s: {label: concat_logs(parts) for label, parts in per.items()} for s, per in logs.items()}, tracks


def gather_context(batches: list[EvalBatch], results: list[BatchResult]) -> tuple[dict, dict]:
    """``({scenario: [event mask of each chunk]}, {scenario: episode length [s]})`` from the batches that
    were asked for them (in the order of :func:`plan_batches`)."""
    events: dict = {}
    durations: dict = {}
    for b, r in zip(batches, results, strict=True):
        if b.events:
            events.setdefault(b.scenario, []).append(r.events)
        if r.duration_s is not None:
            durations[b.scenario] = r.duration_s
    return events, durations
