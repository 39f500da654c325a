"""Where a batched env step's time goes, kernel by kernel (XLA's compiled fusions).

``profile_step.py`` times pieces of the transition written in Python; this script times what
XLA actually runs. It compiles the ``make bench`` rollout (``envbench.rollout_fn``: random
actions, auto-reset, every observation element consumed) for one view and batch size on one
device, records one call with ``jax.profiler.trace``, and sums the recorded duration of each
compiled kernel (fusion, copy, scatter, loop) over the call. Printed per kernel: nanoseconds
per env-step, its share of the summed kernel time, its output shape and its number of
operations (a fusion that recomputes another's work shows up as many operations with many
inputs).

    python benchmarks/profile_kernels.py --view single --envs 4096 --top 30
    python benchmarks/profile_kernels.py --view marl --envs 16
    python benchmarks/profile_kernels.py --chargax-root ../old-checkout      # the same for another commit
    python benchmarks/profile_kernels.py --train ippo ppo --config ippo ppo   # trainers' updates

``--train ALGO [ALGO ...]`` profiles two updates of one seed of each training program instead
(``--config NAME [NAME ...]``: a bundled config for all or one per trainer, ``make train``'s
with ``ippo``; ``--envs`` their ``NUM_ENVS``, default each config's), compiled first and then
traced in turn, ``--repeats`` rounds (each kernel's median), so that the machine's changes of
speed between runs do not skew one trainer against another. Each kernel is put in the phase its
number of calls gives away (once per rollout step, per minibatch, per epoch or per update) and
counted as a matrix product or not; printed: milliseconds per update of each phase and kind,
then the top kernels with the operation XLA names as their source.

The kernel times are summed over XLA's worker threads (two kernels may overlap), and the
trace itself adds a fixed cost per kernel, so at 1-16 envs the figures overstate small
kernels; compare kernels within one run, and throughput with ``throughput.py``.
"""

from __future__ import annotations

import argparse
import collections
import glob
import os
import re
import sys
import tempfile

import numpy as np


def fusion_sizes(hlo_text: str) -> dict:
    """``{kernel name: (shape, operations, inputs)}`` from a compiled module's text."""
    bodies, current = {}, None
    for line in hlo_text.splitlines():
        head = re.match(r"^%(\S+) ", line)
        if head and line.rstrip().endswith("{"):
            current = head.group(1)
            bodies[current] = []
        elif line.startswith("}"):
            current = None
        elif current:
            bodies[current].append(line)
    out = {}
    for line in hlo_text.splitlines():
        m = re.match(r"\s*(?:ROOT )?%(\S+) = (\S+) ", line)
        if not m:
            continue
        called = re.search(r"calls=%([\w.\-]+)", line)
        body = bodies.get(called.group(1), []) if called else []
        ops = [re.search(r"= \S+ ([\w-]+)\(", b) for b in body]
        ops = [
            o.group(1)
            for o in ops
            if o and o.group(1) not in ("parameter", "constant", "broadcast", "bitcast")
        ]
        out[m.group(1)] = (m.group(2), len(ops), sum(" parameter(" in b for b in body))
    return out


def source_ops(hlo_text: str) -> dict:
    """``{kernel name: the op_name of its metadata}`` (the JAX operation it came from)."""
    out = {}
    for line in hlo_text.splitlines():
        m = re.match(r'\s*(?:ROOT )?%(\S+) = .*?op_name="([^"]*)"', line)
        if m:
            out[m.group(1)] = m.group(2)
    return out


def kernel_times(fn, arg, sizes: dict) -> tuple[collections.Counter, collections.Counter]:
    """Nanoseconds and calls of each compiled kernel over one traced call ``fn(arg)``."""
    import jax
    from jax._src.profiler import ProfileData

    total_ns, calls = collections.Counter(), collections.Counter()
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder):
            jax.block_until_ready(fn(arg))
        data = ProfileData.from_file(glob.glob(folder + "/**/*.xplane.pb", recursive=True)[0])
        for plane in data.planes:
            for line in plane.lines:
                if not line.name.startswith("tf_XLAEigen"):
                    continue
                for event in line.events:
                    if event.name in sizes:
                        total_ns[event.name] += event.duration_ns
                        calls[event.name] += 1
    return total_ns, calls


