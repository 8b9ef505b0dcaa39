"""Recorded data sets described by a small TOML spec file (issue 12): ``eval.py --scenario path/to/set.toml``.

A spec names the files of one recording and how to replay them; it is usable
wherever a scenario name is (``envs.worlds.make_world``,
``EnvConfig(scenario=...)``, ``gym.make(id, scenario=...)``, ``eval.py
--scenario``). The shipped recordings are specs too (:data:`SHIPPED_SPECS`, in
``envs/datasets/specs/``), reachable by their names. The reference of every
key, with examples, is ``docs/datasets.md``; in short::

    name = "my-drive"                     # the scenario name in tables and file names
    description = "..."                   # optional

    [gnss]
    format = "rinex"                      # "rinex" (RINEX 3 obs + nav) or "smartloc" (smartLoc text files)
    obs = "drive.24O"                     # relative paths: against the spec's folder;
    nav = ["drive.24N", "drive.24L"]      #   "${NAVGYM_DATA_DIR}" -> the shared data folder
    systems = ["G", "E"]                  # RINEX letters (smartLoc: "G", "R")
    signals = { G = ["C1C"], E = ["C1X", "C1C"] }   # code observables per system, in order of preference
    elevation_mask_deg = 10.0
    min_cn0_dbhz = 0.0
    sigma0_m = 1.5                        # zenith code sigma of the elevation model
    interval_s = 1.0                      # keep one epoch every interval_s (optional)
    sigma_model = "receiver"              # or "elevation", "sigma-epsilon", "elevation-cn0", or a table
                                          #   { name = "elevation", a_m = 0.3, b_m = 0.3 } (envs.sim.sigma_models)

    [corrections]                         # RINEX only (smartLoc pseudoranges come corrected)
    iono = true                           # Klobuchar (GPS broadcast coefficients)
    tropo = true                          # Saastamoinen

    [truth]
    format = "navgym-csv"                 # a reader of envs.datasets.truth_readers (TRUTH_FORMATS)
    file = "truth.csv"

    [imu]                                 # optional: without it, the defaults below, said in one printed line
    source = "synthesized"                # from the truth with a named grade, or "recorded": a CSV with its
    grade = "industrial"                  #   column map, units and mounting (envs.datasets.recorded_imu)
    rate_hz = 100.0

    [odometry]                            # optional; smartLoc only: the recording's wheel odometry as aiding
    source = "recorded"                   #   (forward speed + NHC rows, and the yaw rate)
    speed_sigma_mps = 0.1                 # the sigmas the filter assumes
    nhc_sigma_mps = 0.1
    yaw_rate = true                       # fuse the recorded yaw rate too
    yaw_rate_sigma_dps = 0.3

Every key is checked when the file is loaded (:func:`load_dataset_spec`);
a wrong one raises :class:`DatasetSpecError` naming the file and the key.
``${NAVGYM_DATA_DIR}`` in a path expands to
:func:`~envs.datasets.errors.shared_data_dir` (the environment variable, or
``../shared/data`` beside the checkout when it is unset).

A replay world's scenario is a :class:`ReplayScenario`: a
:class:`~envs.sim.scenarios.Scenario` that also carries its spec, so handing
the scenario object on (``EnvConfig(scenario=world.scenario)``) replays the
same recording; it never builds a simulated world.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..sim.gnss import ClockModel, ReceiverConfig
from ..sim.imu import IMU_GRADES, Vibration
from ..sim.odometer import OdometerModel
from ..sim.scenarios import InitialErrors, Scenario
from ..sim.sigma_models import MODEL_PARAMETERS, SIGMA_MODELS, SigmaModel
from .errors import shared_data_dir

try:  # Python >= 3.11
    import tomllib
except ImportError:  # pragma: no cover - Python 3.10
    try:
        import tomli as tomllib
    except ImportError:
        tomllib = None

__all__ = ["DatasetSpecError", "GnssSpec", "CorrectionsSpec", "TruthSpec", "ImuSpec", "OdometrySpec", "DatasetSpec",
           "ReplayScenario", "SPEC_DIR", "SHIPPED_SPECS", "GNSS_FORMATS", "IMU_SOURCES", "ODOMETRY_SOURCES",
           "load_dataset_spec", "is_spec_path", "dataset_spec_of", "replay_scenario"]

SPEC_DIR = Path(__file__).resolve().parent / "specs"
"""Folder of the shipped specs."""
SHIPPED_SPECS = {"smartloc-potsdamer-platz": "smartloc-potsdamer-platz.toml",
                 "instinct-reach-static": "instinct-reach-static.toml",
                 "smartloc-potsdamer-platz-odometry": "smartloc-potsdamer-platz-odometry.toml",
                 "smartloc-potsdamer-platz-nhc": "smartloc-potsdamer-platz-nhc.toml"}
"""Scenario name -> shipped spec file in :data:`SPEC_DIR`."""
GNSS_FORMATS = ("rinex", "smartloc")
IMU_SOURCES = ("synthesized", "recorded")
ODOMETRY_SOURCES = ("recorded", "nhc")
"""Sources of ``[odometry]``: the recording's own wheel odometry (smartLoc ``odom3`` rows)."""
RINEX_SYSTEMS = ("G", "E", "C")
"""Systems with broadcast Keplerian ephemerides (GLONASS state vectors are not supported)."""
SMARTLOC_SYSTEMS = ("G", "R")
SIGNAL_BANDS = {"G": "1", "E": "1", "C": "2"}
"""The band whose broadcast group delay the satellite clock carries (GPS L1 TGD, Galileo E1 BGD, BeiDou B1I
TGD1): single-frequency code observables must be on it."""
_DATA_VAR = "${NAVGYM_DATA_DIR}"


