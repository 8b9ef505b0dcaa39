"""Recorded GNSS data replayed through the same navigator (DESIGN.md section 6; issue 7).

The recorded sets live in ``../shared/data`` (never copied into the repository;
:func:`~envs.datasets.errors.shared_data_dir`). Modules:

=================  ==========================================================================================
module             holds
=================  ==========================================================================================
``errors``         :class:`DatasetFormatError` (file + line), where the shared data live
``epochs``         :class:`GnssEpochs`, the common per-epoch structure of every loader; satellite velocities
                   from position tracks
``smartloc``       the smartLoc text files (pseudorange3, odom3, point3): strict, all-or-nothing loader
``spp``            batched weighted least-squares single-point positioning (one clock per system)
``spline_truth``   smoothing-spline truth from recorded positions with the consistent ideal IMU
``ephemeris``      broadcast Keplerian orbits and clocks (GPS, Galileo, BeiDou MEO/IGSO)
``atmosphere``     Klobuchar and Saastamoinen delays
``rinex``          RINEX 3 obs/nav through georinex -> corrected single-frequency :class:`GnssEpochs`
``truth_csv``      the reference-trajectory CSV of a generic RINEX replay
``replay``         a :class:`~envs.sim.world.World` from recorded data: ``smartloc-potsdamer-platz``
                   (:func:`load_smartloc_world`) and the generic RINEX scenario (:func:`load_rinex_world`)
``spec``           dataset spec files (TOML): a recording usable as a scenario by name or path (issue 12)
``dataset_world``  the replay world of a spec; the no-silent-drop rules
``truth_readers``  truth formats by name (navgym CSV, static, smartLoc; ``truth_generic_csv``: any CSV)
``recorded_imu``   a recorded IMU CSV (column map, units, mounting) on the world's IMU grid
``nav_merge``      several navigation files as one; ephemeris coverage of the observed satellites
``doppler``        pseudorange rates from RINEX Doppler (sign, wavelength per system and band)
``cache``          parsed RINEX files cached on disk by content hash
``check``          ``python -m envs.datasets check SPEC``: load a data set and print its summary
=================  ==========================================================================================

smartLoc has no Doppler: its replay worlds carry ``gnss.prr = None`` and the
navigator fuses pseudoranges only; RINEX recordings with ``D`` observables
carry pseudorange rates (``gnss.doppler`` of the spec). The IMU is synthesized
from the reference trajectory with a chosen grade; the GNSS errors are the
recorded ones. See ``docs/datasets.md``.
"""
from .epochs import GnssEpochs
from .errors import DatasetFormatError, shared_data_dir
from .replay import RINEX_SCENARIO, SMARTLOC_SCENARIO, load_rinex_world, load_smartloc_world
from .smartloc import SmartLocData, load_smartloc
from .spp import SppSolution, solve_spp

__all__ = ["GnssEpochs", "DatasetFormatError", "shared_data_dir", "SMARTLOC_SCENARIO", "RINEX_SCENARIO",
           "load_smartloc_world", "load_rinex_world", "SmartLocData", "load_smartloc", "SppSolution", "solve_spp"]
