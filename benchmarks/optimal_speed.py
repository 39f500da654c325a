"""How long the MPC's step and the LP hindsight bound's day take, on the default station and
the 25 % grid station (``shopping-grid25-high``).

The MPC runs ``--days`` days through the jitted evaluation loop (host callback included):
ms per step and s per day of the whole loop; with ``--base DIR`` the other checkout's MPC
(its ``optimal/model.py`` and ``optimal/mpc.py``) runs the same days in turn. The host states it saw are then
replayed, and each step's LP is solved, interleaved step by step, from scratch and from the
previous step's basis (as the MPC does) and, with ``--base DIR``, by the LP builder of another
checkout (e.g. ``git worktree add /tmp/base main``). The bound solves ``--bound-days`` days'
LPs with this checkout's builder, each from the previous day's basis (as ``bound_days`` does)
and from scratch, and, with ``--base``, from scratch with the other one's, interleaved day by
day. On the 25 % grid station, ``--reference-days`` held-out days of its task are first played
with every car draw in one batch, as a stored MPC reference is computed. Ratios are
``base / this`` (above 1: this checkout is faster); compare them rather than
the seconds on a shared machine.

Run: ``python benchmarks/optimal_speed.py [--days 2] [--bound-days 8] [--reference-days 1]
[--base /tmp/base]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from chargax_marl import trace as trace_lib
from chargax_marl.benchmark import protocol
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.core import make_params
from chargax_marl.evaluation import run_days
from chargax_marl.optimal import bound as bound_lib
from chargax_marl.optimal import model
from chargax_marl.optimal.mpc import _FIELDS, MPC

REFERENCE_TASKS = {"grid25": "Chargax-shopping-grid25-high-v1"}
"""The task whose stored MPC reference a station's batched timing mimics."""

STATIONS = {
    "default": make_params,
    "grid25": lambda: get_task(REFERENCE_TASKS["grid25"]).make_params(),
}


