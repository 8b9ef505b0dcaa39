"""Invalidation of navgym's on-disk numba caches when a source they were compiled from changes.

numba's ``cache=True`` keys a function's cached machine code on its own source file only (modification time and
size). navgym's kernels call kernels of other modules (a law's fused epoch calls the ``kf`` form's update, the env
core calls :mod:`nav_filters.kernels`), and numba compiles the callee's code into the caller's cache entry. After
an update of the sources (``git pull``, a branch switch, an edit) that changed a callee but not its caller, numba
would load the caller's stale code: the old arithmetic, or, where an argument list changed, a crash.

:func:`invalidate_stale_caches` runs when :mod:`earth` (the bottom layer, imported before any kernel can run) is
first imported. It compares each module of :data:`PACKAGES` with the hash recorded at the last run; where some
changed (or were added or removed), it deletes the cache files (``__pycache__/<module>.*.nbi`` / ``.nbc``) of
those modules and of every module that imports them, directly or through others (a kernel can only call what its
module defines or imports), so those kernels compile afresh once and are cached again. Without a record (the first
run) every cache file of the packages goes. This covers numba's default cache location beside the sources (a
source checkout); a cache moved elsewhere with ``NUMBA_CACHE_DIR`` (or numba's per-user fallback for a read-only
install) is not touched: clear it after updating navgym.
"""
from __future__ import annotations

import ast
import hashlib
import json
import os
from pathlib import Path

from numba.core.event import Listener

PACKAGES = ("earth", "nav_filters", "envs")
"""The packages whose modules define cached numba kernels (the layers below ``agents``)."""

RECORD = Path("earth") / "__pycache__" / "navgym-source-hashes.json"
"""Where (relative to the source root) the modules' hashes of the last run are recorded."""


def module_hashes(root: Path, packages=PACKAGES) -> dict[str, str]:
    """``{path relative to root: SHA-1 of its bytes}`` of every ``.py`` file of ``packages`` under ``root``."""
    out = {}
    for pkg in packages:
        for path in sorted((root / pkg).rglob("*.py")):
            out[path.relative_to(root).as_posix()] = hashlib.sha1(path.read_bytes()).hexdigest()
    return out


def _module_file(name: str, files: set[str]) -> str | None:
    """The file (relative path) of module ``name`` ("a.b.c") among ``files``, or None."""
    base = name.replace(".", "/")
    for cand in (f"{base}.py", f"{base}/__init__.py"):
        if cand in files:
            return cand
    return None


