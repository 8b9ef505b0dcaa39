"""Named scenarios: frozen presets of the whole simulated world (DESIGN.md section 4).

A :class:`Scenario` fixes everything about the world an episode is drawn from
(duration, rates, the vehicle's motion or its random-drive style, IMU grade,
vibration, receiver, GNSS degradations, initial-estimate errors); the episode
seed draws the random parts. ``get_scenario(name, **overrides)`` returns a
preset, optionally with fields replaced (validated again).

=================  ======  =========  ==================================================================
name               length  IMU        world
=================  ======  =========  ==================================================================
``open-sky``       300 s   industrial random open-road drive, clean sky
``urban``          300 s   industrial stop-and-go drive, street canyons (blockage), NLOS/multipath bursts
``outage``         300 s   industrial open-road drive, 60 s full outages at 60-120 s and 180-240 s
``noise-burst``    300 s   industrial open-road drive, true code/Doppler noise x5 for 30 s every 90 s
``seed000-sim``    60 s    seed000    seed paper 000 sec 5.1: 20 m/s, 90-deg turns at 15 s and 45 s,
                                      IMU 100 Hz, GNSS 2 Hz, 3 mg / 1 deg/h noise, Table 1 biases and
                                      initial errors
``seed003-sim``    700 s   seed003    seed paper 003 Table 1: start 36 N 100 E heading 90 deg, stationary /
                                      accelerate / decelerate / corner, outages 100-300 s and 550-650 s,
                                      re-acquisition noise (x5 decaying over 10 s) after each outage;
                                      the paper's sensor set: GNSS + odometer (0.05 % scale error) + NHC
``urban-transition`` 300 s industrial seed paper 000 sec. 5.2 setting: stop-and-go drive, open sky
                                      alternating at random with street canyon / tree cover / overpass
                                      zones; smartLoc-measured NLOS probability, bias and C/N0; re-acquisition
``noise-mismatch`` 300 s   industrial seed paper 003 setting: reported code / Doppler sigma wrong by random
                                      piecewise factors (1/4-4, 20-90 s), IMU bias steps and rough-road
                                      vibration regimes; small-atmosphere (dual-frequency) receiver
``regime-switch``  300 s   industrial Markov-switching nominal / degraded / severe noise regimes, exponential
                                      dwell times (60 / 40 / 20 s); small-atmosphere receiver
``urban-smartloc`` 300 s  industrial stop-and-go drive in a dense canyon calibrated to the smartLoc recording's
                                      channels (3 m label): NLOS share and dwell, bias, C/N0 scatter and
                                      NLOS C/N0 deficit (docs/sim-vs-real.md)
``low-noise``      300 s   industrial open-road drive, clean sky, geodetic-grade receiver (code 0.1 m, Doppler
                                      0.01 m/s, 2 cm atmosphere) whose reported sigmas are a generic
                                      model's: 8x (code) and 5x (Doppler) the true ones
=================  ======  =========  ==================================================================

Every preset reports the receiver's nominal pseudorange sigma; another variance
model of it (RTKLIB elevation, SIGMA-epsilon, Groves' elevation + C/N0;
:mod:`envs.sim.sigma_models`) is the receiver's ``sigma_model``::

    base = get_scenario("urban")
    scen = base.replace(receiver=dataclasses.replace(base.receiver, sigma_model=SigmaModel("elevation-cn0")))

The issue-16 scenarios (``urban-transition``, ``noise-mismatch``,
``regime-switch``) draw every event at random times from the episode seed
(:mod:`envs.sim.events`): no event sits at a fixed clock time. Their
parameters and sources:

* ``urban-transition``: :class:`~envs.sim.events.UrbanZones` defaults: open
  sky U(20, 60) s, then a zone (canyon 45 %, U(20, 60) s; tree cover 35 %,
  U(10, 40) s; overpass 20 %, U(2, 6) s), repeated (about 4-6 zones per 300
  s). Canyon geometry :class:`~envs.sim.canyon.UrbanCanyon` defaults (20 m
  street, 10-40 m buildings); inside zones NLOS probability ``0.88 - 0.71
  sin el``, bias log-normal (median ``16.4 m / sin el``, log-sigma 0.70, 92 %
  positive) and LOS C/N0 ``39.2 + 6.2 sin el`` dB-Hz with an 11 dB NLOS
  deficit, all measured on smartLoc Potsdamer Platz
  (:mod:`envs.datasets.smartloc_stats`); foliage loss 2-12 dB (ITU-R P.833;
  assumption); re-acquisition x5 decaying over 10 s after a loss of lock >= 1
  s. Default single-frequency receiver (the urban error dominates), GNSS 1 Hz
  as the ProPak6 of seed paper 000 sec. 5.2.1.
* ``urban-smartloc`` (issue 36): the smartLoc channels with the 3 m label of
  :mod:`agents.sim_vs_real` (its "Calibration" section): canyon zones of
  U(60, 180) s (90 %; overpasses 10 %) between U(5, 15) s of open sky; NLOS
  probability ``1.02 - 0.56 sin el`` on U(2, 6) s segments (a satellite NLOS
  now stays so a second later with probability ~0.93, smartLoc's); bias
  log-normal, median ``10.9 m / sin el``, log-sigma 0.97; C/N0 scattering by
  :class:`~envs.sim.events.Cn0Scatter` (4.5 dB about the line, smartLoc's
  autocorrelation) with an NLOS deficit of 7.2 +- 4.9 dB. Streets 40 m wide,
  blockage probability 0.5: about 7 GPS satellites per epoch against
  smartLoc's 8 (the simulator has no GLONASS; smartLoc tracks 15 with it).
* ``noise-mismatch``: :class:`~envs.sim.events.SigmaMismatch` defaults (code
  and Doppler separately: segments U(20, 90) s, honest with probability 0.2,
  else the reported sigma is the true one times a log-uniform factor in
  [1/4, 4]; seed paper 003 sec. 2.2, eqs 12-14: a measurement-noise matrix
  "subject to bias"); :class:`~envs.sim.imu.ImuEvents` defaults (gyro /
  accel bias steps 10-50 deg/h / 1-5 mg, 2 + 2 expected per 300 s: seed 003's
  "sudden alteration"; rough-road segments, 2 expected per 300 s, 10-40 s,
  vibration and white noise x2-5); receiver
  :meth:`~envs.sim.gnss.ReceiverConfig.dual_frequency` (iono 0.1 m, tropo
  0.12 m zenith, RTCA DO-229).
* ``regime-switch``: :class:`~envs.sim.events.NoiseRegimes` defaults: nominal
  (x1 code / x1 Doppler, no NLOS, mean dwell 60 s), degraded (x3 / x2.5, 5 %
  of the satellites NLOS, 40 s), severe (x8 / x6, 15 % NLOS, 20 s); first
  regime from the stationary law, next uniform over the others. The scales
  are the DLL / FLL jitter growth of a 10 dB and an 18 dB C/N0 loss
  (``10^(dB/20)``; assumption: foliage-like and deep-shadow signal loss).
  Receiver :meth:`~envs.sim.gnss.ReceiverConfig.dual_frequency`.

``low-noise`` is there to judge the adaptive laws where the innovations are
far *below* what the filter predicts: on a recorded data set with nearly
noise-free pseudoranges (reported sigma0 of metres) the Sage-Husa Q law
drifted from ~0.05 m to 1-2 m horizontal error after ~150 s while ``kf`` held
0.13 m. The receiver is :meth:`~envs.sim.gnss.ReceiverConfig.geodetic`; the
filter is given a generic stochastic model, the default receiver's zenith
0.8 m code and 0.05 m/s Doppler: a constant
:class:`~envs.sim.events.SigmaMismatch` of 8 (code, 0.8 / 0.1) and 5
(Doppler, 0.05 / 0.01) that the receiver never corrects (``p_honest = 0``;
every epoch carries the ``MISMATCH`` bit). An honest geodetic receiver
(reported = true sigma) does not show the drift (measured before the preset
was fixed, 8 development episodes x 300 s, seeds 900000-900007: every
Sage-Husa variant within 1.5 % of ``kf``'s 0.073 m); with the reported sigma
3 or 10 times the true one it does (``sage-husa`` 0.15 / 0.51 m against
``kf`` 0.08 / 0.16 m, the error growing after ~100 s). The factors are not
tuned: they are the ratio of the two receivers' sigmas.

:data:`URBAN_LIKE` names the presets whose pseudoranges carry NLOS /
multipath biases on some satellites (the measurement-noise laws must not
blame the clean ones there).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from .constellation import Constellation
from .events import (SMARTLOC3_BIAS, SMARTLOC3_P_NLOS, SMARTLOC3_SEGMENT_S, Cn0Scatter, NoiseRegimes,
                     Reacquisition, SigmaMismatch, UrbanZones)
from .gnss import GnssEvents, ReceiverConfig, UrbanCanyon
from .imu import IMU_GRADES, ImuEvents, Vibration
from .odometer import SEED003_ODOMETER, OdometerModel
from .trajectory import Accelerate, Cruise, Decelerate, Motion, Static, Turn, random_drive

DRIVE_STYLES = ("urban", "highway", "open")

GENERIC_SIGMA_MODEL = SigmaMismatch(segment_s=(300.0, 300.0), pr_factor=(8.0, 8.0), prr_factor=(5.0, 5.0),
                                    p_honest=0.0)
"""``low-noise``'s reported sigmas: the default receiver's zenith code (0.8 m) and Doppler (0.05 m/s) sigmas
over the geodetic receiver's (0.1 m, 0.01 m/s), constant (every segment draws the same factor)."""

