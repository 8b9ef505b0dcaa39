"""Output folders of the scripts (eval.py, train.py): checked before any work starts."""
from __future__ import annotations

import os
import tempfile
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
