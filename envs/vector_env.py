"""Native batched vector environments: B episodes in one batched navigator (gymnasium 1.x ``VectorEnv``).

Autoreset mode: ``SAME_STEP`` (stated in ``metadata["autoreset_mode"]``). When a
row's episode ends, ``step`` returns the *first observation of its next
episode* in ``obs`` and the last one in ``info["final_obs"]`` (masked by
``info["_final_obs"]``), with ``info["final_info"]`` holding the finished
episode's metrics. Seeding: ``reset(seed=s)`` seeds row i with ``s + i`` (an
int list seeds rows individually), so row i equals the single env reset with
``seed=s + i``, also across automatic resets. ``reset()`` without a seed starts
every row's next episode from its own stream, as the single env's ``reset()``
does (Gymnasium's semantics; the first reset without any seed draws the streams
from the OS): an evaluation env that SB3 resets at every evaluation goes on
through its seeded episodes, reproducibly.

``prefetch_worlds=depth`` (default 0: off) draws the worlds of up to ``depth`` coming automatic resets ahead
in a background process at the lowest CPU priority (:class:`envs.prefetch.WorldPrefetcher`), so that a reset
whose world is ready only copies it in: the same bits, less time where a core is idle (PPO's gradient
epochs). It pays when the rows finish together (episodes of one length, the default time limit); a reset of
another grouping of rows draws its world itself. ``train.py rl`` turns it on. Without it, a reset of fewer than 8
rows draws their worlds in one batch with those of their coming resets once their streams have gone on for two
resets (:class:`envs.worlds_ahead.WorldsAhead`): the same bits, less CPU time per reset in a long run.

``parallel_kernels`` (default ``'auto'``) picks how the filter's row kernels run in ``step``: ``'auto'`` measures
both the parallel and the serial variants and runs the faster (:class:`nav_filters.parallel_governor.
ParallelGovernor`: the mode that has been faster, the other probed for one step every 32 or more steps, sooner
after a switch, and at the start; it switches only after two probes in a row beat the current mode; steps with
automatic resets are left out of the comparison); it is active from
:data:`nav_filters.kernels.PARALLEL_MIN_BATCH` rows on where numba has more than one thread, and otherwise does
nothing. ``'always'``: parallel from that many rows (the fixed rule); ``'never'``: serial. The variants give the
same bits (a row's arithmetic does not depend on the chunking), so the setting changes the wall time only: on a
machine where another process keeps a core busy a parallel launch waits on the thread that shares it, several
times slower than the serial one (``benchmarks/bench_contention.py``). ``reset`` and the automatic resets run in
the mode ``step`` prefers.
"""
from __future__ import annotations

from collections import deque

import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from nav_filters.parallel_governor import ParallelGovernor, check_policy

from .config import EnvConfig
from .core import TuningCore, check_batch_size, draw_world_seed
from .gnss_ins_env import MASTKF_PARAMS, SAGE_HUSA_PARAMS, STKF_PARAMS, make_config
from .satellite_env import SatelliteCore, SatelliteEnvConfig


