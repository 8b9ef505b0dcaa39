"""navgym environments: the simulated world (:mod:`envs.sim`), the episode runner, and the Gymnasium
tuning environments registered here (ids fixed in DESIGN.md section 4):

* ``GnssIns/SageHusa-v0`` -- :class:`envs.gnss_ins_env.SageHusaEnv`
* ``GnssIns/STKF-v0``     -- :class:`envs.gnss_ins_env.StkfEnv`
* ``GnssIns/MASTKF-v0``   -- :class:`envs.gnss_ins_env.MaStkfEnv`

Each has a native ``vector_entry_point`` (:mod:`envs.vector_env`); SB3 trains on it through
:mod:`envs.sb3`. ``python -m rl_zoo3.train --gym-packages envs --env GnssIns/SageHusa-v0`` imports this
package, which registers the ids.
"""
import gymnasium as gym

ENV_IDS = {
    "GnssIns/SageHusa-v0": ("SageHusaEnv", "SageHusaVectorEnv"),
    "GnssIns/STKF-v0": ("StkfEnv", "StkfVectorEnv"),
    "GnssIns/MASTKF-v0": ("MaStkfEnv", "MaStkfVectorEnv"),
}

for _id, (_single, _vector) in ENV_IDS.items():
    if _id not in gym.registry:
        gym.register(id=_id, entry_point=f"envs.gnss_ins_env:{_single}",
                     vector_entry_point=f"envs.vector_env:{_vector}")
