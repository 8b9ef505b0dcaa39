"""navgym environments: the simulated world (:mod:`envs.sim`), the episode runner, and the Gymnasium
tuning environments registered here:

* ``GnssIns/SageHusa-v1`` -- :class:`envs.gnss_ins_env.SageHusaEnv`
* ``GnssIns/STKF-v1``     -- :class:`envs.gnss_ins_env.StkfEnv`
* ``GnssIns/MASTKF-v1``   -- :class:`envs.gnss_ins_env.MaStkfEnv`
* ``GnssIns/SatelliteR-v0`` -- :class:`envs.satellite_env.SatelliteREnv` (one action per receiver channel)
* ``GnssIns/SatelliteSageHusa-v0`` -- :class:`envs.satellite_env.SatelliteSageHusaEnv`

Each has a native ``vector_entry_point`` (:mod:`envs.vector_env`); SB3 trains on it through
:mod:`envs.sb3`. ``python -m rl_zoo3.train --gym-packages envs --env GnssIns/SageHusa-v1`` imports this
package, which registers the ids.

Versions follow Gymnasium's convention: an id's version goes up whenever its results change (the version
history of :mod:`envs.gnss_ins_env` says what changed). The out-of-date ids of :data:`OUTDATED_ENV_IDS`
stay makeable: ``gym.make("GnssIns/SageHusa-v0")`` builds the current version's environment, and Gymnasium
warns that the id is out of date and names the current version (a ``DeprecationWarning``, shown once per
process). The laws of v0 are not kept: its published figures cannot be reproduced bit for bit.
"""
import gymnasium as gym

ENV_IDS = {
    "GnssIns/SageHusa-v1": ("SageHusaEnv", "SageHusaVectorEnv"),
    "GnssIns/STKF-v1": ("StkfEnv", "StkfVectorEnv"),
    "GnssIns/MASTKF-v1": ("MaStkfEnv", "MaStkfVectorEnv"),
    "GnssIns/SatelliteR-v0": ("satellite_env:SatelliteREnv", "SatelliteRVectorEnv"),
    "GnssIns/SatelliteSageHusa-v0": ("satellite_env:SatelliteSageHusaEnv", "SatelliteSageHusaVectorEnv"),
}
"""The current ids -> (single env class, in ``envs.gnss_ins_env`` unless ``module:`` says, vector env class)."""

OUTDATED_ENV_IDS = {
    "GnssIns/SageHusa-v0": "GnssIns/SageHusa-v1",
    "GnssIns/STKF-v0": "GnssIns/STKF-v1",
    "GnssIns/MASTKF-v0": "GnssIns/MASTKF-v1",
}
"""Out-of-date ids -> the current id whose environment they make (with Gymnasium's out-of-date warning)."""

SATELLITE_ENV_IDS = ("GnssIns/SatelliteR-v0", "GnssIns/SatelliteSageHusa-v0")
"""The per-satellite ids (one action per receiver channel, :mod:`envs.satellite_env`)."""


def is_env_id(env_id) -> bool:
    """Whether ``env_id`` is a navgym id: a current one (:data:`ENV_IDS`) or an out-of-date one that is still
    makeable (:data:`OUTDATED_ENV_IDS`)."""
    return env_id in ENV_IDS or env_id in OUTDATED_ENV_IDS


def current_env_id(env_id: str) -> str:
    """The current id of ``env_id`` (itself when it is current)."""
    return OUTDATED_ENV_IDS.get(env_id, env_id)


def warn_if_outdated(env_id: str) -> None:
    """A ``FutureWarning`` (shown to users by default) when ``env_id`` is out of date: it names the current id
    whose environment runs instead. For the paths that build an env's core from its id without ``gym.make``
    (``train.py tune``, eval.py's policies, rules and oracles); ``gym.make`` itself warns with Gymnasium's
    ``DeprecationWarning``."""
    if env_id in OUTDATED_ENV_IDS:
        import warnings
        warnings.warn(f"{env_id} is out of date: it runs {OUTDATED_ENV_IDS[env_id]} (the laws of the old version "
                      "are not kept; see the version history of envs.gnss_ins_env)", FutureWarning, stacklevel=2)


for _id, (_single, _vector) in [*ENV_IDS.items(), *((o, ENV_IDS[n]) for o, n in OUTDATED_ENV_IDS.items())]:
    if _id not in gym.registry:
        _mod, _cls = _single.split(":") if ":" in _single else ("gnss_ins_env", _single)
        gym.register(id=_id, entry_point=f"envs.{_mod}:{_cls}", vector_entry_point=f"envs.vector_env:{_vector}")