class DatasetSpecError(ValueError):
    """A dataset spec file with a wrong or missing key; the message starts with ``<file>: <key>:``.

    Attributes
    ----------
    path : str, the spec file; key : str, the dotted key (``gnss.systems``).
    """

    def __init__(self, path, key: str, message: str):
        self.path, self.key = str(path), key
        super().__init__(f"{self.path}: {key}: {message}")


@dataclass(frozen=True)
class GnssSpec:
    """The ``[gnss]`` section: the observations and how they are selected (see module docstring).

    Attributes
    ----------
    format : ``'rinex'`` or ``'smartloc'``.
    obs : Path, the observation file (smartLoc: ``<name>_Input.txt``).
    nav : tuple of Path, the navigation files (RINEX; merged), empty for smartLoc.
    systems : tuple of RINEX letters.
    signals : tuple of (letter, (code, ...)) pairs, the code observables per system in order of preference.
    elevation_mask_deg : [deg]; min_cn0_dbhz : [dB-Hz]; sigma0_m : zenith code sigma [m] (RINEX).
    interval_s : float or None, keep one epoch every ``interval_s`` [s] (RINEX).
    doppler : bool, pseudorange rates from the Doppler observables (RINEX).
    doppler_sigma0_mps : zenith pseudorange-rate sigma of the elevation model [m/s].
    sigma_model : :class:`~envs.sim.sigma_models.SigmaModel`, the pseudorange sigma the filter is told
        (``'receiver'``: smartLoc's recorded variance, RINEX's ``sigma0_m`` elevation model).
    """

    format: str
    obs: Path
    nav: tuple = ()
    systems: tuple = ("G",)
    signals: tuple = ()
    elevation_mask_deg: float = 10.0
    min_cn0_dbhz: float = 0.0
    sigma0_m: float = 1.5
    interval_s: float | None = None
    doppler: bool = True
    doppler_sigma0_mps: float = 0.1
    sigma_model: SigmaModel = SigmaModel()


@dataclass(frozen=True)
class CorrectionsSpec:
    """The ``[corrections]`` section: atmosphere models applied to RINEX pseudoranges (each on / off)."""

    iono: bool = True
    tropo: bool = True


@dataclass(frozen=True)
class TruthSpec:
    """The ``[truth]`` section: the reference trajectory and the reader that reads it.

    Attributes
    ----------
    format : a name of :data:`envs.datasets.truth_readers.TRUTH_FORMATS`.
    file : Path or None (``'static'`` has no file).
    options : tuple of (key, value) pairs, the reader's own keys (column map, static position, ...),
        checked by the reader when the spec is loaded.
    """

    format: str
    file: Path | None = None
    options: tuple = ()

    def option(self, key, default=None):
        return dict(self.options).get(key, default)


