"""Chargax against the peer simulators on PyPI: seconds per 100k random-action steps.

The paper's Table 4 row "100k random steps": EV2Gym 77.95 s, Chargym 36.34 s, SustainGym
1554.57 s, Chargax 1.36 s (GPU). This script measures the peers on PyPI and chargax_marl on
*this* machine in one run:

1. installs each peer into its own virtual environment under ``benchmarks/.peers/<name>``
   (skipped when the venv already works; ``--reinstall`` forces it):

   * EV2Gym 2.0.0: ``pip install ev2gym==2.0.0 --no-deps`` plus the run-time needs of its
     default env (found by running it): gymnasium, pyyaml, matplotlib, pandas, networkx,
     pandapower, numba, multicopula, psutil, setuptools<81 (``pkg_resources``). gurobipy
     (its optimal-control baselines) is not needed for the env and not installed.
   * SustainGym 0.1.7's ``EVChargingEnv``: ``pip install sustaingym==0.1.7 --no-deps`` plus
     its ``evcharging`` extra without mosek (commercial licence; SustainGym falls back to
     ECOS, which is installed): pettingzoo 1.24, gymnasium 0.28, numpy<2, acnportal, cvxpy,
     ecos, pandas, pytz, requests, scikit-learn.

   Chargym is not on PyPI and is not measured (the paper's number is quoted).
2. runs each peer's driver (``benchmarks/peer_drivers/<name>_driver.py``) with the peer's
   venv python in a subprocess: ``action_space.sample()`` actions on the bundled default
   scenario, resets inside the timed loop; the driver prints ``RESULT {json}``. Slow peers run
   fewer steps (``--sustaingym-steps``, default 2880 = 10 days) and are extrapolated
   linearly to 100k steps (stated in the output).
3. times chargax_marl for 100k random env-steps: 1 env (a 100k-step ``lax.scan``) and 16
   vmapped envs (6250 steps x 16 envs), compile time reported separately;
4. optionally (``--ppo``) the wall time of 100k PPO training env-steps with 1 and 16 envs
   and of IPPO, from ``baselines/algos/ppo.py`` / ``baselines/algos/ippo.py`` (``make_train(config)``);
   skipped with a message when those are missing or fail.

Writes ``benchmarks/results/peers.json`` and ``peers.csv`` (``--out``).
Run: ``python benchmarks/peers.py`` or
``python benchmarks/peers.py --skip-peers`` (chargax only).
"""

from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import time
import venv
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE))

PAPER_S_PER_100K = {
    "EV2Gym": 77.95,
    "Chargym": 36.34,
    "SustainGym": 1554.57,
    "Chargax (paper, GPU)": 1.36,
}
STEPS_100K = 100_000

PEERS = {
    "ev2gym": {
        "name": "EV2Gym",
        "nodeps": ["ev2gym==2.0.0"],
        "deps": [
            "gymnasium",
            "pyyaml",
            "matplotlib",
            "pandas",
            "networkx",
            "pandapower",
            "numba",
            "multicopula",
            "psutil",
            "setuptools<81",
        ],
        "check": "import ev2gym.models.ev2gym_env",
        "driver": "ev2gym_driver.py",
        "versions": ["ev2gym", "gymnasium", "numpy", "pandas", "pandapower", "numba"],
    },
    "sustaingym": {
        "name": "SustainGym",
        "nodeps": ["sustaingym==0.1.7"],
        "deps": [
            "pettingzoo==1.24.*",
            "gymnasium==0.28.*",
            "numpy<2",
            "acnportal",
            "cvxpy>=1.3,<2",
            "ecos",
            "pandas>=1.1,<3",
            "pytz",
            "requests",
            "scikit-learn>=1.1.1",
        ],
        "check": "import sustaingym.envs.evcharging",
        "driver": "sustaingym_driver.py",
        "versions": [
            "sustaingym",
            "acnportal",
            "cvxpy",
            "ecos",
            "gymnasium",
            "numpy",
            "pandas",
            "scikit-learn",
        ],
    },
}


# --------------------------------------------------------------------------- peers


def venv_python(peers_dir: Path, name: str) -> Path:
    return peers_dir / name / "bin" / "python"


