"""Multi-agent view of the station: one agent per charging port and per station battery.

- `ChargaxMARL`: JaxMARL 0.2 ``MultiAgentEnv`` (``reset(key)``, ``step(key, state, actions)``).
- `LogWrapper`, `WorldStateWrapper`: JaxMARL-style episode logging and MAPPO world state;
  `FinalObservationWrapper`: the observations before an auto-reset, for loops of your own.
- `DelayedObservationWrapper`, `ActionLossWrapper`: imperfect communication
  (observations seen late, actions lost; `chargax_marl.marl.communication`), and
  `communicating_act`, a policy played on held-out days under the same communication.
- `parallel_env` / `ChargaxParallelEnv`: PettingZoo ``ParallelEnv`` (numpy in and out);
  `aec_env`: the same through PettingZoo's AEC API. The module
  `chargax_marl.marl.pettingzoo_env` has PettingZoo's usual ``env``, ``raw_env`` and
  ``parallel_env`` constructors (pass it to PettingZoo's ``max_cycles_test``).
"""

import builtins as _builtins
import sys as _sys

# Import JaxMARL without its "Importing submoduled environments..." lines. A module in its
# import chain resets ``sys.stdout``, so ``contextlib.redirect_stdout`` does not hold: drop just
# those lines at ``print`` for the duration of the import, and put back the caller's
# ``sys.stdout`` / ``sys.stderr`` (pytest's ``capsys``, a notebook's capture or a
# ``redirect_stdout`` around our import would otherwise be silently replaced).
_original_print = _builtins.print
_streams = _sys.stdout, _sys.stderr


def _quiet_print(*args, **kwargs):
    if args and isinstance(args[0], str) and "ubmoduled environments" in args[0]:
        return
    _original_print(*args, **kwargs)


_builtins.print = _quiet_print
try:
    import jaxmarl.environments  # noqa: F401, E402
finally:
    _builtins.print = _original_print
    _sys.stdout, _sys.stderr = _streams

# after the quiet JaxMARL import above
from chargax_marl.marl.communication import (  # noqa: E402
    ActionLossWrapper,
    DelayedObservationWrapper,
    communicating_act,
)
from chargax_marl.marl.env import ChargaxMARL  # noqa: E402
from chargax_marl.marl.pettingzoo_env import ChargaxParallelEnv, parallel_env  # noqa: E402
from chargax_marl.marl.pettingzoo_env import env as aec_env  # noqa: E402
from chargax_marl.marl.wrappers import (  # noqa: E402
    FinalObservationWrapper,
    LogEnvState,
    LogWrapper,
    WorldStateWrapper,
)

__all__ = [
    "ActionLossWrapper",
    "ChargaxMARL",
    "DelayedObservationWrapper",
    "ChargaxParallelEnv",
    "FinalObservationWrapper",
    "aec_env",
    "LogEnvState",
    "LogWrapper",
    "WorldStateWrapper",
    "communicating_act",
    "parallel_env",
]
