"""One schema for every training setting, read from TOML files with ``KEY=value`` overrides.

A config is a flat mapping of upper-case keys. `SCHEMA` names every key the trainers,
the evaluation and the command line read, with its default and what it allows; a file in
``baselines/configs/`` (or any path) sets some of them, and ``KEY=value`` arguments set more::

    python -m baselines.train --config ippo TOTAL_TIMESTEPS=2e6 SEEDS=2

The defaults of `SCHEMA` are the paper's Table 3 with every learning aid off, so a
stored run's config, which lists the keys it ran with, resolves to the same settings; the
best-known settings per algorithm are the files ``ppo.toml``, ``ippo.toml`` and
``mappo.toml``, and ``ippo`` is the command line's default. An unknown key, or a value of the
wrong kind, raises `ConfigError` naming the key, the value and what is allowed.
"""

from __future__ import annotations

import json
import math
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from chargax_marl.benchmark.tasks import TASKS, get_task
from chargax_marl.core.params import make_params
from chargax_marl.evaluation import split_days, validation_days
from chargax_marl.single.scenarios import SCENARIOS

CONFIG_DIR = Path(__file__).resolve().parent / "configs"
DEFAULT_CONFIG = "ippo"


class ConfigError(ValueError):
    """A config key that is unknown, or a value that the key does not allow."""


@dataclass(frozen=True)
class Field:
    """One config key: its default, the kinds of value it takes, and (optionally) its choices.

    Attributes:
        default: the value when the config does not set the key (None: the key may be None).
        kinds: the Python types a value may have (a bool only where ``bool`` is listed; a
            whole float is taken for an ``(int,)`` key; a float must be finite).
        choices: the values allowed, when not empty.
        doc: one line on what the key does.
        low: the least number allowed (None: no least); an ``(int,)`` key without ``low``
            or ``high`` still lies in int32.
        high: the greatest number allowed (None: no greatest).
        low_open: ``low`` itself is not allowed.
        nonempty: a string key may not be empty (or only spaces).
    """

    default: Any
    kinds: tuple
    choices: tuple = ()
    doc: str = ""
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    nonempty: bool = False


_NUM = (int, float)
_INT32_MAX = 2**31 - 1
_BATTERY_SHAPING = (False, True, "off", "day_mean", "storage_value", "dp")

