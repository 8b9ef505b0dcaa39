"""On-disk cache of parsed RINEX files, keyed by the files' content hash (issue 12).

georinex takes seconds for a few-MB observation file (8 s for the 2.8 MB
Reach file here). :func:`cached_obs` and :func:`cached_nav` store the parsed
:class:`~envs.datasets.rinex.ObsData` / :class:`~envs.datasets.rinex.NavData`
as ``.npz`` files (no pickle) named by the SHA-256 of the file's bytes, the
loader's arguments and :data:`CACHE_VERSION`; a changed file, other
arguments or a new cache layout miss the cache. The summary lines the parser
printed are stored with it and printed again on a hit.

Folder: ``$NAVGYM_CACHE_DIR`` if set (``none`` turns the cache off), else
``~/.cache/navgym``. A cache entry that cannot be read is parsed again and
rewritten.
"""
from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from .ephemeris import KeplerEphemeris
from .rinex import NavData, ObsData, load_nav, load_obs

__all__ = ["CACHE_VERSION", "cache_dir", "file_digest", "cached_obs", "cached_nav"]

CACHE_VERSION = 2
"""Bumped whenever the loaders' output for the same input changes."""


def cache_dir() -> Path | None:
    """The cache folder (module docstring), or None when ``$NAVGYM_CACHE_DIR`` is ``none``."""
    env = os.environ.get("NAVGYM_CACHE_DIR")
    if env is not None and env.strip().lower() in ("none", "off", "0", ""):
        return None
    return Path(env).expanduser() if env else Path.home() / ".cache" / "navgym"


def file_digest(path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _entry(kind: str, path, args: dict) -> Path | None:
    folder = cache_dir()
    if folder is None:
        return None
    key = hashlib.sha256(json.dumps([kind, CACHE_VERSION, file_digest(path), args], sort_keys=True,
                                    default=str).encode()).hexdigest()[:32]
    return folder / f"{kind}-{Path(path).name}-{key}.npz"


def _save(entry: Path, arrays: dict) -> None:
    entry.parent.mkdir(parents=True, exist_ok=True)
    tmp = entry.with_name(entry.name + f".{os.getpid()}.tmp")
    with open(tmp, "wb") as fh:
        np.savez(fh, **arrays)
    os.replace(tmp, entry)                         # atomic: a reader never sees half a file


def _load(entry: Path | None):
    if entry is None or not entry.is_file():
        return None
    try:
        with np.load(entry, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (OSError, ValueError, KeyError):        # unreadable: parse again
        return None


def cached_obs(path, notes=None, **kw) -> ObsData:
    """:func:`~envs.datasets.rinex.load_obs` through the cache (same arguments; ``notes`` replayed on a hit)."""
    path = Path(path)
    args = {k: (sorted((s, list(c)) for s, c in v.items()) if isinstance(v, dict) else v) for k, v in kw.items()}
    entry = _entry("obs", path, args) if path.is_file() else None
    z = _load(entry)
    if z is not None:
        for line in z["notes"]:
            if notes is not None:
                notes(str(line))
        return ObsData(t=z["t"], week_ref=int(z["week_ref"]), sv=z["sv"], system=z["system"], prn=z["prn"],
                       pr=z["pr"], code=z["code"], cn0=z["cn0"],
                       approx_position=z["approx"] if z["approx"].size else None, path=path,
                       doppler=z["doppler"] if z["doppler"].ndim == 2 else None)
    lines = []

    def keep(line):
        lines.append(line)
        if notes is not None:
            notes(line)

    obs = load_obs(path, notes=keep, **kw)
    if entry is not None:
        _save(entry, {"t": obs.t, "week_ref": obs.week_ref, "sv": obs.sv.astype(str), "system": obs.system,
                      "prn": obs.prn, "pr": obs.pr, "code": obs.code.astype(str), "cn0": obs.cn0,
                      "approx": np.zeros(0) if obs.approx_position is None else obs.approx_position,
                      "doppler": np.zeros(0) if obs.doppler is None else obs.doppler,
                      "notes": np.array(lines, dtype=str)})
    return obs


def cached_nav(path, week_ref: int | None = None) -> NavData:
    """:func:`~envs.datasets.rinex.load_nav` through the cache."""
    path = Path(path)
    entry = _entry("nav", path, {"week_ref": week_ref}) if path.is_file() else None
    z = _load(entry)
    fields = KeplerEphemeris.__dataclass_fields__
    if z is not None:
        return NavData(ephemeris=KeplerEphemeris(**{f: z["eph_" + f] for f in fields}), week_ref=int(z["week_ref"]),
                       iono_alpha=z["alpha"] if z["alpha"].size else None,
                       iono_beta=z["beta"] if z["beta"].size else None,
                       skipped=tuple(str(s) for s in z["skipped"]), path=path)
    nav = load_nav(path, week_ref=week_ref)
    if entry is not None:
        _save(entry, {**{"eph_" + f: np.asarray(getattr(nav.ephemeris, f)) for f in fields},
                      "week_ref": nav.week_ref,
                      "alpha": np.zeros(0) if nav.iono_alpha is None else nav.iono_alpha,
                      "beta": np.zeros(0) if nav.iono_beta is None else nav.iono_beta,
                      "skipped": np.array(nav.skipped, dtype=str)})
    return nav
