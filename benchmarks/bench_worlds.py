"""World generation time (:func:`envs.sim.world.generate_world`, what an env's reset pays) per row, by stage.

For each scenario and batch size B the world is drawn ``--reps`` times (fresh seeds each time, after one
untimed draw that loads the compiled kernels) and the median is printed per row: ``ms/row`` of the whole
world, the IMU samples generated per second (B x N / wall time, the figure of the issue's target), and the
split by stage (ms per row and share of the world's time):

* ``trajectory``: the random drives and :func:`envs.sim.trajectory.generate_truth` (truth and ideal IMU);
* ``imu``: :func:`envs.sim.imu.simulate_imu` (sensor errors, vibration, IMU events);
* ``geometry``: the constellation geometry of :mod:`envs.sim.gnss_stages` (``sky_geometry``,
  ``allocate_channels``, ``channel_ranging``);
* ``events``: the GNSS degradations (``canyon_and_bursts``, ``random_events``, ``scheduled_events``) and the
  world's IMU event bits;
* ``receiver``: the receiver errors (``channel_noise``, ``receiver_errors``);
* ``rest``: the world's time less the stages (row generators, input checks, the GNSS assembly, epochs,
  initial estimate, odometer).

From :data:`envs.sim.world.OVERLAP_ROWS` rows on, the world runs its IMU stage on a thread of its own while it
runs the GNSS stages, so their times overlap: ``ms/row`` and ``samples/s`` are the world as an env pays it, and
the split comes from as many more draws of the same seeds with the stages in turn (their total is the
``in_turn`` row of ``--compare``; the shares are of it).

The stages are timed by wrapping the names their callers look up. A tree without a stage's functions (an
earlier tree of ``--compare``, before the GNSS stages existed) shows ``-`` there and counts that work in
``rest``. Wall time: on a machine shared with other jobs run ``--compare`` (side by side) rather than trusting
one figure, or ``--cpu``: the process CPU time (all threads) instead of the wall time, which swings much less
with the other jobs' load (a stage that runs rows on threads counts their CPU time, not the wall time they
overlap in).

``--cores`` adds, per cell, the cores busy in the world and in each stage: its process CPU time (all threads)
over its wall time, both read around the same calls (1.00: one core throughout; on 2 cores, 2.00 at most).

The draws go through one :class:`envs.sim.buffers.WorldBuffers` (each reuses the arrays of the one before, as an
env core's resets do; a ``--compare`` tree without it allocates them); ``--fresh`` allocates them at every draw.
They form only what an env's reset reads, as the reset does (``generate_world(..., for_reset=True)``: the truth's
position, velocity and attitude at sample 0 and the GNSS epochs only, no record of the IMU's bias; a ``--compare``
tree without that choice draws whole worlds); ``--whole`` draws whole worlds.

``--draw-floor`` adds, per cell, the cost of the IMU stage's random draws alone (:func:`draw_floor`): the
normal variates it draws, counted on the world's own streams by bit generator, drawn again as the stage draws
them (:func:`envs.sim.normals.standard_normal`; numpy's own in a tree without it) one row per thread. The stage
pays that however fast the rest of it gets.

``--compare DIR`` runs every cell twice, in this tree and in the source tree ``DIR`` (e.g. ``git worktree add
/tmp/before <commit>``), alternately in fresh processes (``--rounds`` times, median over the rounds), and
prints both with the speed-up: before/after figures measured under the same machine load. ``DIR`` need not
have this script: the cells run this file with ``NAVGYM_BENCH_ROOT=DIR``, which imports DIR's code.

Usage::

    python benchmarks/bench_worlds.py [--scenarios noise-burst urban] [--batches 1 1024] [--duration-s 60]
                                      [--reps 5] [--compare DIR] [--rounds 1] [--dtype float64] [--cpu]

Defaults: noise-burst and urban, 60 s episodes, B = 1 and 1024 (a few minutes; ``--compare`` twice that).
"""
from __future__ import annotations

import argparse
import contextlib
import inspect
import json
import os
import subprocess
import sys
import time

ROOT = os.environ.get("NAVGYM_BENCH_ROOT") or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