@dataclass(frozen=True)
class ImuSpec:
    """The ``[imu]`` section: the world's IMU at ``rate_hz`` [Hz].

    Attributes
    ----------
    source : ``'synthesized'`` (from the truth with ``grade``) or ``'recorded'`` (replayed from ``file``,
        :mod:`envs.datasets.recorded_imu`).
    grade : a name of :data:`envs.sim.imu.IMU_GRADES`: the synthesized sensor, or the data-sheet grade that
        sets the filter's process noise for a recorded one.
    rate_hz : the IMU grid [Hz].
    file : Path or None, the recorded IMU CSV.
    options : tuple of (key, value) pairs, the recorded IMU's other keys (column map, units, mounting, ...).
    """

    source: str = "synthesized"
    grade: str = "industrial"
    rate_hz: float = 100.0
    file: Path | None = None
    options: tuple = ()

    def option(self, key, default=None):
        return dict(self.options).get(key, default)


@dataclass(frozen=True)
class OdometrySpec:
    """The ``[odometry]`` section: the vehicle's motion constraints as aiding.

    Attributes
    ----------
    source : ``'recorded'``: the recording's wheel odometry (smartLoc only: its ``odom3`` rows), forward speed and
        yaw rate, with the non-holonomic constraint; ``'nhc'``: no odometer, the non-holonomic constraint alone
        (a land vehicle's lateral and vertical body velocity are zero: knowledge of the vehicle, no sensor; any
        recording). ``speed_sigma_mps`` and the yaw-rate keys apply to ``'recorded'`` only.
    speed_sigma_mps : forward-speed sigma the filter assumes [m/s] (default 0.1: on Potsdamer Platz the
        recorded speed differs from the SPAN truth's by 0.04 m/s median, 0.18 m/s p95; scale 1.0044).
    nhc_sigma_mps : lateral / vertical NHC sigma [m/s] (default 0.1, as :data:`envs.sim.odometer.SEED003_ODOMETER`).
    yaw_rate : fuse the recorded yaw rate (default true).
    yaw_rate_sigma_dps : its sigma [deg/s] (default 0.3: the median |recorded - SPAN-spline truth| yaw rate
        above 3 m/s is 0.29 deg/s; the file reports 0.11 deg/s).
    """

    source: str = "recorded"
    speed_sigma_mps: float = 0.1
    nhc_sigma_mps: float = 0.1
    yaw_rate: bool = True
    yaw_rate_sigma_dps: float = 0.3

    def model(self) -> OdometerModel:
        """The :class:`~envs.sim.odometer.OdometerModel` of the replay scenario (its simulated-sensor fields,
        ``scale_error`` and ``noise_mps``, are 0: nothing is simulated)."""
        return OdometerModel(scale_error=0.0, noise_mps=0.0, sigma_mps=self.speed_sigma_mps,
                             nhc_sigma_mps=self.nhc_sigma_mps,
                             yaw_rate_sigma_rps=(math.radians(self.yaw_rate_sigma_dps)
                                                 if self.yaw_rate and self.source == "recorded" else None))


@dataclass(frozen=True)
class DatasetSpec:
    """One recorded data set (module docstring), loaded from ``path`` by :func:`load_dataset_spec`."""

    name: str
    path: Path
    gnss: GnssSpec
    truth: TruthSpec
    imu: ImuSpec = field(default_factory=ImuSpec)
    corrections: CorrectionsSpec = field(default_factory=CorrectionsSpec)
    description: str = ""
    odometry: OdometrySpec | None = None

    def scenario(self, duration_s: float | None = None, imu_grade: str | None = None) -> "ReplayScenario":
        """The descriptor :class:`ReplayScenario` of this data set (no file is read)."""
        return replay_scenario(self, duration_s, imu_grade)