class GnssInsTuningVectorEnv(VectorEnv):
    """Vector version of :class:`envs.gnss_ins_env.GnssInsTuningEnv` (same arguments plus ``num_envs``)."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP, "render_modes": []}
    PARAMS = SAGE_HUSA_PARAMS
    DEFAULTS = {"method": "sage-husa"}
    CONFIG = EnvConfig

    def _make_core(self, batch_size: int) -> TuningCore:
        """The batched core of this env (a subclass may run another)."""
        return TuningCore(self.config, self.PARAMS, batch_size, self.DEFAULTS["method"])

    def __init__(self, num_envs: int = 1, prefetch_worlds: int = 0, parallel_kernels: str = "auto", **kwargs):
        kwargs.pop("render_mode", None)
        self.num_envs = check_batch_size(num_envs, "num_envs")
        self.parallel_governor = ParallelGovernor(check_policy(parallel_kernels, "parallel_kernels"),
                                                  batch_size=self.num_envs)
        if isinstance(prefetch_worlds, bool) or not isinstance(prefetch_worlds, (int, np.integer)) \
                or prefetch_worlds < 0:
            raise ValueError(f"prefetch_worlds must be an int >= 0 (worlds drawn ahead; 0: off), got "
                             f"{prefetch_worlds!r}")
        self.config = make_config(self.DEFAULTS, kwargs, self.CONFIG)
        self.core = self._make_core(self.num_envs)
        self._ahead = [deque() for _ in range(self.num_envs)]  # each row's next world seeds, drawn early
        self._prefetch = None
        if prefetch_worlds:
            from .prefetch import WorldPrefetcher
            self._prefetch = WorldPrefetcher(self.config, int(prefetch_worlds))
        self.single_action_space = spaces.Box(-1.0, 1.0, shape=(self.core.action_dim,), dtype=np.float32)
        self.single_observation_space = spaces.Box(self.core.obs_low, self.core.obs_high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._rngs = [None] * self.num_envs

    def _next_seeds(self, rows):
        return [self._ahead[i].popleft() if self._ahead[i] else draw_world_seed(self._rngs[i]) for i in rows]

    def _coming_seeds(self, rows, k: int):
        """The world seeds of the ``k``-th coming reset of each of ``rows`` (k >= 1), drawn ahead from the rows'
        generators in their order (so the seeds, and the worlds, are those of drawing them at the resets)."""
        out = []
        for i in rows:
            q = self._ahead[i]
            while len(q) < k:
                q.append(draw_world_seed(self._rngs[i]))
            out.append(q[k - 1])
        return out

    def _reset_rows(self, rows):
        """Reset ``rows`` with their next seeds: with a prefetch process, its world when it is ready, then ask it
        for their coming worlds; without, the core draws their worlds (a few rows' in batches with those of their
        coming resets, :class:`envs.worlds_ahead.WorldsAhead`). Returns the observations."""
        seeds = self._next_seeds(rows)
        pf = self._prefetch
        if pf is None:
            return self.core.reset_rows(rows, seeds, coming=lambda k: [self._coming_seeds(rows, j)
                                                                       for j in range(1, k + 1)])
        obs = self.core.reset_rows(rows, seeds, prepared=pf.take(seeds))
        while pf.request(self._coming_seeds(rows, pf.in_flight + 1)):
            pass
        return obs

    def _seed_rows(self, seed):
        """New streams for the rows: ``seed`` an int (row i: ``seed + i``), a list of one per row, or None (from
        the OS); what was drawn ahead for the old streams is dropped."""
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed list must have {self.num_envs} entries, got {len(seeds)}")
        self._rngs = [seeding.np_random(s)[0] for s in seeds]
        for q in self._ahead:
            q.clear()
        self.core.worlds_ahead.restart()
        if self._prefetch is not None:
            self._prefetch.cancel()

    def reset(self, *, seed=None, options=None):
        if seed is not None or any(r is None for r in self._rngs):
            self._seed_rows(seed)
        # else every row's stream goes on: the seeds drawn ahead, and the worlds prefetched for them, stay valid
        rows = np.arange(self.num_envs)
        world_seeds = self._coming_seeds(rows, 1)
        with self.parallel_governor.preferred_mode():
            obs = self._reset_rows(rows)
        return obs, {"seed": np.array(world_seeds), "_seed": np.ones(self.num_envs, bool)}

    def step(self, actions):
        with self.parallel_governor.unit() as unit:  # the row kernels parallel or serial (module docstring)
            res = self.core.step(actions)
            infos = dict(res.info)
            for key in list(infos):
                infos["_" + key] = np.ones(self.num_envs, bool)
            done = res.terminated | res.truncated
            obs = res.obs
            if done.any():
                unit.comparable = False  # its time holds the resets' world generation: not a plain step's
                rows = np.flatnonzero(done)
                final_obs = np.empty(self.num_envs, dtype=object)
                final_info = np.empty(self.num_envs, dtype=object)
                metrics = self.core.episode_metrics(rows)
                for r, m in zip(rows, metrics):
                    final_obs[r] = obs[r].copy()
                    final_info[r] = {"episode_metrics": m}
                infos["final_obs"], infos["_final_obs"] = final_obs, done.copy()
                infos["final_info"], infos["_final_info"] = final_info, done.copy()
                obs = obs.copy()
                obs[rows] = self._reset_rows(rows)
        return obs, res.reward.astype(np.float64), res.terminated.copy(), res.truncated.copy(), infos

    def close_extras(self, **kwargs):
        """Stop the world prefetch process, if any, and release the world buffers."""
        if getattr(self, "core", None) is not None:
            self.core.world_buffers.clear()
            self.core.worlds_ahead.clear()
        if self._prefetch is not None:
            self._prefetch.close()
            self._prefetch = None


class SageHusaVectorEnv(GnssInsTuningVectorEnv):
    """Vector ``GnssIns/SageHusa-v1``."""

    PARAMS = SAGE_HUSA_PARAMS
    DEFAULTS = {"method": "sage-husa"}


class StkfVectorEnv(GnssInsTuningVectorEnv):
    """Vector ``GnssIns/STKF-v1``."""

    PARAMS = STKF_PARAMS
    DEFAULTS = {"method": "stkf"}


class MaStkfVectorEnv(GnssInsTuningVectorEnv):
    """Vector ``GnssIns/MASTKF-v1``."""

    PARAMS = MASTKF_PARAMS
    DEFAULTS = {"method": "ma-stkf"}


class SatelliteRVectorEnv(GnssInsTuningVectorEnv):
    """Vector ``GnssIns/SatelliteR-v0`` (:mod:`envs.satellite_env`)."""

    DEFAULTS = {"method": "kf"}
    CONFIG = SatelliteEnvConfig
    KNOB = "inflation"

    def _make_core(self, batch_size: int) -> SatelliteCore:
        return SatelliteCore(self.config, self.KNOB, batch_size)


class SatelliteSageHusaVectorEnv(SatelliteRVectorEnv):
    """Vector ``GnssIns/SatelliteSageHusa-v0`` (:mod:`envs.satellite_env`)."""

    DEFAULTS = {"method": "sage-husa"}
    KNOB = "b"