SCHEMA: dict[str, Field] = {
    # PPO (the paper's Table 3)
    "LR": Field(2.5e-4, _NUM, doc="Adam learning rate", low=0.0, low_open=True),
    "ANNEAL_LR": Field(True, (bool,), doc="anneal the learning rate linearly to 0"),
    "GAMMA": Field(0.99, _NUM, doc="discount per step", low=0.0, high=1.0),
    "GAE_LAMBDA": Field(0.95, _NUM, doc="GAE lambda", low=0.0, high=1.0),
    "MAX_GRAD_NORM": Field(100.0, _NUM, doc="global gradient-norm clip", low=0.0, low_open=True),
    "CLIP_EPS": Field(0.2, _NUM, doc="PPO ratio clip", low=0.0, low_open=True),
    "VF_CLIP": Field(10.0, _NUM, doc="value clip", low=0.0, low_open=True),
    "ENT_COEF": Field(0.01, _NUM, doc="entropy bonus", low=0.0),
    "VF_COEF": Field(0.25, _NUM, doc="value-loss weight", low=0.0),
    "NUM_ENVS": Field(12, (int,), doc="parallel envs per seed", low=1),
    "NUM_STEPS": Field(300, (int,), doc="rollout steps per update", low=1),
    "NUM_MINIBATCHES": Field(4, (int,), doc="minibatches per epoch", low=1),
    "UPDATE_EPOCHS": Field(4, (int,), doc="epochs per update", low=1),
    "TOTAL_TIMESTEPS": Field(10_000_000, _NUM, doc="env steps per seed", low=1),
    # networks and rewards (the paper does not state them)
    "HIDDEN": Field(256, (int,), doc="hidden units per layer", low=1),
    "NUM_LAYERS": Field(2, (int,), doc="hidden layers (0: a linear policy)", low=0),
    "ACTIVATION": Field("tanh", (str,), ("tanh", "relu")),
    "REWARD_SCALE": Field(
        1.0,
        _NUM,
        doc="rewards (EUR per step) are multiplied by this before GAE",
        low=0.0,
        low_open=True,
    ),
    "ALWAYS_MAX_PRIOR": Field(
        0.0, _NUM, doc="logit offset >= 0 on each port's full-power action", low=0.0
    ),
    "BATTERY_IDLE_PRIOR": Field(
        0.0, _NUM, doc="logit offset >= 0 on each battery's idle action", low=0.0
    ),
    # learning aids: the teachers' shaping and observation features
    "BATTERY_SHAPING": Field(
        False,
        (bool, str),
        _BATTERY_SHAPING,
        "value the batteries' energy as it moves: True = day_mean; storage_value; dp",
    ),
    "PORT_SHAPING": Field(
        "off",
        (str,),
        ("off", "plan", "coupled"),
        "each parked car's value as a potential: plan = its plan alone; coupled = at the "
        "coupled plan's congestion prices",
    ),
    "SHAPING_WEIGHT": Field(
        1.0, _NUM, doc="weight of the BATTERY_SHAPING and PORT_SHAPING terms in the reward"
    ),
    "PLAN_OBS": Field(
        False,
        (bool, str),
        (False, True, "off", "plan", "coupled"),
        "each agent also observes its port's advice: True = plan (charge now by its own plan); "
        "coupled = the coupled plan's share of top power and congestion price",
    ),
    "RELATIVE_PRICES": Field(False, (bool,), doc="the networks also read relative prices"),
    "STATION_OBS": Field(
        False,
        (bool,),
        doc="IPPO / MAPPO: each agent also reads the parked cars' demand on the whole station",
    ),
    "RESIDUAL": Field(
        "off",
        (str,),
        ("off", "coupled_plan"),
        "IPPO / MAPPO: each agent also reads this rule's level, and its actor's logits are "
        "centred on it (the untrained greedy policy is the rule)",
    ),
    "RESIDUAL_PRIOR": Field(
        2.0, _NUM, doc="with RESIDUAL: logit per level of distance from the rule's action (> 0)"
    ),
    "RESIDUAL_BATTERY_PRIOR": Field(
        None, _NUM, doc="with RESIDUAL: the batteries' RESIDUAL_PRIOR (None: RESIDUAL_PRIOR)"
    ),
    "DISTILL": Field(
        "off",
        (str,),
        ("off", "mpc"),
        "IPPO / MAPPO: before PPO, fit the actor to the MPC's actions on the states it visits "
        "(DAgger, baselines.algos.distill)",
    ),
    "DISTILL_AGENTS": Field(
        "all",
        (str,),
        ("all", "battery"),
        "with DISTILL: the agents fitted to the MPC (battery: the ports keep their actor)",
    ),
    "DISTILL_ROUNDS": Field(6, (int,), doc="with DISTILL: DAgger rounds of one day each", low=1),
    "DISTILL_ENVS": Field(32, (int,), doc="with DISTILL: envs (days) labelled per round", low=1),
    "DISTILL_BETA": Field(
        0.5,
        _NUM,
        doc="with DISTILL: round r follows the MPC with probability beta**r",
        low=0.0,
        high=1.0,
    ),
    "DISTILL_STEPS": Field(2000, (int,), doc="with DISTILL: Adam steps per round", low=1),
    "DISTILL_BATCH": Field(2048, (int,), doc="with DISTILL: rows per Adam step", low=1),
    "DISTILL_LR": Field(1e-3, _NUM, doc="with DISTILL: Adam learning rate", low=0.0, low_open=True),
    "DISTILL_HORIZON_H": Field(
        4.0, _NUM, doc="with DISTILL: the MPC's look-ahead (hours)", low=0.0, low_open=True
    ),
    "FAIRNESS_WEIGHT": Field(
        0.0,
        _NUM,
        doc="EUR per unit of the day's fairness metric in the reward (FairnessReward)",
        low=0.0,
    ),
    "FAIRNESS_METRIC": Field(
        "jain_index",
        (str,),
        ("jain_index", "min_satisfaction"),
        "the metric FAIRNESS_WEIGHT weighs",
    ),
    # multi-agent (IPPO / MAPPO)
    "AGENT_ID": Field("onehot", (str,), ("onehot", "scalar"), "agent-index encoding"),
    "LOCAL_REWARD_WEIGHT": Field(
        0.0, _NUM, doc="weight in [0, 1] of each agent's own share", low=0.0, high=1.0
    ),
    "PRIORITY_FILL": Field(
        False,
        (bool,),
        doc="charging actions as priorities, each node filled in that order (PriorityFill)",
    ),
    "PRIORITY_CLASSES": Field(
        0,
        (int,),
        doc="with PRIORITY_FILL: 0 = the view's levels are the priorities; P > 0 = each agent "
        "chooses discharge, idle or one of P charging classes, filled at the env's num_levels",
        low=0,
    ),
    "AGENT_ADV_NORM": Field(False, (bool,), doc="normalise the advantages per agent"),
    "OBS_DELAY_STEPS": Field(
        0, (int,), doc="the context and node loads seen this many steps late (training)", low=0
    ),
    "ACTION_LOSS_PROB": Field(
        0.0, _NUM, doc="each agent's action lost with this probability", low=0.0, high=1.0
    ),
    "LOST_ACTION": Field(
        "previous", (str,), ("previous", "idle"), "what a port applies when its action is lost"
    ),
    "BATTERY_NET": Field(False, (bool,), doc="a separate actor (and critic) for the batteries"),
    "BATTERY_GAMMA": Field(
        None, _NUM, doc="the battery agents' discount (None: GAMMA)", low=0.0, high=1.0
    ),
    "BATTERY_ENT_COEF": Field(
        None, _NUM, doc="the battery agents' entropy bonus (None: ENT_COEF)", low=0.0
    ),
    # single-agent PPO
    "SPLIT_CREDIT": Field(False, (bool,), doc="port heads and battery heads learn from own shares"),
    # the scenario and the held-out protocol
    "SCENARIO": Field("shopping", (str,), tuple(SCENARIOS), "a named scenario"),
    "TASK": Field(
        "",
        (str,),
        ("",) + tuple(TASKS),
        "a benchmark task: its scenario, training data and held-out days (empty: SCENARIO)",
    ),
    "TRAFFIC": Field(None, (str, int, float), doc="low / medium / high or cars per day"),
    "ENV_KWARGS": Field({}, (dict,), doc="extra keyword arguments of make_params"),
    "NUM_EVAL_DAYS": Field(100, (int,), doc="held-out days", low=1),
    "EVAL_DRAWS": Field(1, (int,), doc="car draws per held-out day (keys 0 .. N-1)", low=1),
    "SPLIT_SEED": Field(0, (int,), doc="seed of the held-out split", low=0),
    # the validation split: what a run evaluates on while it trains (drawn from training days)
    "NUM_VALIDATION_DAYS": Field(
        20,
        (int,),
        doc="validation days, drawn from the training days (with TASK: the task's)",
        low=1,
    ),
    "VALIDATION_DRAWS": Field(
        1,
        (int,),
        doc="car draws per validation day (keys 0 .. N-1; with TASK: the task's)",
        low=1,
    ),
    "VALIDATION_SEED": Field(
        1, (int,), doc="seed of the validation draw (with TASK: the task's)", low=1
    ),
}
"""Every key a trainer reads, with its default (Table 3, learning aids off)."""

