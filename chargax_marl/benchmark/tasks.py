"""Versioned benchmark tasks: what a score is measured on.

A task fixes everything a score depends on: the scenario's parameters, the held-out days, the
number of car draws per day and the keys that draw them, and the action space the references
were computed in. Two scores of one task id are comparable; a task's version increases
whenever a change of the model moves its references (the shipped references carry the
parameters' fingerprint, so a stale file is refused rather than used).

Key schedule: draw ``r`` of held-out day ``days[i]`` draws its cars (and the policy's keys)
from ``jax.random.split(jax.random.PRNGKey(r), len(days))[i]``: draw 0 is the evaluation of
`chargax_marl.evaluation.evaluate` with its default key.

Distribution-shift tasks are scored on the held-out days of a test price year (or market)
that their training data do not contain: `Task.train_params` gives the training env.

Tasks of one's own: a `Task` takes ``overrides``, `chargax_marl.core.make_params` keywords on
top of its scenario's (another station, traffic or grid connection), and `load_task` reads a
task from a TOML or JSON file (`get_task` takes the file's path as it takes a registered id).

Validation split: a training run follows and selects its policy on `Task.validation_days`,
days drawn from the task's training days (played in `Task.validation_params`, the training
env), under the keys of draws ``0 .. validation_draws - 1`` as above; the held-out days are
played once per finished run, for its score.
"""

from __future__ import annotations

import dataclasses
import functools
import inspect
import json
import os
import re
import tomllib
from collections.abc import Callable, Iterator, Mapping
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import clock, make_params
from chargax_marl.core.data_io import SESSION_MODELS
from chargax_marl.core.params import validate_params
from chargax_marl.core.prices import PriceData, load_prices
from chargax_marl.core.scenarios import SCENARIOS, scenario_kwargs
from chargax_marl.core.types import EnvParams
from chargax_marl.evaluation import split_days, validation_days

NUM_EVAL_DAYS = 100
"""Held-out days per task."""

NUM_VALIDATION_DAYS = 20
"""Validation days per task (drawn from its training days)."""


BOUNDS = ("occupancy", "pooled")
"""The bounds a task's score 1 can be (`Task.bound`)."""

_TASK_KEYWORDS = {
    "prices": "set the task's field 'prices'",
    "session_model": "set the task's field 'session_model'",
    "reset_days": "the task sets it: its training days",
}
"""`make_params` keywords a task sets itself, with what to do instead of overriding them."""

OVERRIDE_KEYS = tuple(
    k for k in inspect.signature(make_params).parameters if k not in _TASK_KEYWORDS
)
"""The `chargax_marl.core.make_params` keywords a task's ``overrides`` may set."""


class _FrozenMapping(Mapping):
    """A read-only, hashable mapping (a task's ``overrides``; its values frozen by `_freeze`),
    so that a `Task` stays hashable and its parameters are cached per task."""

    def __init__(self, items=()):
        self._items = dict(items)

    def __getitem__(self, key: str) -> Any:
        return self._items[key]

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __hash__(self) -> int:
        return hash(tuple(sorted(self._items.items())))

    def __repr__(self) -> str:
        return repr(self._items)


def _freeze(value: Any) -> Any:
    """``value`` with its dicts as `_FrozenMapping` s and its lists as tuples, at any depth.

    Raises:
        TypeError: a value that is not hashable even so (an array, say).
    """
    if isinstance(value, Mapping):
        return _FrozenMapping((k, _freeze(v)) for k, v in value.items())
    if isinstance(value, (list, tuple)):
        return tuple(_freeze(v) for v in value)
    hash(value)
    return value


def _thaw(value: Any) -> Any:
    """The inverse of `_freeze` for `make_params`: `_FrozenMapping` s as dicts."""
    if isinstance(value, _FrozenMapping):
        return {k: _thaw(v) for k, v in value.items()}
    if isinstance(value, tuple):
        return tuple(_thaw(v) for v in value)
    return value


