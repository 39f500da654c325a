"""What the experiment runners share: their arguments, learning settings, budgets and run records.

Every runner trains on the CPU-sized default budget unless ``--full`` asks for the paper's (1e7
env-steps per seed and the paper's seed count for that figure). ``--settings`` picks the
learning settings: ``tuned`` (default) are those of the learned-agents work (``make train-ppo``
for PPO, ``make train`` for IPPO / MAPPO); ``table3`` are the paper's Table 3 exactly. Every
result file records the budget, the seeds, the settings, the wall time and the machine, and
whether the run was cut from the paper's scale (``cut``), so no cut run reads as the paper's.
A runner refuses to write over the result files of an earlier run, or beside another live
runner at the same path, unless ``--overwrite`` deletes the earlier files (`output`).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from contextlib import AbstractContextManager

import jax
import numpy as np

from baselines import runs
from baselines.config import SCHEMA, build_env_params, resolve, settings
from baselines.eval.heldout import OPTIMAL_CHOICES, baseline_results
from baselines.pipeline import RunOutput, chunked_updates, run
from chargax_marl.machine import machine_info

PAPER_TIMESTEPS = int(1e7)  # Table 3: 1e7 env-steps per seed

TUNED = {
    algo: {
        k: v
        for k, v in settings(algo).items()
        if k not in ("SCENARIO", "TRAFFIC", "TASK", "TOTAL_TIMESTEPS")
    }
    for algo in ("ppo", "ippo", "mappo")
}
"""The ``tuned`` learning settings per algorithm: those of ``baselines/configs/<algo>.toml``
(``make train-ppo``, ``make train``, ``make train-mappo``) without their task, scenario and
budget.
The result files committed before these settings record the ones they ran with (``config``)."""

DEFAULT_TIMESTEPS = 2e6
DEFAULT_SEEDS = 4


def parser(
    doc: str, full_seeds: int, timesteps: float = DEFAULT_TIMESTEPS, seeds: int = DEFAULT_SEEDS
) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--algo", choices=("ppo", "ippo", "mappo"), default="ppo")
    p.add_argument(
        "--full",
        action="store_true",
        help=f"the paper's budget: {PAPER_TIMESTEPS:.0e} env-steps per seed, {full_seeds} seeds",
    )
    p.add_argument(
        "--timesteps", type=float, default=timesteps, help="env-steps per seed (without --full)"
    )
    p.add_argument("--seeds", type=int, default=seeds, help="seeds (without --full)")
    p.add_argument(
        "--settings",
        choices=("tuned", "table3"),
        default="tuned",
        help="learning settings: the learned-agents ones (tuned) or the paper's Table 3 (table3)",
    )
    p.add_argument(
        "--optimal",
        choices=OPTIMAL_CHOICES,
        default="bound",
        help="add the LP hindsight bound (bound, default), also the MPC (mpc), or neither (off)",
    )
    p.add_argument(
        "--overwrite",
        action="store_true",
        help="delete the result files of an earlier run at the same path instead of refusing",
    )
    p.set_defaults(full_seeds=full_seeds)
    return p


def config_of(args) -> tuple[dict, int]:
    """``(training config, seeds)`` of the parsed arguments."""
    base = dict(TUNED[args.algo]) if args.settings == "tuned" else {}
    # the paper's experiments run on its session model (the default is the v2 model)
    base["ENV_KWARGS"] = {"session_model": "paper", **(base.get("ENV_KWARGS") or {})}
    base["TOTAL_TIMESTEPS"] = PAPER_TIMESTEPS if args.full else int(args.timesteps)
    return base, (args.full_seeds if args.full else args.seeds)


def output(
    out: str, overwrite: bool = False, suffixes: Sequence[str] = (".json", ".png")
) -> AbstractContextManager[str]:
    """Claim a runner's result files for the duration of a ``with`` block.

    The runners' outputs follow the rule of a training run's directory
    (`baselines.runs.claim_outputs`): ``out + ".lock"`` is held while the runner runs, and
    result files of an earlier run are refused unless ``overwrite`` deletes them first.

    Args:
        out: The path prefix of the result files (e.g. ``outputs/traffic_sweep``); its folder
            is created.
        overwrite: ``--overwrite``: delete the earlier run's result files instead of refusing.
        suffixes: What the runner appends to ``out`` (default ``.json`` and ``.png``).

    Returns:
        A context manager that yields ``out`` as a string.

    Raises:
        baselines.runs.RunDirError: On entering the block: result files ``out + suffix``
            exist and ``overwrite`` is not given, or another live process runs into ``out``.
    """
    return runs.claim_outputs(out, suffixes, overwrite=overwrite)


def with_env_kwargs(base: dict, **kwargs) -> dict:
    """``base`` with ``kwargs`` added to its ``ENV_KWARGS`` (the others kept)."""
    return {**base, "ENV_KWARGS": {**(base.get("ENV_KWARGS") or {}), **kwargs}}


def with_prices(base: dict, prices: str) -> dict:
    """``base`` with the price dataset ``prices`` (other ``ENV_KWARGS`` kept)."""
    return with_env_kwargs(base, prices=prices)


def eval_setup(base: dict, prices: str, optimal: str = "off") -> tuple:
    """``(full params, held-out days, baseline results)`` of ``base`` on ``prices``."""
    _, full, _, days = build_env_params(resolve(with_prices(base, prices)))
    return full, days, baseline_results(full, days, optimal)


def train_on(algo: str, base: dict, prices: str, seeds: int, baselines: dict) -> RunOutput:
    """Train ``seeds`` seeds on ``prices`` (2 chunks, evaluated once at the end on its own held-out days)."""
    return run(
        algo,
        with_prices(base, prices),
        seeds=seeds,
        chunks=2,
        evaluate_every_chunk=False,
        baselines=baselines,
        quiet=True,
    )


def profit_curve(curve: dict) -> dict:
    """A run's training curve cut to what the runners plot: the timesteps and the sampled
    episode profit per seed. The loss and entropy curves of every cell made the result files
    tens of MB; a run's own ``results.json`` (``baselines.train --out``) keeps them."""
    return {k: curve[k] for k in ("timesteps", "episode_profit_eur")}