RUN_SCHEMA: dict[str, Field] = {
    "ALGO": Field("ippo", (str,), ("ppo", "ippo", "mappo")),
    "SEEDS": Field(2, (int,), doc="seeds trained at once (vmapped)", low=1),
    "SEED": Field(0, (int,), doc="the first seed's key", low=0),
    "CHUNKS": Field(10, (int,), doc="training pieces (progress and validation evaluation)", low=1),
    "OUT": Field(
        "outputs/run",
        (str,),
        doc="run directory (git-ignored outputs/ by default)",
        nonempty=True,
    ),
    "OPTIMAL": Field("bound", (str,), ("off", "bound", "mpc"), "references beside the rules"),
    "REFERENCES_DIR": Field(
        "", (str,), doc="directory of stored references (make optimal) to reuse; empty: compute"
    ),
}
"""Keys of a run (what to train and where to write), not of the trainer."""

_INTEGERS = tuple(k for k, f in {**SCHEMA, **RUN_SCHEMA}.items() if f.kinds == (int,))


def _allowed(field: Field, value: Any = None) -> str:
    """What ``field`` allows, in words, for a message about ``value`` (an integer key's int32
    bound is named only where ``value`` passes it)."""
    if field.choices:
        return f"one of {list(field.choices)}"
    kinds = " or ".join(k.__name__ for k in field.kinds)
    if field.kinds == (int,):
        kinds = "an integer"
    elif field.kinds == _NUM:
        kinds = "a finite number"
    low, high = _bounds(field)
    if field.high is None and not (isinstance(value, (int, float)) and value > _INT32_MAX):
        high = None
    low, high = (None if b is None else _number_text(b) for b in (low, high))
    if low is not None and high is not None:
        kinds += f" in {'(' if field.low_open else '['}{low}, {high}]"
    elif low is not None:
        kinds += f" {'>' if field.low_open else '>='} {low}"
    if field.nonempty:
        kinds = f"a non-empty {kinds}"
    if field.default is None:
        kinds += " (or None)"
    return kinds


