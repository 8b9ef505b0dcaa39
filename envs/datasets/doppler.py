"""Pseudorange rates from RINEX Doppler observables (issue 12).

RINEX 3 (sec. 5.6) records the Doppler ``D`` in Hz, **positive for
approaching satellites** (the range decreasing). The pseudorange rate of the
navigator (:mod:`earth.ranging`, :class:`envs.sim.gnss.GnssData`: ``prr =
rho_dot + c (dt_r_dot - dt_s_dot)``, positive when the range grows) is
therefore::

    prr = -lambda * D + c * dt_s_dot

with ``lambda = c / f`` the carrier wavelength of the observable's system and
band (:data:`CARRIER_HZ`, from the GPS, Galileo and BeiDou ICDs) and
``dt_s_dot`` the broadcast satellite clock drift (``af1 + 2 af2 (t - toc)``
plus the relativistic term's rate,
:func:`envs.datasets.ephemeris.satellite_states`). The receiver clock drift
``c dt_r_dot`` remains, as the navigator expects. GLONASS (FDMA: one
frequency per channel number) is not handled, like its orbits.

The one-sigma error is the elevation model of the code,
``sigma0 * sqrt(1 + 1 / sin^2 el)`` with a zenith ``sigma0`` in m/s.
"""
from __future__ import annotations

import numpy as np

from earth.wgs84 import C_LIGHT

__all__ = ["CARRIER_HZ", "wavelength", "pseudorange_rate"]

CARRIER_HZ = {
    ("G", "1"): 1575.42e6, ("G", "2"): 1227.60e6, ("G", "5"): 1176.45e6,
    ("E", "1"): 1575.42e6, ("E", "5"): 1176.45e6, ("E", "7"): 1207.14e6, ("E", "8"): 1191.795e6,
    ("E", "6"): 1278.75e6,
    ("C", "2"): 1561.098e6, ("C", "1"): 1575.42e6, ("C", "5"): 1176.45e6, ("C", "7"): 1207.14e6,
    ("C", "8"): 1191.795e6, ("C", "6"): 1268.52e6,
}
"""(system letter, RINEX band digit) -> carrier frequency [Hz] (IS-GPS-200/705, Galileo OS SIS ICD 2.1,
BeiDou ICDs B1I/B1C/B2a/B3I)."""


def wavelength(system: str, observable: str) -> float:
    """Carrier wavelength [m] of a RINEX 3 observable (``'D1C'``, ``'C2I'``, ...) of system ``system``.

    Raises
    ------
    ValueError : a system / band pair without a fixed carrier (GLONASS FDMA, unknown band).
    """
    key = (system, str(observable)[1:2])
    if system == "C" and str(observable)[1:3] in ("1I", "1Q"):      # RINEX 3.02 named B1I band 1 (3.03+: 2)
        key = ("C", "2")
    if key not in CARRIER_HZ:
        raise ValueError(f"no carrier frequency for system {system!r} observable {observable!r} "
                         f"(known: {sorted(CARRIER_HZ)}; GLONASS FDMA is not supported)")
    return C_LIGHT / CARRIER_HZ[key]


def pseudorange_rate(doppler_hz, wavelength_m, sat_clock_drift):
    """Pseudorange rate [m/s] (module docstring) from Doppler [Hz], wavelength [m] and the satellite clock
    drift [s/s]; arrays broadcast together."""
    return -np.asarray(wavelength_m) * np.asarray(doppler_hz) + C_LIGHT * np.asarray(sat_clock_drift)


NO_DOPPLER_SIGMA_MPS = 1e4
"""Pseudorange-rate sigma [m/s] of a channel with a code but no Doppler: its rate row carries no information
(the channel's pseudorange is kept)."""


def doppler_epochs(obs, mi, si, sat_clock_drift, ok, sin_el, sigma0_mps: float):
    """(M, S) pseudorange rates and sigmas of :func:`envs.datasets.rinex.rinex_epochs` (module docstring).

    Parameters
    ----------
    obs : ObsData with ``doppler``; mi, si : (K,) epoch / satellite index of the channels with an orbit;
    sat_clock_drift : (K,) their satellite clock drift [s/s]; ok : (M, S) valid channels;
    sin_el : (M, S) sine of the elevation (floored); sigma0_mps : zenith sigma [m/s], > 0.

    Returns
    -------
    prr, prr_sigma : (M, S) [m/s], zero off ``ok``; a valid channel without a Doppler gets rate 0 and
    sigma :data:`NO_DOPPLER_SIGMA_MPS`.
    """
    if not (isinstance(sigma0_mps, (int, float)) and np.isfinite(sigma0_mps) and sigma0_mps > 0):
        raise ValueError(f"doppler_sigma0_mps must be a finite number > 0, got {sigma0_mps!r}")
    letters = [str(s)[0] for s in obs.sv]
    lam = np.array([wavelength(l, c) for l, c in zip(letters, obs.code)])
    M, S = obs.pr.shape
    prr = np.zeros((M, S))
    drift = np.zeros((M, S))
    drift[mi, si] = sat_clock_drift
    d = obs.doppler
    has = ok & np.isfinite(d)
    prr[has] = pseudorange_rate(d[has], np.broadcast_to(lam, (M, S))[has], drift[has])
    sigma = np.where(has, sigma0_mps * np.sqrt(1.0 + 1.0 / sin_el ** 2), NO_DOPPLER_SIGMA_MPS)
    return prr, np.where(ok, sigma, 0.0)
