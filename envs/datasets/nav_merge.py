"""Several RINEX navigation files as one, and the check that every observed satellite has an orbit (issue 12).

A recording often comes with one navigation file per system (``*.24N`` GPS,
``*.24L`` Galileo, ``*.24C`` BeiDou) or a mixed one. :func:`merge_nav`
concatenates their Keplerian records (GPS, Galileo, BeiDou MEO/IGSO; GLONASS
state vectors and BeiDou GEOs stay unsupported, as in
:func:`envs.datasets.rinex.load_nav`), drops exact repeats, and takes the
ionosphere model from the first file that has the GPS Klobuchar coefficients
(``IONOSPHERIC CORR GPSA / GPSB``): a Galileo-only file has none.

:func:`check_coverage` is the "no silent drops" rule for orbits: a system
listed in the spec with no observation, or with no ephemeris at all, is an
error naming the files; satellites without a healthy ephemeris within its age
limit (at some or all epochs) are dropped with one printed summary line per
system.
"""
from __future__ import annotations

import numpy as np

from .ephemeris import KeplerEphemeris, select_ephemeris
from .epochs import SYSTEM_LETTERS
from .rinex import _SYSTEM_NAME, NavData, ObsData

__all__ = ["merge_nav", "check_coverage"]

_KEY_FIELDS = ("system", "prn", "toe", "toc", "af0", "m0")


def merge_nav(navs) -> NavData:
    """One :class:`NavData` of several (all loaded with the same ``week_ref``).

    Records are concatenated in file order; a record repeated in a later file (same system, PRN, toe, toc,
    clock bias and mean anomaly) is dropped. The Klobuchar coefficients are the first file's that has them.

    Raises
    ------
    ValueError : no file, or files loaded against different GPS weeks.
    """
    navs = list(navs)
    if not navs:
        raise ValueError("merge_nav needs at least one navigation file")
    if len({n.week_ref for n in navs}) != 1:
        raise ValueError(f"navigation files loaded against different GPS weeks "
                         f"{[(str(n.path), n.week_ref) for n in navs]}: load them with one week_ref")
    if len(navs) == 1:
        return navs[0]
    fields = KeplerEphemeris.__dataclass_fields__
    cat = {f: np.concatenate([np.asarray(getattr(n.ephemeris, f)) for n in navs]) for f in fields}
    key = np.stack([cat[f].astype(np.float64) for f in _KEY_FIELDS], -1)
    _, first = np.unique(key, axis=0, return_index=True)
    keep = np.sort(first)
    eph = KeplerEphemeris(**{f: cat[f][keep] for f in fields})
    iono = next((n for n in navs if n.iono_alpha is not None), None)
    skipped = tuple(dict.fromkeys(s for n in navs for s in n.skipped))
    return NavData(ephemeris=eph, week_ref=navs[0].week_ref, iono_alpha=None if iono is None else iono.iono_alpha,
                   iono_beta=None if iono is None else iono.iono_beta, skipped=skipped, path=navs[0].path)


def check_coverage(obs: ObsData, nav: NavData, spec, note) -> ObsData:
    """Errors or summary lines for observed satellites without orbits (module docstring).

    Parameters
    ----------
    obs, nav : the observations and the (merged) navigation data.
    spec : the :class:`~envs.datasets.spec.DatasetSpec` (its systems, signals and file names for messages).
    note : callable taking one summary line.

    Returns
    -------
    ``obs`` unchanged (the epochs builder masks the satellites without an ephemeris).
    """
    g = spec.gnss
    navs = ", ".join(p.name for p in g.nav)
    M, S = obs.pr.shape
    rec = select_ephemeris(nav.ephemeris, obs.system[None], obs.prn[None], obs.t[:, None])
    seen = np.isfinite(obs.pr)
    for letter in g.systems:
        name = _SYSTEM_NAME[letter]
        cols = np.nonzero(obs.system == SYSTEM_LETTERS[letter])[0]
        if cols.size == 0:
            codes = "/".join(dict(g.signals).get(letter, ()))
            raise ValueError(f"{obs.path}: gnss.systems lists {name} but the file has no {name} satellite "
                             f"with a {codes} observation: remove {letter!r} from gnss.systems or list its "
                             f"code in gnss.signals.{letter}")
        if not np.any(nav.ephemeris.system == SYSTEM_LETTERS[letter]):
            why = "; ".join(s for s in nav.skipped if s.startswith(letter)) or "none in the files"
            raise ValueError(f"{spec.path}: {name}: {cols.size} satellites observed but no {name} ephemeris in "
                             f"gnss.nav ({navs}; {why}): add its navigation file or remove {letter!r} from "
                             f"gnss.systems")
        never, partial = [], 0
        for j in cols:
            obs_j = seen[:, j]
            if not obs_j.any():
                continue
            miss = obs_j & (rec[:, j] < 0)
            if miss.sum() == obs_j.sum():
                never.append(str(obs.sv[j]))
            elif miss.any():
                partial += int(miss.sum())
        if never:
            note(f"{name}: {len(never)} of {cols.size} satellites observed have no healthy ephemeris in "
                 f"{navs}: dropped ({', '.join(never)})")
        if partial:
            note(f"{name}: {partial} observations at epochs beyond their satellite's ephemeris age limit: dropped")
    return obs
