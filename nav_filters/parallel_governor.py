"""Parallel or serial row kernels, chosen by measuring both: :class:`ParallelGovernor`.

The row kernels of the package (:func:`~nav_filters.kernels.row_kernel`) run their parallel variant from
:data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows on. A parallel launch waits for its slowest thread: on a
machine where another process keeps one core busy, the thread that shares that core makes every launch several
times slower than the serial variant (measured on 2 cores: the native vector env at B = 1024 fell from 43k to
8.5k env-steps/s with one competing CPU-bound process). Both variants give the same bits (a row's arithmetic does
not depend on the chunking), so which one runs is a question of wall time only, and it changes with the load of
the machine. The governor answers it for a repeated unit of work (one vector-env step): it runs the unit in the
mode that has been faster and now and then runs one unit in the other mode (a *probe*) to see whether that has
become the faster one.
"""
from __future__ import annotations

import time
from collections import deque
from contextlib import contextmanager

from .kernels import PARALLEL_MIN_BATCH, serial_rows

POLICIES = ("auto", "always", "never")
"""``parallel_kernels`` policies: ``'auto'`` (measure and pick), ``'always'`` (parallel from
:data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows, the package's fixed rule) and ``'never'`` (serial)."""

MODES = ("parallel", "serial")


def check_policy(policy, name: str = "parallel_kernels") -> str:
    """``policy`` if it is one of :data:`POLICIES`, else a ``ValueError`` naming the argument ``name``."""
    if not isinstance(policy, str) or policy not in POLICIES:
        raise ValueError(f"{name} must be one of {', '.join(repr(p) for p in POLICIES)}, got {policy!r}")
    return policy


