"""The PNG plots of eval.py, one set per scenario.

* ``error_vs_time_<scenario>.png``: top, the median horizontal error of every method over the episodes
  (lines) with the reference's 10-90% band only; bottom, the paired difference to the reference over time
  (method minus reference, episode by episode: median line per method, 10-90% band for the focus method).
  The scenario's event windows are shaded on both.
* ``trajectory_<scenario>.png``: episode 0 in a local east/north frame (equal axes) from the start: the truth,
  the reference and the one or two most interesting other methods (:func:`focus_methods`), the truth drawn
  thick where an event is active, zoomed on the epoch where the estimates lie farthest apart (the whole track
  small beside it), and the position errors beside the map.
* ``actions_<scenario>.png`` (only with learned methods): for each policy row, the filter parameter it set
  (e.g. the Sage-Husa ``b``) over time, median and 10-90% band over episodes plus episode 0, against the
  events.
* ``cdf_<scenario>.png``: CDF of the horizontal error (left is better).
* ``paired_<scenario>.png``: each method's paired difference of the horizontal RMSE to the reference with its
  bootstrap 95% CI, coloured by verdict (the note's verdicts); no CI below
  :data:`envs.metrics.MIN_CI_EPISODES` episodes.

Events come from the world (:attr:`envs.sim.gnss.GnssData.event_mask`, bits of :mod:`envs.sim.events`);
they are drawn per episode, so a window is shaded where the event is active in at least half of the
episodes (:func:`event_windows`); an event active almost all the time is named in the legend as
"throughout" instead of shading the whole axes. Labels are the short ones of
:func:`agents.provenance.short_labels`; results.json keeps the full specs. Legends sit outside the axes; tick
labels are plain decimals (:func:`plain_ticks`).
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
SYMLOG_ABOVE_M = 5.0
"""The paired-difference panel of the error plot turns symlog (linear within 1 m) when a drawn difference
exceeds this [m]; below, it stays linear."""
THROUGHOUT = 0.95
"""An event active (in at least :data:`MIN_SHARE` of the episodes) over this share of the time is named, not
shaded."""


def _mpl():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plain_ticks(ax, axis: str = "y") -> None:
    """Plain decimal tick labels (``0.3``, ``2``, ``10``; never ``3x10^-1``) on a log, symlog or linear axis:
    the label of a minor tick of a log axis is shown where matplotlib would show one (an axis spanning less
    than about a decade)."""
    from matplotlib.ticker import FuncFormatter, LogFormatter, ScalarFormatter

    class PlainLog(LogFormatter):  # matplotlib's choice of the labelled ticks, written as %g
        def _num_to_string(self, x, vmin, vmax):
            return f"{x:.3g}"
    a = ax.xaxis if axis == "x" else ax.yaxis
    scale = a.get_scale()
    if scale == "log":
        a.set_major_formatter(PlainLog(labelOnlyBase=False))
        a.set_minor_formatter(PlainLog(labelOnlyBase=False, minor_thresholds=(1, 0.4)))
    elif scale == "symlog":
        a.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    else:
        f = ScalarFormatter(useOffset=False)
        f.set_scientific(False)
        a.set_major_formatter(f)


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
    plain_ticks(ax)
    ax.grid(True, which="both", alpha=0.3)
    ax.set_title(f"{scenario}: horizontal error, median over {int(ok_ref.sum())} episodes")
    ax2.axhline(0.0, color="k", lw=1.5)
    big = [0.0]  # the largest |difference| drawn [m]
    for m, log in logs.items():
        if m == ref or m not in colors:
            continue
        ok = _ok(log) & ok_ref
        if not ok.any():
            continue
        d = log.horizontal_error[ok] - logs[ref].horizontal_error[ok]
        ls = "--" if m.startswith("oracle") else "-"
        med = np.median(d, 0)
        ax2.plot(t, med, color=colors[m], lw=1.3, ls=ls)
        big.append(float(np.nanmax(np.abs(med), initial=0.0)))
        if m == focus:
            lo, hi = np.quantile(d, [0.1, 0.9], axis=0)
            ax2.fill_between(t, lo, hi, color=colors[m], alpha=0.2, lw=0)
            big.append(float(np.nanmax(np.abs([lo, hi]), initial=0.0)))
            ax2.plot([], [], color=colors[m], lw=6, alpha=0.3, label=f"{labels[m]}: 10-90% of episodes")
    if max(big) > SYMLOG_ABOVE_M:  # spikes of tens of metres beside centimetres: compress them
        ax2.set_yscale("symlog", linthresh=1.0)
    plain_ticks(ax2)
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel(f"minus {labels[ref]} [m]")
    ax2.set_title("paired difference to the reference (episode by episode), median; < 0: better", fontsize=9)
    ax2.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    if focus in colors:
        ax2.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    _save(plt, fig, path)


ZOOM_MIN_HALF_M = 0.5
"""Smallest half-width of the trajectory plot's zoom [m]."""
ZOOM_SKIP_FRACTION = 0.1
"""Leading share of the epochs the zoom does not choose from: every filter starts from the same initial error,
and their transients differ most there, which says little about the methods."""