@dataclass(frozen=True)
class ReplayScenario(Scenario):
    """A :class:`~envs.sim.scenarios.Scenario` that replays a recorded data set (its ``dataset`` spec).

    Only ``imu_rate_hz``, ``imu_grade``, ``vibration``, ``receiver.clock``, ``receiver.sigma_model`` (the
    spec's ``gnss.sigma_model``), ``odometer`` (the spec's ``[odometry]``: the recorded odometry is carried and
    fused), ``initial`` and ``duration_s`` (a prefix of the recording) are used by :func:`envs.datasets.dataset_world.world_from_spec`; ``drive``,
    ``constellation``, ``events`` describe nothing and ``gnss_rate_hz`` is the nominal rate.
    """

    dataset: DatasetSpec | None = None

    def __post_init__(self):
        super().__post_init__()
        if not isinstance(self.dataset, DatasetSpec):
            raise ValueError(f"ReplayScenario.dataset must be a DatasetSpec, got {type(self.dataset).__name__}")


def replay_scenario(spec: DatasetSpec, duration_s: float | None = None, imu_grade: str | None = None,
                    gnss_rate_hz: float | None = None) -> ReplayScenario:
    """The descriptor scenario of ``spec``: its IMU grade and rate, TCXO clock, pseudorange sigma model, recorded
    odometry's model (``odometer``, from ``[odometry]``), default initial errors.

    ``duration_s`` None means the whole recording (a nominal 1e6 s: the replay cuts at the truth's end);
    ``gnss_rate_hz`` the nominal GNSS rate (default: smartLoc 5 Hz, RINEX 1 Hz).
    """
    rate = gnss_rate_hz or (5.0 if spec.gnss.format == "smartloc" else 1.0)
    imu_rate = spec.imu.rate_hz
    if abs(imu_rate / rate - round(imu_rate / rate)) > 1e-9:
        rate = imu_rate / max(1, math.floor(imu_rate / rate))
    return ReplayScenario(name=spec.name, duration_s=1e6 if duration_s is None else float(duration_s),
                          imu_rate_hz=imu_rate, gnss_rate_hz=rate, imu_grade=imu_grade or spec.imu.grade,
                          drive="urban" if spec.gnss.format == "smartloc" else "open", vibration=Vibration(),
                          receiver=ReceiverConfig(clock=ClockModel.tcxo(), sigma_model=spec.gnss.sigma_model),
                          initial=InitialErrors(), odometer=None if spec.odometry is None else spec.odometry.model(),
                          description=f"replay: {spec.description or spec.path.name}", dataset=spec)


def is_spec_path(scenario) -> bool:
    """Whether ``scenario`` names a spec file (a str or Path ending in ``.toml``)."""
    return isinstance(scenario, (str, Path)) and str(scenario).lower().endswith(".toml")


def dataset_spec_of(scenario) -> DatasetSpec | None:
    """The :class:`DatasetSpec` that ``scenario`` refers to, or None for a simulated scenario.

    A shipped name (:data:`SHIPPED_SPECS`), a ``.toml`` path or a :class:`ReplayScenario` give their spec;
    a plain :class:`Scenario` named like a recording, or described as a replay, raises ``ValueError``
    (it would silently build a *simulated* world).
    """
    if isinstance(scenario, ReplayScenario):
        return scenario.dataset
    if isinstance(scenario, str) and scenario in SHIPPED_SPECS:
        return load_dataset_spec(SPEC_DIR / SHIPPED_SPECS[scenario])
    if is_spec_path(scenario):
        return load_dataset_spec(scenario)
    if isinstance(scenario, Scenario) and (scenario.name in SHIPPED_SPECS
                                           or scenario.description.startswith("replay:")):
        raise ValueError(f"scenario {scenario.name!r} is a plain Scenario describing a recording: it would build "
                         f"a simulated world. Pass the data set's name, its spec path, or a ReplayScenario "
                         f"(DatasetSpec.scenario())")
    return None


