"""The PNG plots of eval.py, one set per scenario.

* ``error_vs_time_<scenario>.png``: top, the median horizontal error of every method over the episodes
  (lines) with the reference's 10-90% band only; bottom, the paired difference to the reference over time
  (method minus reference, episode by episode: median line per method, 10-90% band for the focus method).
  The scenario's event windows are shaded on both.
* ``trajectory_<scenario>.png``: episode 0 in a local east/north frame (equal axes) from the start: the truth,
  the reference and the one or two most interesting other methods (:func:`focus_methods`), the truth drawn
  thick where an event is active.
* ``actions_<scenario>.png`` (only with learned methods): for each policy row, the filter parameter it set
  (e.g. the Sage-Husa ``b``) over time, median and 10-90% band over episodes plus episode 0, against the
  events.
* ``cdf_<scenario>.png`` and ``rmse_bars_<scenario>.png``: CDF of the horizontal error and the RMSE with
  its bootstrap 95% CI.

Events come from the world (:attr:`envs.sim.gnss.GnssData.event_mask`, bits of :mod:`envs.sim.events`);
they are drawn per episode, so a window is shaded where the event is active in at least half of the
episodes (:func:`event_windows`); an event active almost all the time is named in the legend as
"throughout" instead of shading the whole axes. Labels are the short ones of
:func:`agents.provenance.short_labels`; the tables keep the full specs. Legends sit outside the axes.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

EVENT_NAMES = {"OUTAGE": "GNSS outage", "NOISE": "noise burst", "NLOS_ZONE": "urban zone (NLOS)",
               "OVERPASS": "overpass", "REGIME": "noise regime", "IMU_EVENT": "IMU event", "ROUGH_ROAD": "rough road",
               "MISMATCH": "sigma mismatch", "TREES": "tree cover"}
"""Event bits shown in the plots (:data:`envs.sim.events.EVENT_BITS`) and their legend names; the
re-acquisition transient (per channel, after every outage) is left out."""
EVENT_COLORS = {"OUTAGE": "tab:red", "NOISE": "tab:orange", "NLOS_ZONE": "tab:purple", "OVERPASS": "tab:brown",
                "REGIME": "tab:olive", "IMU_EVENT": "tab:cyan", "ROUGH_ROAD": "tab:gray", "MISMATCH": "tab:pink",
                "TREES": "tab:green"}
TRACK_COLORS = ("C0", "C2", "C4", "C9")
"""Colours of the reference and the focus methods in the trajectory plot (none an event colour)."""
MIN_SHARE = 0.5
"""An event window is shaded where the event is active in at least this share of the episodes."""
THROUGHOUT = 0.95
"""An event active (in at least :data:`MIN_SHARE` of the episodes) over this share of the time is named, not
shaded."""


def _mpl():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def _save(plt, fig, path: Path) -> None:
    """Write and close a figure (``bbox_inches='tight'`` keeps the outside legend)."""
    from envs.outputs import atomic_path
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, bbox_inches="tight", format=Path(path).suffix.lstrip(".") or None)
    finally:
        plt.close(fig)


def event_windows(t, event_mask, min_share: float = MIN_SHARE) -> list[tuple[str, list, bool]]:
    """Event windows of a scenario from the worlds' event masks.

    Parameters
    ----------
    t : (M,) epoch times [s].
    event_mask : (B, M) or (M,) uint event bits (:attr:`envs.sim.gnss.GnssData.event_mask`); None: no events.
    min_share : share of the episodes in which the event must be active at an epoch.

    Returns
    -------
    list of ``(bit name, [(t0, t1), ...] windows [s], throughout)`` for every bit of :data:`EVENT_NAMES` with
    at least one window; ``throughout`` when the windows cover more than :data:`THROUGHOUT` of the epochs.
    A window spans half an epoch interval either side of its first and last epoch.
    """
    from envs.sim.events import EVENT_BITS
    if event_mask is None:
        return []
    t = np.asarray(t, float)
    em = np.atleast_2d(np.asarray(event_mask))
    if em.shape[-1] != t.size:
        raise ValueError(f"event_mask has {em.shape[-1]} epochs, t has {t.size}")
    half = 0.5 * (np.median(np.diff(t)) if t.size > 1 else 1.0)
    out = []
    for name in EVENT_NAMES:
        on = ((em & EVENT_BITS[name]) > 0).mean(0) >= min_share
        if not on.any():
            continue
        edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(np.int8), [0]])))
        wins = [(float(t[a] - half), float(t[b - 1] + half)) for a, b in zip(edges[::2], edges[1::2])]
        out.append((name, wins, bool(on.mean() > THROUGHOUT)))
    return out


def shade_events(ax, windows, legend: bool = True) -> None:
    """Shade ``windows`` (:func:`event_windows`) on ``ax``; an event ``throughout`` gets a legend entry only."""
    for name, wins, throughout in windows:
        label = f"{EVENT_NAMES[name]} (throughout)" if throughout else EVENT_NAMES[name]
        if throughout:
            if legend:
                ax.plot([], [], color=EVENT_COLORS[name], lw=6, alpha=0.3, label=label)
            continue
        for i, (a, b) in enumerate(wins):
            ax.axvspan(a, b, color=EVENT_COLORS[name], alpha=0.15, lw=0,
                       label=label if legend and i == 0 else None)


def _ok(log) -> np.ndarray:
    return ~log.diverged & np.isfinite(log.horizontal_error).all(1)


def focus_methods(logs: dict, ref: str, rmse: dict, learned=(), k: int = 2) -> list[str]:
    """The ``k`` most interesting methods besides the reference: the learned ones first, then the lowest
    horizontal RMSE among the methods a user could run (no oracle), then the oracles."""
    from agents.methods import is_oracle_label
    others = [m for m in logs if m != ref]
    order = sorted(others, key=lambda m: (m not in learned, is_oracle_label(m), rmse.get(m, np.inf)))
    return order[:k]


def plot_error_vs_time(scenario: str, logs: dict, path: Path, ref: str, labels: dict, event_mask=None,
                       focus=None) -> None:
    """Error vs time and the paired difference to the reference (module docstring).

    Parameters
    ----------
    logs : ``{method label: EpisodeLog}`` of the same paired episodes; ``ref`` one of its keys.
    labels : ``{method label: short label}``.
    event_mask : (B, M) event bits of the episodes, or None.
    focus : the method whose paired difference gets a 10-90% band (default: none).
    """
    plt = _mpl()
    fig, (ax, ax2) = plt.subplots(2, 1, figsize=(9, 6.5), dpi=110, sharex=True,
                                  gridspec_kw=dict(height_ratios=[3, 2]))
    t = logs[ref].t
    wins = event_windows(t, event_mask)
    shade_events(ax, wins)
    shade_events(ax2, wins, legend=False)
    ok_ref = _ok(logs[ref])
    colors = {}
    for i, (m, log) in enumerate(logs.items()):
        ok = _ok(log)
        if not ok.any():
            continue
        h = log.horizontal_error[ok]
        style = dict(lw=2.2, color="k") if m == ref else dict(lw=1.3, color=f"C{i % 10}")
        if m.startswith("oracle"):
            style["ls"] = "--"
        (line,) = ax.plot(t, np.median(h, 0), label=labels[m] + (" (reference)" if m == ref else ""), **style)
        colors[m] = line.get_color()
        if m == ref:
            lo, hi = np.quantile(h, [0.1, 0.9], axis=0)
            ax.fill_between(t, lo, hi, color="k", alpha=0.12, lw=0, label=f"{labels[m]}: 10-90% of episodes")
    ax.set_ylabel("horizontal error [m]")
    ax.set_yscale("log")
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(f"{scenario}: horizontal error, median over {int(ok_ref.sum())} episodes")
    ax2.axhline(0.0, color="k", lw=1.5)
    for m, log in logs.items():
        if m == ref or m not in colors:
            continue
        ok = _ok(log) & ok_ref
        if not ok.any():
            continue
        d = log.horizontal_error[ok] - logs[ref].horizontal_error[ok]
        ls = "--" if m.startswith("oracle") else "-"
        ax2.plot(t, np.median(d, 0), color=colors[m], lw=1.3, ls=ls)
        if m == focus:
            lo, hi = np.quantile(d, [0.1, 0.9], axis=0)
            ax2.fill_between(t, lo, hi, color=colors[m], alpha=0.2, lw=0)
            ax2.plot([], [], color=colors[m], lw=6, alpha=0.3, label=f"{labels[m]}: 10-90% of episodes")
    ax2.set_yscale("symlog", linthresh=1.0)
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel(f"minus {labels[ref]} [m]")
    ax2.set_title("paired difference to the reference (episode by episode), median; < 0: better", fontsize=9)
    ax2.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    if focus in colors:
        ax2.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    _save(plt, fig, path)


def plot_trajectory(scenario: str, logs: dict, truth_ne, path: Path, ref: str, labels: dict, focus=(),
                    event_mask0=None) -> None:
    """Episode 0: left, the map in a local east/north frame from the start (equal axes): the truth (thick and
    coloured where an event is active), the reference and the ``focus`` methods; right, the same methods'
    position error (estimate minus truth, east/north, equal axes) with the epochs inside events marked, which
    shows what the map cannot at its scale.

    Parameters
    ----------
    truth_ne : (M, 2) true north, east of episode 0 from its start [m] at the epochs.
    event_mask0 : (M,) event bits of episode 0, or None.
    """
    from envs.sim.events import EVENT_BITS
    plt = _mpl()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5.5), dpi=110)
    ax.plot(truth_ne[:, 1], truth_ne[:, 0], "k-", lw=1.5, label="truth")
    ax.plot(truth_ne[0, 1], truth_ne[0, 0], "k^", ms=8, label="start")
    ax2.plot(0, 0, "k+", ms=12, mew=2)
    wins = event_windows(np.arange(truth_ne.shape[0]), event_mask0)
    for name, _, throughout in wins:
        on = (np.asarray(event_mask0) & EVENT_BITS[name]) > 0
        ax.plot(np.where(on, truth_ne[:, 1], np.nan), np.where(on, truth_ne[:, 0], np.nan), color=EVENT_COLORS[name],
                lw=7, alpha=0.35, solid_capstyle="butt",
                label=EVENT_NAMES[name] + (" (throughout)" if throughout else ""))
    for i, m in enumerate([ref, *[f for f in focus if f != ref]]):
        log = logs[m]
        if log.diverged[0]:
            continue
        c = TRACK_COLORS[i % len(TRACK_COLORS)]
        err = log.pos_err_ned[0, :, :2]
        est = truth_ne + err
        ax.plot(est[:, 1], est[:, 0], lw=1.0, color=c, label=labels[m] + (" (reference)" if m == ref else ""))
        ax2.plot(err[:, 1], err[:, 0], lw=0.8, color=c)
        for name, _, throughout in wins:
            if throughout:
                continue
            on = (np.asarray(event_mask0) & EVENT_BITS[name]) > 0
            ax2.plot(err[on, 1], err[on, 0], "o", ms=4, mfc="none", mec=EVENT_COLORS[name], alpha=0.6)
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_title(f"{scenario}: episode 0, estimates against the truth", fontsize=10)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(alpha=0.3)
    ax2.set_xlabel("east error [m]")
    ax2.set_ylabel("north error [m]")
    marked = any(not throughout for _, _, throughout in wins)
    ax2.set_title("episode 0: position error" + (" (circles: epochs inside an event)" if marked else ""), fontsize=10)
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.grid(alpha=0.3)
    fig.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 0.95))
    fig.tight_layout()
    _save(plt, fig, path)


def plot_actions(scenario: str, logs: dict, path: Path, labels: dict, event_mask=None) -> bool:
    """For every log with ``params`` (a policy's rows), the parameter values it set over time: median and
    10-90% band over the episodes and episode 0, against the event windows. One panel per parameter;
    returns False (and writes nothing) when no log has ``params``."""
    learned = {m: log for m, log in logs.items() if log.params}
    if not learned:
        return False
    names = list(dict.fromkeys(k for log in learned.values() for k in log.params))
    plt = _mpl()
    fig, axes = plt.subplots(len(names), 1, figsize=(9, 3.2 * len(names)), dpi=110, sharex=True, squeeze=False)
    t = next(iter(learned.values())).t
    wins = event_windows(t, event_mask)
    for j, (name, ax) in enumerate(zip(names, axes[:, 0])):
        shade_events(ax, wins, legend=j == 0)
        for i, (m, log) in enumerate(learned.items()):
            if name not in log.params:
                continue
            v = log.params[name]
            c = f"C{i % 10}"
            lo, med, hi = np.nanquantile(v, [0.1, 0.5, 0.9], axis=0)
            ax.plot(t, med, color=c, lw=1.6, label=f"{labels[m]}: median")
            ax.fill_between(t, lo, hi, color=c, alpha=0.2, lw=0, label=f"{labels[m]}: 10-90% of episodes")
            ax.plot(t, v[0], color=c, lw=0.7, ls=":", label=f"{labels[m]}: episode 0")
        ax.set_ylabel(name)
        ax.grid(True, alpha=0.3)
        ax.set_title(f"{scenario}: the parameter {name!r} the policy set, {v.shape[0]} episodes", fontsize=10)
        ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    axes[-1, 0].set_xlabel("time [s]")
    _save(plt, fig, path)
    return True


def plot_cdf(scenario: str, logs: dict, path: Path, labels: dict) -> None:
    """Empirical CDF of the horizontal error over all epochs and episodes."""
    plt = _mpl()
    fig, ax = plt.subplots(figsize=(7.5, 4), dpi=110)
    for m, log in logs.items():
        h = np.sort(log.horizontal_error[~log.diverged].ravel())
        if h.size:
            ax.plot(h, np.arange(1, h.size + 1) / h.size, label=labels[m], lw=1.2,
                    ls="--" if m.startswith("oracle") else "-")
    ax.set_xscale("log")
    ax.set_xlabel("horizontal position error [m]")
    ax.set_ylabel("fraction of epochs")
    ax.set_title(f"{scenario}: CDF of the horizontal error")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    _save(plt, fig, path)


def plot_bars(scenario: str, per: dict, path: Path, labels: dict) -> None:
    """Horizontal RMSE per method with its bootstrap 95% CI (``per``: results.json's rows of the scenario); no
    error bars below :data:`envs.metrics.MIN_CI_EPISODES` episodes (the title says so)."""
    from envs.metrics import MIN_CI_EPISODES, no_ci_text
    plt = _mpl()
    names = list(per)
    v = np.array([per[m]["rmse_h_m"] for m in names])
    lo = np.array([per[m]["rmse_h_ci95_m"][0] for m in names])
    hi = np.array([per[m]["rmse_h_ci95_m"][1] for m in names])
    fig, ax = plt.subplots(figsize=(max(5, 1.0 * len(names)), 4), dpi=110)
    few = min(per[m]["episodes"] for m in names) < MIN_CI_EPISODES
    ax.bar(range(len(names)), v, yerr=None if few else [np.maximum(v - lo, 0), np.maximum(hi - v, 0)], capsize=4,
           color=["tab:gray" if m.startswith("oracle") else "tab:blue" for m in names], alpha=0.8)
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels([labels[m] for m in names], rotation=25, ha="right", fontsize=8)
    ax.set_ylabel("horizontal RMSE [m]")
    ax.set_title(f"{scenario}: RMSE " + (f"({no_ci_text()})" if few else "with 95% bootstrap CI")
                 + (" (oracles grey)" if any(m.startswith("oracle") for m in names) else ""))
    ax.grid(True, axis="y", alpha=0.3)
    _save(plt, fig, path)


def write_plots(out: Path, scenario: str, logs: dict, summary: dict, ref: str, labels: dict, truth_ne,
                event_mask=None, learned=()) -> list[Path]:
    """Every plot of one scenario into ``out``; returns the paths written.

    Parameters
    ----------
    logs : ``{method label: EpisodeLog}``; summary : results.json's ``scenarios[scenario]``.
    ref : the reference's label; labels : ``{label: short label}``.
    truth_ne : (M, 2) episode 0's true north/east from its start [m]; event_mask : (B, M) or None.
    learned : labels of the learned methods (preferred by :func:`focus_methods`).
    """
    out = Path(out)
    rmse = {m: r["rmse_h_m"] for m, r in summary.items()}
    focus = focus_methods(logs, ref, rmse, learned)
    paths = [out / f"{k}_{scenario}.png" for k in ("error_vs_time", "trajectory", "cdf", "rmse_bars")]
    plot_error_vs_time(scenario, logs, paths[0], ref, labels, event_mask, focus[0] if focus else None)
    plot_trajectory(scenario, logs, truth_ne, paths[1], ref, labels, focus,
                    None if event_mask is None else np.asarray(event_mask)[0])
    plot_cdf(scenario, logs, paths[2], labels)
    plot_bars(scenario, summary, paths[3], labels)
    act = out / f"actions_{scenario}.png"
    if plot_actions(scenario, logs, act, labels, event_mask):
        paths.append(act)
    return paths
