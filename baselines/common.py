"""Pieces shared by the PPO, IPPO and MAPPO trainers.

Networks (separate actor and critic MLPs) and their relative-price inputs, masked factored
categoricals, GAE, the clipped PPO loss, the optimiser with an annealed learning rate, sharding
of the env batch over devices, the chunked runner and held-out evaluation of trained
parameters. The reward shaping is :mod:`baselines.shaping`; what a run writes (checkpoints,
JSON, plots) is :mod:`baselines.outputs`.
"""

from __future__ import annotations

import time
from typing import Any, Callable, Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax.linen.initializers import constant, variance_scaling
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from chargax_marl.core.params import make_params
from chargax_marl.evaluation import METRICS, run_days, split_days, summarize

NEG_INF = -1e9

# Paper Table 3 (PPO hyper-parameters); the trainers start from these.
PAPER_DEFAULTS: dict[str, Any] = {
    "LR": 2.5e-4,
    "ANNEAL_LR": True,
    "GAMMA": 0.99,
    "GAE_LAMBDA": 0.95,
    "MAX_GRAD_NORM": 100.0,
    "CLIP_EPS": 0.2,
    "VF_CLIP": 10.0,
    "ENT_COEF": 0.01,
    "VF_COEF": 0.25,
    "NUM_ENVS": 12,
    "NUM_STEPS": 300,
    "NUM_MINIBATCHES": 4,
    "UPDATE_EPOCHS": 4,
    "TOTAL_TIMESTEPS": int(1e7),
    # Ours (the paper does not state them):
    "HIDDEN": 256,
    "NUM_LAYERS": 2,
    "ACTIVATION": "tanh",
    "REWARD_SCALE": 1.0,  # rewards (EUR per step) are multiplied by this before GAE
    "ALWAYS_MAX_PRIOR": 0.0,  # logit offset on each port's full-power action (0: none)
    "BATTERY_IDLE_PRIOR": 0.0,  # logit offset on each battery's idle action (0: none)
    "LOCAL_REWARD_WEIGHT": 0.0,  # IPPO/MAPPO: ChargaxMARL(local_reward_weight=...) (0: shared reward)
    "BATTERY_SHAPING": False,  # value the batteries' energy change at every step, not at the day's end
    "PORT_SHAPING": "off",  # "plan": each parked car's remaining demand valued by its best plan (baselines/car_value.py)
    "SCENARIO": "shopping",
    "TRAFFIC": None,  # low / medium / high or cars per day; None: the scenario's own (medium for "shopping")
    "ENV_KWARGS": {},  # extra keyword arguments of make_params (station, prices, alpha, step_minutes, ...)
    "NUM_EVAL_DAYS": 100,
    "EVAL_DRAWS": 1,  # car draws per held-out day, keys PRNGKey(0 .. EVAL_DRAWS - 1), averaged per day (draw_keys)
    "SPLIT_SEED": 0,
}


# --------------------------------------------------------------------------- env parameters


def build_env_params(config: dict):
    """``(train_params, eval_params, train_days, eval_days)`` for a config.

    Training resets draw from the training days only; the ``NUM_EVAL_DAYS`` held-out days
    (``split_days(num_days, NUM_EVAL_DAYS, seed=SPLIT_SEED)``) are kept for evaluation.
    """
    from chargax_marl.single.scenarios import SCENARIOS

    kwargs = dict(SCENARIOS[config["SCENARIO"]])
    if config.get("TRAFFIC") is not None:
        kwargs["traffic"] = config["TRAFFIC"]
    kwargs.update(config.get("ENV_KWARGS") or {})
    full = make_params(**kwargs)
    train_days, eval_days = split_days(int(full.num_days), int(config["NUM_EVAL_DAYS"]), seed=int(config["SPLIT_SEED"]))
    return make_params(**kwargs, reset_days=train_days), full, train_days, eval_days


# --------------------------------------------------------------------------- networks


def _act(name: str) -> Callable:
    return {"tanh": nn.tanh, "relu": nn.relu}[name]


def _init(gain: float):
    """Gaussian init with the variance of an orthogonal init of this gain (``gain**2 / fan_in``).

    Not ``orthogonal``: its batched QR (under ``jax.vmap`` over seeds) runs LAPACK on XLA's
    CPU thread pool, which deadlocked on this 2-core machine under load (jaxlib 0.10).
    """
    return variance_scaling(gain**2, "fan_in", "normal")


