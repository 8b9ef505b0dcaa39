"""The filter-method registry: every method name of DESIGN.md section 4, plain forms and adaptive laws alike.

It sits above both packages it registers: :mod:`nav_filters.forms` (the Kalman-filter forms) and
:mod:`nav_filters.adaptive` (the laws that compose them), neither of which imports it at import time, so
there is no import cycle between them. A method name may carry the ``+onestep`` suffix (covariance
propagated once per measurement epoch, seed paper 001); that is a property of the navigator's propagation,
not of the form, and :func:`parse_method` splits it off.
"""
from __future__ import annotations

from .adaptive import ADAPTIVE_METHODS
from .forms import (FilterForm, InformationFilter, KalmanFilter, SquareRootInformationFilter, SvdInformationFilter,
                    SvdKalmanFilter, SvdSquareRootKF)

FORMS: dict = {
    "kf": KalmanFilter,
    "svd-srkf": SvdSquareRootKF,
    "svd-kf": SvdKalmanFilter,
    "if": InformationFilter,
    "svd-if": SvdInformationFilter,
    "srif": SquareRootInformationFilter,
    **ADAPTIVE_METHODS,
}
"""Registered filter methods by name: a form class or a law factory, each ``(P0, x0=None, dtype=None) ->
FilterForm``."""

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


__all__ = ["FORMS", "ONESTEP_SUFFIX", "parse_method", "make_form"]
