"""Statistics, verdicts and claims of the reproductions: paired relative changes with bootstrap CIs
(:func:`paired_change`), the verdict rule (:func:`verdict`), one claim entry (:func:`make_claim`) and the
Markdown helpers of the reports."""
from __future__ import annotations

import numpy as np

from envs.metrics import MIN_CI_EPISODES, no_ci_text

N_BOOT = 2000
"""Bootstrap resamples of the paired confidence intervals."""


def _rmse(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x)))) if x.size else float("nan")


def paired_change(a: np.ndarray, b: np.ndarray, stat: str = "rms", n_boot: int = N_BOOT, seed: int = 0):
    """Relative change of a pooled statistic of A against B, ``stat(A) / stat(B) - 1``, with a paired CI.

    Parameters
    ----------
    a, b : (E, M) errors of E paired episodes (the same episodes, rows in the same order).
    stat : ``'rms'`` (pooled RMS over all epochs) or ``'mean_abs'`` (pooled mean absolute value).
    n_boot : bootstrap resamples (episodes resampled with replacement, the same indices for A and B).

    Returns
    -------
    (change, (low, high)) as fractions (-0.1 = A is 10 % below B); nan without episodes.
    """
    if stat == "rms":
        pa, pb = np.mean(np.square(a), 1), np.mean(np.square(b), 1)
        f = np.sqrt
    elif stat == "mean_abs":
        pa, pb = np.mean(np.abs(a), 1), np.mean(np.abs(b), 1)
        f = lambda x: x  # noqa: E731
    else:
        raise ValueError(f"stat must be 'rms' or 'mean_abs', got {stat!r}")
    E = pa.size
    if E == 0:
        return float("nan"), (float("nan"), float("nan"))
    point = float(f(pa.mean()) / f(pb.mean()) - 1.0)
    idx = np.random.default_rng(seed).integers(0, E, size=(n_boot, E))
    boot = f(pa[idx].mean(1)) / f(pb[idx].mean(1)) - 1.0
    return point, (float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975)))


VERDICTS = ("reproduced", "direction only", "not reproduced")
"""Claim verdicts: the paper's effect with at least half its size / significant in the paper's direction but
less than half its size / not significant in the paper's direction (or opposite). A claim behind fewer than
:data:`envs.metrics.MIN_CI_EPISODES` episodes has none (``None``, :func:`make_claim`)."""


def verdict(paper_change: float, point: float, ci=None, magnitude: bool = True) -> str:
    """Verdict of a relative-change claim (fractions; negative = A below B).

    Parameters
    ----------
    paper_change : the paper's relative change (its sign is the claimed direction).
    point : our relative change.
    ci : our 95% CI (low, high), or None (then the point estimate decides the direction).
    magnitude : also require at least half the paper's size for ``'reproduced'``.

    Returns
    -------
    one of :data:`VERDICTS`.
    """
    lo, hi = (point, point) if ci is None else ci
    if not all(np.isfinite(x) for x in (lo, hi, point)) or paper_change == 0:
        return "not reproduced"
    side = hi < 0 if paper_change < 0 else lo > 0
    if not side:
        return "not reproduced"
    if magnitude and abs(point) < 0.5 * abs(paper_change):
        return "direction only"
    return "reproduced"


def _smaller(point, paper) -> str:
    return f"significant in the paper's direction but {_pct(point)} against the paper's {_pct(paper)}"


def _max_dev(a, b) -> float:
    """Largest Euclidean distance between matching rows of two (..., 3) error arrays (nan if empty)."""
    return float(np.linalg.norm(a - b, axis=-1).max()) if a.size else float("nan")


def _md_header(*cols) -> list[str]:
    return ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]


def _md_row(*cells) -> str:
    return "| " + " | ".join(str(c) for c in cells) + " |"


def _pct(x, digits=1) -> str:
    return "nan" if x is None or not np.isfinite(x) else f"{100 * x:+.{digits}f}%"


def _ci_pct(ci, digits=1) -> str:
    """``[lo, hi]`` in percent; a missing CI (below the minimum episodes) says so."""
    if ci is None:
        return f"({no_ci_text()})"
    return f"[{_pct(ci[0], digits)}, {_pct(ci[1], digits)}]"


def _ci_or_none(ci, episodes: int):
    """A paired CI as a list, or None below :data:`envs.metrics.MIN_CI_EPISODES` episodes (or without one)."""
    return None if ci is None or episodes < MIN_CI_EPISODES else list(ci)


def make_claim(cid, text, source, paper, ours, ci, verdict, why="", *, episodes: int) -> dict:
    """One entry of ``results["claims"]`` (module docstring).

    Parameters
    ----------
    cid, text, source : the claim's id, its sentence and where the paper makes it.
    paper, ours : the paper's figure and ours (a fraction, or a string).
    ci : our 95% CI ``(lo, hi)`` or None; verdict : one of :data:`VERDICTS`; why : why not reproduced.
    episodes : the episodes behind ``ours`` (the paired episodes without a divergence; all episodes for a
        time claim).

    Returns
    -------
    dict with ``id``, ``claim``, ``source``, ``paper``, ``ours``, ``ci95``, ``verdict``, ``why``,
    ``episodes``. Below :data:`envs.metrics.MIN_CI_EPISODES` episodes there is no verdict and no CI
    (``verdict`` and ``ci95`` None, ``why`` :func:`envs.metrics.no_ci_text`), as eval.py's tables; from it on,
    the given ones (``why`` empty for a reproduced claim).
    """
    episodes = int(episodes)
    if episodes < MIN_CI_EPISODES:
        ci, verdict, why = None, None, no_ci_text()
    return {"id": cid, "claim": text, "source": source, "paper": paper, "ours": ours,
            "ci95": list(ci) if ci is not None else None, "verdict": verdict,
            "why": why if verdict != "reproduced" else "", "episodes": episodes}


def _claims_table(claims) -> list[str]:
    out = ["| claim | source | paper | ours (95% CI) | verdict | why (if not reproduced) |", "|---|---|---|---|---|---|"]
    for c in claims:
        ours = c["ours"] if isinstance(c["ours"], str) else _pct(c["ours"])
        if c["ci95"] is not None and not isinstance(c["ours"], str):
            ours += " " + _ci_pct(c["ci95"])
        paper = c["paper"] if isinstance(c["paper"], str) else _pct(c["paper"])
        if c["verdict"] is None:  # below the minimum episodes: no verdict (why: no_ci_text())
            out.append(f"| {c['claim']} | {c['source']} | {paper} | {ours} | {c['why']} | |")
        else:
            out.append(f"| {c['claim']} | {c['source']} | {paper} | {ours} | **{c['verdict']}** | {c['why']} |")
    return out


def verdict_summary(claims: list[dict]) -> str:
    """The report's closing count of verdicts: how many claims were reproduced of those judged, and how many
    have no verdict (fewer than :data:`envs.metrics.MIN_CI_EPISODES` episodes, :func:`make_claim`)."""
    judged = [c for c in claims if c["verdict"] is not None]
    none = len(claims) - len(judged)
    if not judged:
        return (f"No verdicts: {no_ci_text()} (every claim has fewer than {MIN_CI_EPISODES} episodes behind it; "
                f"run at least {MIN_CI_EPISODES}).")
    n_rep = sum(c["verdict"] == "reproduced" for c in judged)
    tail = f"; {none} without a verdict ({no_ci_text()})" if none else ""
    return f"{n_rep} of {len(judged)} claims reproduced{tail}."
