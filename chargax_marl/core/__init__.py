"""The shared station simulator: pure functions over pytrees.

- :mod:`station`: the station tree and its compiled arrays.
- :mod:`types`: parameters, state and step report pytrees.
- :mod:`params`: building validated parameters from scenario names or custom data.
- :mod:`physics`: actions, rate curves, node limits, charging and energy flows.
- :mod:`traffic`: departures and arrivals.
- :mod:`reward`: prices, profit and penalty terms.
- :mod:`simulator`: ``reset`` and ``step``.
- :mod:`observation`: observation features.
- :mod:`datasets`: bundled and custom exogenous data (a re-export of :mod:`prices`,
  :mod:`profiles` (user profiles and traffic), :mod:`fleets` and :mod:`signals` (MOER, grid
  demand), each with one validator per data kind; shared helpers in :mod:`data_io`).
- :mod:`checks`: the bounds and the checker of every user-given number.
- :mod:`actions`: how NaN, huge, wrongly sized and non-numeric actions are handled.
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
