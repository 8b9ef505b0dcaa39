"""Validation of recorded-data files at load time: nothing is half-loaded (issue 13).

A damaged file (truncated, bytes inserted or overwritten, the wrong type, empty) must fail when it is
loaded, with a :class:`~envs.datasets.errors.DatasetFormatError` naming the file and the line (or the
record), never load part of its data silently. Parsers that skip what they cannot read (georinex) are
checked against the file:

* :func:`scan_rinex_obs` / :func:`scan_rinex_nav` read a RINEX 3 file's structure line by line (header with
  ``RINEX VERSION / TYPE`` of the right type and ``END OF HEADER``; every epoch record of an observation
  file with its satellite lines and well-formed observation fields, epochs in time order; every navigation
  record with the line count of its system and numeric fields) and return what the parser must then deliver;
  :func:`check_obs_parsed` / :func:`check_nav_parsed` compare (epochs, records).
* the values: the pseudoranges (and Doppler) of the signals a loader uses against what the orbits and one
  receiver clock per epoch allow, and every GPS / Galileo / BeiDou broadcast parameter against the range of its
  ICD field (:mod:`envs.datasets.plausibility`): a physically impossible value names its line too;
* :func:`check_smartloc` cross-checks the smartLoc files: the pseudorange, odometry and ground-truth spans
  agree both ways (a file cut at a line end is shorter), and no pseudorange or odometry row is repeated.

RINEX 3.0x layout: RINEX 3.04 (IGS/RTCM), sections 5 (observation records: ``>`` epoch lines, one line per
satellite, F14.3 + LLI + SSI fields) and 6 (navigation records: one line with the epoch and 3 fields, then 7
continuation lines of 4 D19.12 fields for GPS/Galileo/BeiDou/QZSS/NavIC, 3 for GLONASS/SBAS).

Limit: a file cut exactly at a record boundary is a valid, shorter RINEX file (RINEX keeps no record count,
and ``TIME OF FIRST OBS`` / ``TIME OF LAST OBS`` may describe the whole log an excerpt came from: in the
shared Emlid file they span 14 minutes around a 61 s excerpt), so it cannot be told apart; a cut anywhere
else leaves a line without its end or an incomplete record.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import DatasetFormatError
from .plausibility import NAV_FIELDS, check_rinex_epochs, icd_violation

__all__ = ["RinexObsLayout", "RinexNavLayout", "scan_rinex_obs", "scan_rinex_nav", "check_obs_parsed",
           "check_nav_parsed", "check_smartloc", "SPAN_TOLERANCE_S"]

NAV_CONTINUATION_LINES = {"G": 7, "E": 7, "C": 7, "J": 7, "I": 7, "R": 3, "S": 3}
"""Continuation lines after a navigation record's first line, per system (RINEX 3.04 section 6)."""
SPAN_TOLERANCE_S = 1.0
"""Largest difference [s] between the start (end) times of files of one recording before one counts as cut."""

_EPOCH = re.compile(r"^> (\d{4}) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d\.\d{7})  ([0-6])([ \d]{3})")
_SAT = re.compile(r"^[GRECJSI][ \d]\d$")
_OBS_FIELD = re.compile(r"^ *-?\d*\.\d{3}$")
_NAV_FIRST = re.compile(r"^([GRECJSI][ \d]\d) (\d{4}) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d) ([ \d]\d)")


@dataclass(frozen=True)
class RinexObsLayout:
    """What a structurally sound RINEX 3 observation file holds.

    Attributes
    ----------
    epochs : (n,) float64 epoch times (observation records with flag 0 or 1), seconds since 1980-01-06
        on the file's time scale (a monotonic key, not GPS time).
    systems : (n,) str, the system letters with a satellite line in each epoch.
    header_end : 1-based line number of ``END OF HEADER``.
    """

    epochs: np.ndarray
    systems: np.ndarray
    header_end: int


@dataclass(frozen=True)
class RinexNavLayout:
    """What a structurally sound RINEX 3 navigation file holds: ``records`` {system letter: number of distinct
    (satellite, epoch) records}, ``header_end`` (1-based line)."""

    records: dict
    header_end: int


