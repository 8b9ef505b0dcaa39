"""Vehicle pseudo-measurements: ZUPT, zero heading rate (ZIHR/ZARU), NHC, odometer, yaw rate, and stacking.

Every function here returns the structure of
:func:`nav_filters.measurements.gnss_innovations` (less its line-of-sight
output)::

    dz : (B, m) innovation z - h(x_nominal);  H : (B, m, 17);  R : (B, m) variances;
    row_mask : (B, m) bool

so that any filter form can fuse them through ``FilterForm.update(dz, H, R,
row_mask)``, alone or stacked with the GNSS rows by
:func:`stack_measurements` into one update. Rows of inactive batch rows are
neutral (``dz = 0``, ``H = 0``, ``R = 1``, ``row_mask = False``), as
DESIGN.md section 2 requires of masked rows.

Conventions
-----------
Body frame FRD (x forward, y right, z down); ECEF ``e`` is the navigation
frame; ``C_eb`` rotates body to ECEF, ``C_be = C_eb^T``. Error state as in
:mod:`nav_filters.error_model` (x = truth minus estimate)::

    C_eb_true = (I + [psi x]) C_eb,   v_true = v_e + dv,   bias_true = bias_est + b.

``H`` is the Jacobian of the predicted measurement with respect to the *true*
state, so ``dz = H x + v`` to first order. Two linearizations are used below.

*Body-frame velocity* ``v_b = C_be v_e`` (NHC, odometer, body-frame ZUPT)::

    C_be_true v_true = C_be (I - [psi x]) (v_e + dv)
                     = C_be v_e + C_be dv + C_be [v_e x] psi + O(|x|^2)

so ``H_VEL = C_be`` and ``H_ATT = C_be [v_e x]`` (rows picked per constraint).

*Earth-referenced body rate at rest* (ZIHR / ZARU). With the navigator's
bias-corrected gyro sample ``w = w_raw - bg_est = omega_ib_true + b_g + n_g``
and a stationary body (``omega_eb = 0``), ``omega_ib_true = C_be_true w_ie``,
``w_ie = (0, 0, OMEGA_IE)``::

    w - C_be w_ie = C_be (I - [psi x]) w_ie - C_be w_ie + b_g + n_g
                  = C_be [w_ie x] psi + b_g + n_g + O(|x|^2)

so ``H_BG = I`` and ``H_ATT = C_be [w_ie x]`` (first order in the attitude
error, small: |H_ATT| = OMEGA_IE = 7.3e-5 rad/s per rad, but kept).

References
----------
Seed paper 000 (sec 1 and sec 2, "If the system is in a zero-velocity state
... velocity and heading constraints are applied"; sec 1: "a vehicle will not
have lateral or vertical velocity", i.e. the NHC) motivates the ZUPT, heading
and NHC rows; it gives no equations for them. Seed paper 003 (eqs 30-31)
fuses the odometer as a dead-reckoned position difference with its own
odometer-position states; this project has no such states, so the odometer
enters as the instantaneous forward-speed measurement instead (the velocity
form of the same sensor). The models follow the zero-update and
motion-constraint measurements of P. D. Groves, *Principles of GNSS,
Inertial, and Multisensor Integrated Navigation Systems*, 2nd ed. (2013),
ch. 15 (zero velocity update, zero angular rate update, land-vehicle motion
constraints) and ch. 16 (odometer integration) - chapter level only, no
equation numbers are claimed - and are re-derived above for this project's
sign convention.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from earth.rotations import skew
from earth.wgs84 import E2 as _E2
from earth.wgs84 import OMEGA_IE

from .error_model import ATT, BG, N_STATES, VEL
from .forms.base import check_dtype, check_measurement_shapes
from .kernels import unit_diagonal

__all__ = [
    "zupt",
    "zero_heading_rate",
    "nhc",
    "odometer",
    "odometer_nhc",
    "yaw_rate",
    "stack_measurements",
    "body_velocity_jacobian",
]

_W_IE = np.array([0.0, 0.0, OMEGA_IE])
_W_IE_SKEW = skew(_W_IE)


# --------------------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------------------
def _array(name, value, tail, B=None):
    """``value`` as float64 of shape (B,) + tail; ValueError naming ``name`` otherwise."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array of shape {('B',) + tuple(tail)}") from None
    want = ("B",) + tuple(tail)
    if a.ndim != 1 + len(tail) or a.shape[1:] != tuple(tail) or (B is not None and a.shape[0] != B):
        shape = tuple(B if (s == "B" and B is not None) else s for s in want)
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def _rows(name, active, B, default_all=False):
    """(B,) bool activity flags; a Python/NumPy bool scalar broadcasts; None -> all (if allowed)."""
    if active is None:
        if default_all:
            return np.ones(B, bool)
        raise ValueError(f"{name} must be a (B,) bool array, got None")
    a = np.asarray(active)
    if a.dtype != bool:
        raise ValueError(f"{name} must be a bool array of shape ({B},), got dtype {a.dtype}")
    if a.ndim == 0:
        return np.full(B, bool(a))
    if a.shape != (B,):
        raise ValueError(f"{name} must have shape ({B},), got {a.shape}")
    return a


