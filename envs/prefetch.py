"""Draw the worlds of coming episodes ahead, in a background process at the lowest CPU priority.

A reset of a simulated env draws the whole episode's world (trajectory, IMU at 100 Hz, GNSS): in PPO at
n_envs 16-256 the automatic resets took half of the vector env's time (``benchmarks/bench_training.py``,
``resets``). The world is a function of the config and the seeds only (:func:`envs.prepared.prepare_world`)
and a row's next seeds are known ahead (its own generator), so :class:`WorldPrefetcher` draws them in
another process while the env steps and PPO's gradient epochs run; a reset whose world is ready takes it
(the same bits as drawing it then).

The worker runs at ``nice`` 19: it takes the CPU the training leaves idle (during PPO's single-threaded
gradient epochs one of two cores is) and yields it to everything else. It is a fresh interpreter
(``python -c``, not :mod:`multiprocessing`: that would re-import the user's main script, which then needs an
``if __name__ == "__main__"`` guard, and a fork of a process whose numba/OpenMP threads run is unsafe) that
imports only navgym's envs and loads the compiled kernels from numba's cache, a few seconds during which the
resets draw their own worlds. It talks pickles over its stdin / stdout (the results as pickle protocol 5 with
out-of-band buffers: the arrays' bytes go through the pipe once, into receive buffers reused from one reset
to the next, which the reset copies out), and exits when its stdin closes (this process closing it or
ending). It ignores SIGINT and runs in a session of its own: a Ctrl-C reaches the main process only, which
decides what to say (no traceback from the worker). It holds up to ``depth`` prepared worlds, about a fifth of a world each
(:class:`~envs.prepared.PreparedWorld`; ~0.4 MB per row of a 60 s episode at 100 Hz). POSIX only (it polls
the pipe with ``select``).

A request no longer wanted (the rows reset in another grouping than the one prefetched, e.g. after an
early termination; or a new ``reset(seed=...)``) is dropped: the worker skips it if it has not started it,
and its result is discarded otherwise. A failed or dead worker never changes a result: the reset draws
the world itself (and a dead worker is reported once with a warning).
"""
from __future__ import annotations

import os
import pickle
import queue
import select
import struct
import subprocess
import sys
import threading
import warnings
from collections import deque
from dataclasses import replace
from pathlib import Path

__all__ = ["WorldPrefetcher"]

_ROOT = str(Path(__file__).resolve().parents[1])
"""The folder holding navgym's top-level packages (the worker imports ``envs`` from there)."""


def _frame(obj) -> list:
    """``obj`` as the parts of one message: an 8-byte length, the pickled (pickle length, buffer sizes), the
    pickle (protocol 5) and its out-of-band buffers, the arrays' bytes as they are (no copy made here)."""
    bufs = []
    head = pickle.dumps(obj, protocol=5, buffer_callback=bufs.append)
    raws = [b.raw() for b in bufs]
    meta = pickle.dumps((len(head), [r.nbytes for r in raws]))
    return [struct.pack("<Q", len(meta)), meta, head, *raws]


def _read_exact(f, n: int, into=None) -> memoryview:
    """``n`` bytes from the unbuffered stream ``f`` (into the writable buffer ``into`` if given);
    ``EOFError`` at its end."""
    buf = memoryview(bytearray(n) if into is None else into).cast("B")
    got = 0
    while got < n:
        k = f.readinto(buf[got:])
        if not k:
            raise EOFError("the world prefetch process closed its output")
        got += k
    return buf


def _read_frame(f, pool: list | None = None):
    """One message of :func:`_frame` from ``f``: each array's bytes read straight into the memory it keeps,
    fresh memory, or with ``pool`` (a list of bytearrays, grown as needed) the pool's buffers, reused from one
    message to the next: the arrays are then valid until the next read into the same pool. (Fresh memory costs a
    page fault per 4 KB at first touch: on this project's 2-core VMs 120 ms for a 99 MB world of 256 rows,
    ten times the copy into memory touched before.)"""
    (n,) = struct.unpack("<Q", _read_exact(f, 8))
    head_len, sizes = pickle.loads(_read_exact(f, n))
    head = _read_exact(f, head_len)
    bufs = []
    for i, size in enumerate(sizes):
        into = None
        if pool is not None:
            if i == len(pool):
                pool.append(bytearray(size))
            elif len(pool[i]) < size:
                pool[i] = bytearray(size)
            into = memoryview(pool[i])[:size]
        bufs.append(_read_exact(f, size, into))
    return pickle.loads(head, buffers=bufs)