def _lines(path: Path) -> list[str]:
    """The file's lines (ASCII, every one ended); ``DatasetFormatError`` for an empty file, a non-ASCII byte
    (a corrupted file: its line) or a last line without its line end (a truncated file)."""
    data = path.read_bytes()
    if not data.strip():
        raise DatasetFormatError(path, None, "the file is empty")
    try:
        text = data.decode("ascii")
    except UnicodeDecodeError as exc:
        raise DatasetFormatError(path, data[:exc.start].count(b"\n") + 1,
                                 f"non-ASCII byte 0x{data[exc.start]:02x}: corrupted file") from None
    lines = text.split("\n")
    if lines[-1].strip():
        raise DatasetFormatError(path, len(lines), "last line has no line end: the file is truncated")
    return [ln.rstrip("\r") for ln in lines[:-1]]


def _header(path: Path, lines: list[str], kind: str) -> tuple[dict, int]:
    """Header labels -> list of (line number, line) and the END OF HEADER line number; checks the type."""
    first = lines[0]
    if first[60:80].strip() != "RINEX VERSION / TYPE":
        raise DatasetFormatError(path, 1, "not a RINEX file: the first line is not 'RINEX VERSION / TYPE'")
    try:
        version = float(first[:9])
    except ValueError:
        raise DatasetFormatError(path, 1, f"RINEX version {first[:9].strip()!r} is not a number") from None
    ftype = first[20:21]
    names = {"O": "an observation file", "N": "a navigation file", "G": "a GLONASS navigation file",
             "M": "a meteorological file", "C": "a clock file"}
    if ftype != kind:
        raise DatasetFormatError(path, 1, f"{names.get(ftype, f'a RINEX file of type {ftype!r}')} (RINEX "
                                          f"{version:g}), expected {names[kind]}")
    labels: dict = {}
    for i, ln in enumerate(lines, start=1):
        label = ln[60:80].strip()
        if label == "END OF HEADER":
            return labels, i
        if not label:
            raise DatasetFormatError(path, i, "header line without a label in columns 61-80 before END OF HEADER")
        labels.setdefault(label, []).append((i, ln))
    raise DatasetFormatError(path, None, "no END OF HEADER line: truncated or not a RINEX file")


def _epoch_seconds(y, mo, d, h, mi, s) -> float:
    days = (np.datetime64(f"{int(y):04d}-{int(mo):02d}-{int(d):02d}") - np.datetime64("1980-01-06")).astype(int)
    return float(days) * 86400.0 + int(h) * 3600.0 + int(mi) * 60.0 + float(s)


def _obs_types(path: Path, labels: dict) -> dict:
    """System letter -> number of observation types (``SYS / # / OBS TYPES``, continuation lines included)."""
    out = {}
    for i, ln in labels.get("SYS / # / OBS TYPES", []):
        if ln[0] != " ":
            try:
                out[ln[0]] = int(ln[3:6])
            except ValueError:
                raise DatasetFormatError(path, i, f"SYS / # / OBS TYPES: {ln[3:6]!r} is not a count") from None
    if not out:
        raise DatasetFormatError(path, None, "no SYS / # / OBS TYPES header line")
    return out


def _obs_type_names(labels: dict) -> dict:
    """System letter -> its observation type names in file order (``SYS / # / OBS TYPES``, continuation lines
    included; the counts are :func:`_obs_types`')."""
    out, cur = {}, None
    for _, ln in labels.get("SYS / # / OBS TYPES", []):
        if ln[0] != " ":
            cur = ln[0]
            out[cur] = []
        if cur is not None:
            out[cur] += ln[7:60].split()
    return out