@dataclasses.dataclass(frozen=True)
class Task:
    """A benchmark task.

    Attributes:
        name: the id's middle part (``Chargax-<name>-v<version>``).
        version: increases whenever a model change moves the task's references.
        scenario: a name of `chargax_marl.core.scenarios.SCENARIOS`.
        draws: car draws per held-out day; a policy's per-day profit is the mean over them.
        description: one line for the task table.
        prices: the price data the task is scored on (a bundled dataset name).
        train_prices: price datasets a shift task trains on (empty: the training days of
            ``prices``, the days that are not held out).
        num_eval_days: held-out days, drawn by ``split_days(num_days, num_eval_days,
            split_seed)``.
        split_seed: seed of the held-out split.
        params_fn: builds the scored env's parameters in place of ``scenario`` and
            ``prices`` (a task on a station or prices of one's own; its references are
            built with `chargax_marl.benchmark.references.compute_references`).
        num_validation_days: validation days, drawn from the training days by
            `chargax_marl.evaluation.validation_days` (at most the number of training days,
            checked when the days are first drawn).
        validation_draws: car draws per validation day: 1 on a task of 2 draws, 2 on one of 8
            (a noisier station); a quarter or half of ``draws`` on a fifth of the days keeps
            the evaluations during training a small part of a run.
        validation_seed: seed of the validation draw.
        overrides: `chargax_marl.core.make_params` keywords (`OVERRIDE_KEYS`) applied on top
            of the scenario's, in the scored, training and validation envs alike: another
            station (``station``, ``station_kwargs``), traffic, user profile or grid
            connection (``grid_fraction``). Given as any mapping, kept read-only (dicts at
            any depth read-only too, lists as tuples), so that the task stays hashable.
        source: the task file the task was read from (`load_task`); None for a task made
            in Python. Its references are looked for in the file's folder by default. It
            takes no part in the task's equality.
        session_model: the cars' session model (`chargax_marl.core.data_io.SESSION_MODELS`):
            ``"paper"`` on the version-1 tasks, ``"v2"`` on version 2, ``"v3"`` on version 3.
        bound: the reference that scores 1 (`BOUNDS`): ``"occupancy"``, the LP hindsight
            bound over always-max's port occupancy (`chargax_marl.optimal.bound`), on the
            version-1 and version-3 tasks (on version 3 every policy has that occupancy, so
            the bound is exact up to the continuous currents); ``"pooled"``, the port-pooled
            bound over every policy (`chargax_marl.optimal.pooled`), on version 2.

    Raises:
        ValueError: ``num_validation_days``, ``validation_draws`` or ``validation_seed`` not
            a positive integer; ``overrides`` not a mapping, a key of it that is not one of
            `OVERRIDE_KEYS`, a value that is not hashable once frozen, or overrides together
            with ``params_fn`` (the message names the field, the value and what is allowed).
    """

    name: str
    version: int
    scenario: str
    draws: int
    description: str
    prices: str = "NL-2023"
    train_prices: tuple[str, ...] = ()
    num_eval_days: int = NUM_EVAL_DAYS
    split_seed: int = 0
    params_fn: Callable[[], EnvParams] | None = None
    num_validation_days: int = NUM_VALIDATION_DAYS
    validation_draws: int = 1
    validation_seed: int = 1
    session_model: str = "v2"
    bound: str = "pooled"
    overrides: Mapping[str, Any] = _FrozenMapping()
    source: Path | None = dataclasses.field(default=None, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "overrides", self._frozen_overrides())
        if self.bound not in BOUNDS:
            raise ValueError(
                f"task {self.name!r}: field 'bound' must be one of {list(BOUNDS)}, "
                f"got {self.bound!r}"
            )
        if self.session_model not in SESSION_MODELS:
            raise ValueError(
                f"task {self.name!r}: field 'session_model' must be one of "
                f"{list(SESSION_MODELS)}, got {self.session_model!r}"
            )
        for name in ("num_validation_days", "validation_draws", "validation_seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(
                    f"task {self.name!r}: field {name!r} must be a positive integer, got {value!r}"
                )

    def _frozen_overrides(self) -> _FrozenMapping:
        """``overrides`` checked and frozen (`_freeze`)."""
        given = self.overrides
        if not isinstance(given, Mapping):
            raise ValueError(
                f"task {self.name!r}: field 'overrides' must be a mapping of make_params "
                f"keywords to values, got {given!r}"
            )
        if given and self.params_fn is not None:
            raise ValueError(
                f"task {self.name!r}: field 'overrides' must be empty on a task with params_fn "
                f"(params_fn builds the whole params), got {dict(given)!r}"
            )
        for key, value in given.items():
            if key in _TASK_KEYWORDS:
                raise ValueError(
                    f"task {self.name!r}: field 'overrides' may not set {key!r} "
                    f"({_TASK_KEYWORDS[key]})"
                )
            if key not in OVERRIDE_KEYS:
                raise ValueError(
                    f"task {self.name!r}: field 'overrides' has the key {key!r}, which is not "
                    f"a make_params keyword; allowed: {list(OVERRIDE_KEYS)}"
                )
            try:
                _freeze(value)
            except TypeError:
                raise ValueError(
                    f"task {self.name!r}: override {key!r} must be a number, string, bool, "
                    f"list or table of them, got {value!r} (build such params with params_fn)"
                ) from None
        return _freeze(given)

    @property
    def id(self) -> str:
        """The task id, ``Chargax-<name>-v<version>``."""
        return f"Chargax-{self.name}-v{self.version}"

    @property
    def is_shift(self) -> bool:
        """Whether the task trains on other price data than it is scored on."""
        return bool(self.train_prices)

    def env_kwargs(self) -> dict[str, Any]:
        """The `chargax_marl.core.make_params` keywords of the scored env: the scenario's,
        with the task's ``prices``, ``session_model`` and ``overrides`` on top.

        Raises:
            ValueError: a ``params_fn`` task (it has no keywords).
        """
        if self.params_fn is not None:
            raise ValueError(f"task {self.id!r} builds its params with params_fn, not keywords")
        return scenario_kwargs(
            self.scenario,
            prices=self.prices,
            session_model=self.session_model,
            **_thaw(self.overrides),
        )

    def _kwargs(self, overrides: dict[str, Any]) -> dict[str, Any]:
        """The task's `make_params` keywords with ``overrides`` on top; its session model
        cannot be overridden (another model is another task)."""
        model = overrides.get("session_model", self.session_model)
        if model != self.session_model:
            raise ValueError(
                f"task {self.id!r} runs on session_model={self.session_model!r}; an override "
                f"session_model={model!r} would be another task"
            )
        return {**self.env_kwargs(), **overrides}

    def make_params(self) -> EnvParams:
        """The env parameters the task is scored with (every day of ``prices``)."""
        return _params(self)

    def policy_params(self, num_levels: int | None = None) -> EnvParams:
        """The scored env in a policy's own action space: the task's parameters with
        ``num_levels`` levels per direction (default: the task's). The cars, prices and
        station stay the task's, so the profits compare with the references; only what the
        policy can choose differs.

        Args:
            num_levels: the policy's levels per direction (None: the task's).

        Returns:
            The task's `EnvParams`, with ``num_levels`` replaced where it differs.

        Raises:
            ValueError: ``num_levels`` not a positive integer.
        """
        params = self.make_params()
        if num_levels is None or int(num_levels) == int(params.num_levels):
            return params
        if isinstance(num_levels, bool) or int(num_levels) != num_levels or num_levels < 1:
            raise ValueError(f"field 'num_levels' must be a positive integer, got {num_levels!r}")
        return validate_params(params.replace(num_levels=int(num_levels)))

    def eval_days(self) -> np.ndarray:
        """The held-out days, ``(num_eval_days,)`` int32 indices of ``prices``."""
        return _days(self)[1]

    def train_params(self, **overrides: Any) -> EnvParams:
        """The env a policy for this task trains in: resets draw only days it is not scored
        on (the training days of ``prices``, or every day of ``train_prices``).

        Args:
            **overrides: `chargax_marl.core.make_params` keywords on top of the task's
                (``num_levels=1``: a policy trained in fewer levels); not for ``params_fn``
                tasks.

        Returns:
            The training env's `EnvParams`: the scored env with ``reset_days`` the training
            days, or on a shift task an env over the joined ``train_prices``.

        Raises:
            ValueError: overrides on a ``params_fn`` task, or a ``session_model`` override
                other than the task's.
        """
        if self.params_fn is not None:
            if overrides:
                raise ValueError(f"task {self.id!r} builds its params with params_fn: no overrides")
            train_days = jnp.asarray(_days(self)[0])
            return validate_params(self.make_params().replace(reset_days=train_days))
        if not self.train_prices:
            return make_params(**self._kwargs(overrides), reset_days=_days(self)[0])
        data = [load_prices(p) for p in self.train_prices]
        joined = PriceData(
            "+".join(self.train_prices),
            np.concatenate([d.prices_eur_kwh for d in data]),
            data[0].first_weekday,
            _joined_first_date(data),
            data[0].country if len({d.country for d in data}) == 1 else None,
        )
        return make_params(**{**self._kwargs(overrides), "prices": joined})

    def validation_days(self) -> np.ndarray:
        """The days a training run evaluates its policy on while it trains.

        ``num_validation_days`` days drawn by `chargax_marl.evaluation.validation_days` with
        ``validation_seed`` from the training days: the days that are not held out, or on a
        shift task every day of the joined ``train_prices``. They never include a held-out
        day (a shift task's index another price year).

        Returns:
            ``(num_validation_days,)`` sorted int32 day indices of `validation_params`'s
            price data.

        Raises:
            ValueError: ``num_validation_days`` more than the training days.
        """
        return _validation_days(self).copy()

    def validation_params(self, **overrides: Any) -> EnvParams:
        """The env the validation days are played in.

        On a shift task, the training env (`train_params`: the training years' prices, which
        the validation days index). Otherwise the scored env (`scored_params`): the validation
        days are days of its price data, and a played day starts from an empty station on
        that day, so the training env's restricted ``reset_days`` would change nothing but
        the compiled program, which the held-out evaluation then shares.

        Args:
            **overrides: `chargax_marl.core.make_params` keywords, as for `train_params`.

        Returns:
            The parameters to play `validation_days` in.

        Raises:
            ValueError: overrides on a ``params_fn`` task.
        """
        if self.is_shift:
            return self.train_params(**overrides)
        return self.scored_params(**overrides)

    def scored_params(self, **overrides: Any) -> EnvParams:
        """The scored env with ``overrides`` on top (`make_params` without them).

        Args:
            **overrides: `chargax_marl.core.make_params` keywords on top of the task's.

        Returns:
            The scored env's `EnvParams`.

        Raises:
            ValueError: overrides on a ``params_fn`` task, or a ``session_model`` override
                other than the task's.
        """
        if not overrides:
            return self.make_params()
        if self.params_fn is not None:
            raise ValueError(f"task {self.id!r} builds its params with params_fn: no overrides")
        return make_params(**self._kwargs(overrides))

    def day_keys(self) -> jax.Array:
        """The cars' keys, ``(num_eval_days, draws, 2)`` (the module's key schedule)."""
        n = self.num_eval_days
        return jnp.stack(
            [jax.random.split(jax.random.PRNGKey(r), n) for r in range(self.draws)], axis=1
        )

    def action_space(self) -> str:
        """The action space the references were computed in, in words."""
        p = self.make_params()
        return f"{p.action_mode}, {int(p.num_levels)} levels, v2g={bool(p.v2g)}"


