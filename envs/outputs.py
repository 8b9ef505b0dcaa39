"""Output folders and files of the scripts (eval.py, train.py): folders checked before any work starts; every
output file written to a temporary file beside it and renamed into place (:func:`write_atomic`,
:func:`atomic_path`), so that a run killed while writing leaves the previous file whole (or none), never a
truncated one."""
from __future__ import annotations

import itertools
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path


def check_output_dir(path, owner: str = "--out") -> Path:
    """Create ``path`` (with parents) and check that files can be written in it; return it.

    Raises
    ------
    ValueError
        one line naming ``owner`` and the path: it is an existing file, it cannot be created (a parent is
        a file, no permission, a read-only or virtual file system), or a file cannot be written in it.
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise ValueError(f"{owner} {str(p)!r} is a file, not a directory")
    try:
        p.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(prefix=".write-test-", dir=p)
        os.close(fd)
        os.unlink(probe)
    except OSError as e:
        raise ValueError(f"{owner} {str(p)!r}: cannot write there ({e.strerror or type(e).__name__})") from None
    return p


@contextmanager
def atomic_path(path):
    """A temporary path beside ``path`` to write to; renamed onto ``path`` when the block ends without an
    exception, removed when it raises (an interrupted write leaves the previous ``path`` as it was).

    For writers that take a file name (``model.save``, ``fig.savefig``, ``torch.save``): the temporary name
    keeps the suffix of ``path`` (``.model.zip.<pid>-<n>.tmp.zip``), so a writer that picks its format or adds
    an extension from the suffix does the same. The file is flushed to the disk before the rename (``fsync``),
    and gets the permissions a plain ``open(path, 'w')`` would (the process's umask).

    Yields
    ------
    Path : the temporary file (created empty; the writer replaces or overwrites it).
    """
    path = Path(path)
    for n in itertools.count():
        tmp = path.with_name(f".{path.name}.{os.getpid()}-{n}.tmp{path.suffix}")
        try:
            os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))
            break
        except FileExistsError:
            continue
    try:
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def write_atomic(path, data) -> Path:
    """Write ``data`` (str: UTF-8 text; bytes: as they are) to ``path`` through :func:`atomic_path`: readers
    see the previous file or the whole new one, never a part; returns ``path``."""
    path = Path(path)
    raw = data.encode("utf-8") if isinstance(data, str) else bytes(data)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(raw)
    return path


def remove_if_empty(path) -> bool:
    """Remove the folder ``path`` if it exists and is empty (a run's output folder that ended with nothing in
    it); whether it was removed."""
    p = Path(path)
    try:
        p.rmdir()  # only an empty folder
    except OSError:
        return False
    return True