URBAN_LIKE = ("urban", "urban-transition", "regime-switch")
"""The presets whose pseudoranges carry NLOS / multipath biases on some satellites (street canyons, urban zones,
the degraded and severe noise regimes)."""


def _finite(owner, name, value, lo=None, lo_open=False):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or not math.isfinite(value):
        raise ValueError(f"{owner}.{name} must be a finite number, got {value!r}")
    if lo is not None and (value <= lo if lo_open else value < lo):
        raise ValueError(f"{owner}.{name} must be {'>' if lo_open else '>='} {lo}, got {value!r}")


@dataclass(frozen=True)
class InitialErrors:
    """Errors of the navigator's initial estimate (and the matching initial uncertainty).

    Attributes
    ----------
    position_sigma_m : (north, east, down) one-sigma position error [m].
    velocity_sigma_mps : (north, east, down) one-sigma velocity error [m/s].
    attitude_sigma_rad : (roll, pitch, yaw) one-sigma attitude error [rad] (small angles about NED axes).
    clock_sigma_m, drift_sigma_mps : receiver clock bias [m] / drift [m/s] error of the initial
        estimate (as from a single-point solution before the filter starts).
    fixed_ecef : if True the errors are not drawn: each is exactly +sigma on the ECEF x, y, z axes
        (seed paper 000 Table 1: "dpX = dpY = dpZ = 10 m"), and the initial covariance is diagonal in ECEF.
    """

    position_sigma_m: tuple = (3.0, 3.0, 5.0)
    velocity_sigma_mps: tuple = (0.1, 0.1, 0.1)
    attitude_sigma_rad: tuple = (math.radians(0.5), math.radians(0.5), math.radians(2.0))
    clock_sigma_m: float = 10.0
    drift_sigma_mps: float = 0.5
    fixed_ecef: bool = False

    def __post_init__(self):
        for name in ("position_sigma_m", "velocity_sigma_mps", "attitude_sigma_rad"):
            v = getattr(self, name)
            if not isinstance(v, (tuple, list)) or len(v) != 3:
                raise ValueError(f"InitialErrors.{name} must be a tuple of 3 numbers, got {v!r}")
            for x in v:
                _finite("InitialErrors", name, x, lo=0.0)
            object.__setattr__(self, name, tuple(float(x) for x in v))
        _finite("InitialErrors", "clock_sigma_m", self.clock_sigma_m, lo=0.0)
        _finite("InitialErrors", "drift_sigma_mps", self.drift_sigma_mps, lo=0.0)


