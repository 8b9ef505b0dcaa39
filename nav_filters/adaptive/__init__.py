"""Adaptive laws that compose the Kalman-filter forms (DESIGN.md section 4 method names).

Each law is a :class:`~nav_filters.forms.base.FilterForm` wrapping an *inner*
form through its public interface (:mod:`nav_filters.adaptive.base`), so one
law adapts every form:

===================  ==============================================================  ===============
method               law                                                             inner form
===================  ==============================================================  ===============
``sage-husa``        :class:`SageHusa`, full Q correction, R per satellite           ``kf``
``svd-akf``          :class:`SageHusa`, full Q correction (seed 000 eq 22), R per    ``svd-kf``
                     satellite
``svd-asrkf``        :class:`SageHusa`, diagonal Q correction (seed 000 eq 21), R    ``svd-srkf``
                     per satellite
``sage-husa-r``      :class:`SageHusa`, R per satellite, nominal Q                   ``kf``
``sage-husa-group``  :class:`SageHusa`, full Q correction, one R scale per           ``kf``
                     measurement group, frozen d (the law before per-satellite R)
``stkf``             :class:`StrongTracking` (suboptimal fading factor)              ``kf``
``ma-stkf``          :class:`MeasurementAdaptiveSTKF` (seed 003 eqs 10-26)           ``kf``
``vb-akf``           :class:`VariationalR`: variational-Bayes R per satellite           ``kf``
                     (Särkkä & Nummenmaa 2009)
===================  ==============================================================  ===============

The robust measurement screens compose the forms the same way (:data:`nav_filters.registry.ROBUST_METHODS`):

===================  ==============================================================  ===============
method               law                                                             inner form
===================  ==============================================================  ===============
``kf-fde``           :class:`FaultExclusion`: chi-square detection, exclusion by the    ``kf``
                     normalized deleted residual, per-row gate (``+fde`` wraps any
                     method)
``kf-igg3``          :class:`RobustUpdate`, IGG-III equivalent weights (Yang et al.)   ``kf``
``kf-huber``         :class:`RobustUpdate`, Huber weights                             ``kf``
===================  ==============================================================  ===============

The per-satellite methods need the measurement keys (``Navigator.update_gnss(..., sat_keys=...)``); the
environments and eval.py pass them.

:func:`law_factory` builds the ``(P0, x0=None, dtype=None) -> FilterForm``
callable that :data:`nav_filters.registry.FORMS` holds, given the law and the
factory of its inner form. The laws know nothing of method names: the
registry (:mod:`nav_filters.registry`, which sits above this package and the
forms) registers the entries above, resolving each inner form's name to its
factory (:data:`nav_filters.registry.ADAPTIVE_METHODS`).

Agents set the per-row parameters between steps with ``form.set_params(...)``
and read ``form.params()`` and ``form.adaptive_state()`` ((B,) arrays).
"""
from __future__ import annotations

from ..forms.kf import KalmanFilter
from .base import AdaptiveLaw, EpochContext, UpdatePlan, resolve_inner
from .innovation import GROUP_NAMES, InnovationTraces, innovation_traces, measurement_groups
from .params import ParamSpec
from .sage_husa import SageHusa, SageHusaConfig, clip_relative_eigenvalues, sage_husa_weight
from .strong_tracking import (MeasurementAdaptiveSTKF, MeasurementAdaptiveSTKFConfig, StrongTracking,
                              StrongTrackingConfig, fading_factor)
from .fde import FaultExclusion, FdeConfig
from .mestimation import RobustConfig, RobustUpdate
from .vb import VariationalR, VbConfig


def law_factory(law: type, inner=KalmanFilter, **config):
    """A filter-form factory ``(P0, x0=None, dtype=None) -> law`` for :data:`nav_filters.registry.FORMS`.

    Parameters
    ----------
    law : an :class:`AdaptiveLaw` subclass.
    inner : the inner form's class or factory ``(P0, x0=None, dtype=None) -> FilterForm`` (the registry passes
        the factory registered under the inner method's name).
    **config : fields of ``law.config_class`` (validated now).

    Returns
    -------
    callable with attributes ``law``, ``inner`` and ``config``.
    """
    if not (isinstance(law, type) and issubclass(law, AdaptiveLaw)):
        raise ValueError(f"law must be an AdaptiveLaw subclass, got {law!r}")
    cfg = law.config_class(**config)
    inner = resolve_inner(inner)

    def factory(P0, x0=None, dtype=None):
        return law(P0, x0=x0, dtype=dtype, inner=inner, config=cfg)

    factory.law, factory.inner, factory.config = law, inner, cfg
    factory.__name__ = f"{law.__name__}[{getattr(inner, '__name__', 'inner')}]"
    factory.__doc__ = f"{law.__name__} around {factory.__name__[len(law.__name__) + 1:-1]} with {cfg!r}."
    return factory


SATELLITE_R = dict(adapt_r=True, r_mode="satellite", d_freeze_tol=0.0, r_sample="consensus", prior_inflation=1.0,
                   sat_scale_min=1.0, median_guard=True)
"""Per-satellite measurement-noise adaptation without the freezing of d, with the consensus sample (the smaller
of the deleted residual against the filter's own prior, relative to its epoch's median, and the snapshot-fit
residual) and no satellite trusted more than its reported variance (see :class:`SageHusa`): the configuration
of the registered per-satellite Sage-Husa methods (:data:`nav_filters.registry.ADAPTIVE_METHODS`)."""

Q_ABOVE_NOMINAL = dict(q_lower="nominal")
"""The Q law only adds process noise to the nominal model (the applied epoch Q at least the nominal one; see
:class:`SageHusa`, 'Q never below the nominal model'): the registered Sage-Husa methods that adapt Q."""

__all__ = [
    "AdaptiveLaw", "EpochContext", "UpdatePlan", "resolve_inner", "ParamSpec",
    "GROUP_NAMES", "InnovationTraces", "innovation_traces", "measurement_groups",
    "SageHusa", "SageHusaConfig", "sage_husa_weight", "clip_relative_eigenvalues",
    "StrongTracking", "StrongTrackingConfig", "MeasurementAdaptiveSTKF", "MeasurementAdaptiveSTKFConfig",
    "fading_factor", "law_factory", "SATELLITE_R", "Q_ABOVE_NOMINAL", "FaultExclusion", "FdeConfig", "RobustUpdate", "RobustConfig",
    "VariationalR", "VbConfig",
]
