"""Helpers shared by the tests: hand-made stations and states, random trees, rollouts."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import strategies as st

from baselines.config import SCHEMA
from chargax_marl.core import Battery, Port, Splitter, multiple_types, simulator
from chargax_marl.core.params import make_params


def place_car(
    state,
    i,
    *,
    soc=0.3,
    capacity_kwh=60.0,
    max_rate_kw=100.0,
    tau=0.8,
    remaining_kwh=20.0,
    time_min=60.0,
    charge_sensitive=False,
    arrival_soc=None,
    current_a=0.0,
    target_soc=1.0,
    max_discharge_rate_kw=None,
    earliest_min=0.0,
):
    """Return ``state`` with a car parked at leaf ``i`` (by default it may charge to full and
    discharge at its charging rate)."""
    arrival_soc = soc if arrival_soc is None else arrival_soc
    max_discharge_rate_kw = max_rate_kw if max_discharge_rate_kw is None else max_discharge_rate_kw
    return state.replace(
        target_soc=state.target_soc.at[i].set(target_soc),
        max_discharge_rate_kw=state.max_discharge_rate_kw.at[i].set(max_discharge_rate_kw),
        slack_min=state.slack_min.at[i].set(time_min - earliest_min),
        occupied=state.occupied.at[i].set(True),
        soc=state.soc.at[i].set(soc),
        capacity_kwh=state.capacity_kwh.at[i].set(capacity_kwh),
        max_rate_kw=state.max_rate_kw.at[i].set(max_rate_kw),
        tau=state.tau.at[i].set(tau),
        energy_remaining_kwh=state.energy_remaining_kwh.at[i].set(remaining_kwh),
        time_remaining_min=state.time_remaining_min.at[i].set(time_min),
        charge_sensitive=state.charge_sensitive.at[i].set(charge_sensitive),
        arrival_soc=state.arrival_soc.at[i].set(arrival_soc),
        current_a=state.current_a.at[i].set(current_a),
    )


def no_arrivals(params):
    """The same params with zero arrival rate, so hand-built states evolve without new cars."""
    return params.replace(arrival_rate=jnp.zeros_like(params.arrival_rate))


def start(params, day=0):
    return simulator.empty_state(jnp.asarray(day), params)


def random_rollout(params, key, num_steps=None, policy="random"):
    """Scan ``num_steps`` steps with uniform random levels; return (states_before, infos)."""
    from chargax_marl.policies import POLICIES

    num_steps = num_steps or params.num_steps
    pol = POLICIES[policy]

    def body(state, k):
        k1, k2 = jax.random.split(k)
        levels = pol(state, k1, params)
        new_state, info = simulator.step(k2, state, levels, params)
        return new_state, (state, levels, new_state, info)

    def rollout(key):
        state = simulator.reset(key, params)
        return jax.lax.scan(body, state, jax.random.split(key, num_steps))[1]

    # one compiled program: run eagerly, the reset and the key split compile op by op
    return jax.jit(rollout)(key)


def three_level_station(ac_discharge_current_a: float = 16.0) -> Splitter:
    """grid -> {dc splitter -> 2 EVSE groups of 2 DC ports, ac splitter -> 2 AC ports, battery}."""
    dc = [Port(f"dc{i}", "DC", 500.0, 200.0, 200.0, 0.95) for i in range(4)]
    ac = [Port(f"ac{i}", "AC", 400.0, 32.0, ac_discharge_current_a, 0.97) for i in range(2)]
    evse = [
        Splitter("evse0", 150.0, tuple(dc[:2]), 0.99),
        Splitter("evse1", 150.0, tuple(dc[2:]), 0.99),
    ]
    return Splitter(
        "grid",
        220.0,
        (
            Splitter("dc_split", 200.0, tuple(evse), 0.98),
            Splitter("ac_split", 20.0, tuple(ac), 0.99),
            Battery(
                "bat", capacity_kwh=100.0, max_kw=50.0, efficiency=0.95, tau=0.8, initial_soc=0.5
            ),
        ),
    )


def rng(seed: int) -> np.random.Generator:
    return np.random.default_rng(seed)


def mixed_station() -> Splitter:
    """The three-level station with AC ports that cannot discharge (no V2G): masks matter."""
    return three_level_station(ac_discharge_current_a=0.0)


@st.composite
def trees(draw, max_depth=3, tiny_limits=False, max_leaves=None):
    """A random station tree (hypothesis strategy).

    Args:
        draw: Hypothesis' draw function.
        max_depth: The deepest level of a leaf below the grid connection's child.
        tiny_limits: Draw every splitter's limit log-uniformly from 0.001 kW to 10 MW (else
            from 1 to 500 kW, the root's from 1 to 800 kW).
        max_leaves: At most this many leaves (ports and batteries) in the whole tree.

    Returns:
        The root `Splitter`.
    """
    counter = iter(range(10_000))
    leaves = [1]  # the always-present port

    def limit_kw(low, high):
        if tiny_limits:
            return 10.0 ** draw(st.floats(-3.0, 4.0))
        return draw(st.floats(low, high))

    def node(depth):
        full = max_leaves is not None and leaves[0] >= max_leaves - 1
        if full or depth >= max_depth or draw(st.booleans()) and depth > 0:
            leaves[0] += 1
            if draw(st.integers(0, 5)) == 0:
                return Battery(
                    f"b{next(counter)}",
                    capacity_kwh=draw(st.floats(10, 300)),
                    max_kw=draw(st.floats(5, 200)),
                    efficiency=draw(st.floats(0.8, 1.0)),
                )
            v = draw(st.sampled_from([230.0, 400.0, 500.0, 800.0]))
            i = draw(st.floats(10.0, 400.0))
            return Port(
                f"p{next(counter)}",
                draw(st.sampled_from(["AC", "DC"])),
                v,
                i,
                draw(st.sampled_from([0.0, i / 2, i])),
                draw(st.floats(0.8, 1.0)),
            )
        kids = tuple(node(depth + 1) for _ in range(draw(st.integers(1, 3))))
        return Splitter(f"s{next(counter)}", limit_kw(1.0, 500.0), kids, draw(st.floats(0.8, 1.0)))

    root = node(0)
    if not isinstance(root, Splitter):
        root = Splitter("root", 100.0, (root,))
    root = Splitter("grid", limit_kw(1.0, 800.0), (root, Port("always_port")))
    return root


def tiny_root_station() -> Splitter:
    """The tiny-limit station: a 0.001 kW root over a V2G port, a charging-only port (150 kW each)
    and the default battery."""
    return Splitter(
        "grid",
        0.001,
        (
            Port("p0", "DC", 500.0, 300.0, 300.0, 0.95),
            Port("p1", "DC", 500.0, 300.0, 0.0, 0.95),
            Battery(),
        ),
    )


def grid_side_node_flows_kw(leaf_power_kw: np.ndarray, station) -> np.ndarray:
    """``(T, H)`` net grid-side flow through every node from the leaf powers ``(T, L)``, in
    float64: a leaf's power divided by the efficiency of its path up to and including the node
    when it charges, multiplied by it when it discharges."""
    leaf_power_kw = np.atleast_2d(np.asarray(leaf_power_kw, np.float64))
    depth = np.asarray(station.node_depth)
    at_depth = np.asarray(station.node_of_leaf_at_depth)
    eff = np.asarray(station.leaf_efficiency_at_depth, np.float64)
    flows = np.zeros((leaf_power_kw.shape[0], depth.shape[0]))
    for h, d in enumerate(depth):
        below = at_depth[d] == h
        e = eff[d][below]
        p = leaf_power_kw[:, below]
        flows[:, h] = np.abs(np.where(p > 0, p / e, p * e).sum(axis=1))
    return flows


# The test session compiles with XLA's elemental emitter (``tests/conftest.py``), which rounds
# the same float32 arithmetic differently in differently fused programs. Two programs compared
# bit for bit are compiled as users' programs are, with XLA's default fusion emitters.
EXACT = {"xla_cpu_use_fusion_emitters": True}
"""``compiler_options`` for a program whose outputs a test compares bit for bit with another's."""


