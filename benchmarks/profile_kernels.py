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


def main(argv=None) -> list[dict]:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--view", choices=["single", "marl"], default="single")
    parser.add_argument("--envs", type=int, default=4096)
    parser.add_argument("--steps", type=int, default=32, help="scan length of the traced call")
    parser.add_argument("--top", type=int, default=25)
    parser.add_argument("--scenario", default="shopping")
    parser.add_argument(
        "--chargax-root",
        default=None,
        help="import chargax_marl from this checkout (e.g. an older commit, for a before/after)",
    )
    args = parser.parse_args(argv)

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    if args.chargax_root:
        sys.path.insert(0, os.path.abspath(args.chargax_root))
    import jax
    import jax.numpy as jnp
    from envbench import rollout_fn
    from jax._src.profiler import ProfileData
    from throughput import _views

    env, params = _views("chargax_marl", args.scenario, "onehot")[args.view]
    fn = jax.jit(rollout_fn(args.view, env, params, args.envs, args.steps))
    sizes = fusion_sizes(fn.lower(jnp.uint32(0)).compile().as_text())
    jax.block_until_ready(fn(jnp.uint32(0)))
    with tempfile.TemporaryDirectory() as folder:
        with jax.profiler.trace(folder):
            jax.block_until_ready(fn(jnp.uint32(1)))
        data = ProfileData.from_file(glob.glob(folder + "/**/*.xplane.pb", recursive=True)[0])
        total_ns = collections.Counter()
        for plane in data.planes:
            for line in plane.lines:
                if not line.name.startswith("tf_XLAEigen"):
                    continue
                for event in line.events:
                    if event.name in sizes:
                        total_ns[event.name] += event.duration_ns
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