def zoom_epoch(logs: dict, shown: list, ref: str) -> tuple[int, float] | None:
    """``(epoch, distance [m])`` of episode 0 where a shown method's horizontal estimate lies farthest from the
    reference's (the trajectory plot's zoom) after the first :data:`ZOOM_SKIP_FRACTION` of the epochs (the
    initial convergence), or None when no other shown method has a finite track there."""
    e_ref = logs[ref].pos_err_ned[0, :, :2]
    far = np.full(e_ref.shape[0], np.nan)
    for m in shown:
        if m == ref or logs[m].diverged[0]:
            continue
        far = np.fmax(far, np.hypot(*(logs[m].pos_err_ned[0, :, :2] - e_ref).T))
    far[:int(ZOOM_SKIP_FRACTION * far.shape[0])] = np.nan
    if not np.isfinite(far).any():
        return None
    k = int(np.nanargmax(far))
    return k, float(far[k])


def plot_trajectory(scenario: str, logs: dict, truth_ne, path: Path, ref: str, labels: dict, focus=(),
                    event_mask0=None) -> None:
    """Episode 0 of the reference and the ``focus`` methods. Left, the map zoomed on the epoch where their
    estimates lie farthest apart (:func:`zoom_epoch`): the truth (thick and coloured where an event is
    active), each estimate with a dot per epoch and a line from the truth to it at that epoch, in a local
    east/north frame from the start (equal axes), with the whole track as an overview beside the legend (the
    zoom marked); a map at the track's scale hides the metre-scale differences. Right, the same methods'
    position error (estimate minus truth, east/north, equal axes), the epochs inside events circled and the
    zoomed epoch marked.

    Parameters
    ----------
    truth_ne : (M, 2) true north, east of episode 0 from its start [m] at the epochs.
    event_mask0 : (M,) event bits of episode 0, or None.
    """
    plt = _mpl()
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(12, 5.5), dpi=110)
    shown = [m for m in [ref, *[f for f in focus if f != ref]] if not logs[m].diverged[0]]
    wins = event_windows(np.arange(truth_ne.shape[0]), event_mask0)
    _track_events(ax, truth_ne, wins, event_mask0)
    zoom = zoom_epoch(logs, shown, ref)
    k = zoom[0] if zoom else None
    ax2.plot(0, 0, "k+", ms=12, mew=2)
    reach = 0.0  # the largest estimate distance from the truth at the zoomed epoch [m]
    for m in shown:
        c = TRACK_COLORS[[ref, *focus].index(m) % len(TRACK_COLORS)]
        err = logs[m].pos_err_ned[0, :, :2]
        est = truth_ne + err
        ax.plot(est[:, 1], est[:, 0], lw=1.0, color=c, marker=".", ms=4 if k is not None else 0,
                label=labels[m] + (" (reference)" if m == ref else ""))
        ax2.plot(err[:, 1], err[:, 0], lw=0.8, color=c)
        _error_events(ax2, err, wins, event_mask0)
        if k is not None:
            ax.plot([truth_ne[k, 1], est[k, 1]], [truth_ne[k, 0], est[k, 0]], color=c, lw=0.8, ls=":")
            ax2.plot(err[k, 1], err[k, 0], marker="s", ms=7, color=c, ls="none")
            reach = max(reach, float(np.hypot(*err[k])))
    t = logs[ref].t
    if k is not None:
        half = max(ZOOM_MIN_HALF_M, 1.3 * reach)
        ax.plot(truth_ne[k, 1], truth_ne[k, 0], "kx", ms=9, mew=2, label=f"truth at t = {t[k]:.1f} s")
        ax.set_xlim(truth_ne[k, 1] - half, truth_ne[k, 1] + half)
        ax.set_ylim(truth_ne[k, 0] - half, truth_ne[k, 0] + half)
        ax.set_aspect("equal", adjustable="box")
        ax.set_title(f"{scenario}: episode 0 zoomed on t = {t[k]:.1f} s,\nwhere the estimates lie farthest "
                     f"apart ({zoom[1]:.2g} m)", fontsize=10)
        _overview(ax2, truth_ne, truth_ne[k], half)
    else:
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_title(f"{scenario}: episode 0, estimates against the truth", fontsize=10)
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    from matplotlib.ticker import MaxNLocator
    ax.xaxis.set_major_locator(MaxNLocator(5))  # map coordinates are long numbers: few ticks stay readable
    ax.grid(alpha=0.3)
    plain_ticks(ax, "x"), plain_ticks(ax, "y")
    ax2.set_xlabel("east error [m]")
    ax2.set_ylabel("north error [m]")
    notes = (["circles: epochs inside an event"] if any(not thr for _, _, thr in wins) else []) + \
        (["squares: the zoomed epoch"] if k is not None else [])
    ax2.set_title("episode 0: position error" + (f" ({'; '.join(notes)})" if notes else ""), fontsize=10)
    ax2.set_aspect("equal", adjustable="datalim")
    ax2.grid(alpha=0.3)
    fig.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="upper left", bbox_to_anchor=(1.0, 0.95))
    fig.tight_layout()
    _save(plt, fig, path)


