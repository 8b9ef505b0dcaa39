"""Non-GNSS aiding rows of a world's sensor set, stacked with the GNSS update (DESIGN.md section 2).

A scenario with a wheel odometer (``Scenario.odometer``, :mod:`envs.sim.odometer`; ``seed003-sim``) gives every
GNSS epoch, also in outages, one odometer forward-speed row and the two non-holonomic constraint rows
(lateral and vertical body velocity zero) of :mod:`nav_filters.constraints`. :func:`odometer_rows` builds them
for a navigator; :func:`with_rows` stacks them after other extra rows (zero-velocity updates), giving the
``extra`` argument of ``Navigator.update_gnss``. The env core and :func:`envs.episodes.run_episodes` use the
same two functions, so every method, policy and oracle sees the same sensor set.
"""
from __future__ import annotations

import numpy as np

from nav_filters.constraints import odometer_nhc, stack_measurements

from .sim.odometer import OdometerModel


def odometer_rows(nav, speed_mps: np.ndarray, model: OdometerModel):
    """Odometer + NHC measurement block of one epoch.

    Parameters
    ----------
    nav : the navigator (its current velocity ``v`` (B, 3) [m/s] and attitude ``C`` (B, 3, 3)).
    speed_mps : (B,) odometer readings of the epoch [m/s] (NaN: no reading on that row).
    model : the odometer (its ``sigma_mps`` and ``nhc_sigma_mps`` are the variances the filter assumes).

    Returns
    -------
    ``(dz (B, 3), H (B, 3, 17), R (B, 3), row_mask (B, 3))``: the odometer row of
    :func:`nav_filters.constraints.odometer` then the two rows of :func:`nav_filters.constraints.nhc`
    (:func:`nav_filters.constraints.odometer_nhc`, one compiled pass).
    """
    return odometer_nhc(nav.v, nav.C, np.asarray(speed_mps, np.float64), model.sigma_mps, model.nhc_sigma_mps,
                        model.nhc_sigma_mps, dtype=nav.dtype)


def with_rows(extra, rows):
    """``extra`` (a measurement block or None) followed by ``rows`` (a block or None): one block or None."""
    if rows is None:
        return extra
    if extra is None:
        return rows
    return stack_measurements(extra, rows)


__all__ = ["odometer_rows", "with_rows"]