def _plausibility_fields(labels: dict, codes: dict | None, doppler: bool) -> dict:
    """System letter -> [(index, observable)] of the code observations ``codes`` ({letter: (code, ...)}) and, with
    ``doppler``, their Doppler observations, to be checked for plausibility."""
    if not codes:
        return {}
    names = _obs_type_names(labels)
    out = {}
    for letter, cs in codes.items():
        have = names.get(letter, [])
        want = list(cs) + (["D" + c[1:] for c in cs] if doppler else [])
        out[letter] = [(have.index(o), o) for o in want if o in have]
    return out


def scan_rinex_obs(path, codes: dict | None = None, doppler: bool = False) -> RinexObsLayout:
    """Read the structure of a RINEX 3 observation file (module docstring); ``DatasetFormatError`` naming the
    file and line at the first flaw. RINEX 2 files get the header checks only (their epoch layout differs).

    With ``codes`` ({system letter: code observables}, what the loader uses) those pseudoranges, and with
    ``doppler`` their Doppler, are also checked against what the orbits and one receiver clock per epoch allow
    (:func:`envs.datasets.plausibility.check_rinex_epochs`)."""
    path = Path(path)
    lines = _lines(path)
    labels, end = _header(path, lines, "O")
    if float(lines[0][:9]) < 3:
        return RinexObsLayout(epochs=np.zeros(0), systems=np.zeros(0, str), header_end=end)
    ntypes = _obs_types(path, labels)
    fields = _plausibility_fields(labels, codes, doppler)
    values: list = []  # (epoch index, line, satellite, observable, value) for the plausibility check
    epochs, present = [], []
    i, n = end, len(lines)  # i: 0-based index of the next line
    while i < n:
        ln = lines[i]
        m = _EPOCH.match(ln)
        if not m:
            raise DatasetFormatError(path, i + 1, f"expected an epoch line '> yyyy mm dd hh mm ss.sssssss  flag n', "
                                                  f"got {ln[:40]!r}")
        flag, count = int(m.group(7)), int(m.group(8))
        if flag <= 1 or flag == 6:  # observations (6: cycle slips) follow, one line per satellite
            for k in range(count):
                j = i + 1 + k
                if j >= n:
                    raise DatasetFormatError(path, i + 1, f"epoch record announces {count} satellites, the file ends "
                                                          f"after {k}: truncated")
                _check_sat_line(path, j + 1, lines[j], ntypes)
                if flag <= 1:
                    _collect(values, len(epochs), j + 1, lines[j], fields)
            if flag <= 1:
                t = _epoch_seconds(*m.groups()[:6])
                if epochs and t <= epochs[-1]:
                    raise DatasetFormatError(path, i + 1, "epoch time does not increase (a repeated or out-of-order "
                                                          "record)")
                epochs.append(t)
                present.append("".join(sorted({lines[i + 1 + k][0] for k in range(count)})))
        elif i + count >= n:
            raise DatasetFormatError(path, i + 1, f"event record announces {count} lines, the file ends first")
        i += 1 + count
    if not epochs:
        raise DatasetFormatError(path, None, "no observation epoch after the header")
    check_rinex_epochs(path, values)
    return RinexObsLayout(epochs=np.asarray(epochs), systems=np.asarray(present), header_end=end)


def _collect(values: list, epoch: int, lineno: int, ln: str, fields: dict) -> None:
    """Append the checked observations of a satellite line (:func:`_plausibility_fields`) to ``values``."""
    sat = ln[:3].replace(" ", "0")
    for k, o in fields.get(ln[0], ()):
        f = ln[3 + 16 * k:3 + 16 * k + 14].strip()
        if f and float(f) != 0.0:  # RINEX 3.04 5.7: a missing observation is blank or 0.0
            values.append((epoch, lineno, sat, o, float(f)))


