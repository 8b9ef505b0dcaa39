"""The 17-state error-state model of the tightly coupled GNSS/INS filter (seed paper 000, eq 1).

State vector (order fixed project-wide), ``x`` of shape (B, 17)::

    x = [dpsi (0:3), dv_e (3:6), dr_e (6:9), b_g (9:12), b_a (12:15), clk (15), drift (16)]

=========  ==========  ===================================================  ========
slice      name        meaning                                              unit
=========  ==========  ===================================================  ========
``ATT``    dpsi        attitude error, resolved in ECEF                     rad
``VEL``    dv_e        velocity error, ECEF                                 m/s
``POS``    dr_e        position error, ECEF                                 m
``BG``     b_g         gyro-bias residual, body frame                       rad/s
``BA``     b_a         accelerometer-bias residual, body frame              m/s^2
``CLK``    clk         receiver clock-bias residual (times c)               m
``DRIFT``  drift       receiver clock-drift residual (times c)              m/s
=========  ==========  ===================================================  ========

Sign convention (fixed project-wide): ``x`` is the correction to **add** to
the estimate, i.e. truth minus estimate::

    C_eb_true = (I + [dpsi x]) C_eb_est,   v_true = v_est + dv,   r_true = r_est + dr,
    bias_true = bias_est + b,              clock_true = clock_est + clk.

The navigator subtracts its bias estimates from the raw IMU samples
(``w = w_raw - bg_est``, ``f = f_raw - ba_est``), so with
``w_raw = w_true + bg_true + n_g`` the corrected samples it integrates are
``w = w_true + b_g + n_g`` and ``f = f_true + b_a + n_a``.

Derivation of the continuous-time dynamics ``dx/dt = F x + G w`` for this
convention (the ECEF error model of Groves, *Principles of GNSS, Inertial, and
Multisensor Integrated Navigation Systems*, 2nd ed., sec 14.2.3, eqs
14.48-14.50, whose errors are estimate minus truth: the navigation blocks are
the same, the bias columns change sign because here a positive residual makes
the corrected sample too *large*). With ``C = C_eb_est``,
``Omega = [w_ie x]``, ``w_ie = (0, 0, OMEGA_IE)``:

* truth ``dC/dt = C [w_true x] - Omega C``, estimate the same with ``w``;
  differentiating ``C_true = (I + [dpsi x]) C`` and keeping first-order terms
  gives ``d(dpsi)/dt = -Omega dpsi + C (w_true - w) = -Omega dpsi - C b_g - C n_g``;
* ``dv_true/dt = C_true f_true + g(r_true) - 2 Omega v_true``; subtracting the
  estimate's equation, ``C_true f_true = C f_true + dpsi x (C f)`` and
  ``f_true = f - b_a - n_a`` give
  ``d(dv)/dt = -[(C f) x] dpsi - 2 Omega dv + Gamma dr - C b_a - C n_a``;
* ``d(dr)/dt = dv``;
* biases: random walk ``db/dt = w_b`` or first-order Gauss-Markov
  ``db/dt = -b / tau + w_b`` (the GM form of the *residual* assumes the
  navigator's own bias estimate decays with the same ``tau``, or is zero);
* clock: ``d(clk)/dt = drift + w_clk``, ``d(drift)/dt = w_drift``.

``Gamma = d g / d r`` is the gravity gradient; see :func:`gravity_gradient`.

References: Groves (2013) sec 14.2.3 (ECEF INS error model, eqs 14.48-14.50),
sec 3.2 (discretization: ``Phi`` as a power series in ``F dt``, trapezoidal
``Q_d``), sec 14.2.7 (bias and receiver-clock states; equation numbers are
those of the 2nd edition as far as the implementer could check them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple, Union

import numpy as np

from earth.wgs84 import GM, OMEGA_IE

__all__ = [
    "N_STATES", "ATT", "VEL", "POS", "BG", "BA", "CLK", "DRIFT", "STATE_NAMES",
    "ProcessNoise", "gravity_gradient", "system_matrix", "discretize", "transition",
]

N_STATES = 17
"""Number of error states."""
ATT = slice(0, 3)
"""Attitude error dpsi (ECEF-resolved) [rad]."""
VEL = slice(3, 6)
"""Velocity error dv_e [m/s]."""
POS = slice(6, 9)
"""Position error dr_e [m]."""
BG = slice(9, 12)
"""Gyro-bias residual, body frame [rad/s]."""
BA = slice(12, 15)
"""Accelerometer-bias residual, body frame [m/s^2]."""
CLK = slice(15, 16)
"""Receiver clock-bias residual [m]."""
DRIFT = slice(16, 17)
"""Receiver clock-drift residual [m/s]."""
STATE_NAMES = (
    "psi_x", "psi_y", "psi_z", "dv_x", "dv_y", "dv_z", "dr_x", "dr_y", "dr_z",
    "bg_x", "bg_y", "bg_z", "ba_x", "ba_y", "ba_z", "clk", "drift",
)
"""Names of the 17 states, in order (ECEF axes x, y, z; body axes for the biases)."""

PsdLike = Union[float, Tuple[float, float, float]]


def _float_dtype(*arrays):
    dt = np.result_type(*arrays)
    return dt if np.issubdtype(dt, np.floating) else np.dtype(np.float64)


# --------------------------------------------------------------------------------------
# Process noise
# --------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProcessNoise:
    """Continuous-time process-noise power spectral densities (SI), validated.

    The four IMU fields accept a float (the same PSD on every body axis) or a
    3-tuple (one per body axis x, y, z). Every PSD defaults to 0 (a perfect
    IMU and clock), so ``ProcessNoise()`` is valid but models no process noise.

    Attributes
    ----------
    gyro_psd : float or (3,)
        gyro white-noise PSD = ARW^2 [rad^2/s] (ARW in rad/sqrt(s)).
    accel_psd : float or (3,)
        accelerometer white-noise PSD = VRW^2 [(m/s^2)^2/s = m^2/s^3]
        (VRW in m/s/sqrt(s)).
    gyro_bias_psd : float or (3,)
        PSD of the gyro-bias driving noise [(rad/s)^2/s = rad^2/s^3]; for a
        Gauss-Markov bias with standard deviation sigma and correlation time
        tau it is 2 sigma^2 / tau.
    accel_bias_psd : float or (3,)
        PSD of the accelerometer-bias driving noise [(m/s^2)^2/s = m^2/s^5].
    clock_bias_psd : float
        PSD of the white noise on the receiver clock bias (phase) [m^2/s].
    clock_drift_psd : float
        PSD of the white noise on the clock drift (frequency) [m^2/s^3].
    gyro_bias_tau_s, accel_bias_tau_s : float or None
        Gauss-Markov correlation times [s]; ``None``: random walk.

    Raises
    ------
    ValueError
        naming the field, for a negative, non-finite or badly shaped value.
    """

    gyro_psd: PsdLike = 0.0
    accel_psd: PsdLike = 0.0
    gyro_bias_psd: PsdLike = 0.0
    accel_bias_psd: PsdLike = 0.0
    clock_bias_psd: float = 0.0
    clock_drift_psd: float = 0.0
    gyro_bias_tau_s: Optional[float] = None
    accel_bias_tau_s: Optional[float] = None

    def __post_init__(self):
        for name in ("gyro_psd", "accel_psd", "gyro_bias_psd", "accel_bias_psd"):
            object.__setattr__(self, name, _check_psd(name, getattr(self, name), per_axis=True))
        for name in ("clock_bias_psd", "clock_drift_psd"):
            object.__setattr__(self, name, _check_psd(name, getattr(self, name), per_axis=False))
        for name in ("gyro_bias_tau_s", "accel_bias_tau_s"):
            tau = getattr(self, name)
            if tau is None:
                continue
            try:
                tau = float(tau)
            except (TypeError, ValueError):
                raise ValueError(f"{name} must be None or a positive finite number of seconds, got {tau!r}") from None
            if not (math.isfinite(tau) and tau > 0.0):
                raise ValueError(f"{name} must be None or a positive finite number of seconds, got {tau!r}")
            object.__setattr__(self, name, tau)

    @classmethod
    def from_imu_specs(cls, arw, vrw, gyro_bias_instability=0.0, gyro_bias_tau_s=None,
                       accel_bias_instability=0.0, accel_bias_tau_s=None,
                       clock_q_bias=0.0, clock_q_drift=0.0):
        """Process noise from IMU data-sheet figures (already converted to SI).

        Parameters
        ----------
        arw : float or (3,)
            angle random walk [rad/sqrt(s)] (``earth.units.dpsh`` converts deg/sqrt(h)).
        vrw : float or (3,)
            velocity random walk [m/s/sqrt(s)] (``earth.units.ugpsh`` / ``mpsph``).
        gyro_bias_instability : float or (3,)
            standard deviation sigma of the Gauss-Markov gyro bias [rad/s].
        gyro_bias_tau_s : float or None
            its correlation time [s]; ``None`` or ``inf``: a random constant
            (no driving noise; its sigma belongs in the initial covariance).
        accel_bias_instability : float or (3,)
            standard deviation of the Gauss-Markov accelerometer bias [m/s^2].
        accel_bias_tau_s : float or None
            its correlation time [s]; ``None`` or ``inf`` as above.
        clock_q_bias : float
            clock-bias (phase) white-noise PSD [m^2/s].
        clock_q_drift : float
            clock-drift (frequency) white-noise PSD [m^2/s^3].

        Returns
        -------
        ProcessNoise with ``gyro_psd = arw^2``, ``accel_psd = vrw^2`` and the
        Gauss-Markov driving PSDs ``2 sigma^2 / tau`` (a first-order
        Gauss-Markov process ``db/dt = -b/tau + w`` with PSD ``q`` has the
        stationary variance ``q tau / 2``; Groves sec 3.2 / App. J). The
        data-sheet "bias instability" (Allan-deviation floor) is used as
        ``sigma`` as given; convert beforehand if a different fit is wanted.
        """
        def sq(name, x):
            x = _check_psd(name, x, per_axis=True)
            return tuple(v * v for v in x) if isinstance(x, tuple) else x * x

        def gm(name_sigma, sigma, name_tau, tau):
            sig2 = sq(name_sigma, sigma)
            if tau is None or (isinstance(tau, (int, float)) and math.isinf(tau) and tau > 0):
                return 0.0, None
            try:
                tau_f = float(tau)
            except (TypeError, ValueError):
                raise ValueError(f"{name_tau} must be None or a positive number of seconds, got {tau!r}") from None
            if not (math.isfinite(tau_f) and tau_f > 0.0):
                raise ValueError(f"{name_tau} must be None or a positive number of seconds, got {tau!r}")
            q = tuple(2.0 * s / tau_f for s in sig2) if isinstance(sig2, tuple) else 2.0 * sig2 / tau_f
            return q, tau_f

        qbg, tg = gm("gyro_bias_instability", gyro_bias_instability, "gyro_bias_tau_s", gyro_bias_tau_s)
        qba, ta = gm("accel_bias_instability", accel_bias_instability, "accel_bias_tau_s", accel_bias_tau_s)
        return cls(gyro_psd=sq("arw", arw), accel_psd=sq("vrw", vrw), gyro_bias_psd=qbg, accel_bias_psd=qba,
                   clock_bias_psd=clock_q_bias, clock_drift_psd=clock_q_drift,
                   gyro_bias_tau_s=tg, accel_bias_tau_s=ta)

    def diagonal(self) -> np.ndarray:
        """The 17 continuous PSDs on the diagonal of ``Q_c`` (body-frame IMU axes), shape (17,), float64."""
        q = np.zeros(N_STATES)
        q[ATT] = self.gyro_psd
        q[VEL] = self.accel_psd
        q[BG] = self.gyro_bias_psd
        q[BA] = self.accel_bias_psd
        q[CLK] = self.clock_bias_psd
        q[DRIFT] = self.clock_drift_psd
        return q

    @property
    def isotropic(self) -> bool:
        """True when the gyro and accelerometer white-noise PSDs are the same on every axis."""
        return not isinstance(self.gyro_psd, tuple) and not isinstance(self.accel_psd, tuple)


def _check_psd(name, value, per_axis):
    if per_axis and np.ndim(value) == 1:
        try:
            vals = tuple(float(v) for v in value)
        except (TypeError, ValueError):
            raise ValueError(f"{name} must be a non-negative finite float or 3 of them, got {value!r}") from None
        if len(vals) != 3:
            raise ValueError(f"{name} must be a float or a sequence of 3 floats (body x, y, z), got {len(vals)}")
        if not all(math.isfinite(v) and v >= 0.0 for v in vals):
            raise ValueError(f"{name} must be non-negative and finite, got {value!r}")
        return vals[0] if vals[0] == vals[1] == vals[2] else vals
    if np.ndim(value) != 0:
        what = "a float or 3 floats" if per_axis else "a float"
        raise ValueError(f"{name} must be {what}, got {value!r}")
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a non-negative finite float, got {value!r}") from None
    if not (math.isfinite(v) and v >= 0.0):
        raise ValueError(f"{name} must be non-negative and finite, got {value!r}")
    return v


# --------------------------------------------------------------------------------------
# Continuous-time system matrix
# --------------------------------------------------------------------------------------
def gravity_gradient(r_e, form="point-mass"):
    """Gravity gradient ``Gamma = d g_e / d r_e`` used in the velocity<-position block.

    ``form="point-mass"`` (default): the exact gradient of point-mass
    gravitation plus the centrifugal term of :func:`earth.wgs84.gravity_ecef`,

        ``Gamma = GM / |r|^3 (3 u u^T - I) + w_ie^2 diag(1, 1, 0)``,  ``u = r / |r|``;

    its horizontal part ``-GM/|r|^3 ~ -1.5e-6 s^-2`` is the Schuler term. The
    J2 part of the gradient (relative size ~1e-3) is neglected.

    ``form="radial"``: Groves eq 14.49's radial-only form
    ``2 g0 / r_eS * u u^T`` with ``g0 / r_eS`` evaluated as ``GM / |r|^3``
    (the two agree to ~0.3 %).

    Parameters
    ----------
    r_e : (B, 3) ECEF position [m]
    form : {"point-mass", "radial"}

    Returns
    -------
    (B, 3, 3) [1/s^2], dtype of ``r_e``.
    """
    r = np.asarray(r_e)
    if not np.issubdtype(r.dtype, np.floating):
        r = r.astype(np.float64)
    r2 = np.einsum("bi,bi->b", r, r)
    k = GM / (r2 * np.sqrt(r2))  # GM / |r|^3
    if form == "point-mass":
        G = np.einsum("bi,bj->bij", r * (3.0 * k / r2)[:, None], r)
        G[:, 0, 0] -= k - OMEGA_IE * OMEGA_IE
        G[:, 1, 1] -= k - OMEGA_IE * OMEGA_IE
        G[:, 2, 2] -= k
        return G
    if form == "radial":
        return np.einsum("bi,bj->bij", r * (2.0 * k / r2)[:, None], r)
    raise ValueError(f"gravity_gradient form must be 'point-mass' or 'radial', got {form!r}")


def _bias_rate(tau, name):
    if tau is None:
        return 0.0
    tau = float(tau)
    if not (math.isfinite(tau) and tau > 0.0):
        raise ValueError(f"{name} must be None or a positive finite number of seconds, got {tau!r}")
    return -1.0 / tau


def system_matrix(C_eb, f_b, r_e, gyro_bias_tau_s=None, accel_bias_tau_s=None, *, gravity_form="point-mass",
                  out=None):
    """Continuous-time system matrix ``F`` of the 17-state error model (Groves eqs 14.48-14.50).

    For the convention ``x = truth - estimate`` (module docstring), with
    ``C = C_eb``, ``a = C f_b``, ``Omega = [w_ie x]``::

        d(dpsi)/dt  = -Omega dpsi                                - C b_g
        d(dv)/dt    = -[a x] dpsi - 2 Omega dv + Gamma dr        - C b_a
        d(dr)/dt    =                 dv
        d(b_g)/dt   = -b_g / tau_g   (0 for a random walk)
        d(b_a)/dt   = -b_a / tau_a   (0 for a random walk)
        d(clk)/dt   = drift,   d(drift)/dt = 0

    Parameters
    ----------
    C_eb : (B, 3, 3) estimated body-to-ECEF DCM
    f_b : (B, 3) bias-corrected specific force the navigator integrates [m/s^2]
    r_e : (B, 3) estimated ECEF position [m]
    gyro_bias_tau_s, accel_bias_tau_s : float or None
        Gauss-Markov correlation times [s]; ``None``: random walk.
    gravity_form : {"point-mass", "radial"}
        the ``Gamma`` of :func:`gravity_gradient`.
    out : (B, 17, 17) array, optional
        buffer of the result dtype to write into (zeroed first), e.g. the
        previous step's ``F``; avoids a large allocation per call.

    Returns
    -------
    F : (B, 17, 17) [1/s and mixed SI units], the common floating dtype of the inputs.
    """
    dtype = _float_dtype(C_eb, f_b, r_e)
    C = np.asarray(C_eb, dtype=dtype)
    f = np.asarray(f_b, dtype=dtype)
    r = np.asarray(r_e, dtype=dtype)
    kg = _bias_rate(gyro_bias_tau_s, "gyro_bias_tau_s")
    ka = _bias_rate(accel_bias_tau_s, "accel_bias_tau_s")
    B = C.shape[0]
    W = OMEGA_IE
    if out is None:
        F = np.zeros((B, N_STATES, N_STATES), dtype=dtype)
    else:
        F = out
        if not isinstance(F, np.ndarray) or F.shape != (B, N_STATES, N_STATES) or F.dtype != dtype:
            raise ValueError(f"out must be a {dtype} array of shape ({B}, {N_STATES}, {N_STATES})")
        F.fill(0.0)
    # attitude: -Omega dpsi - C b_g
    F[:, 0, 1] = W
    F[:, 1, 0] = -W
    np.negative(C, out=F[:, 0:3, 9:12])
    # velocity: -[a x] dpsi - 2 Omega dv + Gamma dr - C b_a
    a = np.einsum("bij,bj->bi", C, f)
    F[:, 3, 1] = a[:, 2]
    F[:, 3, 2] = -a[:, 1]
    F[:, 4, 0] = -a[:, 2]
    F[:, 4, 2] = a[:, 0]
    F[:, 5, 0] = a[:, 1]
    F[:, 5, 1] = -a[:, 0]
    F[:, 3, 4] = 2.0 * W
    F[:, 4, 3] = -2.0 * W
    F[:, 3:6, 6:9] = gravity_gradient(r, gravity_form)
    np.negative(C, out=F[:, 3:6, 12:15])
    # position: dv
    F[:, 6, 3] = 1.0
    F[:, 7, 4] = 1.0
    F[:, 8, 5] = 1.0
    # biases
    if kg:
        F[:, 9, 9] = F[:, 10, 10] = F[:, 11, 11] = kg
    if ka:
        F[:, 12, 12] = F[:, 13, 13] = F[:, 14, 14] = ka
    # clock
    F[:, 15, 16] = 1.0
    return F


# --------------------------------------------------------------------------------------
# Discretization
# --------------------------------------------------------------------------------------
def _dt_array(dt, dtype, B):
    """``dt`` as a Python float (scalar) or a (B, 1, 1) array; validated positive finite."""
    if np.ndim(dt) == 0:
        h = float(dt)
        if not (math.isfinite(h) and h > 0.0):
            raise ValueError(f"dt must be positive and finite, got {dt!r}")
        return h
    h = np.asarray(dt, dtype=dtype).reshape(-1)
    if h.shape[0] not in (1, B):
        raise ValueError(f"dt must be a scalar or have shape (B,) = ({B},), got {np.shape(dt)}")
    if not np.all(np.isfinite(h) & (h > 0)):
        raise ValueError("dt must be positive and finite")
    return h.reshape(-1, 1, 1)


def _noise_vectors(noise, dtype):
    if not isinstance(noise, ProcessNoise):
        raise TypeError(f"noise must be a ProcessNoise, got {type(noise).__name__}")
    q = noise.diagonal().astype(dtype)
    return q, np.sqrt(q)


def _outputs(out, B, dtype):
    """Output buffers (fully overwritten by the caller): fresh arrays, or the caller's ``(Phi, Qd)``."""
    if out is None:
        return np.empty((B, N_STATES, N_STATES), dtype=dtype), np.empty((B, N_STATES, N_STATES), dtype=dtype)
    try:
        Phi, Qd = out
    except (TypeError, ValueError):
        raise ValueError("out must be a pair (Phi, Qd) of arrays") from None
    for name, a in (("Phi", Phi), ("Qd", Qd)):
        if not isinstance(a, np.ndarray) or a.shape != (B, N_STATES, N_STATES) or a.dtype != dtype:
            raise ValueError(f"out {name} must be a {dtype} array of shape ({B}, {N_STATES}, {N_STATES})")
    if Phi is Qd or np.shares_memory(Phi, Qd):
        raise ValueError("out Phi and Qd must not share memory")
    return Phi, Qd


