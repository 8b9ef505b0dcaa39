"""The filter-method registry: every method name of DESIGN.md section 4, plain forms and adaptive laws alike.

It sits on top of both packages it registers, and the direction is one way: :mod:`nav_filters.forms` (the
Kalman-filter forms) and :mod:`nav_filters.adaptive` (the laws that compose them) know nothing of method
names or of this module. The registry resolves the name of a law's inner form to its factory and hands it to
the law (:func:`~nav_filters.adaptive.law_factory`).

A method name may carry suffixes:

* ``+fde`` (any method): innovation-based fault detection and exclusion screens the epoch's measurements
  before the method's own update (:class:`~nav_filters.adaptive.fde.FaultExclusion` around it);
  ``kf-fde`` is ``kf+fde``;
* ``+onestep``: the covariance propagated once per measurement epoch (seed paper 001); a property of the
  navigator's propagation, not of the form.

:func:`parse_method` splits ``+onestep`` off; :func:`make_form` builds the form of a name with its ``+fde``.
"""
from __future__ import annotations

import functools

from .adaptive import (Q_ABOVE_NOMINAL, SATELLITE_R, FaultExclusion, MeasurementAdaptiveSTKF, RobustUpdate, SageHusa, StrongTracking,
                       VariationalR, law_factory)
from .forms import (FilterForm, InformationFilter, KalmanFilter, SquareRootInformationFilter, SvdInformationFilter,
                    SvdKalmanFilter, SvdSquareRootKF)

FORMS: dict = {
    "kf": KalmanFilter,
    "svd-srkf": SvdSquareRootKF,
    "svd-kf": SvdKalmanFilter,
    "if": InformationFilter,
    "svd-if": SvdInformationFilter,
    "srif": SquareRootInformationFilter,
}
"""Registered filter methods by name: a form class or a law factory, each ``(P0, x0=None, dtype=None) ->
FilterForm``."""

PLAIN_FORMS = tuple(FORMS)
"""The forms every law composes (DESIGN.md section 4)."""

ADAPTIVE_METHODS: dict = {}
"""Method name -> form factory of the adaptive laws (Sage-Husa, strong tracking; DESIGN.md section 4)."""


def _register(table: dict, name: str, law: type, inner: str, **config) -> None:
    """Register ``name`` as ``law`` around the registered form ``inner`` with ``config`` (in FORMS and ``table``)."""
    FORMS[name] = table[name] = law_factory(law, FORMS[inner], **config)
    FORMS[name].inner_name = inner


_register(ADAPTIVE_METHODS, "sage-husa", SageHusa, "kf", diagonal_q=False, **Q_ABOVE_NOMINAL, **SATELLITE_R)
_register(ADAPTIVE_METHODS, "svd-akf", SageHusa, "svd-kf", diagonal_q=False, **Q_ABOVE_NOMINAL, **SATELLITE_R)
_register(ADAPTIVE_METHODS, "svd-asrkf", SageHusa, "svd-srkf", diagonal_q=True, **Q_ABOVE_NOMINAL, **SATELLITE_R)
_register(ADAPTIVE_METHODS, "sage-husa-r", SageHusa, "kf", adapt_q=False, **SATELLITE_R)
_register(ADAPTIVE_METHODS, "sage-husa-group", SageHusa, "kf", diagonal_q=False, adapt_r=True)
_register(ADAPTIVE_METHODS, "stkf", StrongTracking, "kf")
_register(ADAPTIVE_METHODS, "ma-stkf", MeasurementAdaptiveSTKF, "kf")
_register(ADAPTIVE_METHODS, "vb-akf", VariationalR, "kf")

ROBUST_METHODS: dict = {}
"""Method name -> form factory of the robust measurement screens (fault exclusion, M-estimation)."""
_register(ROBUST_METHODS, "kf-fde", FaultExclusion, "kf")
_register(ROBUST_METHODS, "kf-igg3", RobustUpdate, "kf", weight="igg3")
_register(ROBUST_METHODS, "kf-huber", RobustUpdate, "kf", weight="huber")

FDE_SUFFIX = "+fde"

ONESTEP_SUFFIX = "+onestep"


def parse_method(method: str) -> tuple[str, bool]:
    """Split ``'kf+onestep'`` into ``('kf', True)``; ``ValueError`` for an unknown base name.

    The base keeps any other suffix (``'sage-husa+fde+onestep'`` -> ``('sage-husa+fde', True)``)."""
    if not isinstance(method, str):
        raise ValueError(f"method must be a string, got {method!r}")
    onestep = method.endswith(ONESTEP_SUFFIX)
    base = method[: -len(ONESTEP_SUFFIX)] if onestep else method
    method_factory(base, method)
    return base, onestep


def method_factory(base: str, method: str | None = None):
    """The form factory of a method name without ``+onestep`` (``ValueError`` naming ``method`` if unknown):
    the registered one, or for ``'<name>+fde'`` fault exclusion around ``<name>``'s."""
    if base in FORMS:
        return FORMS[base]
    if base.endswith(FDE_SUFFIX) and base[: -len(FDE_SUFFIX)] in FORMS:
        return _with_fde(base[: -len(FDE_SUFFIX)])
    raise ValueError(f"unknown filter method {method or base!r}; known: {sorted(FORMS)} (optionally with "
                     f"'{FDE_SUFFIX}' and/or '{ONESTEP_SUFFIX}')")


@functools.lru_cache(maxsize=None)
def _with_fde(name: str):
    """The factory of ``name + '+fde'``: :class:`~nav_filters.adaptive.FaultExclusion` around ``name``'s factory."""
    f = law_factory(FaultExclusion, FORMS[name])
    f.inner_name = name
    return f


def make_form(method: str, P0, x0=None, dtype=None) -> FilterForm:
    """Instantiate the form named by ``method`` (``+onestep`` ignored) with initial covariance ``P0`` (B, n, n)."""
    base, _ = parse_method(method)
    return method_factory(base)(P0, x0=x0, dtype=dtype)


def law_class(method: str):
    """The adaptive law class a method runs (for ``+fde``, the wrapped method's; ``+onestep`` ignored), or None
    for a plain form or a robust screen without a law of parameters."""
    f = method_factory(parse_method(method)[0])
    while getattr(f, "law", None) is FaultExclusion:
        f = f.inner
    return getattr(f, "law", None)


def law_params(method: str) -> tuple:
    """The adaptive parameters (:class:`~nav_filters.adaptive.ParamSpec`) a method takes through
    ``form.set_params``: its law's (for ``+fde``, the wrapped method's), ``()`` for a plain form."""
    f = method_factory(parse_method(method)[0])
    while getattr(f, "law", None) is FaultExclusion:
        f = f.inner
    law = getattr(f, "law", None)
    return () if law is None else tuple(law.PARAMS)


__all__ = ["FORMS", "PLAIN_FORMS", "ADAPTIVE_METHODS", "ROBUST_METHODS", "FDE_SUFFIX", "ONESTEP_SUFFIX", "parse_method", "method_factory",
           "make_form", "law_params", "law_class"]