def _joined_first_date(data: list[PriceData]) -> str | None:
    """The first date of price data joined end to end, where their days follow each other
    (the calendar, and so the holidays, of the joined days); else None."""
    if any(d.first_date is None for d in data):
        return None
    for a, b in zip(data, data[1:], strict=False):
        end = np.datetime64(a.first_date) + a.num_days
        if end != np.datetime64(b.first_date):
            return None
    return data[0].first_date


@functools.cache
def _params(task: Task) -> EnvParams:
    if task.params_fn is not None:
        return task.params_fn()
    return make_params(**task.env_kwargs())


@functools.cache
def _training_days(task: Task) -> np.ndarray:
    """The indices of the days a task trains on, in its training env's price data."""
    if not task.train_prices:
        return _days(task)[0]
    days = sum(int(load_prices(p).prices_eur_kwh.shape[0]) for p in task.train_prices)
    params = _params(task)
    return np.arange(clock.num_start_days(days, params.episode_start_hour, params.episode_days))


@functools.cache
def _validation_days(task: Task) -> np.ndarray:
    try:
        return validation_days(_training_days(task), task.num_validation_days, task.validation_seed)
    except ValueError as e:
        raise ValueError(f"task {task.id!r}: {e}") from None


@functools.cache
def _days(task: Task) -> tuple[np.ndarray, np.ndarray]:
    # the days an episode can start on: all of them, or fewer when the scenario's episodes
    # start after midnight or span several days (`clock.num_episode_starts`)
    return split_days(
        clock.num_episode_starts(_params(task)), task.num_eval_days, seed=task.split_seed
    )