def _check_sat_line(path, lineno, ln, ntypes):
    sat = ln[:3]
    if not _SAT.match(sat) or sat[0] not in ntypes:
        raise DatasetFormatError(path, lineno, f"expected a satellite observation line (system with observation "
                                               f"types {sorted(ntypes)}), got {ln[:40]!r}")
    nt = ntypes[sat[0]]
    if len(ln) > 3 + 16 * nt:
        raise DatasetFormatError(path, lineno, f"{sat} line has {len(ln)} characters, at most {3 + 16 * nt} for "
                                               f"{nt} observation types")
    for k in range(nt):
        a = 3 + 16 * k
        field = ln[a:a + 14]
        if field.strip() and not _OBS_FIELD.match(field):
            raise DatasetFormatError(path, lineno, f"{sat} observation {k + 1}: {field.strip()!r} is not an F14.3 "
                                                   "number")
        flags = ln[a + 14:a + 16]
        if flags.strip() and not all(c == " " or c.isdigit() for c in flags):
            raise DatasetFormatError(path, lineno, f"{sat} observation {k + 1}: LLI/SSI {flags!r} are not digits")


def _nav_number(path, lineno, field, sv: str = "", place: tuple | None = None):
    """The number in a navigation field (None when blank); ``DatasetFormatError`` when it is not one, or when the
    broadcast parameter at ``place`` (line of the record, field: :data:`~envs.datasets.plausibility.NAV_FIELDS`)
    of satellite ``sv`` is outside its ICD range."""
    s = field.strip()
    if not s:
        return None
    try:
        v = float(s.replace("D", "E").replace("d", "e"))
    except ValueError:
        raise DatasetFormatError(path, lineno, f"{s!r} is not a number") from None
    name = NAV_FIELDS.get(place) if place is not None else None
    msg = icd_violation(sv[:1], name, v) if name is not None else None
    if msg is not None:
        raise DatasetFormatError(path, lineno, f"{sv} record: {msg}")
    return v


def scan_rinex_nav(path) -> RinexNavLayout:
    """Read the structure of a RINEX 3 navigation file (module docstring); ``DatasetFormatError`` naming the
    file and line at the first flaw, or at a GPS / Galileo / BeiDou broadcast parameter outside the range of its
    ICD field (:data:`envs.datasets.plausibility.ICD_RANGES`)."""
    path = Path(path)
    lines = _lines(path)
    _, end = _header(path, lines, "N")
    if float(lines[0][:9]) < 3:
        return RinexNavLayout(records={}, header_end=end)
    seen: dict = {}
    i, n = end, len(lines)
    while i < n:
        ln = lines[i]
        m = _NAV_FIRST.match(ln)
        if not m or ln[0] not in NAV_CONTINUATION_LINES:
            raise DatasetFormatError(path, i + 1, f"expected the first line of a navigation record "
                                                  f"('G01 yyyy mm dd hh mm ss ...'), got {ln[:40]!r}")
        sv = m.group(1).replace(" ", "0")
        for k in range(3):
            _nav_number(path, i + 1, ln[23 + 19 * k:42 + 19 * k], sv, (0, k))
        if len(ln.rstrip()) > 80:
            raise DatasetFormatError(path, i + 1, f"navigation line has {len(ln.rstrip())} characters, at most 80")
        cont = NAV_CONTINUATION_LINES[ln[0]]
        for k in range(1, cont + 1):
            j = i + k
            if j >= n:
                raise DatasetFormatError(path, i + 1, f"{m.group(1)} record has {k - 1} of its {cont} continuation "
                                                      "lines: the file is truncated")
            c = lines[j]
            if not c.startswith("    ") or len(c.rstrip()) > 80:
                raise DatasetFormatError(path, j + 1, f"expected continuation line {k} of the {m.group(1)} record "
                                                      f"(4 spaces, then up to 4 numbers), got {c[:40]!r}")
            for f in range(4):
                _nav_number(path, j + 1, c[4 + 19 * f:23 + 19 * f], sv, (k, f))
        seen.setdefault(ln[0], set()).add((m.group(1), m.groups()[1:]))
        i += 1 + cont
    if not seen:
        raise DatasetFormatError(path, None, "no navigation record after the header")
    return RinexNavLayout(records={s: len(v) for s, v in seen.items()}, header_end=end)