# The peers' `-c` checks run with `-P` (no current directory on sys.path): from the repository root,
# chargax_marl.egg-info would show the peer's gymnasium our `gymnasium.envs` entry point, which imports jax.
def _run(cmd: list[str], timeout: float | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([str(c) for c in cmd], capture_output=True, text=True, timeout=timeout)


def install_peer(name: str, peers_dir: Path, reinstall: bool = False) -> tuple[Path | None, str]:
    """Create ``peers_dir/name`` and install the peer; return ``(python, message)`` (python None on failure)."""
    spec = PEERS[name]
    py = venv_python(peers_dir, name)
    if py.exists() and not reinstall and _run([py, "-P", "-c", spec["check"]], 300).returncode == 0:
        return py, "already installed"
    try:
        venv.EnvBuilder(with_pip=True, clear=True).create(peers_dir / name)
        for args in (["--no-deps", *spec["nodeps"]], spec["deps"]):
            proc = _run(
                [py, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", *args], 1800
            )
            if proc.returncode != 0:
                return (
                    None,
                    f"pip install {' '.join(args)} failed: {proc.stderr.strip().splitlines()[-3:]}",
                )
        proc = _run([py, "-P", "-c", spec["check"]], 300)
        if proc.returncode != 0:
            return None, f"import check failed: {proc.stderr.strip().splitlines()[-1:]}"
    except (OSError, subprocess.SubprocessError) as exc:
        return None, f"install failed: {exc!r}"
    return py, "installed"


def peer_versions(py: Path, packages: list[str]) -> dict:
    code = (
        "import json, importlib.metadata as m, platform\n"
        f"out = {{'python': platform.python_version()}}\n"
        f"for p in {packages!r}:\n"
        "    try: out[p] = m.version(p)\n"
        "    except Exception: out[p] = None\n"
        "print(json.dumps(out))"
    )
    proc = _run([py, "-P", "-c", code], 120)
    return json.loads(proc.stdout) if proc.returncode == 0 else {}


def parse_result(stdout: str) -> dict:
    """The JSON of the last ``RESULT {...}`` line a driver printed (ValueError when there is none)."""
    for line in reversed(stdout.splitlines()):
        if line.startswith("RESULT "):
            return json.loads(line[len("RESULT ") :])
    raise ValueError("driver printed no RESULT line")


def run_driver(
    python: str | Path,
    driver: str | Path,
    steps: int,
    extra: list[str] | None = None,
    timeout: float = 3600,
) -> dict:
    """Run a peer driver for ``steps`` steps; add ``s_per_100k`` (linear extrapolation) and ``extrapolated``."""
    proc = _run([python, driver, str(steps), *(extra or [])], timeout)
    if proc.returncode != 0:
        raise RuntimeError(
            f"driver exited {proc.returncode}: {proc.stderr.strip().splitlines()[-3:]}"
        )
    res = parse_result(proc.stdout)
    res["s_per_100k"] = res["seconds"] / res["steps"] * STEPS_100K
    res["extrapolated"] = res["steps"] < STEPS_100K
    return res


# --------------------------------------------------------------------------- chargax


def time_chargax(total_steps: int = STEPS_100K, env_counts=(1, 16), repeats: int = 1) -> list[dict]:
    """Seconds for ``total_steps`` random env-steps of the default single-agent env, per env count."""
    from throughput import make_runner, measure

    from chargax_marl.single import Chargax

    env = Chargax()
    params = env.default_params
    rows = []
    for n in env_counts:
        steps = total_steps // n
        compile_s, run_s = measure(make_runner(env, params, n, steps), repeats)
        rows.append(
            {
                "name": f"chargax_marl {n} env" + ("s" if n > 1 else ""),
                "envs": n,
                "steps": steps * n,
                "seconds": run_s,
                "compile_s": compile_s - run_s,
                "s_per_100k": run_s / (steps * n) * STEPS_100K,
                "extrapolated": steps * n < STEPS_100K,
            }
        )
    return rows


def time_training(total_steps: int = STEPS_100K) -> list[dict]:
    """Wall time of ``total_steps`` PPO env-steps (1 and 16 envs) and IPPO (16 envs); [] with a message if unavailable."""
    import importlib

    import jax

    sys.path.insert(0, str(ROOT))
    rows = []
    plans = [
        ("ppo", "PPO(1)", 1),
        ("ppo", "PPO(16)", 16),
        ("ippo", "IPPO(1)", 1),
        ("ippo", "IPPO(16)", 16),
    ]
    for module, label, n in plans:
        try:
            mod = importlib.import_module(f"baselines.algos.{module}")
            config = dict(getattr(mod, "DEFAULT_CONFIG", {}) or {})
            config = _training_config(config, n, total_steps)
            train = jax.jit(mod.make_train(config))
            start = time.perf_counter()
            compiled = train.lower(jax.random.PRNGKey(0)).compile()
            compile_s = time.perf_counter() - start
            start = time.perf_counter()
            jax.block_until_ready(compiled(jax.random.PRNGKey(0)))
            run_s = time.perf_counter() - start
            rows.append(
                {
                    "name": label,
                    "envs": n,
                    "steps": total_steps,
                    "seconds": run_s,
                    "compile_s": compile_s,
                    "s_per_100k": run_s / total_steps * STEPS_100K,
                    "extrapolated": False,
                    "config": {
                        k: v for k, v in config.items() if isinstance(v, (int, float, str, bool))
                    },
                }
            )
            print(
                f"{label:<10} {n:>4} envs  compile {compile_s:7.2f} s  run {run_s:8.2f} s per {total_steps:,} steps",
                flush=True,
            )
        except Exception as exc:  # noqa: BLE001 - report and continue
            print(
                f"SKIP {label}: baselines/{module}.py unavailable or failed: {type(exc).__name__}: {exc}"[
                    :400
                ],
                flush=True,
            )
    return rows


def _training_config(config: dict, num_envs: int, total_steps: int) -> dict:
    """Set the env count and total env-steps under the key names the baselines use."""
    config = dict(config)
    for key in ("NUM_ENVS", "num_envs"):
        if key in config or key == "NUM_ENVS":
            config[key] = num_envs
    for key in ("TOTAL_TIMESTEPS", "total_timesteps"):
        if key in config or key == "TOTAL_TIMESTEPS":
            config[key] = total_steps
    return config


# --------------------------------------------------------------------------- main


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--peers", nargs="*", default=list(PEERS), choices=list(PEERS))
    parser.add_argument("--skip-peers", action="store_true", help="chargax only (no installs)")
    parser.add_argument("--peers-dir", default=str(HERE / ".peers"))
    parser.add_argument("--reinstall", action="store_true")
    parser.add_argument("--ev2gym-steps", type=int, default=STEPS_100K)
    parser.add_argument(
        "--sustaingym-steps", type=int, default=2880, help="extrapolated to 100k (about 11 ms/step)"
    )
    parser.add_argument("--chargax-steps", type=int, default=STEPS_100K)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--ppo", action="store_true", help="also time 100k PPO/IPPO training steps (baselines/)"
    )
    parser.add_argument("--out", default=str(HERE / "results"))
    args = parser.parse_args(argv)

    from throughput import load_info, machine_info

    info = machine_info()
    print(
        f"peers benchmark | {info['cpu']} x{info['cores']} cores | jax {info['jax']} ({info['backend']}) | "
        f"python {info['python']} | {load_info()}",
        flush=True,
    )
    results: dict = {
        "machine": info,
        "paper_s_per_100k": PAPER_S_PER_100K,
        "peers": [],
        "chargax": [],
        "training": [],
        "notes": [],
    }
    peers_dir = Path(args.peers_dir)
    if not args.skip_peers:
        for name in args.peers:
            spec = PEERS[name]
            start = time.perf_counter()
            py, msg = install_peer(name, peers_dir, args.reinstall)
            print(
                f"{spec['name']}: {msg} ({time.perf_counter() - start:.0f} s) in {peers_dir / name}",
                flush=True,
            )
            if py is None:
                results["notes"].append(f"{spec['name']} not measured: {msg}")
                continue
            steps = args.ev2gym_steps if name == "ev2gym" else args.sustaingym_steps
            try:
                res = run_driver(py, HERE / "peer_drivers" / spec["driver"], steps)
            except (RuntimeError, ValueError, subprocess.SubprocessError) as exc:
                print(f"{spec['name']}: run failed: {exc}", flush=True)
                results["notes"].append(f"{spec['name']} run failed: {exc}")
                continue
            res["versions"] = peer_versions(py, spec["versions"])
            res["load"] = load_info()
            results["peers"].append(res)
            print(
                f"{spec['name']} {res['version']}: {res['steps']:,} steps in {res['seconds']:.2f} s "
                f"({res['resets']} resets) -> {res['s_per_100k']:.2f} s per 100k"
                f"{' (extrapolated)' if res['extrapolated'] else ''} | scenario {json.dumps(res['scenario'])} | "
                f"versions {json.dumps(res['versions'])} | {res['load']}",
                flush=True,
            )

    for row in time_chargax(args.chargax_steps, repeats=args.repeats):
        row["load"] = load_info()
        results["chargax"].append(row)
        print(
            f"{row['name']}: {row['steps']:,} env-steps in {row['seconds']:.3f} s (compile {row['compile_s']:.2f} s) "
            f"-> {row['s_per_100k']:.3f} s per 100k | {row['load']}",
            flush=True,
        )

    if args.ppo:
        results["training"] = time_training()

    # the table
    print()
    print(
        f"{'simulator':<24} {'s per 100k steps':>17} {'paper Table 4':>14} {'speed-up chargax 1 env':>23} "
        f"{'speed-up chargax 16 envs':>25}"
    )
    ch = {r["envs"]: r["s_per_100k"] for r in results["chargax"]}
    for res in results["peers"]:
        s = res["s_per_100k"]
        res["speedup_1env"] = s / ch[1] if 1 in ch else None
        res["speedup_16env"] = s / ch[16] if 16 in ch else None
        print(
            f"{res['peer'] + (' *' if res['extrapolated'] else ''):<24} {s:>17.2f} "
            f"{PAPER_S_PER_100K.get(res['peer'], float('nan')):>14.2f} {res['speedup_1env']:>22.0f}x "
            f"{res['speedup_16env']:>24.0f}x"
        )
    print(f"{'Chargym (not on PyPI)':<24} {'-':>17} {PAPER_S_PER_100K['Chargym']:>14.2f}")
    for row in results["chargax"]:
        paper = PAPER_S_PER_100K["Chargax (paper, GPU)"]
        print(f"{row['name']:<24} {row['s_per_100k']:>17.3f} {paper:>14.2f}")
    for row in results["training"]:
        print(f"{row['name'] + ' training':<24} {row['s_per_100k']:>17.2f}")
    if any(r["extrapolated"] for r in results["peers"]):
        print("* extrapolated linearly from fewer steps (see steps above)")
    for note in results["notes"]:
        print("note:", note)
    print(load_info())

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "peers.json").write_text(json.dumps(results, indent=2, default=str))
    with open(out / "peers.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(
            [
                "name",
                "version",
                "steps_measured",
                "seconds_measured",
                "s_per_100k",
                "extrapolated",
                "paper_s_per_100k",
                "speedup_vs_chargax_1env",
                "speedup_vs_chargax_16env",
                "load",
            ]
        )
        for r in results["peers"]:
            writer.writerow(
                [
                    r["peer"],
                    r["version"],
                    r["steps"],
                    f"{r['seconds']:.3f}",
                    f"{r['s_per_100k']:.2f}",
                    r["extrapolated"],
                    PAPER_S_PER_100K.get(r["peer"]),
                    f"{r['speedup_1env']:.1f}",
                    f"{r['speedup_16env']:.1f}",
                    r["load"],
                ]
            )
        for r in results["chargax"] + results["training"]:
            writer.writerow(
                [
                    r["name"],
                    info["jax"],
                    r["steps"],
                    f"{r['seconds']:.3f}",
                    f"{r['s_per_100k']:.3f}",
                    r["extrapolated"],
                    "",
                    "",
                    "",
                    r.get("load", ""),
                ]
            )
    print(f"wrote {out / 'peers.json'} and {out / 'peers.csv'}")
    return results


if __name__ == "__main__":
    main()