def phase_of(calls: int, per_phase: dict) -> str:
    """The phase a kernel called ``calls`` times belongs to: the name in ``per_phase``
    (``{name: calls of a kernel run once per that phase}``) with that count, ``"other"`` for
    none and the names joined by ``"|"`` where several phases share the count."""
    names = [name for name, n in per_phase.items() if n == calls]
    return "|".join(names) if names else "other"


def is_matrix_product(name: str, source: str) -> bool:
    """A kernel that multiplies matrices: XLA's own ``dot`` kernel, or a fusion whose source
    operation is a ``dot_general`` (a library fusion, YNNPACK's on the CPU)."""
    return name.startswith("dot") or source.endswith("dot_general")


def _trainer_program(algo: str, config_name: str | None, num_envs: int | None, updates: int):
    """A trainer's compiled program of ``updates`` updates of one seed, its kernels' shapes and
    sources, and the calls a kernel of each phase makes in one call."""
    import jax
    from train_speed import build

    from baselines.config import SCHEMA, settings

    config = dict(settings(config_name)) if config_name else {}
    config.pop("TOTAL_TIMESTEPS", None)
    get = lambda k: config.get(k, SCHEMA[k].default)  # noqa: E731
    envs = int(num_envs or get("NUM_ENVS"))
    steps, epochs, minibatches = (
        int(get("NUM_STEPS")),
        int(get("UPDATE_EPOCHS")),
        int(get("NUM_MINIBATCHES")),
    )
    train, _ = build(algo, envs, updates * envs * steps, config)
    compiled = train.lower(jax.random.PRNGKey(0)).compile()
    text = compiled.as_text()
    jax.block_until_ready(compiled(jax.random.PRNGKey(0)))
    per_phase = {
        "rollout step": updates * steps,
        "minibatch": updates * epochs * minibatches,
        "epoch": updates * epochs,
        "update": updates,
    }
    title = (
        f"--train {algo} --config {config_name or '(paper defaults)'} | {envs} envs x {steps} "
        f"steps, {epochs} epochs x {minibatches} minibatches"
    )
    return compiled, fusion_sizes(text), source_ops(text), per_phase, title


def profile_training(
    algos: list[str],
    config_names: list[str | None],
    num_envs: int | None,
    top: int,
    repeats: int = 3,
    updates: int = 2,
) -> dict[str, list[dict]]:
    """Profile ``updates`` updates of one seed of each trainer (see the module docstring).

    The trainers' programs are compiled first, then traced in turn, ``repeats`` rounds, so that
    a change of the machine's speed meets all of them alike; each kernel's time is its median
    over the rounds.

    Args:
        algos: the trainers (``ppo``, ``ippo``, ``mappo``).
        config_names: a bundled config per trainer (None: the paper defaults), or one for all.
        num_envs: ``NUM_ENVS``, or None for each config's.
        top: how many of each trainer's longest kernels to print.
        repeats: traced calls per trainer.
        updates: updates per call.

    Returns:
        Per trainer, the rows of its phase table.

    Raises:
        ValueError: ``config_names`` holds neither one config nor one per trainer.
    """
    import jax

    if len(config_names) == 1:
        config_names = list(config_names) * len(algos)
    if len(config_names) != len(algos):
        raise ValueError(
            f"field 'config' must name one config or one per trainer ({len(algos)}), "
            f"got {config_names!r}"
        )
    programs = [
        _trainer_program(a, c, num_envs, updates) for a, c in zip(algos, config_names, strict=True)
    ]
    traced = [[] for _ in programs]
    for r in range(repeats):
        for i, (compiled, sizes, *_) in enumerate(programs):
            traced[i].append(kernel_times(compiled, jax.random.PRNGKey(r + 1), sizes))
    out = {}
    for (_, sizes, sources, per_phase, title), runs in zip(programs, traced, strict=True):
        calls = runs[0][1]
        total_ns = collections.Counter(
            {name: int(np.median([t[0][name] for t in runs])) for name in runs[0][0]}
        )
        summed = sum(total_ns.values())
        groups = collections.defaultdict(lambda: [0, 0])
        for name, ns in total_ns.items():
            kind = "products" if is_matrix_product(name, sources.get(name, "")) else "other"
            g = groups[(phase_of(calls[name], per_phase), kind)]
            g[0] += ns
            g[1] += 1
        print(
            f"\nprofile_kernels {title}, {updates} updates of one seed | {len(total_ns)} kernels, "
            f"summed kernel time {summed / updates / 1e6:.0f} ms per update (each kernel's "
            f"median over {repeats} traced calls, the trainers traced in turn)"
        )
        print(f"{'phase':<14} {'kind':<9} {'kernels':>7} {'ms / update':>11} {'share':>6}")
        rows = []
        for (phase, kind), (ns, n) in sorted(groups.items(), key=lambda kv: -kv[1][0]):
            ms = ns / updates / 1e6
            rows.append(
                {
                    "phase": phase,
                    "kind": kind,
                    "kernels": n,
                    "ms_per_update": ms,
                    "share": ns / summed,
                }
            )
            print(f"{phase:<14} {kind:<9} {n:>7} {ms:>11.1f} {100 * ns / summed:>5.1f}%")
        if top:
            print(f"the {top} kernels with the most time (ms per update, phase, shape, source)")
        for name, ns in total_ns.most_common(top):
            source = sources.get(name, "").split("closed_call/")[-1][:60]
            print(
                f"{ns / updates / 1e6:7.1f} ms  {phase_of(calls[name], per_phase):<13} "
                f"{sizes[name][0][:30]:<30} {name:<30} {source}"
            )
        out[title] = rows
    return out


