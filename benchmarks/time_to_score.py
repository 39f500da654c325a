"""Wall-clock to a score: how long PPO, IPPO and MAPPO at their bundled configs take to reach
a quarter and a half of the default task's headroom on its validation days.

    python benchmarks/time_to_score.py                        # ppo, ippo, mappo; 12 chunks
    python benchmarks/time_to_score.py --algos ippo --chunks 20 --out time_to_score.json

Each algorithm's config (``baselines/configs/<algo>.toml``, its seeds and env-steps) is trained
on ``TASK=Chargax-shopping-v1`` by `baselines.sweep` (one setting), scored after each of
``--chunks`` chunks on the task's validation days against always-max and the LP hindsight
bound there. The headroom of a chunk is the mean over seeds of the fraction of the bound's gain
over always-max that each seed's greedy policy captures. Time is the training's wall-clock
since its start, compile included and the evaluations left out; a threshold is reached at the
first chunk whose headroom is at least it, so the resolution is one chunk; the training stops
at the chunk that reaches the last threshold.

Prints the machine, one row per algorithm and threshold, and writes the figures as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # baselines/ is not installed: run from a checkout
from baselines import sweep  # noqa: E402
from chargax_marl.machine import load_info, machine_info  # noqa: E402

TASK = "Chargax-shopping-v1"
THRESHOLDS = (0.25, 0.5)


def time_to_score(algo: str, chunks: int, overrides=()) -> dict:
    """Train ``algo``'s bundled config on the default task and find when it reaches each of
    `THRESHOLDS` of the headroom on the validation days.

    Args:
        algo: ``ppo``, ``ippo`` or ``mappo`` (the bundled config of that name).
        chunks: evaluations over the training (the time's resolution).
        overrides: more ``KEY=value`` strings.

    Returns:
        The config's seeds and env-steps, the validation curve (env-steps, training seconds,
        headroom over seeds) and, per threshold, the env-steps and seconds of the first chunk
        that reaches it (None: not within the config's env-steps).
    """
    results = sweep.sweep(
        algo,
        [f"TASK={TASK}", f"CHUNKS={chunks}", *overrides],
        write=False,
        quiet=True,
        stop_at_headroom=max(THRESHOLDS),
    )
    entry = results["results"][0]
    curve = [
        {
            "timesteps": e["timesteps"],
            "train_seconds": round(e["train_seconds"], 1),
            "headroom": e["headroom"]["mean"],
            "headroom_stderr": e["headroom"]["stderr"],
            "mean_profit": e["mean_profit"],
        }
        for e in entry["eval_curve"]
    ]
    reached = {}
    for t in THRESHOLDS:
        first = next((c for c in curve if c["headroom"] >= t), None)
        reached[str(t)] = (
            None
            if first is None
            else {"timesteps": first["timesteps"], "train_seconds": first["train_seconds"]}
        )
    return {
        "algo": algo,
        "task": TASK,
        "seeds": results["seeds"],
        "timesteps": entry["config"]["TOTAL_TIMESTEPS"],
        "validation_days": len(results["validation"]["days"]),
        "validation_draws": results["validation"]["draws"],
        "overrides": list(overrides),
        "curve": curve,
        "reached": reached,
        "wall_seconds": results["wall_seconds"],
    }


def main(argv=None) -> list[dict]:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--algos", nargs="+", default=["ppo", "ippo", "mappo"])
    p.add_argument("--chunks", type=int, default=12)
    p.add_argument("--set", nargs="*", default=[], metavar="KEY=value", help="config overrides")
    p.add_argument("--out", default=None, help="write the figures to this JSON file")
    a = p.parse_args(argv)
    info = machine_info()
    print(f"machine: {json.dumps(info)}\nload before: {load_info()}")
    rows = []
    for algo in a.algos:
        r = time_to_score(algo, a.chunks, a.set)
        r["machine"] = info
        rows.append(r)
        for t, hit in r["reached"].items():
            when = (
                f"{hit['train_seconds']:.0f} s, {hit['timesteps']:.3g} env-steps"
                if hit
                else f"not within {r['timesteps']:.3g} env-steps"
            )
            print(f"{algo:6s} {r['seeds']} seeds: {float(t):.2f} of the headroom after {when}")
        print(
            f"{algo:6s} curve (env-steps, s, headroom): "
            + ", ".join(
                f"({c['timesteps']:.3g}, {c['train_seconds']:.0f}, {c['headroom']:.2f})"
                for c in r["curve"]
            ),
            flush=True,
        )
        if a.out:
            Path(a.out).write_text(json.dumps(rows, indent=1) + "\n")
    print(f"load after: {load_info()}")
    return rows


if __name__ == "__main__":
    main()
