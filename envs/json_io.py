"""Plain-JSON conversion of result dictionaries (numpy scalars, tuples, non-finite floats)."""
from __future__ import annotations

import json
import math

import numpy as np


def jsonable(x):
    """``x`` with numpy scalars turned into Python ones, tuples into lists, dict keys into strings, and
    non-finite floats (NaN, +-inf) into None (JSON has no NaN); other values pass through."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def dumps(x, **kw) -> str:
    """Strict JSON text of ``x`` (:func:`jsonable` first: NaN and +-inf become ``null``, which every JSON parser
    reads; Python's default would write the non-standard ``NaN``). ``kw`` as for :func:`json.dumps`."""
    return json.dumps(jsonable(x), allow_nan=False, **kw)


def without_timing(x):
    """A result dictionary without its wall-clock fields (keys containing ``time`` or ``timing``, e.g.
    ``filter_time_per_epoch_s``, ``wall_time_s``, a ``timing`` section): what two runs of the same
    computation must agree on."""
    if isinstance(x, dict):
        return {k: without_timing(v) for k, v in x.items() if not ("time" in str(k) or "timing" in str(k))}
    if isinstance(x, (list, tuple)):
        return [without_timing(v) for v in x]
    return x
