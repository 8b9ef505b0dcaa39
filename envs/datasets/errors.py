"""Errors raised by the recorded-data loaders, and where the shared data sets live."""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["DatasetFormatError", "shared_data_dir", "require_file"]


class DatasetFormatError(ValueError):
    """A recorded-data file that cannot be trusted: truncated, corrupted, or of an unknown layout.

    The message starts with ``<path>:<line>:`` (1-based line number) when one
    line is to blame, or ``<path>:`` for a whole-file problem.

    Attributes
    ----------
    path : str, the file.
    line : int or None, the 1-based line number.
    """

    def __init__(self, path, line, message: str):
        self.path = str(path)
        self.line = None if line is None else int(line)
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        super().__init__(f"{where}: {message}")


def shared_data_dir() -> Path:
    """The shared recorded-data folder (DESIGN.md section 6), which may not exist.

    ``$NAVGYM_DATA_DIR`` if set, else ``../shared/data`` beside the project
    checkout (``<repo>/../shared/data``). Callers (tests) check ``.is_dir()``.
    """
    env = os.environ.get("NAVGYM_DATA_DIR")
    if env:
        return Path(env)
    return (Path(__file__).resolve().parents[2] / ".." / "shared" / "data").resolve()


def require_file(path) -> Path:
    """``Path(path)`` if it is an existing regular file; ``FileNotFoundError`` naming it otherwise."""
    p = Path(path)
    if not p.is_file():
        what = "is not a regular file" if p.exists() else "does not exist"
        raise FileNotFoundError(f"{p}: recorded-data file {what}")
    return p