def _number_text(x: float) -> str:
    """A bound as a message writes it: ``2147483647``, ``0``, ``0.5``."""
    return str(int(x)) if float(x).is_integer() else f"{x:g}"


def _bounds(field: Field) -> tuple[float | None, float | None]:
    """``(low, high)`` of ``field``: an integer key lies in int32 when no bound says more."""
    if field.kinds != (int,):
        return field.low, field.high
    low = -(2**31) if field.low is None else field.low
    return low, _INT32_MAX if field.high is None else field.high


def check_value(key: str, value: Any, field: Field, what: str = "config key") -> Any:
    """``value`` for ``key`` coerced to its field's kind, or `ConfigError`: the one check of a
    user's value for a config key (a file's, an override's, a sweep grid's each value).

    Args:
        key: the key, for the message.
        value: the value as read (TOML's value, or the text when it is not one).
        field: the key's `Field`.
        what: what the message calls the key (``config key``; a command's option).

    Returns:
        The value: a whole float of an ``(int,)`` key as an int; otherwise as given.

    Raises:
        ConfigError: a value of another kind (a bool where ``bool`` is not listed), a float
            that is not finite, a value not among ``choices``, a number outside the
            field's bounds, or an empty string where ``nonempty``; the message names the key,
            the value and what is allowed.
    """
    if value is None and field.default is None:
        return None
    ok = isinstance(value, field.kinds) and not (
        isinstance(value, bool) and bool not in field.kinds
    )
    if field.kinds == (int,) and isinstance(value, float) and value.is_integer():
        value, ok = int(value), True
    if ok and isinstance(value, float) and not math.isfinite(value):
        ok = False
    if ok and field.choices and value not in field.choices:
        ok = False
    if ok and isinstance(value, (int, float)) and not isinstance(value, bool):
        low, high = _bounds(field)
        if low is not None and (value <= low if field.low_open else value < low):
            ok = False
        if high is not None and value > high:
            ok = False
    if ok and field.nonempty and isinstance(value, str) and not value.strip():
        ok = False
    if not ok:
        raise ConfigError(
            f"{what} {key}={value!r} is not allowed: expected {_allowed(field, value)}"
        )
    return value


ALIASES = {
    "BATTERY_SHAPING": {True: "day_mean", False: "off"},
    "PLAN_OBS": {True: "plan", False: "off"},
}
"""Keys whose bool values are names for one of their string values."""


def canonical(key: str, value: Any) -> str:
    """A checked value of ``key`` as the text two equal settings share (``64`` and ``64.0``,
    ``True`` and ``"day_mean"`` of ``BATTERY_SHAPING``), to compare settings.

    Args:
        key: the config key.
        value: its value, checked (`check_value`).

    Returns:
        The value's JSON text, after `ALIASES`.
    """
    aliases = ALIASES.get(key, {})
    if isinstance(value, bool) and value in aliases:
        value = aliases[value]
    return json.dumps(value, sort_keys=True)


