"""Scaling study: env-steps/s against station size and the number of vmapped envs.

Stations are ``multiple_types(num_dc, num_ac)`` in the default station's 10:6 DC:AC
proportion with 16, 64, 256 and 1024 ports (plus the default battery), run with a random
policy under ``jax.jit`` + ``jax.lax.scan`` for ``jax.vmap`` over 1, 16, 256, 1024 and 4096
envs, for

* ``single``: the single-agent env (`chargax_marl.single.Chargax`);
* ``marl-scalar``: the JaxMARL view with ``agent_id="scalar"`` (observation linear in the
  number of agents; used for every size);
* ``marl-onehot``: the JaxMARL view with the default one-hot agent id (16 ports only: its
  observation is quadratic in the number of agents);
* ``pettingzoo``: the PettingZoo wrapper, one env only (a Python loop, numpy in and out).

Memory budget: a combination is skipped when ``ports * envs > --max-port-envs``
(default 2**20, about one million simulated ports at once, i.e. 1024 ports x 1024 envs).
The scan is short for large configurations (``steps = clamp(--work / (envs * ports/16),
--min-steps, --max-steps)``), compile time is measured separately (first call) and the
run time is the best of ``--repeats`` calls.

Peak memory: every (view, size) runs in a fresh subprocess that goes through the env counts
in increasing order and reads ``ru_maxrss`` after each; the process-wide peak only grows, so
each row's ``peak_rss_mb`` is the peak up to and including that configuration (the largest
configuration so far dominates).

Outputs (``--out``, default ``benchmarks/results``): ``scaling.csv``, ``scaling.png``
(log-log env-steps/s vs envs, one line per station size and view; and time per env-step vs
ports at fixed env counts) and the fitted exponent of time per env-step vs ports.
Run: ``python benchmarks/scaling.py`` or
``python benchmarks/scaling.py --ports 16 --envs 1 2 --views single --work 64`` (smoke).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import resource
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

VIEWS = ("single", "marl-scalar", "marl-onehot", "pettingzoo")
FIELDS = [
    "view",
    "ports",
    "leaves",
    "envs",
    "steps",
    "compile_s",
    "run_s",
    "env_steps_per_s",
    "us_per_env_step",
    "peak_rss_mb",
    "load",
]


def station_kwargs(ports: int) -> dict:
    """``multiple_types`` arguments for ``ports`` ports in the 10:6 DC:AC proportion."""
    num_dc = round(ports * 10 / 16)
    return {"num_dc": num_dc, "num_ac": ports - num_dc}


def rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _single_runner(env, params, num_envs: int, num_steps: int):
    import jax

    space = env.action_space(params)

    @jax.jit
    def run(key):
        keys = jax.random.split(key, num_envs + 1)
        _, states = jax.vmap(env.reset, in_axes=(0, None))(keys[1:], params)

        def body(carry, _):
            states, key = carry
            key, ka, ks = jax.random.split(key, 3)
            actions = jax.random.randint(ka, (num_envs,) + space.shape, 0, space.nvec)
            obs, states, reward, _, _, _ = jax.vmap(env.step, in_axes=(0, 0, 0, None))(
                jax.random.split(ks, num_envs), states, actions, params
            )
            return (states, key), reward.sum() + obs[..., 0].sum()

        _, rewards = jax.lax.scan(body, (states, keys[0]), None, length=num_steps)
        return rewards.sum()

    return run


def run_worker(
    view: str,
    ports: int,
    envs: list[int],
    work: int,
    min_steps: int,
    max_steps: int,
    repeats: int,
    max_port_envs: int,
) -> list[dict]:
    """Measure one (view, station size) over ``envs`` in this process; return the rows."""
    import jax
    import numpy as np
    from marl_throughput import (
        _marl_runner as marl_runner,  # the same rollout as the MARL benchmark
    )
    from throughput import load_info, measure

    from chargax_marl.core.params import make_params

    params = make_params(station="multiple_types", station_kwargs=station_kwargs(ports))
    leaves = int(params.station.num_leaves)
    rows = []
    for n in sorted(envs):
        if view == "pettingzoo" and n != 1:
            continue
        if ports * n > max_port_envs:
            print(
                f"skip {view} ports={ports} envs={n}: ports*envs={ports * n} > budget {max_port_envs}",
                flush=True,
            )
            continue
        steps = int(min(max(work // (n * max(ports // 16, 1)), min_steps), max_steps))
        if view == "pettingzoo":
            from chargax_marl.marl import parallel_env

            pz = (
                parallel_env(params=params, agent_id="scalar")
                if ports > 16
                else parallel_env(params=params)
            )
            rng = np.random.default_rng(0)
            acts = rng.integers(
                0, pz.action_space(pz.possible_agents[0]).n, size=(steps, len(pz.possible_agents))
            )
            start = time.perf_counter()
            pz.reset(seed=0)
            pz.step({a: int(acts[0, i]) for i, a in enumerate(pz.possible_agents)})
            compile_s = time.perf_counter() - start
            run_s = float("inf")
            for _ in range(repeats):
                pz.reset(seed=1)
                start = time.perf_counter()
                for t in range(steps):
                    if not pz.agents:
                        pz.reset()
                    pz.step({a: int(acts[t, i]) for i, a in enumerate(pz.possible_agents)})
                run_s = min(run_s, time.perf_counter() - start)
        else:
            if view == "single":
                from chargax_marl.single import Chargax

                fn = _single_runner(Chargax(params=params), params, n, steps)
            else:
                from chargax_marl.marl import ChargaxMARL

                fn = marl_runner(ChargaxMARL(params=params, agent_id=view.split("-")[1]), n, steps)
            compile_s, run_s = measure(fn, repeats)
            del fn
            jax.clear_caches()
        sps = n * steps / run_s
        row = {
            "view": view,
            "ports": ports,
            "leaves": leaves,
            "envs": n,
            "steps": steps,
            "compile_s": round(compile_s, 3),
            "run_s": round(run_s, 4),
            "env_steps_per_s": round(sps, 1),
            "us_per_env_step": round(1e6 / sps, 3),
            "peak_rss_mb": round(rss_mb(), 1),
            "load": load_info(),
        }
        print("ROW " + json.dumps(row), flush=True)
        rows.append(row)
    return rows


def fit_exponent(rows: list[dict], view: str, envs: int) -> float | None:
    """Least-squares slope of log(time per env-step) against log(ports) at a fixed env count."""
    pts = [
        (r["ports"], r["us_per_env_step"]) for r in rows if r["view"] == view and r["envs"] == envs
    ]
    if len({p for p, _ in pts}) < 2:
        return None
    xs = [math.log(p) for p, _ in pts]
    ys = [math.log(t) for _, t in pts]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / sum((x - mx) ** 2 for x in xs)


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(12, 4.8))
    styles = {"single": "-", "marl-scalar": "--", "marl-onehot": ":"}
    for view, ls in styles.items():
        for ports in sorted({r["ports"] for r in rows if r["view"] == view}):
            pts = sorted(
                (r["envs"], r["env_steps_per_s"])
                for r in rows
                if r["view"] == view and r["ports"] == ports
            )
            if pts:
                ax1.plot(*zip(*pts), ls, marker="o", label=f"{view} {ports} ports")
    pz = [r for r in rows if r["view"] == "pettingzoo"]
    if pz:
        ax1.scatter(
            [1] * len(pz),
            [r["env_steps_per_s"] for r in pz],
            marker="x",
            color="k",
            label="pettingzoo (1 env)",
        )
    ax1.set(
        xscale="log",
        yscale="log",
        xlabel="vmapped envs",
        ylabel="env-steps/s",
        title="throughput (CPU)",
    )
    ax1.legend(fontsize=7)
    for view, ls in styles.items():
        for envs in sorted({r["envs"] for r in rows if r["view"] == view}):
            pts = sorted(
                (r["ports"], r["us_per_env_step"])
                for r in rows
                if r["view"] == view and r["envs"] == envs
            )
            if len(pts) > 1:
                ax2.plot(*zip(*pts), ls, marker="o", label=f"{view} {envs} envs")
    ports = sorted({r["ports"] for r in rows})
    if len(ports) > 1:
        ax2.plot(
            ports,
            [ports[0] and p / ports[0] * min(r["us_per_env_step"] for r in rows) for p in ports],
            "k-",
            lw=0.5,
            label="linear reference",
        )
    ax2.set(
        xscale="log",
        yscale="log",
        xlabel="ports",
        ylabel="us per env-step",
        title="cost per env-step vs ports",
    )
    ax2.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--ports", type=int, nargs="+", default=[16, 64, 256, 1024])
    parser.add_argument("--envs", type=int, nargs="+", default=[1, 16, 256, 1024, 4096])
    parser.add_argument("--views", nargs="+", default=list(VIEWS), choices=VIEWS)
    parser.add_argument(
        "--work",
        type=int,
        default=2**17,
        help="target env-steps per timed call, scaled down by ports/16 (default 131072)",
    )
    parser.add_argument("--min-steps", type=int, default=16)
    parser.add_argument("--max-steps", type=int, default=1024)
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument(
        "--max-port-envs", type=int, default=2**20, help="memory budget: skip ports*envs above this"
    )
    parser.add_argument(
        "--onehot-max-ports", type=int, default=16, help="largest station for marl-onehot"
    )
    parser.add_argument("--out", default=str(HERE / "results"))
    parser.add_argument("--no-plot", action="store_true")
    parser.add_argument("--worker", nargs=2, metavar=("VIEW", "PORTS"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    common = dict(
        work=args.work,
        min_steps=args.min_steps,
        max_steps=args.max_steps,
        repeats=args.repeats,
        max_port_envs=args.max_port_envs,
    )
    if args.worker:
        return run_worker(args.worker[0], int(args.worker[1]), args.envs, **common)

    from throughput import load_info, machine_info

    info = machine_info()
    print(
        f"chargax_marl scaling | {info['cpu']} x{info['cores']} cores | jax {info['jax']} ({info['backend']}) | "
        f"budget ports*envs <= {args.max_port_envs} | {load_info()}",
        flush=True,
    )
    rows: list[dict] = []
    t0 = time.perf_counter()
    for view in args.views:
        for ports in args.ports:
            if view == "marl-onehot" and ports > args.onehot_max_ports:
                continue
            cmd = [
                sys.executable,
                str(Path(__file__).resolve()),
                "--worker",
                view,
                str(ports),
                "--envs",
                *map(str, args.envs),
                "--work",
                str(args.work),
                "--min-steps",
                str(args.min_steps),
                "--max-steps",
                str(args.max_steps),
                "--repeats",
                str(args.repeats),
                "--max-port-envs",
                str(args.max_port_envs),
            ]
            proc = subprocess.run(cmd, capture_output=True, text=True)
            for line in proc.stdout.splitlines():
                if line.startswith("ROW "):
                    r = json.loads(line[4:])
                    rows.append(r)
                    print(
                        f"{r['view']:>12} ports={r['ports']:>5} envs={r['envs']:>5} steps={r['steps']:>5} "
                        f"compile {r['compile_s']:7.2f} s  {r['env_steps_per_s']:>12,.0f} env-steps/s  "
                        f"{r['us_per_env_step']:>9.2f} us/env-step  peak {r['peak_rss_mb']:>7.0f} MB  {r['load']}",
                        flush=True,
                    )
                elif line.startswith("skip"):
                    print(line, flush=True)
            if proc.returncode != 0:
                print(
                    f"FAILED {view} ports={ports}: {proc.stderr.strip().splitlines()[-1:]}",
                    flush=True,
                )
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if rows:
        with open(out / "scaling.csv", "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=FIELDS)
            writer.writeheader()
            writer.writerows(rows)
    for view in ("single", "marl-scalar"):
        for envs in sorted({r["envs"] for r in rows if r["view"] == view}):
            k = fit_exponent(rows, view, envs)
            if k is not None:
                n = len([r for r in rows if r["view"] == view and r["envs"] == envs])
                print(
                    f"exponent of time per env-step vs ports: {view:>12} envs={envs:>5}: {k:.2f} ({n} sizes)"
                )
    for view in ("single", "marl-scalar", "marl-onehot"):
        for ports in sorted({r["ports"] for r in rows if r["view"] == view}):
            pts = sorted(
                (r["envs"], r["env_steps_per_s"])
                for r in rows
                if r["view"] == view and r["ports"] == ports
            )
            if len(pts) > 1:
                best = max(pts, key=lambda p: p[1])
                gains = " ".join(f"{e}:{s:,.0f}" for e, s in pts)
                print(
                    f"saturation {view:>12} ports={ports:>5}: peak {best[1]:,.0f} env-steps/s at {best[0]} envs ({gains})"
                )
    if rows and not args.no_plot:
        plot(rows, out / "scaling.png")
        print(f"wrote {out / 'scaling.csv'} and {out / 'scaling.png'}")
    print(f"total {time.perf_counter() - t0:.0f} s | {load_info()}")
    return rows


if __name__ == "__main__":
    main()