@dataclass(frozen=True)
class Scenario:
    """A simulated world (see the module table for the presets).

    Attributes
    ----------
    name : scenario name.
    duration_s : episode length [s].
    imu_rate_hz, gnss_rate_hz : sample rates [Hz]; the IMU rate must be an integer multiple of the GNSS rate.
    imu_grade : a key of :data:`envs.sim.imu.IMU_GRADES`.
    drive : a random-drive style (``'urban'``, ``'highway'``, ``'open'``) drawn per episode, or a fixed
        :class:`~envs.sim.trajectory.Motion` shared by every episode.
    start : (lat_deg, lon_deg, h_m) of random drives.
    vibration : vehicle vibration model (engine idle, road).
    receiver : GNSS receiver and residual errors.
    constellation : satellite constellation.
    events : GNSS degradations (outages, noise bursts, NLOS, street canyons, random events).
    imu_events : random IMU bias steps and rough-road vibration regimes, or None.
    odometer : a wheel odometer (:class:`~envs.sim.odometer.OdometerModel`) whose forward speed and the
        non-holonomic constraints every filter fuses at each GNSS epoch, also in outages; or None (GNSS only).
    initial : initial-estimate errors.
    description : one line for tables and docs.
    """

    name: str
    duration_s: float = 300.0
    imu_rate_hz: float = 100.0
    gnss_rate_hz: float = 1.0
    imu_grade: str = "industrial"
    drive: object = "open"
    start: tuple = (52.5096, 13.3760, 34.0)
    vibration: Vibration = field(default_factory=Vibration)
    receiver: ReceiverConfig = field(default_factory=ReceiverConfig)
    constellation: Constellation = field(default_factory=Constellation)
    events: GnssEvents = field(default_factory=GnssEvents)
    initial: InitialErrors = field(default_factory=InitialErrors)
    description: str = ""
    imu_events: ImuEvents | None = None
    odometer: OdometerModel | None = None

    def __post_init__(self):
        o = "Scenario"
        if not isinstance(self.name, str) or not self.name:
            raise ValueError(f"{o}.name must be a non-empty string, got {self.name!r}")
        _finite(o, "duration_s", self.duration_s, lo=0.0, lo_open=True)
        _finite(o, "imu_rate_hz", self.imu_rate_hz, lo=0.0, lo_open=True)
        _finite(o, "gnss_rate_hz", self.gnss_rate_hz, lo=0.0, lo_open=True)
        if self.gnss_rate_hz > self.imu_rate_hz:
            raise ValueError(f"{o}.gnss_rate_hz ({self.gnss_rate_hz}) must not exceed imu_rate_hz ({self.imu_rate_hz})")
        ratio = self.imu_rate_hz / self.gnss_rate_hz
        if abs(ratio - round(ratio)) > 1e-9:
            raise ValueError(f"{o}.gnss_rate_hz ({self.gnss_rate_hz}) must divide imu_rate_hz ({self.imu_rate_hz}) "
                             f"into a whole number of IMU samples per epoch")
        if self.duration_s * self.gnss_rate_hz < 1:
            raise ValueError(f"{o}.duration_s ({self.duration_s}) is shorter than one GNSS epoch")
        if self.imu_grade not in IMU_GRADES:
            raise ValueError(f"{o}.imu_grade {self.imu_grade!r} is unknown; known: {sorted(IMU_GRADES)}")
        if isinstance(self.drive, str):
            if self.drive not in DRIVE_STYLES:
                raise ValueError(f"{o}.drive {self.drive!r} is unknown; known styles: {list(DRIVE_STYLES)} or a Motion")
        elif not isinstance(self.drive, Motion):
            raise ValueError(f"{o}.drive must be a drive style or a Motion, got {type(self.drive).__name__}")
        if not (isinstance(self.start, (tuple, list)) and len(self.start) == 3):
            raise ValueError(f"{o}.start must be (lat_deg, lon_deg, h_m), got {self.start!r}")
        for x in self.start:
            _finite(o, "start", x)
        if not -90 <= self.start[0] <= 90:
            raise ValueError(f"{o}.start latitude must be in [-90, 90] deg, got {self.start[0]}")
        for name, typ in (("vibration", Vibration), ("receiver", ReceiverConfig), ("constellation", Constellation),
                          ("events", GnssEvents), ("initial", InitialErrors)):
            if not isinstance(getattr(self, name), typ):
                raise ValueError(f"{o}.{name} must be a {typ.__name__}, got {type(getattr(self, name)).__name__}")
        if self.imu_events is not None and not isinstance(self.imu_events, ImuEvents):
            raise ValueError(f"{o}.imu_events must be an ImuEvents or None, got {type(self.imu_events).__name__}")
        if self.odometer is not None and not isinstance(self.odometer, OdometerModel):
            raise ValueError(f"{o}.odometer must be an OdometerModel or None, got {type(self.odometer).__name__}")

    @property
    def samples_per_epoch(self) -> int:
        """IMU samples per GNSS epoch."""
        return int(round(self.imu_rate_hz / self.gnss_rate_hz))

    def motions(self, rngs: Sequence[np.random.Generator]) -> list[Motion]:
        """One :class:`Motion` per batch row (drawn from the row's trajectory generator for random drives)."""
        if isinstance(self.drive, Motion):
            return [self.drive] * len(rngs)
        lat, lon, h = self.start
        return [random_drive(g, self.duration_s, style=self.drive, lat0_deg=lat, lon0_deg=lon, h0_m=h) for g in rngs]

    def replace(self, **changes) -> "Scenario":
        """A copy with fields replaced (validated)."""
        return dataclasses.replace(self, **changes)