def imported_modules(root: Path, rel: str, files: set[str]) -> set[str]:
    """The files among ``files`` that the module ``rel`` imports anywhere in its body (module-level or inside a
    function; ``from x import name`` also counts the submodule ``x.name`` where that is a file)."""
    tree = ast.parse((root / rel).read_bytes(), filename=rel)
    package = rel[:-3].split("/")[:-1]  # the package a relative import starts from (also for an __init__)
    found = set()
    for node in ast.walk(tree):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # level 1: this package, 2: its parent, ...
                base = package[:len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            names = [mod] + [f"{mod}.{a.name}" for a in node.names]
        for name in names:
            f = _module_file(name, files)
            if f is not None and f != rel:
                found.add(f)
    return found


def affected_modules(root: Path, changed: set[str], files: set[str]) -> set[str]:
    """``changed`` and every module among ``files`` that imports one of them, directly or through others."""
    importers: dict[str, set[str]] = {f: set() for f in files}
    for f in files:
        for g in imported_modules(root, f, files):
            importers[g].add(f)
    out, todo = set(), [f for f in changed if f in files]
    while todo:
        f = todo.pop()
        if f in out:
            continue
        out.add(f)
        todo.extend(importers[f] - out)
    return out


def _cache_files(root: Path, rel: str):
    """numba's in-tree cache files of the module ``rel``: ``<dir>/__pycache__/<stem>.*.nbi`` / ``.nbc``."""
    path = root / rel
    return (path.parent / "__pycache__").glob(f"{path.stem}.*.nb[ic]")


def invalidate_stale_caches(root: Path | None = None, packages=PACKAGES) -> int:
    """Delete the numba cache files that may hold code of a module changed since the last call; returns how many
    files were deleted (see the module docstring).

    Parameters
    ----------
    root : the folder holding the packages (default: navgym's source root, the parent of :mod:`earth`).
    packages : the package folder names (default :data:`PACKAGES`).

    A folder that cannot be written (a read-only install, where numba caches elsewhere) is left as it is; a file
    another process deleted first is skipped.
    """
    root = Path(__file__).resolve().parents[1] if root is None else Path(root)
    now = module_hashes(root, packages)
    record = root / RECORD
    try:
        before = json.loads(record.read_text())
    except (OSError, ValueError):  # no record yet (or a damaged one): the caches' sources are unknown
        before = None
    if before == now:
        return 0
    if before is None:
        stale = [p for pkg in packages for p in (root / pkg).rglob("__pycache__/*.nb[ic]")]
    else:
        changed = {f for f in now.keys() | before.keys() if now.get(f) != before.get(f)}
        stale = [p for f in sorted(affected_modules(root, changed, set(now)) | (changed - set(now)))
                 for p in _cache_files(root, f)]
    removed = 0
    for path in stale:
        try:
            path.unlink()
            removed += 1
        except OSError:
            pass
    try:
        record.parent.mkdir(parents=True, exist_ok=True)
        tmp = record.with_name(f"{record.name}.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(now, indent=0, sort_keys=True))
        os.replace(tmp, record)  # atomic: a concurrent import reads the old record or the new one
    except OSError:
        pass
    return removed


COMPILE_NOTICE = ("navgym: compiling its numba kernels once (a minute or a few on 2 cores; later runs load them from "
                  "the cache)...")
"""The line :func:`announce_compilation` prints when navgym's kernels start compiling."""
KERNEL_PACKAGES = (*PACKAGES, "agents")
"""The top-level packages whose numba kernels :func:`announce_compilation` watches."""


class CompileNotice(Listener):
    """A numba event listener (``numba:compile``, fired on a cache miss only) that writes :data:`COMPILE_NOTICE`
    to ``stream`` (default: stderr at the time) when the first kernel of ``packages`` starts compiling, once."""

    def __init__(self, stream=None, packages=KERNEL_PACKAGES):
        self.stream, self.packages, self.said = stream, tuple(packages), False

    def on_start(self, event):
        if self.said:
            return
        func = getattr(event.data.get("dispatcher"), "py_func", None)
        if str(getattr(func, "__module__", "")).split(".")[0] in self.packages:
            import sys
            self.said = True
            stream = self.stream or sys.stderr
            try:  # above a running progress bar, not inside its line
                from tqdm import tqdm
                tqdm.write(COMPILE_NOTICE, file=stream)
                stream.flush()
            except ImportError:  # pragma: no cover - tqdm comes with navgym
                print(COMPILE_NOTICE, file=stream, flush=True)

    def on_end(self, event):
        pass


_NOTICE: CompileNotice | None = None


def announce_compilation(stream=None) -> CompileNotice:
    """From now on, print :data:`COMPILE_NOTICE` once in this process when one of navgym's kernels compiles
    (numba's cache missed: the first run of a checkout, or an update of the sources invalidated the caches,
    :func:`invalidate_stale_caches`); a run that loads every kernel from the cache says nothing. eval.py and
    train.py call it before their work, so that a first run does not look hung. Idempotent (one listener per
    process; ``stream`` replaces the earlier one)."""
    global _NOTICE
    if _NOTICE is None:
        from numba.core import event
        _NOTICE = CompileNotice(stream)
        event.register("numba:compile", _NOTICE)
    elif stream is not None:
        _NOTICE.stream = stream
    return _NOTICE