def _worker() -> None:  # pragma: no cover - runs in the worker process (covered by tests/envs/test_prefetch.py)
    """The worker process: the config, then ``("req", gen, seeds)`` / ``("cancel", gen)`` on stdin; on stdout
    ``("ready",)`` once loaded, then per request not cancelled before it started ``("done", gen, seeds,
    PreparedWorld without its arrays, True)`` followed by the arrays dict, or ``("done", gen, seeds, error
    text, False)``. Ends at end of stdin."""
    try:
        os.nice(19)
    except OSError:
        pass
    fin, fout = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing else may write into the result stream
    config = pickle.load(fin)
    from .prepared import prepare_world
    os.chdir(sys.argv[1])  # the caller's folder (navgym was imported from its own): relative dataset spec paths
    todo: queue.Queue = queue.Queue()
    latest = [0]

    def read():  # requests and cancellations as they come, while a world is being drawn
        try:
            while True:
                msg = pickle.load(fin)
                if msg[0] == "cancel":
                    latest[0] = msg[1]
                else:
                    todo.put(msg)
        except (EOFError, OSError, pickle.UnpicklingError):
            todo.put(None)

    threading.Thread(target=read, daemon=True).start()
    out: queue.Queue = queue.Queue()

    def write():  # results leave while the next world is drawn (the main process reads at its resets)
        try:
            while True:
                for obj in out.get():
                    for part in _frame(obj):
                        fout.write(part)
                fout.flush()
        except OSError:  # the main process is gone (closed its end): nothing to report, nobody to read it
            os._exit(0)

    threading.Thread(target=write, daemon=True).start()
    out.put([("ready",)])
    while True:
        msg = todo.get()
        if msg is None:
            os._exit(0)
        _, gen, seeds = msg
        if gen < latest[0]:
            continue
        try:
            res = prepare_world(config, seeds)
        except Exception as exc:  # the reset draws this world itself and raises the error there
            out.put([("done", gen, tuple(seeds), f"{type(exc).__name__}: {exc}", False)])
        else:  # the world arrays in a frame of their own (read into the main process's reused buffers)
            out.put([("done", gen, tuple(seeds), replace(res, arrays={}), True), res.arrays])


