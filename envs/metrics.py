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
    if log.n_excluded is not None:  # a method that screens its measurements
        out["excluded_per_epoch"] = float(np.mean(log.n_excluded[ok])) if ok.any() else float("nan")
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


# --------------------------------------------------------------------------- headroom
MIN_CI_EPISODES = 10
"""Below this many (paired) episodes no confidence interval or verdict is given: a bootstrap over fewer
episodes does not cover its nominal level."""


def no_ci_text(min_episodes: int = MIN_CI_EPISODES) -> str:
    """The text that stands in for a CI / verdict below the minimum number of episodes."""
    return f"n < {min_episodes}: no CI"


VERDICTS = ("lower", "higher", "not significant", "no CI")
"""The verdicts of a paired difference (:func:`paired_verdict`)."""


def paired_verdict(p: dict, min_episodes: int = MIN_CI_EPISODES) -> str:
    """The verdict of a paired difference ``p`` (:func:`paired_difference`: method minus reference):
    ``'lower'`` (its 95% CI lies below 0: the method's RMSE is lower), ``'higher'`` (above 0),
    ``'not significant'`` (the CI includes 0), ``'no CI'`` (fewer than ``min_episodes`` paired episodes, or a
    missing or non-finite CI, as results.json's null)."""
    lo, hi = (np.nan if v is None else float(v) for v in (p.get("diff_rmse_h_ci95_m") or (None, None)))
    if p["episodes"] < min_episodes or not (np.isfinite(lo) and np.isfinite(hi)):
        return "no CI"
    return "lower" if hi < 0 else "higher" if lo > 0 else "not significant"


def episode_mse(log: EpisodeLog) -> np.ndarray:
    """(E,) mean squared horizontal error of each episode [m^2] (NaN where non-finite)."""
    return np.mean(log.horizontal_error ** 2, axis=1)


def _ci(boot, level):
    a = (1 - level) / 2
    return [float(np.quantile(boot, a)), float(np.quantile(boot, 1 - a))]


def _check_paired(**arrays):
    n = None
    for name, a in arrays.items():
        a = np.asarray(a, np.float64)
        if a.ndim != 1 or (n is not None and a.size != n):
            raise ValueError(f"{name} must be a 1-D array of per-episode mean squared errors of the same "
                             f"{n if n is not None else 'E'} episodes, got shape {a.shape}")
        if not np.all(np.isfinite(a)) or np.any(a < 0):
            raise ValueError(f"{name} must hold finite non-negative mean squared errors")
        n = a.size
    return n


def headroom(fixed, oracle, placebo=None, n_boot: int = 2000, level: float = 0.95, seed: int = 0,
             min_episodes: int = MIN_CI_EPISODES) -> dict:
    """Headroom of an oracle over the optimized fixed parameter: ``(RMSE_fixed - RMSE_oracle) / RMSE_fixed``.

    Parameters
    ----------
    fixed, oracle : (E,) per-episode mean squared horizontal errors [m^2] of the same episodes (paired).
    placebo : optional ``(fixed0, oracle0)``, the same of the placebo scenario (one without events, where a
        hindsight oracle wins only by luck); its headroom ``h0`` is subtracted: net headroom ``h - h0``.
    n_boot, level, seed : bootstrap resamples, CI level and seed; episodes are resampled with the same
        indices for both methods (paired), the placebo's episodes independently.
    min_episodes : below this many episodes (of either scenario) the CIs are None (``ci_note`` says so).

    Returns
    -------
    dict: ``episodes``, ``headroom``, ``headroom_ci95`` ([lo, hi] or None), ``placebo_headroom``,
    ``placebo_episodes``, ``net_headroom``, ``net_headroom_ci95`` (None without a placebo), ``ci_note``.
    """
    E = _check_paired(fixed=fixed, oracle=oracle)
    if E == 0:
        raise ValueError("headroom needs at least one episode")
    f, o = np.asarray(fixed, np.float64), np.asarray(oracle, np.float64)
    rng = np.random.default_rng(seed)

    def rel(a, b):
        ra = np.sqrt(a)
        return (ra - np.sqrt(b)) / ra

    h = float(rel(f.mean(), o.mean()))
    idx = rng.integers(0, E, size=(n_boot, E))
    boot = rel(f[idx].mean(1), o[idx].mean(1))
    out = {"episodes": int(E), "headroom": h, "headroom_ci95": _ci(boot, level) if E >= min_episodes else None,
           "placebo_headroom": None, "placebo_episodes": None, "net_headroom": None, "net_headroom_ci95": None,
           "ci_note": None if E >= min_episodes else no_ci_text(min_episodes)}
    if placebo is not None:
        f0, o0 = (np.asarray(a, np.float64) for a in placebo)
        E0 = _check_paired(placebo_fixed=f0, placebo_oracle=o0)
        if E0 == 0:
            raise ValueError("the placebo needs at least one episode")
        h0 = float(rel(f0.mean(), o0.mean()))
        idx0 = rng.integers(0, E0, size=(n_boot, E0))
        boot0 = rel(f0[idx0].mean(1), o0[idx0].mean(1))
        ok = min(E, E0) >= min_episodes
        out.update(placebo_headroom=h0, placebo_episodes=int(E0), net_headroom=h - h0,
                   net_headroom_ci95=_ci(boot - boot0, level) if ok else None)
        if not ok:
            out["ci_note"] = no_ci_text(min_episodes)
    return out


