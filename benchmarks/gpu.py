"""Speeds on one accelerator: env-steps/s of both views at 2^10 ... 2^20 envs, and PPO / IPPO
training seconds per 100k env-steps at 1024 envs (the units of the paper's Table 4).

The env rows use the ``make bench`` harness (`envbench`: random actions from a counter
hash, every observation read, auto-reset) on the default device, one jitted ``lax.scan`` per
batch size and view (``single``, ``marl``: the JaxMARL dict API, ``marl_array``: the stacked
path the trainers use). Compile time is reported apart; the rate is the best of ``--repeats``
calls. The training rows are `train_speed.measure_training` with the paper defaults plus
``--train-set``. Every row is printed and appended to ``--out`` as one JSON line as soon as it is
measured, and nothing new starts after ``--budget-s`` seconds, so a run cut short still reports
what it finished.

    python benchmarks/gpu.py --out gpu.jsonl                      # the full sweep
    python benchmarks/gpu.py --exponents 4 6 --train-envs 16      # a quick check on a CPU
    python benchmarks/gpu.py --table benchmarks/results/gpu_h200.jsonl   # the docs' tables
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
import traceback
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import jax  # noqa: E402
from envbench import compiled_rollout, steps_for  # noqa: E402
from throughput import _views, state_bytes  # noqa: E402
from train_speed import _parse_set, measure_training  # noqa: E402


def device_info() -> dict:
    """The accelerator's name (from ``nvidia-smi`` where there is one) and JAX's view of it."""
    dev = jax.devices()[0]
    info = {
        "jax": jax.__version__,
        "platform": dev.platform,
        "device_kind": getattr(dev, "device_kind", ""),
        "python": platform.python_version(),
    }
    try:
        info["nvidia_smi"] = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,memory.total,driver_version", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=20,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        info["nvidia_smi"] = ""
    return info


def env_row(view: str, env, params, num_envs: int, num_steps: int, repeats: int) -> dict:
    """Compile and time one rollout; env-steps/s of the best of ``repeats`` calls."""
    t0 = time.perf_counter()
    fn, _ = compiled_rollout(view, env, params, num_envs, num_steps)
    fn(0)
    compile_s = time.perf_counter() - t0
    best = float("inf")
    for r in range(repeats):
        t0 = time.perf_counter()
        fn(r + 1)
        best = min(best, time.perf_counter() - t0)
    steps = num_envs * num_steps
    return {
        "kind": "env",
        "view": view,
        "envs": num_envs,
        "steps_per_env": num_steps,
        "compile_s": compile_s,
        "run_s": best,
        "env_steps_per_s": steps / best,
        "s_per_100k": best / steps * 100_000,
        "temp_bytes_per_env": fn.temp_bytes_per_env,
    }


def _hidden(row: dict) -> int:
    """The hidden width of a training row (the paper default unless overridden)."""
    return int((row.get("overrides") or {}).get("HIDDEN", 256))


def tables(rows: list[dict]) -> str:
    """Markdown tables of a result file's rows: env-steps/s per view and batch size (with each
    multi-agent path's ratio to the single view), then training seconds per 100k env-steps."""
    device = next((r for r in rows if r["kind"] == "device"), {})
    env = {(r["view"], r["envs"]): r["env_steps_per_s"] for r in rows if r["kind"] == "env"}
    lines = [
        f"Device: {device.get('nvidia_smi') or device.get('device_kind', '?')}, "
        f"jax {device.get('jax', '?')}, Python {device.get('python', '?')}.",
        "",
        "| envs | single env-steps/s | MARL array env-steps/s | MARL dict env-steps/s "
        "| array / single | dict / single |",
        "|---|---|---|---|---|---|",
    ]
    for n in sorted({n for _, n in env}):
        single, array, dict_ = (env.get((v, n)) for v in ("single", "marl_array", "marl"))

        def cell(x):
            return f"{x:,.0f}" if x else "-"

        def ratio(x):
            return f"{x / single:.2f}" if x and single else "-"

        exp = n.bit_length() - 1
        label = f"2^{exp}" if n == 2**exp and n > 16 else str(n)
        lines.append(
            f"| {label} | {cell(single)} | {cell(array)} | {cell(dict_)} "
            f"| {ratio(array)} | {ratio(dict_)} |"
        )
    lines += [
        "",
        "| algorithm | envs | networks | s / 100k env-steps | env-steps/s | / PPO's | compile s |",
        "|---|---|---|---|---|---|---|",
    ]
    order = {"ppo": 0, "ippo": 1, "mappo": 2}
    train = [r for r in rows if r["kind"] == "train"]
    ppo = {(_hidden(r), r["envs"]): r["steps_per_s"] for r in train if r["algo"] == "ppo"}
    for r in sorted(train, key=lambda r: (-_hidden(r), order.get(r["algo"], 9), r["envs"])):
        hidden = _hidden(r)
        base = ppo.get((hidden, r["envs"]))
        ratio = f"{r['steps_per_s'] / base:.2f}" if base else "-"
        lines.append(
            f"| {r['algo'].upper()} | {r['envs']} | 2 x {hidden} | {r['s_per_100k']:.3f} "
            f"| {r['steps_per_s']:,.0f} | {ratio} | {r['compile_s']:.1f} |"
        )
    return "\n".join(lines)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--exponents", type=int, nargs="*", default=[10, 12, 14, 16, 18, 20])
    parser.add_argument("--views", nargs="+", default=["single", "marl_array", "marl"])
    parser.add_argument("--env-steps", type=int, default=2**24, help="env-steps per timed call")
    parser.add_argument("--min-steps", type=int, default=32)
    parser.add_argument("--max-steps", type=int, default=2048)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenario", default="shopping")
    parser.add_argument("--train-envs", type=int, default=1024)
    parser.add_argument("--algos", nargs="*", default=["ppo", "ippo"])
    parser.add_argument("--train-repeats", type=int, default=2)
    parser.add_argument(
        "--train-set", nargs="*", default=[], metavar="KEY=VALUE", help="trainer config overrides"
    )
    parser.add_argument("--budget-s", type=float, default=420.0, help="start nothing after this")
    parser.add_argument("--out", default=None, help="append one JSON line per row here")
    parser.add_argument("--table", default=None, help="print the tables of this result file")
    args = parser.parse_args(argv)
    if args.table:
        print(tables([json.loads(line) for line in Path(args.table).read_text().splitlines()]))
        return

    start = time.perf_counter()
    out = open(args.out, "a") if args.out else None  # noqa: SIM115 (kept open for the run)

    def emit(row: dict) -> None:
        print(json.dumps(row), flush=True)
        if out:
            out.write(json.dumps(row) + "\n")
            out.flush()

    emit({"kind": "device", **device_info()})
    views = _views("chargax_marl", args.scenario, "onehot")
    env, params = views["single"]
    emit({"kind": "state", "bytes_per_env": state_bytes(env, params)})
    for algo in args.algos:  # training first: its rows are the ones the sweep cannot replace
        if time.perf_counter() - start > args.budget_s:
            break
        overrides = _parse_set(args.train_set)
        try:
            (row,) = measure_training(
                (algo,), args.train_envs, repeats=args.train_repeats, overrides=overrides
            )
            row = {k: v for k, v in row.items() if k != "load"}
            emit({"kind": "train", **row})
        except Exception:  # noqa: BLE001 (report and go on with the next row)
            emit({"kind": "error", "what": f"train {algo}", "trace": traceback.format_exc()})
    for exp in args.exponents:
        for view in args.views:
            if time.perf_counter() - start > args.budget_s:
                emit({"kind": "stopped", "at": f"{view} 2^{exp}", "elapsed_s": args.budget_s})
                return
            env, params = views[view]
            n = 2**exp
            try:
                row = env_row(
                    view,
                    env,
                    params,
                    n,
                    steps_for(n, args.env_steps, args.min_steps, args.max_steps),
                    args.repeats,
                )
                emit(row)
            except Exception:  # noqa: BLE001
                emit({"kind": "error", "what": f"{view} 2^{exp}", "trace": traceback.format_exc()})


if __name__ == "__main__":
    main()
