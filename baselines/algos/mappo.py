"""MAPPO for `chargax_marl.marl.ChargaxMARL`: IPPO's shared actor on each agent's own
observation, with a *centralised* critic on the world state.

The env is wrapped as in JaxMARL's MAPPO, ``LogWrapper(WorldStateWrapper(env))``, and stepped
through its array path; the critic reads the world state (``WorldStateWrapper.global_state``:
the env's ``get_global_state``, i.e. the single-agent observation of the whole station, the
row ``obs["world_state"]`` of the dict step). All agents of an env share that world state, so
the critic runs once per env and step and its value is shared by the env's agents (the same
values as one critic call per agent row; `baselines.algos.ippo.DEDUP_CENTRAL_CRITIC`).
The rest of the loop (masking, batchify, GAE, clipped PPO, sharding, vmapped seeds) is the
one in `baselines.algos.ippo`, so that the two differ only in the critic's input.
"""

from __future__ import annotations

from baselines.algos import ippo


def make_train(config: dict | None = None, env_params=None):
    """Build MAPPO's jittable ``train(key)``; see `baselines.algos.ippo.make_train`.

    Args:
        config: the config, as for `baselines.algos.ippo.make_train`.
        env_params: the training env's parameters, as for `baselines.algos.ippo.make_train`.

    Returns:
        `baselines.algos.ippo.make_train`'s trainer with the centralised critic.
    """
    return ippo.make_train(config, env_params, centralised_critic=True)
