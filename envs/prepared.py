"""What an env core's reset needs of a world, drawn and reduced in one pure function.

:func:`prepare_world` draws the world of an :class:`~envs.config.EnvConfig` for B seeds and keeps only what
:meth:`envs.core.TuningCore.reset_rows` uses: the per-row arrays the core stores
(:data:`WORLD_ARRAY_NAMES`: IMU samples, GNSS epochs, truth at the epochs) and the world without its bulky
parts (truth at the IMU rate, IMU error records, GNSS data), which is all the navigator's construction
reads (initial estimate, IMU grade, clock model). It is a function of the config and the seeds only, so it
can run ahead in another process (:mod:`envs.prefetch`) and give the same bits as at the reset itself;
the reduced form is about a fifth of the world's size (what crosses the process boundary: 0.39 of
1.9 MB per row of a 60 s episode at 100 Hz).
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from earth import C_en, ecef_to_geodetic

from .episodes import satellite_keys
from .sim.world import World
from .zupt_source import STILL_SPEED_MPS

WORLD_ARRAY_NAMES = ("f", "w", "sat_pos", "sat_vel", "pr", "prr", "pr_sigma", "prr_sigma", "gmask", "truth_r",
                     "truth_Cne", "truth_still", "truth_still_n", "origin", "origin_Cne", "sat_keys", "odo",
                     "odo_yaw")
"""The per-row world arrays of an env core (all with leading axis B), in :class:`PreparedWorld.arrays`:

``f``, ``w`` (B, N, 3) IMU specific force [m/s^2] and angular rate [rad/s] interval means; ``sat_pos``,
``sat_vel`` (B, M, C, 3) [m, m/s]; ``pr``, ``prr``, ``pr_sigma``, ``prr_sigma`` (B, M, C) [m, m/s] (``prr``
and its sigma zeros when the world has no Doppler); ``gmask`` (B, M, C) bool; ``truth_r`` (B, M, 3) true ECEF
position at the epochs [m]; ``truth_Cne`` (B, M, 3, 3) ECEF-to-NED rotation there; ``truth_still`` (B, M) and
``truth_still_n`` (B, N) bool stationary truth; ``origin`` (B, 3) start position [m], ``origin_Cne`` (B, 3, 3);
``sat_keys`` (B, M, C) int64 (-1 on empty channels); ``odo`` (B, M) odometer readings [m/s] (NaN without one);
``odo_yaw`` (B, M) yaw-rate readings over each epoch's IMU interval [rad/s] (NaN without one).
"""

CHANNEL_ARRAY_NAMES = ("sat_el", "sat_cn0")
"""Per-channel receiver reports in :class:`PreparedWorld.arrays` beside :data:`WORLD_ARRAY_NAMES`, which only the
per-satellite env cores store (:mod:`envs.satellite_env`): ``sat_el`` (B, M, C) elevation [rad] and ``sat_cn0``
(B, M, C) C/N0 [dB-Hz] (0 on empty channels, and where a data set reports none)."""


@dataclass(frozen=True)
class PreparedWorld:
    """The part of a world an env core's reset uses (:func:`prepare_world`).

    Attributes
    ----------
    seeds : the B world seeds.
    world : the :class:`~envs.sim.world.World` with ``truth``, ``imu`` and ``gnss`` set to None (scenario,
        seeds, epoch indices, initial estimate: what :func:`envs.episodes.navigator_for` reads).
    arrays : ``{name: array}`` for every name of :data:`WORLD_ARRAY_NAMES` and :data:`CHANNEL_ARRAY_NAMES`.
    has_rate : whether the world has pseudorange rates (a recording may have no Doppler).
    """

    seeds: tuple
    world: World
    arrays: dict
    has_rate: bool

    @property
    def batch_size(self) -> int:
        return len(self.seeds)

    def rows(self, start: int, stop: int) -> "PreparedWorld":
        """Rows ``start:stop`` of this prepared world, as views (the arrays are copied by the reset that takes
        them): the same as preparing the world of those rows' seeds alone (a world's row depends only on its
        seed, :mod:`envs.sim.world`)."""
        if not 0 <= start < stop <= self.batch_size:
            raise ValueError(f"rows {start}:{stop} outside the {self.batch_size} rows of the prepared world")
        sl = slice(start, stop)
        w = self.world
        init = w.init
        cut = {f.name: getattr(init, f.name)[sl] for f in fields(init) if isinstance(getattr(init, f.name), np.ndarray)}
        world = replace(w, seeds=list(w.seeds[sl]), init=replace(init, **cut),
                        odometer=None if w.odometer is None else w.odometer[sl],
                        odometer_yaw_rate=None if w.odometer_yaw_rate is None else w.odometer_yaw_rate[sl])
        return PreparedWorld(seeds=self.seeds[sl], world=world, arrays={k: a[sl] for k, a in self.arrays.items()},
                             has_rate=self.has_rate)


def world_arrays(world: World) -> dict:
    """The per-row arrays of :data:`WORLD_ARRAY_NAMES` and :data:`CHANNEL_ARRAY_NAMES` from a whole world (float64
    but the IMU samples, which keep the world's IMU dtype until the core stores them)."""
    g, tr = world.gnss, world.truth
    B, M = g.pr.shape[:2]
    ep = world.epoch_idx
    still = tr.stationary(STILL_SPEED_MPS)
    # the origin (sample 0) and the epochs in one conversion and one rotation (elementwise: the same bits); the
    # truth may hold its states only there (generate_world's for_reset)
    r_at = tr.take(np.concatenate([[0], ep])).r_e
    C_ne = np.swapaxes(C_en(*ecef_to_geodetic(r_at)[:2]), -1, -2)
    has_rate = g.prr is not None
    return {
        "f": world.imu.f_b, "w": world.imu.w_b,
        "sat_pos": g.sat_pos, "sat_vel": g.sat_vel,
        "pr": g.pr, "pr_sigma": g.pr_sigma,
        "prr": g.prr if has_rate else np.zeros(g.pr.shape),
        "prr_sigma": g.prr_sigma if has_rate else np.zeros(g.pr.shape),
        "gmask": g.mask,
        "truth_r": r_at[:, 1:],
        "truth_Cne": C_ne[:, 1:],
        "truth_still": still[:, ep],
        "truth_still_n": still,
        "origin": r_at[:, 0],
        "origin_Cne": C_ne[:, 0],
        "sat_keys": satellite_keys(g),
        "odo": np.full((B, M), np.nan) if world.odometer is None else world.odometer,
        "odo_yaw": np.full((B, M), np.nan) if world.odometer_yaw_rate is None else world.odometer_yaw_rate,
        "sat_el": np.where(g.mask, g.elevation, 0.0),
        "sat_cn0": np.zeros(g.pr.shape) if g.cn0_dbhz is None else np.where(g.mask, g.cn0_dbhz, 0.0),
    }


def prepared_from(world: World) -> PreparedWorld:
    """The part of a whole ``world`` a reset uses (:class:`PreparedWorld`)."""
    return PreparedWorld(seeds=tuple(world.seeds), world=replace(world, truth=None, imu=None, gnss=None),
                         arrays=world_arrays(world), has_rate=world.gnss.prr is not None)


def prepare_world(config, seeds, buffers=None) -> PreparedWorld:
    """Draw the world of ``config`` (an :class:`~envs.config.EnvConfig`) for ``seeds`` (B ints) and reduce it
    to what a reset uses (:class:`PreparedWorld`). A pure function of its arguments (``buffers``: the world's
    :class:`envs.sim.buffers.WorldBuffers`, which the result does not depend on). The world is drawn with
    ``for_reset=True``: only what a reset reads of it (the truth's states at sample 0 and the epochs, no IMU bias
    records)."""
    return prepared_from(config.make_world([int(s) for s in seeds], buffers=buffers, for_reset=True))


__all__ = ["WORLD_ARRAY_NAMES", "CHANNEL_ARRAY_NAMES", "PreparedWorld", "prepare_world", "prepared_from", "world_arrays"]