def headroom_share(fixed, method, oracle, placebo=None, n_boot: int = 2000, level: float = 0.95, seed: int = 0,
                   min_episodes: int = MIN_CI_EPISODES) -> dict:
    """Share of an oracle's (net) headroom that a method closed: ``(R_f - R_m) / (R_f - R_o - h0 R_f)``.

    ``R`` are pooled RMSEs over the same episodes (fixed parameter ``f``, method ``m``, oracle ``o``) and
    ``h0`` the placebo headroom (:func:`headroom`; 0 without a placebo): 1 means the method reached the
    oracle's floor (net of luck), 0 the optimized fixed parameter, < 0 worse than it.

    Parameters
    ----------
    fixed, method, oracle : (E,) per-episode mean squared horizontal errors [m^2] of the same episodes.
    placebo : optional ``(fixed0, oracle0)`` of the placebo scenario (resampled independently).
    n_boot, level, seed, min_episodes : as :func:`headroom`.

    Returns
    -------
    dict: ``episodes``, ``share``, ``share_ci95`` ([lo, hi] or None), ``gap_m`` (the (net) headroom in metres,
    ``R_f - R_o - h0 R_f``), ``gap_ci95_m``, ``net`` (placebo subtracted), ``note`` (why a share or CI is
    missing: below ``min_episodes``; no headroom to close; a headroom whose CI includes 0, for which the ratio
    has no bounded interval).
    """
    E = _check_paired(fixed=fixed, method=method, oracle=oracle)
    if E == 0:
        raise ValueError("headroom_share needs at least one episode")
    f, m, o = (np.asarray(a, np.float64) for a in (fixed, method, oracle))
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, E, size=(n_boot, E))
    rf, rm, ro = np.sqrt(f.mean()), np.sqrt(m.mean()), np.sqrt(o.mean())
    bf, bm, bo = (np.sqrt(a[idx].mean(1)) for a in (f, m, o))
    h0, b0, E0 = 0.0, 0.0, None
    if placebo is not None:
        f0, o0 = (np.asarray(a, np.float64) for a in placebo)
        E0 = _check_paired(placebo_fixed=f0, placebo_oracle=o0)
        if E0 == 0:
            raise ValueError("the placebo needs at least one episode")
        h0 = 1.0 - np.sqrt(o0.mean()) / np.sqrt(f0.mean())
        idx0 = rng.integers(0, E0, size=(n_boot, E0))
        b0 = 1.0 - np.sqrt(o0[idx0].mean(1)) / np.sqrt(f0[idx0].mean(1))
    gap = float(rf - ro - h0 * rf)
    bgap = bf - bo - b0 * bf
    enough = E >= min_episodes and (E0 is None or E0 >= min_episodes)
    out = {"episodes": int(E), "share": None, "share_ci95": None, "gap_m": gap,
           "gap_ci95_m": _ci(bgap, level) if enough else None, "net": placebo is not None, "note": None}
    if not gap > 0:
        out["note"] = f"no {'net ' if placebo is not None else ''}headroom to close (gap {gap:+.3g} m): share not defined"
        return out
    out["share"] = float((rf - rm) / gap)
    if not enough:
        out["note"] = no_ci_text(min_episodes)
    elif np.mean(bgap <= 0) > (1 - level) / 2:
        out["note"] = (f"the {'net ' if placebo is not None else ''}headroom's {100 * level:.0f}% CI includes 0: "
                       "the share has no bounded CI")
    else:
        out["share_ci95"] = _ci((bf - bm) / bgap, level)
    return out
