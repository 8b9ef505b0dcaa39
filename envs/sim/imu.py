"""IMU error model with named sensor grades, plus vehicle vibration.

Output convention
-----------------
Sample ``k`` (k = 1..N, stored at index ``k - 1``) is the **mean** specific
force ``f_b`` [m/s^2] and the **mean** angular rate ``w_b`` [rad/s] over the
interval ``(t_{k-1}, t_k]``, ``dt = 1 / imu_rate_hz``, resolved in the body
frame ``b`` (FRD, see :mod:`earth`). The error-free means ``f_true`` and
``w_true`` (B, N, 3) come from the truth generator.

Error model (Groves 2013, *Principles of GNSS, Inertial, and Multisensor
Integrated Navigation Systems*, 2nd ed., sec. 4.4 "Error characteristics":
biases, scale factor and cross-coupling errors, random noise)::

    w_meas = (I + S_g + M_g) (w_true + w_vib) + b_g(t) + n_g
    f_meas = (I + S_a + M_a) (f_true + f_vib) + b_a(t) + n_a
    b(t)   = b_fixed + b_turn_on + b_gm(t)

* ``S`` diagonal scale-factor errors and ``M`` off-diagonal small-angle
  misalignment / non-orthogonality terms, drawn once per run;
* ``b_turn_on`` a per-run random constant (run-to-run / turn-on bias);
* ``b_gm`` a first-order Gauss-Markov process (the usual stand-in for bias
  instability, Groves sec. 4.4; IEEE Std 952-1997 Annex C for the Allan
  variance terms): ``b_k = exp(-dt/tau) b_{k-1} + u_k``,
  ``var(u) = sigma^2 (1 - exp(-2 dt/tau))``, ``b_0 ~ N(0, sigma^2)``, so the
  process is stationary from the first sample;
* ``n`` the white noise of a mean over ``dt``: angle / velocity random walk
  (IEEE Std 952-1997: ARW ``N`` in rad/sqrt(s), VRW in m/s/sqrt(s)) gives a
  per-sample standard deviation ``ARW / sqrt(dt)`` and ``VRW / sqrt(dt)``;
* ``w_vib``, ``f_vib`` vehicle vibration (a property of the vehicle, not of the
  IMU): it is added to the motion the IMU senses, before the sensor's own
  errors, see :class:`Vibration`.

Random numbers
--------------
Row ``i`` draws only from ``rngs[i]``: two 64-bit words, from which independent
per-component child streams are derived (``SeedSequence`` spawn keys; SFC64
bit generators, chosen for speed). Each component (per-run constants, gyro
white noise, accel white noise, gyro Gauss-Markov, accel Gauss-Markov,
vibration) therefore has its own stream: the draws do not depend on the batch
size, and switching one error term on or off (or changing its size) leaves the
realizations of the others unchanged (paired Monte Carlo comparisons).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from earth.units import DEG, deg, dph, dpsh, mg, mpsph, ppm, ugpsh, ugpshz

from .imu_kernels import finite_rows, imu_rows, regimes_rows, rough_fill, sensor_pass, steps_fill, vibration_row
from .normals import SFC64, fill_normals_rows, store_stream_state, stream_state
from .rng import ChildStreams, child_states_rows
from .buffers import empty
from .row_threads import default_workers, run_row_ranges

__all__ = [
    "ImuGrade",
    "IMU_GRADES",
    "get_imu_grade",
    "Vibration",
    "ImuEvents",
    "ImuData",
    "simulate_imu",
    "simulate_vibration",
    "sinusoid_interval_mean",
    "allan_deviation",
    "density_from_sample_sigma",
]

_U64_MAX = np.iinfo(np.uint64).max

_COMPONENTS = ("constants", "gyro_white", "accel_white", "gyro_gm", "accel_gm", "vibration", "events")
"""Child streams derived from each row's generator; spawn key = index here (never reorder)."""


# --------------------------------------------------------------------------- helpers
def _check_nonneg(owner: str, name: str, value) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise ValueError(f"{owner}.{name} must be finite, got {v!r}")
    if v < 0.0:
        raise ValueError(f"{owner}.{name} must be >= 0, got {v!r}")
    return v


def _check_pos(owner: str, name: str, value) -> float:
    v = _check_nonneg(owner, name, value)
    if v <= 0.0:
        raise ValueError(f"{owner}.{name} must be > 0, got {v!r}")
    return v


def _check_vec3(owner: str, name: str, value, *, nonneg: bool = False) -> tuple[float, float, float]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} must be 3 real numbers, got {value!r}") from None
    if arr.shape != (3,):
        raise ValueError(f"{owner}.{name} must have 3 elements, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{owner}.{name} must be finite, got {value!r}")
    if nonneg and np.any(arr < 0):
        raise ValueError(f"{owner}.{name} must be >= 0, got {value!r}")
    return (float(arr[0]), float(arr[1]), float(arr[2]))


def _check_range(owner: str, name: str, value) -> tuple[float, float]:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{owner}.{name} must be a (low, high) pair, got {value!r}") from None
    if arr.shape != (2,):
        raise ValueError(f"{owner}.{name} must be a (low, high) pair, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{owner}.{name} must be finite, got {value!r}")
    if arr[0] < 0 or arr[1] < arr[0]:
        raise ValueError(f"{owner}.{name} must satisfy 0 <= low <= high, got {value!r}")
    return (float(arr[0]), float(arr[1]))


def density_from_sample_sigma(sigma: float, rate_hz: float) -> float:
    """Random-walk coefficient equivalent to a per-sample white-noise sigma.

    A mean over ``dt = 1/rate_hz`` of white noise with density ``N`` has the
    standard deviation ``N / sqrt(dt)`` (IEEE Std 952-1997, angle / velocity
    random walk), so ``N = sigma * sqrt(dt)``.

    Parameters
    ----------
    sigma : per-sample standard deviation [rad/s or m/s^2].
    rate_hz : sample rate the sigma refers to [Hz].

    Returns
    -------
    float, ARW [rad/sqrt(s)] or VRW [m/s/sqrt(s)].
    """
    return float(sigma) * math.sqrt(1.0 / float(rate_hz))


# --------------------------------------------------------------------------- grade
@dataclass(frozen=True)
class ImuGrade:
    """Error budget of one IMU (SI units; one value per sensor triad, same on each axis).

    Attributes
    ----------
    name : str
        Label of the grade.
    gyro_arw : float
        Gyro angle random walk [rad/sqrt(s)]; per-sample sigma ``gyro_arw / sqrt(dt)`` [rad/s].
    accel_vrw : float
        Accelerometer velocity random walk [m/s/sqrt(s)]; per-sample sigma ``accel_vrw / sqrt(dt)`` [m/s^2].
    gyro_bias_turn_on_sigma : float
        Sigma of the per-run constant gyro bias [rad/s].
    accel_bias_turn_on_sigma : float
        Sigma of the per-run constant accelerometer bias [m/s^2].
    gyro_bias_instability : float
        Steady-state sigma of the first-order Gauss-Markov gyro bias [rad/s].
    gyro_bias_tau_s : float
        Correlation time of that process [s], > 0.
    accel_bias_instability : float
        Steady-state sigma of the Gauss-Markov accelerometer bias [m/s^2].
    accel_bias_tau_s : float
        Its correlation time [s], > 0.
    gyro_scale_sigma, accel_scale_sigma : float
        Sigma of the per-axis scale-factor errors (diagonal of ``S``) [dimensionless].
    gyro_misalignment_sigma, accel_misalignment_sigma : float
        Sigma of each off-diagonal small-angle misalignment / non-orthogonality
        term of ``M`` [rad].
    gyro_bias_fixed : tuple of 3 floats or None
        Deterministic gyro bias added on every run [rad/s].
    accel_bias_fixed : tuple of 3 floats or None
        Deterministic accelerometer bias added on every run [m/s^2].
    """

    name: str
    gyro_arw: float = 0.0
    accel_vrw: float = 0.0
    gyro_bias_turn_on_sigma: float = 0.0
    accel_bias_turn_on_sigma: float = 0.0
    gyro_bias_instability: float = 0.0
    gyro_bias_tau_s: float = 3600.0
    accel_bias_instability: float = 0.0
    accel_bias_tau_s: float = 3600.0
    gyro_scale_sigma: float = 0.0
    accel_scale_sigma: float = 0.0
    gyro_misalignment_sigma: float = 0.0
    accel_misalignment_sigma: float = 0.0
    gyro_bias_fixed: tuple[float, float, float] | None = None
    accel_bias_fixed: tuple[float, float, float] | None = None

    def __post_init__(self):
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"ImuGrade.name must be a non-empty str, got {self.name!r}")
        for f in dataclasses.fields(self):
            if f.name in ("name", "gyro_bias_fixed", "accel_bias_fixed"):
                continue
            check = _check_pos if f.name.endswith("_tau_s") else _check_nonneg
            object.__setattr__(self, f.name, check("ImuGrade", f.name, getattr(self, f.name)))
        for fname in ("gyro_bias_fixed", "accel_bias_fixed"):
            v = getattr(self, fname)
            if v is not None:
                object.__setattr__(self, fname, _check_vec3("ImuGrade", fname, v))

    def replace(self, **changes) -> "ImuGrade":
        """Copy with some fields changed (``dataclasses.replace``; validated again)."""
        return dataclasses.replace(self, **changes)

    @property
    def is_ideal(self) -> bool:
        """True when every error term is zero (the output then equals the truth)."""
        zero = all(
            getattr(self, f.name) == 0.0
            for f in dataclasses.fields(self)
            if f.name not in ("name", "gyro_bias_tau_s", "accel_bias_tau_s", "gyro_bias_fixed", "accel_bias_fixed")
        )
        fixed = all(
            v is None or not any(v) for v in (self.gyro_bias_fixed, self.accel_bias_fixed)
        )
        return zero and fixed


IMU_GRADES: dict[str, ImuGrade] = {
    # No error at all: the output is the truth (analytic INS checks).
    "ideal": ImuGrade(name="ideal"),
    # Consumer MEMS (smartphone / low-cost automotive), values typical of the
    # Bosch BMI160 / BMI088 and TDK ICM-20602 / ICM-42688-P data sheets:
    # gyro noise density 0.003-0.007 deg/s/sqrt(Hz) (BMI160: 0.007, i.e.
    # 0.42 deg/sqrt(h)), zero-rate offset +-0.5 deg/s (ICM-42688-P; a few
    # deg/s uncalibrated), sensitivity tolerance ~0.5-1 %, cross-axis ~1 %;
    # accel noise 70-180 ug/sqrt(Hz) (BMI160: 180), zero-g offset +-20..40 mg.
    # In-run bias instability of this class: ~10 deg/h and ~0.1 mg (Allan
    # floors), modelled as Gauss-Markov with 100 s correlation time.
    "consumer": ImuGrade(
        name="consumer",
        gyro_arw=deg(0.007),                    # 0.007 deg/s/sqrt(Hz) = 0.42 deg/sqrt(h)
        accel_vrw=ugpshz(180.0),                # 180 ug/sqrt(Hz)
        gyro_bias_turn_on_sigma=deg(0.5),       # 0.5 deg/s
        accel_bias_turn_on_sigma=mg(20.0),      # 20 mg
        gyro_bias_instability=dph(10.0),        # 10 deg/h
        gyro_bias_tau_s=100.0,
        accel_bias_instability=mg(0.1),         # 0.1 mg
        accel_bias_tau_s=100.0,
        gyro_scale_sigma=ppm(5000.0),           # 0.5 %
        accel_scale_sigma=ppm(5000.0),          # 0.5 %
        gyro_misalignment_sigma=0.005,          # 5 mrad (~0.3 deg, cross-axis ~0.5 %)
        accel_misalignment_sigma=0.005,
    ),
    # Industrial MEMS, STIM300-like: seed paper 003 Table 1 (gyro zero-bias
    # stability 8 deg/h, used here as the turn-on sigma; accel bias instability
    # 0.05 mg) and the Safran/Sensonor STIM300 data sheet (gyro bias instability
    # ~0.3-0.5 deg/h, ARW 0.15 deg/sqrt(h), scale factor accuracy +-500 ppm,
    # misalignment ~1 mrad; 10 g accel VRW 0.07 m/s/sqrt(h), bias instability
    # 0.05 mg, scale factor +-300 ppm). Note: seed 003's VRW of 700 ug/sqrt(h)
    # is 0.0069 m/s/sqrt(h), ten times below the data sheet; its exact Table 1
    # is the grade "seed003".
    "industrial": ImuGrade(
        name="industrial",
        gyro_arw=dpsh(0.15),                    # 0.15 deg/sqrt(h)
        accel_vrw=mpsph(0.07),                  # 0.07 m/s/sqrt(h)
        gyro_bias_turn_on_sigma=dph(8.0),       # 8 deg/h (seed 003 Table 1)
        accel_bias_turn_on_sigma=mg(2.0),       # 2 mg: typical industrial-MEMS run-to-run accel bias (not in seed 003)
        gyro_bias_instability=dph(0.5),         # 0.5 deg/h
        gyro_bias_tau_s=300.0,
        accel_bias_instability=mg(0.05),        # 0.05 mg (seed 003 Table 1)
        accel_bias_tau_s=300.0,
        gyro_scale_sigma=ppm(500.0),
        accel_scale_sigma=ppm(300.0),
        gyro_misalignment_sigma=1e-3,           # 1 mrad
        accel_misalignment_sigma=1e-3,
    ),
    # Tactical, NovAtel IMU-FSAS (iMAR FOG + servo accelerometers) as quoted in
    # seed paper 000 sec. 5.2: accelerometer bias 1 mg and scale factor 300 ppm,
    # gyro bias 0.75 deg/h and scale factor 400 ppm; FSAS data sheet ARW
    # ~0.1 deg/sqrt(h). Accelerometer noise (50 ug/sqrt(Hz)), in-run
    # instabilities (0.1 deg/h, 0.1 mg; 1 h correlation) and misalignment
    # (0.1 mrad after calibration) are typical values of this class.
    "tactical": ImuGrade(
        name="tactical",
        gyro_arw=dpsh(0.1),                     # 0.1 deg/sqrt(h)
        accel_vrw=ugpshz(50.0),                 # 50 ug/sqrt(Hz) = 0.03 m/s/sqrt(h)
        gyro_bias_turn_on_sigma=dph(0.75),      # 0.75 deg/h (seed 000)
        accel_bias_turn_on_sigma=mg(1.0),       # 1 mg (seed 000)
        gyro_bias_instability=dph(0.1),
        gyro_bias_tau_s=3600.0,
        accel_bias_instability=mg(0.1),
        accel_bias_tau_s=3600.0,
        gyro_scale_sigma=ppm(400.0),            # 400 ppm (seed 000)
        accel_scale_sigma=ppm(300.0),           # 300 ppm (seed 000)
        gyro_misalignment_sigma=1e-4,
        accel_misalignment_sigma=1e-4,
    ),
    # Seed paper 000 sec. 5.1 simulation: per-sample white noise 3 mg (accel)
    # and 1 deg/h (gyro) at 100 Hz, expressed as the equivalent random walks
    # for dt = 0.01 s (VRW = 3 mg * sqrt(0.01 s), ARW = 1 deg/h * sqrt(0.01 s));
    # at another rate the per-sample sigma scales as 1/sqrt(dt). Plus the fixed
    # biases of its Table 1; no other error.
    "seed000": ImuGrade(
        name="seed000",
        gyro_arw=density_from_sample_sigma(dph(1.0), 100.0),
        accel_vrw=density_from_sample_sigma(mg(3.0), 100.0),
        gyro_bias_fixed=(-8.7e-4, 13e-4, -8.7e-4),
        accel_bias_fixed=(0.0883, -0.1275, 0.0785),
    ),
    # Seed paper 003 Table 1 verbatim (STIM300-like): gyro zero-bias stability
    # 8 deg/h and accel zero-bias instability 0.05 mg as random constants (the
    # paper's filter states are "gyro random constant drift" and "accelerometer
    # random constant bias"), ARW 0.2 deg/sqrt(h), VRW 700 ug/sqrt(h).
    "seed003": ImuGrade(
        name="seed003",
        gyro_arw=dpsh(0.2),
        accel_vrw=ugpsh(700.0),
        gyro_bias_turn_on_sigma=dph(8.0),
        accel_bias_turn_on_sigma=mg(0.05),
    ),
}
"""Named IMU grades (sources in the comments of each entry)."""


def get_imu_grade(name) -> ImuGrade:
    """The preset :class:`ImuGrade` called ``name`` (an ``ImuGrade`` is returned as is).

    Raises
    ------
    ValueError
        Unknown name; the message lists the known names.
    """
    if isinstance(name, ImuGrade):
        return name
    try:
        return IMU_GRADES[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown IMU grade {name!r}; known grades: {sorted(IMU_GRADES)}") from None


# --------------------------------------------------------------------------- vibration
@dataclass(frozen=True)
class Vibration:
    """Vehicle vibration sensed by the IMU (a property of the vehicle, not of the IMU).

    Three regimes, decided per sample from ``engine_on`` and ``speed``:

    * engine on and stationary (``|speed| <= stationary_speed_mps``): engine-idle
      vibration, a sinusoid at the engine firing frequency ``f_e`` plus its
      second harmonic, independent random phase on each channel. A 4-stroke
      4-cylinder engine fires twice per revolution, so 600-1050 rpm idle gives
      ``f_e`` = 20-35 Hz. ``f_e`` and the rms levels are drawn once per run,
      uniformly in the configured ranges.
    * engine on and moving: road vibration. The *displacement* (tilt angle,
      vibration velocity) is band-limited Gaussian noise (a damped second-order
      resonance at ``road_center_hz``, damping ``road_damping``); the sensed
      rate sample is its increment over the interval divided by dt, so the
      integrated vibration stays bounded (no spurious attitude/velocity random
      walk). The rate rms is ``road_rms_ref * (|speed| /
      road_ref_speed_mps) ** road_speed_exponent``; ``road_rms_ref`` is drawn
      once per run.
    * engine off: none.

    Because an IMU sample is the mean over ``(t_{k-1}, t_k]``, the idle
    sinusoids are averaged analytically (:func:`sinusoid_interval_mean`): the
    mean is the mid-interval value attenuated by ``sinc(w dt / 2)``, and a tone
    above the Nyquist frequency ``1 / (2 dt)`` (e.g. the 40-70 Hz harmonic at
    100 Hz, or the fundamental at 10 Hz) is aliased into the output, as in a
    real integrating IMU. The road noise is generated directly at the output
    rate as the impulse-invariant discretization of the resonance (its spectrum
    folds around Nyquist likewise; the mild sinc attenuation of the interval
    mean is neglected).

    Attributes
    ----------
    enabled : bool
        False: no vibration at all (see :meth:`none`).
    engine_freq_hz_range : (float, float)
        Range of the idle firing frequency [Hz].
    harmonic_ratio : float
        Amplitude of the second harmonic (``2 f_e``) relative to the fundamental [-].
    idle_accel_rms_range : (float, float)
        Range of the per-axis rms of the idle specific-force vibration [m/s^2].
    idle_gyro_rms_range : (float, float)
        Range of the per-axis rms of the idle angular-rate vibration [rad/s].
    road_accel_rms_ref_range : (float, float)
        Range of the per-axis rms of road specific-force vibration at
        ``road_ref_speed_mps`` [m/s^2].
    road_gyro_rms_ref_range : (float, float)
        Same for the angular rate [rad/s].
    road_ref_speed_mps : float
        Reference speed of the road levels [m/s], > 0.
    road_speed_exponent : float
        Exponent of the rms growth with speed [-], >= 0.
    road_center_hz : float
        Natural frequency of the road-vibration resonance [Hz], > 0.
    road_damping : float
        Damping ratio of that resonance, 0 < zeta < 1.
    axis_weights : (float, float, float)
        Per-axis multipliers of all rms levels (x, y, z body axes) [-].
    stationary_speed_mps : float
        Speeds at or below this are "stationary" [m/s].
    """

    enabled: bool = True
    engine_freq_hz_range: tuple[float, float] = (20.0, 35.0)
    harmonic_ratio: float = 0.5
    idle_accel_rms_range: tuple[float, float] = (0.05, 0.3)
    idle_gyro_rms_range: tuple[float, float] = (0.05 * DEG, 0.3 * DEG)
    road_accel_rms_ref_range: tuple[float, float] = (0.2, 0.6)
    road_gyro_rms_ref_range: tuple[float, float] = (0.2 * DEG, 0.8 * DEG)
    road_ref_speed_mps: float = 20.0
    road_speed_exponent: float = 1.0
    road_center_hz: float = 12.0
    road_damping: float = 0.3
    axis_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    stationary_speed_mps: float = 0.05

    def __post_init__(self):
        if not isinstance(self.enabled, (bool, np.bool_)):
            raise ValueError(f"Vibration.enabled must be a bool, got {self.enabled!r}")
        object.__setattr__(self, "enabled", bool(self.enabled))
        for name in ("engine_freq_hz_range", "idle_accel_rms_range", "idle_gyro_rms_range",
                     "road_accel_rms_ref_range", "road_gyro_rms_ref_range"):
            object.__setattr__(self, name, _check_range("Vibration", name, getattr(self, name)))
        if self.engine_freq_hz_range[0] <= 0.0:
            raise ValueError(f"Vibration.engine_freq_hz_range must be > 0, got {self.engine_freq_hz_range!r}")
        for name in ("harmonic_ratio", "road_speed_exponent", "stationary_speed_mps"):
            object.__setattr__(self, name, _check_nonneg("Vibration", name, getattr(self, name)))
        for name in ("road_ref_speed_mps", "road_center_hz", "road_damping"):
            object.__setattr__(self, name, _check_pos("Vibration", name, getattr(self, name)))
        if self.road_damping >= 1.0:
            raise ValueError(f"Vibration.road_damping must be < 1 (under-damped), got {self.road_damping!r}")
        object.__setattr__(self, "axis_weights", _check_vec3("Vibration", "axis_weights", self.axis_weights, nonneg=True))

    @classmethod
    def none(cls) -> "Vibration":
        """No vibration."""
        return cls(enabled=False)

    def replace(self, **changes) -> "Vibration":
        """Copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def sinusoid_interval_mean(amplitude, omega, phase, t_start, dt):
    """Mean of ``amplitude * sin(omega t + phase)`` over ``(t_start, t_start + dt]``.

    Exact: ``A (cos(a) - cos(b)) / (omega dt)`` with ``a = omega t_start + phase``,
    ``b = a + omega dt``, evaluated in the equivalent well-conditioned form
    ``A sinc(omega dt / 2) sin(omega (t_start + dt/2) + phase)`` (product-to-sum
    identity; ``sinc(x) = sin(x)/x``, 1 at x = 0).

    Parameters
    ----------
    amplitude : array_like, same unit as the result.
    omega : array_like, angular frequency [rad/s].
    phase : array_like [rad].
    t_start : array_like, interval start [s].
    dt : float or array_like, interval length [s], > 0.

    Returns
    -------
    ndarray, broadcast shape of the inputs.
    """
    omega = np.asarray(omega, dtype=float)
    half = 0.5 * omega * dt
    atten = np.sinc(half / np.pi)  # numpy sinc is sin(pi x)/(pi x)
    return np.asarray(amplitude, dtype=float) * atten * np.sin(omega * (np.asarray(t_start, dtype=float) + 0.5 * dt) + phase)


def _ar2_coefficients(center_hz: float, damping: float, dt: float) -> tuple[float, float, float]:
    """AR(2) ``y_k = a1 y_{k-1} + a2 y_{k-2} + e_k`` with the poles of a damped resonance sampled at dt.

    Impulse invariance: continuous poles ``-zeta w_n +- i w_n sqrt(1 - zeta^2)``
    map to ``r exp(+-i theta)``, ``r = exp(-zeta w_n dt)``, ``theta = w_n
    sqrt(1 - zeta^2) dt`` (any rate; frequencies above Nyquist alias).
    Returns ``(a1, a2, gamma0)`` with ``gamma0`` the stationary variance for a
    unit-variance ``e`` (Box & Jenkins AR(2) autocovariance):
    ``gamma0 = (1 - a2) / ((1 + a2) ((1 - a2)^2 - a1^2))``.
    """
    wn = 2.0 * math.pi * center_hz
    r = math.exp(-damping * wn * dt)
    theta = wn * math.sqrt(1.0 - damping * damping) * dt
    a1 = 2.0 * r * math.cos(theta)
    a2 = -r * r
    gamma0 = (1.0 - a2) / ((1.0 + a2) * ((1.0 - a2) ** 2 - a1 * a1))
    return a1, a2, gamma0


def _idle_rows(f_e, a_rms, g_rms, phases, vib: Vibration, dt: float, rows, d: "_RowDraws") -> None:
    """The idle tones of ``rows`` (R,) into ``d.w12`` and ``d.coef``, for
    :func:`~envs.sim.imu_kernels.idle_samples`: per channel rms r -> fundamental amplitude ``sqrt(2) r /
    sqrt(1 + h^2)``, the harmonic ``h`` times that, each attenuated by ``sinc(w dt / 2)``
    (:func:`sinusoid_interval_mean`) and split on the random phase: ``A sin(th + phi) = A cos(phi) sin(th) +
    A sin(phi) cos(th)``. ``f_e``, ``a_rms``, ``g_rms`` (R,) and ``phases`` (R, 2, 6) are the rows' draws."""
    weights = np.asarray(vib.axis_weights)
    rms = np.concatenate([a_rms[:, None] * weights, g_rms[:, None] * weights], axis=1)
    h = vib.harmonic_ratio
    amp1 = math.sqrt(2.0) * rms / math.sqrt(1.0 + h * h)
    cos_ph, sin_ph = np.cos(phases), np.sin(phases)
    for j, (mult, amp) in enumerate(((1.0, amp1), (2.0, h * amp1))):
        w = 2.0 * math.pi * f_e * mult
        y = math.pi * (w * dt / (2.0 * math.pi))
        # numpy's sinc(w dt / 2pi) = sin(w dt/2) / (w dt/2), by the C library's sine as for one row
        atten = np.array([math.sin(v) / v if v else 1.0 for v in y.tolist()])[:, None]
        d.w12[rows, j] = w
        d.coef[rows, 2 * j] = amp * atten * cos_ph[:, j]
        d.coef[rows, 2 * j + 1] = amp * atten * sin_ph[:, j]


def _road_rows(gens, z, road_a, road_g, n_road, vib: Vibration, dt: float, rows, d: "_RowDraws") -> None:
    """The road resonance of ``rows`` (R,) into ``d``: its start state ``zi``, its output ``scale``, ``road_par``
    and where its innovations come from (the compiled stream of ``gens[i]``, or ``e`` drawn here by numpy).

    ``z`` (R, 2, 6) holds the rows' 2 x 6 start normals, ``road_a``, ``road_g`` (R,) their levels and ``n_road`` (R,)
    their road samples. The stationary start: ``y_1 = z_0``, ``y_2 = rho_1 z_0 + sqrt(1 - rho_1^2) z_1`` (the
    AR(2) lag-1 correlation ``rho_1 = a_1 / (1 - a_2)``), the delay state of ``lfilter`` from them, times
    ``sqrt(gamma0)``. y (stationary variance gamma0) is the vibration *displacement* (tilt angle, velocity) of the
    resonance; the IMU senses its rate, and the interval mean of a rate is the displacement increment over the
    interval divided by dt. So the sample is ``(L_k y_k - L_(k-1) y_(k-1)) / dt``: its sum telescopes, the
    integrated vibration (attitude, velocity) stays bounded, and its spectrum is zero at DC, as for a physical
    oscillation (a rate with power at DC would integrate into an attitude random walk that no vehicle has).
    ``var(y_k - y_(k-1)) = 2 gamma0 (1 - rho1)`` for the unit-innovation process, hence ``scale``. The process
    runs only over the road samples (a stationary process restarted from its carried-over state after a stop is
    still stationary).
    """
    weights = np.asarray(vib.axis_weights)
    a1, a2, gamma0 = _ar2_coefficients(vib.road_center_hz, vib.road_damping, dt)
    rho1 = a1 / (1.0 - a2)
    y1 = z[:, 0]
    y2 = rho1 * z[:, 0] + math.sqrt(max(1.0 - rho1 * rho1, 0.0)) * z[:, 1]
    d.zi[rows] = np.stack([a1 * y1 + a2 * y2, a2 * y1], axis=1) * math.sqrt(gamma0)  # state in the unscaled process
    unit = 1.0 / math.sqrt(2.0 * gamma0 * (1.0 - rho1))
    d.scale[rows] = np.concatenate([road_a[:, None] * weights, road_g[:, None] * weights], axis=1) * unit
    d.road_on[rows] = True
    d.road_par[:3] = 1.0, -a1, -a2
    for j, i in enumerate(rows.tolist()):
        gen = gens[i]
        stream = stream_state(gen)
        if stream is None:                          # a bit generator without compiled draws: numpy draws them
            d.e[i] = gen.standard_normal((int(n_road[j]), 6))
        else:
            d.road_kind[i], d.road_state[i] = stream
            d.road_gens[i] = gen


_VIBRATION_DRAWS = 17
"""Uniform draws that start each run's vibration: f_e, idle accel rms, idle gyro rms, 2 x 6 phases, road accel
level, road gyro level."""


def _vibration_rows(gens: Sequence[np.random.Generator], dt: float, engine_on: np.ndarray | None,
                    speed: np.ndarray, vib: Vibration, d: "_RowDraws") -> None:
    """The random draws of each row's vibration and its per-run parameters, without the samples, into ``d``.

    Draw order of row ``i``, from ``gens[i]`` alone (fixed, independent of the data): f_e, idle accel rms, idle
    gyro rms, 2 x 6 phases, road accel level, road gyro level (each ``uniform`` in its range: 17 doubles, drawn
    in one call, ``low + (high - low) u`` as ``Generator.uniform`` forms them), then (only if the run moves with
    the engine on) the road noise (2 + M) x 6, M = number of road samples: its first 2 x 6 here, the M x 6
    innovations by :func:`~envs.sim.imu_kernels.road_samples` from the stream state taken here (or here, for a
    generator whose bit generator has no compiled stream).

    Writes the samples' regimes into ``d.kinds`` (B, n) int8 (:func:`~envs.sim.imu_kernels.regimes`),
    ``d.vib_on`` where the run has vibration (the engine runs at some sample), ``d.idle_on`` and the idle tones
    (:func:`_idle_rows`) where it idles, ``d.road_on`` and the resonance (:func:`_road_rows`) where it drives with
    a road level.
    ``engine_on`` (B, n) or None (on throughout), ``speed`` (B, n) [m/s].
    """
    b = len(gens)
    u = np.empty((b, _VIBRATION_DRAWS))
    for i, gen in enumerate(gens):
        gen.random(out=u[i])

    def uniform(col, bounds):
        low, high = bounds
        return low + (high - low) * u[:, col]

    f_e = uniform(0, vib.engine_freq_hz_range)
    a_rms, g_rms = uniform(1, vib.idle_accel_rms_range), uniform(2, vib.idle_gyro_rms_range)
    phases = uniform(slice(3, 15), (0.0, 2.0 * math.pi)).reshape(b, 2, 6)
    road_a, road_g = uniform(15, vib.road_accel_rms_ref_range), uniform(16, vib.road_gyro_rms_ref_range)
    counts = np.empty((b, 2), np.int64)
    has_eng = engine_on is not None
    regimes_rows(speed, engine_on if has_eng else _NO_FLAGS[None], has_eng, vib.stationary_speed_mps, d.kinds,
                 counts)
    n_idle, n_road = counts[:, 0], counts[:, 1]
    d.vib_on[:] = (n_idle > 0) | (n_road > 0)
    d.idle_on[:] = n_idle > 0
    rows = np.flatnonzero(d.idle_on)
    if rows.size:
        _idle_rows(f_e[rows], a_rms[rows], g_rms[rows], phases[rows], vib, dt, rows, d)
    rows = np.flatnonzero((n_road > 0) & ((road_a > 0.0) | (road_g > 0.0)))
    if rows.size:
        z = np.empty((rows.size, 2, 6))
        for j, i in enumerate(rows.tolist()):
            gens[i].standard_normal(out=z[j])
        _road_rows(gens, z, road_a[rows], road_g[rows], n_road[rows], vib, dt, rows, d)


def _store_road_streams(d: "_RowDraws") -> None:
    """Each row's vibration generator set to where its compiled road innovations left it (``d.road_state``): where
    numpy's draws of them would have left it."""
    for i, gen in enumerate(d.road_gens):
        if gen is not None:
            store_stream_state(gen, d.road_kind[i], d.road_state[i])


def _vibration_samples(gens: Sequence[np.random.Generator], dt: float, engine_on: np.ndarray | None,
                       speed: np.ndarray, vib: Vibration) -> tuple[np.ndarray, np.ndarray]:
    """The vibration of B runs: ``(on, out)``, ``on`` (B,) bool where a run has any (the engine runs at some
    sample), ``out`` (B, n, 6) float64, ``f_vib`` in columns 0-2 and ``w_vib`` in 3-5 (zeros where ``on`` is
    False). The draws of :func:`_vibration_rows` (each generator left where its draws end), then each row's
    samples, compiled (:func:`~envs.sim.imu_kernels.vibration_row`)."""
    b, n = speed.shape
    d = _RowDraws.empty(b, n, vib)
    _vibration_rows(gens, dt, engine_on, speed, vib, d)
    e_flat, e_off = _csr(d.e, 6)
    out = np.zeros((b, n, 6))
    for i in np.flatnonzero(d.vib_on).tolist():
        vibration_row(i, d.kinds, speed, dt, d.idle_on, d.w12, d.coef, d.road_on, d.road_par, d.zi, d.scale,
                      d.road_kind, d.road_state, e_off, e_flat, out[i])
    _store_road_streams(d)
    return d.vib_on, out


def _vibration_row(gen: np.random.Generator, dt: float, engine_on: np.ndarray | None, speed: np.ndarray,
                   vib: Vibration) -> np.ndarray | None:
    """Vibration of one run: (N, 6) float64, ``f_vib`` in columns 0-2 and ``w_vib`` in 3-5, or None if it is zero
    throughout (:func:`_vibration_samples` of that one row)."""
    on, out = _vibration_samples([gen], dt, None if engine_on is None else engine_on[None],
                                 np.asarray(speed, dtype=float)[None], vib)
    return out[0] if on[0] else None


_NO_FLAGS = np.zeros(0, dtype=bool)
_NO_SAMPLES = np.zeros((0, 6))


def simulate_vibration(imu_rate_hz: float, rngs: Sequence[np.random.Generator], speed, engine_on=None,
                       vibration: Vibration | None = None, dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """Vehicle vibration as interval means at the IMU rate (see :class:`Vibration`).

    Row i draws only from ``rngs[i]`` (for the vehicle, the ``"vibration"``
    stream of :func:`envs.sim.rng.row_generators`). :func:`simulate_imu` with
    ``vibration_rngs=rngs`` applies exactly this vibration.

    Parameters
    ----------
    imu_rate_hz : float, sample rate [Hz].
    rngs : B generators; row i draws only from ``rngs[i]``.
    speed : (B, N) vehicle speed [m/s].
    engine_on : (B, N) bool or None (engine on throughout).
    vibration : Vibration or None (defaults).
    dtype : np.float32 or np.float64.

    Returns
    -------
    f_vib : (B, N, 3) specific-force vibration [m/s^2].
    w_vib : (B, N, 3) angular-rate vibration [rad/s].
    """
    vib = Vibration() if vibration is None else vibration
    dtype = _check_dtype(dtype)
    rate = _check_rate(imu_rate_hz)
    speed = np.asarray(speed, dtype=float)
    if speed.ndim != 2:
        raise ValueError(f"speed must have shape (B, N), got {speed.shape}")
    b, n = speed.shape
    _check_rngs(rngs, b)
    speed, engine_on = _check_motion(speed, engine_on, b, n)
    f = np.zeros((b, n, 3), dtype=dtype)
    w = np.zeros((b, n, 3), dtype=dtype)
    if not vib.enabled:
        return f, w
    _, out = _vibration_samples(rngs, 1.0 / rate, engine_on, speed, vib)
    f[:], w[:] = out[..., :3], out[..., 3:]
    return f, w


# --------------------------------------------------------------------------- process-side events
@dataclass(frozen=True)
class ImuEvents:
    """Random process-side events of an episode: bias steps and rough-road vibration regimes.

    * **Bias steps** (seed paper 003 sec. 1 / 2.1: a "sudden alteration" the
      strong-tracking filter has to follow): gyro and accelerometer steps,
      each a Poisson number per episode (mean ``rate * T``), at uniform
      random times, on a uniform random axis with a random sign, of size
      ``U(gyro_step)`` / ``U(accel_step)``; a step persists to the end of the
      episode (it is part of :attr:`ImuData.gyro_bias` / ``accel_bias``).
      Defaults 10-50 deg/h and 1-5 mg: several times the industrial grade's
      8 deg/h / 2 mg turn-on sigmas.
    * **Rough-road regimes**: a Poisson number of segments per episode, at
      uniform random start times, lengths ``U(rough_duration_s)``; inside one
      the vehicle vibration and the sensors' white noise are multiplied by a
      factor ``U(rough_scale)`` (a rough surface excites the whole band the
      navigation filter treats as process noise: assumption, 2-5x).
      Overlapping segments take the larger factor.

    Draw order (one child stream of each row's IMU generator): the gyro step
    count ``n``, then ``n`` times, axes, signs, sizes; the same for the
    accelerometer; then the rough count ``r``, ``r`` starts, lengths, factors.

    Parameters
    ----------
    gyro_step_rate_hz, accel_step_rate_hz : float
        Mean steps per second of episode [1/s], >= 0.
    gyro_step : (float, float)
        Gyro step size range [rad/s], 0 <= min <= max.
    accel_step : (float, float)
        Accelerometer step size range [m/s^2], 0 <= min <= max.
    rough_rate_hz : float
        Mean rough-road segments per second of episode [1/s], >= 0.
    rough_duration_s : (float, float)
        Segment length range [s], 0 < min <= max.
    rough_scale : (float, float)
        Vibration / white-noise multiplier range, 1 <= min <= max.
    flag_window_s : float
        The world's ``IMU_EVENT`` bit stays set this long after a step or a regime change [s], > 0.
    """

    gyro_step_rate_hz: float = 1.0 / 150.0
    accel_step_rate_hz: float = 1.0 / 150.0
    gyro_step: tuple = (dph(10.0), dph(50.0))
    accel_step: tuple = (mg(1.0), mg(5.0))
    rough_rate_hz: float = 1.0 / 150.0
    rough_duration_s: tuple = (10.0, 40.0)
    rough_scale: tuple = (2.0, 5.0)
    flag_window_s: float = 5.0

    def __post_init__(self):
        o = "ImuEvents"
        for name in ("gyro_step_rate_hz", "accel_step_rate_hz", "rough_rate_hz"):
            object.__setattr__(self, name, _check_nonneg(o, name, getattr(self, name)))
        for name in ("gyro_step", "accel_step", "rough_duration_s", "rough_scale"):
            object.__setattr__(self, name, _check_range(o, name, getattr(self, name)))
        if self.rough_duration_s[0] <= 0.0:
            raise ValueError(f"{o}.rough_duration_s must be > 0, got {self.rough_duration_s!r}")
        if self.rough_scale[0] < 1.0:
            raise ValueError(f"{o}.rough_scale must be >= 1, got {self.rough_scale!r}")
        object.__setattr__(self, "flag_window_s", _check_pos(o, "flag_window_s", self.flag_window_s))

    def replace(self, **changes) -> "ImuEvents":
        """Copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)


def _draw_imu_events(gen: np.random.Generator, ev: ImuEvents, dt: float, n: int):
    """Bias steps and rough-road segments of one row (draw order in :class:`ImuEvents`).

    Returns
    -------
    steps : tuple of (t_s, sensor, axis, size) with sensor 'gyro' / 'accel', size signed [rad/s or m/s^2];
    rough : tuple of (t0_s, t1_s, factor).
    """
    T = max(n - 1, 1) * dt                                 # samples end at 0, dt, ..., (n-1) dt
    steps = []
    for sensor, rate, rng in (("gyro", ev.gyro_step_rate_hz, ev.gyro_step),
                              ("accel", ev.accel_step_rate_hz, ev.accel_step)):
        k = int(gen.poisson(rate * T))
        times = gen.uniform(0.0, T, size=k)
        axes = gen.integers(0, 3, size=k)
        signs = np.where(gen.random(k) < 0.5, -1.0, 1.0)
        sizes = gen.uniform(rng[0], rng[1], size=k)
        steps += [(float(times[j]), sensor, int(axes[j]), float(signs[j] * sizes[j])) for j in range(k)]
    r = int(gen.poisson(ev.rough_rate_hz * T))
    starts = gen.uniform(0.0, T, size=r)
    lengths = gen.uniform(ev.rough_duration_s[0], ev.rough_duration_s[1], size=r)
    factors = gen.uniform(ev.rough_scale[0], ev.rough_scale[1], size=r)
    rough = tuple(sorted((float(starts[j]), float(min(starts[j] + lengths[j], T)), float(factors[j]))
                         for j in range(r)))
    return tuple(sorted(steps)), rough


# --------------------------------------------------------------------------- output
@dataclass(frozen=True)
class ImuData:
    """Simulated IMU output of B runs of N samples (interval means, see the module docstring).

    Attributes
    ----------
    f_b : (B, N, 3) measured specific force [m/s^2].
    w_b : (B, N, 3) measured angular rate [rad/s].
    gyro_bias : (B, N, 3) total additive gyro bias at each sample
        (fixed + turn-on + Gauss-Markov) [rad/s]; a read-only broadcast view
        when it is constant in time; None where not recorded (``simulate_imu(..., bias_records=False)``, a
        recorded IMU).
    accel_bias : (B, N, 3) same for the accelerometers [m/s^2].
    gyro_scale_misalignment : (B, 3, 3) per-run ``S_g + M_g`` [-]; the sensor
        applies ``I + gyro_scale_misalignment``.
    accel_scale_misalignment : (B, 3, 3) per-run ``S_a + M_a`` [-].
    dt : float, sample interval [s].
    grade : ImuGrade used.
    bias_steps : tuple of B tuples of (t_s, sensor, axis, size) or None
        The :class:`ImuEvents` bias steps of each row (time [s since start] of the first sample they
        affect, ``'gyro'`` / ``'accel'``, axis 0-2, signed size [rad/s or m/s^2]); None without events.
    rough : tuple of B tuples of (t0_s, t1_s, factor) or None
        The rough-road segments of each row (half-open in the sample's end time); None without events.
    """

    f_b: np.ndarray
    w_b: np.ndarray
    gyro_bias: np.ndarray | None
    accel_bias: np.ndarray | None
    gyro_scale_misalignment: np.ndarray
    accel_scale_misalignment: np.ndarray
    dt: float
    grade: ImuGrade = field(repr=False)
    bias_steps: tuple | None = None
    rough: tuple | None = None


# --------------------------------------------------------------------------- validation
def _check_dtype(dtype):
    dt = np.dtype(dtype)
    if dt not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be np.float32 or np.float64, got {dtype!r}")
    return dt


def _check_rate(rate) -> float:
    try:
        r = float(rate)
    except (TypeError, ValueError):
        raise ValueError(f"imu_rate_hz must be a positive number, got {rate!r}") from None
    if not math.isfinite(r) or r <= 0.0:
        raise ValueError(f"imu_rate_hz must be finite and > 0, got {rate!r}")
    return r


def _check_rngs(rngs, b: int) -> None:
    if isinstance(rngs, np.random.Generator) or not hasattr(rngs, "__len__"):
        raise ValueError("rngs must be a list of B numpy Generators (one per row)")
    if len(rngs) != b:
        raise ValueError(f"rngs must hold one Generator per row: len(rngs) = {len(rngs)} but B = {b}")
    for i, g in enumerate(rngs):
        if not isinstance(g, np.random.Generator):
            raise ValueError(f"rngs[{i}] must be a numpy.random.Generator, got {type(g).__name__}")


def _check_motion(speed, engine_on, b: int, n: int):
    if speed is not None:
        speed = np.asarray(speed, dtype=float)
        if speed.shape != (b, n):
            raise ValueError(f"speed must have shape (B, N) = {(b, n)}, got {speed.shape}")
        if not np.all(np.isfinite(speed)):
            raise ValueError("speed must be finite")
    if engine_on is not None:
        engine_on = np.asarray(engine_on)
        if engine_on.shape != (b, n):
            raise ValueError(f"engine_on must have shape (B, N) = {(b, n)}, got {engine_on.shape}")
        if engine_on.dtype != bool:
            if not np.all(np.isin(engine_on, (0, 1))):
                raise ValueError("engine_on must be boolean (or 0/1)")
            engine_on = engine_on.astype(bool)
    return speed, engine_on


# --------------------------------------------------------------------------- simulation
def _children(rng: np.random.Generator) -> ChildStreams:
    """Independent per-component streams of one row (2 draws from ``rng``), by name (:data:`_COMPONENTS`): child
    ``k`` is ``Generator(SFC64(SeedSequence(entropy, spawn_key=(k,))))``, each built on first use
    (:class:`envs.sim.rng.ChildStreams`). :func:`_draw_rows` takes the same streams of all rows at once; this one
    row's form is what the one-row stages and their tests use."""
    return _streams_of(_seed_words(rng))


def _streams_of(words) -> ChildStreams:
    """The component streams (:func:`_children`) seeded by a row's two words (:func:`_seed_words`)."""
    return ChildStreams([int(w) for w in words], len(_COMPONENTS), np.random.SFC64, _COMPONENTS)


def _seed_words(rng: np.random.Generator) -> np.ndarray:
    """The two uint64 words a row draws from ``rng`` to seed its component streams (:func:`_children`,
    :func:`_draw_rows`)."""
    return rng.integers(0, _U64_MAX, size=2, dtype=np.uint64, endpoint=True)


def _error_matrix(z: np.ndarray, scale_sigma: float, mis_sigma: float) -> np.ndarray:
    """``S + M`` (..., 3, 3) from 9 unit normals per matrix ``z`` (..., 3, 3) (row-major draw order): diagonal
    scale errors, off-diagonal misalignments."""
    e = z * mis_sigma
    diag = np.arange(3)
    e[..., diag, diag] = z[..., diag, diag] * scale_sigma
    return e


@dataclass(frozen=True)
class _SensorSpec:
    """Per-sensor view of an ImuGrade used inside :func:`simulate_imu` (SI units)."""

    fixed_in: tuple | None
    turn_on_sigma: float
    scale_sigma: float
    mis_sigma: float
    gm_sigma: float
    gm_tau: float
    white_sigma: float  # per-sample sigma of the interval mean
    gm_stream: str
    white_stream: str

    @property
    def fixed(self) -> np.ndarray:
        return np.zeros(3) if self.fixed_in is None else np.asarray(self.fixed_in, dtype=float)

    @property
    def has_sm(self) -> bool:
        return self.scale_sigma > 0 or self.mis_sigma > 0


@dataclass(frozen=True)
class _RowJob:
    """What one row of :func:`simulate_imu` reads and where it writes (row ``i`` of each output array).

    Inputs: ``sensors`` (gyro, accel :class:`_SensorSpec`), ``truth`` (w_true, f_true) (B, N, 3), ``dt`` [s],
    ``rngs`` / ``vibration_rngs`` (B generators or None), ``engine_on``, ``speed`` (B, N) or None,
    ``vibration`` (None when off), ``events`` (:class:`ImuEvents` or None), ``step_rates`` (gyro, accel) [1/s].
    Outputs: ``outs`` (gyro, accel) (B, N, 3) of the output dtype, ``bias_full`` (the time-varying biases or
    None), ``bias_const`` (2, B, 3) and ``sm`` (2, B, 3, 3) (gyro, accel), ``ev_rows`` (B,) list of the rows'
    ``(steps, rough)``.
    """

    sensors: tuple
    truth: tuple
    dt: float
    rngs: Sequence
    vibration_rngs: Sequence | None
    engine_on: np.ndarray | None
    speed: np.ndarray | None
    vibration: Vibration | None
    events: ImuEvents | None
    step_rates: tuple
    outs: tuple
    bias_full: tuple
    bias_const: np.ndarray
    sm: np.ndarray
    ev_rows: list


def _check_inputs(f_true, w_true, imu_rate_hz, grade, rngs, engine_on, speed, vibration, dtype, workers,
                  vibration_rngs, events):
    """The arguments of :func:`simulate_imu` checked and converted (``ValueError`` naming the argument).

    Returns ``(grade, dtype, dt, f_true, w_true, engine_on, speed, vibration, workers)`` with ``vibration``
    None when it is off and ``workers`` resolved.
    """
    grade = get_imu_grade(grade)
    dtype = _check_dtype(dtype)
    dt = 1.0 / _check_rate(imu_rate_hz)
    f_true = np.asarray(f_true)
    w_true = np.asarray(w_true)
    if f_true.ndim != 3 or f_true.shape[-1] != 3:
        raise ValueError(f"f_true must have shape (B, N, 3), got {f_true.shape}")
    if w_true.shape != f_true.shape:
        raise ValueError(f"w_true must have the shape of f_true {f_true.shape}, got {w_true.shape}")
    b, n, _ = f_true.shape
    if b == 0 or n == 0:
        raise ValueError(f"f_true must hold at least one row and one sample, got shape {f_true.shape}")
    if workers is None:
        workers = default_workers(b)
    elif not isinstance(workers, (int, np.integer)) or isinstance(workers, bool) or workers < 1:
        raise ValueError(f"workers must be a positive int or None, got {workers!r}")
    for name, arr in (("f_true", f_true), ("w_true", w_true)):
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise ValueError(f"{name} must be a real array, got dtype {arr.dtype}")
        if not _all_finite(arr, workers):
            raise ValueError(f"{name} must be finite")
    _check_rngs(rngs, b)
    speed, engine_on = _check_motion(speed, engine_on, b, n)
    if vibration is not None and not isinstance(vibration, Vibration):
        raise ValueError(f"vibration must be a Vibration or None, got {type(vibration).__name__}")
    vib_on = vibration is not None and vibration.enabled
    if vib_on and speed is None:
        raise ValueError("speed (B, N) is required when vibration is enabled")
    if vibration_rngs is not None:
        try:
            _check_rngs(vibration_rngs, b)
        except ValueError as exc:
            raise ValueError(f"vibration_rngs: {exc}") from None
    if events is not None and not isinstance(events, ImuEvents):
        raise ValueError(f"events must be an ImuEvents or None, got {type(events).__name__}")
    return grade, dtype, dt, f_true, w_true, engine_on, speed, (vibration if vib_on else None), workers


def _all_finite(a: np.ndarray, workers: int) -> bool:
    """Whether every element of ``a`` (B, ...) is finite: for a C-contiguous float32 or float64 array by
    :func:`~envs.sim.imu_kernels.finite_rows` in row ranges on ``workers`` threads, else by numpy."""
    if a.dtype.kind in "iub":
        return True
    if a.dtype not in (np.float32, np.float64) or not a.flags.c_contiguous:
        return bool(np.isfinite(a).all())
    flat = a.reshape(a.shape[0], -1)
    ok = np.empty(a.shape[0], dtype=bool)
    run_row_ranges(lambda r0, r1: finite_rows(flat, r0, r1, ok), a.shape[0], workers)
    return bool(ok.all())


def _sensor_specs(g: ImuGrade, dt: float) -> tuple[_SensorSpec, _SensorSpec]:
    """The (gyro, accel) views of the grade ``g`` at the sample interval ``dt`` [s]: the white noise as the
    per-sample sigma of an interval mean, ``ARW / sqrt(dt)`` and ``VRW / sqrt(dt)`` (IEEE Std 952-1997)."""
    return (
        _SensorSpec(g.gyro_bias_fixed, g.gyro_bias_turn_on_sigma, g.gyro_scale_sigma, g.gyro_misalignment_sigma,
                    g.gyro_bias_instability, g.gyro_bias_tau_s, g.gyro_arw / math.sqrt(dt), "gyro_gm", "gyro_white"),
        _SensorSpec(g.accel_bias_fixed, g.accel_bias_turn_on_sigma, g.accel_scale_sigma, g.accel_misalignment_sigma,
                    g.accel_bias_instability, g.accel_bias_tau_s, g.accel_vrw / math.sqrt(dt), "accel_gm",
                    "accel_white"),
    )


def _event_arrays(steps, rough) -> tuple[np.ndarray, np.ndarray]:
    """A row's events (:func:`_draw_imu_events`) as arrays for :func:`rough_fill` and :func:`steps_fill`: the
    rough-road segments ``(t0, t1, factor)`` (R, 3) and the bias steps ``(t, sensor, axis, size)`` (S, 4),
    sensor 0 gyro and 1 accel, in their order."""
    seg = np.array(rough, dtype=np.float64).reshape(-1, 3)
    rec = np.array([(t, 0.0 if sensor == "gyro" else 1.0, axis, size) for t, sensor, axis, size in steps],
                   dtype=np.float64).reshape(-1, 4)
    return seg, rec


def _row_events(gen: np.random.Generator, events: ImuEvents, step_rates, dt: float, n: int):
    """Stage of one row: its :class:`ImuEvents` (bias steps, rough-road segments) drawn from ``gen``.

    Returns ``(steps, rough)`` (:func:`_draw_imu_events`), the rough-road factor per sample (n,) or None
    without a segment, and the step biases (gyro, accel) (n, 3) each, None where that sensor's step rate is 0.
    Sample j covers ``(t_j-1, t_j]``, ``t_j = j dt`` (:func:`rough_fill`, :func:`steps_fill`).
    """
    steps, rough = _draw_imu_events(gen, events, dt, n)
    seg, rec = _event_arrays(steps, rough)
    rough_f = None
    if rough:
        rough_f = np.empty(n)
        rough_fill(seg, dt, rough_f)
    sb = [None] * 2
    for k, r in enumerate(step_rates):
        if r > 0:
            sb[k] = np.empty((n, 3))
            steps_fill(rec, k, dt, sb[k])
    return (steps, rough), rough_f, tuple(sb)


_NONE = np.empty((0, 3))
"""An empty (0, 3) array: "no such input" (or output) for :func:`sensor_pass`."""
_NO_STATE = np.zeros(4, dtype=np.uint64)
"""The stream state of a draw that does not happen."""


def _gm_parameters(s: _SensorSpec, dt: float) -> np.ndarray:
    """``(sigma, phi, scale)`` (3,) of the sensor's Gauss-Markov bias at the sample interval ``dt`` [s]:
    ``phi = exp(-dt / tau)``, ``scale = sigma sqrt(1 - exp(-2 dt / tau))``; zeros without one."""
    if not s.gm_sigma > 0:
        return np.zeros(3)
    return np.array([s.gm_sigma, math.exp(-dt / s.gm_tau), s.gm_sigma * math.sqrt(-math.expm1(-2.0 * dt / s.gm_tau))])


def _sensor_row(s: _SensorSpec, truth, vib, rough, sm_row, const, step_bias, ch, dt: float, out, bias_out) -> bool:
    """Stage of one row: one sensor's measured output into ``out`` (n, 3) (any float dtype).

    ``out = (I + S + M)(truth + vib rough) + bias + white`` (:func:`sensor_pass`): ``vib`` (n, 3) or None,
    ``rough`` (n,) the rough-road factor (ones without), ``sm_row`` the row's ``S + M``, the bias the constant
    ``const`` (3,) plus the Gauss-Markov process (drawn from the sensor's stream of ``ch``: 3 for its start,
    then n x 3) and the ``step_bias`` (n, 3) or None; the white noise (n x 3 from its own stream of ``ch``).
    ``bias_out`` (n, 3) receives the bias when it varies in time. Returns whether it does.
    """
    n = truth.shape[0]
    has_gm, has_white, has_step = s.gm_sigma > 0, s.white_sigma > 0, step_bias is not None
    gm_kind, gm_state = ch.raw_state(s.gm_stream) if has_gm else (0, _NO_STATE)
    white_kind, white_state = ch.raw_state(s.white_stream) if has_white else (0, _NO_STATE)
    sensor_pass(truth, _NONE if vib is None else vib, rough, np.eye(3) + sm_row, s.has_sm, const, bool(const.any()),
                _gm_parameters(s, dt), gm_kind, gm_state, has_gm, _NONE if step_bias is None else step_bias, has_step,
                s.white_sigma, white_kind, white_state, has_white, np.empty((n + 1, 3) if has_gm else (0, 3)),
                np.empty((n, 3) if has_white else (0, 3)), out, bias_out)
    return has_gm or has_step


@dataclass(frozen=True)
class _RowDraws:
    """What :func:`_draw_rows` draws for the compiled pass :func:`imu_rows` (row ``i`` of each array): the child
    stream states of the sensors' bias processes and white noise ``gm_state``, ``white_state`` (2, B, 4), the
    vibration (``vib_on``, ``idle_on``, ``w12``, ``coef``, ``road_on``, ``zi``, ``scale``, ``road_kind``,
    ``road_state``, ``kinds`` (B, n) the regimes; ``road_par`` (5,) shared; ``road_gens`` the generators whose
    states the pass advances), and per row the event arrays ``rough`` (R, 3), ``steps`` (S, 4) and the road
    innovations ``e`` (M, 6) of a generator drawn by numpy."""

    gm_state: np.ndarray
    white_state: np.ndarray
    vib_on: np.ndarray
    idle_on: np.ndarray
    w12: np.ndarray
    coef: np.ndarray
    road_on: np.ndarray
    zi: np.ndarray
    scale: np.ndarray
    road_kind: np.ndarray
    road_state: np.ndarray
    kinds: np.ndarray
    road_par: np.ndarray
    road_gens: list
    rough: list
    steps: list
    e: list

    @classmethod
    def empty(cls, b: int, n: int, vib: Vibration | None) -> "_RowDraws":
        nv = b if vib is not None else 1
        road_par = np.zeros(5)
        if vib is not None:
            road_par[3:] = 1.0 / vib.road_ref_speed_mps, float(vib.road_speed_exponent)
        return cls(np.zeros((2, b, 4), np.uint64), np.zeros((2, b, 4), np.uint64), np.zeros(b, bool),
                   np.zeros(b, bool), np.zeros((b, 2)), np.zeros((b, 4, 6)), np.zeros(b, bool), np.zeros((b, 2, 6)),
                   np.zeros((b, 6)), np.full(b, -1, np.int64), np.zeros((b, 4), np.uint64),
                   np.zeros((nv, n if vib is not None else 1), np.int8), road_par, [None] * b, [_NO_SEG] * b,
                   [_NO_STEPS] * b, [_NO_SAMPLES] * b)


_NO_SEG = np.zeros((0, 3))
_NO_STEPS = np.zeros((0, 4))


def _draw_rows(job: _RowJob, d: _RowDraws) -> None:
    """Every row of :func:`simulate_imu` up to its per-sample work: its per-run constants (into the job), its
    vibration and events drawn (into ``d`` and ``job.ev_rows``) and its sensors' child streams taken. Row ``i``
    draws only from ``job.rngs[i]`` (two words that seed its component streams, :func:`_children`) and
    ``job.vibration_rngs[i]``; the streams' raw states come from one compiled call
    (:func:`envs.sim.rng.child_states_rows`), each stream's draws in its own order."""
    b, n = job.truth[0].shape[:2]
    words = np.empty((b, 2), np.uint64)
    for i, gen in enumerate(job.rngs):
        words[i] = _seed_words(gen)
    raw = ["constants"] + [s.gm_stream for s in job.sensors if s.gm_sigma > 0] \
        + [s.white_stream for s in job.sensors if s.white_sigma > 0]
    states = child_states_rows(words, [_COMPONENTS.index(name) for name in raw], SFC64)
    # per-run constants, fixed order: turn-on gyro (3), turn-on accel (3), S+M gyro (9), S+M accel (9)
    z = np.empty((b, 24))
    fill_normals_rows(SFC64, np.ascontiguousarray(states[:, 0]), z)
    for k, s in enumerate(job.sensors):
        job.bias_const[k] = s.fixed + z[:, 3 * k:3 * k + 3] * s.turn_on_sigma
        job.sm[k] = _error_matrix(z[:, 6 + 9 * k:15 + 9 * k].reshape(b, 3, 3), s.scale_sigma, s.mis_sigma)
    kids = None
    if job.events is not None or (job.vibration is not None and job.vibration_rngs is None):
        kids = [_streams_of(row) for row in words]
    if job.vibration is not None:
        gens = job.vibration_rngs if job.vibration_rngs is not None else [c["vibration"] for c in kids]
        _vibration_rows(gens, job.dt, job.engine_on, job.speed, job.vibration, d)
    if job.events is not None:
        for i, c in enumerate(kids):
            job.ev_rows[i] = _draw_imu_events(c["events"], job.events, job.dt, n)
            d.rough[i], d.steps[i] = _event_arrays(*job.ev_rows[i])
    for k, s in enumerate(job.sensors):
        if s.gm_sigma > 0:
            d.gm_state[k] = states[:, raw.index(s.gm_stream)]
        if s.white_sigma > 0:
            d.white_state[k] = states[:, raw.index(s.white_stream)]


def _csr(parts: list, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Per-row arrays (m_i, width) as one (sum m_i, width) float64 array and its row offsets (B + 1,) int64."""
    off = np.zeros(len(parts) + 1, np.int64)
    sizes = [p.shape[0] for p in parts]
    if not any(sizes):
        return np.zeros((0, width)), off
    np.cumsum(sizes, out=off[1:])
    return np.concatenate(parts).reshape(-1, width), off


def _kernel_args(job: _RowJob, d: _RowDraws) -> tuple:
    """The arguments of :func:`imu_rows` after ``r0, r1``: the job's inputs and outputs and the rows' draws."""
    w_true, f_true = (np.ascontiguousarray(t, dtype=np.float64) for t in job.truth)
    has_step = [job.events is not None and r > 0 for r in job.step_rates]
    flags = np.array([(s.has_sm, s.gm_sigma > 0, has_step[k], s.white_sigma > 0, job.bias_full[k] is not None)
                      for k, s in enumerate(job.sensors)])
    const = job.bias_const
    dtype = job.outs[0].dtype
    bias = [np.empty((1, 0, 3), dtype) if f is None else f for f in job.bias_full]   # (1, 0, 3): not recorded
    speed = np.zeros((1, 1)) if job.vibration is None else np.ascontiguousarray(job.speed)
    rough_seg, rough_off = _csr(d.rough, 3)
    step_rec, step_off = _csr(d.steps, 4)
    e_flat, e_off = _csr(d.e, 6)
    return (w_true, f_true, job.dt, flags, np.eye(3) + job.sm, const, const.any(axis=-1),
            np.stack([_gm_parameters(s, job.dt) for s in job.sensors]), np.array([s.white_sigma for s in job.sensors]),
            _CHILD_KIND, d.gm_state, d.white_state, d.vib_on, d.idle_on, d.w12, d.coef, d.road_on, d.road_par, d.zi,
            d.scale, d.road_kind, d.road_state, e_off, e_flat, d.kinds, speed, rough_off, rough_seg, step_off,
            step_rec, job.outs[0], job.outs[1], bias[0], bias[1])


_CHILD_KIND = SFC64
"""The compiled kind of the rows' component streams (:func:`_children` builds them on SFC64)."""


def simulate_imu(f_true, w_true, imu_rate_hz: float, grade, rngs: Sequence[np.random.Generator],
                 engine_on=None, speed=None, vibration: Vibration | None = None, dtype=np.float64,
                 workers: int | None = None, vibration_rngs: Sequence[np.random.Generator] | None = None,
                 events: ImuEvents | None = None, buffers=None, bias_records: bool = True) -> ImuData:
    """Corrupt ideal IMU interval means with the errors of an IMU grade (and vehicle vibration).

    Implements (Groves 2013 sec. 4.4; IEEE Std 952-1997 noise terms)::

        w_meas = (I + S_g + M_g)(w_true + w_vib) + b_fixed,g + b_on,g + b_gm,g(t) + n_g
        f_meas = (I + S_a + M_a)(f_true + f_vib) + b_fixed,a + b_on,a + b_gm,a(t) + n_a

    with ``n ~ N(0, (ARW or VRW)^2 / dt)`` per sample and the Gauss-Markov
    recursion of the module docstring (the bias of sample k is the process
    value ``b_k``; its variation inside one interval, O(dt/tau), is neglected).
    The "ideal" grade with no vibration returns the truth exactly.

    Parameters
    ----------
    f_true : (B, N, 3) ideal mean specific force per interval [m/s^2].
    w_true : (B, N, 3) ideal mean angular rate per interval [rad/s].
    imu_rate_hz : float, sample rate [Hz]; ``dt = 1 / imu_rate_hz``.
    grade : ImuGrade or a name of :data:`IMU_GRADES`.
    rngs : list of B ``numpy.random.Generator``; row i draws only from ``rngs[i]``
        (two 64-bit words per call, see the module docstring).
    engine_on : (B, N) bool or None. None: engine on throughout (only used for vibration).
    speed : (B, N) vehicle speed [m/s] or None; required when vibration is enabled.
    vibration : Vibration or None (None: no vibration).
    dtype : np.float32 or np.float64, dtype of the output arrays (internal
        arithmetic is float64, so a float32 result is the float64 result rounded).
    workers : int or None
        Threads over row ranges for the per-sample work: each row's small draws are made first, in Python
        (:func:`_draw_rows`), then :func:`envs.sim.imu_kernels.imu_rows` runs ranges of rows, releasing the GIL
        (:func:`envs.sim.row_threads.run_row_ranges`). None: ``min(B, os.cpu_count(), 8)``; 1: serial. Results
        do not depend on it.
    vibration_rngs : list of B generators or None
        Streams of the vehicle vibration (e.g. ``row_generators(seeds,
        "vibration")``); then the vibration equals :func:`simulate_vibration`
        with these generators. None: a child stream of ``rngs[i]`` (still
        independent of the IMU error terms).
    events : ImuEvents or None
        Random bias steps and rough-road regimes (:class:`ImuEvents`), drawn
        from their own child stream of ``rngs[i]`` (the other terms' draws do
        not change). None: none.
    buffers : :class:`envs.sim.buffers.WorldBuffers` or None: the (B, N, 3) outputs come from it (reused from an
        earlier draw that nobody holds any more). The values do not depend on it.
    bias_records : bool
        Record each sample's bias in ``ImuData.gyro_bias`` / ``accel_bias`` (default). False: those are None
        and the (B, N, 3) arrays are neither allocated nor written (an env's reset reads only ``f_b``, ``w_b``);
        the samples are the same bits.

    Returns
    -------
    ImuData

    Raises
    ------
    ValueError
        Bad shapes (naming ``f_true``, ``w_true``, ``rngs``, ``engine_on``,
        ``speed``), non-finite truth, unknown grade, bad rate, dtype or workers.
    """
    grade, dtype, dt, f_true, w_true, engine_on, speed, vibration, workers = _check_inputs(
        f_true, w_true, imu_rate_hz, grade, rngs, engine_on, speed, vibration, dtype, workers, vibration_rngs, events)
    if not isinstance(bias_records, (bool, np.bool_)):
        raise ValueError(f"bias_records must be a bool, got {bias_records!r}")
    b, n, _ = f_true.shape
    sensors = _sensor_specs(grade, dt)
    step_rates = (0.0, 0.0) if events is None else (events.gyro_step_rate_hz, events.accel_step_rate_hz)
    job = _RowJob(sensors=sensors, truth=(w_true, f_true), dt=dt, rngs=rngs, vibration_rngs=vibration_rngs,
                  engine_on=engine_on, speed=speed, vibration=vibration, events=events, step_rates=step_rates,
                  outs=(empty(buffers, "imu.w_b", (b, n, 3), dtype), empty(buffers, "imu.f_b", (b, n, 3), dtype)),
                  bias_full=tuple(empty(buffers, f"imu.{name}", (b, n, 3), dtype)
                                  if bias_records and (s.gm_sigma > 0 or r > 0) else None
                                  for name, s, r in zip(("gyro_bias", "accel_bias"), sensors, step_rates)),
                  bias_const=np.empty((2, b, 3)), sm=np.zeros((2, b, 3, 3)),
                  ev_rows=[None] * b)
    draws = _RowDraws.empty(b, n, vibration)
    _draw_rows(job, draws)
    args = _kernel_args(job, draws)
    run_row_ranges(lambda r0, r1: imu_rows(r0, r1, *args), b, workers)
    _store_road_streams(draws)
    return _imu_data(job, grade, bool(bias_records))


def _imu_data(job: _RowJob, grade: ImuGrade, bias_records: bool = True) -> ImuData:
    """The rows' outputs as :class:`ImuData` (a constant bias as a read-only broadcast view; no bias without
    ``bias_records``)."""
    b, n = job.truth[0].shape[:2]
    dtype = job.outs[0].dtype

    def _bias(full, const):
        if not bias_records:
            return None
        if full is not None:
            return full
        return np.broadcast_to(const.astype(dtype)[:, None, :], (b, n, 3))

    with_events = job.events is not None
    return ImuData(
        f_b=job.outs[1],
        w_b=job.outs[0],
        gyro_bias=_bias(job.bias_full[0], job.bias_const[0]),
        accel_bias=_bias(job.bias_full[1], job.bias_const[1]),
        gyro_scale_misalignment=job.sm[0].astype(dtype),
        accel_scale_misalignment=job.sm[1].astype(dtype),
        dt=job.dt,
        grade=grade,
        bias_steps=tuple(r[0] for r in job.ev_rows) if with_events else None,
        rough=tuple(r[1] for r in job.ev_rows) if with_events else None,
    )


# --------------------------------------------------------------------------- analysis
def allan_deviation(x, dt: float, taus, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of a rate signal (IEEE Std 952-1997 Annex C).

    With the integrated signal ``theta_k = dt * sum_{j<=k} x_j`` and cluster
    length ``m = round(tau / dt)``::

        AVAR(tau) = sum_k (theta_{k+2m} - 2 theta_{k+m} + theta_k)^2 / (2 tau^2 (L - 2m))

    where ``L`` is the number of theta samples. For white noise of density
    ``N`` (ARW/VRW), ``ADEV(tau) = N / sqrt(tau)``.

    Parameters
    ----------
    x : (..., L, ...) rate samples (interval means) [unit].
    dt : sample interval [s].
    taus : (M,) cluster times [s]; rounded to multiples of dt, each needs 2 m < L.
    axis : time axis of ``x``.

    Returns
    -------
    taus_used : (M,) the cluster times actually used [s].
    adev : x's shape with the time axis replaced by M, [unit].
    """
    x = np.moveaxis(np.asarray(x, dtype=float), axis, -1)
    theta = np.concatenate([np.zeros(x.shape[:-1] + (1,)), np.cumsum(x, axis=-1) * dt], axis=-1)
    big_l = theta.shape[-1]
    ms = np.maximum(1, np.round(np.asarray(taus, dtype=float) / dt).astype(int))
    if np.any(2 * ms >= big_l):
        raise ValueError(f"taus too long for {big_l - 1} samples at dt = {dt}")
    out = []
    for m in ms:  # loop over cluster sizes, vectorized over time
        d = theta[..., 2 * m:] - 2.0 * theta[..., m:-m] + theta[..., :-2 * m]
        tau = m * dt
        out.append(np.sqrt(np.mean(d * d, axis=-1) / (2.0 * tau * tau)))
    adev = np.moveaxis(np.stack(out, axis=-1), -1, axis)
    return ms * dt, adev