def _variance(name, sigma, B):
    """Standard deviation (scalar or (B,)), positive and finite everywhere -> (B,) variances."""
    try:
        s = np.asarray(sigma, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive finite float or a (B,) array of them") from None
    if s.ndim == 0:
        s = np.full(B, float(s))
    elif s.shape != (B,):
        raise ValueError(f"{name} must be a scalar or have shape ({B},), got {s.shape}")
    if not np.all(np.isfinite(s) & (s > 0.0)):
        raise ValueError(f"{name} must be positive and finite, got {sigma!r}")
    return s * s


def _finite_on(name, a, rows):
    """ValueError naming ``name`` if ``a`` has a non-finite value on an active batch row."""
    bad = ~np.isfinite(a.reshape(a.shape[0], -1)).all(-1) & rows
    if bad.any():
        raise ValueError(f"{name} has a non-finite value on active batch row {int(np.argmax(bad))}")


def _finish(dz, H, R, rows, dtype):
    """Neutralize the rows of inactive batch rows (``rows`` (B,) bool) and cast: (dz, H, R, row_mask)."""
    return _neutralize(dz, H, R, np.repeat(rows[:, None], dz.shape[1], axis=1), dtype)


def _neutralize(dz, H, R, row_mask, dtype):
    """Masked measurement rows (``row_mask`` (B, m) False) -> ``dz = 0``, ``H = 0``, variance 1; cast to dtype.

    ``R`` holds (B, m) variances. Returns (dz, H, R, row_mask).
    """
    with np.errstate(invalid="ignore"):
        dz = np.where(row_mask, dz, 0.0).astype(dtype)
        H = np.where(row_mask[..., None], H, 0.0).astype(dtype)
        R = np.where(row_mask, R, 1.0).astype(dtype)
    return dz, H, R, row_mask


def body_velocity_jacobian(v_e, C_eb):
    """Body-frame velocity and its Jacobians with respect to the true velocity and attitude.

    ``v_b = C_be v_e``; under ``C_eb_true = (I + [psi x]) C_eb``,
    ``v_true = v_e + dv``: ``v_b_true = v_b + C_be dv + C_be [v_e x] psi + O(|x|^2)``
    (module docstring; Groves 2013 ch. 15 land-vehicle constraints, re-derived
    for this sign convention).

    Parameters
    ----------
    v_e : (B, 3) estimated ECEF velocity [m/s]
    C_eb : (B, 3, 3) estimated body (FRD) -> ECEF DCM

    Returns
    -------
    v_b : (B, 3) [m/s]; H_vel : (B, 3, 3) = C_be [-]; H_att : (B, 3, 3) = C_be [v_e x] [m/s/rad]
        float64.
    """
    v = np.asarray(v_e, dtype=np.float64)
    C_be = np.swapaxes(np.asarray(C_eb, dtype=np.float64), -1, -2)
    v_b = (C_be @ v[..., None])[..., 0]
    return v_b, C_be, C_be @ skew(v)


# --------------------------------------------------------------------------------------
# zero-velocity update
# --------------------------------------------------------------------------------------

def _body_velocity_rows(v, C, axes):
    """Body-frame velocity components ``axes`` of the estimate and their H rows (VEL and ATT columns).

    Returns ``v_b[:, axes]`` (B, k) and H (B, k, 17) from :func:`body_velocity_jacobian`; rows whose
    inputs are not finite (inactive rows may hold NaN) give NaN here and are neutralized by :func:`_finish`.
    """
    with np.errstate(invalid="ignore"):
        v_b, H_vel, H_att = body_velocity_jacobian(v, C)
    H = np.zeros((v.shape[0], len(axes), N_STATES))
    H[:, :, VEL] = H_vel[:, axes]
    H[:, :, ATT] = H_att[:, axes]
    return v_b[:, axes], H

def zupt(v_e, C_eb, sigma_mps, active, *, frame="ecef", dtype=np.float64):
    """Zero-velocity update (ZUPT) rows for a stationary vehicle.

    Pseudo-measurement "the true velocity is zero" (seed paper 000 sec 2:
    velocity constraint when the zero-velocity detector fires; Groves 2013
    ch. 15, zero velocity update)::

        frame="ecef" (default):  dz = 0 - v_e,          H[VEL] = I            (exact, linear)
        frame="body":            dz = 0 - C_be v_e,     H[VEL] = C_be, H[ATT] = C_be [v_e x]

    The two carry the same information for the isotropic ``sigma`` used here
    (``C_be`` is a rotation); ``"ecef"`` is the default because it is exactly
    linear and does not couple a velocity residual into attitude. The body
    form is offered for symmetry with :func:`nhc` (its attitude term is
    ``|v_e| |psi|``, second order near rest).

    Parameters
    ----------
    v_e : (B, 3) estimated ECEF velocity [m/s]
    C_eb : (B, 3, 3) estimated body -> ECEF DCM (only used, and then required, for ``frame="body"``;
        may be None for ``"ecef"``)
    sigma_mps : float or (B,) standard deviation of the zero-velocity pseudo-measurement
        per axis [m/s] (residual vehicle motion: engine idle, suspension), > 0
    active : (B,) bool, True where the vehicle is declared stationary (detector output)
    frame : {"ecef", "body"} axes the three rows are resolved in
    dtype : float32 or float64, dtype of dz, H, R

    Returns
    -------
    dz : (B, 3) [m/s]; H : (B, 3, 17); R : (B, 3) [m^2/s^2]; row_mask : (B, 3) bool

    Raises
    ------
    ValueError
        naming the argument: bad shape, non-positive or non-finite sigma,
        non-finite state on an active row, unknown ``frame``, bad ``dtype``.
    """
    dtype = check_dtype(dtype)
    if frame not in ("ecef", "body"):
        raise ValueError(f"frame must be 'ecef' or 'body', got {frame!r}")
    v = _array("v_e", v_e, (3,))
    B = v.shape[0]
    rows = _rows("active", active, B)
    var = _variance("sigma_mps", sigma_mps, B)
    _finite_on("v_e", v, rows)
    if frame == "ecef":
        dz = -v
        H = np.zeros((B, 3, N_STATES))
        H[:, :, VEL] = np.eye(3)
    else:
        C = _array("C_eb", C_eb, (3, 3), B)
        _finite_on("C_eb", C, rows)
        v_b, H = _body_velocity_rows(v, C, [0, 1, 2])
        dz = -v_b
    return _finish(dz, H, np.repeat(var[:, None], 3, 1), rows, dtype)


# --------------------------------------------------------------------------------------
# zero heading rate / zero angular rate
# --------------------------------------------------------------------------------------
def _local_down(r_e):
    """Local down unit vector at ``r_e`` (B, 3), ECEF-resolved: minus the WGS84 ellipsoid normal.

    ``-(x, y, z / (1 - e^2)) / |.|``, the normal of the ellipsoid scaled through
    ``r_e``: exactly the geodetic down (third column of ``C_en``) on the
    ellipsoid, within ``e^2 h / (2 a) < 6e-9 rad per metre of height`` above it
    (5e-7 rad at 1 km; ``H`` needs the vertical only to first order). Closed
    form, about 20x cheaper than :func:`earth.wgs84.ecef_to_geodetic`.
    """
    n = r_e * np.array([1.0, 1.0, 1.0 / (1.0 - _E2)])
    return n / -np.linalg.norm(n, axis=-1, keepdims=True)


def zero_heading_rate(C_eb, w_b_corrected, r_e, sigma_rps, active, *, axes="heading", dtype=np.float64):
    """Zero integrated heading rate (ZIHR) row, or zero angular rate update (ZARU) rows, at rest.

    A stationary body does not rotate with respect to the Earth, so its true
    inertial rate is the Earth rate ``C_be_true w_ie``; the navigator's
    bias-corrected gyro sample ``w = w_raw - bg_est`` then differs from the
    predicted ``C_be w_ie`` by the gyro-bias residual ``b_g`` (state BG),
    noise, and a first-order attitude term (module docstring)::

        axes="all" (ZARU):     dz = w - C_be w_ie                        (3 rows, body axes)
                               H[BG] = I,   H[ATT] = C_be [w_ie x]
        axes="heading" (ZIHR): dz = d_e^T (C_eb w - w_ie)               (1 row, local vertical)
                               H[BG] = (C_be d_e)^T,   H[ATT] = (d_e x w_ie)^T

    with ``d_e`` the geodetic down unit vector at ``r_e`` (its error enters
    only at second order, so ``H[POS] = 0``). This is the heading constraint
    of seed paper 000 sec 2 ("velocity and heading constraints are applied")
    and the zero angular rate update of Groves 2013 ch. 15.

    Why the heading axis by default: (i) at rest a ZUPT already observes the
    horizontal gyro biases (they tilt the platform, gravity leaks into the
    velocity the ZUPT watches), while the heading error couples into velocity
    only through horizontal specific force, which is zero at rest, so the
    vertical gyro bias and heading drift are what a ZUPT leaves unobserved;
    (ii) a stopped road vehicle still rocks in roll and pitch (engine idle,
    suspension, occupants) but does not yaw, so the heading-axis constraint
    holds to a tighter sigma than the other two. Use ``axes="all"`` for a
    truly static platform.

    Parameters
    ----------
    C_eb : (B, 3, 3) estimated body -> ECEF DCM
    w_b_corrected : (B, 3) bias-corrected angular rate omega_ib^b [rad/s], e.g. the mean
        of the navigator's corrected samples over the stationary interval
    r_e : (B, 3) estimated ECEF position [m] (for the local vertical; may be None for ``axes="all"``)
    sigma_rps : float or (B,) standard deviation of the row(s) [rad/s], > 0: the gyro
        white noise over the averaging interval (ARW / sqrt(T)) plus residual rocking
    active : (B,) bool, True where the vehicle is declared stationary
    axes : {"heading", "all"}
    dtype : float32 or float64

    Returns
    -------
    dz : (B, m) [rad/s]; H : (B, m, 17); R : (B, m) [rad^2/s^2]; row_mask : (B, m) bool;
    m = 1 for "heading", 3 for "all".

    Raises
    ------
    ValueError
        naming the argument (shapes, sigma, non-finite input on an active row, ``axes``, ``dtype``).
    """
    dtype = check_dtype(dtype)
    if axes not in ("heading", "all"):
        raise ValueError(f"axes must be 'heading' or 'all', got {axes!r}")
    C = _array("C_eb", C_eb, (3, 3))
    B = C.shape[0]
    w = _array("w_b_corrected", w_b_corrected, (3,), B)
    rows = _rows("active", active, B)
    var = _variance("sigma_rps", sigma_rps, B)
    _finite_on("C_eb", C, rows)
    _finite_on("w_b_corrected", w, rows)
    C_be = np.swapaxes(C, -1, -2)
    with np.errstate(invalid="ignore"):
        if axes == "all":
            dz = w - C_be @ _W_IE
            H = np.zeros((B, 3, N_STATES))
            H[:, :, BG] = np.eye(3)
            H[:, :, ATT] = C_be @ _W_IE_SKEW
        else:
            r = _array("r_e", r_e, (3,), B)
            _finite_on("r_e", r, rows)
            d_e = np.where(rows[:, None], _local_down(np.where(rows[:, None], r, 6.4e6)), 0.0)
            w_e = (C @ w[..., None])[..., 0] - _W_IE            # Earth-referenced rate, ECEF
            dz = np.einsum("bi,bi->b", d_e, w_e)[:, None]
            H = np.zeros((B, 1, N_STATES))
            H[:, 0, BG] = (C_be @ d_e[..., None])[..., 0]
            H[:, 0, 0] = OMEGA_IE * d_e[:, 1]            # d_e x w_ie, w_ie = (0, 0, OMEGA_IE)
            H[:, 0, 1] = -OMEGA_IE * d_e[:, 0]
    m = dz.shape[1]
    return _finish(dz, H, np.repeat(var[:, None], m, 1), rows, dtype)


# --------------------------------------------------------------------------------------
# non-holonomic constraint and odometer
# --------------------------------------------------------------------------------------
def nhc(v_e, C_eb, sigma_lat_mps, sigma_vert_mps, active=None, *, dtype=np.float64):
    """Non-holonomic constraint (NHC): a land vehicle has no lateral or vertical body velocity.

    Pseudo-measurement ``v_b[1] = v_b[2] = 0`` (seed paper 000 sec 1; Groves
    2013 ch. 15, land-vehicle motion constraints), linearized under the
    project convention (``C_eb_true = (I + [psi x]) C_eb``, ``v_true = v_e +
    dv``, module docstring)::

        dz = 0 - (C_be v_e)[1:3]
        H[VEL] = C_be[1:3, :],   H[ATT] = (C_be [v_e x])[1:3, :]

    A yaw error ``dyaw`` (rotation of the truth from the estimate about the
    local down axis) at forward speed ``s`` gives ``dz_lateral = -s dyaw``.
    The IMU is taken at the constraint point (no lever arm, no mounting
    misalignment); a non-zero lateral/vertical velocity there (skidding,
    bumps) belongs in the sigmas.

    Parameters
    ----------
    v_e : (B, 3) estimated ECEF velocity [m/s]
    C_eb : (B, 3, 3) estimated body (FRD) -> ECEF DCM
    sigma_lat_mps, sigma_vert_mps : float or (B,) standard deviations of the lateral (body y)
        and vertical (body z) rows [m/s], > 0
    active : (B,) bool or None (default: all rows active)
    dtype : float32 or float64

    Returns
    -------
    dz : (B, 2) [m/s] rows (lateral, vertical); H : (B, 2, 17); R : (B, 2) [m^2/s^2];
    row_mask : (B, 2) bool

    Raises
    ------
    ValueError
        naming the argument.
    """
    dtype = check_dtype(dtype)
    v = _array("v_e", v_e, (3,))
    B = v.shape[0]
    C = _array("C_eb", C_eb, (3, 3), B)
    rows = _rows("active", active, B, default_all=True)
    var = np.stack([_variance("sigma_lat_mps", sigma_lat_mps, B),
                    _variance("sigma_vert_mps", sigma_vert_mps, B)], 1)
    _finite_on("v_e", v, rows)
    _finite_on("C_eb", C, rows)
    v_b, H = _body_velocity_rows(v, C, [1, 2])
    return _finish(-v_b, H, var, rows, dtype)


def odometer(v_e, C_eb, speed_mps, sigma_mps, mask, *, dtype=np.float64):
    """Odometer forward-speed row: ``z = speed``, ``h = (C_be v_e)[0]``.

    The velocity form of the odometer measurement (seed paper 003 fuses the
    same sensor as a dead-reckoned position, eqs 30-31, with odometer-position
    states this 17-state model does not have; Groves 2013 ch. 16, odometer
    integration), linearized under the project convention::

        dz = speed - (C_be v_e)[0]
        H[VEL] = C_be[0, :],   H[ATT] = (C_be [v_e x])[0, :]

    Not modelled: the odometer scale-factor error (no state; calibrate it
    beforehand or cover it in ``sigma_mps``, e.g. ``sqrt(s0^2 + (k |speed|)^2)``
    per row), the lever arm between the IMU and the wheel (the rotation term
    ``omega x l``), wheel slip. ``speed`` is *signed* (negative when
    reversing); an unsigned sensor must be signed by the caller.

    Parameters
    ----------
    v_e : (B, 3) estimated ECEF velocity [m/s]
    C_eb : (B, 3, 3) estimated body (FRD) -> ECEF DCM
    speed_mps : (B,) measured forward speed [m/s]; may be NaN where ``mask`` is False
    sigma_mps : float or (B,) its standard deviation [m/s], > 0
    mask : (B,) bool, True where a speed reading is available
    dtype : float32 or float64

    Returns
    -------
    dz : (B, 1) [m/s]; H : (B, 1, 17); R : (B, 1) [m^2/s^2]; row_mask : (B, 1) bool

    Raises
    ------
    ValueError
        naming the argument.
    """
    dtype = check_dtype(dtype)
    v = _array("v_e", v_e, (3,))
    B = v.shape[0]
    C = _array("C_eb", C_eb, (3, 3), B)
    s = _array("speed_mps", speed_mps, (), B)
    rows = _rows("mask", mask, B)
    var = _variance("sigma_mps", sigma_mps, B)
    for name, a in (("v_e", v), ("C_eb", C), ("speed_mps", s)):
        _finite_on(name, a, rows)
    v_b, H = _body_velocity_rows(v, C, [0])
    return _finish(s[:, None] - v_b, H, var[:, None], rows, dtype)


def odometer_nhc(v_e, C_eb, speed_mps, sigma_mps, sigma_lat_mps, sigma_vert_mps, *, dtype=np.float64):
    """The odometer row then the two NHC rows of one epoch, as one block.

    ``stack_measurements(odometer(v_e, C_eb, where(have, speed, 0), sigma_mps, have), nhc(v_e, C_eb,
    sigma_lat_mps, sigma_vert_mps), dtype)`` with ``have = isfinite(speed_mps)`` (a NaN speed: no reading on
    that row), bit for bit: :func:`body_velocity_jacobian` evaluated once for both (the same products) and one
    compiled pass (:func:`_odometer_nhc_rows`) that places, neutralizes and casts the rows, instead of the
    some fifty small array operations of the composition, most of a single env's step on ``seed003-sim``
    (agreement test in ``tests/nav_filters/test_constraints.py``). Where the inputs are not what that pass
    takes (a non-finite state, a sigma that is not a positive finite number, other shapes) the composition
    runs, and raises its error naming the argument.

    Parameters
    ----------
    v_e : (B, 3) estimated ECEF velocity [m/s]; C_eb : (B, 3, 3) estimated body (FRD) -> ECEF DCM;
    speed_mps : (B,) measured forward speed [m/s], NaN where there is no reading;
    sigma_mps, sigma_lat_mps, sigma_vert_mps : standard deviations [m/s] of the odometer and the lateral and
    vertical NHC rows (floats or (B,) arrays, > 0); dtype : float32 or float64.

    Returns
    -------
    dz : (B, 3) [m/s]; H : (B, 3, 17); R : (B, 3) [m^2/s^2]; row_mask : (B, 3) bool (the odometer row masked
    where there is no reading).
    """
    sig = (sigma_mps, sigma_lat_mps, sigma_vert_mps)
    v = np.asarray(v_e)
    C = np.asarray(C_eb)
    speed = np.asarray(speed_mps)
    fast = (all(type(x) in (float, int, np.float64) and math.isfinite(x) and x > 0 for x in sig)
            and v.dtype == C.dtype == speed.dtype == np.float64 and v.ndim == 2 and v.shape[1] == 3
            and C.shape == (v.shape[0], 3, 3) and speed.shape == (v.shape[0],))
    if fast:
        dt = check_dtype(dtype)
        if _states_finite(v, C):
            B = v.shape[0]
            dz, R, mask = np.empty((B, 3), dt), np.empty((B, 3), dt), np.empty((B, 3), bool)
            H = np.empty((B, 3, N_STATES), dt)
            v_b, _, H_att = body_velocity_jacobian(v, C)
            _odometer_nhc_rows(speed, v_b, np.ascontiguousarray(C), H_att,
                               *(float(x) * float(x) for x in sig), VEL.start, ATT.start, dz, H, R, mask)
            return dz, H, R, mask
    have = np.isfinite(np.asarray(speed_mps, np.float64))
    return stack_measurements(
        odometer(v_e, C_eb, np.where(have, speed_mps, 0.0), sigma_mps, have, dtype=dtype),
        nhc(v_e, C_eb, sigma_lat_mps, sigma_vert_mps, dtype=dtype))


@nb.njit(cache=True)
def _states_finite(v, C):
    """Whether every entry of ``v`` (B, 3) and ``C`` (B, 3, 3) is finite."""
    for b in range(v.shape[0]):
        for i in range(3):
            if not np.isfinite(v[b, i]):
                return False
            for j in range(3):
                if not np.isfinite(C[b, i, j]):
                    return False
    return True


@nb.njit(cache=True)
def _odometer_nhc_rows(speed, v_b, C, H_att, var_odo, var_lat, var_vert, vel0, att0, dz, H, R, mask):
    """The rows of :func:`odometer_nhc` from ``v_b = C_be v_e`` (B, 3) and ``H_att = C_be [v_e x]`` (B, 3, 3) of
    :func:`body_velocity_jacobian` and ``C`` = ``C_eb`` (B, 3, 3) (``H_vel = C_be = C^T``): row 0 the odometer
    (``speed - v_b[0]``, neutral where ``speed`` is NaN), rows 1, 2 the NHC (``-v_b[1]``, ``-v_b[2]``), each
    with its variance; the outputs in their own dtype (one rounding from float64, as ``astype``)."""
    B = speed.shape[0]
    n = H.shape[2]
    for b in range(B):
        for k in range(3):
            for j in range(n):
                H[b, k, j] = 0.0
        have = np.isfinite(speed[b])
        for k in range(3):
            if k == 0 and not have:
                dz[b, 0] = 0.0
                R[b, 0] = 1.0
                mask[b, 0] = False
                continue
            dz[b, k] = speed[b] - v_b[b, 0] if k == 0 else -v_b[b, k]
            for j in range(3):
                H[b, k, vel0 + j] = C[b, j, k]
                H[b, k, att0 + j] = H_att[b, k, j]
            R[b, k] = var_odo if k == 0 else (var_lat if k == 1 else var_vert)
            mask[b, k] = True


# --------------------------------------------------------------------------------------
# vehicle yaw rate
# --------------------------------------------------------------------------------------
def yaw_rate(C_eb, w_b_corrected, yaw_rate_rps, sigma_rps, mask, *, dtype=np.float64):
    """Yaw-rate row of a vehicle rate sensor (wheel odometry / ESP yaw-rate sensor), body FRD.

    The sensor reads the Earth-referenced rate of the body about its z axis (down): ``z = (omega_eb^b)[2]``
    (positive: a right turn), as a vehicle sensor zeroed at standstill does. The navigator predicts it from
    its bias-corrected gyro ``w = w_raw - bg_est = omega_ib_true + b_g + n_g`` (over the same interval as the
    reading) and its attitude; linearized under the project convention (``C_be_true = C_be (I - [psi x])``,
    ``bias_true = bias_est + b_g``; module docstring)::

        dz = z - (w - C_be w_ie)[2]
           = -b_g[2] - (C_be [w_ie x] psi)[2] - n_g[2] + n_z
        H[BG] = -e_z^T,   H[ATT] = -(C_be [w_ie x])[2, :]

    (the rate counterpart of :func:`zero_heading_rate`, which constrains the same quantity to zero at rest;
    Groves 2013 ch. 15/16 land-vehicle aiding, chapter level, re-derived here). It observes the z gyro bias
    while moving; the sensor's own scale error and bias are not modelled (cover them in ``sigma_rps``).

    Parameters
    ----------
    C_eb : (B, 3, 3) estimated body (FRD) -> ECEF DCM
    w_b_corrected : (B, 3) bias-corrected angular rate omega_ib^b [rad/s] (e.g. the mean of the navigator's
        corrected samples over the reading's interval)
    yaw_rate_rps : (B,) measured yaw rate about body z (down) [rad/s]; may be NaN where ``mask`` is False
    sigma_rps : float or (B,) standard deviation of the row [rad/s], > 0: the sensor's noise and the gyro
        white noise over the interval
    mask : (B,) bool, True where a reading is available
    dtype : float32 or float64

    Returns
    -------
    dz : (B, 1) [rad/s]; H : (B, 1, 17); R : (B, 1) [rad^2/s^2]; row_mask : (B, 1) bool

    Raises
    ------
    ValueError
        naming the argument.
    """
    dtype = check_dtype(dtype)
    C = _array("C_eb", C_eb, (3, 3))
    B = C.shape[0]
    w = _array("w_b_corrected", w_b_corrected, (3,), B)
    z = _array("yaw_rate_rps", yaw_rate_rps, (), B)
    rows = _rows("mask", mask, B)
    var = _variance("sigma_rps", sigma_rps, B)
    for name, a in (("C_eb", C), ("w_b_corrected", w), ("yaw_rate_rps", z)):
        _finite_on(name, a, rows)
    with np.errstate(invalid="ignore"):
        C_be = np.swapaxes(C, -1, -2)
        dz = z - (w - C_be @ _W_IE)[:, 2]
        H = np.zeros((B, 1, N_STATES))
        H[:, 0, BG.start + 2] = -1.0
        H[:, 0, ATT] = -(C_be @ _W_IE_SKEW)[:, 2]
    return _finish(dz[:, None], H, var[:, None], rows, dtype)


# --------------------------------------------------------------------------------------
# stacking
# --------------------------------------------------------------------------------------
def stack_measurements(*blocks, dtype=None):
    """Stack measurement blocks into one ``(dz, H, R, row_mask)`` for a single update.

    Each block is a tuple ``(dz (B, m_i), H (B, m_i, n), R, row_mask (B, m_i))``
    with ``R`` either (B, m_i) variances or a (B, m_i, m_i) covariance: the
    output of :func:`zupt`, :func:`zero_heading_rate`, :func:`nhc`,
    :func:`odometer`, or ``gnss_innovations(...)[:4]``. ``None`` blocks are
    skipped (optional constraints). Rows are concatenated in the order given;
    blocks are taken as mutually uncorrelated, so with all-diagonal inputs
    ``R`` stays (B, m) variances, otherwise it becomes the block-diagonal
    (B, m, m) covariance. Masked rows are (re-)neutralized: ``dz = 0``,
    ``H = 0``, unit variance, no cross-covariance. For a Kalman filter one
    update with the stack equals sequential updates with the blocks (tested).

    Parameters
    ----------
    *blocks : tuples as above (or None)
    dtype : float32, float64, or None (the common floating dtype of the blocks' dz)

    Returns
    -------
    dz : (B, m); H : (B, m, n); R : (B, m) or (B, m, m); row_mask : (B, m) bool, m = sum m_i.

    Raises
    ------
    ValueError
        no block, a block that is not a 4-tuple, inconsistent B or n, bad shapes.
    """
    blocks = [b for b in blocks if b is not None]
    if not blocks:
        raise ValueError("blocks: at least one measurement block is required")
    parts = []
    for i, blk in enumerate(blocks):
        if not isinstance(blk, (tuple, list)) or len(blk) != 4:
            raise ValueError(f"blocks[{i}] must be a tuple (dz, H, R, row_mask); "
                             "pass gnss_innovations(...)[:4] for a GNSS epoch")
        dz, H, R, mk = (np.asarray(a) for a in blk)
        B, m = check_measurement_shapes(dz, H, R, owner=f"blocks[{i}] ")
        if mk.shape != (B, m) or mk.dtype != bool:
            raise ValueError(f"blocks[{i}] row_mask must be a bool array of shape ({B}, {m})")
        parts.append((dz, H, R, mk))
    B0, n0 = parts[0][1].shape[0], parts[0][1].shape[2]
    for i, (dz, H, R, mk) in enumerate(parts):
        if H.shape[0] != B0 or H.shape[2] != n0:
            raise ValueError(f"blocks[{i}] has B={H.shape[0]}, n={H.shape[2]}; blocks[0] has B={B0}, n={n0}")
    if dtype is None:
        dt = np.result_type(*(p[0] for p in parts))
        dtype = dt if dt.kind == "f" else np.float64
    dtype = check_dtype(dtype)

    mask = np.concatenate([p[3] for p in parts], 1)
    dz_all = np.concatenate([p[0] for p in parts], 1)
    H_all = np.concatenate([p[1] for p in parts], 1)
    if all(p[2].ndim == 2 for p in parts):
        return _neutralize(dz_all, H_all, np.concatenate([p[2] for p in parts], 1), mask, dtype)
    # a full covariance somewhere: block-diagonal R, masked rows/columns -> identity
    dz, H, _, _ = _neutralize(dz_all, H_all, np.ones(mask.shape), mask, dtype)
    m = mask.shape[1]
    R = np.zeros((B0, m, m))
    j = 0
    for dzi, _, Ri, _ in parts:
        mi = dzi.shape[1]
        R[:, j:j + mi, j:j + mi] = Ri if Ri.ndim == 3 else Ri[:, :, None] * np.eye(mi)
        j += mi
    with np.errstate(invalid="ignore"):
        R = np.where(mask[:, :, None] & mask[:, None, :], R, 0.0).astype(dtype)
    return dz, H, unit_diagonal(R, mask), mask
