"""The shared station simulator: pure functions over pytrees.

- `station`: the station tree and its compiled arrays.
- `types`: parameters, state and step report pytrees.
- `params`: building validated parameters from scenario names or custom data.
- `physics`: actions, rate curves, node limits, charging and energy flows.
- `traffic`: departures and arrivals.
- `reward`: prices, profit and penalty terms.
- `simulator`: ``reset`` and ``step``.
- `clock`: the clock time and calendar day of a step (episodes may start at any hour).
- `observation`: observation features.
- `datasets`: bundled and custom exogenous data (a re-export of `prices`,
  `profiles` (user profiles and traffic), `fleets` and `signals` (MOER, grid
  demand), each with one validator per data kind; shared helpers in `data_io`).
- `checks`: the bounds and the checker of every user-given number.
- `actions`: how NaN, huge, wrongly sized and non-numeric actions are handled.
"""

from chargax_marl.core.params import make_params, validate_params, validated_replace
from chargax_marl.core.simulator import empty_state, is_done, reset, step
from chargax_marl.core.station import (
    Battery,
    Port,
    Splitter,
    StationArrays,
    build_station,
    compile_station,
    multiple_splitters,
    multiple_types,
    single_type,
)
from chargax_marl.core.types import (
    PENALTY_TERMS,
    EnvParams,
    EnvState,
    EpisodeTotals,
    PenaltyWeights,
    StepInfo,
)

__all__ = [
    "Battery",
    "EnvParams",
    "EnvState",
    "EpisodeTotals",
    "PENALTY_TERMS",
    "PenaltyWeights",
    "Port",
    "Splitter",
    "StationArrays",
    "StepInfo",
    "build_station",
    "compile_station",
    "empty_state",
    "is_done",
    "make_params",
    "multiple_splitters",
    "multiple_types",
    "reset",
    "single_type",
    "step",
    "validate_params",
    "validated_replace",
]
