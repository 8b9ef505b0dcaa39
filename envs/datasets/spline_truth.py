"""A truth trajectory with a consistent ideal IMU from recorded reference positions.

Recorded data sets without an IMU (smartLoc) or with one that does not match
the GNSS receiver give a reference trajectory only: positions at discrete
times. This module turns them into an :class:`envs.sim.trajectory.Truth` (the
structure the simulated world uses), so that an IMU of a chosen grade can be
*synthesized* (:func:`envs.sim.imu.simulate_imu`) while the GNSS errors stay
the recorded ones.

Position
    A cubic smoothing spline through the ECEF reference positions (Reinsch
    1967 / Woltring 1986; ``scipy.interpolate.make_smoothing_spline``),
    minimizing ``sum_i w_i |r_i - s(t_i)|^2 + lam int |s''(t)|^2 dt`` on the
    three ECEF axes at once (an isotropic penalty). Its velocity is C1 and its
    acceleration continuous and piecewise linear. The reference may hold
    isolated glitches (smartLoc's SPAN truth has about ten points displaced by
    0.3-0.8 m against their neighbours: a 30-40 m/s^2 spike for an
    interpolating spline); they are down-weighted iteratively: a point whose
    residual exceeds ``outlier_m`` gets weight ``1e-6`` and the spline is
    refitted (``passes`` times). The spline *is* the truth from then on; its
    distance to the recorded inliers is reported (:attr:`SplineFit.residual_m`,
    2 cm rms on smartLoc Potsdamer Platz, 8 points down-weighted).

Attitude (assumed: the recording has none)
    Body FRD with x along the velocity and roll 0 about it (a car without
    suspension roll; the roll of a real car in a turn, 1-3 deg, is ignored).
    In the local NED frame at the current position: heading ``psi =
    atan2(v_E, v_N)``, pitch ``theta = atan2(-v_D, |v_NE|)`` (the flight-path
    angle), ``C_nb = dcm_from_euler(0, theta, psi)``, ``C_eb = C_en C_nb``.
    Below ``min_speed_mps`` the velocity direction is meaningless (a stopped
    car, spline wiggles): heading and pitch are interpolated linearly in time
    across such gaps between the last and next moving samples (held at the
    ends), so the attitude stays continuous; the body x axis is then not
    exactly along the (tiny) velocity.

Ideal IMU (Groves 2013, 2nd ed., sec 5.3, the ECEF mechanization the
navigator integrates), the convention of :mod:`envs.sim.trajectory`::

    f_b    = C_be (a_e + 2 Omega_ie v_e - g_e(r_e))            g_e = earth.gravity_ecef
    w_ib^b : exp([w_b dt x]) = C_eb(t_{k-1})^T exp([omega_ie x] dt) C_eb(t_k)

Sample ``k >= 1`` is the mean over ``(t_{k-1}, t_k]``: ``f_b`` by Simpson's
rule on the end and mid-interval values (the integrand is smooth inside an
interval: the spline acceleration is linear, the attitude turns by at most a
few mrad per 10 ms); ``w_b`` as the rotation vector of the interval's exact
attitude change with the Earth rotation removed, so the attitude update of the
mechanization reproduces the truth attitude exactly (no coning residual
beyond the Earth-rate term). Sample 0 is the instantaneous ``f_b`` and the
rate of sample 1 (the navigator never uses sample 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline, make_smoothing_spline

from earth import C_en, dcm_from_euler, ecef_to_geodetic, gravity_ecef, log_so3
from earth.rotations import rot_z
from earth.wgs84 import OMEGA_IE, OMEGA_IE_E

from ..sim.trajectory import Truth

__all__ = ["SplineFit", "fit_positions", "truth_from_fit"]


@dataclass(frozen=True, eq=False)
class SplineFit:
    """A smoothing spline through recorded ECEF positions.

    Attributes
    ----------
    spline : vector-valued BSpline of ``r_e - r_ref`` over time [m].
    r_ref : (3,) ECEF offset [m] (the first recorded position; conditioning).
    t0, t1 : first and last recorded time [s].
    t : (G,) recorded times; inlier : (G,) bool, points kept at full weight.
    residual_m : (G,) distance spline - recorded position [m].
    lam : smoothing parameter of ``make_smoothing_spline`` (time in s, positions in m).
    """

    spline: BSpline
    r_ref: np.ndarray
    t0: float
    t1: float
    t: np.ndarray
    inlier: np.ndarray
    residual_m: np.ndarray
    lam: float

    def position(self, t) -> np.ndarray:
        """(n, 3) ECEF position [m] at times ``t`` (n,) [s]."""
        return self.spline(np.asarray(t, np.float64)) + self.r_ref

    def velocity(self, t) -> np.ndarray:
        """(n, 3) ECEF velocity [m/s]."""
        return self.spline.derivative(1)(np.asarray(t, np.float64))

    def acceleration(self, t) -> np.ndarray:
        """(n, 3) ECEF acceleration relative to the Earth, ``d2 r_e / dt2`` [m/s^2]."""
        return self.spline.derivative(2)(np.asarray(t, np.float64))

    @property
    def inlier_rms_m(self) -> float:
        """RMS distance of the spline to the inlier reference positions [m]."""
        return float(np.sqrt(np.mean(self.residual_m[self.inlier] ** 2)))


def fit_positions(t, r_e, lam: float = 0.01, outlier_m: float = 0.25, passes: int = 3) -> SplineFit:
    """Fit the smoothing spline of the module docstring through reference positions.

    Parameters
    ----------
    t : (G,) strictly increasing times [s], G >= 5.
    r_e : (G, 3) ECEF positions [m].
    lam : smoothing parameter (time in s, positions in m), > 0. The default
        0.01 keeps smartLoc's SPAN truth within 2 cm rms (inliers) and its
        acceleration below ~3 m/s^2, jerk below ~7 m/s^3.
    outlier_m : residual [m] above which a point is down-weighted, > 0.
    passes : refits after down-weighting, >= 1.

    Returns
    -------
    SplineFit
    """
    t = np.asarray(t, np.float64)
    r_e = np.asarray(r_e, np.float64)
    if t.ndim != 1 or t.size < 5:
        raise ValueError(f"t must be 1-D with at least 5 times, got shape {t.shape}")
    if r_e.shape != (t.size, 3):
        raise ValueError(f"r_e must have shape ({t.size}, 3), got {r_e.shape}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(r_e))):
        raise ValueError("t and r_e must be finite")
    if not np.all(np.diff(t) > 0):
        raise ValueError("t must be strictly increasing")
    for name, v in (("lam", lam), ("outlier_m", outlier_m)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
            raise ValueError(f"{name} must be a finite number > 0, got {v!r}")
    if not isinstance(passes, int) or passes < 1:
        raise ValueError(f"passes must be an int >= 1, got {passes!r}")
    r_ref = r_e[0].copy()
    y = r_e - r_ref
    w = np.ones(t.size)
    for _ in range(passes):
        spl = make_smoothing_spline(t, y, w=w, lam=lam)
        res = np.linalg.norm(spl(t) - y, axis=-1)
        w_new = np.where(res > outlier_m, 1e-6, 1.0)
        if np.array_equal(w_new, w):
            break
        w = w_new
    return SplineFit(spline=spl, r_ref=r_ref, t0=float(t[0]), t1=float(t[-1]), t=t, inlier=res <= outlier_m,
                     residual_m=res, lam=float(lam))


def _fill_gaps(x: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Linear interpolation of ``x`` across samples where ``ok`` is False (held at the ends)."""
    if ok.all():
        return x
    if not ok.any():
        return np.zeros_like(x)
    i = np.arange(x.size)
    return np.interp(i, i[ok], x[ok])


def _attitude(r_e, v_e, min_speed_mps):
    """C_eb (n, 3, 3), heading, pitch (n,) [rad] from the velocity direction (module docstring)."""
    lat, lon, _ = ecef_to_geodetic(r_e)
    Cen = C_en(lat, lon)
    v_n = (np.swapaxes(Cen, -1, -2) @ v_e[..., None])[..., 0]
    vh = np.hypot(v_n[:, 0], v_n[:, 1])
    moving = np.linalg.norm(v_n, axis=-1) >= min_speed_mps
    psi = _fill_gaps(_unwrap_masked(np.arctan2(v_n[:, 1], v_n[:, 0]), moving), moving)
    theta = _fill_gaps(np.arctan2(-v_n[:, 2], vh), moving)
    C_nb = dcm_from_euler(np.zeros_like(psi), theta, psi)
    return Cen @ C_nb, psi, theta


def _unwrap_masked(a: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Unwrap the angles ``a`` over the samples where ``ok`` (others: placeholders filled later)."""
    out = np.zeros_like(a)
    out[ok] = np.unwrap(a[ok])
    return out


def truth_from_fit(fit: SplineFit, imu_rate_hz: float = 100.0, batch_size: int = 1,
                   min_speed_mps: float = 1.0) -> Truth:
    """The truth and ideal IMU on the grid ``t_k = k / imu_rate_hz`` (time since ``fit.t0``).

    Parameters
    ----------
    fit : SplineFit
    imu_rate_hz : IMU rate [Hz], > 0. The grid covers ``[fit.t0, fit.t1]`` to within half a sample.
    batch_size : B; every row is the same trajectory (the arrays are read-only broadcast views).
    min_speed_mps : speed below which the attitude is interpolated, not taken from the velocity [m/s].

    Returns
    -------
    Truth with ``t`` (N,) relative to ``fit.t0``, ``heading`` the local NED heading (not that of a start
    frame), ``pitch`` the flight-path angle, ``engine_on`` all True, ``lat0, lon0, h0`` at ``fit.t0``.
    """
    if isinstance(imu_rate_hz, bool) or not isinstance(imu_rate_hz, (int, float)) or not math.isfinite(imu_rate_hz) \
            or imu_rate_hz <= 0:
        raise ValueError(f"imu_rate_hz must be a finite number > 0, got {imu_rate_hz!r}")
    if not isinstance(batch_size, int) or isinstance(batch_size, bool) or batch_size < 1:
        raise ValueError(f"batch_size must be an int >= 1, got {batch_size!r}")
    if isinstance(min_speed_mps, bool) or not isinstance(min_speed_mps, (int, float)) \
            or not math.isfinite(min_speed_mps) or min_speed_mps <= 0:
        raise ValueError(f"min_speed_mps must be a finite number > 0, got {min_speed_mps!r}")
    dt = 1.0 / float(imu_rate_hz)
    N = int(round((fit.t1 - fit.t0) / dt)) + 1                # ends within dt/2 of fit.t1 (tiny extrapolation)
    if N < 2:
        raise ValueError(f"the reference spans {fit.t1 - fit.t0} s: shorter than one IMU interval ({dt} s)")
    th = fit.t0 + 0.5 * dt * np.arange(2 * N - 1)          # half-step grid: nodes and interval midpoints
    r = fit.position(th)
    v = fit.velocity(th)
    a = fit.acceleration(th)
    C_eb, psi, theta = _attitude(r, v, min_speed_mps)
    g = gravity_ecef(r)
    cor = 2.0 * np.cross(OMEGA_IE_E, v)
    F = (np.swapaxes(C_eb, -1, -2) @ (a + cor - g)[..., None])[..., 0]   # instantaneous f_b on the half grid
    f_b = np.empty((N, 3))
    f_b[0] = F[0]
    f_b[1:] = (F[0:-2:2] + 4.0 * F[1:-1:2] + F[2::2]) / 6.0            # Simpson over (t_{k-1}, t_k]
    Cn = C_eb[::2]
    dC = np.swapaxes(Cn[:-1], -1, -2) @ rot_z(np.array(OMEGA_IE * dt)) @ Cn[1:]
    w_b = np.empty((N, 3))
    w_b[1:] = log_so3(dC) / dt
    w_b[0] = w_b[1]
    rn, vn = r[::2], v[::2]
    lat0, lon0, h0 = ecef_to_geodetic(rn[0])
    B = batch_size

    def bc(x, dtype=np.float64):
        return np.broadcast_to(np.asarray(x, dtype)[None], (B,) + np.shape(x))

    return Truth(t=np.arange(N) * dt, r_e=bc(rn), v_e=bc(vn), C_eb=bc(Cn), f_b=bc(f_b), w_b=bc(w_b),
                 speed=bc(np.linalg.norm(vn, axis=-1)),
                 heading=bc(np.mod(psi[::2] + np.pi, 2 * np.pi) - np.pi), pitch=bc(theta[::2]),
                 engine_on=bc(np.ones(N, bool), bool), lat0=np.full(B, float(lat0)), lon0=np.full(B, float(lon0)),
                 h0=np.full(B, float(h0)), imu_rate_hz=float(imu_rate_hz))