_MEDIUM_DRAWS = 2
_HIGH_DRAWS = 8
_HIGH_VALIDATION_DRAWS = 2  # the medium-draw tasks validate on 1 draw (the default)

TASKS: dict[str, Task] = {
    t.id: t
    for t in (
        Task(
            "shopping",
            1,
            "shopping",
            _MEDIUM_DRAWS,
            "the default: shopping users, medium traffic, NL 2023 prices",
            session_model="paper",
            bound="occupancy",
        ),
        Task(
            "shopping-grid25-high",
            1,
            "shopping-grid25-high",
            _HIGH_DRAWS,
            "high traffic, the grid connection at 25 % of what the station could draw",
            session_model="paper",
            bound="occupancy",
            validation_draws=_HIGH_VALIDATION_DRAWS,
        ),
        Task(
            "shopping-grid10-high",
            1,
            "shopping-grid10-high",
            _HIGH_DRAWS,
            "high traffic, the grid connection at 10 %",
            session_model="paper",
            bound="occupancy",
            validation_draws=_HIGH_VALIDATION_DRAWS,
        ),
        Task(
            "shopping-peak",
            1,
            "shopping-peak",
            _MEDIUM_DRAWS,
            "an evening time-of-use surcharge and a peak-demand charge",
            session_model="paper",
            bound="occupancy",
        ),
        Task(
            "workplace",
            1,
            "workplace",
            _MEDIUM_DRAWS,
            "workplace users (long morning stays), medium traffic",
            session_model="paper",
            bound="occupancy",
        ),
        Task(
            "shift-nl2023",
            1,
            "shopping",
            _MEDIUM_DRAWS,
            "train on NL 2021-2022 prices, score on NL 2023",
            session_model="paper",
            bound="occupancy",
            train_prices=("NL-2021", "NL-2022"),
        ),
        Task(
            "shift-nl2024",
            1,
            "shopping",
            _MEDIUM_DRAWS,
            "train on NL 2021-2022 prices, score on NL 2024",
            session_model="paper",
            bound="occupancy",
            prices="NL-2024",
            train_prices=("NL-2021", "NL-2022"),
        ),
        Task(
            "shift-de2023",
            1,
            "shopping",
            _MEDIUM_DRAWS,
            "train on NL 2023 prices, score on DE 2023 (another market)",
            session_model="paper",
            bound="occupancy",
            prices="DE-2023",
            train_prices=("NL-2023",),
        ),
    )
}