class MLP(nn.Module):
    """``NUM_LAYERS`` hidden layers then a linear head (PureJaxRL's gains: sqrt(2) hidden,
    0.01 policy head, 1 value head)."""

    out: int
    hidden: int = 256
    layers: int = 2
    activation: str = "tanh"
    head_scale: float = 0.01

    @nn.compact
    def __call__(self, x):
        for _ in range(self.layers):
            x = _act(self.activation)(nn.Dense(self.hidden, kernel_init=_init(np.sqrt(2)),
                                               bias_init=constant(0.0))(x))
        return nn.Dense(self.out, kernel_init=_init(self.head_scale), bias_init=constant(0.0))(x)


def actor_critic(config: dict, num_logits: int, num_values: int = 1):
    kw = dict(hidden=int(config["HIDDEN"]), layers=int(config["NUM_LAYERS"]), activation=config["ACTIVATION"])
    return MLP(num_logits, head_scale=0.01, **kw), MLP(num_values, head_scale=1.0, **kw)


def always_max_prior(config: dict) -> tuple[float, float]:
    """The validated ``(ALWAYS_MAX_PRIOR, BATTERY_IDLE_PRIOR)``: fixed offsets ``>= 0`` added to
    the logit of the action that the always-max baseline takes, full power at every port and
    idle at every battery. With both ``> 0`` the untrained greedy policy *is* always-max and
    the sampled policy explores around it (an offset of 6 leaves about 5 % of a 21-action
    head's mass on the other 20 actions, 2 about 73 %); training moves away from the
    baseline wherever that pays, since the network's logits can outweigh the offsets. A
    weaker battery offset keeps the battery exploring. ``0`` is the plain policy."""
    out = []
    for name in ("ALWAYS_MAX_PRIOR", "BATTERY_IDLE_PRIOR"):
        b = float(config.get(name, 0.0))
        if not np.isfinite(b) or b < 0:
            raise ValueError(f"{name}={b} must be a finite number >= 0 (0 disables the offset)")
        out.append(b)
    return tuple(out)


# --------------------------------------------------------------------------- relative prices (a network input)


def relative_price_columns(params, context_start: int):
    """``(price_cols, q20_col, q50_col, q80_col)``: where an observation whose shared context
    (:func:`chargax_marl.core.observation.context_features`) starts at column ``context_start``
    holds the observed buy prices (now and the next hours) and the day's 20 / 50 / 80 % price
    quantiles. The single-agent observation ends with the context; a
    :class:`chargax_marl.marl.ChargaxMARL` agent's has the agent index after it."""
    from chargax_marl.core import observation

    prices = context_start + np.arange(int(params.price_horizon_hours) + 1)
    q0 = context_start + observation.context_index(params, "price_quantiles")
    qi = {q: q0 + observation.PRICE_QUANTILES.index(q) for q in (0.2, 0.5, 0.8)}
    return prices, qi[0.2], qi[0.5], qi[0.8]


def with_relative_prices(obs, columns) -> jnp.ndarray:
    """The network input: ``obs`` with :func:`relative_prices` appended, or ``obs`` itself when
    ``columns`` (from :func:`relative_price_columns`) is ``None`` (``RELATIVE_PRICES`` off)."""
    if columns is None:
        return obs
    return jnp.concatenate([obs, relative_prices(obs, *columns)], axis=-1)


def relative_prices(obs, prices, q20, q50, q80) -> jnp.ndarray:
    """Each observed price's place in its day's range, ``(p - median) / (q80 - q20)`` (the spread
    floored at 0.01 EUR/kWh), clipped to [-5, 5]: the comparison a battery's charge or discharge
    decision turns on, which the raw prices (a few hundredths apart within a day, while the
    day's level moves by tenths) leave the network to learn."""
    from chargax_marl.core.observation import PRICE_SCALE_EUR_KWH

    spread = jnp.maximum(obs[..., q80] - obs[..., q20], 0.01 / PRICE_SCALE_EUR_KWH)[..., None]
    return jnp.clip((obs[..., prices] - obs[..., q50][..., None]) / spread, -5.0, 5.0)


# --------------------------------------------------------------------------- masked categoricals


def masked_logits(logits: jnp.ndarray, mask) -> jnp.ndarray:
    return jnp.where(mask, logits, NEG_INF)


