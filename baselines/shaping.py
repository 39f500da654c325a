"""The battery shaping in the trainers' config (``BATTERY_SHAPING``).

The potentials and the per-agent terms are library code,
:mod:`chargax_marl.teachers.shaping` (the battery-only programme and LP:
:mod:`chargax_marl.teachers.storage_value`); this module maps the trainers' ``BATTERY_SHAPING``
setting onto them. Shared by PPO, IPPO and MAPPO; the port shaping (a parked car's best plan)
is :mod:`baselines.car_value`.
"""

from __future__ import annotations

from chargax_marl.teachers import shaping as teacher_shaping

# Re-exported for the trainers and tests until they import the library
# (chargax_marl.teachers.shaping).
from chargax_marl.teachers.shaping import (  # noqa: F401
    agent_battery_shaping,
    agent_potential_shaping,
    battery_shaping,
    battery_value_price,
    core_state,
    mix_own_terms,
)

SHAPING_MODES = ("off",) + teacher_shaping.BATTERY_POTENTIALS


def shaping_mode(config: dict) -> str:
    """``BATTERY_SHAPING`` as one of :data:`SHAPING_MODES` (``False`` / ``True`` are ``"off"`` /
    ``"day_mean"``)."""
    v = config.get("BATTERY_SHAPING", False)
    mode = {False: "off", True: "day_mean", None: "off"}.get(v, v) if isinstance(v, (bool, type(None))) else v
    if mode not in SHAPING_MODES:
        raise ValueError(f"BATTERY_SHAPING must be a bool or one of {SHAPING_MODES}, got {v!r}")
    return mode


def battery_potential(config: dict, env_params):
    """``None`` when ``BATTERY_SHAPING`` is off, else the potential of
    :func:`chargax_marl.teachers.shaping.battery_potential` of that mode:
    ``potential(env_state) -> shift(net_kwh)``."""
    mode = shaping_mode(config)
    if mode == "off":
        return None
    return teacher_shaping.battery_potential(env_params, mode)