class WorldPrefetcher:
    """Prepared worlds of an :class:`~envs.config.EnvConfig` drawn ahead in one background process.

    Parameters
    ----------
    config : EnvConfig
        The env's config (pickled to the worker).
    depth : int
        Most requests in flight (each a batch of rows' next worlds); >= 1.

    Attributes
    ----------
    hits : resets that took a prefetched world.
    misses : resets that drew their world themselves (nothing or something else prefetched, the worker not
        yet started or gone).

    Usage (what :class:`envs.vector_env.GnssInsTuningVectorEnv` does with ``prefetch_worlds=depth``)::

        pf = WorldPrefetcher(config, depth=2)
        pf.request(next_seeds)                 # as soon as the seeds of a coming reset are known
        prepared = pf.take(seeds)              # at that reset: its PreparedWorld, or None (draw it yourself)
        pf.close()
    """

    def __init__(self, config, depth: int):
        if isinstance(depth, bool) or not isinstance(depth, int) or depth < 1:
            raise ValueError(f"depth must be an int >= 1, got {depth!r}")
        if os.name != "posix":
            raise ValueError("prefetch_worlds needs a POSIX system (the worker's pipe is polled with select)")
        self.depth = depth
        try:
            blob = pickle.dumps(config, protocol=pickle.HIGHEST_PROTOCOL)
        except Exception as exc:
            raise ValueError(f"prefetch_worlds: the env's config cannot be sent to the worker process ({exc}); "
                             f"use prefetch_worlds=0 with this scenario") from exc
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([_ROOT] + [p for p in [os.environ.get("PYTHONPATH")] if p]))
        # Ctrl-C is the main process's to handle: the worker runs in a session of its own (the terminal's SIGINT
        # goes to the foreground process group only) and ignores SIGINT from its first line (a traceback per
        # worker otherwise); it ends when the main process closes its input or dies
        cmd = [sys.executable, "-c", "import signal; signal.signal(signal.SIGINT, signal.SIG_IGN); "
               "from envs.prefetch import _worker; _worker()", os.getcwd()]
        self._proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env, cwd=_ROOT, bufsize=0,
                                      start_new_session=True)
        try:  # Linux: a 1 MB pipe instead of 64 KB, fewer wake-ups of the (nice 19) writer per world
            import fcntl
            fcntl.fcntl(self._proc.stdout.fileno(), getattr(fcntl, "F_SETPIPE_SZ", 1031), 1 << 20)
        except (ImportError, OSError):
            pass
        self._gen = 0
        self._pending: deque[tuple] = deque()  # seeds of the live requests, in request order
        self._ready = False  # the worker has loaded navgym (until then a reset draws its world itself)
        self._dead = False
        self._warned_error = False
        self.hits = 0
        self.misses = 0
        self._pool: list = []  # receive buffers of the world arrays, reused (see _read_frame)
        self._send_bytes(blob)

    # ------------------------------------------------------------------ pipe
    def _send(self, msg) -> bool:
        return self._send_bytes(pickle.dumps(msg, protocol=pickle.HIGHEST_PROTOCOL))

    def _send_bytes(self, blob: bytes) -> bool:
        try:
            self._proc.stdin.write(blob)
            self._proc.stdin.flush()
            return True
        except (BrokenPipeError, OSError, ValueError):
            self._gone()
            return False

    def _recv(self):
        """The worker's next message (blocking), a result with its arrays (read into the reused buffers); None
        when the worker is gone."""
        try:
            msg = _read_frame(self._proc.stdout)
            if msg[0] == "done" and msg[4]:
                arrays = _read_frame(self._proc.stdout, self._pool)
                msg = msg[:3] + (replace(msg[3], arrays=arrays),)
            return msg
        except (EOFError, OSError, ValueError, struct.error, pickle.UnpicklingError):
            self._gone()
            return None

    def _poll_ready(self, timeout_s: float) -> bool:
        if not self._ready and not self._dead:
            readable, _, _ = select.select([self._proc.stdout], [], [], timeout_s)
            if readable:
                msg = self._recv()
                self._ready = msg is not None and msg[0] == "ready"
        return self._ready

    # ------------------------------------------------------------------ API
    @property
    def in_flight(self) -> int:
        """Live requests (not yet taken or cancelled)."""
        return len(self._pending)

    def wait_ready(self, timeout_s: float = 60.0) -> bool:
        """Wait up to ``timeout_s`` for the worker to finish starting; whether it has."""
        return self._poll_ready(timeout_s)

    def request(self, seeds) -> bool:
        """Ask for the prepared world of ``seeds`` (B ints); False (nothing asked) when ``depth`` requests are in
        flight or the worker is gone."""
        if self._dead or len(self._pending) >= self.depth:
            return False
        key = tuple(int(s) for s in seeds)
        if not self._send(("req", self._gen, key)):
            return False
        self._pending.append(key)
        return True

    def cancel(self) -> None:
        """Drop every live request (the worker skips those it has not started)."""
        if self._pending:
            self._pending.clear()
            self._gen += 1
            if not self._dead:
                self._send(("cancel", self._gen))

    def take(self, seeds):
        """The :class:`~envs.prepared.PreparedWorld` of ``seeds`` if it is the oldest live request (waiting for
        it if it is not ready), else None after cancelling every live request (they no longer match the
        resets to come). None too when the worker has not finished starting (navgym's import, a few seconds),
        failed on this world or is gone. Its ``arrays`` live in buffers the next ``take`` reuses: copy them
        before (as :meth:`envs.core.TuningCore.reset_rows` does)."""
        key = tuple(int(s) for s in seeds)
        if not self._dead and self._pending:
            self._poll_ready(0.0)  # until the worker is up, waiting would cost its start-up time
        if self._dead or not self._ready or not self._pending or self._pending[0] != key:
            self.misses += 1
            self.cancel()
            return None
        self._pending.popleft()
        while True:
            msg = self._recv()
            if msg is None:
                self.misses += 1
                return None
            if msg[0] == "done" and msg[1] == self._gen and msg[2] == key:
                break  # older results are of cancelled requests: dropped
        if isinstance(msg[3], str):  # the worker's error: the caller draws the world and raises it there
            self.misses += 1
            if not self._warned_error:
                self._warned_error = True
                warnings.warn(f"envs.prefetch: the world prefetch process failed to draw the world of seeds "
                              f"{list(key)[:4]}... ({msg[3]}); the resets draw such worlds themselves", RuntimeWarning,
                              stacklevel=3)
            return None
        self.hits += 1
        return msg[3]

    def _gone(self) -> None:
        if self._dead:
            return
        self._dead = True
        self._pending.clear()
        if self._proc is not None:
            code = self._proc.poll()
            warnings.warn(f"envs.prefetch: the world prefetch process exited (code {code}); the env draws its "
                          f"worlds at reset from now on (same results, no prefetch)", RuntimeWarning, stacklevel=4)

    def close(self) -> None:
        """Stop the worker (idempotent)."""
        proc, self._proc = self._proc, None
        self._dead = True
        if proc is None:
            return
        try:
            proc.stdin.close()  # the worker exits at end of its input
        except OSError:  # pragma: no cover - already broken
            pass
        try:
            proc.wait(timeout=0.2)  # idle: it has exited; busy: nothing it holds is wanted any more
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5.0)
        proc.stdout.close()

    def __del__(self):
        try:
            self.close()
        except Exception:  # pragma: no cover - interpreter shutdown
            pass