def exact_jit(fun):
    """``jax.jit`` with the default fusion emitters, for programs compared bit for bit."""
    return jax.jit(fun, compiler_options=EXACT)


TINY_ENV = {
    "station": "single_type",
    "station_kwargs": {"num_ports": 4, "battery": True},
    "step_minutes": 60.0,
}


TINY = {
    "NUM_ENVS": 4,
    "NUM_STEPS": 24,
    "NUM_MINIBATCHES": 2,
    "UPDATE_EPOCHS": 2,
    "HIDDEN": 32,
    "TOTAL_TIMESTEPS": 4 * 24,
    "ENV_KWARGS": TINY_ENV,
    "REWARD_SCALE": 0.1,
}


def toml_inline(value) -> str:
    """``value`` as a TOML inline value (for a ``KEY=value`` override)."""
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {toml_inline(v)}" for k, v in value.items()) + " }"
    if isinstance(value, bool):
        return "true" if value else "false"
    return json.dumps(value)


TINY_CLI = [
    "--config",
    "cpu",
    "SEEDS=2",
    "NUM_ENVS=4",
    "NUM_STEPS=24",
    "HIDDEN=16",
    f"ENV_KWARGS={toml_inline(TINY_ENV)}",
    "NUM_EVAL_DAYS=20",  # enough held-out days for every property; the default 100 for users
    "NUM_VALIDATION_DAYS=20",  # as many as held out: the evaluations share their programs
]
"""The command line of a tiny run (add ``ALGO=``, ``TOTAL_TIMESTEPS=``, ``CHUNKS=``, ``OUT=``)."""