import numpy as np  # noqa: E402
from stage_timing import timed  # noqa: E402  (this script's folder)

STAGES = ("trajectory", "imu", "geometry", "events", "receiver", "rest")
"""Columns of the split; ``rest`` is the world's time less the timed stages."""

_WRAPPED = {
    "trajectory": (("envs.sim.world", "generate_truth"), ("envs.sim.scenarios", "Scenario.motions")),
    "imu": (("envs.sim.world", "simulate_imu"),),
    "geometry": (("envs.sim.gnss_stages", "sky_geometry"), ("envs.sim.gnss_stages", "allocate_channels"),
                 ("envs.sim.gnss_stages", "channel_ranging")),
    "events": (("envs.sim.gnss_stages", "canyon_and_bursts"), ("envs.sim.gnss_stages", "random_events"),
               ("envs.sim.gnss_stages", "scheduled_events"), ("envs.sim.world", "imu_event_bits")),
    "receiver": (("envs.sim.gnss_stages", "channel_noise"), ("envs.sim.gnss_stages", "receiver_errors")),
}
"""Stage -> the (module, name) its callers look up (wrapped to time it; ``Class.method`` on the class). None of
them calls another, so the stages do not nest."""


def _install_timers(acc, clock) -> set:
    """Wrap the functions of every stage this tree has all of; returns those stages (the others stay at 0 and
    their work counts in ``rest``)."""
    import importlib
    found = set()
    for stage, targets in _WRAPPED.items():
        owners = []
        for mod_name, name in targets:
            try:
                obj = importlib.import_module(mod_name)
            except ImportError:
                break
            *path, attr = name.split(".")
            for o in path:
                obj = getattr(obj, o)
            if not hasattr(obj, attr):
                break
            owners.append((obj, attr))
        else:
            for obj, attr in owners:
                setattr(obj, attr, timed(getattr(obj, attr), acc, stage, clock))
            found.add(stage)
    return found


def _make_world(scenario, seeds, duration_s, dtype, buffers=None, for_reset=True):
    """The world as an env's reset draws it (``for_reset``; a tree without that choice draws the whole world)."""
    from envs.sim.scenarios import get_scenario
    from envs.sim.world import generate_world
    kw = {} if buffers is None else {"buffers": buffers}
    if "for_reset" in inspect.signature(generate_world).parameters:
        kw["for_reset"] = for_reset
    return generate_world(get_scenario(scenario, duration_s=duration_s), seeds, dtype=dtype, **kw)


def _world_buffers(fresh: bool):
    """An :class:`envs.sim.buffers.WorldBuffers` (the draws reuse the arrays of the one before, as an env's resets
    do), or None with ``fresh`` or in a tree without it (each draw allocates its arrays)."""
    if fresh:
        return None
    try:
        from envs.sim.buffers import WorldBuffers
    except ImportError:  # a tree before it (--compare)
        return None
    return WorldBuffers()


@contextlib.contextmanager
def _stages_in_turn(on: bool):
    """With ``on``, :func:`envs.sim.world.generate_world` runs its stages one after the other (its IMU stage no
    longer overlaps the GNSS stages, ``OVERLAP_ROWS``), so that each stage's timer reads that stage alone; a tree
    without the overlap runs them in turn anyway."""
    from envs.sim import world
    if not on or not hasattr(world, "OVERLAP_ROWS"):
        yield
        return
    old, world.OVERLAP_ROWS = world.OVERLAP_ROWS, sys.maxsize
    try:
        yield
    finally:
        world.OVERLAP_ROWS = old


def _timed_draws(scenario, B, duration_s, reps, dtype, buffers, clock, acc, acc_cpu, offset, for_reset):
    """``reps`` draws of B rows (seeds from ``offset`` on); per draw the totals and stage times (wall or ``clock``,
    and CPU), with ``rest`` the remainder: two (reps, 2 + stages) arrays."""
    rows, cpu_rows = [], []
    for r in range(reps):
        for k in acc:
            acc[k] = acc_cpu[k] = 0.0
        seeds = list(range(offset + r * B, offset + (r + 1) * B))
        t0, c0 = clock(), time.process_time()
        _make_world(scenario, seeds, duration_s, np.dtype(dtype), buffers, for_reset)
        total, total_cpu = clock() - t0, time.process_time() - c0
        rows.append((total, *(acc[k] for k in _WRAPPED), total - sum(acc.values())))
        cpu_rows.append((total_cpu, *(acc_cpu[k] for k in _WRAPPED), total_cpu - sum(acc_cpu.values())))
    return np.array(rows), np.array(cpu_rows)


