"""Seconds per solve of the port-pooled bound (`chargax_marl.optimal.pooled`) with its first
solver settings (`POOLED_OPTIONS`) against the hindsight bound's (`LP_OPTIONS`), interleaved
on the same days of each task's v2 version. Time it alone.

    python benchmarks/pooled_speed.py --out benchmarks/results/pooled_speed_cpu.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from chargax_marl import trace as trace_lib
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.optimal import model
from chargax_marl.optimal.pooled import pooled_bound


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--tasks", nargs="+", default=["shopping", "shopping-grid10-high"])
    parser.add_argument("--days", type=int, default=2)
    parser.add_argument("--out", default=None)
    args = parser.parse_args(argv)
    settings = {"pooled options": dict(model.POOLED_OPTIONS), "lp options": dict(model.LP_OPTIONS)}
    out = {"settings": settings, "tasks": {}}
    for name in args.tasks:
        task = dataclasses.replace(
            get_task(f"Chargax-{name}-v1"), version=2, session_model="v2", bound="pooled"
        )
        params = task.make_params()
        days, keys = task.eval_days()[: args.days], task.day_keys()[: args.days, 0]
        traces = trace_lib.make_traces(params, days, day_keys=keys)
        seconds = {k: [] for k in settings}
        values = {k: [] for k in settings}
        for i in range(args.days):
            tr = trace_lib.day_of(traces, i)
            for label, options in settings.items():  # interleaved
                saved = dict(model.POOLED_OPTIONS)
                model.POOLED_OPTIONS.clear()
                model.POOLED_OPTIONS.update(options)
                try:
                    t0 = time.perf_counter()
                    b = pooled_bound(params, tr, time_limit_s=600.0)
                    seconds[label].append(time.perf_counter() - t0)
                    values[label].append(b.profit_eur)
                finally:
                    model.POOLED_OPTIONS.clear()
                    model.POOLED_OPTIONS.update(saved)
        out["tasks"][task.id] = {
            "seconds": seconds,
            "bound_eur": values,
            "median_ratio_lp_over_pooled": float(
                np.median(np.array(seconds["lp options"]) / np.array(seconds["pooled options"]))
            ),
        }
        print(task.id, {k: np.round(v, 1).tolist() for k, v in seconds.items()}, flush=True)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
