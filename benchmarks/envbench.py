"""The env-throughput harness shared by ``make bench`` (``throughput.py``) and the A/B tool.

A *rollout* runs ``num_envs`` envs for ``num_steps`` random-action steps inside one jitted
``jax.lax.scan``, with gymnax / JaxMARL auto-reset, and *consumes every element of every
observation* (their sum enters the scan's carry, so XLA can drop none of it). Both views use
the same harness and the same random actions: the single-agent view gets the action vector
``a (L,)``, the multi-agent view the dict ``{agent_i: a[i]}``.

The harness's own randomness (per-env step keys and the random actions) comes from the
counter hash of `chargax_marl.core.rng` rather than ``jax.random``: a Threefry ``split``
per env and a ``randint`` per action entry cost about 0.3 CPU-microseconds per env-step on
this CPU, a third of the target's budget, and are the harness's cost, not the env's. The keys
given to the env are raw ``uint32[2]`` keys, as ``jax.random.PRNGKey`` makes.

With ``devices > 1`` (host devices, ``XLA_FLAGS=--xla_force_host_platform_device_count``)
the env batch is split over the devices with ``shard_map``: XLA runs one CPU thread per
device, so this is how a batch uses both cores of the 2-core CPU. Batches smaller than the
device count, or not divisible by it, run on one device.
"""

from __future__ import annotations

import os
import time


def without_host_devices(xla_flags: str) -> str:
    """``xla_flags`` without a host device count (JAX's default: one CPU device)."""
    return " ".join(f for f in xla_flags.split() if "host_platform_device_count" not in f)


def set_host_devices(count: int) -> None:
    """Expose ``count`` CPU devices to XLA; must run before JAX initialises its backend."""
    flags = without_host_devices(os.environ.get("XLA_FLAGS", "")).split()
    if count > 1:
        flags.append(f"--xla_force_host_platform_device_count={count}")
    os.environ["XLA_FLAGS"] = " ".join(flags)


def _hash_keys(seed, t, n):
    """``(n, 2) uint32`` step keys of envs ``0..n-1`` at step ``t``."""
    import jax.numpy as jnp

    from chargax_marl.core import rng

    s = rng.fmix32(seed + t.astype(jnp.uint32) * rng._GOLDEN)
    return rng.bits(jnp.stack([s, ~s]), 7, (n, 2))


def _hash_actions(seed, t, n, width, num_choices):
    import jax.numpy as jnp

    from chargax_marl.core import rng

    s = rng.fmix32(seed ^ (t.astype(jnp.uint32) * rng._M1))
    return (rng.bits(jnp.stack([~s, s]), 8, (n, width)) % jnp.uint32(num_choices)).astype(jnp.int32)


def rollout_fn(view: str, env, params, num_envs: int, num_steps: int):
    """``run(seed uint32) -> float32`` running one rollout of ``view`` (``single``, ``marl``: the dict API, ``marl_array``: its array path)
    on ``num_envs`` local envs; the result folds in every reward and observation."""
    import jax
    import jax.numpy as jnp

    if view == "single":
        nvec = env.action_space(params).nvec
        width, choices = int(nvec.shape[0]), int(nvec.max())

        def reset(k):
            return env.reset(k, params)

        def step(k, s, a):
            obs, s, r, _, _, _ = env.step(k, s, a, params)
            return obs, s, r

        def consume(obs):
            return obs.sum()
    elif view == "marl":  # the JaxMARL dict API
        agents = env.agents
        width, choices = len(agents), int(env.num_actions)

        def reset(k):
            return env.reset(k)

        def step(k, s, a):
            obs, s, r, _, _ = env.step(k, s, {ag: a[i] for i, ag in enumerate(agents)})
            return obs, s, r[agents[0]]

        def consume(obs):
            return sum(o.sum() for o in obs.values())
    else:  # "marl_array": the multi-agent view's array path (ChargaxMARL.step_arrays)
        width, choices = env.num_agents, int(env.num_actions)

        def reset(k):
            return env.reset(k)

        def step(k, s, a):
            obs, s, r, _, _ = env.step_arrays(k, s, a)
            return obs, s, r[0]

        def consume(obs):
            return obs.sum()

    def run(seed):
        _, state = jax.vmap(reset)(_hash_keys(seed, jnp.uint32(0), num_envs))

        def body(carry, t):
            state, acc = carry
            actions = _hash_actions(seed, t, num_envs, width, choices)
            obs, state, reward = jax.vmap(step)(_hash_keys(seed, t + 1, num_envs), state, actions)
            return (state, acc + reward.sum() + consume(obs)), None

        (_, acc), _ = jax.lax.scan(
            body, (state, jnp.zeros((), jnp.float32)), jnp.arange(num_steps, dtype=jnp.uint32)
        )
        return acc

    return run


