"""Copying batch rows inside a batch: exact state branching of B lock-step filters.

``copy_rows(dst, src)`` on a form, an adaptive law, a navigator (and the env core
above them) makes row ``dst[i]`` an exact copy of row ``src[i]``: fed the same
inputs afterwards, the two rows continue bit for bit alike. That is what a
hindsight search needs (branch K copies of an episode's filter, try K actions,
keep the best branch). The copy is *generic*: every attribute that is an ndarray
with leading axis B, every dict of such arrays and every nested object with its
own ``copy_rows`` is copied, so per-row state added to a class later is copied
without touching this code. Arrays that are not per row but may happen to have
length B (e.g. a (17,) noise diagonal when B = 17) must be named in the owner's
``skip`` set.

Copies are copy-on-write: a copied attribute is replaced by a new array (the old
one is never written), so arrays shared with another object (a snapshot, a form
that kept what it was handed) are left untouched. Overlapping ``dst`` / ``src``
are safe: the source rows are gathered before any row is written.
"""
from __future__ import annotations

import dataclasses

import numpy as np


def check_row_pairs(dst, src, batch_size: int) -> tuple[np.ndarray, np.ndarray]:
    """``(dst, src)`` as equal-length 1-D intp arrays of row indices in ``[0, batch_size)``.

    Raises
    ------
    ValueError
        non-integer, not 1-D, different lengths, or an index out of range (names ``dst`` / ``src``).
    """
    out = []
    for name, a in (("dst", dst), ("src", src)):
        arr = np.asarray(a)
        if arr.ndim == 0:
            arr = arr[None]
        if arr.ndim != 1 or (arr.size and arr.dtype.kind not in "iu"):
            raise ValueError(f"{name} must be a 1-D array of integer row indices, got {np.asarray(a)!r}")
        arr = arr.astype(np.intp)
        if arr.size and (arr.min() < 0 or arr.max() >= batch_size):
            raise ValueError(f"{name} has a row index outside [0, {batch_size}): {arr.tolist()}")
        out.append(arr)
    if out[0].shape != out[1].shape:
        raise ValueError(f"dst and src must have the same length, got {out[0].size} and {out[1].size}")
    return out[0], out[1]


def copied_array(value: np.ndarray, dst: np.ndarray, src: np.ndarray) -> np.ndarray:
    """A new array equal to ``value`` with rows ``dst`` set to the (original) rows ``src``; a read-only
    ``value`` gives a read-only copy."""
    new = value.copy()
    new[dst] = value[src]
    if not value.flags.writeable:
        new.flags.writeable = False
    return new


def is_row_array(value, batch_size: int) -> bool:
    """Whether ``value`` is an ndarray with leading axis ``batch_size`` (a per-row array)."""
    return isinstance(value, np.ndarray) and value.ndim >= 1 and value.shape[0] == batch_size


def copy_row_value(value, dst, src, batch_size: int, owner: str):
    """``value`` with its rows copied: a per-row array, a dict of values (recursively), a dataclass
    instance with per-row fields (a new instance), an object with ``copy_rows`` (copied in place,
    returned as is); anything else (scalars, None, configs, caches named in a skip set) unchanged."""
    if is_row_array(value, batch_size):
        return copied_array(value, dst, src)
    if isinstance(value, dict):
        return {k: copy_row_value(v, dst, src, batch_size, f"{owner}[{k!r}]") for k, v in value.items()}
    if (not isinstance(value, type) and hasattr(value, "copy_rows")
            and getattr(value, "batch_size", None) == batch_size):
        value.copy_rows(dst, src)
        return value
    return value


def copy_dataclass_rows(obj, dst, src, batch_size: int, owner: str):
    """A copy of the dataclass instance ``obj`` whose per-row array fields have rows ``src`` copied to ``dst``.

    Fields may be per-row arrays, None, bools or numbers; any other field value cannot be copied row-wise
    and raises ``ValueError`` naming ``owner`` and the field.
    """
    kw = {}
    for f in dataclasses.fields(obj):
        v = getattr(obj, f.name)
        if is_row_array(v, batch_size):
            kw[f.name] = copied_array(v, dst, src)
        elif not (v is None or isinstance(v, (bool, int, float, np.bool_, np.integer, np.floating))):
            raise ValueError(f"cannot copy rows of {owner}: its field {f.name!r} is a {type(v).__name__}, "
                             "not a per-row array")
    return dataclasses.replace(obj, **kw)


def copy_rows_generic(obj, dst, src, batch_size: int, skip=frozenset()) -> None:
    """Copy rows ``src`` to ``dst`` in every attribute of ``obj`` (see the module docstring) except ``skip``.

    Per-row arrays and dicts of them are replaced by copies; nested objects with a ``copy_rows`` and the
    same batch size copy their own rows.
    """
    for name, value in list(vars(obj).items()):
        if name in skip:
            continue
        new = copy_row_value(value, dst, src, batch_size, f"{type(obj).__name__}.{name}")
        if new is not value:
            setattr(obj, name, new)