def bench_cell(scenario, B, duration_s, reps, dtype="float64", cpu=False, cores=False, fresh=False,
               for_reset=True):
    """Median wall time (``cpu`` without ``cores``: process CPU time) per row [s] of the world and of each stage
    over ``reps`` draws of B rows, and N. The draws go through one :class:`envs.sim.buffers.WorldBuffers`, as an
    env core's resets do (``fresh``: without, each draw allocates its arrays), and form only what an env's reset
    reads (``for_reset``; False: whole worlds).

    The world's total is timed as an env pays it (the IMU stage overlapping the GNSS stages where the world does
    that); the stages are timed in ``reps`` more draws of the same seeds with the stages in turn
    (:func:`_stages_in_turn`), whose total is ``in_turn``: the stages and ``rest`` add up to it.

    Returns ``{"total": s, "in_turn": s, "<stage>": s or None, ..., "rest": s, "n": N}`` (per row; each stage the
    median of its own times, None where this tree lacks it; ``rest`` the median of the per-draw remainders).
    ``cores``: also ``"cores": {"total" or stage: cores busy}``, the stage's process CPU time (all threads) over
    its wall time, both clocks read around the same calls of the same draws (1: one core; 2: two cores
    throughout).
    """
    acc = dict.fromkeys(_WRAPPED, 0.0)
    acc_cpu = dict.fromkeys(_WRAPPED, 0.0)
    clock = time.process_time if cpu and not cores else time.perf_counter  # cores: wall beside CPU
    found = _install_timers(acc, clock)
    if cores:
        _install_timers(acc_cpu, time.process_time)  # around the wall timers: the same calls
    buffers = _world_buffers(fresh)
    w = _make_world(scenario, list(range(B)), duration_s, np.dtype(dtype), buffers,  # untimed: kernels load
                    for_reset)
    n = w.truth.t.shape[0]
    del w
    draws = (scenario, B, duration_s, reps, dtype, buffers, clock, acc, acc_cpu, B, for_reset)
    with _stages_in_turn(True):
        rows, cpu_rows = _timed_draws(*draws)
    paid, paid_cpu = rows[:, 0], cpu_rows[:, 0]
    from envs.sim import world
    if B >= getattr(world, "OVERLAP_ROWS", sys.maxsize):          # the world overlaps stages at this B
        got, got_cpu = _timed_draws(*draws)
        paid, paid_cpu = got[:, 0], got_cpu[:, 0]
    med = np.median(rows, axis=0) / B
    out = dict(zip(("in_turn",) + STAGES, map(float, med)), total=float(np.median(paid)) / B, n=n)
    if cores:
        med_cpu = np.median(cpu_rows, axis=0) / B
        out["cores"] = {k: (float(c / w) if w > 0 else None)
                        for k, c, w in zip(("in_turn",) + STAGES, med_cpu, med)}
        out["cores"]["total"] = float(np.median(paid_cpu) / np.median(paid))
    for stage in _WRAPPED:
        if stage not in found:
            out[stage] = None
            if cores:
                out["cores"][stage] = None
    return out


class _CountingGenerator(np.random.Generator):
    """A Generator on another one's bit generator (the very same stream) that records how many normal variates
    it hands out, by bit generator (:func:`draw_floor`)."""

    drawn: list = []  # (bit generator name, variates)

    def standard_normal(self, size=None, dtype=np.float64, out=None):
        _CountingGenerator.count(self, out.size if out is not None else int(np.prod(size or 1)))
        return super().standard_normal(size, dtype, out)

    def normal(self, loc=0.0, scale=1.0, size=None):
        _CountingGenerator.count(self, int(np.prod(size)) if size is not None else np.broadcast(loc, scale).size)
        return super().normal(loc, scale, size)

    @staticmethod
    def count(gen, n: int) -> None:
        _CountingGenerator.drawn.append((type(gen.bit_generator).__name__, int(n)))