def _median(samples) -> float:
    s = sorted(samples)
    k = len(s)
    return s[k // 2] if k % 2 else 0.5 * (s[k // 2 - 1] + s[k // 2])


class _Unit:
    """The handle of one governed unit (:meth:`ParallelGovernor.unit`): its ``mode``, and ``comparable``, which
    the caller sets to False when the unit did other work than usual (a vector-env step with automatic resets)."""

    __slots__ = ("mode", "comparable")

    def __init__(self, mode: str):
        self.mode = mode
        self.comparable = True


class ParallelGovernor:
    """Runs a repeated unit of work with the row kernels parallel or serial, whichever has been faster.

    Policy ``'auto'``: each mode keeps the wall times of its last ``window`` comparable units; the governor
    runs the *preferred* mode and now and then runs one unit in the other mode (a *probe*). The preferred mode
    changes only on fresh evidence: ``confirmations`` probes in a row, each faster than the preferred mode's
    median by more than ``margin`` (hysteresis). A median over ``window`` samples does not move for one slow or
    fast unit, and the other mode's older samples never switch the mode by themselves: where the machine's
    load changes, they are out of date (measured: on an idle machine a burst of slow parallel steps made the
    parallel median exceed the serial one of the start, and a rule that compared the two switched to a serial
    mode that was then twice as slow).

    * Start: the first unit in each mode is a warm-up (numba loads each kernel variant from its cache at its
      first call) and is not recorded; then the modes alternate until each has ``start_samples`` samples, and
      the faster one is preferred (parallel until then, the package's default).
    * Probes: in steady state the interval is ``probe_every`` units stretched by the other mode's slowdown (the
      ratio of the medians, at most ``max_stretch``), which keeps the probes' cost near ``1 / probe_every`` of a
      unit's time however slow the other mode is. A probe that wins is confirmed at the next unit. A probe
      that loses replaces the other mode's samples (the latest word on it) and doubles the interval up to the
      steady one. After a switch the first probe of the mode left comes after ``probe_min`` units, so a burst
      of load that ends soon costs a few units in the slower mode, not a whole interval.
    * Early probes: where the preferred mode's median rises above the other mode's (older) median by the
      margin, the other mode is probed at the next unit, so a lasting change of load switches the mode within
      ``window // 2 + 1 + confirmations`` units.
    * Units marked not comparable (``unit.comparable = False``: a step that also reset episodes, whose time
      holds a world generation) enter neither median; their times are kept apart (:attr:`excluded`). A probe
      that falls on one is repeated at the next unit. Where more than ``2 window`` units in a row are marked so
      (one-step episodes: every step resets), they are the usual unit and enter the medians.

    ``'always'`` runs every unit with the package's fixed rule (parallel from
    :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows) and ``'never'`` every unit serial
    (:func:`~nav_filters.kernels.serial_rows`); neither measures anything. ``'auto'`` is inactive (does nothing,
    measures nothing: the fixed rule) below :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` rows, where the
    kernels are serial anyway, and where numba runs on one thread (nothing to choose).

    Parameters
    ----------
    policy : {'auto', 'always', 'never'}
        How the mode is chosen (above).
    batch_size : int, optional
        Rows of the unit's row kernels; below :data:`~nav_filters.kernels.PARALLEL_MIN_BATCH` ``'auto'`` is
        inactive. None: assume at least that many.
    probe_every : int, default 32
        Units between probes of the other mode (before the stretch), >= 2.
    window : int, default 5
        Samples per mode in the median (the last ones), >= 1.
    start_samples : int, default 3
        Samples of each mode before the first decision, in [1, window].
    margin : float, default 0.05
        Relative hysteresis: the other mode must be faster by this fraction of the preferred median, in [0, 1).
    max_stretch : float, default 8
        Largest stretch of the probe interval, >= 1.
    probe_min : int, default 4
        Units from a switch to the first probe of the mode left, >= 1.
    confirmations : int, default 2
        Winning probes in a row that switch the mode, >= 1.
    threads : int, optional
        Numba's thread count; default ``numba.get_num_threads()`` (asked only where ``'auto'`` could be active:
        it starts numba's threading layer).
    clock : callable, default ``time.perf_counter``
        Wall clock [s].

    Attributes
    ----------
    active : bool
        Whether ``'auto'`` measures and decides (False: a fixed mode).
    preferred : str
        ``'parallel'`` or ``'serial'``: the mode of the non-probe units.
    samples : dict
        Mode -> ``deque`` of the last ``window`` comparable wall times [s].
    excluded : dict
        Mode -> ``deque`` of the last ``window`` wall times [s] of the units marked not comparable.
    units, probes, switches : int
        Units run, probe units among them, and changes of the preferred mode.
    """

    def __init__(self, policy: str = "auto", batch_size: int | None = None, probe_every: int = 32,
                 window: int = 5, start_samples: int = 3, margin: float = 0.05, max_stretch: float = 8.0,
                 probe_min: int = 4, confirmations: int = 2, threads: int | None = None, clock=time.perf_counter):
        self.policy = check_policy(policy)
        if isinstance(probe_every, bool) or not isinstance(probe_every, int) or probe_every < 2:
            raise ValueError(f"probe_every must be an int >= 2 (units between probes), got {probe_every!r}")
        if isinstance(window, bool) or not isinstance(window, int) or window < 1:
            raise ValueError(f"window must be an int >= 1 (samples per mode), got {window!r}")
        if isinstance(start_samples, bool) or not isinstance(start_samples, int) \
                or not 1 <= start_samples <= window:
            raise ValueError(f"start_samples must be an int in [1, window = {window}], got {start_samples!r}")
        if not 0.0 <= margin < 1.0:
            raise ValueError(f"margin must be in [0, 1) (relative hysteresis), got {margin!r}")
        if not max_stretch >= 1.0:
            raise ValueError(f"max_stretch must be >= 1, got {max_stretch!r}")
        if isinstance(probe_min, bool) or not isinstance(probe_min, int) or probe_min < 1:
            raise ValueError(f"probe_min must be an int >= 1 (units to the first probe after a switch), got "
                             f"{probe_min!r}")
        if isinstance(confirmations, bool) or not isinstance(confirmations, int) or confirmations < 1:
            raise ValueError(f"confirmations must be an int >= 1 (winning probes in a row to switch), got "
                             f"{confirmations!r}")
        self.probe_min, self.confirmations = probe_min, confirmations
        self.probe_every, self.window, self.start_samples = probe_every, window, start_samples
        self.margin, self.max_stretch, self.clock = float(margin), float(max_stretch), clock
        self.batch_size = batch_size
        could = policy == "auto" and (batch_size is None or batch_size >= PARALLEL_MIN_BATCH)
        if could and threads is None:
            import numba
            threads = numba.get_num_threads()
        self.threads = threads
        self.active = bool(could and threads > 1)
        self.preferred = "serial" if policy == "never" else "parallel"
        self.samples = {m: deque(maxlen=window) for m in MODES}
        self.excluded = {m: deque(maxlen=window) for m in MODES}
        self._warm = set()
        self._until_probe = 0
        self._gap = probe_every  # the current interval between probes (shortened after a switch, then doubled)
        self._wins = 0  # probes in a row that beat the preferred mode
        self._started = False  # the start's samples are in (a lost probe later leaves the other mode one sample)
        self._confirm = False
        self._apart = 0  # consecutive units marked not comparable
        self.units = self.probes = self.switches = 0

    @staticmethod
    def _other(mode: str) -> str:
        return "serial" if mode == "parallel" else "parallel"

    def _starting(self) -> bool:
        if self._started:
            return False
        self._started = all(len(self.samples[m]) >= self.start_samples for m in MODES)
        return not self._started

    def next_mode(self) -> str:
        """The mode the next unit runs in (no side effect)."""
        if not self.active:
            return self.preferred
        if self._starting():
            for m in MODES:  # warm-ups first, then the mode with fewer samples (parallel on a tie)
                if m not in self._warm:
                    return m
            return min(MODES, key=lambda m: len(self.samples[m]))
        if self._confirm or self._until_probe <= 0:
            return self._other(self.preferred)
        return self.preferred

    def record(self, mode: str, seconds: float, comparable: bool = True) -> None:
        """Take the wall time ``seconds`` [s] of a unit run in ``mode`` (what :meth:`unit` does on exit):
        decide the preferred mode and schedule the next probe. Nothing where the governor is inactive."""
        if not self.active:
            return
        self.units += 1
        if mode not in self._warm:  # a warm-up: kernel loading, first touch of scratch
            self._warm.add(mode)
            return
        starting = self._starting()
        probe = not starting and mode != self.preferred
        self.probes += probe
        self._apart = 0 if comparable else self._apart + 1
        if not comparable and self._apart <= 2 * self.window:
            self.excluded[mode].append(float(seconds))
            if not probe and not self._confirm:
                self._until_probe -= 1  # (a due probe that fell here stays due: the next unit probes)
            return
        if starting:
            self.samples[mode].append(float(seconds))
            if not self._starting():  # the start's last sample: the first decision, on samples of the same time
                if self._beats(self._other(self.preferred)):
                    self._switch()
                self._gap = self._until_probe = self._interval()
            return
        if probe:
            self._probed(float(seconds))
            return
        self.samples[mode].append(float(seconds))
        self._until_probe -= 1
        if self._until_probe > 0 and not self._confirm and self._beats(self._other(mode)):
            self._until_probe = 0  # the other mode's (older) median is lower now: measure it afresh at once

    def _probed(self, seconds: float) -> None:
        """A probe's time: it replaces the other mode's older samples where it loses (it is the latest word on that
        mode); :attr:`confirmations` wins in a row switch the mode; else back to the schedule, its gap doubled."""
        other = self._other(self.preferred)
        if seconds < (1.0 - self.margin) * _median(self.samples[self.preferred]):
            self.samples[other].append(seconds)
            self._wins += 1
            self._confirm = self._wins < self.confirmations
            if not self._confirm:
                self._switch()
                self._gap = self._until_probe = min(self.probe_min, self._interval())
            return
        self.samples[other].clear()
        self.samples[other].append(seconds)
        self._wins, self._confirm = 0, False
        self._gap = min(2 * self._gap, self._interval())
        self._until_probe = self._gap

    def _beats(self, mode: str) -> bool:
        """Whether ``mode``'s median is lower than the other mode's by more than the margin."""
        return _median(self.samples[mode]) < (1.0 - self.margin) * _median(self.samples[self._other(mode)])

    def _switch(self) -> None:
        self.preferred = self._other(self.preferred)
        self.switches += 1
        self._wins, self._confirm = 0, False

    def _interval(self) -> int:
        """Units between probes in steady state: ``probe_every`` x the other mode's slowdown, clipped to
        [1, max_stretch]."""
        ratio = _median(self.samples[self._other(self.preferred)]) / max(_median(self.samples[self.preferred]),
                                                                        1e-12)
        return max(1, round(self.probe_every * min(self.max_stretch, max(1.0, ratio))))

    @contextmanager
    def unit(self):
        """Context manager around one unit of work: runs it in :meth:`next_mode` (``'serial'``: inside
        :func:`~nav_filters.kernels.serial_rows`), times it with ``clock`` and :meth:`record` s the time on a
        normal exit (not when the body raises). Yields the unit's handle: set ``handle.comparable = False`` when
        the unit did extra work. Inactive: the fixed mode, no timing."""
        handle = _Unit(self.next_mode())
        with serial_rows(handle.mode == "serial"):
            if not self.active:
                yield handle
                return
            t0 = self.clock()
            yield handle
            dt = self.clock() - t0
        self.record(handle.mode, dt, handle.comparable)

    @contextmanager
    def preferred_mode(self):
        """Context manager: run work that is not a unit (a reset) in the preferred mode, untimed."""
        with serial_rows(self.preferred == "serial"):
            yield

    def summary(self) -> dict:
        """Policy, whether active, the preferred mode, counts and the medians [s] of each mode (None: none)."""
        med = {m: (_median(self.samples[m]) if self.samples[m] else None) for m in MODES}
        return {"policy": self.policy, "active": self.active, "preferred": self.preferred, "units": self.units,
                "probes": self.probes, "switches": self.switches, "median_s": med}
