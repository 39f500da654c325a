"""Running a trainer: the env batch sharded over devices, and training in jitted chunks under a
progress bar with a callback after each."""

from __future__ import annotations

import functools
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec
from tqdm import tqdm  # plain text bars: no widget (nor warning) in Jupyter kernels

from baselines.algos.ppo_core import HYPER_KEYS

ENV_AXIS = "envs"


def env_mesh(num_envs: int) -> Mesh:
    """A 1-D mesh over every device JAX sees (all hosts after ``jax.distributed.initialize()``).

    Args:
        num_envs: the env batch (``NUM_ENVS``), split evenly over the devices.

    Returns:
        The mesh, its one axis named `ENV_AXIS`.

    Raises:
        ValueError: ``num_envs`` is not a multiple of the number of devices.
    """
    devices = jax.devices()
    if num_envs % len(devices):
        raise ValueError(
            f"NUM_ENVS={num_envs} must be divisible by the number of devices ({len(devices)}: "
            f"{devices[0].platform}); pick a multiple of {len(devices)}"
        )
    return Mesh(np.asarray(devices), (ENV_AXIS,))


def shard_envs(tree, mesh: Mesh):
    """Constrain the leading (env) axis of every array leaf to be split over the mesh.

    Args:
        tree: a pytree whose array leaves have the env batch as their leading axis (scalar
            leaves are left as they are).
        mesh: the mesh (`env_mesh`).

    Returns:
        The same pytree, each leaf of one or more axes under a sharding constraint over
        `ENV_AXIS` (inside ``jit``).
    """
    sharding = NamedSharding(mesh, PartitionSpec(ENV_AXIS))
    return jax.tree.map(
        lambda x: jax.lax.with_sharding_constraint(x, sharding) if jnp.ndim(x) >= 1 else x, tree
    )


def chunk_bounds(total_updates: int, num_chunks: int) -> np.ndarray:
    """Where the chunks of a run start and end.

    Args:
        total_updates: The PPO updates of the whole run.
        num_chunks: How many chunks they are split into.

    Returns:
        ``(num_chunks + 1,)`` the update index at which each chunk starts, then ``total_updates``.
    """
    return np.linspace(0, total_updates, num_chunks + 1).astype(int)


def run_in_chunks(
    train, keys, num_chunks: int, on_chunk=None, desc: str = "train", resume=None, hyper=None
):
    """Run ``train.init`` then ``train.run_updates`` in ``num_chunks`` jitted chunks.

    The runs (seeds, or a sweep's settings x seeds) are vmapped. After each chunk
    ``on_chunk(chunk_index, runner_state, metrics, steps, seconds)`` is called (e.g. an
    evaluation or a checkpoint; the runner state is donated to the next chunk, so copy what
    you keep), under a tqdm progress bar.

    Args:
        train: A `baselines.algos.trainer.Trainer`.
        keys: ``(seeds, 2)`` the seeds' keys (unused when resuming).
        num_chunks: How many chunks the updates are split into (`chunk_bounds`).
        on_chunk: The callback after each chunk, or None.
        desc: The progress bar's label.
        resume: None to start from ``train.init(keys)``, or ``(next_chunk, runner_state,
            metric_chunks, seconds)`` from a checkpoint: the chunk to run next, the runner state
            after the chunks before it, their metrics (one dict per chunk) and the seconds they
            took; training continues exactly as it would have without the interruption.
        hyper: None for the config's values of `baselines.algos.ppo_core.HYPER_KEYS` in every
            run, or ``{key: (runs,)}`` each run's own (a sweep; unused when resuming).

    Returns:
        ``(runner_state, metrics, seconds)`` where ``metrics`` holds arrays ``(seeds, updates)``.
    """
    total = train.num_updates
    bounds = chunk_bounds(total, num_chunks)
    sizes = sorted(set(int(b - a) for a, b in zip(bounds[:-1], bounds[1:]) if b > a))
    steps_per_update = train.config["NUM_ENVS"] * train.config["NUM_STEPS"]
    if resume is None:
        start, chunks, t0 = 0, [], time.time()
        rs = jax.jit(jax.vmap(train.init))(keys, hyper)
    else:
        start, rs, chunks, seconds = resume
        chunks, t0 = list(chunks), time.time() - seconds
    with _bar(total * steps_per_update, desc, int(bounds[start]) * steps_per_update) as bar:
        progress = _Progress(bar, steps_per_update)
        # The runner state is donated: each chunk updates it in place instead of copying the
        # parameters, optimiser moments and env states (``on_chunk`` must not keep its arrays).
        runs = {
            n: jax.jit(functools.partial(_chunk, train, n, progress.update), donate_argnums=0)
            for n in sizes
        }
        for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            if b <= a or i < start:
                continue
            if not progress.started:
                bar.set_postfix_str("compiling the training program")
            rs, m = runs[int(b - a)](rs)
            m = jax.device_get(m)
            chunks.append(m)
            bar.n = int(b) * steps_per_update  # the updates the callbacks counted, exactly
            bar.refresh()
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


