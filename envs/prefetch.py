"""Draw the worlds of coming episodes ahead, in a background process at the lowest CPU priority.

A reset of a simulated env draws the whole episode's world (trajectory, IMU at 100 Hz, GNSS): in PPO at
n_envs 16-256 the automatic resets took half of the vector env's time (``benchmarks/bench_training.py``,
``resets``). The world is a function of the config and the seeds only (:func:`envs.prepared.prepare_world`)
and a row's next seeds are known ahead (its own generator), so :class:`WorldPrefetcher` draws them in
another process while the env steps and PPO's gradient epochs run; a reset whose world is ready takes it
(the same bits as drawing it then).

The worker runs at ``nice`` 19: it takes the CPU the training leaves idle (during PPO's single-threaded
gradient epochs one of two cores is) and yields it to everything else. It is started with the ``spawn``
method (a fork of a process whose numba/OpenMP threads run is unsafe) and loads navgym's compiled kernels
from numba's cache; it holds up to ``depth`` prepared worlds, about a quarter of a world each
(:class:`~envs.prepared.PreparedWorld`; ~0.5 MB per row of a 60 s episode at 100 Hz).

A request no longer wanted (the rows reset in another grouping than the one prefetched, e.g. after an
early termination; or a new ``reset(seed=...)``) is dropped: the worker skips it if it has not started it,
and its result is discarded otherwise. A failed or dead worker never changes a result: the reset draws
the world itself (and a dead worker is reported once with a warning).
"""
from __future__ import annotations

import multiprocessing as mp
import os
import queue
import warnings
from collections import deque

__all__ = ["WorldPrefetcher"]

_POLL_S = 1.0
"""Seconds between liveness checks of the worker while a reset waits for its world."""


def _serve(config, requests, results, generation) -> None:
    """The worker's loop: ``(gen, seeds)`` from ``requests`` -> ``(gen, seeds, PreparedWorld or error text)`` on
    ``results``; a request whose ``gen`` is older than ``generation.value`` (cancelled) is skipped."""
    try:
        os.nice(19)
    except OSError:  # pragma: no cover - a platform without nice
        pass
    from .prepared import prepare_world
    results.put(("ready", (), None))
    while True:
        msg = requests.get()
        if msg is None:
            return
        gen, seeds = msg
        if gen < generation.value:
            continue
        try:
            out = prepare_world(config, seeds)
        except Exception as exc:  # the reset draws this world itself and raises the error there
            out = f"{type(exc).__name__}: {exc}"
        results.put((gen, tuple(seeds), out))


class WorldPrefetcher:
    """Prepared worlds of an :class:`~envs.config.EnvConfig` drawn ahead in one background process.

    Parameters
    ----------
    config : EnvConfig
        The env's config (pickled to the worker).
    depth : int
        Most requests in flight (each a batch of rows' next worlds); >= 1.

    Usage (what :class:`envs.vector_env.GnssInsTuningVectorEnv` does with ``prefetch_worlds=depth``)::

        pf = WorldPrefetcher(config, depth=2)
        pf.request(next_seeds)                 # as soon as the seeds of a coming reset are known
        prepared = pf.take(seeds)              # at that reset: its PreparedWorld, or None (draw it yourself)
        pf.close()
    """

    def __init__(self, config, depth: int):
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
            raise ValueError(f"depth must be an int >= 1, got {depth!r}")
        self.depth = depth
        ctx = mp.get_context("spawn")
        self._requests = ctx.Queue()
        self._results = ctx.Queue()
        self._generation = ctx.Value("l", 0)
        self._gen = 0
        self._pending: deque[tuple] = deque()  # seeds of the live requests, in request order
        self._proc = ctx.Process(target=_serve, args=(config, self._requests, self._results, self._generation),
                                 daemon=True, name="navgym-world-prefetch")
        self._proc.start()
        self._dead = False
        self._ready = False  # the worker has loaded navgym (until then a reset draws its world itself)
        self.hits = 0
        """Resets that took a prefetched world."""
        self.misses = 0
        """Resets that drew their world themselves (nothing or something else prefetched, worker not ready)."""

    @property
    def in_flight(self) -> int:
        """Live requests (not yet taken or cancelled)."""
        return len(self._pending)

    def wait_ready(self, timeout_s: float = 60.0) -> bool:
        """Wait up to ``timeout_s`` for the worker to finish starting; whether it has."""
        if not self._ready and self._proc is not None and not self._dead:
            try:
                self._ready = self._results.get(timeout=timeout_s)[0] == "ready"
            except queue.Empty:
                pass
        return self._ready

    def request(self, seeds) -> bool:
        """Ask for the prepared world of ``seeds`` (B ints); False (nothing asked) when ``depth`` requests are in
        flight or the worker is gone."""
        if self._dead or len(self._pending) >= self.depth:
            return False
        key = tuple(int(s) for s in seeds)
        self._requests.put((self._gen, key))
        self._pending.append(key)
        return True

    def cancel(self) -> None:
        """Drop every live request (the worker skips those it has not started)."""
        if self._pending:
            self._pending.clear()
            self._gen += 1
            with self._generation.get_lock():
                self._generation.value = self._gen

    def take(self, seeds):
        """The :class:`~envs.prepared.PreparedWorld` of ``seeds`` if it is the oldest live request (waiting for
        it if it is not ready), else None after cancelling every live request (they no longer match the
        resets to come). None too when the worker has not finished starting (navgym's import, a few seconds),
        failed on this world or is gone."""
        key = tuple(int(s) for s in seeds)
        if not self._ready and self._pending and self._proc is not None:
            try:  # the worker's first message; until it comes, waiting would cost its start-up time
                self._ready = self._results.get_nowait()[0] == "ready"
            except queue.Empty:
                pass
        if not self._ready or not self._pending or self._pending[0] != key:
            self.misses += 1
            self.cancel()
            return None
        self._pending.popleft()
        while True:
            try:
                gen, got, out = self._results.get(timeout=_POLL_S)
            except queue.Empty:
                if not self._proc.is_alive():
                    self._gone()
                    return None
                continue
            if gen == self._gen and got == key:
                break  # older results are of cancelled requests: dropped
        if isinstance(out, str):  # the worker's error: the caller draws the world and raises it there
            self.misses += 1
            return None
        self.hits += 1
        return out

    def _gone(self) -> None:
        self._dead = True
        self._pending.clear()
        warnings.warn(f"envs.prefetch: the world prefetch process exited (code {self._proc.exitcode}); the env "
                      f"draws its worlds at reset from now on (same results, no prefetch)", RuntimeWarning,
                      stacklevel=3)

    def close(self) -> None:
        """Stop the worker (idempotent)."""
        if self._proc is None:
            return
        self.cancel()
        try:
            self._requests.put(None)
        except (OSError, ValueError):  # pragma: no cover - queue already closed
            pass
        self._proc.join(timeout=0.2)  # idle: it has exited; busy: nothing it holds is wanted any more
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=2.0)
        for q in (self._requests, self._results):
            q.close()
            q.cancel_join_thread()
        self._proc = None
        self._dead = True

    def __del__(self):
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass
