"""Truth trajectories from motion segments, with a consistent ideal IMU (batched).

A vehicle path is a list of *segments* (:class:`Static`, :class:`Accelerate`,
:class:`Decelerate` / :func:`Stop`, :class:`Cruise`, :class:`Turn`,
:class:`Climb`) driven in the local tangent plane ``L`` of the start point:
NED axes fixed at ``(lat0, lon0, h0)``, a frame fixed to the Earth. Each
segment changes only one of (speed, heading, pitch), so the position is closed
form on every piece:

* straight, constant acceleration ``a`` along the fixed unit direction ``u``::

      p(t) = p0 + u (v0 t + a t^2 / 2),   u = [cos g cos psi, cos g sin psi, -sin g]

* horizontal arc at constant speed ``v`` and yaw rate ``w`` (pitch ``g`` fixed)::

      x = x0 + (v cos g / w)(sin(psi0 + w t) - sin psi0)
      y = y0 - (v cos g / w)(cos(psi0 + w t) - cos psi0)
      z = z0 - v sin(g) t

* vertical (pitch) arc at constant speed and pitch rate ``q`` (heading fixed)::

      d = (v / q)(sin(g0 + q t) - sin g0)          (horizontal distance)
      x = x0 + d cos psi,  y = y0 + d sin psi,  z = z0 + (v / q)(cos(g0 + q t) - cos g0)

The path is exact *flat tangent-plane* kinematics. It is not an ellipsoid-
following road: the tangent plane rises above the ellipsoid by ``d^2 / 2R``
(about 8 mm at 1 km, 8 m at 10 km from the start) and its "level" departs from
the local level by ``d / R`` (0.09 deg at 10 km). The truth is physically
consistent all the same (the IMU sees that tilt); this is fine for a simulator.

ECEF truth (``C_en0 = C_en(lat0, lon0)``, ``r0_e`` the start point)::

    r_e = r0_e + C_en0 p_L,   v_e = C_en0 v_L,   a_e = C_en0 a_L
    C_eb = C_en0 C_Lb,        C_Lb = dcm_from_euler(roll=0, pitch=g, yaw=psi)

with ``g`` the flight-path (= pitch) angle and ``psi`` the heading: no
sideslip, the body x axis is along the velocity when moving (body frame FRD).

Ideal IMU, consistent with the ECEF mechanization (Groves 2013, 2nd ed.,
section 5.3: ``v_dot_e = C_eb f_b + g_e(r_e) - 2 Omega_ie v_e`` and
``C_dot_eb = C_eb [w_ib^b x] - [omega_ie x] C_eb``)::

    f_b    = C_be (a_e + 2 Omega_ie v_e - g_e(r_e))        g_e = earth.gravity_ecef
    w_ib^b = w_Lb^b + C_be omega_ie_e,   w_Lb^b = [-psi_dot sin g, g_dot, psi_dot cos g]

(the last is the Z-Y-X Euler-rate relation with roll = 0). IMU sample ``k >= 1``
is the *mean* over ``(t_{k-1}, t_k]`` (what an integrating IMU delivers as
``delta_v / dt`` and ``delta_theta / dt``); sample 0 is the instantaneous value at
``t_0``. The mean is Simpson's 1/3 rule on every smooth sub-interval, from the
analytic values at its ends and midpoint:

* an interval that contains segment boundaries is split there and each part
  uses the one-sided values of its own piece (a boundary costs no accuracy; a
  plain Simpson across a jump ``D`` of acceleration errs by up to ``D / 6``);
* on an arc the integrands are smooth on time scales of seconds: Simpson's
  error at 100 Hz is below 1e-12 m/s^2 (measured against 2 kHz sub-means);
* on a straight piece the integrand is exactly linear inside an interval
  (constant attitude, linear speed, gravity interpolated linearly between
  anchors that are nodes), so Simpson equals the trapezoid of the end values
  and the midpoint is not evaluated.

Gravity is ``earth.gravity_ecef`` evaluated exactly on an anchor grid of
spacing ``h <= GRAVITY_ANCHOR_S`` (0.1 s, every K-th IMU node) and interpolated
linearly in time in between. The interpolation error is bounded by
``h^2/8 * |d2 g/dt2| <= h^2/8 * (|grad g| |a| + |grad^2 g| |v|^2)``, i.e. below
``4e-8 m/s^2`` (4 ng) for accelerations up to 10 m/s^2 (measured: < 5e-9 m/s^2
on the random drives): far below any IMU error model, and it spares most of the
gravity evaluations, the dominant cost otherwise.

Angular rates: within a piece the body turns relative to the Earth-fixed ``L``
frame about a *body-fixed* axis at a constant rate, so the mean of ``w_Lb^b``
over an interval is exactly the rotation vector of the interval's attitude
change (in general the mean rate and the rotation vector differ by coning
terms; not for these single-axis motions), and the mechanization update
``C_eb(t_k) = exp(-[omega_ie x] dt) C_eb(t_{k-1}) exp([w_b[k] dt x])`` reproduces
the truth. Two residuals remain, both true properties of the motion, not
errors of the IMU: the Earth-rate part of ``w_ib^b`` turns with the body during
a turn (coning ``~ dt^3 |w_Lb|^2 |omega_ie| / 6 < 1e-12 rad`` per 10 ms sample),
and an interval that holds a boundary between two pieces turning about
different axes (a turn running into a pitch arc) carries ``|phi_1 x phi_2| / 2``
(up to ~4e-7 rad for 10 deg/s rates at 100 Hz).

Evaluation: the grid nodes of all rows in one compiled pass (states on the
straight pieces, instantaneous IMU, the interval means of the intervals that
lie on one piece); numpy for everything else (the cos/sin of the arc angles,
the arcs' states, gravity, the intervals at segment boundaries), with the same
operations in the same order as an elementwise numpy evaluation and the
products whose rounding could depend on the array shapes (BLAS, einsum) formed
with a single row's shapes, so no output depends on the batch. Throughput
(2-core machine shared with other jobs): 60 s noise-burst drives at B = 64
about 0.6 ms of CPU per row; B = 64, 600 s at 100 Hz, random urban drives
about 6e6 IMU samples per second, most of it the first touch of the ~0.7 GB
of outputs (the compiled pass alone runs at ~4e7 nodes per second on warm
memory).

Rows are independent and deterministic: row ``i`` depends only on
``motions[i]`` (equal motions are evaluated once and copied). Random drives are
drawn by :func:`random_drive` from the row's own generator.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence, Union

import numba as nb
import numpy as np

from earth import C_en, OMEGA_IE_E, dcm_from_euler, geodetic_to_ecef, gravity_ecef
from earth.units import DEG

from .buffers import empty
from .row_threads import OVERLAP_ROWS, run_row_ranges

__all__ = [
    "Static", "Accelerate", "Decelerate", "Cruise", "Turn", "Climb", "Stop", "Segment",
    "Motion", "Truth", "TruthAt", "generate_truth", "random_drive", "SegmentPlan", "STYLES", "GRAVITY_ANCHOR_S",
]

GRAVITY_ANCHOR_S = 0.1
"""Largest spacing [s] of the anchor grid on which gravity is evaluated exactly."""

STYLES = ("urban", "highway", "open")
"""Driving styles known to :func:`random_drive`."""


# --------------------------------------------------------------------------- validation helpers
def _real(obj, name: str, *, lo=None, hi=None, lo_open=False, hi_open=False) -> float:
    """Check ``obj.name`` is a finite real in the given range, store it as float, return it."""
    x = getattr(obj, name)
    if type(x) is not float:                  # a float is stored as it is (the random drives build ~15 a row)
        if isinstance(x, (bool, np.bool_)) or not isinstance(x, (int, float, np.integer, np.floating)):
            raise ValueError(f"{type(obj).__name__}.{name} must be a real number, got {x!r}")
        x = float(x)
        object.__setattr__(obj, name, x)
    if not math.isfinite(x):
        raise ValueError(f"{type(obj).__name__}.{name} must be finite, got {x!r}")
    if lo is not None and (x <= lo if lo_open else x < lo):
        raise ValueError(f"{type(obj).__name__}.{name} must be {'>' if lo_open else '>='} {lo}, got {x!r}")
    if hi is not None and (x >= hi if hi_open else x > hi):
        raise ValueError(f"{type(obj).__name__}.{name} must be {'<' if hi_open else '<='} {hi}, got {x!r}")
    return x


def _flag(obj, name: str) -> bool:
    x = getattr(obj, name)
    if not isinstance(x, (bool, np.bool_)):
        raise ValueError(f"{type(obj).__name__}.{name} must be a bool, got {x!r}")
    object.__setattr__(obj, name, bool(x))
    return bool(x)


# --------------------------------------------------------------------------- segments
@dataclass(frozen=True)
class Static:
    """Vehicle at rest (speed must already be 0).

    Attributes
    ----------
    duration_s : time at rest [s], >= 0.
    engine_on : engine idling (True: vibration, a stop at a light) or off.
    """

    duration_s: float
    engine_on: bool = True

    def __post_init__(self):
        _real(self, "duration_s", lo=0.0)
        _flag(self, "engine_on")


@dataclass(frozen=True)
class Accelerate:
    """Straight, constant acceleration from the current speed up to ``to_speed_mps``.

    Attributes
    ----------
    duration_s : [s], >= 0 (0 only if the speed does not change).
    to_speed_mps : final speed [m/s], >= current speed.
    """

    duration_s: float
    to_speed_mps: float

    def __post_init__(self):
        _real(self, "duration_s", lo=0.0)
        _real(self, "to_speed_mps", lo=0.0)


@dataclass(frozen=True)
class Decelerate:
    """Straight, constant deceleration from the current speed down to ``to_speed_mps``.

    Attributes
    ----------
    duration_s : [s], >= 0 (0 only if the speed does not change).
    to_speed_mps : final speed [m/s], 0 <= to_speed_mps <= current speed.
    """

    duration_s: float
    to_speed_mps: float = 0.0

    def __post_init__(self):
        _real(self, "duration_s", lo=0.0)
        _real(self, "to_speed_mps", lo=0.0)


def Stop(duration_s: float) -> Decelerate:
    """Alias: ``Decelerate(duration_s, to_speed_mps=0.0)`` (brake to rest in ``duration_s`` [s])."""
    return Decelerate(duration_s, 0.0)


@dataclass(frozen=True)
class Cruise:
    """Straight at constant speed, heading and pitch for ``duration_s`` [s] (>= 0)."""

    duration_s: float

    def __post_init__(self):
        _real(self, "duration_s", lo=0.0)


@dataclass(frozen=True)
class Turn:
    """Horizontal arc at constant speed (> 0) and constant yaw rate.

    Attributes
    ----------
    angle_deg : heading change [deg]; positive = right turn (heading increases, NED).
    rate_deg_s : yaw-rate magnitude [deg/s], > 0. The duration is ``|angle| / rate``.
    """

    angle_deg: float
    rate_deg_s: float

    def __post_init__(self):
        _real(self, "angle_deg")
        _real(self, "rate_deg_s", lo=0.0, lo_open=True)

    @property
    def duration_s(self) -> float:
        """``|angle_deg| / rate_deg_s`` [s]."""
        return abs(self.angle_deg) / self.rate_deg_s


@dataclass(frozen=True)
class Climb:
    """Pitch change at constant speed (> 0): a vertical arc, then straight.

    The pitch (flight-path angle) goes from its current value to ``pitch_deg`` at
    a constant pitch rate over ``transition_s``; the vehicle then drives straight
    at that pitch for the rest of ``duration_s``.

    Attributes
    ----------
    pitch_deg : final pitch [deg], in (-90, 90); positive = nose up (climbing).
    duration_s : total duration [s], >= transition_s.
    transition_s : duration of the pitch arc [s], >= 0 (0 only if the pitch does not change).
    """

    pitch_deg: float
    duration_s: float
    transition_s: float

    def __post_init__(self):
        _real(self, "pitch_deg", lo=-90.0, hi=90.0, lo_open=True, hi_open=True)
        _real(self, "duration_s", lo=0.0)
        _real(self, "transition_s", lo=0.0)
        if self.transition_s > self.duration_s:
            raise ValueError(f"Climb.transition_s ({self.transition_s}) must not exceed "
                             f"Climb.duration_s ({self.duration_s})")


Segment = Union[Static, Accelerate, Decelerate, Cruise, Turn, Climb]
_SEGMENT_TYPES = (Static, Accelerate, Decelerate, Cruise, Turn, Climb)

# piece kinds
_STRAIGHT, _HARC, _VARC = 0, 1, 2


_PLAN_COLUMNS = ("t0", "kind", "pN", "pE", "pD", "v0", "acc", "psi0", "w", "gam0", "q", "engine")
"""The columns of a motion's compiled table (``Motion._plan``, :func:`_compile`): one row per piece, all float64
(``kind`` and ``engine`` as 0.0 / 1.0 / 2.0), the fields of :class:`_Plan` before its trigonometry."""


class _Plan(NamedTuple):
    """Motions compiled into P analytic pieces (each motion's last one open-ended), arrays of shape (P,): the
    pieces of the rows evaluated together (:func:`_pieces` forms it from the motions' tables)."""

    t0: np.ndarray      # start time [s], strictly increasing, t0[0] = 0
    kind: np.ndarray    # _STRAIGHT / _HARC / _VARC
    p0: np.ndarray      # (P, 3) start position in L (NED) [m]
    v0: np.ndarray      # start speed [m/s]
    acc: np.ndarray     # along-track acceleration [m/s^2] (straight pieces)
    psi0: np.ndarray    # start heading [rad]
    w: np.ndarray       # yaw rate [rad/s] (horizontal arcs)
    gam0: np.ndarray    # start pitch [rad]
    q: np.ndarray       # pitch rate [rad/s] (vertical arcs)
    engine: np.ndarray  # bool
    cpsi: np.ndarray    # cos/sin of psi0, gam0 (constant on straight pieces)
    spsi: np.ndarray
    cgam: np.ndarray
    sgam: np.ndarray


def _advance(kind, dur, p, v, a, psi, w, gam, q):
    """End state (p, v, psi, gam) of one piece after ``dur`` seconds (scalar closed forms above)."""
    pN, pE, pD = p
    if kind == _STRAIGHT:
        s = dur * (v + 0.5 * a * dur)
        cg = math.cos(gam)
        return (pN + s * cg * math.cos(psi), pE + s * cg * math.sin(psi), pD - s * math.sin(gam)), v + a * dur, psi, gam
    if kind == _HARC:
        psi1 = psi + w * dur
        R = v * math.cos(gam) / w
        return ((pN + R * (math.sin(psi1) - math.sin(psi)), pE - R * (math.cos(psi1) - math.cos(psi)),
                 pD - v * math.sin(gam) * dur), v, psi1, gam)
    gam1 = gam + q * dur
    Rv = v / q
    d = Rv * (math.sin(gam1) - math.sin(gam))
    return (pN + d * math.cos(psi), pE + d * math.sin(psi), pD + Rv * (math.cos(gam1) - math.cos(gam))), v, psi, gam1


def _segment_name(i: int, s) -> str:
    """``Motion.segments[i] (Type)``, the culprit an error of :func:`_compile` names (formed only when it raises)."""
    return f"Motion.segments[{i}] ({type(s).__name__})"


def _compile(m: "Motion") -> np.ndarray:
    """Compile the segments of a motion into analytic pieces: its (P, 12) float64 table, a row per piece in the
    columns :data:`_PLAN_COLUMNS` (one array: a motion costs one conversion; :func:`_pieces` forms the
    :class:`_Plan` of many motions and its trigonometry at once); ValueError on inconsistent segments."""
    rows = []
    t, p, v, psi, gam = 0.0, (0.0, 0.0, 0.0), m.speed0_mps, m.heading0_deg * DEG, 0.0
    engine = True

    def piece(kind, dur, a=0.0, w=0.0, q=0.0, eng=True):
        nonlocal t, p, v, psi, gam, engine
        if dur <= 0.0:
            return
        rows.append((t, kind, *p, v, a, psi, w, gam, q, 1.0 if eng else 0.0))
        p, v, psi, gam = _advance(kind, dur, p, v, a, psi, w, gam, q)
        t, engine = t + dur, eng

    for i, s in enumerate(m.segments):
        if isinstance(s, Static):
            if v != 0.0:
                raise ValueError(f"{_segment_name(i, s)}: the vehicle moves at {v} m/s; Static needs speed 0 "
                                 f"(Stop first)")
            piece(_STRAIGHT, s.duration_s, eng=s.engine_on)
            if s.duration_s == 0.0:
                engine = s.engine_on
        elif isinstance(s, (Accelerate, Decelerate)):
            dv = s.to_speed_mps - v
            if isinstance(s, Accelerate) and dv < 0.0:
                raise ValueError(f"{_segment_name(i, s)}: to_speed_mps={s.to_speed_mps} is below the current "
                                 f"speed {v} m/s")
            if isinstance(s, Decelerate) and dv > 0.0:
                raise ValueError(f"{_segment_name(i, s)}: to_speed_mps={s.to_speed_mps} is above the current "
                                 f"speed {v} m/s")
            if s.duration_s == 0.0 and dv != 0.0:
                raise ValueError(f"{_segment_name(i, s)}: duration_s=0 with a speed change of {dv} m/s "
                                 f"(infinite acceleration)")
            if s.duration_s > 0.0:
                piece(_STRAIGHT, s.duration_s, a=dv / s.duration_s)
                v = s.to_speed_mps  # exact end speed (no rounding drift)
        elif isinstance(s, Cruise):
            piece(_STRAIGHT, s.duration_s, eng=engine if v == 0.0 else True)
        elif isinstance(s, Turn):
            if v <= 0.0:
                raise ValueError(f"{_segment_name(i, s)}: a Turn needs a non-zero speed, the vehicle is at rest "
                                 f"(speed0_mps / previous segments); angle_deg={s.angle_deg}")
            if s.angle_deg != 0.0:
                psi_end = psi + s.angle_deg * DEG
                piece(_HARC, s.duration_s, w=math.copysign(s.rate_deg_s * DEG, s.angle_deg))
                psi = psi_end
        elif isinstance(s, Climb):
            if v <= 0.0:
                raise ValueError(f"{_segment_name(i, s)}: a Climb needs a non-zero speed, the vehicle is at rest "
                                 f"(speed0_mps / previous segments); pitch_deg={s.pitch_deg}")
            target = s.pitch_deg * DEG
            if target != gam:
                if s.transition_s == 0.0:
                    raise ValueError(f"{_segment_name(i, s)}: transition_s=0 with a pitch change of "
                                     f"{(target - gam) / DEG} deg (infinite pitch rate)")
                piece(_VARC, s.transition_s, q=(target - gam) / s.transition_s)
                gam = target
                piece(_STRAIGHT, s.duration_s - s.transition_s)
            else:
                piece(_STRAIGHT, s.duration_s)
        else:  # pragma: no cover - Motion validates the types
            raise ValueError(f"{_segment_name(i, s)}: unknown segment type")
    # open-ended continuation: straight at the last velocity, or at rest with the last engine flag
    rows.append((t, _STRAIGHT, *p, v, 0.0, psi, 0.0, gam, 0.0, 1.0 if (engine if v == 0.0 else True) else 0.0))
    return np.array(rows, dtype=np.float64)


@dataclass(frozen=True)
class Motion:
    """One vehicle's path: start point, start heading/speed and a segment list.

    Attributes
    ----------
    lat0_deg : geodetic latitude of the start [deg], in [-90, 90].
    lon0_deg : longitude of the start [deg], in [-180, 360].
    h0_m : ellipsoidal height of the start [m], in [-1e4, 1e5].
    heading0_deg : initial heading [deg] from north toward east (any finite value).
    speed0_mps : initial speed [m/s], >= 0 (pitch starts at 0).
    segments : tuple of segments (a list is accepted and stored as a tuple).

    The segments are checked for consistency at construction (``ValueError``
    naming ``Motion.segments[i]``): a Turn or Climb at rest, an Accelerate to a
    lower speed, a Decelerate to a higher one, a Static while moving.
    """

    lat0_deg: float
    lon0_deg: float
    h0_m: float
    heading0_deg: float
    speed0_mps: float = 0.0
    segments: tuple = ()
    _plan: np.ndarray = field(init=False, repr=False, compare=False, hash=False)   # (P, 12), :func:`_compile`

    def __post_init__(self):
        _real(self, "lat0_deg", lo=-90.0, hi=90.0)
        _real(self, "lon0_deg", lo=-180.0, hi=360.0)
        _real(self, "h0_m", lo=-1e4, hi=1e5)
        _real(self, "heading0_deg")
        _real(self, "speed0_mps", lo=0.0)
        segs = self.segments
        if isinstance(segs, _SEGMENT_TYPES) or not isinstance(segs, (tuple, list)):
            raise ValueError(f"Motion.segments must be a tuple of segments, got {type(segs).__name__}")
        for i, s in enumerate(segs):
            if not isinstance(s, _SEGMENT_TYPES):
                raise ValueError(f"Motion.segments[{i}] must be one of "
                                 f"{[c.__name__ for c in _SEGMENT_TYPES]}, got {type(s).__name__}")
        object.__setattr__(self, "segments", tuple(segs))
        object.__setattr__(self, "_plan", _compile(self))

    @property
    def duration_s(self) -> float:
        """Total duration of the segments [s]."""
        return float(sum(s.duration_s for s in self.segments))


# --------------------------------------------------------------------------- outputs
@dataclass(frozen=True, eq=False)
class TruthAt:
    """Truth at selected sample indices (e.g. GNSS epochs). Shapes: B rows, M samples.

    Attributes
    ----------
    t : (M,) [s];  r_e : (B, M, 3) [m];  v_e : (B, M, 3) [m/s];  C_eb : (B, M, 3, 3);
    speed : (B, M) [m/s];  heading : (B, M) [rad].
    """

    t: np.ndarray
    r_e: np.ndarray
    v_e: np.ndarray
    C_eb: np.ndarray
    speed: np.ndarray
    heading: np.ndarray


@dataclass(frozen=True, eq=False)
class Truth:
    """Whole-episode truth and ideal IMU on the shared grid ``t_k = k / imu_rate_hz``.

    Attributes
    ----------
    t : (N,) time [s].
    r_e : (B, N, 3) ECEF position [m] (None when ``states_every`` > 1).
    v_e : (B, N, 3) ECEF velocity [m/s] (None when ``states_every`` > 1).
    C_eb : (B, N, 3, 3) attitude, body FRD -> ECEF (None when ``states_every`` > 1).
    f_b : (B, N, 3) ideal specific force [m/s^2]: mean over ``(t_{k-1}, t_k]`` (k >= 1),
        instantaneous at k = 0.
    w_b : (B, N, 3) ideal angular rate ``w_ib^b`` [rad/s], same sampling as ``f_b``.
    speed : (B, N) [m/s].
    heading : (B, N) heading psi relative to north of the start frame L [rad], in [-pi, pi).
    pitch : (B, N) pitch = flight-path angle [rad].
    engine_on : (B, N) bool.
    lat0, lon0 : (B,) start latitude / longitude [rad];  h0 : (B,) start height [m].
    imu_rate_hz : IMU rate [Hz].
    states_every : int >= 1: the states ``r_e``, ``v_e``, ``C_eb`` were formed at every ``states_every``-th sample
        only (``generate_truth(..., states_every=s)``: what an env reads, sample 0 and the GNSS epochs). With
        s > 1 those three fields are None and the states are in ``coarse``; read them with :meth:`take`.
    coarse : :class:`TruthAt` at the samples ``0, s, 2 s, ...`` when ``states_every`` = s > 1, else None.
    """

    t: np.ndarray
    r_e: np.ndarray
    v_e: np.ndarray
    C_eb: np.ndarray
    f_b: np.ndarray
    w_b: np.ndarray
    speed: np.ndarray
    heading: np.ndarray
    pitch: np.ndarray
    engine_on: np.ndarray
    lat0: np.ndarray
    lon0: np.ndarray
    h0: np.ndarray
    imu_rate_hz: float
    states_every: int = 1
    coarse: TruthAt | None = None

    @property
    def batch_size(self) -> int:
        """B."""
        return self.speed.shape[0]

    @property
    def dt(self) -> float:
        """IMU sample interval [s]."""
        return 1.0 / self.imu_rate_hz

    def take(self, idx) -> TruthAt:
        """Truth (r_e, v_e, C_eb, speed, heading) at sample indices ``idx`` (M,) int (negative ones count from
        the end). A truth with ``states_every`` = s > 1 has its states only at the multiples of s: any other
        index is refused."""
        idx = np.asarray(idx)
        if idx.ndim != 1 or not np.issubdtype(idx.dtype, np.integer):
            raise ValueError(f"idx must be a 1-D integer array, got shape {idx.shape} dtype {idx.dtype}")
        n = self.t.shape[0]
        if idx.size and (idx.min() < -n or idx.max() >= n):
            raise ValueError(f"idx out of range for N = {n} samples")
        k = np.where(idx < 0, idx + n, idx)
        src, j = self, k
        if self.coarse is not None:                         # the states at the multiples of s only
            s = self.states_every
            off = np.flatnonzero(k % s)
            if off.size:
                raise ValueError(f"this truth holds its states only at the samples that are multiples of {s} "
                                 f"(states_every={s}); sample {int(k[off[0]])} is not one")
            src, j = self.coarse, k // s
        pick = _picker(j)
        return TruthAt(src.t[j], pick(src.r_e), pick(src.v_e), pick(src.C_eb), pick(src.speed), pick(src.heading))

    def stationary(self, threshold_mps: float = 0.05) -> np.ndarray:
        """(B, N) bool: true speed below ``threshold_mps`` [m/s] (the ZUPT label)."""
        if isinstance(threshold_mps, bool) or not isinstance(threshold_mps, (int, float, np.integer, np.floating)) \
                or not math.isfinite(threshold_mps) or threshold_mps < 0:
            raise ValueError(f"threshold_mps must be a finite number >= 0, got {threshold_mps!r}")
        return self.speed < threshold_mps


def _picker(j: np.ndarray):
    """``a -> a[:, j]`` for the sample indices ``j`` (M,) >= 0, a new array (a copy, never a view): for evenly
    spaced ascending ``j`` (the GNSS epochs) a C-contiguous copy of the slice, ~3x faster than numpy's gather
    along axis 1 (used for the other index sets)."""
    if j.size > 1:
        step = int(j[1] - j[0])
        if step > 0 and np.array_equal(j, np.arange(j[0], j[0] + step * j.size, step)):
            sel = slice(int(j[0]), int(j[-1]) + 1, step)
            return lambda a: np.ascontiguousarray(a[:, sel])
    return lambda a: a[:, j]


# --------------------------------------------------------------------------- evaluation
class _Kin(NamedTuple):
    """Kinematic quantities at M points (each (M,) unless noted)."""

    tau: np.ndarray    # time since the piece start [s]
    v0: np.ndarray     # piece start speed [m/s]
    v: np.ndarray      # speed [m/s]
    i_h: np.ndarray    # indices of the points on horizontal arcs
    i_v: np.ndarray    # indices of the points on vertical arcs
    psi_h: np.ndarray  # heading on the horizontal-arc points [rad]
    gam_v: np.ndarray  # pitch on the vertical-arc points [rad]
    cpsi: np.ndarray   # cos/sin of heading and pitch
    spsi: np.ndarray
    cgam: np.ndarray
    sgam: np.ndarray


class _Pieces(NamedTuple):
    """The pieces of the U evaluated rows back to back (P in all, row by row) with their frame constants.

    Per piece (leading size P) unless noted; the frame constants are those of the piece start
    (valid on the whole of a straight piece).
    """

    pl: _Plan           # the rows' plans concatenated (times from each row's own start)
    row: np.ndarray     # (P,) row of the piece
    last: np.ndarray    # (P,) bool: the row's last (open-ended) piece
    rate: np.ndarray    # (P,) turning rate of an arc: w (horizontal arcs), else q [rad/s]
    trig: np.ndarray    # (P, 4) cos/sin of the start heading and pitch (columns cpsi, spsi, cgam, sgam)
    re0: np.ndarray     # (P, 3) piece start position, ECEF [m]
    xe: np.ndarray      # (P, 3) body x axis (direction of motion), ECEF
    C_eb: np.ndarray    # (P, 3, 3) attitude at the piece start
    wb: np.ndarray      # (P, 3) Earth rate in the body at the piece start [rad/s]
    psi0w: np.ndarray   # (P,) piece start heading wrapped to [-pi, pi)
    C_eL: np.ndarray    # (U, 3, 3) per row: L (NED at the start) -> ECEF
    r0: np.ndarray      # (U, 3) per row: start point, ECEF [m]
    wND: np.ndarray     # (U, 2) per row: Earth rate in L, north and down [rad/s] (east is 0)


def _wrap(a):
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def _plan_of(tables: Sequence[np.ndarray]) -> _Plan:
    """The :class:`_Plan` of the motions' tables (:func:`_compile`, (P_u, 12) each) back to back: one contiguous
    array per field, and the cos / sin of the start headings and pitches over all the pieces at once (numpy's
    elementwise cos and sin: the same values as for each motion's pieces alone)."""
    tab = np.concatenate(tables) if len(tables) > 1 else tables[0]
    col = lambda j: np.ascontiguousarray(tab[:, j])  # noqa: E731
    psi0, gam0 = col(7), col(9)
    return _Plan(col(0), tab[:, 1].astype(np.int8), np.ascontiguousarray(tab[:, 2:5]), col(5), col(6), psi0, col(8),
                 gam0, col(10), tab[:, 11] != 0.0, np.cos(psi0), np.sin(psi0), np.cos(gam0), np.sin(gam0))


def _pieces(tables: Sequence[np.ndarray], C_eL, r0, wL) -> _Pieces:
    """Concatenate the U rows' plans (the motions' tables, :func:`_plan_of`) and add the per-piece frame
    constants (C_eL (U, 3, 3), r0 (U, 3), wL (U, 3)).

    The products whose rounding could depend on the array shapes (a BLAS product with the row's piece count
    as a dimension) are formed row by row, exactly as for a row alone; the stacked 3 x 3 products, the Earth
    rate in the body (``C_bL omega_ie_L``, summed in the order of the index: numpy's ``einsum`` of a row alone
    gives the same bits) and the elementwise terms are formed once for all rows.
    """
    pl = _plan_of(tables)
    counts = [tab.shape[0] for tab in tables]
    row = np.repeat(np.arange(len(tables)), counts)
    last = np.zeros(row.shape[0], bool)
    last[np.cumsum(counts) - 1] = True
    C_Lb = dcm_from_euler(0.0, pl.gam0, pl.psi0)                  # (P, 3, 3)
    C_eb = C_eL[row] @ C_Lb
    re0 = np.empty((row.shape[0], 3))
    a = 0
    for u in range(len(tables)):
        b = a + counts[u]
        re0[a:b] = r0[u] + pl.p0[a:b] @ C_eL[u].T
        a = b
    wr = wL[row]
    wb = np.zeros((row.shape[0], 3))                               # C_bL omega_ie_L, from +0 as einsum sums
    wb += C_Lb[:, 0, :] * wr[:, 0:1]
    wb += C_Lb[:, 1, :] * wr[:, 1:2]
    wb += C_Lb[:, 2, :] * wr[:, 2:3]
    return _Pieces(pl, row, last, np.where(pl.kind == _HARC, pl.w, pl.q),
                   np.stack([pl.cpsi, pl.spsi, pl.cgam, pl.sgam], axis=1), re0,
                   np.ascontiguousarray(C_eb[:, :, 0]), C_eb, wb, _wrap(pl.psi0), C_eL, r0,
                   np.ascontiguousarray(wL[:, ::2]))


def _kin(pl: _Plan, t, pid) -> _Kin:
    """Speed and heading/pitch trigonometry at times ``t`` (M,) on pieces ``pid`` (M,)."""
    gat = lambda x: x[pid]  # noqa: E731
    tau = t - gat(pl.t0)
    v0 = gat(pl.v0)
    v = gat(pl.acc)
    v *= tau
    v += v0
    kind = gat(pl.kind)
    cpsi, spsi, cgam, sgam = gat(pl.cpsi), gat(pl.spsi), gat(pl.cgam), gat(pl.sgam)
    i_h = np.flatnonzero(kind == _HARC)
    ph = pid[i_h]
    psi_h = pl.psi0[ph] + pl.w[ph] * tau[i_h]
    cpsi[i_h], spsi[i_h] = np.cos(psi_h), np.sin(psi_h)
    i_v = np.flatnonzero(kind == _VARC)
    pv = pid[i_v]
    gam_v = pl.gam0[pv] + pl.q[pv] * tau[i_v]
    cgam[i_v], sgam[i_v] = np.cos(gam_v), np.sin(gam_v)
    return _Kin(tau, v0, v, i_h, i_v, psi_h, gam_v, cpsi, spsi, cgam, sgam)


def _arc_positions(pl: _Plan, pid, k: _Kin, out) -> None:
    """Write the position in L [m] at the arc points ``k.i_h``, ``k.i_v`` into ``out`` (M, 3) (closed forms of the
    module docstring)."""
    i, pp = k.i_h, pid[k.i_h]                                       # horizontal arcs
    R = k.v[i] * k.cgam[i] / pl.w[pp]
    ph = pl.p0[pp]
    ph[:, 0] += R * (k.spsi[i] - pl.spsi[pp])
    ph[:, 1] -= R * (k.cpsi[i] - pl.cpsi[pp])
    ph[:, 2] -= k.v[i] * k.sgam[i] * k.tau[i]
    out[i] = ph
    i, pp = k.i_v, pid[k.i_v]                                       # vertical arcs
    Rv = k.v[i] / pl.q[pp]
    d = Rv * (k.sgam[i] - pl.sgam[pp])
    pv = pl.p0[pp]
    pv[:, 0] += d * k.cpsi[i]
    pv[:, 1] += d * k.spsi[i]
    pv[:, 2] += Rv * (k.cgam[i] - pl.cgam[pp])
    out[i] = pv


def _positions(pl: _Plan, t, pid) -> np.ndarray:
    """Position in L (NED) [m] at times ``t`` (M,) on pieces ``pid`` (M,), shape (M, 3)."""
    k = _kin(pl, t, pid)
    s = k.v0 + k.v
    s *= 0.5 * k.tau                                                # straight: s = tau (v0 + v) / 2
    cg = k.cgam * s
    out = pl.p0[pid]
    out[:, 0] += cg * k.cpsi
    out[:, 1] += cg * k.spsi
    out[:, 2] -= s * k.sgam
    _arc_positions(pl, pid, k, out)
    return out


def _arc_kin(pl: _Plan, t, pid):
    """:func:`_kin` at points that all lie on arcs (times ``t`` (m,), pieces ``pid`` (m,)), and the cos and sin of
    each point's turning angle (heading on horizontal arcs, pitch on vertical ones): the compiled kernels' arc
    input, so that the kernels use numpy's cos and sin."""
    k = _kin(pl, t, pid)
    c, s = k.cgam.copy(), k.sgam.copy()
    c[k.i_h], s[k.i_h] = k.cpsi[k.i_h], k.spsi[k.i_h]
    return k, c, s


# The compiled kernels below evaluate the closed forms point by point in the order of operations of numpy's
# elementwise evaluation (no fastmath: the same roundings); the cos/sin of arc angles are the C library's, which
# numpy's float64 cos and sin are (the node pass forms them; :func:`_imu_points` takes numpy's, :func:`_arc_kin`).
# Their helpers take scalars: passing arrays into a helper call costs reference counting on every point.
@nb.njit(cache=True)
def _gravity_at(tk, u, gA, dgA, inv_h):
    """Gravity in L [m/s^2] (three scalars) at time ``tk`` of row ``u``: linear interpolation on the anchor grid
    (``gA`` (U, 3, A) at the anchors, ``dgA`` (U, 3, A - 1) their differences, ``inv_h`` the inverse spacing)."""
    x = tk * inv_h
    j = min(int(x), dgA.shape[2] - 1)
    x -= j
    return dgA[u, 0, j] * x + gA[u, 0, j], dgA[u, 1, j] * x + gA[u, 1, j], dgA[u, 2, j] * x + gA[u, 2, j]


@nb.njit(cache=True, inline="always")
def _point_at(tau, kind, v0, acc, rate, cpsi, spsi, cgam, sgam, arc_c, arc_s, wb0, wb1, wb2, wN, wD, gN, gE, gD):
    """Speed, cos/sin of heading and pitch, and the instantaneous ideal IMU (f_b, w_ib^b) at time ``tau`` into a
    piece (all scalars).

    Piece constants: ``kind``, start speed ``v0``, acceleration ``acc``, arc rate ``rate`` (yaw or pitch),
    the start cos/sin of heading and pitch, the Earth rate in the body ``wb0..2`` (straight pieces); on an
    arc ``arc_c``, ``arc_s`` are the cos/sin of the turning angle at the point. Row constants: the Earth rate
    in L, north ``wN`` and down ``wD``; gravity in L ``gN, gE, gD`` at the point.

    With no sideslip ``v_b = [v, 0, 0]`` and ``a_b = C_bL a_L = [a, v psi_dot cos g, -v g_dot]``,
    so ``f_b = a_b + 2 omega_b x v_b - g_b`` (the module docstring's
    ``C_be (a_e + 2 Omega v_e - g_e)`` resolved in the body) and ``w_ib^b = w_Lb^b + omega_b``,
    ``omega_b = C_bL omega_ie_L``.
    """
    v = acc * tau + v0
    cp, sp, cg, sg = cpsi, spsi, cgam, sgam
    if kind == _HARC:
        cp, sp = arc_c, arc_s
    elif kind == _VARC:
        cg, sg = arc_c, arc_s
    if kind == _STRAIGHT:                                           # Earth rate in the body (piece constant)
        w0, w1, w2 = wb0, wb1, wb2
    else:                                                           # arcs: C_bL [wN, 0, wD] at the current attitude
        w0 = cg * cp * wN - sg * wD
        w1 = -sp * wN
        w2 = sg * cp * wN + cg * wD
    # -g_b = -C_bL g_L; rows of C_bL: x_b=[cg cp, cg sp, -sg], y_b=[-sp, cp, 0], z_b=[sg cp, sg sp, cg]
    hN = cp * gN + sp * gE
    f0 = sg * gD - cg * hN + acc
    f1 = sp * gN - cp * gE
    f2 = -(sg * hN + cg * gD)
    v2 = 2.0 * v
    f1 += v2 * w2                                                   # Coriolis 2 omega_b x [v, 0, 0]
    f2 -= v2 * w1
    if kind == _HARC:                                               # turn: centripetal + yaw rate
        f1 += v * rate * cg
        w0 -= rate * sg
        w2 += rate * cg
    elif kind == _VARC:                                             # pitch arc: normal acceleration + pitch rate
        f2 -= v * rate
        w1 += rate
    return v, f0, f1, f2, w0, w1, w2


@nb.njit(cache=True)
def _imu_points(t, pid, arc_c, arc_s, pc, gA, dgA, inv_h, f, w):
    """Instantaneous ideal IMU at times ``t`` (M,) on pieces ``pid`` (M,) into ``f``, ``w`` (M, 3).

    ``arc_c``, ``arc_s``: the turning angle's cos/sin at the points on arcs, in point order (:func:`_arc_kin`).
    """
    t0, v0, acc, kind, trig, rate, row, wb, wND = (pc.pl.t0, pc.pl.v0, pc.pl.acc, pc.pl.kind, pc.trig, pc.rate,
                                                   pc.row, pc.wb, pc.wND)
    j = 0
    for i in range(t.shape[0]):
        p = pid[i]
        u = row[p]
        kd = kind[p]
        ac = sc = 0.0
        if kd != _STRAIGHT:
            ac, sc = arc_c[j], arc_s[j]
            j += 1
        gN, gE, gD = _gravity_at(t[i], u, gA, dgA, inv_h)
        _, f[i, 0], f[i, 1], f[i, 2], w[i, 0], w[i, 1], w[i, 2] = _point_at(
            t[i] - t0[p], kd, v0[p], acc[p], rate[p], trig[p, 0], trig[p, 1], trig[p, 2], trig[p, 3], ac, sc,
            wb[p, 0], wb[p, 1], wb[p, 2], wND[u, 0], wND[u, 1], gN, gE, gD)


@nb.njit(cache=True, inline="always")
def _arc_angle(tau, kind, p, psi0, gam0, rate):
    """The turning angle at time ``tau`` into arc piece ``p``: the heading ``psi0 + w tau`` on a horizontal arc,
    the pitch ``gam0 + q tau`` on a vertical one (the operations of :func:`_kin`)."""
    if kind == _HARC:
        return psi0[p] + rate[p] * tau
    return gam0[p] + rate[p] * tau


@nb.njit(cache=True, nogil=True)
def _node_kernel(t, dtk, pn, simpson, pc, gA, dgA, inv_h, r, ve, C, speed, heading, pitch, engine, fo, wo, se,
                 u0, u1):
    """One pass over the grid nodes of rows ``u0 .. u1 - 1`` of the U x N grid (``pn`` (U N,) their pieces).

    Writes speed, engine_on, heading (wrapped to [-pi, pi)) and pitch everywhere, and r_e, v_e, C_eb on the
    straight pieces at the nodes ``k`` that are multiples of ``se`` (into index ``k // se`` of ``r``, ``ve``,
    ``C``; the arcs' states are numpy's, :func:`_arc_node_states`); and the
    IMU outputs ``fo``, ``wo`` (U, N, 3): the instantaneous value at node 0, and the mean over each interval
    that lies on one piece: the trapezoid of the node values on a straight piece (= Simpson there), Simpson
    with the midpoint value on an arc, or everywhere with ``simpson`` (gravity with kinks inside intervals).
    The intervals at segment boundaries get the trapezoid as a placeholder (:func:`_split_means`).
    On an arc the turning angle at the node and at the interval's midpoint (:func:`_arc_angle`) and their cos
    and sin are formed here, as :func:`_kin` forms them (numpy's float64 cos and sin are the C library's, which
    these calls are: the same bits). Rows are independent: any split into row ranges gives the same bits, and
    the kernel releases the GIL (:func:`_node_rows` runs row ranges on threads).
    """
    t0, v0, acc, kind, trig, rate, wb, wND = (pc.pl.t0, pc.pl.v0, pc.pl.acc, pc.pl.kind, pc.trig, pc.rate, pc.wb,
                                              pc.wND)
    eng, gam0, psi0, psi0w, xe, re0, C_eb = (pc.pl.engine, pc.pl.gam0, pc.pl.psi0, pc.psi0w, pc.xe, pc.re0,
                                             pc.C_eb)
    n = speed.shape[1]
    a0 = a1 = a2 = b0 = b1 = b2 = 0.0
    for u in range(u0, u1):
        ks = 0                                                      # the row's next stored state, at node ks se
        for k in range(n):
            p = pn[u * n + k]
            kd = kind[p]
            tau = t[k] - t0[p]
            ac = sc = 0.0
            if kd != _STRAIGHT:
                ang = _arc_angle(tau, kd, p, psi0, gam0, rate)
                ac, sc = np.cos(ang), np.sin(ang)
            gN, gE, gD = _gravity_at(t[k], u, gA, dgA, inv_h)
            v, f0, f1, f2, w0, w1, w2 = _point_at(
                tau, kd, v0[p], acc[p], rate[p], trig[p, 0], trig[p, 1], trig[p, 2], trig[p, 3], ac, sc,
                wb[p, 0], wb[p, 1], wb[p, 2], wND[u, 0], wND[u, 1], gN, gE, gD)
            speed[u, k] = v
            engine[u, k] = eng[p]
            if kd == _HARC:
                heading[u, k] = (ang + math.pi) % (2.0 * math.pi) - math.pi     # _wrap
            else:
                heading[u, k] = psi0w[p]
            pitch[u, k] = ang if kd == _VARC else gam0[p]
            if k == ks * se:                                        # a stored state's node (no division)
                if kd == _STRAIGHT:
                    s = (v0[p] + v) * (0.5 * tau)                   # straight: s = tau (v0 + v) / 2
                    for c in range(3):
                        r[u, ks, c] = xe[p, c] * s + re0[p, c]
                        ve[u, ks, c] = xe[p, c] * v
                        for d in range(3):
                            C[u, ks, c, d] = C_eb[p, c, d]
                ks += 1
            if k == 0:
                fo[u, 0, 0], fo[u, 0, 1], fo[u, 0, 2] = f0, f1, f2
                wo[u, 0, 0], wo[u, 0, 1], wo[u, 0, 2] = w0, w1, w2
            elif pn[u * n + k - 1] == p and (simpson or kd != _STRAIGHT):    # Simpson with the midpoint value
                tm = 0.5 * (t[k - 1] + t[k])
                ac = sc = 0.0
                if kd != _STRAIGHT:
                    ang = _arc_angle(tm - t0[p], kd, p, psi0, gam0, rate)
                    ac, sc = np.cos(ang), np.sin(ang)
                gN, gE, gD = _gravity_at(tm, u, gA, dgA, inv_h)
                _, m0, m1, m2, n0, n1, n2 = _point_at(
                    tm - t0[p], kd, v0[p], acc[p], rate[p], trig[p, 0], trig[p, 1], trig[p, 2], trig[p, 3], ac, sc,
                    wb[p, 0], wb[p, 1], wb[p, 2], wND[u, 0], wND[u, 1], gN, gE, gD)
                e, d = dtk[k - 1] / 6.0, dtk[k - 1]
                fo[u, k, 0] = (a0 + f0 + 4.0 * m0) * e / d
                fo[u, k, 1] = (a1 + f1 + 4.0 * m1) * e / d
                fo[u, k, 2] = (a2 + f2 + 4.0 * m2) * e / d
                wo[u, k, 0] = (b0 + w0 + 4.0 * n0) * e / d
                wo[u, k, 1] = (b1 + w1 + 4.0 * n1) * e / d
                wo[u, k, 2] = (b2 + w2 + 4.0 * n2) * e / d
            else:                                                   # trapezoid (= Simpson on straight pieces)
                h, d = 0.5 * dtk[k - 1], dtk[k - 1]
                fo[u, k, 0], fo[u, k, 1], fo[u, k, 2] = (a0 + f0) * h / d, (a1 + f1) * h / d, (a2 + f2) * h / d
                wo[u, k, 0], wo[u, k, 1], wo[u, k, 2] = (b0 + w0) * h / d, (b1 + w1) * h / d, (b2 + w2) * h / d
            a0, a1, a2, b0, b1, b2 = f0, f1, f2, w0, w1, w2


def _arc_node_states(pc: _Pieces, ia, p, t, out: dict, se: int = 1) -> None:
    """Write r_e, v_e, C_eb at the arc nodes ``ia`` (m,) whose states are stored (global node indices ``u N + k``
    of the U x N grid ``t`` (N,), each ``k`` a multiple of ``se``; pieces ``p``; kinematics by :func:`_kin`) into
    ``out`` at the state index ``u ((N - 1) // se + 1) + k // se`` (the heading and pitch on arcs come from the
    node pass, :func:`_node_kernel`).

    ``r_e = r0_e + C_eL p_L`` is formed row by row with the row's stored arc nodes in the order (horizontal,
    vertical) of a row alone: the BLAS product's rounding may depend on its row count (``test_trajectory``
    checks the same bits as every node's states).
    """
    flat = lambda name: out[name].reshape((-1,) + out[name].shape[2:])  # noqa: E731
    n = t.shape[0]
    k = _kin(pc.pl, t[ia % n], p)
    ia = ia // n * ((n - 1) // se + 1) + ia % n // se
    U = pc.C_eL.shape[0]
    ca, sa, cb, sb = k.cgam, k.sgam, k.cpsi, k.spsi
    C_Lb = np.empty((ia.size, 3, 3))
    C_Lb[:, 0, 0], C_Lb[:, 1, 0], C_Lb[:, 2, 0] = ca * cb, ca * sb, -sa
    C_Lb[:, 0, 1], C_Lb[:, 1, 1], C_Lb[:, 2, 1] = -sb, cb, 0.0
    C_Lb[:, 0, 2], C_Lb[:, 1, 2], C_Lb[:, 2, 2] = sa * cb, sa * sb, ca
    rows = pc.row[p]
    Ca = pc.C_eL[rows] @ C_Lb
    pa = np.empty((ia.size, 3))
    _arc_positions(pc.pl, p, k, pa)
    order = np.lexsort((pc.pl.kind[p], rows))                     # by row, then horizontal before vertical
    pa, rows = pa[order], rows[order]
    r = np.empty((ia.size, 3))
    bounds = np.searchsorted(rows, np.arange(U + 1))
    for u in np.flatnonzero(np.diff(bounds)):
        a, b = bounds[u], bounds[u + 1]
        r[a:b] = pa[a:b] @ pc.C_eL[u].T + pc.r0[u]
    flat("C_eb")[ia] = Ca
    flat("v_e")[ia] = Ca[:, :, 0] * k.v[:, None]
    flat("r_e")[ia[order]] = r


@nb.njit(cache=True)
def _boundary_means(u, k, t, dtk, left, mid, qi, last, bi, endB, o, FE, WE, fo, wo):
    """Write the means of the intervals at segment boundaries (:func:`_split_means`) into ``fo``, ``wo`` (U, N, 3).

    Intervals ``(t_k, t_k+1]`` of rows ``u`` (Q,) in global order; ``FE``, ``WE`` (M, 3): the IMU at the points
    of :func:`_split_means`, in blocks ``o``: start nodes, end nodes, left values at boundary nodes (interval
    ``left`` >= 0), right and left values at the boundaries inside intervals (``qi``, ``bi``, ``last``, ``endB``
    of each, in interval order), midpoints of the first parts, of the other parts, of the intervals on one arc
    (``mid`` >= 0). The same operations in the same order as the numpy rule they replace: trapezoid,
    Simpson, or the split intervals' parts summed from 0.0 in order (first part, then the others).
    """
    nb_ = qi.shape[0]
    ib = 0                                                          # next boundary inside an interval
    nfirst = 0                                                      # split intervals done
    for iq in range(u.shape[0]):
        d = dtk[k[iq]]
        q = qi[ib] if ib < nb_ else -1
        split = q == u[iq] * dtk.shape[0] + k[iq]
        for E, out in ((FE, fo), (WE, wo)):
            for c in range(3):
                Fa = E[o[0] + iq, c]
                Fe = E[o[2] + left[iq], c] if left[iq] >= 0 else E[o[1] + iq, c]
                if split:
                    SA = (Fa + 4.0 * E[o[5] + nfirst, c] + E[o[4] + ib, c]) * ((bi[ib] - t[k[iq]]) / 6.0)
                    SB = 0.0
                    jb = ib
                    while jb < nb_ and qi[jb] == q:
                        endv = Fe if last[jb] else E[o[4] + jb + 1, c]
                        SB += (E[o[3] + jb, c] + 4.0 * E[o[6] + jb, c] + endv) * ((endB[jb] - bi[jb]) / 6.0)
                        jb += 1
                    S = (0.0 + SA) + SB
                elif mid[iq] >= 0:
                    S = (Fa + Fe + 4.0 * E[o[7] + mid[iq], c]) * (d / 6.0)
                else:
                    S = (Fa + Fe) * (0.5 * d)
                out[u[iq], k[iq] + 1, c] = S / d
        if split:
            while ib < nb_ and qi[ib] == q:
                ib += 1
            nfirst += 1


def _split_means(pc: _Pieces, t, dtk, starts, pn, grav, linear_gravity: bool, out: dict) -> None:
    """The IMU means of the intervals at segment boundaries, in ``out`` f_b, w_b (over the kernel's placeholder).

    * an interval ending on a node where a piece starts: the end value is the left-hand one (of the piece
      that ends there); trapezoid on a straight piece, Simpson with the midpoint value on an arc (or
      everywhere when gravity has kinks inside intervals);
    * an interval holding segment boundaries: split there, Simpson on each part with the one-sided end
      values of the part's own piece.

    Global indices: node ``g = u N + k``, interval ``q = u (N - 1) + k`` for ``(t_k, t_k+1]`` of row ``u``.
    """
    pl = pc.pl
    n = t.shape[0]
    U = pc.C_eL.shape[0]
    m = n - 1
    # segment boundaries inside the episode: on a node, or strictly inside an interval
    jb = np.flatnonzero(~np.roll(pc.last, 1) & (pl.t0 <= t[-1]))   # pieces that start a row are not boundaries
    tb = pl.t0[jb]
    on = t[starts[jb]] == tb
    jo, ko = jb[on], starts[jb[on]]                                # piece starting on node ko ...
    qo = pc.row[jo] * m + ko - 1                                   # ... the end of interval qo
    ji, bi = jb[~on], tb[~on]                                      # piece starting strictly inside ...
    qi_k = starts[ji] - 1
    qi = pc.row[ji] * m + qi_k                                     # ... interval qi
    first = np.ones(ji.size, bool)
    first[1:] = qi[1:] != qi[:-1]                                  # first boundary of its interval
    last = np.ones(ji.size, bool)
    last[:-1] = qi[:-1] != qi[1:]
    special = np.zeros(U * m, bool)
    special[qi] = True
    redo = special.copy()                                          # every interval to redo
    redo[qo] = True
    Q = np.flatnonzero(redo)
    # intervals ending on a boundary node that need a midpoint value: on an arc piece (or all when gravity has
    # kinks inside intervals); the other intervals on one piece are the kernel's
    qa = qo[~special[qo]]
    if linear_gravity:
        qa = qa[pl.kind[pn[qa + qa // m]] != _STRAIGHT]
    gs = Q + Q // m                                                # its start node
    kQ = Q % m
    # sub-intervals of the split intervals: [t_q, b_first] (type A), [b_i, next] (type B)
    qA_k, jA = qi_k[first], ji[first]
    endB = np.where(last, t[np.minimum(qi_k + 1, m)], np.append(bi[1:], 0.0))
    # one evaluation for all the points: the ends of the intervals redone, left values at boundary nodes,
    # both sides of the boundaries inside intervals, midpoints
    te = np.concatenate([t[kQ], t[kQ + 1], t[ko], bi, bi, 0.5 * (t[qA_k] + bi[first]), 0.5 * (bi + endB),
                         0.5 * (t[qa % m] + t[qa % m + 1])])
    pe = np.concatenate([pn[gs], pn[gs + 1], jo - 1, ji, ji - 1, jA - 1, ji, pn[qa + qa // m]])
    o = np.cumsum([0, Q.size, Q.size, ko.size, ji.size, ji.size, jA.size, ji.size, qa.size])
    on_arc = np.flatnonzero(pl.kind[pe] != _STRAIGHT)
    _, arc_c, arc_s = _arc_kin(pl, te[on_arc], pe[on_arc])
    FE, WE = np.empty((te.size, 3)), np.empty((te.size, 3))
    _imu_points(te, pe, arc_c, arc_s, pc, *grav, FE, WE)
    left = np.full(Q.size, -1)                                     # per interval redone: its left value ...
    left[np.searchsorted(Q, qo)] = np.arange(qo.size)
    mid = np.full(Q.size, -1)                                      # ... and its midpoint value, if any
    mid[np.searchsorted(Q, qa)] = np.arange(qa.size)
    _boundary_means(Q // m, kQ, t, dtk, left, mid, qi, last, bi, endB, o, FE, WE, out["f_b"], out["w_b"])


def _grid_pieces(pc: _Pieces, t):
    """The pieces on a time grid ``t`` (N,) shared by the U rows of ``pc``: the first grid index of each piece
    in its row (P,), the number of grid points on it (P,), and the piece of each point (U N,) (right-continuous:
    the last piece starting at or before the point)."""
    n = t.shape[0]
    starts = np.searchsorted(t, pc.pl.t0)
    ends = np.append(starts[1:], n)
    ends[pc.last] = n
    cnt = ends - starts
    return starts, cnt, np.repeat(np.arange(starts.shape[0]), cnt)


def _node_rows(args, U: int, workers: int | None = None) -> None:
    """:func:`_node_kernel` over the U rows, in row ranges on ``workers`` threads (default ``min(os.cpu_count(),
    8)``; dynamic: a thread takes the next range when it is done, so a busy core costs only its share).

    ``args``: the kernel's arguments up to ``se``. The same bits as one call over all rows (rows are independent).
    """
    run_row_ranges(lambda u0, u1: _node_kernel(*args, u0, u1), U, workers)


def _evaluate(pc: _Pieces, t, grav, linear_gravity: bool, out: dict, workers: int | None = None, se: int = 1) -> None:
    """Write all outputs of the U rows of ``pc`` on the grid ``t`` (N,) into ``out``, the (U, N, ...) arrays of
    :class:`Truth` by name (C-contiguous rows; :func:`_truth_outputs`), the states r_e, v_e, C_eb only at every
    ``se``-th node ((U, (N - 1) // se + 1, ...)); ``workers``: the node pass's threads (:func:`_node_rows`).

    States and instantaneous IMU at the grid nodes; IMU means over the intervals ``(t_{k-1}, t_k]`` by
    Simpson's rule on each smooth sub-interval:

    * an interval on one straight piece: the integrand is linear in t there
      (constant attitude, linear speed, gravity interpolated linearly between
      anchors that are nodes), so Simpson equals the trapezoid of the end values;
    * an interval on one arc: Simpson with the analytic midpoint value;
    * an interval holding segment boundaries: split there, Simpson on each part
      with the one-sided end values of the part's own piece.
    """
    n = t.shape[0]
    U = pc.C_eL.shape[0]
    pl = pc.pl
    starts, cnt, pn = _grid_pieces(pc, t)
    arcs = np.flatnonzero((pl.kind != _STRAIGHT) & (cnt > 0))
    c = cnt[arcs]
    ia = np.repeat(pc.row[arcs] * n + starts[arcs] - (np.cumsum(c) - c), c) + np.arange(c.sum())  # arc nodes
    if se > 1:
        ia = ia[ia % n % se == 0]                                  # those whose states are stored
    pa = pn[ia]
    dtk = np.diff(t)
    node_args = ((t, dtk, pn, not linear_gravity, pc, *grav, out["r_e"], out["v_e"], out["C_eb"], out["speed"],
                  out["heading"], out["pitch"], out["engine_on"], out["f_b"], out["w_b"], se), U, workers)
    if ia.size and U >= OVERLAP_ROWS:   # the node pass (off the arcs' states) beside the arcs' states (numpy)
        with ThreadPoolExecutor(max_workers=1) as ex:
            pending = ex.submit(_node_rows, *node_args)
            _arc_node_states(pc, ia, pa, t, out, se)
            pending.result()
    else:
        _node_rows(*node_args)
        if ia.size:
            _arc_node_states(pc, ia, pa, t, out, se)
    _split_means(pc, t, dtk, starts, pn, grav, linear_gravity, out)


_TRUTH_FIELDS = (("r_e", (3,)), ("v_e", (3,)), ("C_eb", (3, 3)), ("f_b", (3,)), ("w_b", (3,)), ("speed", ()),
                 ("heading", ()), ("pitch", ()), ("engine_on", ()))


_STATE_FIELDS = ("r_e", "v_e", "C_eb")


def _truth_outputs(U: int, n: int, dtype, buffers=None, se: int = 1) -> dict:
    """The (U, n, ...) output arrays of :class:`Truth` by name, the states' (U, (n - 1) // se + 1, ...) (from
    ``buffers``, :class:`envs.sim.buffers.WorldBuffers`, when given)."""
    ns = (n - 1) // se + 1
    return {key: empty(buffers, f"truth.{key}", (U, ns if key in _STATE_FIELDS else n) + tail,
                       bool if key == "engine_on" else dtype)
            for key, tail in _TRUTH_FIELDS}


TRUTH_RANGE_ROWS = 64
"""Fewest rows per range of :func:`generate_truth`'s row ranges on threads (from twice as many rows on): each range
runs the stage's numpy part (the pieces, the exact gravity on the anchor grid, the arc nodes' states) on its own
rows, so the threads overlap where numpy releases the GIL; a range pays the stage's fixed Python costs once."""


def _truth_rows(motions: Sequence[Motion], lat0, lon0, h0, t, rate: float, out: dict,
                workers: int | None = None, se: int = 1) -> None:
    """The truth of ``motions`` (U distinct motions, their start points ``lat0``, ``lon0`` [rad], ``h0`` [m] (U,))
    on the grid ``t`` (N,) at ``rate`` [Hz] into ``out`` (:func:`_truth_outputs` of U rows, or rows of it): each
    row depends only on its motion."""
    n = t.shape[0]
    U = len(motions)
    C_eL = C_en(lat0, lon0)                                        # (U, 3, 3)
    r0 = geodetic_to_ecef(lat0, lon0, h0)                          # (U, 3)
    wL = np.einsum("uji,j->ui", C_eL, OMEGA_IE_E)                  # C_Le omega_ie_e, (U, 3); east = 0

    pc = _pieces([m._plan for m in motions], C_eL, r0, wL)

    # exact gravity on the anchor grid, one batched call
    ta, h, on_nodes = _anchor_grid(n, rate)
    pa = _positions(pc.pl, np.tile(ta, U), _grid_pieces(pc, ta)[2]).reshape(U, ta.shape[0], 3)
    ga_e = gravity_ecef(pa @ C_eL.mT + r0[:, None, :])            # r_e = r0 + C_eL p_L
    ga_L = (ga_e @ C_eL).mT.copy()                                 # (U, 3, A): C_Le g_e
    dga_L = np.diff(ga_L, axis=-1)
    _evaluate(pc, t, (ga_L, dga_L, 1.0 / h), on_nodes, out, workers, se)


def _check_dtype(dtype):
    try:
        d = np.dtype(dtype)
    except TypeError:
        raise ValueError(f"dtype must be np.float32 or np.float64, got {dtype!r}") from None
    if d not in (np.dtype(np.float32), np.dtype(np.float64)):
        raise ValueError(f"dtype must be np.float32 or np.float64, got {dtype!r}")
    return d


def _anchor_grid(n: int, rate: float):
    """Anchor times for exact gravity: every K-th IMU node, or a refinement of the IMU grid.

    Returns the anchor times (A,), their spacing h [s] (<= GRAVITY_ANCHOR_S) and
    whether every anchor is a node (then the interpolated gravity is linear inside
    each IMU interval).
    """
    dt = 1.0 / rate
    if dt <= GRAVITY_ANCHOR_S:
        K = max(1, int(math.floor(GRAVITY_ANCHOR_S * rate + 1e-9)))
        J = -(-(n - 1) // K)
        return np.arange(J + 1) * (K / rate), K / rate, True
    M = int(math.ceil(dt / GRAVITY_ANCHOR_S - 1e-9))
    return np.arange((n - 1) * M + 1) / (rate * M), 1.0 / (rate * M), False


def generate_truth(motions: Sequence[Motion], duration_s: float, imu_rate_hz: float, dtype=np.float64,
                   buffers=None, states_every: int = 1) -> Truth:
    """Truth trajectory and ideal IMU for a batch of motions on one time grid.

    Parameters
    ----------
    motions : sequence of B :class:`Motion` (one per row).
    duration_s : episode length [s], > 0. The grid is ``t_k = k / imu_rate_hz``,
        ``k = 0 .. N-1`` with ``N = round(duration_s * imu_rate_hz) + 1``. A row whose
        segments end earlier continues at its last velocity (or at rest with its last
        engine flag); segments beyond the end are ignored.
    imu_rate_hz : IMU sample rate [Hz], > 0.
    dtype : np.float64 (default) or np.float32, the dtype of the float outputs other
        than ``t``, ``lat0``, ``lon0``, ``h0`` (float64 always); computed in float64,
        rounded once.
    buffers : :class:`envs.sim.buffers.WorldBuffers` or None: the output arrays come from it (reused from an
        earlier draw that nobody holds any more). The values do not depend on it.
    states_every : int >= 1: form the states ``r_e``, ``v_e``, ``C_eb`` only at the samples ``0, s, 2 s, ...``
        (:attr:`Truth.coarse`; the same bits as those samples of every sample's states). An env reads them
        only at sample 0 and at the GNSS epochs, every ``samples_per_epoch``-th sample; the IMU and the other
        fields are the same either way. It saves 15 of the 24 stored numbers per sample and their arithmetic.

    From ``2 TRUTH_RANGE_ROWS`` distinct motions on, the rows run in ranges on threads
    (:func:`~envs.sim.row_threads.run_row_ranges`, :data:`TRUTH_RANGE_ROWS`): each row depends only on its
    motion, so the same bits.

    Returns
    -------
    Truth
        Kinematics from the closed forms, IMU from the ECEF-mechanization relations
        of the module docstring (mean over each sample interval by split Simpson).
    """
    dtype = _check_dtype(dtype)
    if isinstance(motions, Motion) or not isinstance(motions, Sequence):
        raise ValueError(f"motions must be a sequence of Motion, got {type(motions).__name__}")
    motions = list(motions)
    if not motions:
        raise ValueError("motions must not be empty")
    for i, m in enumerate(motions):
        if not isinstance(m, Motion):
            raise ValueError(f"motions[{i}] must be a Motion, got {type(m).__name__}")
    for name, val in (("duration_s", duration_s), ("imu_rate_hz", imu_rate_hz)):
        if isinstance(val, bool) or not isinstance(val, (int, float, np.integer, np.floating)) \
                or not math.isfinite(val) or val <= 0:
            raise ValueError(f"{name} must be a finite number > 0, got {val!r}")
    if isinstance(states_every, bool) or not isinstance(states_every, (int, np.integer)) or states_every < 1:
        raise ValueError(f"states_every must be an int >= 1, got {states_every!r}")
    se = int(states_every)
    rate = float(imu_rate_hz)
    n = int(round(float(duration_s) * rate)) + 1
    if n < 2:
        raise ValueError(f"duration_s * imu_rate_hz must be >= 0.5 (at least two samples), got "
                         f"{duration_s} s * {imu_rate_hz} Hz")
    t = np.arange(n) / rate
    B = len(motions)

    # equal motions are evaluated once
    uniq: dict = {}
    row_of = [uniq.setdefault(m, len(uniq)) for m in motions]
    ums = list(uniq)
    U = len(ums)
    lat0 = np.array([m.lat0_deg for m in ums]) * DEG
    lon0 = np.array([m.lon0_deg for m in ums]) * DEG
    h0 = np.array([m.h0_m for m in ums])
    out = _truth_outputs(U, n, dtype, buffers, se)
    if U < 2 * TRUTH_RANGE_ROWS:
        _truth_rows(ums, lat0, lon0, h0, t, rate, out, se=se)
    else:   # row ranges on threads (each range's node pass on one thread beside it): the same bits
        run_row_ranges(lambda u0, u1: _truth_rows(ums[u0:u1], lat0[u0:u1], lon0[u0:u1], h0[u0:u1], t, rate,
                                                  {k: a[u0:u1] for k, a in out.items()}, 1, se),
                       U, min_rows=TRUTH_RANGE_ROWS)
    idx = np.array(row_of)
    if not np.array_equal(idx, np.arange(B)):                     # copy the rows of equal motions
        out = {key: val[idx] for key, val in out.items()}
    coarse = None
    if se > 1:
        coarse = TruthAt(t[::se], *(out.pop(key) for key in _STATE_FIELDS), out["speed"][:, ::se],
                         out["heading"][:, ::se])
        out.update(dict.fromkeys(_STATE_FIELDS))
    return Truth(t=t, lat0=lat0[idx], lon0=lon0[idx], h0=h0[idx], imu_rate_hz=rate, states_every=se, coarse=coarse,
                 **out)


# --------------------------------------------------------------------------- random drives
class SegmentPlan:
    """A segment list under construction: tracks its total duration [s] and the current speed [m/s].

    ``add(*segments)`` appends; ``change_speed(to_mps, accel_mps2)`` appends the Accelerate or Decelerate
    that reaches ``to_mps`` at ``accel_mps2`` (nothing when already there). It draws no random numbers, so
    the random drive generators keep their draw order.
    """

    def __init__(self):
        self.segments: list = []
        self.total = 0.0
        self.speed = 0.0

    def add(self, *segments):
        self.segments.extend(segments)
        self.total += sum(seg.duration_s for seg in segments)

    def change_speed(self, to_mps: float, accel_mps2: float):
        if to_mps > self.speed:
            self.add(Accelerate((to_mps - self.speed) / accel_mps2, to_mps))
        elif to_mps < self.speed:
            self.add(Decelerate((self.speed - to_mps) / accel_mps2, to_mps))
        self.speed = to_mps


def random_drive(rng: np.random.Generator, duration_s: float, style: str = "urban",
                 lat0_deg: float = 52.5096, lon0_deg: float = 13.3760, h0_m: float = 34.0,
                 heading0_deg: float | None = None) -> Motion:
    """A seeded random segment list covering at least ``duration_s``.

    Every drive starts at rest with the engine on for 5-10 s (initial alignment).

    * ``"urban"``: stop-and-go. Cruises of 5-30 s at 8-15 m/s, accelerations of
      1-2.5 m/s^2, stops of 5-40 s at lights with the engine idling, 90-degree
      turns at 10-20 deg/s (slowing to 4-7 m/s first), occasional slow creeps
      below 0.3 m/s after a stop.
    * ``"highway"``: 25-33 m/s, long cruises (20-120 s), lane-change-like
      S-manoeuvres (2-5 deg at 1-3 deg/s and back), gentle curves, speed changes
      at 0.3-1 m/s^2.
    * ``"open"``: 10-25 m/s with turns of 20-120 deg at 3-10 deg/s, small climbs
      and descents (up to 5 deg, back to level), speed changes.

    Parameters
    ----------
    rng : numpy Generator of this row (its draws depend on nothing else).
    duration_s : minimum total duration [s], > 0.
    style : one of :data:`STYLES`.
    lat0_deg, lon0_deg, h0_m : start point [deg, deg, m] (default: Berlin Potsdamer Platz).
    heading0_deg : initial heading [deg]; drawn uniformly in [0, 360) when None.

    Returns
    -------
    Motion
    """
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    if style not in STYLES:
        raise ValueError(f"style must be one of {STYLES}, got {style!r}")
    if isinstance(duration_s, bool) or not isinstance(duration_s, (int, float, np.integer, np.floating)) \
            or not math.isfinite(duration_s) or duration_s <= 0:
        raise ValueError(f"duration_s must be a finite number > 0, got {duration_s!r}")
    # U(lo, hi): numpy's uniform draw, ``lo + (hi - lo) * next_double`` (what ``rng.uniform(lo, hi)`` returns, the same
    # bits), without the cost of its argument handling
    U = lambda lo, hi: lo + (hi - lo) * rng.random()  # noqa: E731
    sign = lambda: 1.0 if rng.random() < 0.5 else -1.0  # noqa: E731
    heading = U(0.0, 360.0) if heading0_deg is None else heading0_deg
    plan = SegmentPlan()
    add, change_speed = plan.add, plan.change_speed

    add(Static(U(5.0, 10.0), True))

    if style == "urban":
        while plan.total < duration_s:
            if plan.speed == 0.0:
                if rng.random() < 0.15:              # slow creep toward the stop line, then stop again
                    change_speed(U(0.05, 0.3), U(0.1, 0.3))
                    add(Cruise(U(2.0, 6.0)))
                    change_speed(0.0, U(0.2, 0.5))
                    add(Static(U(2.0, 8.0), True))
                change_speed(U(8.0, 15.0), U(1.0, 2.5))
            add(Cruise(U(5.0, 30.0)))
            r = rng.random()
            if r < 0.35:                                 # turn at an intersection
                change_speed(U(4.0, 7.0), U(1.0, 2.5))
                add(Turn(sign() * 90.0, U(10.0, 20.0)))
                change_speed(U(8.0, 15.0), U(1.0, 2.5))
            elif r < 0.7:                                # red light, engine idling
                change_speed(0.0, U(1.0, 2.5))
                add(Static(U(5.0, 40.0), True))
            else:
                change_speed(U(8.0, 15.0), U(1.0, 2.5))
    elif style == "highway":
        change_speed(U(25.0, 33.0), U(1.5, 3.0))         # on-ramp
        while plan.total < duration_s:
            add(Cruise(U(20.0, 120.0)))
            r = rng.random()
            if r < 0.5:                                  # lane change: S-manoeuvre
                ang, rate = sign() * U(2.0, 5.0), U(1.0, 3.0)
                add(Turn(ang, rate), Cruise(U(1.0, 3.0)), Turn(-ang, rate))
            elif r < 0.8:
                change_speed(U(25.0, 33.0), U(0.3, 1.0))
            else:                                        # gentle curve
                add(Turn(sign() * U(5.0, 30.0), U(0.5, 2.0)))
    else:  # open
        change_speed(U(10.0, 25.0), U(1.0, 2.5))
        while plan.total < duration_s:
            add(Cruise(U(10.0, 60.0)))
            r = rng.random()
            if r < 0.35:
                add(Turn(sign() * U(20.0, 120.0), U(3.0, 10.0)))
            elif r < 0.65:                               # climb or descend, then back to level
                tr1, tr2 = U(2.0, 5.0), U(2.0, 5.0)
                add(Climb(sign() * U(1.0, 5.0), tr1 + U(10.0, 40.0), tr1))
                add(Climb(0.0, tr2 + U(5.0, 20.0), tr2))
            else:
                change_speed(U(10.0, 25.0), U(0.5, 2.0))
    return Motion(lat0_deg, lon0_deg, h0_m, heading, 0.0, tuple(plan.segments))