def _seed000_motion() -> Motion:
    """Seed 000 sec 5.1: 20 m/s for 60 s with two 90-degree turns starting at 15 s and 45 s (15 deg/s)."""
    return Motion(lat0_deg=32.06, lon0_deg=118.79, h0_m=20.0, heading0_deg=0.0, speed0_mps=20.0,
                  segments=(Cruise(15.0), Turn(90.0, 15.0), Cruise(24.0), Turn(90.0, 15.0), Cruise(9.0)))


def _seed003_motion() -> Motion:
    """Seed 003 Table 1 start (36 N, 100 E, heading 90 deg); stationary / accelerate / decelerate / corner."""
    segs = (Static(30.0), Accelerate(10.0, 15.0), Cruise(50.0), Turn(90.0, 9.0), Cruise(40.0),
            Decelerate(7.5, 0.0), Static(20.0), Accelerate(12.5, 25.0), Cruise(80.0), Turn(-90.0, 6.0),
            Cruise(60.0), Decelerate(10.0, 5.0), Turn(90.0, 10.0), Accelerate(7.5, 20.0), Cruise(120.0),
            Decelerate(10.0, 0.0), Static(25.0), Accelerate(10.0, 15.0), Turn(-90.0, 9.0), Cruise(130.0),
            Decelerate(7.5, 0.0), Static(30.0))
    return Motion(lat0_deg=36.0, lon0_deg=100.0, h0_m=1500.0, heading0_deg=90.0, speed0_mps=0.0, segments=segs)