def _track_events(ax, truth_ne, wins, event_mask0) -> None:
    """The truth of episode 0 on the map, thick and coloured where an event is active, and its start."""
    from envs.sim.events import EVENT_BITS
    ax.plot(truth_ne[:, 1], truth_ne[:, 0], "k-", lw=1.5, label="truth")
    ax.plot(truth_ne[0, 1], truth_ne[0, 0], "k^", ms=8, label="start")
    for name, _, throughout in wins:
        on = (np.asarray(event_mask0) & EVENT_BITS[name]) > 0
        ax.plot(np.where(on, truth_ne[:, 1], np.nan), np.where(on, truth_ne[:, 0], np.nan), color=EVENT_COLORS[name],
                lw=7, alpha=0.35, solid_capstyle="butt",
                label=EVENT_NAMES[name] + (" (throughout)" if throughout else ""))


def _error_events(ax2, err, wins, event_mask0) -> None:
    """Circle the epochs of ``err`` inside an event (not those of an event active throughout)."""
    from envs.sim.events import EVENT_BITS
    for name, _, throughout in wins:
        if throughout:
            continue
        on = (np.asarray(event_mask0) & EVENT_BITS[name]) > 0
        ax2.plot(err[on, 1], err[on, 0], "o", ms=4, mfc="none", mec=EVENT_COLORS[name], alpha=0.6)


def _overview(ax2, truth_ne, centre, half) -> None:
    """The whole track of episode 0, small, to the right of ``ax2`` (under the legend), the zoom marked."""
    ov = ax2.inset_axes([1.06, 0.0, 0.36, 0.36])
    ov.plot(truth_ne[:, 1], truth_ne[:, 0], "k-", lw=1.0)
    ov.plot(truth_ne[0, 1], truth_ne[0, 0], "k^", ms=5)
    ov.plot(centre[1], centre[0], "o", ms=9, mfc="none", mec="tab:red", mew=1.5)
    ov.set_aspect("equal", adjustable="datalim")
    ov.set_xticks([]), ov.set_yticks([])
    ov.set_title(f"whole track (circle: the zoom, {2 * half:.2g} m wide)", fontsize=7)


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
    plain_ticks(ax, "x")
    ax.set_xlabel("horizontal position error [m] (log scale)")
    ax.set_ylabel("fraction of epochs with at most this error")
    ax.set_title(f"{scenario}: CDF of the horizontal error over all epochs and episodes (left is better)",
                 fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0)
    _save(plt, fig, path)