def resolve(config: dict | None = None, schema: dict[str, Field] = SCHEMA) -> dict:
    """The full config: every key of ``schema``, from ``config`` or its default.

    Args:
        config: keys to set (a stored run's ``config``, a file's, or overrides).
        schema: the keys allowed (`SCHEMA` for a trainer).

    Returns:
        A new dict with every key of ``schema``; ``TOTAL_TIMESTEPS`` as an int.

    Raises:
        ConfigError: a key not in ``schema``, a value it does not allow (`check_value`), or
            ``TOTAL_TIMESTEPS`` below one rollout (``NUM_ENVS * NUM_STEPS``).
    """
    config = dict(config or {})
    unknown = sorted(set(config) - set(schema))
    if unknown:
        raise ConfigError(f"unknown config key(s) {unknown}; allowed: {sorted(schema)}")
    out = {}
    for key, field in schema.items():
        value = config.get(key, field.default)
        out[key] = check_value(key, dict(value) if isinstance(value, dict) else value, field)
    if "TOTAL_TIMESTEPS" in out:
        out["TOTAL_TIMESTEPS"] = int(float(out["TOTAL_TIMESTEPS"]))
        rollout = out["NUM_ENVS"] * out["NUM_STEPS"]
        if out["TOTAL_TIMESTEPS"] < rollout:
            raise ConfigError(
                f"config key TOTAL_TIMESTEPS={config.get('TOTAL_TIMESTEPS')!r} is not allowed: "
                f"expected at least one rollout, NUM_ENVS * NUM_STEPS = {rollout} env steps"
            )
    if "EVAL_DRAWS" in out and out["EVAL_DRAWS"] < 1:
        raise ConfigError(f"config key EVAL_DRAWS={out['EVAL_DRAWS']!r}: expected an integer >= 1")
    if out.get("TASK"):  # the validation keys not given are the task's
        task = get_task(out["TASK"])
        for key, value in _task_validation(task).items():
            if key in out and key not in config:
                out[key] = value
    for key in VALIDATION_KEYS:
        if key in out and out[key] < 1:
            raise ConfigError(f"config key {key}={out[key]!r}: expected an integer >= 1")
    return out


VALIDATION_KEYS = ("NUM_VALIDATION_DAYS", "VALIDATION_DRAWS", "VALIDATION_SEED")
"""The keys of the validation split (`validation_env`); with ``TASK``, the task's."""


def name_session_model(config: dict) -> dict:
    """A resolved config of a new run with its session model named: without ``TASK`` (whose
    task names it) and without ``ENV_KWARGS["session_model"]``, the default ``"v2"``, so that
    the stored run says which model it trained on.

    Args:
        config: a resolved config (`resolve`).

    Returns:
        The config, with ``ENV_KWARGS["session_model"]`` set where it was missing.
    """
    env = dict(config.get("ENV_KWARGS") or {})
    if config.get("TASK") or "session_model" in env:
        return config
    return {**config, "ENV_KWARGS": {**env, "session_model": "v2"}}


def stored_config(config: dict) -> dict:
    """A stored run's config as the run trained it: a config without ``TASK`` whose
    ``ENV_KWARGS`` do not name ``session_model`` was stored before the session model v2
    existed (new runs name it, `name_session_model`), so it ran on the paper's sessions.

    Args:
        config: the ``config`` of a run's ``results.json`` or checkpoint.

    Returns:
        The config, with ``ENV_KWARGS["session_model"] = "paper"`` where it was missing.
    """
    env = dict(config.get("ENV_KWARGS") or {})
    if config.get("TASK") or "session_model" in env:
        return config
    return {**config, "ENV_KWARGS": {**env, "session_model": "paper"}}


def _task_validation(task) -> dict:
    """The validation keys' values of a `chargax_marl.benchmark.Task`."""
    return dict(
        zip(
            VALIDATION_KEYS,
            (task.num_validation_days, task.validation_draws, task.validation_seed),
            strict=True,
        )
    )


def config_path(name: str | Path) -> Path:
    """The TOML file of a config name (``ippo``) or path (``my.toml``).

    Args:
        name: a bundled config's name (looked up in ``CONFIG_DIR``), or a path ending in
            ``.toml``.

    Returns:
        The path of the file.

    Raises:
        ConfigError: no such file.
    """
    path = Path(name)
    if path.suffix != ".toml":
        path = CONFIG_DIR / f"{name}.toml"
    if not path.is_file():
        names = sorted(p.stem for p in CONFIG_DIR.glob("*.toml"))
        raise ConfigError(f"config {str(name)!r}: no file {path}; the bundled configs are {names}")
    return path


def parse_override(text: str) -> tuple[str, Any]:
    """``"KEY=value"`` as ``(KEY, value)``, the value read as a TOML value (a bare word: a string).

    Args:
        text: one override, ``KEY=value``.

    Returns:
        ``(key, value)``: the key stripped and upper-cased; the value as TOML reads it, or
        the text after ``=``, stripped, when it is not a TOML value.

    Raises:
        ConfigError: no ``=`` in ``text``, nothing before it, or a line break in the value.
    """
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"override {text!r}: expected KEY=value, e.g. TOTAL_TIMESTEPS=2e6")
    if "\n" in raw or "\r" in raw:
        raise ConfigError(f"override {text!r}: a value is one line (no line breaks)")
    try:
        parsed = tomllib.loads(f"v = {raw}")
    except tomllib.TOMLDecodeError:
        parsed = {"v": raw.strip()}
    return key.strip().upper(), parsed["v"]