def discretize(F, C_eb, noise, dt, order=2, *, out=None):
    """Discrete transition matrix and process-noise covariance of the error model (generic ``F``).

    ``Phi = I + F dt + (F dt)^2 / 2`` (``order=2``; ``order=1``: ``I + F dt``),
    a truncated ``expm(F dt)`` (Groves sec 3.2), and the trapezoidal
    process-noise covariance (Groves sec 3.2 / 14.2)::

        Q_d = 0.5 (Phi G Q_c G^T Phi^T + G Q_c G^T) dt.

    ``G`` maps the body-frame gyro and accelerometer white noise into the
    ECEF attitude and velocity errors through ``-C_eb`` (module docstring) and
    the bias and clock driving noises one-to-one into their states, so
    ``G Q_c G^T = blockdiag(C diag(q_g) C^T, C diag(q_a) C^T, 0, diag(q_bg),
    diag(q_ba), q_clk, q_drift)``. With isotropic gyro/accelerometer PSDs
    (one float each) the first two blocks are ``q_g I`` and ``q_a I`` and
    ``C_eb`` is not used (this assumes ``C_eb`` orthonormal, as the INS keeps it).

    Cost: two stacked 17x17 products (``F dt F dt`` and ``M M^T`` with
    ``M = Phi G Qc^{1/2}``) and a few elementwise passes. (A blockwise closed
    form exploiting the sparsity of ``F`` was tried and measured no faster
    with numpy: its ~150 small strided operations cost as much as the two
    stacked products at B = 1024 and more below.)

    Parameters
    ----------
    F : (B, 17, 17) continuous-time system matrix
    C_eb : (B, 3, 3) estimated body-to-ECEF DCM (used only for per-axis PSDs)
    noise : ProcessNoise
    dt : float or (B,) propagation interval [s]
    order : {1, 2} truncation order of the ``Phi`` series
    out : (Phi, Qd), optional
        two (B, 17, 17) arrays of the dtype of ``F`` to write the result into
        (e.g. the previous step's), saving two large allocations per call.

    Returns
    -------
    Phi : (B, 17, 17)
    Qd : (B, 17, 17) symmetric positive semi-definite
        both in the dtype of ``F``.

    Notes
    -----
    The trapezoidal rule is exact to second order in ``dt``; its known
    third-order defect is the position variance driven by accelerometer
    white noise, ``q_a dt^3 / 2`` instead of the exact ``q_a dt^3 / 3``
    (Van Loan), negligible next to the ``q_a dt`` velocity variance at IMU rates.
    """
    F = np.asarray(F)
    if not np.issubdtype(F.dtype, np.floating):
        F = F.astype(np.float64)
    dtype = F.dtype
    if F.ndim != 3 or F.shape[1:] != (N_STATES, N_STATES):
        raise ValueError(f"F must have shape (B, {N_STATES}, {N_STATES}), got {F.shape}")
    if order not in (1, 2):
        raise ValueError(f"order must be 1 or 2, got {order!r}")
    B = F.shape[0]
    h = _dt_array(dt, dtype, B)
    q, sq = _noise_vectors(noise, dtype)

    Phi, Qd = _outputs(out, B, dtype)

    Fdt = np.multiply(F, h)                  # the only large temporary
    if order == 2:
        np.matmul(Fdt, Fdt, out=Phi)
        Phi *= 0.5
        Phi += Fdt
    else:
        np.copyto(Phi, Fdt)
    idx = np.arange(N_STATES)
    Phi[:, idx, idx] += 1.0

    # Phi G Qc G^T Phi^T = M M^T with M = Phi G Qc^{1/2}
    M = np.multiply(Phi, sq, out=Fdt)
    if not noise.isotropic:
        C = np.asarray(C_eb, dtype=dtype)
        blocks = []
        for sl, psd in ((ATT, noise.gyro_psd), (VEL, noise.accel_psd)):
            CD = C * np.sqrt(np.broadcast_to(np.asarray(psd, dtype=dtype), (3,)))   # C diag(sqrt q)
            M[:, :, sl] = Phi[:, :, sl] @ CD
            blocks.append((sl, CD @ np.swapaxes(CD, -1, -2)))
    np.matmul(M, np.swapaxes(M, -1, -2), out=Qd)
    if noise.isotropic:
        Qd[:, idx, idx] += q
    else:
        Qd[:, idx[6:], idx[6:]] += q[6:]
        for sl, blk in blocks:
            Qd[:, sl, sl] += blk
    Qd *= 0.5 * h
    np.add(Qd, np.swapaxes(Qd, -1, -2), out=Fdt)     # exact symmetry
    np.multiply(Fdt, 0.5, out=Qd)
    return Phi, Qd