# ----------------------------------------------------------------------------------------------- loading
def load_dataset_spec(path) -> DatasetSpec:
    """Read and validate a dataset spec file (module docstring); errors name the file and the key.

    Raises
    ------
    FileNotFoundError : no such spec file. DatasetSpecError : a bad key or value.
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"{path}: dataset spec file does not exist")
    path = path.resolve()
    if tomllib is None:  # pragma: no cover
        raise ImportError("reading a dataset spec needs Python >= 3.11 (tomllib) or the 'tomli' package")
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise DatasetSpecError(path, "(syntax)", f"not valid TOML: {exc}") from None
    r = _Reader(path)
    r.keys(doc, "", {"name", "description", "gnss", "truth", "imu", "corrections", "odometry"})
    name = r.str(doc, "name", required=True)
    if not re.fullmatch(r"[A-Za-z0-9][A-Za-z0-9._+-]*", name):
        raise DatasetSpecError(path, "name", f"must be letters, digits, '.', '_', '+', '-' (it names result "
                                             f"files), got {name!r}")
    gnss = _gnss(r, r.table(doc, "gnss", required=True))
    corr_t = r.table(doc, "corrections")
    if gnss.format == "smartloc" and corr_t:
        raise DatasetSpecError(path, "corrections", "smartLoc pseudoranges come with the atmosphere removed: "
                                                    "leave out the [corrections] section")
    r.keys(corr_t, "corrections", {"iono", "tropo"})
    corr = CorrectionsSpec(iono=r.bool(corr_t, "corrections.iono", True),
                           tropo=r.bool(corr_t, "corrections.tropo", True))
    truth = _truth(r, r.table(doc, "truth", required=True), gnss)
    imu = _imu(r, r.table(doc, "imu"))
    if "imu" not in doc:
        _tell_imu_default(path, name, imu)
    odometry = _odometry(r, doc, gnss)
    return DatasetSpec(name=name, path=path, gnss=gnss, truth=truth, imu=imu, corrections=corr,
                       description=r.str(doc, "description", default=""), odometry=odometry)


_IMU_DEFAULT_TOLD: set = set()
"""Spec files whose missing ``[imu]`` section was reported in this process (once each)."""


def _tell_imu_default(path: Path, name: str, imu: ImuSpec) -> None:
    """One line on stderr, once per spec file and process: a spec without ``[imu]`` gets the documented default
    IMU (:class:`ImuSpec`'s defaults), which decides the filter's process noise and the synthesized sensor."""
    if path in _IMU_DEFAULT_TOLD:
        return
    _IMU_DEFAULT_TOLD.add(path)
    import sys
    print(f"navgym dataset {name}: {path} has no [imu] section: the IMU is synthesized from the truth, "
          f"{imu.grade} grade at {imu.rate_hz:g} Hz (the documented default; add an [imu] section to choose)",
          file=sys.stderr, flush=True)


def _gnss(r: "_Reader", t: dict) -> GnssSpec:
    r.keys(t, "gnss", {"format", "obs", "nav", "systems", "signals", "elevation_mask_deg", "min_cn0_dbhz",
                       "sigma0_m", "interval_s", "doppler", "doppler_sigma0_mps", "sigma_model"})
    fmt = r.choice(t, "gnss.format", GNSS_FORMATS, required=True)
    obs = r.file(t, "gnss.obs", required=True)
    sigma_model = _sigma_model(r, t)
    if fmt == "smartloc":
        if not obs.name.endswith("_Input.txt"):
            raise DatasetSpecError(r.path, "gnss.obs", f"a smartLoc observation file is '<name>_Input.txt', "
                                                       f"got {obs.name!r}")
        for k in ("nav", "signals", "sigma0_m", "interval_s", "doppler", "doppler_sigma0_mps"):
            if _has(t, "gnss." + k):
                raise DatasetSpecError(r.path, "gnss." + k, "does not apply to the smartLoc format (its files "
                                                            "carry satellite positions, sigmas and no Doppler)")
        systems = r.letters(t, "gnss.systems", SMARTLOC_SYSTEMS, default=SMARTLOC_SYSTEMS)
        return GnssSpec(format=fmt, obs=obs, nav=(), systems=systems, signals=(),
                        elevation_mask_deg=r.num(t, "gnss.elevation_mask_deg", 0.0, lo=-90, hi=90),
                        min_cn0_dbhz=r.num(t, "gnss.min_cn0_dbhz", 0.0, lo=0), doppler=False,
                        sigma_model=sigma_model)
    if sigma_model.name != "receiver" and _has(t, "gnss.sigma0_m"):
        raise DatasetSpecError(r.path, "gnss.sigma0_m", f"applies to sigma_model 'receiver' only (the loader's "
                                                        f"elevation model), not {sigma_model.name!r}")
    nav = t.get("nav")
    if isinstance(nav, str):
        nav = [nav]
    if not (isinstance(nav, list) and nav and all(isinstance(x, str) for x in nav)):
        raise DatasetSpecError(r.path, "gnss.nav", f"must be a file or a non-empty list of files, got {nav!r}")
    navs = tuple(r.resolve(x, "gnss.nav") for x in nav)
    systems = r.letters(t, "gnss.systems", RINEX_SYSTEMS, default=("G",))
    sig_t = t.get("signals", {})
    if not isinstance(sig_t, dict):
        raise DatasetSpecError(r.path, "gnss.signals", f"must be a table system -> [codes], got {sig_t!r}")
    from .rinex import SIGNALS
    signals = []
    for s in systems:
        codes = sig_t.get(s, list(SIGNALS[s][0]))
        if isinstance(codes, str):
            codes = [codes]
        key = f"gnss.signals.{s}"
        if not (isinstance(codes, list) and codes and all(isinstance(c, str) for c in codes)):
            raise DatasetSpecError(r.path, key, f"must be a non-empty list of code observables, got {codes!r}")
        for c in codes:
            if not re.fullmatch(r"C[1-9][A-Z]", c):
                raise DatasetSpecError(r.path, key, f"{c!r} is not a RINEX 3 code observable (e.g. 'C1C')")
            if c[1] != SIGNAL_BANDS[s] and not (s == "C" and c in ("C1I", "C1Q")):   # RINEX 3.02 B1I names
                raise DatasetSpecError(r.path, key, f"{c!r}: single-frequency codes must be on band "
                                                    f"{SIGNAL_BANDS[s]} (the broadcast group delay is for it)")
        signals.append((s, tuple(codes)))
    extra = sorted(set(sig_t) - set(systems))
    if extra:
        raise DatasetSpecError(r.path, f"gnss.signals.{extra[0]}", f"system {extra[0]!r} is not in gnss.systems")
    interval = t.get("interval_s")
    if interval is not None:
        interval = r.num(t, "gnss.interval_s", None, lo=0, lo_open=True)
    return GnssSpec(format=fmt, obs=obs, nav=navs, systems=systems, signals=tuple(signals),
                    elevation_mask_deg=r.num(t, "gnss.elevation_mask_deg", 10.0, lo=-90, hi=90),
                    min_cn0_dbhz=r.num(t, "gnss.min_cn0_dbhz", 0.0, lo=0),
                    sigma0_m=r.num(t, "gnss.sigma0_m", 1.5, lo=0, lo_open=True), interval_s=interval,
                    doppler=r.bool(t, "gnss.doppler", True),
                    doppler_sigma0_mps=r.num(t, "gnss.doppler_sigma0_mps", 0.1, lo=0, lo_open=True),
                    sigma_model=sigma_model)


def _sigma_model(r: "_Reader", t: dict) -> SigmaModel:
    """``gnss.sigma_model``: a model name, or a table with ``name`` and the model's parameters
    (:data:`envs.sim.sigma_models.MODEL_PARAMETERS`, numbers >= 0)."""
    v = t.get("sigma_model", "receiver")
    key = "gnss.sigma_model"
    if isinstance(v, str):
        v = {"name": v}
    elif not isinstance(v, dict):
        r.fail(key, f"must be a model name or a table {{ name = ..., <parameters> }}, got {v!r}")
    elif "name" not in v:
        r.fail(key + ".name", "missing: the model's name")
    name = r.choice(v, key + ".name", SIGMA_MODELS)
    known = MODEL_PARAMETERS[name]
    for k in v:
        if k != "name" and k not in known:
            r.fail(f"{key}.{k}", f"not a parameter of the {name!r} model (its parameters: "
                                 f"{', '.join(known) or 'none'})")
    params = {k: r.num(v, f"{key}.{k}", None, lo=0) for k in known if k in v}
    try:
        return SigmaModel(name, **params)
    except ValueError as exc:                     # "SigmaModel.<field>..." -> the spec's key
        field_name = str(exc).split(":")[0].split()[0].split(".")[-1]
        raise DatasetSpecError(r.path, f"{key}.{field_name}", str(exc)) from None


def _truth(r: "_Reader", t: dict, gnss: GnssSpec) -> TruthSpec:
    from .truth_readers import TRUTH_FORMATS, check_truth_options
    fmt = r.choice(t, "truth.format", tuple(TRUTH_FORMATS), required=True)
    reader = TRUTH_FORMATS[fmt]
    if (fmt == "smartloc") != (gnss.format == "smartloc"):
        raise DatasetSpecError(r.path, "truth.format", "the smartLoc ground truth goes with gnss.format = "
                                                       "'smartloc' and only with it")
    r.keys(t, "truth", {"format", "file"} | set(reader.options))
    file = r.file(t, "truth.file", required=reader.needs_file) if reader.needs_file else None
    if not reader.needs_file and _has(t, "truth.file"):
        raise DatasetSpecError(r.path, "truth.file", f"the {fmt!r} truth has no file")
    if fmt == "smartloc" and file.name != gnss.obs.name[:-len("_Input.txt")] + "_GT.txt":
        raise DatasetSpecError(r.path, "truth.file", f"the smartLoc ground truth of {gnss.obs.name!r} is "
                                                     f"{gnss.obs.name[:-len('_Input.txt')] + '_GT.txt'!r}")
    opts = {k: v for k, v in t.items() if k not in ("format", "file")}
    try:
        check_truth_options(fmt, opts)
    except ValueError as exc:
        key, _, msg = str(exc).partition(": ")
        raise DatasetSpecError(r.path, f"truth.{key}", msg) from None
    return TruthSpec(format=fmt, file=file, options=tuple(sorted((k, _freeze(v)) for k, v in opts.items())))


def _imu(r: "_Reader", t: dict) -> ImuSpec:
    from .recorded_imu import IMU_OPTIONS, check_imu_options
    r.keys(t, "imu", {"source", "grade", "rate_hz"} | set(IMU_OPTIONS))
    src = r.choice(t, "imu.source", IMU_SOURCES, default="synthesized")
    grade = r.choice(t, "imu.grade", tuple(sorted(IMU_GRADES)), default="industrial")
    rate = r.num(t, "imu.rate_hz", 100.0, lo=0, lo_open=True)
    if src == "synthesized":
        for k in IMU_OPTIONS:
            if _has(t, "imu." + k):
                raise DatasetSpecError(r.path, "imu." + k, "applies to a recorded IMU only (source = 'recorded')")
        return ImuSpec(source=src, grade=grade, rate_hz=rate)
    if "grade" not in t:
        raise DatasetSpecError(r.path, "imu.grade", "missing: a recorded IMU needs its data-sheet grade (the "
                                                    "filter's process noise)")
    opts = {k: v for k, v in t.items() if k not in ("source", "grade", "rate_hz")}
    try:
        check_imu_options(opts)
    except ValueError as exc:
        key, _, msg = str(exc).partition(": ")
        raise DatasetSpecError(r.path, f"imu.{key}", msg) from None
    file = r.file(t, "imu.file", required=True)
    opts.pop("file")
    return ImuSpec(source=src, grade=grade, rate_hz=rate, file=file,
                   options=tuple(sorted((k, _freeze(v)) for k, v in opts.items())))


def _odometry(r: "_Reader", doc: dict, gnss: GnssSpec) -> OdometrySpec | None:
    if "odometry" not in doc:
        return None
    t = r.table(doc, "odometry")
    r.keys(t, "odometry", {"source", "speed_sigma_mps", "nhc_sigma_mps", "yaw_rate", "yaw_rate_sigma_dps"})
    src = r.choice(t, "odometry.source", ODOMETRY_SOURCES, required=True)
    if src == "nhc":
        for key in ("speed_sigma_mps", "yaw_rate", "yaw_rate_sigma_dps"):
            if _has(t, f"odometry.{key}"):
                r.fail(f"odometry.{key}", "applies with source = 'recorded' only (source = 'nhc' has no odometer)")
        d = OdometrySpec()
        return OdometrySpec(source=src, yaw_rate=False, nhc_sigma_mps=r.num(t, "odometry.nhc_sigma_mps",
                                                                            d.nhc_sigma_mps, lo=0, lo_open=True))
    if gnss.format != "smartloc":
        r.fail("odometry.source", f"recorded odometry is read from smartLoc files only (their odom3 rows); "
                                  f"gnss.format is {gnss.format!r}")
    d = OdometrySpec()
    yaw = r.bool(t, "odometry.yaw_rate", d.yaw_rate)
    if not yaw and _has(t, "odometry.yaw_rate_sigma_dps"):
        r.fail("odometry.yaw_rate_sigma_dps", "applies with yaw_rate = true only")
    return OdometrySpec(source=src, yaw_rate=yaw,
                        speed_sigma_mps=r.num(t, "odometry.speed_sigma_mps", d.speed_sigma_mps, lo=0, lo_open=True),
                        nhc_sigma_mps=r.num(t, "odometry.nhc_sigma_mps", d.nhc_sigma_mps, lo=0, lo_open=True),
                        yaw_rate_sigma_dps=r.num(t, "odometry.yaw_rate_sigma_dps", d.yaw_rate_sigma_dps, lo=0,
                                                 lo_open=True))


def _has(t: dict, dotted: str) -> bool:
    return dotted.rsplit(".", 1)[-1] in t


def _freeze(v):
    if isinstance(v, dict):
        return tuple(sorted((k, _freeze(x)) for k, x in v.items()))
    if isinstance(v, list):
        return tuple(_freeze(x) for x in v)
    return v


class _Reader:
    """Typed access to a parsed TOML document with errors naming the spec file and the dotted key."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, key, msg):
        raise DatasetSpecError(self.path, key, msg)

    def keys(self, t: dict, where: str, known: set):
        bad = sorted(set(t) - known)
        if bad:
            self.fail(f"{where}.{bad[0]}" if where else bad[0], f"unknown key; known: {', '.join(sorted(known))}")

    def table(self, doc, key, required=False) -> dict:
        if key not in doc:
            if required:
                self.fail(key, "missing section")
            return {}
        if not isinstance(doc[key], dict):
            self.fail(key, f"must be a [{key}] section, got {doc[key]!r}")
        return doc[key]

    def _get(self, t, key, required, default):
        k = key.rsplit(".", 1)[-1]
        if k not in t:
            if required:
                self.fail(key, "missing")
            return default, False
        return t[k], True

    def str(self, t, key, required=False, default=None):
        v, there = self._get(t, key, required, default)
        if there and not isinstance(v, str):
            self.fail(key, f"must be a string, got {v!r}")
        return v

    def bool(self, t, key, default):
        v, there = self._get(t, key, False, default)
        if there and not isinstance(v, bool):
            self.fail(key, f"must be true or false, got {v!r}")
        return v

    def num(self, t, key, default, lo=None, hi=None, lo_open=False):
        v, there = self._get(t, key, False, default)
        if not there:
            return default
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            self.fail(key, f"must be a finite number, got {v!r}")
        if lo is not None and (v < lo or (lo_open and v == lo)):
            self.fail(key, f"must be {'>' if lo_open else '>='} {lo}, got {v!r}")
        if hi is not None and v > hi:
            self.fail(key, f"must be <= {hi}, got {v!r}")
        return float(v)

    def choice(self, t, key, choices, required=False, default=None):
        v = self.str(t, key, required, default)
        if v not in choices:
            self.fail(key, f"must be one of {', '.join(choices)}, got {v!r}")
        return v

    def letters(self, t, key, allowed, default):
        v, there = self._get(t, key, False, default)
        if isinstance(v, str):
            v = [v]
        if not (isinstance(v, (list, tuple)) and v and all(isinstance(x, str) for x in v)):
            self.fail(key, f"must be a non-empty list of system letters, got {v!r}")
        bad = [x for x in v if x not in allowed]
        if bad:
            why = " (GLONASS broadcasts state vectors, not supported)" if "R" in bad else ""
            self.fail(key, f"{bad[0]!r} is not supported here; choose among {', '.join(allowed)}{why}")
        if len(set(v)) != len(v):
            self.fail(key, f"a system is listed twice: {v!r}")
        return tuple(v)

    def resolve(self, s, key) -> Path:
        if not isinstance(s, str) or not s:
            self.fail(key, f"must be a file path, got {s!r}")
        if "${" in s.replace(_DATA_VAR, ""):
            self.fail(key, f"only {_DATA_VAR} may be expanded in a path, got {s!r}")
        p = Path(s.replace(_DATA_VAR, str(shared_data_dir()))).expanduser()
        return p if p.is_absolute() else (self.path.parent / p).resolve()

    def file(self, t, key, required=False):
        v, there = self._get(t, key, required, None)
        return self.resolve(v, key) if there else None

