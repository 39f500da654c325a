"""Running a trainer: the env batch sharded over devices, and training in jitted chunks under a
progress bar with a callback after each."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from tqdm.auto import tqdm

ENV_AXIS = "envs"


def env_mesh(num_envs: int) -> Mesh:
    """A 1-D mesh over every device JAX sees (all hosts after ``jax.distributed.initialize()``)."""
    devices = jax.devices()
    if num_envs % len(devices):
        raise ValueError(
            f"NUM_ENVS={num_envs} must be divisible by the number of devices ({len(devices)}: "
            f"{devices[0].platform}); pick a multiple of {len(devices)}"
        )
    return Mesh(np.asarray(devices), (ENV_AXIS,))


def shard_envs(tree, mesh: Mesh):
    """Constrain the leading (env) axis of every array leaf to be split over the mesh."""
    sharding = NamedSharding(mesh, PartitionSpec(ENV_AXIS))
    return jax.tree.map(
        lambda x: jax.lax.with_sharding_constraint(x, sharding) if jnp.ndim(x) >= 1 else x, tree
    )


def run_in_chunks(train, keys, num_chunks: int, on_chunk=None, desc: str = "train"):
    """Run ``train.init`` then ``train.run_updates`` in ``num_chunks`` jitted chunks over the
    vmapped seeds, calling ``on_chunk(chunk_index, runner_state, metrics)`` after each (e.g.
    held-out evaluation; the runner state is donated to the next chunk, so copy what you keep) under a tqdm progress bar. Returns ``(runner_state, metrics, seconds)``
    where ``metrics`` holds arrays ``(seeds, updates)``."""
    total = train.num_updates
    bounds = np.linspace(0, total, num_chunks + 1).astype(int)
    sizes = sorted(set(int(b - a) for a, b in zip(bounds[:-1], bounds[1:]) if b > a))
    init = jax.jit(jax.vmap(train.init))
    # The runner state is donated: each chunk updates it in place instead of copying the
    # parameters, optimiser moments and env states (``on_chunk`` must not keep its arrays).
    runs = {
        n: jax.jit(jax.vmap(lambda rs, n=n: train.run_updates(rs, n)), donate_argnums=0)
        for n in sizes
    }
    t0 = time.time()
    rs = init(keys)
    chunks = []
    steps_per_update = train.config["NUM_ENVS"] * train.config["NUM_STEPS"]
    with tqdm(
        total=total * steps_per_update, desc=desc, unit="step", unit_scale=True, dynamic_ncols=True
    ) as bar:
        for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            if b <= a:
                continue
            rs, m = runs[int(b - a)](rs)
            m = jax.device_get(m)
            chunks.append(m)
            bar.update((b - a) * steps_per_update)
            last = slice(-min(4, b - a), None)  # not every update ends an episode (rollout < day)
            prof = np.nanmean(m["episode_profit_eur"][:, last])
            ret = np.nanmean(m["episode_return"][:, last])
            bar.set_postfix(profit=f"{prof:.1f}", ret=f"{ret:.1f}")
            tqdm.write(
                f"[{desc}] update {b}/{total} steps {b * steps_per_update:.3g}: "
                f"episode profit {prof:.1f} EUR, return {ret:.1f}, "
                f"entropy {np.nanmean(m['entropy'][:, -1]):.2f}, t={time.time() - t0:.0f}s"
            )
            if on_chunk is not None:
                on_chunk(i, rs, m, b * steps_per_update, time.time() - t0)
    metrics = {k: np.concatenate([c[k] for c in chunks], axis=1) for k in chunks[0]}
    return rs, metrics, time.time() - t0