def load_base(root: str):
    """``chargax_marl/optimal/model.py`` and ``mpc.py`` of the checkout at ``root``, as
    separate modules (its MPC solves with its own model); the rest is this checkout's.

    Returns:
        ``(model_module, mpc_module)``.

    Raises:
        ValueError: ``root`` holds no such files.
    """
    here = Path(root) / "chargax_marl" / "optimal"
    mods = []
    for name in ("model", "mpc"):
        path = here / f"{name}.py"
        if not path.is_file():
            raise ValueError(f"field 'base' must be a checkout with {path}, got {root!r}")
        spec = importlib.util.spec_from_file_location(f"base_optimal_{name}", path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = mod
        # the base MPC imports the base model under the package's name while it loads
        this_model = sys.modules["chargax_marl.optimal.model"]
        if mods:
            sys.modules["chargax_marl.optimal.model"] = mods[0]
        try:
            spec.loader.exec_module(mod)
        finally:
            sys.modules["chargax_marl.optimal.model"] = this_model
        mods.append(mod)
    return tuple(mods)


def mpc_loop(params, days: np.ndarray, base_mpc) -> tuple[list[dict], dict[str, float]]:
    """Run the MPC on ``days`` in the jitted loop (and ``base_mpc``'s, day by day in turn);
    return the host states this checkout's MPC saw and each loop's ms per step (a warm-up
    day first excludes the compile)."""
    seen: list[dict] = []
    loops = {}
    for name, cls in [("this", MPC)] + ([("base", base_mpc.MPC)] if base_mpc else []):
        mpc = cls(params)
        if name == "this":
            act = mpc.host_act

            def record(*arrays, act=act, slot=0):
                seen.append({k: np.asarray(v).copy() for k, v in zip(_FIELDS, arrays)})
                return act(*arrays, slot=slot)

            mpc.host_act = record
        policy = lambda s, kk, mpc=mpc: mpc(s, kk, params)  # noqa: E731
        loops[name] = jax.jit(lambda d, k, policy=policy: run_days(policy, params, d, k))
    key = jax.random.PRNGKey(0)
    for loop in loops.values():
        jax.block_until_ready(loop(days[:1], key))  # compile (one day)
    seen.clear()
    wall = {name: 0.0 for name in loops}
    for d in days:
        for name, loop in loops.items():
            t0 = time.perf_counter()
            jax.block_until_ready(loop(np.array([d]), key))
            wall[name] += time.perf_counter() - t0
    steps = len(days) * params.num_steps
    return seen, {name: 1000.0 * w / steps for name, w in wall.items()}


def replay_lps(params, states: list[dict], base) -> dict[str, float]:
    """Solve each recorded step's LP: warm (this checkout, from the previous step's basis),
    cold (this checkout) and base (``base``'s builder), interleaved; ms per step each."""
    mpc = MPC(params)
    times = {"warm": 0.0, "cold": 0.0, "base": 0.0}
    basis, prev = None, None
    for s in states:
        day, t = int(s["day"]), int(s["timestep"])
        n, econ, sessions = mpc.problem(s)
        if sessions.size == 0:
            continue
        urgency = np.where(sessions.charge_sensitive, mpc.urgency_eur_kwh_h, 0.0)
        common = dict(time_limit_s=mpc.time_limit_s, urgency_eur_kwh_h=urgency)
        if prev is None or prev != (day, t - 1):
            basis = None
        t0 = time.perf_counter()
        sol = model.build_and_solve(
            sessions,
            n,
            mpc.limits,
            econ,
            step_offset=t,
            warm_start=basis,
            keep_basis=True,
            **common,
        )
        times["warm"] += time.perf_counter() - t0
        basis, prev = sol.basis, (day, t)
        t0 = time.perf_counter()
        model.build_and_solve(sessions, n, mpc.limits, econ, **common)
        times["cold"] += time.perf_counter() - t0
        if base is not None:
            t0 = time.perf_counter()
            base.build_and_solve(sessions, n, mpc.limits, econ, **common)
            times["base"] += time.perf_counter() - t0
    return {k: 1000.0 * v / len(states) for k, v in times.items()}


def reference_batch(task_id: str, num_days: int, base_mpc) -> tuple[dict[str, float], bool]:
    """Play the MPC on a task's first ``num_days`` held-out days with every car draw in one
    batch, as a stored reference is computed (``benchmark.protocol.play``; this checkout's MPC
    and ``base_mpc``'s in turn, compile included in each); ms per day-step each, and whether
    the two gave the same totals."""
    task = get_task(task_id)
    params = task.make_params()
    days, keys = task.eval_days()[:num_days], task.day_keys()[:num_days]
    ms, totals = {}, {}
    for name, cls in [("this", MPC)] + ([("base", base_mpc.MPC)] if base_mpc else []):
        t0 = time.perf_counter()
        totals[name] = protocol.play(cls(params), params, days, keys)
        ms[name] = 1000.0 * (time.perf_counter() - t0) / (keys[..., 0].size * params.num_steps)
    same = base_mpc is not None and all(
        np.array_equal(a, b) for a, b in zip(*map(jax.tree.leaves, totals.values()))
    )
    return ms, same


def bound_days(params, num_days: int, base) -> dict[str, float]:
    """The bound's LP on ``num_days`` days, interleaved day by day: this checkout's from the
    previous day's basis (``this``, as `bound_days` solves a task's days) and from scratch
    (``cold``), and ``base``'s from scratch; s per day each, and the largest relative
    difference of a day's value to this checkout's from scratch."""
    days = np.arange(num_days) * 30
    keys = jax.random.split(jax.random.PRNGKey(0), num_days)
    traces = trace_lib.make_traces(params, days, day_keys=keys)
    limits = model.StationLimits.of(params)
    out = {"this": 0.0, "cold": 0.0, "base": 0.0, "max_rel_diff": 0.0}
    basis = None
    for i in range(num_days):
        tr = trace_lib.day_of(traces, i)
        occ = bound_lib.occupancy(params, tr, keys[i])
        n = tr.num_steps
        sessions = model.Sessions.concat(
            [occ.sessions, bound_lib.battery_sessions(params, tr.battery_soc0, 0, n - 1)]
        )
        econ = bound_lib.economics(params, tr)
        tol = float(params.charged_tolerance_kwh)
        t0 = time.perf_counter()
        warm = model.build_and_solve(
            sessions, n, limits, econ, charged_tolerance_kwh=tol, warm_start=basis, keep_basis=True
        )
        out["this"] += time.perf_counter() - t0
        basis = warm.basis
        t0 = time.perf_counter()
        cold = model.build_and_solve(sessions, n, limits, econ, charged_tolerance_kwh=tol)
        out["cold"] += time.perf_counter() - t0
        values = [warm.value_eur]
        if base is not None:
            t0 = time.perf_counter()
            ref = base.build_and_solve(sessions, n, limits, econ, charged_tolerance_kwh=tol)
            out["base"] += time.perf_counter() - t0
            values.append(ref.value_eur)
        for v in values:
            out["max_rel_diff"] = max(
                out["max_rel_diff"], abs(v - cold.value_eur) / abs(cold.value_eur)
            )
    for k in ("this", "cold", "base"):
        out[k] /= num_days
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--days", type=int, default=2, help="MPC days per station")
    parser.add_argument("--bound-days", type=int, default=8, help="LP bound days per station")
    parser.add_argument("--base", default=None, help="another checkout to compare with")
    parser.add_argument(
        "--reference-days",
        type=int,
        default=1,
        help="days of the grid25 task's held-out set played with all its draws in one batch "
        "(0: none)",
    )
    parser.add_argument("--stations", nargs="+", default=list(STATIONS), choices=list(STATIONS))
    args = parser.parse_args()
    if args.days < 1 or args.bound_days < 1 or args.reference_days < 0:
        raise ValueError(
            f"--days and --bound-days must be >= 1 and --reference-days >= 0, got {args.days}, "
            f"{args.bound_days}, {args.reference_days}"
        )
    base, base_mpc = load_base(args.base) if args.base else (None, None)
    print(f"load averages {os.getloadavg()}, {os.cpu_count()} cores, jax {jax.__version__}")
    for name in args.stations:
        if name in REFERENCE_TASKS and args.reference_days > 0:
            ms, same = reference_batch(REFERENCE_TASKS[name], args.reference_days, base_mpc)
            task = get_task(REFERENCE_TASKS[name])
            line = (
                f"{name}: MPC reference {ms['this']:.2f} ms per day-step ({task.id}, "
                f"{args.reference_days} days x {task.draws} draws in one batch, compile included)"
            )
            if base_mpc is not None:
                line += (
                    f"; base {ms['base']:.2f} ms; base/this {ms['base'] / ms['this']:.2f}x; "
                    f"same totals {same}"
                )
            print(line, flush=True)
        params = STATIONS[name]()
        states, ms = mpc_loop(params, np.arange(args.days) * 30 + 10, base_mpc)
        line = f"{name}: MPC loop {ms['this']:.2f} ms/step, {ms['this'] * params.num_steps / 1000:.1f} s/day"
        if base is not None:
            line += f"; base {ms['base']:.2f} ms/step; base/this {ms['base'] / ms['this']:.2f}x"
        print(line + " (jitted loop, host callback included; days in turn)")
        lp = replay_lps(params, states, base)
        line = f"{name}: MPC LP per step: warm {lp['warm']:.2f} ms, cold {lp['cold']:.2f} ms"
        if base is not None:
            line += (
                f", base {lp['base']:.2f} ms; base/warm {lp['base'] / lp['warm']:.2f}x, "
                f"base/cold {lp['base'] / lp['cold']:.2f}x"
            )
        print(line)
        b = bound_days(params, args.bound_days, base)
        line = (
            f"{name}: LP bound {b['this']:.3f} s/day from the previous day's basis, "
            f"{b['cold']:.3f} from scratch (cold/this {b['cold'] / b['this']:.2f}x)"
        )
        if base is not None:
            line += f", base {b['base']:.3f} from scratch (base/this {b['base'] / b['this']:.2f}x)"
        print(f"{line}; values differ by {b['max_rel_diff']:.1e} at most (relative)", flush=True)
    print(f"load averages {os.getloadavg()}")


if __name__ == "__main__":
    main()