class Rollout:
    """A rollout program ``fn(seed: int)`` that blocks until done. Its first call compiles it
    (``lower().compile()``, so the first call's time still includes the compile) and keeps
    XLA's memory analysis of the compiled program.

    Attributes:
        envs_per_device: the envs each device steps.
        temp_bytes: the program's temporaries on one device, bytes (XLA's memory analysis;
            None before the first call, or where the backend gives none).
    """

    def __init__(self, jitted, make_arg, envs_per_device: int):
        self._jitted, self._make_arg, self._exe = jitted, make_arg, None
        self.envs_per_device = envs_per_device
        self.temp_bytes: int | None = None

    @property
    def temp_bytes_per_env(self) -> float | None:
        """`temp_bytes` per env of a device (None where `temp_bytes` is)."""
        return None if self.temp_bytes is None else self.temp_bytes / self.envs_per_device

    def __call__(self, seed: int):
        import jax

        arg = self._make_arg(seed)
        if self._exe is None:
            self._exe = self._jitted.lower(arg).compile()
            memory = self._exe.memory_analysis()
            self.temp_bytes = None if memory is None else int(memory.temp_size_in_bytes)
        return jax.block_until_ready(self._exe(arg))


def compiled_rollout(view: str, env, params, num_envs: int, num_steps: int):
    """The jitted rollout over all envs, split over the host devices when the batch allows.
    Returns ``(fn, devices_used)`` with ``fn`` a `Rollout` (``fn(seed: int)`` blocks until
    done)."""
    import jax
    import jax.numpy as jnp
    import numpy as np
    from jax.sharding import Mesh, PartitionSpec

    devices = jax.devices()
    nd = len(devices)
    if nd > 1 and num_envs >= nd and num_envs % nd == 0:
        local = rollout_fn(view, env, params, num_envs // nd, num_steps)
        mesh = Mesh(np.array(devices), ("envs",))

        def per_device(seeds):
            return local(seeds[0])[None]

        sharded = jax.jit(
            jax.shard_map(
                per_device,
                mesh=mesh,
                in_specs=PartitionSpec("envs"),
                out_specs=PartitionSpec("envs"),
                check_vma=False,
            )
        )

        def seeds(seed: int):
            return jnp.arange(nd, dtype=jnp.uint32) * np.uint32(0x9E3779B9) + np.uint32(seed)

        return Rollout(sharded, seeds, num_envs // nd), nd
    single = jax.jit(rollout_fn(view, env, params, num_envs, num_steps))
    return Rollout(single, jnp.uint32, num_envs), 1


def time_interleaved(fns: dict, repeats: int) -> tuple[dict, dict]:
    """Compile (first call, timed) then time every function ``repeats`` times, round-robin;
    returns ``(compile_s, best_s)`` dicts. Interleaving spreads other load evenly over them."""
    compile_s, best = {}, {}
    for name, fn in fns.items():
        start = time.perf_counter()
        fn(0)
        compile_s[name] = time.perf_counter() - start
        best[name] = float("inf")
    for r in range(repeats):
        for name, fn in fns.items():
            start = time.perf_counter()
            fn(r + 1)
            best[name] = min(best[name], time.perf_counter() - start)
    return compile_s, best


def steps_for(num_envs: int, total: int = 2**19, minimum: int = 96, maximum: int = 8192) -> int:
    """Scan length so that one timed call does about ``total`` env-steps, within
    ``[minimum, maximum]`` steps (small batches run fewer env-steps per call)."""
    return min(max(total // num_envs, minimum), maximum)