def log_prob(logits: jnp.ndarray, action: jnp.ndarray) -> jnp.ndarray:
    """Log-probability of integer ``action`` under (masked) ``logits (..., K)``."""
    logp = jax.nn.log_softmax(logits, axis=-1)
    return jnp.take_along_axis(logp, action[..., None].astype(jnp.int32), axis=-1)[..., 0]


# t = u * total is shrunk by this relative margin so that rounding can never push it to the
# total, where the inversion would fall through to the masked (zero-probability) tail.
_INVERSION_MARGIN = np.float32(1.0 - 2.0 ** -22)


def categorical_from_uniform(u: jnp.ndarray, logits: jnp.ndarray):
    """One draw per head from ``softmax(logits (..., K))`` by inverting its CDF at ``u (...)``
    in ``[0, 1)``. Returns ``(action int32 (...), log-probability of it (...))``.

    The chosen index is the first ``j`` with ``cdf[j] > u * cdf[K-1]``, so an index of zero
    probability (a masked action, ``NEG_INF`` logit) is never chosen, whatever ``u``; the
    margin keeps ``u * cdf[K-1]`` below ``cdf[K-1]``, so some ``j < K`` always qualifies.
    """
    logp_all = jax.nn.log_softmax(logits, axis=-1)
    cdf = jnp.cumsum(jnp.exp(logp_all), axis=-1)
    t = (u * _INVERSION_MARGIN)[..., None] * cdf[..., -1:]
    action = jnp.sum(cdf <= t, axis=-1, dtype=jnp.int32)
    return action, jnp.take_along_axis(logp_all, action[..., None], axis=-1)[..., 0]


def sample_categorical(key: jax.Array, logits: jnp.ndarray):
    """``(action, log-probability)`` of one draw per head of ``logits (..., K)``.

    Same distribution as ``jax.random.categorical`` (which adds Gumbel noise to every logit,
    ``K`` uniforms per head), from one uniform per head by inversion
    (:func:`categorical_from_uniform`). On this project's 2-core CPU the Gumbel draw was about
    two thirds of a PPO rollout step with 16 envs (140 of 215 us); this costs about a third of
    that (``benchmarks/README.md``, training speed).
    """
    return categorical_from_uniform(jax.random.uniform(key, logits.shape[:-1]), logits)


def entropy(logits: jnp.ndarray) -> jnp.ndarray:
    logp = jax.nn.log_softmax(logits, axis=-1)
    p = jnp.exp(logp)
    return -jnp.sum(jnp.where(p > 0, p * logp, 0.0), axis=-1)


# --------------------------------------------------------------------------- PPO pieces


def gae(rewards, values, dones, last_value, gamma: float, lam: float):
    """Generalised advantage estimation over a rollout ``(T, ...)``; ``dones[t]`` ends the
    episode after step ``t`` (the day ends: the next value is not bootstrapped)."""

    def body(carry, x):
        next_adv, next_value = carry
        r, v, d = x
        delta = r + gamma * next_value * (1.0 - d) - v
        adv = delta + gamma * lam * (1.0 - d) * next_adv
        return (adv, v), adv

    _, adv = jax.lax.scan(body, (jnp.zeros_like(last_value), last_value), (rewards, values, dones), reverse=True)
    return adv, adv + values


def ppo_loss(new_logp, old_logp, advantages, values, old_values, targets, ent, config, ent_coef=None):
    """Clipped surrogate + clipped value loss - entropy bonus. Returns ``(total, parts)``.

    ``ent_coef``: the entropy coefficient of each row (default ``config["ENT_COEF"]`` for all)."""
    adv = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    ratio = jnp.exp(new_logp - old_logp)
    eps = config["CLIP_EPS"]
    actor_loss = -jnp.minimum(ratio * adv, jnp.clip(ratio, 1 - eps, 1 + eps) * adv).mean()
    v_clip = old_values + jnp.clip(values - old_values, -config["VF_CLIP"], config["VF_CLIP"])
    value_loss = 0.5 * jnp.maximum((values - targets) ** 2, (v_clip - targets) ** 2).mean()
    bonus = (config["ENT_COEF"] if ent_coef is None else ent_coef) * ent
    ent = ent.mean()
    total = actor_loss + config["VF_COEF"] * value_loss - bonus.mean()
    approx_kl = ((ratio - 1) - (new_logp - old_logp)).mean()
    return total, {"actor_loss": actor_loss, "value_loss": value_loss, "entropy": ent, "approx_kl": approx_kl}