def _presets() -> dict[str, Scenario]:
    return {
        "open-sky": Scenario(name="open-sky", drive="open",
                             description="open-road drive under a clean sky"),
        "urban": Scenario(name="urban", drive="urban", receiver=ReceiverConfig(elevation_mask_deg=15.0),
                          events=GnssEvents.urban(),
                          description="stop-and-go city drive: street-canyon blockage and NLOS/multipath bursts"),
        "outage": Scenario(name="outage", drive="open",
                           events=GnssEvents(outages=((60.0, 120.0), (180.0, 240.0))),
                           description="open-road drive with two 60 s full GNSS outages"),
        "noise-burst": Scenario(name="noise-burst", drive="open",
                                events=GnssEvents.noise_bursts(scale=5.0, duration_s=30.0, period_s=90.0,
                                                               t_start_s=45.0, t_end_s=300.0),
                                description="open-road drive; true code/Doppler noise x5 for 30 s every 90 s"),
        "seed000-sim": Scenario(name="seed000-sim", duration_s=60.0, imu_rate_hz=100.0, gnss_rate_hz=2.0,
                                imu_grade="seed000", drive=_seed000_motion(), vibration=Vibration.none(),
                                initial=InitialErrors(position_sigma_m=(10.0, 10.0, 10.0),
                                                      velocity_sigma_mps=(0.1, 0.1, 0.1),
                                                      attitude_sigma_rad=(math.radians(0.03),) * 3,
                                                      fixed_ecef=True),
                                description="seed paper 000 sec 5.1 / Table 1 simulation"),
        "seed003-sim": Scenario(name="seed003-sim", duration_s=700.0, imu_rate_hz=100.0, gnss_rate_hz=1.0,
                                imu_grade="seed003", drive=_seed003_motion(),
                                events=GnssEvents(outages=((100.0, 300.0), (550.0, 650.0)),
                                                  reacquisition=Reacquisition()),
                                odometer=SEED003_ODOMETER,
                                initial=InitialErrors(position_sigma_m=(0.0175, 0.0175, 1.0),
                                                      velocity_sigma_mps=(0.03, 0.03, 0.03),
                                                      attitude_sigma_rad=(math.radians(1.0),) * 3),
                                description="seed paper 003 Table 1 simulation with outages 100-300 s, 550-650 s, "
                                            "re-acquisition noise after them, odometer + NHC"),
        "urban-transition": Scenario(name="urban-transition", drive="urban",
                                     events=GnssEvents(zones=UrbanZones(), reacquisition=Reacquisition()),
                                     description="open sky alternating at random with street canyon, tree cover "
                                                 "and overpass zones (seed paper 000 sec. 5.2 setting)"),
        "noise-mismatch": Scenario(name="noise-mismatch", drive="open", receiver=ReceiverConfig.dual_frequency(),
                                   events=GnssEvents(mismatch=SigmaMismatch()), imu_events=ImuEvents(),
                                   description="reported code/Doppler sigma wrong by random piecewise factors, "
                                               "IMU bias steps and rough-road regimes (seed paper 003 setting)"),
        "regime-switch": Scenario(name="regime-switch", drive="open", receiver=ReceiverConfig.dual_frequency(),
                                  events=GnssEvents(regimes=NoiseRegimes()),
                                  description="Markov-switching nominal/degraded/severe noise regimes with "
                                              "exponential dwell times"),
        "urban-smartloc": Scenario(
            name="urban-smartloc", drive="urban",
            events=GnssEvents(zones=UrbanZones(open_s=(5.0, 15.0), canyon_s=(60.0, 180.0), weights=(0.9, 0.0, 0.1),
                                               canyon=UrbanCanyon(street_width_m=40.0, blockage_probability=0.5),
                                               segment_s=SMARTLOC3_SEGMENT_S, nlos_probability=SMARTLOC3_P_NLOS,
                                               nlos_bias=SMARTLOC3_BIAS),
                              reacquisition=Reacquisition(), cn0=Cn0Scatter()),
            description="dense street canyon calibrated to the smartLoc recording's channels: NLOS share, "
                        "dwell, bias and C/N0 scatter (docs/sim-vs-real.md)"),
        "low-noise": Scenario(name="low-noise", drive="open", receiver=ReceiverConfig.geodetic(),
                              events=GnssEvents(mismatch=GENERIC_SIGMA_MODEL),
                              description="geodetic-grade receiver under a clean sky reporting a generic "
                                          "stochastic model (sigmas 8x code / 5x Doppler the true ones)"),
    }


SCENARIOS: dict[str, Scenario] = _presets()
"""The named presets."""


def get_scenario(name, **overrides) -> Scenario:
    """The preset ``name`` (or a :class:`Scenario` passed through), with fields replaced by ``overrides``."""
    if isinstance(name, Scenario):
        scen = name
    elif name not in SCENARIOS:
        raise ValueError(f"unknown scenario {name!r}; known: {sorted(SCENARIOS)}")
    else:
        scen = SCENARIOS[name]
    if overrides:
        bad = set(overrides) - {f.name for f in dataclasses.fields(Scenario)}
        if bad:
            raise ValueError(f"unknown Scenario field(s) {sorted(bad)}")
        scen = scen.replace(**overrides)
    return scen