def reused_run(path, algo: str, config: dict, seeds: int, chunks: int) -> dict:
    """The results of a run that ``baselines.train`` already made (its ``results.json`` at
    ``path``), checked to be the run that ``run(algo, config, seeds=seeds, chunks=chunks)``
    would make: the same algorithm, seeds (from key 0), learning settings, env-steps, training
    and evaluation parameters and held-out days. Raises ``ValueError`` naming what differs.

    A setting the stored run lacks is accepted at its default (`baselines.algos.PAPER_DEFAULTS`):
    options are added off by default, so the run predates it. The code's version is not
    checked; the result carries ``reused_from`` with the path, the stored run's ``code``
    (commit, where it was recorded) and those options, so a reader can see what was mixed."""

    with open(path) as f:
        res = json.load(f)
    config = resolve(config)
    _, n_upd = chunked_updates(config, chunks)
    want = {
        "algo": algo,
        "seeds": seeds,
        "seed": 0,
        "timesteps": n_upd * config["NUM_ENVS"] * config["NUM_STEPS"],
    }
    diffs = [f"{k}={res.get(k)!r} (this run: {v!r})" for k, v in want.items() if res.get(k) != v]
    theirs = res.get("config", {})
    # an option the stored run predates is taken at its default: options are added off by default
    absent = sorted(
        k
        for k in config
        if k not in theirs and config[k] == (SCHEMA[k].default if k in SCHEMA else object())
    )
    theirs = {**{k: config[k] for k in absent}, **theirs}
    # the runners name the session model; a run stored without it predates the v2 model and
    # ran on the paper's
    theirs["ENV_KWARGS"] = {"session_model": "paper", **(theirs.get("ENV_KWARGS") or {})}
    diffs += [
        f"config {k}={theirs.get(k)!r} (this run: {config.get(k)!r})"
        for k in sorted(set(config) | set(theirs))
        if k not in ("TOTAL_TIMESTEPS", "ENV_KWARGS") and theirs.get(k) != config.get(k)
    ]
    if not diffs:  # ENV_KWARGS may spell the same station differently (a default given or not)
        mine, other = (build_env_params(resolve(c)) for c in (config, theirs))
        same = all(
            jax.tree_util.tree_structure(a) == jax.tree_util.tree_structure(b)
            and all(
                np.array_equal(x, y)
                for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
            )
            for a, b in zip(mine, other)
        )
        if not same:
            diffs.append(
                f"config ENV_KWARGS={theirs.get('ENV_KWARGS')!r} builds another station, "
                f"prices or days than {config['ENV_KWARGS']!r}"
            )
    if diffs:
        raise ValueError(f"{path} is not this run: " + "; ".join(diffs))
    return {
        **res,
        "reused_from": {"path": str(path), "code": res.get("code"), "options_added_since": absent},
    }


class Record:
    """The budget and provenance every runner writes beside its results: start it before the
    first training, call `as_dict` after the last."""

    def __init__(self, args, seeds: int, base: dict, paper_seeds: int | None, figure: str):
        """``paper_seeds``: the paper's seed count for this figure (``None``: no paper counterpart)."""
        self.args, self.seeds, self.base, self.paper_seeds, self.figure = (
            args,
            seeds,
            base,
            paper_seeds,
            figure,
        )
        self.t0 = time.time()

    def as_dict(self) -> dict:
        timesteps = int(self.base["TOTAL_TIMESTEPS"])
        paper = self.paper_seeds is not None
        cut = paper and (timesteps < PAPER_TIMESTEPS or self.seeds < self.paper_seeds)
        info = machine_info()
        return {
            "figure": self.figure,
            "algo": self.args.algo,
            "full": bool(self.args.full),
            "settings": self.args.settings,
            "seeds": self.seeds,
            "timesteps_per_seed": timesteps,
            "paper": {"timesteps_per_seed": PAPER_TIMESTEPS, "seeds": self.paper_seeds}
            if paper
            else None,
            "cut": cut,
            "cut_note": (
                f"cut from the paper's scale: {self.seeds} seeds x {timesteps:.2g} env-steps per seed "
                f"(the paper: {self.paper_seeds} x {PAPER_TIMESTEPS:.0e})"
            )
            if cut
            else "the paper's scale"
            if paper
            else f"no paper counterpart: {self.seeds} seeds x {timesteps:.2g} env-steps per seed",
            "wall_seconds": time.time() - self.t0,
            "machine": info,
        }

    @staticmethod
    def summary(d: dict) -> str:
        """One line of an `as_dict` result, for the log."""
        m = d["machine"]
        return (
            f"{d['figure']}: {d['cut_note']}; {d['wall_seconds'] / 60:.1f} min on {m['cpu']} x{m['cores']} "
            f"({m['backend']})"
        )