def main(argv=None) -> list[dict] | dict[str, list[dict]]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--view", choices=["single", "marl", "marl_array"], default="single")
    parser.add_argument(
        "--envs", type=int, default=None, help="env batch (default 4096; --train: the config's)"
    )
    parser.add_argument("--steps", type=int, default=32, help="scan length of the traced call")
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--scenario", default="shopping")
    parser.add_argument(
        "--chargax-root",
        default=None,
        help="import chargax_marl from this checkout (e.g. an older commit, for a before/after)",
    )
    parser.add_argument(
        "--train", nargs="+", metavar="ALGO", help="profile trainers (ppo, ippo, mappo) in turn"
    )
    parser.add_argument(
        "--config",
        nargs="+",
        default=[None],
        help="with --train: a bundled config's settings, one for all trainers or one each",
    )
    parser.add_argument(
        "--repeats", type=int, default=3, help="with --train: traced calls (each kernel's median)"
    )
    args = parser.parse_args(argv)

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    if args.chargax_root:
        sys.path.insert(0, os.path.abspath(args.chargax_root))
    if args.train:
        return profile_training(args.train, args.config, args.envs, args.top, args.repeats)
    args.envs = args.envs or 4096
    import jax
    import jax.numpy as jnp
    from envbench import rollout_fn
    from throughput import _views

    env, params = _views("chargax_marl", args.scenario, "onehot")[args.view]
    fn = jax.jit(rollout_fn(args.view, env, params, args.envs, args.steps))
    sizes = fusion_sizes(fn.lower(jnp.uint32(0)).compile().as_text())
    jax.block_until_ready(fn(jnp.uint32(0)))
    total_ns, _ = kernel_times(fn, jnp.uint32(1), sizes)
    env_steps = args.envs * args.steps
    summed = sum(total_ns.values())
    import chargax_marl

    print(
        f"profile_kernels | {os.path.dirname(os.path.dirname(chargax_marl.__file__))} | view={args.view} envs={args.envs} | {len(total_ns)} kernels, summed kernel time "
        f"{summed / env_steps:.0f} ns per env-step"
    )
    rows = []
    for name, ns in total_ns.most_common(args.top):
        shape, ops, inputs = sizes[name]
        rows.append(
            {
                "kernel": name,
                "ns_per_env_step": ns / env_steps,
                "share": ns / summed,
                "shape": shape,
                "ops": ops,
                "inputs": inputs,
            }
        )
        print(
            f"{ns / env_steps:9.1f} ns {100 * ns / summed:5.1f} %  {name:<32} {shape[:34]:<34} "
            f"{ops:>4} ops {inputs:>3} inputs"
        )
    return rows


if __name__ == "__main__":
    main()
