"""Shared argument handling of the experiment runners (small CPU defaults, ``--full`` = paper scale)."""

from __future__ import annotations

import argparse

from baselines.train import FAST

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
