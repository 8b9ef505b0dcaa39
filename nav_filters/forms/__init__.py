"""Kalman-filter forms behind one interface (:class:`FilterForm`).

The method names of DESIGN.md section 4 (these forms and the adaptive laws of :mod:`nav_filters.adaptive`
that compose them) are looked up in :mod:`nav_filters.registry` (``FORMS``, ``parse_method``,
``make_form``), which sits above both packages; the forms know nothing of it.
"""
from __future__ import annotations

from .base import FilterForm, UpdateResult, prepare_measurement
from .information import InformationFilter, SvdInformationFilter
from .kf import KalmanFilter
from .srif import SquareRootInformationFilter
from .svd import SvdKalmanFilter, SvdSquareRootKF

__all__ = ["FilterForm", "UpdateResult", "KalmanFilter", "InformationFilter", "SvdInformationFilter",
           "SquareRootInformationFilter", "SvdSquareRootKF", "SvdKalmanFilter", "prepare_measurement"]

