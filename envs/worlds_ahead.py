"""Draw the worlds of a few coming resets in one batch, in this process, where few rows reset at a time.

A world costs much more per row when drawn alone than in a batch: the stages' fixed Python and kernel-call
costs are paid once per draw (``benchmarks/bench_worlds.py``; measured at 60 s, noise-burst: 3.0-3.3 ms for
one row against 1.8-2.0 ms per row for 16). A single env, or a vector env of few rows, resets one or a few
rows at a time, and their coming world seeds are known ahead (each row's own generator). :class:`WorldsAhead`
draws the worlds of the next resets of those rows in one batch of up to :data:`AHEAD_ROWS` rows and hands each
reset its part: the same bits as drawing it at the reset (a world's row depends only on its seed,
:mod:`envs.sim.world`), for less CPU time per reset in a long run.

The depth grows as resets keep continuing the same streams: after a ``reset(seed=...)`` the first two resets
draw their own worlds (as without this module), then 2, 4, 8 ... resets' worlds are drawn together, up to
:data:`AHEAD_ROWS` rows. A loop that reseeds every episode thus never draws ahead, and the worlds drawn and not
used (a reset of another grouping of rows, or a reseed) are at most about as many as those used since the last
reseed. Memory: each env holds the prepared worlds of one batch (:data:`AHEAD_SAMPLES`: up to 6.4 MB at 60 s
episodes, released by its ``close()``); the bulk arrays a batch is drawn in (30 MB at 60 s) are kept for the next
draw once per thread (:func:`shared_buffers`), not per env, so that a DummyVecEnv of n single envs (RL Zoo) keeps
one set, not n. The background process of :mod:`envs.prefetch` is the other way to take resets off the step
loop (only where a core is idle); a vector env uses one or the other.
"""
from __future__ import annotations

import threading
import weakref

from .prepared import PreparedWorld, prepare_world
from .sim.buffers import WorldBuffers

__all__ = ["AHEAD_ROWS", "AHEAD_SAMPLES", "WorldsAhead", "shared_buffers"]

AHEAD_ROWS = 16
"""Most rows drawn in one batch ahead; resets of more than half as many rows draw their own worlds. Larger batches
cost somewhat less per row still (``bench_worlds.py --batches 1 16 64``) but hold memory in proportion
(:data:`AHEAD_SAMPLES`)."""

AHEAD_SAMPLES = 96_000
"""Most IMU samples (rows x samples per row) drawn in one batch ahead: 16 rows of a 60 s episode at 100 Hz. Such a
batch keeps 6.4 MB of prepared worlds, and its thread 30 MB of bulk arrays for the next draw
(:func:`shared_buffers`, :mod:`envs.sim.buffers`: 20% less CPU time per row than fresh arrays, measured at 16
rows). Longer episodes draw fewer rows ahead (600 s at 100 Hz: none); their worlds cost mostly per sample, where a
batch saves little."""


_THREAD = threading.local()


class _SharedBuffers:
    """One thread's :class:`~envs.sim.buffers.WorldBuffers` for the batches of every :class:`WorldsAhead` drawing
    in it, and the ones that have drawn since they last released them (weak references: an env dropped without
    ``close()`` leaves too)."""

    def __init__(self):
        self.buffers = WorldBuffers()
        self.users = weakref.WeakSet()

    def join(self, user) -> None:
        if user not in self.users:
            self.users.add(user)
            weakref.finalize(user, self.release_if_unused)

    def leave(self, user) -> None:
        self.users.discard(user)
        self.release_if_unused()

    def release_if_unused(self) -> None:
        if next(iter(self.users), None) is None:  # live users only (a collected one may not be discarded yet)
            self.buffers.clear()


def _pool() -> _SharedBuffers:
    pool = getattr(_THREAD, "pool", None)
    if pool is None:
        pool = _THREAD.pool = _SharedBuffers()
    return pool


def shared_buffers() -> WorldBuffers:
    """The bulk arrays of this thread's batches ahead (:class:`~envs.sim.buffers.WorldBuffers`, one per thread).

    The envs of one thread draw their batches in turn, so one set serves them all: an array is handed out again only
    when no world references it (:mod:`envs.sim.buffers`), so sharing changes no world. Envs in other threads draw
    into their own thread's set. Released when the last env that drew in this thread releases its worlds ahead
    (:meth:`WorldsAhead.clear`, the env's ``close()``).
    """
    return _pool().buffers


class WorldsAhead:
    """The worlds of the coming resets of a few rows, drawn in batches (module docstring).

    Parameters
    ----------
    config : the env's :class:`~envs.config.EnvConfig` (its ``make_world``).
    max_rows : most rows of one batch (default :data:`AHEAD_ROWS`; fewer for long episodes,
        :data:`AHEAD_SAMPLES`).
    """

    def __init__(self, config, max_rows: int = AHEAD_ROWS):
        self.config = config
        self.max_rows = int(max_rows)
        self._parts: dict = {}  # tuple of a reset's seeds -> its PreparedWorld (views into the batch)
        self._draws = 0  # draws since the last restart (the depth grows with them)
        self._row_samples = None  # IMU samples per row of the config's worlds (read at the first draw)

    def restart(self) -> None:
        """New streams (a reset with a seed): drop what was drawn ahead and start the depth again."""
        self._parts.clear()
        self._draws = 0

    def depth(self, n_rows: int) -> int:
        """How many resets of ``n_rows`` rows the next draw covers: 1 for the first two draws after a restart, then
        doubling, at most ``max_rows // n_rows`` and :data:`AHEAD_SAMPLES` in all (1: no drawing ahead)."""
        if self._draws < 2:
            return 1
        if self._row_samples is None:
            scen = self.config.resolve_scenario()
            self._row_samples = max(1, int(scen.duration_s * scen.imu_rate_hz))
        rows = min(self.max_rows, AHEAD_SAMPLES // self._row_samples)
        return max(1, min(1 << min(self._draws - 1, 30), rows // max(int(n_rows), 1)))

    def take(self, seeds, coming) -> PreparedWorld | None:
        """The prepared world of a reset with ``seeds`` (one per row), or None where the caller should draw it
        itself (the depth is 1: the same as without this module).

        ``coming(k)``: the seeds of the ``k`` resets after this one, as a list of ``k`` lists like ``seeds``
        (called only when a batch is drawn). A reset whose seeds were drawn ahead takes its part; any other drops
        what was drawn ahead and draws a new batch: this reset's world and those of the coming resets.
        """
        key = tuple(int(s) for s in seeds)
        part = self._parts.pop(key, None)
        if part is not None:
            return part
        self._parts.clear()
        k = self.depth(len(key))
        self._draws += 1
        if k == 1:
            return None
        groups = [list(key)] + [[int(s) for s in g] for g in coming(k - 1)]
        if len(groups) != k or any(len(g) != len(key) for g in groups):
            raise ValueError(f"coming({k - 1}) must give {k - 1} lists of {len(key)} seeds")
        pool = _pool()
        pool.join(self)
        batch = prepare_world(self.config, [s for g in groups for s in g], buffers=pool.buffers)
        n = len(key)
        for j, g in enumerate(groups[1:], start=1):
            self._parts[tuple(g)] = batch.rows(j * n, (j + 1) * n)
        return batch.rows(0, n)

    def clear(self) -> None:
        """Release the worlds drawn ahead; the last user of this thread's bulk arrays releases them too
        (:func:`shared_buffers`)."""
        self._parts.clear()
        pool = getattr(_THREAD, "pool", None)
        if pool is not None:
            pool.leave(self)
