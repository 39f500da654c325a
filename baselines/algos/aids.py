"""The learning aids of the trainers' config mapped onto the library's teachers.

``BATTERY_SHAPING`` (`chargax_marl.teachers.shaping`: the batteries' stored energy
valued as a potential), ``PORT_SHAPING`` (`chargax_marl.teachers.car_plan`: each
parked car's plan value as a potential), ``FAIRNESS_WEIGHT`` / ``FAIRNESS_METRIC``
(`chargax_marl.wrappers.FairnessReward`: a weight on the day's fairness) and the
multi-agent trainers' imperfect communication, ``OBS_DELAY_STEPS``, ``ACTION_LOSS_PROB`` and
``LOST_ACTION`` (`chargax_marl.marl.communication`), and their ``PRIORITY_FILL``
(`chargax_marl.wrappers.PriorityFill`: charging actions as priorities), and ``RESIDUAL``
(`chargax_marl.teachers.rules`: a rule's action read beside the observation, which the
multi-agent actors' logits are centred on), and ``STATION_OBS`` (`station_features`: the
parked cars' demand on the whole station, read beside each agent's observation).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from chargax_marl.core.observation import ENERGY_SCALE_KWH, MINUTES_PER_DAY
from chargax_marl.core.station import KIND_BATTERY
from chargax_marl.marl import ActionLossWrapper, DelayedObservationWrapper
from chargax_marl.teachers import car_plan, congestion, rules
from chargax_marl.teachers import shaping as teacher_shaping
from chargax_marl.wrappers import FairnessReward, PriorityFill

PORT_SHAPING_MODES = ("off", "plan", "coupled")
PLAN_OBS_MODES = ("off", "plan", "coupled")
RESIDUAL_MODES = ("off", "coupled_plan")


def communication(config: dict, env):
    """``env`` seen through ``OBS_DELAY_STEPS`` and ``ACTION_LOSS_PROB`` / ``LOST_ACTION``
    (`chargax_marl.marl.DelayedObservationWrapper`, then
    `chargax_marl.marl.ActionLossWrapper`); ``env`` itself when both are off.

    Args:
        config: the trainer's config (``OBS_DELAY_STEPS``, default 0;
            ``ACTION_LOSS_PROB``, default 0; ``LOST_ACTION``, default ``"previous"``).
        env: a multi-agent env (`chargax_marl.marl.ChargaxMARL` or a wrapper of it).

    Returns:
        The wrapped env, or ``env`` itself.

    Raises:
        ValueError: a bad delay, probability or lost action.
    """
    delay = config.get("OBS_DELAY_STEPS", 0)
    loss = config.get("ACTION_LOSS_PROB", 0.0)
    lost = config.get("LOST_ACTION", "previous")
    try:
        if delay != 0:
            env = DelayedObservationWrapper(env, delay)
        if loss != 0.0:
            env = ActionLossWrapper(env, loss, lost)
    except ValueError as exc:
        raise ValueError(
            f"OBS_DELAY_STEPS={delay!r}, ACTION_LOSS_PROB={loss!r}, LOST_ACTION={lost!r}: {exc}"
        ) from None
    return env


def fairness(config: dict, env):
    """``env`` wrapped in `chargax_marl.wrappers.FairnessReward` with ``FAIRNESS_WEIGHT``
    and ``FAIRNESS_METRIC``; ``env`` itself when the weight is 0 (the default).

    Args:
        config: the trainer's config (``FAIRNESS_WEIGHT``, default 0; ``FAIRNESS_METRIC``,
            default ``"jain_index"``).
        env: the env to wrap.

    Returns:
        The wrapped env, or ``env`` itself.

    Raises:
        ValueError: a negative or non-finite weight, or an unknown metric.
    """
    weight = config.get("FAIRNESS_WEIGHT", 0.0)
    metric = config.get("FAIRNESS_METRIC", "jain_index")
    if weight == 0.0:
        return env
    try:
        return FairnessReward(env, weight, metric)
    except ValueError as exc:
        raise ValueError(f"FAIRNESS_WEIGHT={weight!r}, FAIRNESS_METRIC={metric!r}: {exc}") from None


def port_shaping_mode(config: dict) -> str:
    """``PORT_SHAPING`` as one of `PORT_SHAPING_MODES`.

    Args:
        config: the trainer's config (``PORT_SHAPING``, default ``"off"``; None or False
            is ``"off"``).

    Returns:
        The mode, a string of `PORT_SHAPING_MODES`.

    Raises:
        ValueError: any other value.
    """
    mode = config.get("PORT_SHAPING", "off")
    mode = "off" if mode in (None, False) else mode
    if mode not in PORT_SHAPING_MODES:
        raise ValueError(
            f"PORT_SHAPING must be one of {PORT_SHAPING_MODES}, got {config.get('PORT_SHAPING')!r}"
        )
    return mode


def car_potential(config: dict, env_params):
    """``None`` when ``PORT_SHAPING`` is off, else the per-car potential of
    `chargax_marl.teachers.car_plan.car_potential`: ``potential(env_state) -> shift``.

    Args:
        config: the trainer's config (``PORT_SHAPING``).
        env_params: concrete `chargax_marl.core.types.EnvParams` of the training env.

    Returns:
        None; for ``"plan"`` `chargax_marl.teachers.car_plan.car_potential`'s potential;
        for ``"coupled"`` `chargax_marl.teachers.congestion.coupled_potential`'s.

    Raises:
        ValueError: an unknown ``PORT_SHAPING`` (`port_shaping_mode`).
    """
    mode = port_shaping_mode(config)
    if mode == "off":
        return None
    if mode == "coupled":
        return congestion.coupled_potential(env_params)
    return car_plan.car_potential(env_params)


def plan_obs_mode(config: dict) -> str:
    """``PLAN_OBS`` as one of `PLAN_OBS_MODES` (``False`` / ``True`` are ``"off"`` /
    ``"plan"``).

    Args:
        config: the trainer's config (``PLAN_OBS``, default False).

    Returns:
        The mode, a string of `PLAN_OBS_MODES`.

    Raises:
        ValueError: any other value.
    """
    v = config.get("PLAN_OBS", False)
    mode = {False: "off", True: "plan", None: "off"}.get(v, v) if not isinstance(v, str) else v
    if mode not in PLAN_OBS_MODES:
        raise ValueError(f"PLAN_OBS must be a bool or one of {PLAN_OBS_MODES}, got {v!r}")
    return mode


def plan_features(config: dict, env_params):
    """The per-leaf advice ``PLAN_OBS`` appends to the observations, or ``None`` when off.

    Args:
        config: the trainer's config (``PLAN_OBS``).
        env_params: concrete `chargax_marl.core.types.EnvParams` of the training env.

    Returns:
        ``None``, or ``(advice, width)``: ``advice(core) -> (L, width)`` float32 for one
        (unbatched) core state; ``plan``: width 1, `chargax_marl.teachers.car_plan.plan_advice`
        (1 = its car's best plan under the day's prices charges now); ``coupled``: width
        `chargax_marl.teachers.congestion.COUPLED_ADVICE_WIDTH`,
        `chargax_marl.teachers.congestion.coupled_advice` (the share of the port's top power
        the coupled plan takes now and the congestion price on its path). 0 for batteries.

    Raises:
        ValueError: an unknown ``PLAN_OBS`` (`plan_obs_mode`).
    """
    mode = plan_obs_mode(config)
    if mode == "off":
        return None
    if mode == "coupled":
        return congestion.coupled_advice(env_params), congestion.COUPLED_ADVICE_WIDTH
    plan = car_plan.plan_advice(env_params)
    return (lambda core: plan(core)[:, None]), 1


def residual_mode(config: dict) -> str:
    """``RESIDUAL`` as one of `RESIDUAL_MODES`.

    Args:
        config: the trainer's config (``RESIDUAL``, default ``"off"``).

    Returns:
        The mode.

    Raises:
        ValueError: any other value.
    """
    v = config.get("RESIDUAL", "off")
    if v not in RESIDUAL_MODES:
        raise ValueError(f"RESIDUAL must be one of {RESIDUAL_MODES}, got {v!r}")
    return v


def residual_features(config: dict, env_params):
    """The base rule's level per leaf, which ``RESIDUAL`` appends to the observations (the
    last column of the advice), or ``None`` when off.

    Args:
        config: the trainer's config (``RESIDUAL``).
        env_params: concrete `chargax_marl.core.types.EnvParams` of the env played (the rule
            reads its prices).

    Returns:
        ``None``, or ``(advice, 1)``: ``advice(core) -> (L, 1)`` float32, the rule's level
        over ``num_levels`` (in ``[-1, 1]``) for one (unbatched) core state.

    Raises:
        ValueError: an unknown ``RESIDUAL`` (`residual_mode`).
    """
    mode = residual_mode(config)
    if mode == "off":
        return None
    rule = rules.RULE_BUILDERS[mode](env_params)
    num_levels = float(env_params.num_levels)
    key = jax.random.PRNGKey(0)  # the rules are deterministic

    def advice(core):
        return (rule(core, key, env_params).astype(jnp.float32) / num_levels)[:, None]

    return advice, 1


def advice_features(config: dict, env_params):
    """The per-leaf columns appended to the multi-agent observations: the ``PLAN_OBS``
    advice (`plan_features`), then the ``RESIDUAL`` rule's level (`residual_features`).

    Args:
        config: the trainer's config (``PLAN_OBS``, ``RESIDUAL``).
        env_params: concrete `chargax_marl.core.types.EnvParams` of the env played.

    Returns:
        ``None`` when both are off, else ``(advice, width)`` with ``advice(core) -> (L,
        width)`` for one (unbatched) core state.

    Raises:
        ValueError: an unknown ``PLAN_OBS`` or ``RESIDUAL``.
    """
    parts = [
        f
        for f in (plan_features(config, env_params), residual_features(config, env_params))
        if f is not None
    ]
    if not parts:
        return None
    if len(parts) == 1:
        return parts[0]
    (a, wa), (b, wb) = parts
    return (lambda core: jnp.concatenate([a(core), b(core)], axis=-1)), wa + wb


SHAPING_MODES = ("off",) + teacher_shaping.BATTERY_POTENTIALS


def shaping_mode(config: dict) -> str:
    """``BATTERY_SHAPING`` as one of `SHAPING_MODES` (``False`` / ``True`` are ``"off"`` /
    ``"day_mean"``).

    Args:
        config: the trainer's config (``BATTERY_SHAPING``, default False).

    Returns:
        The mode, a string of `SHAPING_MODES`.

    Raises:
        ValueError: any other value.
    """
    v = config.get("BATTERY_SHAPING", False)
    mode = (
        {False: "off", True: "day_mean", None: "off"}.get(v, v)
        if isinstance(v, (bool, type(None)))
        else v
    )
    if mode not in SHAPING_MODES:
        raise ValueError(f"BATTERY_SHAPING must be a bool or one of {SHAPING_MODES}, got {v!r}")
    return mode


def battery_potential(config: dict, env_params):
    """``None`` when ``BATTERY_SHAPING`` is off, else the potential of
    `chargax_marl.teachers.shaping.battery_potential` of that mode:
    ``potential(env_state) -> shift(net_kwh)``.

    Args:
        config: the trainer's config (``BATTERY_SHAPING``).
        env_params: concrete `chargax_marl.core.types.EnvParams` of the training env.

    Returns:
        None, or the potential.

    Raises:
        ValueError: an unknown ``BATTERY_SHAPING`` (`shaping_mode`), or a mode that needs a
            battery on a station without one.
    """
    mode = shaping_mode(config)
    if mode == "off":
        return None
    return teacher_shaping.battery_potential(env_params, mode)


def priority_fill(config: dict, env):
    """``env`` wrapped in `chargax_marl.wrappers.PriorityFill` when ``PRIORITY_FILL`` is on
    (with ``PRIORITY_CLASSES`` charging classes when it is positive); ``env`` itself otherwise.

    Args:
        config: the trainer's config (``PRIORITY_FILL``, default False;
            ``PRIORITY_CLASSES``, default 0; ``OBS_DELAY_STEPS`` and ``ACTION_LOSS_PROB``,
            which must be 0 with the fill).
        env: a multi-agent env.

    Returns:
        The wrapped env, or ``env`` itself.

    Raises:
        ValueError: ``PRIORITY_FILL`` together with an observation delay or an action loss (a
            lost action would undo the fill, which is computed from the state the agents see);
            ``PRIORITY_CLASSES`` negative, or positive without ``PRIORITY_FILL``.
    """
    classes = config.get("PRIORITY_CLASSES", 0)
    if classes < 0:
        raise ValueError(f"PRIORITY_CLASSES must be 0 or a positive integer, got {classes!r}")
    if not config.get("PRIORITY_FILL", False):
        if classes:
            raise ValueError(
                f"PRIORITY_CLASSES={classes} needs PRIORITY_FILL=true: the classes are the "
                "fill's priorities (set PRIORITY_CLASSES=0 or PRIORITY_FILL=true)"
            )
        return env
    delay, loss = config.get("OBS_DELAY_STEPS", 0), config.get("ACTION_LOSS_PROB", 0.0)
    if delay != 0 or loss != 0.0:
        raise ValueError(
            f"PRIORITY_FILL=true plays the fill on the state the agents act on; it cannot be "
            f"combined with OBS_DELAY_STEPS={delay!r} or ACTION_LOSS_PROB={loss!r} (set them to 0)"
        )
    return PriorityFill(env, classes or None)


STATION_WIDTH = 5
"""Columns of `station_features`."""


def station_features(core, params) -> jnp.ndarray:
    """The parked cars' demand on the whole station, the same for every agent (``STATION_OBS``).

    From the state the station knows now (the cars parked, their targets and planned
    departures; no future car): the energy the parked cars still want, over
    ``num_ports * ENERGY_SCALE_KWH``; the share of ports with a car; the parked cars' mean time
    to their planned departure, over a day; the power that would finish every car by its
    departure, over the ports' total rating; and the energy wanted by cars leaving within the
    hour, over ``num_ports * ENERGY_SCALE_KWH``.

    Args:
        core: the core state (`chargax_marl.core.types.EnvState`), any leading axes.
        params: the env parameters.

    Returns:
        ``(..., STATION_WIDTH)`` float32 features.
    """
    st = params.station
    port = st.leaf_kind != KIND_BATTERY
    num_ports = jnp.maximum(port.sum(), 1).astype(jnp.float32)
    occupied = core.occupied & port
    want_kwh = jnp.where(
        occupied, jnp.maximum(core.target_soc - core.soc, 0.0) * core.capacity_kwh, 0.0
    )
    left_min = jnp.where(occupied, jnp.maximum(core.time_remaining_min, 0.0), 0.0)
    cars = occupied.sum(-1)
    energy_scale = num_ports * ENERGY_SCALE_KWH
    rating_kw = jnp.maximum(jnp.sum(jnp.where(port, st.leaf_max_kw, 0.0)), 1e-6)
    finish_kw = want_kwh / jnp.maximum(left_min / 60.0, params.step_hours)
    return jnp.stack(
        [
            want_kwh.sum(-1) / energy_scale,
            cars / num_ports,
            left_min.sum(-1) / jnp.maximum(cars, 1) / MINUTES_PER_DAY,
            finish_kw.sum(-1) / rating_kw,
            jnp.where(left_min < 60.0, want_kwh, 0.0).sum(-1) / energy_scale,
        ],
        axis=-1,
    ).astype(jnp.float32)