VERDICT_STYLE = {"lower": ("tab:green", "lower RMSE than the reference (95% CI below 0)"),
                 "higher": ("tab:red", "higher RMSE than the reference (95% CI above 0)"),
                 "not significant": ("tab:gray", "no significant difference (95% CI includes 0)"),
                 "no CI": ("k", "")}
"""Colour and legend text of each verdict (:func:`envs.metrics.paired_verdict`) in :func:`plot_paired`."""


def _paired_text(p: dict, verdict: str) -> str:
    """The right-hand column of :func:`plot_paired`: the difference, its CI (or why none) and the percentage."""
    d = p["diff_rmse_h_m"]
    if p["episodes"] == 0 or d is None or not np.isfinite(d):
        return "no paired episode"
    small = max(abs(x) for x in [d, *(p["diff_rmse_h_ci95_m"] if verdict != "no CI" else [])]) < 0.1

    def m(x):
        return f"{x:+.3f}" if small else f"{x:+.2f}"
    rel = f"{100 * p['rel_diff']:+.1f}%"
    if verdict == "no CI":
        return f"{m(d)} m ({rel})"
    lo, hi = p["diff_rmse_h_ci95_m"]
    return f"{m(d)} m [{m(lo)}, {m(hi)}] ({rel})"


def plot_paired(scenario: str, rows: dict, path: Path, ref: str, labels: dict) -> dict:
    """The paired difference of every method's horizontal RMSE to the reference's, with its 95% bootstrap CI:
    the picture of the verdicts of the results note.

    One row per method (``--methods`` order, the reference on top at 0), a point at the difference (method
    minus reference, over the episodes where neither diverged) and a bar over its CI, coloured by verdict
    (:func:`envs.metrics.paired_verdict`): green lower, red higher, grey not significant; a method with fewer
    than :data:`envs.metrics.MIN_CI_EPISODES` paired episodes is a hollow point without a bar, its label says
    so. Oracle rows are diamonds. The right-hand column gives the numbers.

    Parameters
    ----------
    rows : ``{label: results.json row}``, the reference's and the others' (with ``paired_vs_reference``; the
        pooled rows of seed groups too).
    ref : the reference's label; labels : ``{label: short label}``.

    Returns
    -------
    ``{label: verdict}`` of the methods drawn (the reference left out).
    """
    from envs.metrics import MIN_CI_EPISODES, paired_verdict
    plt = _mpl()
    others = [m for m in rows if m != ref and rows[m].get("paired_vs_reference")]
    n = len(others) + 1
    fig, ax = plt.subplots(figsize=(9.5, 1.6 + 0.42 * n), dpi=110)
    verdicts, right, used = {}, [], set()
    ax.axvline(0.0, color="k", lw=1.2)
    ax.plot([0.0], [0], marker="*", ms=13, color="k", ls="none")
    r = rows[ref]
    right.append(f"RMSE {r['rmse_h_m']:.2f} m" if r.get("rmse_h_m") is not None else "")
    ylabels = [f"{labels.get(ref, ref)} (reference)"]
    span = [0.0]
    for y, m in enumerate(others, start=1):
        p = rows[m]["paired_vs_reference"]
        v = verdicts[m] = paired_verdict(p)
        color, _ = VERDICT_STYLE[v]
        marker = "D" if m.startswith("oracle") else "o"
        few = v == "no CI"
        ylabels.append(labels.get(m, m) + (f" (n < {MIN_CI_EPISODES}: no CI)" if few else "")
                       + (f" ({rows[m]['diverged']} diverged)" if rows[m].get("diverged") else ""))
        right.append(_paired_text(p, v))
        d = p["diff_rmse_h_m"]
        if d is None or not np.isfinite(d):
            continue
        span.append(d)
        if not few:
            lo, hi = p["diff_rmse_h_ci95_m"]
            ax.plot([lo, hi], [y, y], color=color, lw=2.5, solid_capstyle="butt")
            span += [lo, hi]
        ax.plot([d], [y], marker=marker, ms=7, color=color, mfc="white" if few else color, ls="none")
        used.add((v, marker == "D"))
    _paired_axes(ax, scenario, ylabels, right, span, labels.get(ref, ref))
    _paired_legend(ax, used)
    _save(plt, fig, path)
    return verdicts


