"""Variance models for the pseudorange sigma the filter is told (``sigma_model``; DESIGN.md section 8).

A receiver reports a sigma with each pseudorange (smartLoc: the recorded variance; RINEX: the loader's
elevation model; the simulator: its nominal model). A user may instead compute the sigma from the
elevation and the C/N0 of the measurement; :class:`SigmaModel` names the model and its parameters:

=================  ============================================================  ==================================
name               variance [m^2]                                                source
=================  ============================================================  ==================================
``receiver``       the reported sigma squared (unchanged)                       --
``elevation``      ``a^2 + b^2 / sin^2(el)``                                     RTKLIB (:func:`elevation_variance`)
``sigma-epsilon``  ``C 10^(-(C/N0)/10)``                                         Hartinger & Brunner 1999
                                                                                 (:func:`sigma_epsilon_variance`)
``elevation-cn0``  ``(sigma_Z^2 + sigma_c^2 / (c/n0)) / sin^2(el)``              Groves 2013 eq. 9.168
                                                                                 (:func:`elevation_cn0_variance`)
=================  ============================================================  ==================================

Units: elevation in radians inside, C/N0 in dB-Hz (``c/n0 = 10^((C/N0)/10)`` in Hz), sigmas in metres.
``1/sin(el)`` is evaluated at ``max(el, MIN_ELEVATION_RAD)`` (1 deg, as the simulator's own 1/sin model:
finite at a 0-deg mask). Only the sigma the filter is told changes (``pr_sigma``); the true errors never
depend on the model. The functions broadcast over any leading axes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["SIGMA_MODELS", "MODEL_PARAMETERS", "MIN_ELEVATION_RAD", "SIGMA_EPSILON_CODE_M2HZ",
           "RTKLIB_CODE_ERROR_M", "SigmaModel", "elevation_variance", "sigma_epsilon_variance",
           "elevation_cn0_variance", "model_pr_sigma"]

SIGMA_MODELS = ("receiver", "elevation", "sigma-epsilon", "elevation-cn0")
"""The model names."""
MODEL_PARAMETERS = {"receiver": (), "elevation": ("a_m", "b_m"), "sigma-epsilon": ("c_m2hz",),
                    "elevation-cn0": ("zenith_m", "tracking_m_sqrthz")}
"""The :class:`SigmaModel` fields each model uses."""
MIN_ELEVATION_RAD = math.radians(1.0)
"""Elevation floor of the ``1/sin(el)`` terms [rad]."""
RTKLIB_CODE_ERROR_M = 0.3
"""RTKLIB's default code error factors a = b [m]: its carrier-phase error factors (0.003 m) times its default
code/carrier-phase error ratio (100) (RTKLIB ver. 2.4.2 manual, Appendix E.6 / E.7, options ``err`` and
``eratio``)."""
SIGMA_EPSILON_CODE_M2HZ = 1.1e4
"""The SIGMA-epsilon constant for GPS C/A-code pseudoranges [m^2 Hz]. Hartinger & Brunner (1999) give the
form and its constants for *carrier phase* (millimetre-level); for code pseudoranges the form is used with
``C = 1.1e4 m^2 Hz`` in urban single-point positioning (quoted among the citing statements of Hartinger &
Brunner 1999; the primary source of the number could not be traced here). Its physical reading: the
thermal-noise variance of a coherent early-minus-late code loop, ``Tc^2 B_L d / (2 c/n0)``, with the C/A chip
``Tc = 293.05 m``, loop bandwidth ``B_L = 0.5 Hz`` and spacing ``d = 0.5`` chip gives 1.07e4 m^2 Hz. It holds
tracking noise only (no multipath): 0.59 m at 45 dB-Hz, 3.3 m at 30 dB-Hz."""


@dataclass(frozen=True)
class SigmaModel:
    """The pseudorange sigma model (module table) and its parameters.

    Attributes
    ----------
    name : a name of :data:`SIGMA_MODELS` (default ``'receiver'``: the reported sigma, unchanged).
    a_m, b_m : ``elevation``: constant and elevation-dependent terms [m] (default 0.3 and 0.3:
        :data:`RTKLIB_CODE_ERROR_M`).
    c_m2hz : ``sigma-epsilon``: the constant C [m^2 Hz] (default :data:`SIGMA_EPSILON_CODE_M2HZ`).
    zenith_m : ``elevation-cn0``: zenith term sigma_Z [m] (default 0.3 m; assumption: RTKLIB's zenith code
        error, as ``a_m``).
    tracking_m_sqrthz : ``elevation-cn0``: C/N0-dependent tracking term sigma_c [m Hz^0.5] (default
        ``sqrt(SIGMA_EPSILON_CODE_M2HZ)`` = 104.9; assumption: the SIGMA-epsilon constant, so that at zenith
        the model is ``zenith_m^2`` plus the ``sigma-epsilon`` variance).

    Every parameter is a finite number >= 0, and the named model's parameters are not all zero (a zero
    sigma would be an infinitely precise measurement); parameters of other models are ignored.
    """

    name: str = "receiver"
    a_m: float = RTKLIB_CODE_ERROR_M
    b_m: float = RTKLIB_CODE_ERROR_M
    c_m2hz: float = SIGMA_EPSILON_CODE_M2HZ
    zenith_m: float = RTKLIB_CODE_ERROR_M
    tracking_m_sqrthz: float = math.sqrt(SIGMA_EPSILON_CODE_M2HZ)

    def __post_init__(self):
        if self.name not in SIGMA_MODELS:
            raise ValueError(f"SigmaModel.name {self.name!r} is unknown; known: {', '.join(SIGMA_MODELS)}")
        for f in ("a_m", "b_m", "c_m2hz", "zenith_m", "tracking_m_sqrthz"):
            v = getattr(self, f)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) \
                    or not math.isfinite(v):
                raise ValueError(f"SigmaModel.{f} must be a finite number, got {v!r}")
            if v < 0:
                raise ValueError(f"SigmaModel.{f} must be >= 0, got {v!r}")
        used = MODEL_PARAMETERS[self.name]
        if used and all(getattr(self, f) == 0 for f in used):
            raise ValueError(f"SigmaModel.{used[0]}: the {self.name!r} model needs a parameter > 0 among "
                             f"{', '.join(used)} (a zero sigma)")

    @property
    def needs_cn0(self) -> bool:
        """Whether the model reads the C/N0."""
        return self.name in ("sigma-epsilon", "elevation-cn0")

    def variance(self, elevation, cn0_dbhz) -> np.ndarray:
        """The model's variance [m^2] at ``elevation`` [rad] and ``cn0_dbhz`` [dB-Hz] (broadcast; the
        ``receiver`` model has none: ``ValueError``)."""
        if self.name == "elevation":
            return elevation_variance(elevation, self.a_m, self.b_m)
        if self.name == "sigma-epsilon":
            return sigma_epsilon_variance(cn0_dbhz, self.c_m2hz)
        if self.name == "elevation-cn0":
            return elevation_cn0_variance(elevation, cn0_dbhz, self.zenith_m, self.tracking_m_sqrthz)
        raise ValueError("SigmaModel.name 'receiver' has no variance model: the reported sigma is used")


def _inv_sin2(elevation) -> np.ndarray:
    s = np.sin(np.maximum(np.asarray(elevation, np.float64), MIN_ELEVATION_RAD))
    return 1.0 / (s * s)


def elevation_variance(elevation, a_m: float, b_m: float) -> np.ndarray:
    """RTKLIB's elevation-dependent error model ``sigma^2 = a^2 + b^2 / sin^2(el)``.

    T. Takasu, RTKLIB ver. 2.4.2 Manual (2013), Appendix E.7 (relative positioning: the measurement error
    variance ``a^2 + b^2 / sin^2 El`` of the phase error factors, scaled by the code/carrier-phase error
    ratio for code; ``rtkpos.c`` ``varerr``). Its single-point variant (Appendix E.6, eq. E.6.24;
    ``pntpos.c``) divides ``b^2`` by ``sin El``, not its square.

    Parameters
    ----------
    elevation : (...) [rad], floored at :data:`MIN_ELEVATION_RAD`.
    a_m, b_m : [m].

    Returns
    -------
    (...) variance [m^2].
    """
    return a_m * a_m + b_m * b_m * _inv_sin2(elevation)


def sigma_epsilon_variance(cn0_dbhz, c_m2hz: float) -> np.ndarray:
    """The SIGMA-epsilon model ``sigma^2 = C 10^(-(C/N0)/10)``.

    H. Hartinger and F. K. Brunner, "Variances of GPS phase observations: the SIGMA-epsilon model", GPS
    Solutions 2(4), 35-43 (1999), doi:10.1007/PL00012765: the noise variance of a tracked signal is inversely
    proportional to its carrier-to-noise density ``c/n0 = 10^((C/N0)/10)`` [Hz]. Code pseudoranges: ``C`` of
    :data:`SIGMA_EPSILON_CODE_M2HZ`.

    Parameters
    ----------
    cn0_dbhz : (...) C/N0 [dB-Hz].
    c_m2hz : C [m^2 Hz].

    Returns
    -------
    (...) variance [m^2].
    """
    return c_m2hz * 10.0 ** (-np.asarray(cn0_dbhz, np.float64) / 10.0)


def elevation_cn0_variance(elevation, cn0_dbhz, zenith_m: float, tracking_m_sqrthz: float,
                           accel_s2: float = 0.0, range_accel_mps2=0.0) -> np.ndarray:
    """Groves' elevation- and C/N0-dependent pseudo-range error model.

    P. D. Groves, Principles of GNSS, Inertial, and Multisensor Integrated Navigation Systems, 2nd ed.
    (2013), section 9.4.2, eq. 9.168::

        sigma_rho^2 = (1 / sin^2 el) (sigma_rhoZ^2 + sigma_rhoc^2 / (c/n0) + sigma_rhoa^2 rddot_a^2)

    with ``c/n0 = 10^((C/N0)/10)`` [Hz] and ``rddot_a`` the line-of-sight range acceleration (tracking lag
    under dynamics). A receiver reports no range acceleration, so :class:`SigmaModel` leaves the last term
    out (``accel_s2 = 0``); it is kept here for completeness.

    Parameters
    ----------
    elevation : (...) [rad], floored at :data:`MIN_ELEVATION_RAD`.
    cn0_dbhz : (...) C/N0 [dB-Hz].
    zenith_m : sigma_rhoZ [m]; tracking_m_sqrthz : sigma_rhoc [m Hz^0.5]; accel_s2 : sigma_rhoa [s^2].
    range_accel_mps2 : (...) range acceleration [m/s^2].

    Returns
    -------
    (...) variance [m^2].
    """
    cn0 = 10.0 ** (np.asarray(cn0_dbhz, np.float64) / 10.0)
    accel = accel_s2 * np.asarray(range_accel_mps2, np.float64)
    return (zenith_m * zenith_m + tracking_m_sqrthz * tracking_m_sqrthz / cn0 + accel * accel) \
        * _inv_sin2(elevation)


def model_pr_sigma(model: SigmaModel, reported, mask, elevation, cn0_dbhz, source: str = "") -> np.ndarray:
    """The pseudorange sigma [m] the filter is told under ``model``: ``reported`` for ``'receiver'``, else the
    model's on valid channels and 0 on masked ones.

    Parameters
    ----------
    model : SigmaModel.
    reported : (...) the reported sigma [m]; mask : (...) bool valid channel.
    elevation : (...) [rad]; cn0_dbhz : (...) [dB-Hz], 0 (or less) where unknown, or None where the source
        has none.
    source : the file (or data set) the channels come from, for the error message.

    Raises
    ------
    ValueError : a C/N0 model and a valid channel without a C/N0, naming ``source`` and the count.
    """
    if model.name == "receiver":
        return reported
    mask = np.asarray(mask, bool)
    if model.needs_cn0:
        where = source or "the GNSS data"
        if cn0_dbhz is None:
            raise ValueError(f"{where}: sigma_model {model.name!r} needs the C/N0 of each pseudorange; this "
                             f"source has none")
        missing = mask & ~(np.asarray(cn0_dbhz, np.float64) > 0)
        if missing.any():
            raise ValueError(f"{where}: sigma_model {model.name!r} needs the C/N0 of each pseudorange; "
                             f"{int(missing.sum())} of {int(mask.sum())} have none (e.g. no S1C/S1X "
                             f"observable for their code)")
    with np.errstate(over="ignore", invalid="ignore"):
        var = model.variance(elevation, cn0_dbhz)
    return np.where(mask, np.sqrt(var), 0.0)
