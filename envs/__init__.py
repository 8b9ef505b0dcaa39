"""navgym environments: the simulated world (:mod:`envs.sim`), the episode runner, and the Gymnasium
tuning environments registered here (ids fixed in DESIGN.md section 4):

* ``GnssIns/SageHusa-v0`` -- :class:`envs.gnss_ins_env.SageHusaEnv`
* ``GnssIns/STKF-v0``     -- :class:`envs.gnss_ins_env.StkfEnv`
* ``GnssIns/MASTKF-v0``   -- :class:`envs.gnss_ins_env.MaStkfEnv`
* ``GnssIns/SatelliteR-v0`` -- :class:`envs.satellite_env.SatelliteREnv` (one action per receiver channel)
* ``GnssIns/SatelliteSageHusa-v0`` -- :class:`envs.satellite_env.SatelliteSageHusaEnv`

Each has a native ``vector_entry_point`` (:mod:`envs.vector_env`); SB3 trains on it through
:mod:`envs.sb3`. ``python -m rl_zoo3.train --gym-packages envs --env GnssIns/SageHusa-v0`` imports this
package, which registers the ids.
"""
import gymnasium as gym

ENV_IDS = {
    "GnssIns/SageHusa-v0": ("SageHusaEnv", "SageHusaVectorEnv"),
    "GnssIns/STKF-v0": ("StkfEnv", "StkfVectorEnv"),
    "GnssIns/MASTKF-v0": ("MaStkfEnv", "MaStkfVectorEnv"),
    "GnssIns/SatelliteR-v0": ("satellite_env:SatelliteREnv", "SatelliteRVectorEnv"),
    "GnssIns/SatelliteSageHusa-v0": ("satellite_env:SatelliteSageHusaEnv", "SatelliteSageHusaVectorEnv"),
}
"""Registered ids -> (single env class, in ``envs.gnss_ins_env`` unless ``module:`` says, vector env class)."""

SATELLITE_ENV_IDS = ("GnssIns/SatelliteR-v0", "GnssIns/SatelliteSageHusa-v0")
"""The per-satellite ids (one action per receiver channel, :mod:`envs.satellite_env`)."""

for _id, (_single, _vector) in ENV_IDS.items():
    if _id not in gym.registry:
        _mod, _cls = _single.split(":") if ":" in _single else ("gnss_ins_env", _single)
        gym.register(id=_id, entry_point=f"envs.{_mod}:{_cls}", vector_entry_point=f"envs.vector_env:{_vector}")
