"""Per-row adaptive parameters: their valid ranges and validation.

Every parameter an agent may set between steps (the Sage-Husa forgetting factor
``b``, the strong-tracking softening factor, ...) is held as a (B,) float64
array, one value per batch row, and validated by a :class:`ParamSpec`: a NaN,
an out-of-range value or a wrong shape raises ``ValueError`` naming the
parameter.
"""
from __future__ import annotations

import math
import operator
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ParamSpec:
    """Valid range of one adaptive parameter.

    Attributes
    ----------
    name : parameter name (the keyword of ``set_params`` and the key of ``params()``).
    low, high : range bounds (``high`` may be ``inf``).
    low_closed, high_closed : whether the bound itself is allowed.
    doc : one line for error messages and docs.
    """

    name: str
    low: float
    high: float
    low_closed: bool = False
    high_closed: bool = True
    doc: str = ""

    def __post_init__(self):
        # the two bound tests, chosen once (check runs at every env step): float bounds so that a Python float
        # and a float64 array compare alike (numpy converts the bounds to float64 as well)
        object.__setattr__(self, "_above_low", operator.ge if self.low_closed else operator.gt)
        object.__setattr__(self, "_below_high", operator.le if self.high_closed else operator.lt)
        object.__setattr__(self, "_bounds", (float(self.low), float(self.high)))

    def inside(self, x):
        """Whether ``x`` lies in the range: a bool for a Python float, a bool array for an array (NaN: False)."""
        low, high = self._bounds
        return self._above_low(x, low) & self._below_high(x, high)

    def describe(self) -> str:
        """The interval as text, e.g. ``(0, 1]``."""
        return f"{'[' if self.low_closed else '('}{self.low:g}, {self.high:g}{']' if self.high_closed else ')'}"

    def check(self, value, batch_size: int | None = None, owner: str = "") -> np.ndarray:
        """Validate ``value`` and return it as a float64 array.

        Parameters
        ----------
        value : scalar, or (B,) array when ``batch_size`` is given (a scalar is broadcast to (B,)).
        batch_size : B, or None to require a scalar (configuration defaults).
        owner : prefix for the error message (e.g. the config class name).

        Returns
        -------
        (B,) float64 array, or a 0-d array when ``batch_size`` is None.

        Raises
        ------
        ValueError
            non-numeric, wrong shape, NaN, or outside the range; the message names the parameter.
        """
        label = f"{owner}.{self.name}" if owner else self.name
        if isinstance(value, (bool, np.bool_)):
            raise ValueError(f"{label} must be a number in {self.describe()}, got {value!r}")
        try:
            arr = np.array(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"{label} must be a number in {self.describe()}, got {value!r}") from None
        if batch_size is None:
            if arr.ndim != 0:
                raise ValueError(f"{label} must be a scalar, got shape {arr.shape}")
        else:
            if arr.ndim == 0:
                arr = np.full(batch_size, float(arr))
            elif arr.shape != (batch_size,):
                raise ValueError(f"{label} must be a scalar or have shape ({batch_size},), got shape {arr.shape}")
        # the common case, all valid (NaN fails both tests): one test; a single value (B = 1) as a Python float,
        # two comparisons instead of four numpy calls
        if self.inside(arr.item()) if arr.size == 1 else bool(self.inside(arr).all()):
            return arr
        if np.isnan(arr).any():
            raise ValueError(f"{label} must not be NaN ({self.doc or 'adaptive parameter'})")
        lo_bad = arr < self.low if self.low_closed else arr <= self.low
        hi_bad = arr > self.high if self.high_closed else arr >= self.high
        if math.isinf(self.high) and not self.high_closed:
            hi_bad = hi_bad | np.isinf(arr)
        bad = lo_bad | hi_bad
        if bad.any():
            v = arr.reshape(-1)[np.argmax(bad.reshape(-1))]
            raise ValueError(f"{label} must lie in {self.describe()} ({self.doc}), got {v!r}")
        return arr


def check_option(owner: str, name: str, value, low=None, high=None, low_closed=True, high_closed=True,
                 allow_inf=False) -> None:
    """Validate a scalar configuration option (not a per-row parameter); ``ValueError`` naming it."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{owner}.{name} must be a number, got {value!r}")
    if math.isnan(value) or (math.isinf(value) and not allow_inf):
        raise ValueError(f"{owner}.{name} must be finite, got {value!r}")
    if low is not None and (value < low if low_closed else value <= low):
        raise ValueError(f"{owner}.{name} must be {'>=' if low_closed else '>'} {low}, got {value!r}")
    if high is not None and (value > high if high_closed else value >= high):
        raise ValueError(f"{owner}.{name} must be {'<=' if high_closed else '<'} {high}, got {value!r}")