def _count_imu_normals(scenario, B, duration_s, dtype, seed0: int = 0) -> tuple:
    """``(counts, world)``: the normal variates :func:`envs.sim.imu.simulate_imu` draws for the world of seeds
    ``seed0 .. seed0 + B - 1`` (its row streams and their child streams counted, whether numpy or
    :mod:`envs.sim.normals` draws them), as ``{bit generator name: variates}``, and that world (the same bits as
    without counting)."""
    from envs.sim import imu, rng, world
    try:
        from envs.sim import imu_kernels
    except ImportError:                     # a tree before the compiled row pass
        imu_kernels = None
    counting = lambda g: _CountingGenerator(g.bit_generator)  # noqa: E731
    orig_rows, orig_item = world.row_generators, rng.ChildStreams.__getitem__
    kinds = ("SFC64", "PCG64")                               # envs.sim.normals' kind codes
    hooks = {}                                               # the compiled draws a tree has: name -> counter

    def rows(seeds, stream):
        gens = orig_rows(seeds, stream)
        return [counting(g) for g in gens] if stream in ("imu", "vibration") else gens

    def item(self, k):
        got = orig_item(self, k)
        return [counting(g) for g in got] if isinstance(got, list) else counting(got)

    def filled(orig):
        def fill(kind, state, out):         # envs.sim.normals.fill_normals on a raw state
            _CountingGenerator.drawn.append((kinds[kind], out.size))
            return orig(kind, state, out)
        return fill

    def road(orig):
        def samples(kinds_, *a):            # imu._road_samples: 6 innovations per road sample, drawn inline
            kind = a[6]
            if kind >= 0:
                _CountingGenerator.drawn.append((kinds[kind], 6 * int(np.count_nonzero(kinds_ == imu._ROAD))))
            return orig(kinds_, *a)
        return samples

    def rows_pass(orig):
        names = list(inspect.signature(orig.py_func).parameters)

        def kernel(*a):                     # imu_kernels.imu_rows: each row's sensor and road draws, inline
            v = dict(zip(names, a))
            n = v["w_true"].shape[1]
            for i in range(v["r0"], v["r1"]):
                for k in range(2):          # flags[k] = (has_sm, has_gm, has_step, has_white, has_bias)
                    m = 3 * (n + 1) * bool(v["flags"][k, 1]) + 3 * n * bool(v["flags"][k, 3])
                    if m:
                        _CountingGenerator.drawn.append((kinds[v["child_kind"]], m))
                if v["road_on"][i] and v["road_kind"][i] >= 0:
                    m = 6 * int(np.count_nonzero(v["kinds"][i] == imu_kernels.ROAD))
                    _CountingGenerator.drawn.append((kinds[v["road_kind"][i]], m))
            return orig(*a)
        return kernel

    for name, wrap in (("fill_normals", filled), ("_road_samples", road), ("imu_rows", rows_pass)):
        if hasattr(imu, name):
            hooks[name] = getattr(imu, name)
            setattr(imu, name, wrap(hooks[name]))
    orig_sim = world.simulate_imu

    def sim(*a, **kw):
        rng.ChildStreams.__getitem__ = item  # only the IMU's children while it runs
        try:
            return orig_sim(*a, **kw)
        finally:
            rng.ChildStreams.__getitem__ = orig_item

    world.row_generators, world.simulate_imu = rows, sim
    _CountingGenerator.drawn = []
    try:
        with _stages_in_turn(True):         # the GNSS stages' children must not be counted while the IMU runs
            w = _make_world(scenario, list(range(seed0, seed0 + B)), duration_s, np.dtype(dtype))
    finally:
        world.row_generators, world.simulate_imu = orig_rows, orig_sim
        for name, orig in hooks.items():
            setattr(imu, name, orig)
    counts: dict = {}
    for name, n in _CountingGenerator.drawn:
        counts[name] = counts.get(name, 0) + n
    return counts, w