_V2 = (
    "shopping",
    "shopping-grid25-high",
    "shopping-grid10-high",
    "shopping-peak",
    "workplace",
    "shift-nl2023",
    "shift-nl2024",
    "shift-de2023",
)
# versions 2 and 3: the same stations, prices and days on the session model v2, scored against
# the port-pooled bound, and on the session model v3, whose departures are fixed when a car
# arrives, so the occupancy bound is exact: every policy has the day's occupancy
TASKS.update(
    (t.id, t)
    for version, session_model, bound in ((2, "v2", "pooled"), (3, "v3", "occupancy"))
    for t in (
        dataclasses.replace(
            TASKS[f"Chargax-{name}-v1"],
            version=version,
            session_model=session_model,
            bound=bound,
        )
        for name in _V2
    )
)
"""Every registered task by id."""


TASK_FILE_SUFFIXES = (".toml", ".json")
"""The suffixes of the task files `load_task` reads (and `get_task` takes as paths)."""


def _is_int(value: Any, least: int) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= least


def _is_str(value: Any) -> bool:
    return isinstance(value, str)


_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")

TASK_FILE_FIELDS: dict[str, tuple[Callable[[Any], bool], str]] = {
    "name": (
        lambda v: isinstance(v, str) and _NAME.fullmatch(v) is not None,
        "a string of letters, digits, '.', '_' and '-' (the id's middle part)",
    ),
    "version": (lambda v: _is_int(v, 1), "an integer >= 1"),
    "scenario": (lambda v: isinstance(v, str) and v in SCENARIOS, "a scenario name"),
    "draws": (lambda v: _is_int(v, 1), "an integer >= 1"),
    "description": (_is_str, "a string"),
    "prices": (_is_str, "a bundled price dataset name (e.g. 'FR-2022')"),
    "train_prices": (
        lambda v: isinstance(v, list) and all(isinstance(x, str) for x in v),
        "a list of price dataset names",
    ),
    "num_eval_days": (lambda v: _is_int(v, 1), "an integer >= 1"),
    "split_seed": (lambda v: _is_int(v, 0), "an integer >= 0"),
    "num_validation_days": (lambda v: _is_int(v, 1), "an integer >= 1"),
    "validation_draws": (lambda v: _is_int(v, 1), "an integer >= 1"),
    "validation_seed": (lambda v: _is_int(v, 1), "an integer >= 1"),
    "session_model": (lambda v: isinstance(v, str) and v in SESSION_MODELS, "a session model"),
    "bound": (lambda v: isinstance(v, str) and v in BOUNDS, f"one of {list(BOUNDS)}"),
    "overrides": (
        lambda v: isinstance(v, dict),
        "a table of make_params keywords (the file's [overrides] section)",
    ),
}
"""The keys of a task file, each with its check and what it allows."""