def run_settings_in_chunks(
    train,
    keys,
    hyper: dict,
    num_chunks: int,
    on_chunk=None,
    desc: str = "sweep",
    settings_per_batch: int = 1,
):
    """Train several settings of the hyper-parameters, each over the same seeds, as one program.

    Every setting trains exactly the program `run_in_chunks` runs for one setting: its seeds
    vmapped, in the same chunks. The settings are mapped over (``jax.lax.map``), so the program
    is compiled once for all of them; with ``settings_per_batch`` 1 each setting's numbers are
    bit for bit those of `run_in_chunks` with its values, and with more, that many settings
    are vmapped together (faster where the device has parallel width to spare, such as a GPU;
    XLA may then sum in another order, so the numbers agree to float32 rounding).

    Args:
        train: A `baselines.algos.trainer.Trainer` (its shapes and structure are the settings').
        keys: ``(seeds, 2)`` the seeds' keys, the same for every setting.
        hyper: ``{key: (settings,)}`` each setting's values of
            `baselines.algos.ppo_core.HYPER_KEYS`.
        num_chunks: How many chunks the updates are split into (`chunk_bounds`).
        on_chunk: ``on_chunk(chunk_index, runner_state, metrics, steps, seconds)`` after each
            chunk, with leading axes ``(settings, seeds)``, or None; it returns True to stop
            the training there (the metrics then end with that chunk).
        desc: The progress bar's label.
        settings_per_batch: Settings vmapped together; it must divide the number of settings.

    Returns:
        ``(runner_state, metrics, seconds)`` with leading axes ``(settings, seeds)`` and
        metrics ``(settings, seeds, updates)``.

    Raises:
        ValueError: ``hyper`` without every key of ``HYPER_KEYS``, of unequal lengths, or a
            ``settings_per_batch`` that does not divide them.
    """
    missing = sorted(set(HYPER_KEYS) - set(hyper))
    lengths = {int(np.shape(v)[0]) for v in hyper.values()}
    if missing or len(lengths) != 1:
        raise ValueError(
            f"hyper must give every key of {HYPER_KEYS} for the same number of settings; "
            f"missing {missing}, lengths {sorted(lengths)}"
        )
    settings = lengths.pop()
    if settings_per_batch < 1 or settings % settings_per_batch:
        raise ValueError(
            f"settings_per_batch={settings_per_batch} must be a positive divisor of the "
            f"{settings} settings"
        )
    hyper = {k: jnp.asarray(v, jnp.float32) for k, v in hyper.items()}
    total = train.num_updates
    bounds = chunk_bounds(total, num_chunks)
    sizes = sorted(set(int(b - a) for a, b in zip(bounds[:-1], bounds[1:]) if b > a))
    steps_per_update = train.config["NUM_ENVS"] * train.config["NUM_STEPS"]
    t0 = time.time()
    per_setting = jax.vmap(train.init, in_axes=(0, None))
    rs = jax.jit(jax.vmap(per_setting, in_axes=(None, 0)))(keys, hyper)
    batch = None if settings_per_batch == 1 else settings_per_batch
    chunks = []
    with _bar(settings * total * steps_per_update, desc) as bar:
        progress = _Progress(bar, steps_per_update)

        def mapped(n, rs):
            one = functools.partial(_chunk, train, n, progress.update)
            return jax.lax.map(one, rs, batch_size=batch)

        runs = {n: jax.jit(functools.partial(mapped, n), donate_argnums=0) for n in sizes}
        for i, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            if b <= a:
                continue
            if not progress.started:
                bar.set_postfix_str("compiling the training program")
            rs, m = runs[int(b - a)](rs)
            m = jax.device_get(m)
            chunks.append(m)
            if on_chunk is not None and on_chunk(i, rs, m, b * steps_per_update, time.time() - t0):
                break
    metrics = {k: np.concatenate([c[k] for c in chunks], axis=2) for k in chunks[0]}
    return rs, metrics, time.time() - t0


def _bar(total_steps: int, desc: str, initial: int = 0):
    """The training progress bar, counting env-steps."""
    return tqdm(
        total=total_steps,
        initial=initial,
        desc=desc,
        unit="step",
        unit_scale=True,
        dynamic_ncols=True,
    )


def _chunk(train, n: int, report, rs):
    """``n`` updates of every seed (vmapped), reporting each update's training return and
    profit to the host (``report(returns, profits)``, arrays over the seeds) as it finishes.

    Returns:
        ``(runner_state, metrics)`` with metrics ``(seeds, n)``, as ``vmap(run_updates(., n))``.
    """

    def update(rs, _):
        rs, m = jax.vmap(lambda r: train.run_updates(r, 1))(rs)
        m = jax.tree.map(lambda x: x[:, 0], m)
        jax.debug.callback(report, m["episode_return"], m["episode_profit_eur"])
        return rs, m

    rs, m = jax.lax.scan(update, rs, None, length=n)
    return rs, jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), m)


class _Progress:
    """The progress bar's per-update callback: advances the bar by one update and shows the
    latest finished episodes' training return and profit (means over the seeds)."""

    def __init__(self, bar, steps_per_update: int):
        self.bar, self.steps_per_update, self.started = bar, steps_per_update, False
        self.ret = self.profit = float("nan")

    def update(self, returns, profits) -> None:
        self.started = True
        returns, profits = np.asarray(returns), np.asarray(profits)
        if np.isfinite(returns).any():  # not every update ends an episode (rollout < day)
            self.ret, self.profit = float(np.nanmean(returns)), float(np.nanmean(profits))
        self.bar.set_postfix(profit=f"{self.profit:.1f}", ret=f"{self.ret:.1f}", refresh=False)
        self.bar.update(self.steps_per_update)