def _paired_axes(ax, scenario: str, ylabels: list, right: list, span: list, ref_label: str) -> None:
    """Ticks, the right-hand number column, limits and titles of :func:`plot_paired`."""
    n = len(ylabels)
    ax.set_yticks(range(n))
    ax.set_yticklabels(ylabels, fontsize=8)
    ax.set_ylim(n - 0.5, -0.5)  # the first method on top
    lo, hi = min(span), max(span)
    pad = 0.08 * (hi - lo) if hi > lo else max(0.05, 0.1 * abs(hi))
    ax.set_xlim(lo - pad, hi + pad)
    twin = ax.twinx()
    twin.set_ylim(ax.get_ylim())
    twin.set_yticks(range(n))
    twin.set_yticklabels(right, fontsize=8)
    twin.tick_params(length=0)
    plain_ticks(ax, "x")
    ax.grid(True, axis="x", alpha=0.3)
    ax.set_xlabel(f"horizontal RMSE minus the reference's ({ref_label}) [m], paired episodes; < 0: lower error")
    ax.set_title(f"{scenario}: paired difference to the reference, 95% bootstrap CI", fontsize=10)


def _paired_legend(ax, used: set) -> None:
    """The legend of :func:`plot_paired`: the verdicts drawn, the hollow point and the oracle diamond."""
    from envs.metrics import MIN_CI_EPISODES
    from matplotlib.lines import Line2D
    handles = [Line2D([], [], marker="*", ms=11, color="k", ls="none", label="the reference (0 by definition)")]
    for v in ("lower", "higher", "not significant"):
        if any(u[0] == v for u in used):
            color, text = VERDICT_STYLE[v]
            handles.append(Line2D([], [], marker="o", color=color, lw=2.5, label=text))
    if any(u[0] == "no CI" for u in used):
        handles.append(Line2D([], [], marker="o", mfc="white", color="k", ls="none",
                              label=f"fewer than {MIN_CI_EPISODES} episodes: no CI, no verdict"))
    if any(u[1] for u in used):
        handles.append(Line2D([], [], marker="D", color="0.4", ls="none",
                              label="oracle (knows the truth; not a method a user could run)"))
    height_in = ax.get_position().height * ax.figure.get_figheight()
    ax.legend(handles=handles, fontsize=8, loc="upper left", bbox_to_anchor=(0.0, -0.5 / height_in), ncol=2,
              frameon=False)  # below the x label (0.5 inch under the axes)


def write_plots(out: Path, scenario: str, logs: dict, summary: dict, ref: str, labels: dict, truth_ne,
                event_mask=None, learned=(), pooled: dict | None = None) -> list[Path]:
    """Every plot of one scenario into ``out``; returns the paths written.

    Parameters
    ----------
    logs : ``{method label: EpisodeLog}``; summary : results.json's ``scenarios[scenario]``.
    ref : the reference's label; labels : ``{label: short label}``.
    truth_ne : (M, 2) episode 0's true north/east from its start [m]; event_mask : (B, M) or None.
    learned : labels of the learned methods (preferred by :func:`focus_methods`).
    pooled : ``{label: row}`` of the pooled rows of seed groups (results.json's ``seed_groups``; their
        labels in ``labels``), drawn in the paired-difference plot after the methods.
    """
    out = Path(out)
    rmse = {m: r["rmse_h_m"] for m, r in summary.items()}
    focus = focus_methods(logs, ref, rmse, learned)
    paths = [out / f"{k}_{scenario}.png" for k in ("error_vs_time", "trajectory", "cdf", "paired")]
    plot_error_vs_time(scenario, logs, paths[0], ref, labels, event_mask, focus[0] if focus else None)
    plot_trajectory(scenario, logs, truth_ne, paths[1], ref, labels, focus,
                    None if event_mask is None else np.asarray(event_mask)[0])
    plot_cdf(scenario, logs, paths[2], labels)
    plot_paired(scenario, {**summary, **(pooled or {})}, paths[3], ref, labels)
    act = out / f"actions_{scenario}.png"
    if plot_actions(scenario, logs, act, labels, event_mask):
        paths.append(act)
    return paths
