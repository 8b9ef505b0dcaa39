"""Urban-error statistics measured on the smartLoc recording (the source of the simulated zone parameters).

The simulated urban zones of :mod:`envs.sim.events` take their NLOS
probability, bias distribution and C/N0 model from these statistics of the
recorded Berlin Potsdamer Platz pseudoranges (u-blox receiver in a dense
street canyon; GPS + GLONASS; 1372 epochs at ~5 Hz, 20038 measurements).
``tests/envs/test_events.py`` recomputes them (when the data are present) and
checks the constants in :mod:`envs.sim.events` against them. Run::

    NAVGYM_DATA_DIR=../shared/data python -m envs.datasets.smartloc_stats

Method
------
Residual ``res = pr - rho(r_true) - clk`` of each recorded pseudorange
against the NovAtel SPAN ground truth (range with the Sagnac term,
:func:`earth.ranging.range_and_rate`), with the receiver clock ``clk`` per
epoch and per system (GPS / GLONASS have different clock offsets) the median
of ``pr - rho`` over the channels with C/N0 >= 42 dB-Hz and elevation >= 30
deg (at least two of them; else over the channels at or above the epoch's
median C/N0). A measurement is *NLOS-like* when ``|res| > 10 m`` (several
times the LOS code noise; the data set has no NLOS label, this is the usual
residual-based proxy) and *LOS-like* when ``|res| < 3 m``.

Measured quantities
-------------------
* ``cn0_los_a + cn0_los_b sin(el)``: least-squares line of C/N0 [dB-Hz] of
  the LOS-like measurements against sin(elevation) (and the residual scatter
  ``cn0_sigma_db``).
* ``nlos_deficit_db``: median C/N0 of the LOS-like minus the NLOS-like
  measurements (over all elevations).
* ``p_nlos_a - p_nlos_b sin(el)``: linear probability model of NLOS-like
  against sin(elevation) (least squares on the 0/1 indicator).
* ``bias_sin_median_m``, ``bias_sigma_ln``: the NLOS-like ``|res| sin(el)``
  is log-normal with this median [m] and log-sigma (so the bias median is
  ``bias_sin_median_m / sin(el)``, larger at low elevation).
* ``bias_positive_fraction``: share of NLOS-like residuals that are positive.
* ``nlos_mean_run_s``: mean duration of an uninterrupted NLOS-like run of one
  satellite [s].
* ``nlos_fraction``: overall NLOS-like share.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from earth.ranging import range_and_rate

from .smartloc import SmartLocData, load_smartloc
from .spline_truth import fit_positions

__all__ = ["UrbanErrorStatistics", "urban_error_statistics"]

NLOS_THRESHOLD_M = 10.0
LOS_THRESHOLD_M = 3.0


@dataclass(frozen=True)
class UrbanErrorStatistics:
    """The measured statistics (see the module docstring for each)."""

    n_measurements: int
    nlos_fraction: float
    cn0_los_a: float
    cn0_los_b: float
    cn0_sigma_db: float
    nlos_deficit_db: float
    p_nlos_a: float
    p_nlos_b: float
    bias_sin_median_m: float
    bias_sigma_ln: float
    bias_positive_fraction: float
    nlos_mean_run_s: float


def _residuals(data: SmartLocData):
    ep = data.epochs()
    gt = data.ground_truth
    fit = fit_positions(gt.t, gt.r_e)
    rho, _, _ = range_and_rate(ep.sat_pos, ep.sat_vel, fit.position(ep.t), fit.velocity(ep.t))
    m, el = ep.mask, ep.elevation
    d0 = np.where(m, ep.pr - rho, np.nan)
    res = np.full(d0.shape, np.nan)
    for sysc in np.unique(ep.system[m]):
        ms = m & (ep.system == sysc)
        good = ms & (ep.cn0 >= 42.0) & (el >= math.radians(30.0))
        cn = np.where(ms, ep.cn0, np.nan)
        with np.errstate(all="ignore"), _quiet():
            strong = ms & (cn >= np.nanmedian(cn, axis=-1, keepdims=True))
            clk_good = np.nanmedian(np.where(good, d0, np.nan), axis=-1)
            clk_strong = np.nanmedian(np.where(strong, d0, np.nan), axis=-1)
        clk = np.where(good.sum(-1) >= 2, clk_good, clk_strong)
        res = np.where(ms, d0 - clk[:, None], res)
    return ep, res


class _quiet:
    """Silence numpy's all-NaN-slice warnings of epochs without a channel of a system."""

    def __enter__(self):
        import warnings
        self._w = warnings.catch_warnings()
        self._w.__enter__()
        warnings.simplefilter("ignore", RuntimeWarning)

    def __exit__(self, *a):
        return self._w.__exit__(*a)


def urban_error_statistics(data: SmartLocData | None = None) -> UrbanErrorStatistics:
    """Measure the statistics of the module docstring on a smartLoc recording (default: Potsdamer Platz)."""
    data = load_smartloc() if data is None else data
    ep, res = _residuals(data)
    ok = ep.mask & np.isfinite(res)
    R, E, C = res[ok], ep.elevation[ok], ep.cn0[ok]
    s = np.sin(E)
    los = np.abs(R) < LOS_THRESHOLD_M
    nl = np.abs(R) > NLOS_THRESHOLD_M
    A = np.c_[np.ones(los.sum()), s[los]]
    (ca, cb), *_ = np.linalg.lstsq(A, C[los], rcond=None)
    cn0_sigma = float(np.std(C[los] - A @ np.array([ca, cb])))
    (pa, pb), *_ = np.linalg.lstsq(np.c_[np.ones(R.size), s], nl.astype(float), rcond=None)
    lb = np.log(np.abs(R[nl]) * s[nl])
    # mean NLOS run length per satellite channel slot (epochs are ~0.2 s apart)
    key = np.where(ep.mask, ep.system * 100_000 + ep.sat_id, -1)
    state = np.abs(np.nan_to_num(res, nan=0.0)) > NLOS_THRESHOLD_M
    runs = []
    for k in np.unique(key[key >= 0]):
        ti, ci = np.nonzero(key == k)
        order = np.argsort(ti)
        ti, st = ti[order], state[ti[order], ci[order]]
        t = ep.t[ti]
        start = None
        for j in range(ti.size):
            contiguous = j > 0 and ti[j] == ti[j - 1] + 1
            if st[j] and (start is None or not contiguous):
                if start is not None:
                    runs.append(t[j - 1] - t[start] + 0.2)
                start = j
            elif not st[j] and start is not None:
                runs.append(t[j - 1] - t[start] + 0.2)
                start = None
        if start is not None:
            runs.append(t[-1] - t[start] + 0.2)
    return UrbanErrorStatistics(
        n_measurements=int(R.size), nlos_fraction=float(nl.mean()),
        cn0_los_a=float(ca), cn0_los_b=float(cb), cn0_sigma_db=cn0_sigma,
        nlos_deficit_db=float(np.median(C[los]) - np.median(C[nl])),
        p_nlos_a=float(pa), p_nlos_b=float(-pb),
        bias_sin_median_m=float(np.exp(np.median(lb))), bias_sigma_ln=float(np.std(lb)),
        bias_positive_fraction=float(np.mean(R[nl] > 0)), nlos_mean_run_s=float(np.mean(runs)))


if __name__ == "__main__":  # pragma: no cover
    for k, v in asdict(urban_error_statistics()).items():
        print(f"{k:24s} {v:.4g}")