def settings(name: str | Path) -> dict:
    """The trainer keys a config file sets, as written (not resolved, no run keys).

    Args:
        name: a bundled config's name or a path to a TOML file.

    Returns:
        The file's keys of `SCHEMA` and their values.
    """
    raw = tomllib.loads(config_path(name).read_text())
    return {k: v for k, v in raw.items() if k not in RUN_SCHEMA}


def load(name: str | Path = DEFAULT_CONFIG, overrides=()) -> tuple[dict, dict]:
    """A config file with ``KEY=value`` overrides, split into trainer and run settings.

    Args:
        name: a bundled config's name (``ippo``, ``ppo``, ...) or a path to a TOML file.
        overrides: ``"KEY=value"`` strings, applied after the file.

    Returns:
        ``(config, run)``: the resolved trainer config (`SCHEMA`) and run settings
        (`RUN_SCHEMA`).

    A ``TASK`` override sets the scenario, the traffic and the validation split
    (`VALIDATION_KEYS`) to the task's: the file's ``SCENARIO``, ``TRAFFIC`` and validation
    keys give way to it (an override of any still must match it).

    Raises:
        ConfigError: no such file, an unknown key, or a value the key does not allow; a
            ``SCENARIO`` override other than the config's ``TASK``'s scenario.
    """
    raw = tomllib.loads(config_path(name).read_text())
    given = dict(parse_override(o) for o in overrides)
    if given.get("TASK"):
        task = get_task(resolve({"TASK": given["TASK"]})["TASK"])
        raw["SCENARIO"] = task.scenario
        for key in ("TRAFFIC", *VALIDATION_KEYS):
            raw.pop(key, None)
    raw.update(given)
    if raw.get("TASK") and "SCENARIO" in given:
        task = get_task(resolve({"TASK": raw["TASK"]})["TASK"])
        if given["SCENARIO"] != task.scenario:
            raise ConfigError(
                f"SCENARIO={given['SCENARIO']!r} differs from TASK={task.id!r}'s scenario "
                f"{task.scenario!r}: a task fixes its scenario (add TASK= to train on a "
                "scenario outside the tasks)"
            )
    run = {k: raw.pop(k) for k in list(raw) if k in RUN_SCHEMA}
    return resolve(raw), resolve(run, RUN_SCHEMA)


def build_env_params(config: dict):
    """The training and held-out env parameters of a config.

    Args:
        config: a resolved config (``SCENARIO``, ``TRAFFIC``, ``ENV_KWARGS``,
            ``NUM_EVAL_DAYS``, ``SPLIT_SEED``, ``TASK``).

    Returns:
        ``(train_params, eval_params, train_days, eval_days)``: training resets draw from the
        training days only; the ``NUM_EVAL_DAYS`` held-out days
        (``split_days(num_days, NUM_EVAL_DAYS, seed=SPLIT_SEED)``) are kept for evaluation.
        With ``TASK``, the task's: its scenario, its training data (a shift task's training
        years: ``train_days`` then index them) and its held-out days.

    Raises:
        ConfigError: ``TASK`` with a ``TRAFFIC`` or a held-out split other than the task's;
            ``ENV_KWARGS`` with ``episode_days`` other than 1 (the trainers' evaluation, the
            teachers and the references play one-day episodes).
    """
    days = (config.get("ENV_KWARGS") or {}).get("episode_days", 1)
    if days != 1:
        raise ConfigError(
            f"ENV_KWARGS: episode_days={days!r}, but the trainers support only episode_days=1 "
            "(their evaluation, teachers and references play one-day episodes)"
        )
    if config.get("TASK"):
        return _task_env_params(config)
    kwargs = dict(SCENARIOS[config["SCENARIO"]])
    if config.get("TRAFFIC") is not None:
        kwargs["traffic"] = config["TRAFFIC"]
    kwargs.update(config.get("ENV_KWARGS") or {})
    full = make_params(**kwargs)
    train_days, eval_days = split_days(
        int(full.num_days), int(config["NUM_EVAL_DAYS"]), seed=int(config["SPLIT_SEED"])
    )
    return make_params(**kwargs, reset_days=train_days), full, train_days, eval_days