def draw_floor(scenario, B, duration_s, dtype="float64", reps=3) -> dict:
    """What the IMU stage's random draws alone cost: the normal variates it draws for B rows
    (:func:`_count_imu_normals`), drawn again on generators of the same bit generators as the stage draws them
    (:func:`envs.sim.normals.standard_normal`; numpy's in a tree without it), one row per task on the IMU's
    thread count, in blocks of at most (N, 3). The stage pays at least this.

    Returns ``{"normals_per_sample", "ms_per_row", "samples_per_s", "threads"}`` (median of ``reps``)."""
    from concurrent.futures import ThreadPoolExecutor
    try:
        from envs.sim.normals import standard_normal as draw
    except ImportError:  # a tree before the compiled draws
        def draw(g, size):
            return g.standard_normal(size)
    counts, w = _count_imu_normals(scenario, B, duration_s, dtype)
    n = w.truth.t.shape[0]
    per_row = {name: c // B for name, c in counts.items()}
    threads = max(1, min(B, os.cpu_count() or 1, 8))
    gens = [{name: np.random.Generator(getattr(np.random, name)(k)) for name in per_row} for k in range(B)]

    def row(i):
        for name, left in per_row.items():
            while left > 0:
                m = min(left, 3 * n)
                draw(gens[i][name], m)
                left -= m

    times = []
    with ThreadPoolExecutor(threads) as ex:
        for _ in range(reps):
            t0 = time.perf_counter()
            list(ex.map(row, range(B)))
            times.append(time.perf_counter() - t0)
    t = float(np.median(times)) / B
    return {"normals_per_sample": sum(per_row.values()) / n, "ms_per_row": 1e3 * t, "samples_per_s": n / t,
            "threads": threads}


def _run_cell(root, scenario, B, duration_s, reps, dtype, cpu, fresh=False, for_reset=True):
    """One cell in a fresh process on the source tree ``root``; returns its JSON result."""
    env = dict(os.environ, NAVGYM_BENCH_ROOT=root)
    cmd = [sys.executable, os.path.abspath(__file__), "--cell", scenario, str(B), str(duration_s), str(reps), dtype,
           "cpu" if cpu else "wall", "fresh" if fresh else "buffers",
           "reset" if for_reset else "whole"]
    out = subprocess.run(cmd, env=env, cwd=root, capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _median_cells(cells):
    return {k: None if cells[0][k] is None else float(np.median([c[k] for c in cells])) for k in cells[0]}


def _ms(x, width) -> str:
    """Seconds as ms right-aligned in ``width`` (``-`` for a stage the tree lacks)."""
    return f"{'-':>{width}s}" if x is None else f"{1e3 * x:{width}.3f}"


def _with_share(r, stage) -> str:
    """A stage's ms per row and its share of the world's time with the stages in turn."""
    share = "   -" if r[stage] is None else f"{100 * r[stage] / r['in_turn']:4.1f}"
    return f"{_ms(r[stage], 8)} ({share}%)"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenarios", nargs="+", default=["noise-burst", "urban"])
    p.add_argument("--batches", nargs="+", type=int, default=[1, 1024])
    p.add_argument("--duration-s", type=float, default=60.0, help="episode length [s]")
    p.add_argument("--reps", type=int, default=None, help="timed draws per cell (default 20 at B = 1, else 5)")
    p.add_argument("--dtype", choices=("float64", "float32"), default="float64", help="IMU output dtype")
    p.add_argument("--compare", metavar="DIR", default=None,
                   help="also run every cell in the source tree DIR, alternately in fresh processes")
    p.add_argument("--rounds", type=int, default=1, help="alternating rounds per cell with --compare (median)")
    p.add_argument("--cpu", action="store_true", help="process CPU time (all threads) instead of wall time")
    p.add_argument("--cores", action="store_true",
                   help="also print, per cell, the cores busy in each stage (its CPU time over its wall time, "
                        "from the same draws): where the world leaves a core idle")
    p.add_argument("--fresh", action="store_true",
                   help="each draw allocates its arrays (default: the draws reuse them through one WorldBuffers, "
                        "as an env's resets do)")
    p.add_argument("--whole", action="store_true",
                   help="draw whole worlds (default: only what an env's reset reads, as the reset draws it: the "
                        "truth's states at the epochs, no IMU bias records)")
    p.add_argument("--draw-floor", action="store_true",
                   help="also print, per cell, what the IMU stage's normal draws alone cost (draw_floor), "
                        "drawn as the stage draws them")
    args = p.parse_args(argv)
    reps = lambda B: args.reps or (20 if B == 1 else 5)  # noqa: E731
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    print(f"world generation per row: {args.duration_s:g} s episodes, IMU dtype {args.dtype}, {os.cpu_count()} CPUs; "
          f"median of the draws; {'CPU' if args.cpu else 'wall'} ms per row (share of the world's time)")
    print("worlds drawn whole" if args.whole else
          "worlds drawn as an env's reset draws them (for_reset: truth states at the epochs, no IMU bias records)")
    if args.compare:
        other = os.path.abspath(args.compare)
        print(f"before = {other}\nafter  = {here}")
        hdr = (f"{'scenario':14s} {'B':>4s} {'stage':10s} {'ms/row before':>14s} {'after':>8s} {'speed-up':>9s}")
        print("(row Msa/s: million IMU samples generated per second, whole world)")
    else:
        hdr = (f"{'scenario':14s} {'B':>4s} {'ms/row':>8s} {'samples/s':>11s} "
               + " ".join(f"{s:>16s}" for s in STAGES))
    print("\n" + hdr + "\n" + "-" * len(hdr))
    for scen in args.scenarios:
        for B in args.batches:
            cell = (scen, B, args.duration_s, reps(B), args.dtype, args.cpu, args.fresh, not args.whole)
            if args.compare:
                before, after = [], []
                for _ in range(args.rounds):
                    before.append(_run_cell(other, *cell))
                    after.append(_run_cell(here, *cell))
                rb, ra = _median_cells(before), _median_cells(after)
                for s in ("total", "in_turn") + STAGES:
                    up = (f"{rb[s] / ra[s]:8.2f}x" if rb[s] is not None and ra[s] is not None and ra[s] > 0
                          else f"{'-':>9s}")
                    print(f"{scen:14s} {B:4d} {s:10s} {_ms(rb[s], 14)} {_ms(ra[s], 8)} {up}", flush=True)
                print(f"{scen:14s} {B:4d} {'Msa/s':10s} {1e-6 * rb['n'] / rb['total']:14.3f} "
                      f"{1e-6 * ra['n'] / ra['total']:8.3f} {rb['total'] / ra['total']:8.2f}x", flush=True)
            else:
                r = bench_cell(*cell[:6], cores=args.cores and not args.cpu, fresh=args.fresh,
                               for_reset=not args.whole)
                parts = " ".join(_with_share(r, s) for s in STAGES)
                print(f"{scen:14s} {B:4d} {1e3 * r['total']:8.3f} {r['n'] / r['total']:11.3g} {parts}", flush=True)
                if "cores" in r:
                    c = r["cores"]
                    print(f"{scen:14s} {B:4d} {'cores busy':>8s} {c['total']:11.2f} "
                          + " ".join(f"{'-' if c[s] is None else f'{c[s]:.2f}':>16s}" for s in STAGES), flush=True)
            if args.draw_floor:
                f = draw_floor(scen, B, args.duration_s, args.dtype)
                print(f"{scen:14s} {B:4d} draw floor: {f['normals_per_sample']:.1f} normals per IMU sample; "
                      f"drawing them alone ({f['threads']} threads) {f['ms_per_row']:.3f} ms/row, "
                      f"{f['samples_per_s']:.3g} samples/s at most", flush=True)


if __name__ == "__main__":
    if len(sys.argv) > 1 and sys.argv[1] == "--cell":
        scenario, B, duration_s, reps, dtype, clock, alloc, part = sys.argv[2:10]
        print(json.dumps(bench_cell(scenario, int(B), float(duration_s), int(reps), dtype, clock == "cpu",
                                    fresh=alloc == "fresh", for_reset=part == "reset")))
    else:
        main()