def count_compiles(fn) -> int:
    """Run ``fn`` and count the XLA programs compiled meanwhile (in this thread)."""
    events = []

    def listener(event, duration_secs, **kwargs):
        if event == "/jax/core/compile/backend_compile_duration":
            events.append(duration_secs)

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        fn()
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)
    return len(events)


def train_seeds(train, keys):
    """``jax.jit(jax.vmap(train))(keys)`` as one program of ``vmap(train.init)`` then
    ``vmap(train.run_updates)``, as the command-line runner trains: the same training, traced
    with less work. Under a single ``vmap(train)`` the optimiser's zero moments and the update
    counter enter the updates' scan unbatched and leave it batched, so ``vmap`` batches the
    scan's body (and every scan in it) again; ``vmap(train.init)`` hands ``run_updates`` a
    runner state batched throughout."""

    def seeds(keys):
        rs = jax.vmap(train.init)(keys)
        rs, metrics = jax.vmap(lambda r: train.run_updates(r, train.num_updates))(rs)
        return {"runner_state": rs, "metrics": metrics}

    return jax.jit(seeds)(keys)


def finite_losses(train, seeds=2, run=train_seeds):
    """Train ``seeds`` seeds with ``run(train, keys)`` and check the losses are finite, one per
    seed and update; returns the training's output."""
    out = run(train, jax.random.split(jax.random.PRNGKey(0), seeds))
    m = jax.device_get(out["metrics"])
    for k in ("actor_loss", "value_loss", "entropy", "approx_kl"):
        assert m[k].shape == (seeds, train.num_updates)
        assert np.all(np.isfinite(m[k])), (k, m[k])
    return out


def hand_params(station, hourly_prices=(0.1,) * 24, **kw):
    """Params for hand-computed optima: two days of ``hourly_prices`` (EUR/kWh), no grid fee,
    no fixed cost, feed-in at the buy price, customers paying 0.75 EUR/kWh."""
    prices = np.tile(np.asarray(hourly_prices, np.float32), (2, 1))
    return make_params(
        station=station,
        prices=prices,
        grid_fee_eur_kwh=0.0,
        fixed_cost_eur=0.0,
        feed_in_factor=1.0,
        customer_price_eur_kwh=0.75,
        **kw,
    )


CONFIG_TEXT = st.one_of(  # texts a user may type after KEY=
    st.text(max_size=12),
    st.integers(-(2**40), 2**40).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(
        ["", " ", "true", "True", "nan", "inf", "-0", "1e400", "[1]", "{a=1}", "'x'", '"y"']
    ),
)


def allowed_by_schema(key: str, value) -> bool:
    """Whether a resolved value of ``key`` is one its field of `baselines.config.SCHEMA`
    allows (a property the config and grid parsers' tests check)."""
    field = SCHEMA[key]
    if value is None:
        return field.default is None
    if isinstance(value, bool) and bool not in field.kinds:
        return False
    if not isinstance(value, field.kinds):
        return False
    if field.choices and value not in field.choices:
        return False
    if isinstance(value, float) and not np.isfinite(value):
        return False
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        low, high = field.low, field.high
        if low is not None and (value <= low if field.low_open else value < low):
            return False
        if high is not None and value > high:
            return False
    return True


ONE_DAY_ONLY = r"field 'episode_days' is 2, but only episode_days=1 .* is supported here yet"
"""The message of `chargax_marl.core.clock.require_one_day` for ``episode_days=2``."""


def two_day_params():
    """A small station (2 AC and 2 DC ports, hourly steps) with two-day episodes, for the
    entry points that refuse them."""
    return make_params(station=multiple_types(2, 2), step_minutes=60, episode_days=2)