def _task_env_params(config: dict):
    task = get_task(config["TASK"])
    traffic = task.env_kwargs().get("traffic")
    if config.get("TRAFFIC") is not None and config["TRAFFIC"] != traffic:
        raise ConfigError(
            f"TASK={task.id!r} fixes the traffic at {traffic!r}; got TRAFFIC={config['TRAFFIC']!r}"
        )
    split = (int(config["NUM_EVAL_DAYS"]), int(config["SPLIT_SEED"]))
    if split != (task.num_eval_days, task.split_seed):
        raise ConfigError(
            f"TASK={task.id!r} holds out split_days(..., {task.num_eval_days}, "
            f"seed={task.split_seed}); got NUM_EVAL_DAYS={split[0]}, SPLIT_SEED={split[1]}"
        )
    overrides = dict(config.get("ENV_KWARGS") or {})
    train = task.train_params(**overrides)
    return train, task.scored_params(**overrides), np.asarray(train.reset_days), task.eval_days()


def validation_env(config: dict, built: tuple | None = None) -> tuple:
    """The validation split of a config: what a training run evaluates on while it trains.

    The validation days are training days (never held-out ones), drawn by
    `chargax_marl.evaluation.validation_days`. They are played in the env of their price
    data: the scored env's parameters, or a shift task's training env
    (`chargax_marl.benchmark.tasks.Task.validation_params`); a played day starts from an
    empty station on its day, so the training env's ``reset_days`` would change nothing.

    Args:
        config: a resolved config (the keys of `build_env_params` and `VALIDATION_KEYS`).
        built: what `build_env_params` returned for ``config``, to reuse its parameters
            (the validation then plays in the same scored-env object as the held-out days,
            and a caller's compiled evaluation serves both); None builds them.

    Returns:
        ``(val_params, val_days, val_draws)``: with ``TASK``, the task's
        ``validation_params(**ENV_KWARGS)``, ``validation_days()`` and ``validation_draws``;
        otherwise the config's scored params, ``NUM_VALIDATION_DAYS`` days drawn with
        ``VALIDATION_SEED`` from its training days, and ``VALIDATION_DRAWS``.

    Raises:
        ConfigError: with ``TASK``, a validation key other than the task's (or a traffic or
            held-out split other than the task's, see `build_env_params`); without it,
            ``NUM_VALIDATION_DAYS`` more than the training days.
    """
    _, full_params, train_days, _ = build_env_params(config) if built is None else built
    return _validation_env(config, full_params, train_days)


def _validation_env(config: dict, full_params, train_days) -> tuple:
    """`validation_env` on the config's built training params and days."""
    if config.get("TASK"):
        task = get_task(config["TASK"])
        for key, value in _task_validation(task).items():
            if int(config[key]) != value:
                raise ConfigError(
                    f"TASK={task.id!r} validates with {key}={value!r}; got {key}={config[key]!r}"
                )
        params = full_params
        if task.is_shift:
            params = task.validation_params(**dict(config.get("ENV_KWARGS") or {}))
        return params, task.validation_days(), task.validation_draws
    try:
        days = validation_days(
            train_days, int(config["NUM_VALIDATION_DAYS"]), int(config["VALIDATION_SEED"])
        )
    except ValueError:
        raise ConfigError(
            f"config key NUM_VALIDATION_DAYS={config['NUM_VALIDATION_DAYS']!r} is not allowed: "
            f"expected an integer in [1, {np.size(train_days)}] (the training days)"
        ) from None
    return full_params, days, int(config["VALIDATION_DRAWS"])


def validation_source(config: dict) -> str:
    """Where a config's validation split comes from, in words (for a run's record).

    Args:
        config: a resolved config.

    Returns:
        The task's fields, or the config's `VALIDATION_KEYS`, with their values.
    """
    if config.get("TASK"):
        task = get_task(config["TASK"])
        return (
            f"task {task.id}: num_validation_days={task.num_validation_days}, "
            f"validation_draws={task.validation_draws}, validation_seed={task.validation_seed}"
        )
    return "config: " + ", ".join(f"{k}={config[k]}" for k in VALIDATION_KEYS)