def shuffled_rows(key: jax.Array, steps: int, actors: int, agents: int = 1) -> jnp.ndarray:
    """A random order ``(steps * actors,)`` of the rows of a rollout flattened from ``(steps, actors)``.

    With ``agents == 1`` a uniform permutation of the rows. With ``agents > 1`` the actors are
    agent-major (``actor = agent * envs + env``, ``envs = actors / agents``) and the
    *env-steps* ``(step, env)`` are permuted instead, each followed by its ``agents`` rows in
    agent order: a minibatch then holds every agent of the env-steps it draws. Permuting the
    rows of a multi-agent rollout (81,600 for 17 agents x 16 envs x 300 steps, a sort) cost
    about a quarter of an IPPO epoch on a CPU; permuting its env-steps is ``agents`` times
    smaller.
    """
    if agents == 1:
        return jax.random.permutation(key, steps * actors)
    envs = actors // agents
    unit = jax.random.permutation(key, steps * envs)  # step * envs + env
    step, env = unit // envs, unit % envs
    rows = step[:, None] * actors + jnp.arange(agents)[None, :] * envs + env[:, None]
    return rows.reshape(-1)


def ppo_epochs(loss_fn, tx, params, opt_state, key, traj, adv, targets, config: dict, agents: int = 1):
    """``UPDATE_EPOCHS`` passes over the rollout in ``NUM_MINIBATCHES`` shuffled minibatches.

    ``traj`` is the rollout (a NamedTuple with an ``info`` field, dropped here) with leading
    axes ``(steps, actors)``; ``loss_fn(params, (traj, adv, targets))`` returns
    ``(loss, parts)``. Returns ``(params, opt_state, key, parts)`` with ``parts`` stacked over
    epochs and minibatches. ``agents > 1`` (IPPO, MAPPO: ``actors = agents * envs``,
    agent-major) shuffles env-steps, each with all of its agents' rows (:func:`shuffled_rows`).
    """
    steps, actors = traj.reward.shape[:2]
    batch = steps * actors

    def epoch(carry, _):
        params, opt_state, key = carry
        key, k_perm = jax.random.split(key)
        data = (traj._replace(info={}), adv, targets)
        flat = jax.tree.map(lambda x: x.reshape((batch,) + x.shape[2:]), data)
        perm = shuffled_rows(k_perm, steps, actors, agents)
        mbs = jax.tree.map(lambda x: x[perm].reshape((config["NUM_MINIBATCHES"], -1) + x.shape[1:]), flat)

        def minibatch(carry, mb):
            params, opt_state = carry
            (_, parts), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, mb)
            updates, opt_state = tx.update(grads, opt_state, params)
            return (jax.tree.map(lambda p, u: p + u, params, updates), opt_state), parts

        (params, opt_state), parts = jax.lax.scan(minibatch, (params, opt_state), mbs)
        return (params, opt_state, key), parts

    (params, opt_state, key), parts = jax.lax.scan(epoch, (params, opt_state, key), None, config["UPDATE_EPOCHS"])
    return params, opt_state, key, parts


