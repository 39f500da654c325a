"""Replay committed runs: their stored held-out evaluation recomputed on this code.

    python -m baselines.analysis.replay results/ippo_shopping_medium results/ppo_shopping_medium

Each run's trainer is rebuilt from its ``results.json`` config, its ``params.msgpack`` loaded,
and every seed's greedy policy scored again on the run's held-out days with its car draws.
The per-day profits are compared with the stored ones at the precision ``results.json`` keeps
them (float32, the simulator's own): ``identical`` when every value is equal to the last bit
there, and the largest absolute difference in EUR/day beside it.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from baselines.config import build_env_params
from baselines.eval import heldout
from baselines.runs import load_run


def replay(run_dir: str | Path) -> dict:
    """Score a stored run's seeds again and compare with its ``results.json``.

    Args:
        run_dir: a run directory of ``python -m baselines.train`` (``results.json``,
            ``params.msgpack``).

    Returns:
        ``{"run", "algo", "seeds", "days", "draws", "identical", "max_abs_eur"}``.
    """
    results, trainer, params = load_run(run_dir)
    config = trainer.config
    _, eval_params, _, days = build_env_params(config)
    days = results["evaluation"].get("days") or days
    draws = int(config["EVAL_DRAWS"])
    make_act = trainer.make_act(eval_params)
    ev = heldout.evaluate_batched(make_act, params, eval_params, days, draws=draws)
    stored = np.asarray(results["evaluation"]["table"][results["algo"]]["daily_profit"], np.float64)
    replayed = np.asarray(ev["daily_profit"], np.float64)
    return {
        "run": str(run_dir),
        "algo": results["algo"],
        "seeds": int(replayed.shape[0]),
        "days": int(replayed.shape[1]),
        "draws": draws,
        "identical": bool(np.array_equal(replayed.astype(np.float32), stored.astype(np.float32))),
        "max_abs_eur": float(np.max(np.abs(replayed - stored))),
    }


def main(argv=None) -> list[dict]:
    """Replay every run directory on the command line and print one line each.

    Args:
        argv: the command-line arguments; ``None`` reads ``sys.argv``.

    Returns:
        One `replay` result per run directory, in order.
    """
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("run_dirs", nargs="+", metavar="RUN_DIR")
    a = p.parse_args(argv)
    out = []
    for run_dir in a.run_dirs:
        r = replay(run_dir)
        out.append(r)
        verdict = (
            "identical" if r["identical"] else f"differs by up to {r['max_abs_eur']:.3g} EUR/day"
        )
        print(
            f"{r['run']}: {r['algo']}, {r['seeds']} seeds x {r['days']} days x {r['draws']} draws: {verdict}",
            flush=True,
        )
    return out


if __name__ == "__main__":
    main()
