"""Multi-agent view of the station: one agent per charging port and per station battery.

- :class:`ChargaxMARL`: JaxMARL 0.2 ``MultiAgentEnv`` (``reset(key)``, ``step(key, state, actions)``).
- :class:`LogWrapper`, :class:`WorldStateWrapper`: JaxMARL-style episode logging and MAPPO world state.
- :func:`parallel_env` / :class:`ChargaxParallelEnv`: PettingZoo ``ParallelEnv`` (numpy in and out).
"""

from chargax_marl.marl.env import ChargaxMARL
from chargax_marl.marl.pettingzoo_env import ChargaxParallelEnv, parallel_env
from chargax_marl.marl.wrappers import LogEnvState, LogWrapper, WorldStateWrapper

__all__ = ["ChargaxMARL", "ChargaxParallelEnv", "LogEnvState", "LogWrapper", "WorldStateWrapper", "parallel_env"]
