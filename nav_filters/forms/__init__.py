"""Kalman-filter forms behind one interface (:class:`FilterForm`).

The method names of DESIGN.md section 4 (these forms and the adaptive laws of :mod:`nav_filters.adaptive`
that compose them) are looked up in :mod:`nav_filters.registry` (``FORMS``, ``parse_method``,
``make_form``), which sits above both packages.
"""
from __future__ import annotations

from .base import FilterForm, UpdateResult, prepare_measurement
from .information import InformationFilter, SvdInformationFilter
from .kf import KalmanFilter
from .srif import SquareRootInformationFilter
from .svd import SvdKalmanFilter, SvdSquareRootKF

__all__ = ["FilterForm", "UpdateResult", "KalmanFilter", "InformationFilter", "SvdInformationFilter",
           "SquareRootInformationFilter", "SvdSquareRootKF", "SvdKalmanFilter", "prepare_measurement"]


def __getattr__(name):
    """``nav_filters.forms.FORMS`` / ``parse_method`` / ``make_form``: the registry's own objects (the same
    dict, so registering through either name is one registration), looked up on first use; new code imports
    them from :mod:`nav_filters.registry`."""
    if name in ("FORMS", "parse_method", "make_form", "ONESTEP_SUFFIX"):
        from .. import registry
        return getattr(registry, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
