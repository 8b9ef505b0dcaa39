"""Episode metrics of DESIGN.md section 4 (results.json) with bootstrap confidence intervals."""
from __future__ import annotations

import numpy as np

from .episodes import EpisodeLog


def bootstrap_rmse_ci(sq_err: np.ndarray, n_boot: int = 2000, level: float = 0.95, seed: int = 0):
    """Percentile bootstrap CI of the pooled RMSE, resampling whole episodes.

    Parameters
    ----------
    sq_err : (E, M) squared errors of E episodes.

    Returns
    -------
    (low, high) [same unit as sqrt(sq_err)]; (nan, nan) without episodes.
    """
    E = sq_err.shape[0]
    if E == 0:
        return (float("nan"), float("nan"))
    per_ep = sq_err.mean(1)
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, E, size=(n_boot, E))
    boot = np.sqrt(per_ep[idx].mean(1))
    a = (1 - level) / 2
    return (float(np.quantile(boot, a)), float(np.quantile(boot, 1 - a)))


def summarize(log: EpisodeLog) -> dict:
    """The per-method metrics dictionary of results.json.

    RMSE, max and p95 pool every epoch of every non-diverged episode; the CI
    resamples episodes. Diverged episodes are counted in ``diverged`` and left
    out of the error statistics.
    """
    ok = ~log.diverged
    h = log.horizontal_error[ok]
    d3 = log.error_3d[ok]
    n_epochs = log.t.size * log.diverged.size
    out = {
        "episodes": int(log.diverged.size),
        "rmse_h_m": float(np.sqrt(np.mean(h ** 2))) if h.size else float("nan"),
        "rmse_3d_m": float(np.sqrt(np.mean(d3 ** 2))) if d3.size else float("nan"),
        "max_h_m": float(np.max(h)) if h.size else float("nan"),
        "p95_h_m": float(np.quantile(h, 0.95)) if h.size else float("nan"),
        "rmse_h_ci95_m": list(bootstrap_rmse_ci(h ** 2)),
        "filter_time_per_epoch_s": float(log.filter_time_s / max(n_epochs, 1)),
        "diverged": int(log.diverged.sum()),
        "zupt_epochs_frac": float(np.mean(log.zupt)) if log.zupt.size else 0.0,
    }
    nees = log.nees_pv[ok]
    out["mean_nees_pv"] = float(np.nanmean(nees)) if np.isfinite(nees).any() else float("nan")
    used = log.n_used[ok]
    nis = log.nis[ok]
    out["mean_nis_per_dof"] = float(np.sum(nis[used > 0]) / max(np.sum(used[used > 0]), 1))
    return out


def paired_difference(log: EpisodeLog, ref: EpisodeLog, n_boot: int = 2000, seed: int = 0) -> dict:
    """Paired difference of the pooled horizontal RMSE of ``log`` and ``ref`` over the same episodes.

    Episodes where either diverged are left out; the CI resamples episodes with the same indices for
    both methods (paired bootstrap), so shared episode difficulty cancels.

    Returns
    -------
    dict: ``diff_rmse_h_m`` (method minus reference), ``diff_rmse_h_ci95_m``, ``rel_diff`` (fraction of the
    reference RMSE), ``episodes`` used.
    """
    ok = ~(log.diverged | ref.diverged)
    return _paired((log.horizontal_error[ok] ** 2).mean(1), (ref.horizontal_error[ok] ** 2).mean(1), n_boot, seed)


def _paired(a: np.ndarray, b: np.ndarray, n_boot: int, seed: int) -> dict:
    """Paired bootstrap of sqrt(mean a) - sqrt(mean b) over the (E,) per-episode mean squared errors."""
    E = a.size
    if E == 0:
        return {"diff_rmse_h_m": float("nan"), "diff_rmse_h_ci95_m": [float("nan")] * 2, "rel_diff": float("nan"),
                "episodes": 0}
    d = float(np.sqrt(a.mean()) - np.sqrt(b.mean()))
    idx = np.random.default_rng(seed).integers(0, E, size=(n_boot, E))
    boot = np.sqrt(a[idx].mean(1)) - np.sqrt(b[idx].mean(1))
    return {"diff_rmse_h_m": d, "diff_rmse_h_ci95_m": [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))],
            "rel_diff": d / float(np.sqrt(b.mean())), "episodes": int(E)}


def summarize_seeds(logs: list[EpisodeLog], ref: EpisodeLog | None = None, n_boot: int = 2000,
                    seed: int = 0) -> dict:
    """Metrics of one learned method trained with several seeds (S logs of the same E episodes).

    The error statistics pool the S x E episodes (:func:`summarize` of their concatenation); the CI and the
    paired difference to ``ref`` resample *episodes* (each drawn episode brings its S seeds' errors), so the
    interval covers the episode sampling with the training seeds averaged. Episodes diverged in any seed (or
    in ``ref``) are left out of the CI and the difference; ``rmse_h_per_seed_m`` shows the spread over seeds.

    Returns
    -------
    :func:`summarize`'s dictionary with ``seeds`` (S), ``rmse_h_per_seed_m`` (S,), the episode-bootstrap
    ``rmse_h_ci95_m`` and, with ``ref``, ``paired_vs_reference`` as in :func:`paired_difference`.
    """
    from .episodes import concat_logs
    if not logs:
        raise ValueError("summarize_seeds needs at least one log")
    out = summarize(concat_logs(logs))
    out["episodes"] = int(logs[0].diverged.size)
    out["seeds"] = len(logs)
    out["rmse_h_per_seed_m"] = [summarize(log)["rmse_h_m"] for log in logs]
    ok = ~np.any([log.diverged for log in logs], 0)
    if ref is not None:
        ok &= ~ref.diverged
    a = np.mean([(log.horizontal_error[ok] ** 2).mean(1) for log in logs], 0) if ok.any() else np.zeros(0)
    out["rmse_h_ci95_m"] = list(bootstrap_rmse_ci(a[:, None], n_boot=n_boot, seed=seed))
    if ref is not None:
        out["paired_vs_reference"] = _paired(a, (ref.horizontal_error[ok] ** 2).mean(1), n_boot, seed)
    return out
