"""The epoch propagation's entry point, :func:`propagate_epoch`: the IMU samples of one epoch through the compiled
mechanization and covariance kernels, exact (:mod:`nav_filters.kernels`, the per-sample transitions composed) or
averaged (:mod:`nav_filters.imu_lanes`, rows in SIMD lanes). It sits above both, so that ``imu_lanes`` builds on
``kernels`` and neither imports the other back."""
from __future__ import annotations

from . import kernels
from .imu_lanes import propagate_lanes
from .kernels import row_kernel


def propagate_epoch(r, v, C, bg, ba, clk, drift, f_raw, w_raw, h, Av, Au, Ag, Cz, qg, qa, qdiag, kg, ka,
                    Phi_acc, Q_acc, exact, orthonormalize, nz, integrate=False, start=False):
    """Compiled epoch propagation (:func:`nav_filters.kernels._propagate_epoch`); parallel over rows for B >= 64.

    ``integrate``: the averaged-dynamics mode (:mod:`nav_filters.kernels`' docstring), :func:`nav_filters.imu_lanes.propagate_lanes`:
    ``Phi_acc`` accumulates ``sum_i F_i h`` (zero outside ``nz``) instead of the transition, and ``Q_acc`` the
    summed process noise (``exact`` must then be False; ``start`` sets both to 0 first)."""
    if integrate and exact:
        raise ValueError("propagate_epoch: integrate (averaged dynamics) needs exact=False")
    if integrate:
        propagate_lanes(r, v, C, bg, ba, clk, drift, f_raw, w_raw, h, Av, Au, Ag, Cz, qg, qa, qdiag, kg, ka,
                        Phi_acc, Q_acc, orthonormalize, start)
        return
    kern, nchunk = row_kernel(kernels._serial, kernels._parallel, f_raw.shape[0])
    kern(r, v, C, bg, ba, clk, drift, f_raw, w_raw, h, Av, Au, Ag, Cz, qg, qa, qdiag, kg, ka,
         Phi_acc, Q_acc, exact, orthonormalize, nz, bool(start), nchunk)