def transition(C_eb, f_b, r_e, noise, dt, order=2, *, gravity_form="point-mass", out=None):
    """``(Phi, Qd)`` for one propagation step: ``discretize(system_matrix(...))`` in one call.

    Builds ``F`` with the bias correlation times of ``noise`` (so the two
    cannot disagree) and discretizes it (see :func:`system_matrix`,
    :func:`discretize`).

    Parameters
    ----------
    C_eb : (B, 3, 3) estimated body-to-ECEF DCM
    f_b : (B, 3) bias-corrected specific force [m/s^2]
    r_e : (B, 3) estimated ECEF position [m]
    noise : ProcessNoise
    dt : float or (B,) [s]
    order : {1, 2}
    gravity_form : {"point-mass", "radial"}, see :func:`gravity_gradient`
    out : (Phi, Qd), optional, see :func:`discretize`

    Returns
    -------
    Phi, Qd : (B, 17, 17) each, in the common floating dtype of the inputs.
    """
    if not isinstance(noise, ProcessNoise):
        raise TypeError(f"noise must be a ProcessNoise, got {type(noise).__name__}")
    F = system_matrix(C_eb, f_b, r_e, noise.gyro_bias_tau_s, noise.accel_bias_tau_s, gravity_form=gravity_form)
    return discretize(F, C_eb, noise, dt, order, out=out)
