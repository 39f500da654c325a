"""Shared argument handling and training / evaluation steps of the experiment runners (small CPU
defaults, ``--full`` = paper scale)."""

from __future__ import annotations

import argparse

from baselines import common
from baselines.train import FAST, baseline_results, run

PAPER_SCALE = {"TOTAL_TIMESTEPS": int(1e7)}  # Table 3 hyper-parameters, 1e7 steps


def parser(doc: str, timesteps: float, seeds: int, full_seeds: int) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--algo", choices=("ppo", "ippo", "mappo"), default="ppo")
    p.add_argument("--full", action="store_true",
                   help=f"paper scale: Table 3 hyper-parameters, 1e7 steps, {full_seeds} seeds")
    p.add_argument("--timesteps", type=float, default=timesteps)
    p.add_argument("--seeds", type=int, default=seeds)
    p.add_argument("--full-seeds", type=int, default=full_seeds, help=argparse.SUPPRESS)
    return p


def config_of(args) -> tuple[dict, int]:
    if args.full:
        return dict(PAPER_SCALE), args.full_seeds
    return {**FAST, "TOTAL_TIMESTEPS": int(args.timesteps)}, args.seeds


def with_prices(base: dict, prices: str) -> dict:
    """``base`` with the price dataset ``prices`` (other ``ENV_KWARGS`` kept)."""
    return {**base, "ENV_KWARGS": {**(base.get("ENV_KWARGS") or {}), "prices": prices}}


def eval_setup(base: dict, prices: str) -> tuple:
    """``(full params, held-out days, always-max / price-threshold results)`` of ``base`` on ``prices``."""
    _, full, _, days = common.build_env_params(common.parse_config({}, with_prices(base, prices)))
    return full, days, baseline_results(full, days)


def train_on(algo: str, base: dict, prices: str, seeds: int, baselines: dict) -> dict:
    """Train ``seeds`` seeds on ``prices`` (2 chunks, evaluated once at the end on its own held-out days)."""
    return run(algo, with_prices(base, prices), seeds=seeds, chunks=2, evaluate_every_chunk=False,
               baselines=baselines, quiet=True)
