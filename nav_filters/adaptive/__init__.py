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
===================  ==============================================================  ===============

The per-satellite methods need the measurement keys (``Navigator.update_gnss(..., sat_keys=...)``); the
environments and eval.py pass them.

:func:`law_factory` builds the ``(P0, x0=None, dtype=None) -> FilterForm``
callable that :data:`nav_filters.registry.FORMS` holds; :data:`ADAPTIVE_METHODS`
lists the entries above (the inner form is looked up by name when the
filter is built, so an entry whose inner form is not registered fails then
with a ``ValueError``).

Agents set the per-row parameters between steps with ``form.set_params(...)``
and read ``form.params()`` and ``form.adaptive_state()`` ((B,) arrays).
"""
from __future__ import annotations

from .base import AdaptiveLaw, EpochContext, UpdatePlan, resolve_inner
from .innovation import GROUP_NAMES, InnovationTraces, innovation_traces, measurement_groups
from .params import ParamSpec
from .sage_husa import SageHusa, SageHusaConfig, clip_relative_eigenvalues, sage_husa_weight
from .strong_tracking import (MeasurementAdaptiveSTKF, MeasurementAdaptiveSTKFConfig, StrongTracking,
                              StrongTrackingConfig, fading_factor)


def law_factory(law: type, inner="kf", **config):
    """A filter-form factory ``(P0, x0=None, dtype=None) -> law`` for :data:`nav_filters.registry.FORMS`.

    Parameters
    ----------
    law : an :class:`AdaptiveLaw` subclass.
    inner : inner form name (resolved when the filter is built) or factory.
    **config : fields of ``law.config_class`` (validated now).

    Returns
    -------
    callable with attributes ``law``, ``inner`` and ``config``.
    """
    if not (isinstance(law, type) and issubclass(law, AdaptiveLaw)):
        raise ValueError(f"law must be an AdaptiveLaw subclass, got {law!r}")
    cfg = law.config_class(**config)
    if not isinstance(inner, str):
        resolve_inner(inner)

    def factory(P0, x0=None, dtype=None):
        return law(P0, x0=x0, dtype=dtype, inner=inner, config=cfg)

    factory.law, factory.inner, factory.config = law, inner, cfg
    factory.__name__ = f"{law.__name__}[{inner if isinstance(inner, str) else getattr(inner, '__name__', 'inner')}]"
    factory.__doc__ = f"{law.__name__} around {inner!r} with {cfg!r}."
    return factory


_SATELLITE_R = dict(adapt_r=True, r_mode="satellite", d_freeze_tol=0.0, r_sample="consensus", prior_inflation=1.0,
                    sat_scale_min=1.0, median_guard=True)
"""Per-satellite measurement-noise adaptation without the freezing of d, with the consensus sample (the smaller
of the deleted residual against the filter's own prior, relative to its epoch's median, and the snapshot-fit
residual) and no satellite trusted more than its reported variance (see :class:`SageHusa`)."""

_Q_ABOVE_NOMINAL = dict(q_lower="nominal")
"""The Q law only adds process noise to the nominal model (the applied epoch Q at least the nominal one; see
:class:`SageHusa`, 'Q never below the nominal model')."""

ADAPTIVE_METHODS = {
    "sage-husa": law_factory(SageHusa, "kf", diagonal_q=False, **_Q_ABOVE_NOMINAL, **_SATELLITE_R),
    "svd-akf": law_factory(SageHusa, "svd-kf", diagonal_q=False, **_Q_ABOVE_NOMINAL, **_SATELLITE_R),
    "svd-asrkf": law_factory(SageHusa, "svd-srkf", diagonal_q=True, **_Q_ABOVE_NOMINAL, **_SATELLITE_R),
    "sage-husa-r": law_factory(SageHusa, "kf", adapt_q=False, **_SATELLITE_R),
    "sage-husa-group": law_factory(SageHusa, "kf", diagonal_q=False, adapt_r=True),
    "stkf": law_factory(StrongTracking, "kf"),
    "ma-stkf": law_factory(MeasurementAdaptiveSTKF, "kf"),
}
"""Method name -> form factory of the adaptive methods of DESIGN.md section 4."""

__all__ = [
    "AdaptiveLaw", "EpochContext", "UpdatePlan", "resolve_inner", "ParamSpec",
    "GROUP_NAMES", "InnovationTraces", "innovation_traces", "measurement_groups",
    "SageHusa", "SageHusaConfig", "sage_husa_weight", "clip_relative_eigenvalues",
    "StrongTracking", "StrongTrackingConfig", "MeasurementAdaptiveSTKF", "MeasurementAdaptiveSTKFConfig",
    "fading_factor", "law_factory", "ADAPTIVE_METHODS",
]
