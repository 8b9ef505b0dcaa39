"""How much of an env step runs inside navgym's compiled kernels, and how much is the Python around them
(``bench_envs.py --kernel-time``).

For the timed steps every numba dispatcher bound to a name in a module of ``earth``, ``nav_filters`` or ``envs``
is replaced by a wrapper that adds the wall time of each call (numba's dispatch and argument unboxing included)
to the kernel's total; what the step takes beyond the kernels is the Python between them (argument checks, small
numpy calls, allocations, objects). Kernels called from other kernels run inside their caller's time; a dispatcher
kept elsewhere than under a module name (an attribute of an object) is not seen. The wrappers' own cost, about
a quarter of a microsecond per call, is counted in the kernels' share.
"""
from __future__ import annotations

import sys
import time
from collections import defaultdict
from contextlib import contextmanager

from stage_timing import timed  # (this script's folder)

PACKAGES = ("earth", "nav_filters", "envs")


def _label(dispatcher) -> str:
    f = dispatcher.py_func
    return f"{f.__module__.rsplit('.', 1)[-1]}.{f.__qualname__}"


@contextmanager
def timed_kernels(totals: dict, calls: dict):
    """Within the block, every call of a navgym kernel through a module name adds its wall time [s] to
    ``totals[label]`` and 1 to ``calls[label]`` (label: ``module.function``)."""
    from numba.core.dispatcher import Dispatcher

    undo = []
    for name, mod in list(sys.modules.items()):
        if name.split(".")[0] not in PACKAGES or mod is None:
            continue
        for attr, value in list(vars(mod).items()):
            if isinstance(value, Dispatcher):
                undo.append((mod, attr, value))
                setattr(mod, attr, timed(value, totals, _label(value), counts=calls))
    try:
        yield
    finally:
        for mod, attr, value in undo:
            setattr(mod, attr, value)


def kernel_share(env, actions):
    """Step ``env`` with each of ``actions`` twice: untimed, then with the kernels timed. Returns (step wall
    time [s] per step, {label: (seconds per step, calls per step)})."""
    for a in actions:  # as many steps untimed first (every code path run once)
        env.step(a)
    totals, calls = defaultdict(float), defaultdict(int)
    n = len(actions)
    with timed_kernels(totals, calls):
        t0 = time.perf_counter()
        for a in actions:
            env.step(a)
        step = (time.perf_counter() - t0) / n
    return step, {k: (v / n, calls[k] / n) for k, v in totals.items()}


def print_kernel_share(label, B, step, per_kernel, top=12):
    """The table of one batch size (times per batched step)."""
    inside = sum(t for t, _ in per_kernel.values())
    ncalls = sum(c for _, c in per_kernel.values())
    us = 1e6
    print(f"\n{label}, B = {B}: step {step * us:.0f} us; inside the kernels {inside * us:.0f} us "
          f"({100 * inside / step:.0f}%, {ncalls:.0f} calls); the Python around them {(step - inside) * us:.0f} us "
          f"({100 * (step - inside) / step:.0f}%)")
    print(f"  {'kernel':52s} {'us/step':>10s} {'calls/step':>11s}")
    for name, (t, c) in sorted(per_kernel.items(), key=lambda kv: -kv[1][0])[:top]:
        print(f"  {name:52s} {t * us:10.1f} {c:11.1f}")