def make_optimizer(config: dict, num_updates: int):
    """Adam with global-norm clipping; the learning rate anneals linearly to 0 over training."""
    steps_per_update = config["NUM_MINIBATCHES"] * config["UPDATE_EPOCHS"]

    def schedule(count):
        return config["LR"] * (1.0 - (count // steps_per_update) / max(num_updates, 1))

    lr = schedule if config["ANNEAL_LR"] else config["LR"]
    return optax.chain(optax.clip_by_global_norm(config["MAX_GRAD_NORM"]), optax.adam(lr, eps=1e-5))


def num_updates(config: dict) -> int:
    n = int(config["TOTAL_TIMESTEPS"]) // (int(config["NUM_ENVS"]) * int(config["NUM_STEPS"]))
    if n < 1:
        raise ValueError(f"TOTAL_TIMESTEPS={config['TOTAL_TIMESTEPS']} is less than one rollout "
                         f"(NUM_ENVS*NUM_STEPS={config['NUM_ENVS'] * config['NUM_STEPS']})")
    return n


def episode_metrics(done, info, prefix="returned_episode") -> dict:
    """Mean over the episodes that ended in a rollout of the episode return and totals."""
    done = done.astype(jnp.float32)
    count = done.sum()

    def mean(x):
        return jnp.where(count > 0, (x * done).sum() / jnp.maximum(count, 1.0), jnp.nan)

    return {
        "episodes": count,
        "episode_return": mean(info[f"{prefix}_returns"]),
        "episode_profit_eur": mean(info[f"{prefix}_profit_eur"]),
        "episode_energy_delivered_kwh": mean(info[f"{prefix}_energy_delivered_kwh"]),
    }


# --------------------------------------------------------------------------- devices


ENV_AXIS = "envs"


def env_mesh(num_envs: int) -> Mesh:
    """A 1-D mesh over every device JAX sees (all hosts after ``jax.distributed.initialize()``)."""
    devices = jax.devices()
    if num_envs % len(devices):
        raise ValueError(f"NUM_ENVS={num_envs} must be divisible by the number of devices ({len(devices)}: "
                         f"{devices[0].platform}); pick a multiple of {len(devices)}")
    return Mesh(np.asarray(devices), (ENV_AXIS,))


def shard_envs(tree, mesh: Mesh):
    """Constrain the leading (env) axis of every array leaf to be split over the mesh."""
    sharding = NamedSharding(mesh, PartitionSpec(ENV_AXIS))
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, sharding) if jnp.ndim(x) >= 1 else x, tree)


# --------------------------------------------------------------------------- running & evaluation


def run_in_chunks(train, keys, num_chunks: int, on_chunk=None, desc: str = "train"):
    """Run ``train.init`` then ``train.run_updates`` in ``num_chunks`` jitted chunks over the
    vmapped seeds, calling ``on_chunk(chunk_index, runner_state, metrics)`` after each (e.g.
    held-out evaluation; the runner state is donated to the next chunk, so copy what you keep) under a tqdm progress bar. Returns ``(runner_state, metrics, seconds)``
    where ``metrics`` holds arrays ``(seeds, updates)``."""
    from tqdm.auto import tqdm

    total = train.num_updates
    bounds = np.linspace(0, total, num_chunks + 1).astype(int)
    sizes = sorted(set(int(b - a) for a, b in zip(bounds[:-1], bounds[1:]) if b > a))
    init = jax.jit(jax.vmap(train.init))
    # The runner state is donated: each chunk updates it in place instead of copying the
    # parameters, optimiser moments and env states (``on_chunk`` must not keep its arrays).
    runs = {n: jax.jit(jax.vmap(lambda rs, n=n: train.run_updates(rs, n)), donate_argnums=0) for n in sizes}
    t0 = time.time()
    rs = init(keys)
    chunks = []
    steps_per_update = train.config["NUM_ENVS"] * train.config["NUM_STEPS"]
    with tqdm(total=total * steps_per_update, desc=desc, unit="step", unit_scale=True, dynamic_ncols=True) as bar:
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
            tqdm.write(f"[{desc}] update {b}/{total} steps {b * steps_per_update:.3g}: "
                       f"episode profit {prof:.1f} EUR, return {ret:.1f}, "
                       f"entropy {np.nanmean(m['entropy'][:, -1]):.2f}, t={time.time() - t0:.0f}s")
            if on_chunk is not None:
                on_chunk(i, rs, m, b * steps_per_update, time.time() - t0)
    metrics = {k: np.concatenate([c[k] for c in chunks], axis=1) for k in chunks[0]}
    return rs, metrics, time.time() - t0


def draw_keys(draws: int = 1) -> list:
    """The evaluation keys of ``draws`` car draws per held-out day: ``PRNGKey(0) ... PRNGKey(draws - 1)``.
    Every policy is scored under the same keys (the same cars), and its per-day profit is the
    mean over the draws, so a paired difference's standard error over days treats the days,
    not the draws, as the independent units (the draws of one day share its prices). Draw 0
    is the single-draw evaluation's key."""
    if isinstance(draws, bool) or not isinstance(draws, (int, np.integer)) or int(draws) < 1:
        raise ValueError(f"field 'EVAL_DRAWS' (car draws per held-out day) must be a positive integer, got {draws!r}")
    return [jax.random.PRNGKey(k) for k in range(int(draws))]