TASK_FILE_REQUIRED = ("name", "version", "scenario", "draws")
"""The keys a task file must have; the others default as `Task`'s fields do."""


def load_task(path: str | os.PathLike) -> Task:
    """Read a task from a TOML or JSON file.

    The file's keys are `Task`'s fields (`TASK_FILE_FIELDS`; ``name``, ``version``,
    ``scenario`` and ``draws`` are required, ``description`` defaults to ``""``), with
    ``overrides`` a table of `chargax_marl.core.make_params` keywords on top of the
    scenario's::

        name = "shopping-fr2022"
        version = 1
        scenario = "shopping"
        draws = 2
        description = "FR 2022 prices on the default station"
        prices = "FR-2022"

        [overrides]
        grid_fraction = 0.15

    The task's parameters and held-out days are built once here, so that a value
    `make_params` refuses is reported now, with the file's path.

    Args:
        path: a ``.toml`` or ``.json`` file (`TASK_FILE_SUFFIXES`).

    Returns:
        The `Task`, its ``source`` the file's resolved path.

    Raises:
        FileNotFoundError: no such file.
        ValueError: another suffix, a file that does not parse, an unknown key (the message
            lists the allowed ones), a missing required key, a value of the wrong type or
            range (naming the key and the value), an override `Task` or `make_params`
            refuses, or an id that is a registered task's.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in TASK_FILE_SUFFIXES:
        raise ValueError(
            f"{path}: a task file must end in one of {list(TASK_FILE_SUFFIXES)}, got {suffix!r}"
        )
    text = path.read_text()
    try:
        data = tomllib.loads(text) if suffix == ".toml" else json.loads(text)
    except (tomllib.TOMLDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a valid {suffix[1:].upper()} file: {e}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a task file must hold a table of keys, got {data!r}")
    unknown = [k for k in data if k not in TASK_FILE_FIELDS]
    if unknown:
        raise ValueError(
            f"{path}: unknown key {unknown[0]!r}; allowed keys: {list(TASK_FILE_FIELDS)}"
        )
    missing = [k for k in TASK_FILE_REQUIRED if k not in data]
    if missing:
        raise ValueError(
            f"{path}: missing key {missing[0]!r}; required keys: {list(TASK_FILE_REQUIRED)}"
        )
    for key, value in data.items():
        check, allowed = TASK_FILE_FIELDS[key]
        if not check(value):
            raise ValueError(f"{path}: field {key!r} must be {allowed}, got {value!r}")
    fields = {**data, "description": data.get("description", "")}
    if "train_prices" in fields:
        fields["train_prices"] = tuple(fields["train_prices"])
    try:
        task = Task(**fields, source=path.resolve())
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    if task.id in TASKS:
        raise ValueError(
            f"{path}: the task id {task.id!r} is a registered task's; give the file another "
            "name or version"
        )
    try:
        task.eval_days()  # builds the parameters: refuses a value make_params refuses
    except (ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{path}: task {task.id!r}: {e}") from None
    return task


def is_task_file(task: Any) -> bool:
    """Whether `get_task` reads ``task`` as a task file's path.

    Args:
        task: anything `get_task` is given.

    Returns:
        True for a `pathlib.Path` (any ``os.PathLike``) and for a string ending in one of
        `TASK_FILE_SUFFIXES`.
    """
    if isinstance(task, os.PathLike):
        return True
    return isinstance(task, str) and task.lower().endswith(TASK_FILE_SUFFIXES)


def get_task(task: str | os.PathLike | Task) -> Task:
    """The task of an id or of a task file.

    Args:
        task: a registered task id (a key of `TASKS`), the path of a task file (a
            `pathlib.Path`, or a string ending in ``.toml`` or ``.json``: `load_task`), or a
            `Task`, returned as it is.

    Returns:
        The `Task`.

    Raises:
        KeyError: an unknown id; the message lists the registered ones.
        FileNotFoundError: a task file that does not exist.
        ValueError: a task file `load_task` refuses.
    """
    if isinstance(task, Task):
        return task
    if is_task_file(task):
        return load_task(task)
    if not isinstance(task, str) or task not in TASKS:
        raise KeyError(
            f"unknown task {task!r}; registered tasks: {sorted(TASKS)} (or the path of a task "
            f"file ending in {' or '.join(TASK_FILE_SUFFIXES)})"
        )
    return TASKS[task]
