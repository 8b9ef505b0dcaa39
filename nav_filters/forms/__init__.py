"""Kalman-filter forms behind one interface (:class:`FilterForm`), looked up by method name.

The method names are the public contract of DESIGN.md section 4. A name may
carry the ``+onestep`` suffix (covariance propagated once per measurement
epoch, seed paper 001); that is a property of the navigator's propagation, not
of the form, and :func:`parse_method` splits it off.
"""
from __future__ import annotations

from .base import FilterForm, UpdateResult, prepare_measurement
from .information import InformationFilter, SvdInformationFilter
from .kf import KalmanFilter
from .srif import SquareRootInformationFilter
from .svd import SvdKalmanFilter, SvdSquareRootKF

FORMS: dict[str, type[FilterForm]] = {
    "kf": KalmanFilter,
    "svd-srkf": SvdSquareRootKF,
    "svd-kf": SvdKalmanFilter,
    "if": InformationFilter,
    "svd-if": SvdInformationFilter,
    "srif": SquareRootInformationFilter,
}
"""Registered forms by method name."""

ONESTEP_SUFFIX = "+onestep"


def parse_method(method: str) -> tuple[str, bool]:
    """Split ``'kf+onestep'`` into ``('kf', True)``; ``ValueError`` for an unknown base name."""
    if not isinstance(method, str):
        raise ValueError(f"method must be a string, got {method!r}")
    onestep = method.endswith(ONESTEP_SUFFIX)
    base = method[: -len(ONESTEP_SUFFIX)] if onestep else method
    if base not in FORMS:
        raise ValueError(f"unknown filter method {method!r}; known: {sorted(FORMS)} (optionally with '{ONESTEP_SUFFIX}')")
    return base, onestep


def make_form(method: str, P0, x0=None, dtype=None) -> FilterForm:
    """Instantiate the form named by ``method`` (suffix ignored) with initial covariance ``P0`` (B, n, n)."""
    base, _ = parse_method(method)
    return FORMS[base](P0, x0=x0, dtype=dtype)


__all__ = ["FilterForm", "UpdateResult", "KalmanFilter", "InformationFilter", "SvdInformationFilter",
           "SquareRootInformationFilter", "SvdSquareRootKF", "SvdKalmanFilter", "FORMS", "parse_method", "make_form", "prepare_measurement"]

# Adaptive laws compose the forms above (they import this module), so they register last.
from ..adaptive import ADAPTIVE_METHODS  # noqa: E402

FORMS.update(ADAPTIVE_METHODS)