def mean_over_draws(evaluate, keys):
    """``evaluate(key) -> pytree of arrays`` averaged leaf by leaf over ``keys`` (one call per key)."""
    outs = [jax.device_get(evaluate(k)) for k in keys]
    return jax.tree.map(lambda *x: np.mean(np.stack([np.asarray(v, np.float64) for v in x]), axis=0), *outs)


def evaluate_batched(make_act, net_params, eval_params, days, key=None, reference_profit=None, draws: int = 1) -> dict:
    """Greedy held-out evaluation of every seed's parameters (leading axis) with
    :func:`chargax_marl.evaluation.run_days`.

    Every seed runs with the *same* key as :func:`chargax_marl.evaluation.evaluate` (default
    ``PRNGKey(0)``), so all policies meet the same drawn cars on the same days (common random
    numbers): differences between policies are then not masked by the day-to-day spread of
    traffic (about ±130 EUR/day on the default scenario). With ``draws`` > 1 (and no ``key``)
    each day is played under the keys of :func:`draw_keys` and every per-day total is the mean
    over the draws. Returns pooled mean ± std over seeds
    × days (``metrics``), each seed's mean daily profit (``per_seed_profit``) and mean of every
    metric over days (``per_seed_metrics``), and daily profits (``daily_profit``, seeds × days). With ``reference_profit`` (the daily profits of a
    baseline on the same days and key, e.g. always-max), also ``paired_diff``: per seed, the
    mean and standard error over days of (policy − reference) profit.
    """
    if key is not None and draws != 1:
        raise ValueError(f"evaluate_batched: give either a key or draws > 1, not both (draws={draws!r})")
    keys = [key] if key is not None else draw_keys(draws)
    days = jnp.asarray(days, jnp.int32)
    seeds = jax.tree.leaves(net_params)[0].shape[0]
    fn = _eval_fn(make_act, eval_params)
    totals = mean_over_draws(lambda k: fn(net_params, days, k), keys)
    flat = jax.tree.map(lambda x: np.asarray(x).reshape(-1), totals)
    profit = np.asarray(totals.profit_eur, np.float64)
    out = {"num_days": int(days.shape[0]), "num_seeds": int(seeds), "metrics": summarize(flat),
           "per_seed_profit": [float(x) for x in profit.mean(axis=1)], "daily_profit": profit,
           "per_seed_metrics": {name: [float(x) for x in np.asarray(getattr(totals, field), np.float64).mean(axis=1)]
                                for name, field in METRICS.items()}}
    if reference_profit is not None:
        out["paired_diff"] = paired_difference(profit, reference_profit)
    return out


def paired_difference(profit, reference_profit) -> dict:
    """Per seed, mean and standard error over days of ``profit (seeds, days) - reference (days,)``;
    and the mean over seeds with the standard error of that mean over seeds × days."""
    d = np.atleast_2d(np.asarray(profit, np.float64)) - np.asarray(reference_profit, np.float64)[None, :]
    n = d.shape[1]
    return {"per_seed_mean": [float(x) for x in d.mean(axis=1)],
            "per_seed_stderr": [float(x) for x in d.std(axis=1, ddof=1) / np.sqrt(n)],
            "mean": float(d.mean()), "stderr": float(d.std(ddof=1) / np.sqrt(d.size))}


_EVAL_CACHE: dict = {}


def _eval_fn(make_act, eval_params):
    k = (make_act, id(eval_params))
    if k not in _EVAL_CACHE:
        _EVAL_CACHE[k] = jax.jit(jax.vmap(lambda p, d, kk: run_days(make_act(p), eval_params, d, kk),
                                          in_axes=(0, None, None)))
    return _EVAL_CACHE[k]


def parse_config(base: dict, overrides: dict | None) -> dict:
    config = {**PAPER_DEFAULTS, **base, **(overrides or {})}
    for k in ("NUM_ENVS", "NUM_STEPS", "NUM_MINIBATCHES", "UPDATE_EPOCHS", "HIDDEN", "NUM_LAYERS", "NUM_EVAL_DAYS"):
        config[k] = int(config[k])
    draw_keys(config["EVAL_DRAWS"])  # a clear error for a bad draw count, before anything trains
    config["TOTAL_TIMESTEPS"] = int(float(config["TOTAL_TIMESTEPS"]))
    return config


def stack_seeds(keys: Sequence) -> jnp.ndarray:
    return jnp.stack(list(keys))