def check_obs_parsed(path, layout: RinexObsLayout, n_parsed: int, systems) -> None:
    """The parser delivered every epoch of the file that holds a satellite of ``systems`` (call when no time
    filter was applied); ``DatasetFormatError`` otherwise."""
    if not layout.epochs.size:
        return
    want = int(sum(any(c in systems for c in p) for p in layout.systems))
    if n_parsed != want:
        raise DatasetFormatError(path, None, f"{want} epoch records with systems {tuple(systems)} in the file, the "
                                             f"parser read {n_parsed}: part of the file was skipped")


def check_nav_parsed(path, layout: RinexNavLayout, nav) -> None:
    """The parser delivered every navigation record of the file: per system, the (satellite, epoch) cells of
    ``nav`` (an xarray Dataset over time x sv, as georinex returns) with any finite value."""
    if not layout.records:
        return
    svs = np.asarray(nav.sv.values).astype(str)
    ok = np.zeros((nav.sizes["time"], svs.size), bool)
    for v in nav.data_vars:
        a = np.asarray(nav[v].values)
        if a.shape == ok.shape and a.dtype.kind == "f":
            ok |= np.isfinite(a)
    got = {}
    for j, sv in enumerate(svs):
        got[sv[0]] = got.get(sv[0], 0) + int(ok[:, j].sum())
    for system, want in sorted(layout.records.items()):
        if got.get(system, 0) != want:
            raise DatasetFormatError(path, None, f"{want} {system} navigation records in the file, the parser read "
                                                 f"{got.get(system, 0)}: part of the file was skipped")


def _span_check(named: list) -> None:
    """``named``: [(path, label, times (n,), lines (n,))]; each pair's start and end agree within
    :data:`SPAN_TOLERANCE_S`, else the shorter file is named at its first or last row."""
    for a in named:
        for b in named:
            if a is b or a[2].size == 0 or b[2].size == 0:
                continue
            if a[2][-1] < b[2][-1] - SPAN_TOLERANCE_S:
                raise DatasetFormatError(a[0], int(a[3][-1]), f"the {a[1]} rows end at {a[2][-1]:.3f} s but the {b[1]} "
                                                              f"rows ({b[0]}) run to {b[2][-1]:.3f} s: truncated")
            if a[2][0] > b[2][0] + SPAN_TOLERANCE_S:
                raise DatasetFormatError(a[0], int(a[3][0]), f"the {a[1]} rows start at {a[2][0]:.3f} s but the "
                                                             f"{b[1]} rows ({b[0]}) at {b[2][0]:.3f} s: cut at the start")


def _repeated(path, what, keys: np.ndarray, lines: np.ndarray) -> None:
    """``DatasetFormatError`` at the second line of the first key (rows of ``keys``) that occurs twice."""
    if keys.shape[0] < 2:
        return
    order = np.lexsort(keys.T[::-1])
    k = keys[order]
    dup = np.flatnonzero((k[1:] == k[:-1]).all(1))
    if dup.size:
        pairs = [(int(lines[order[d]]), int(lines[order[d + 1]])) for d in dup]
        first, second = min(pairs, key=lambda p: max(p))
        first, second = sorted((first, second))
        raise DatasetFormatError(path, second, f"{what} repeats line {first} (same time and key): a duplicated line")


def check_smartloc(input_path, gt_path, pr, od, gt) -> None:
    """Cross-checks of a loaded smartLoc recording (module docstring): spans of the pseudorange, odometry and
    ground-truth rows agree both ways; no (time, system, satellite) pseudorange row and no odometry time
    appears twice. ``pr``, ``od``, ``gt`` are the parsed row sets (with ``t`` and ``line``)."""
    _repeated(input_path, "pseudorange3 row", np.stack([pr.t, pr.system, pr.sat_id], 1).astype(np.float64), pr.line)
    _repeated(input_path, "odom3 row", od.t[:, None].astype(np.float64), od.line)
    named = [(input_path, "pseudorange3", pr.t, pr.line), (gt_path, "point3 (ground truth)", gt.t, gt.line)]
    if od.t.size:
        named.append((input_path, "odom3", od.t, od.line))
    _span_check(named)

