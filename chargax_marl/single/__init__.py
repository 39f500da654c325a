"""Single-agent view of the station: gymnax environment, wrappers and named scenarios."""

from chargax_marl.single.env import Chargax, MultiDiscrete
from chargax_marl.single.scenarios import SCENARIOS, make
from chargax_marl.single.wrappers import FlatDiscrete, GymnasiumEnv, LogWrapper

__all__ = [
    "Chargax",
    "FlatDiscrete",
    "GymnasiumEnv",
    "LogWrapper",
    "MultiDiscrete",
    "SCENARIOS",
    "make",
]
