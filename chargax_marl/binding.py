"""How often each node of the station binds under a policy: where the agents are coupled.

A node *binds* in a step when the grid-side flow of the currents the policy asks for (after
the cars' own limits, before the hard rescale; `chargax_marl.core.physics.apply_actions`)
reaches the node's limit. Where no node binds, the ports do not interact and a multi-agent
problem falls apart into independent ones; the coordination scenarios of
`chargax_marl.core.scenarios` are built so that they do.

``python -m chargax_marl.binding`` prints, for the default and every coordination scenario, the
percentage of steps in which each kind of node binds under always-max on held-out days
(the table in docs/scenarios.md). The per-node figures come from `node_binding`.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from chargax_marl.core import clock, physics, simulator
from chargax_marl.core.params import make_params
from chargax_marl.core.scenarios import COORDINATION_SCENARIOS, scenario_kwargs
from chargax_marl.core.types import EnvParams
from chargax_marl.evaluation import split_days
from chargax_marl.policies import always_max
from chargax_marl.trace import day_keys

BIND_TOLERANCE = 1e-4
"""A node binds when the requested flow is at least ``(1 - BIND_TOLERANCE)`` of its limit."""


def node_binding(
    params: EnvParams, days, key: jax.Array | None = None, policy=always_max
) -> np.ndarray:
    """Fraction of steps ``(H,)`` in which each inner node binds under ``policy``, over one
    whole day per entry of ``days`` with the cars that evaluation draws with ``key``
    (default ``PRNGKey(0)``, as `chargax_marl.evaluation.evaluate_policy`).

    Args:
        params: the environment parameters.
        days: ``(n,)`` day indices of the price data.
        key: day ``i`` draws its cars from ``split(key, n)[i]``; None: ``PRNGKey(0)``.
        policy: ``policy(state, key, params) -> levels``, a rule of
            `chargax_marl.policies`.

    Returns:
        ``(H,)`` float64, one entry per inner node in node order
        (``params.station.node_names``): the share of steps, averaged over the days, in which
        the node's requested grid-side flow is at least ``(1 - BIND_TOLERANCE)`` of its limit.

    Raises:
        ValueError: ``episode_days`` is not 1 (only one-day episodes are supported here yet).
    """
    clock.require_one_day(params, "chargax_marl.binding.node_binding")
    key = jax.random.PRNGKey(0) if key is None else key
    days = jnp.asarray(days, jnp.int32)
    st = params.station
    limit = st.node_max_kw * (1.0 - BIND_TOLERANCE)

    def one_day(day, day_key):
        act_keys, step_keys, battery_key = day_keys(day_key, params.num_steps)

        def body(state, keys):
            k_act, k_step = keys
            levels = policy(state, k_act, params)
            requested_a = physics.requested_current(levels, state, params)
            flows = physics.node_flows_kw(requested_a * st.leaf_voltage_v / 1000.0, st)
            state, _ = simulator.step(k_step, state, levels, params)
            return state, flows >= limit

        _, binds = jax.lax.scan(
            body, simulator.empty_state(day, params, battery_key), (act_keys, step_keys)
        )
        return jnp.mean(binds.astype(jnp.float32), axis=0)

    per_day = jax.jit(jax.vmap(one_day))(days, jax.random.split(key, days.shape[0]))
    return np.asarray(per_day, np.float64).mean(axis=0)


def _kind(name: str) -> str:
    """Node groups of the bundled architectures: the grid connection, cables, EVSE pairs."""
    if name == "grid":
        return "grid connection"
    for prefix, label in (
        ("dc_evse", "DC EVSE pairs"),
        ("ac_evse", "AC EVSE pairs"),
        ("dc_", "DC cable"),
        ("ac_", "AC cable"),
    ):
        if name.startswith(prefix):
            return label
    return name


GROUPS = ("grid connection", "DC cable", "AC cable", "DC EVSE pairs", "AC EVSE pairs")


def grouped(params: EnvParams, fractions: np.ndarray) -> dict:
    """Mean binding fraction per node group (`GROUPS`) of the bundled architectures.

    Args:
        params: the environment parameters, whose station's node names give the groups.
        fractions: ``(H,)`` a value per inner node, as `node_binding` returns.

    Returns:
        ``{group: mean of its nodes' fractions}`` for the groups present in the station (a
        node of no bundled group is a group of its own, under its name).
    """
    out: dict[str, list[float]] = {}
    for name, f in zip(params.station.node_names, fractions):
        out.setdefault(_kind(name), []).append(float(f))
    return {k: float(np.mean(v)) for k, v in out.items()}


def table(scenarios=("shopping",) + COORDINATION_SCENARIOS, num_days: int = 100) -> list[dict]:
    """One row per scenario: the grid limit and the percentage of steps each node group binds
    under always-max on the held-out days ``split_days(params.num_days, num_days)``.

    Args:
        scenarios: names of `chargax_marl.core.scenarios`.
        num_days: how many held-out days each scenario plays
            (``split_days(params.num_days, num_days, seed=0)``).

    Returns:
        One dict per scenario: ``"scenario"`` (its name), ``"grid_kw"`` (the grid
        connection's limit, kW) and, per node group present, the percentage of steps in which
        its nodes bind (`grouped`).
    """
    rows = []
    for name in scenarios:
        params = make_params(**scenario_kwargs(name))
        _, days = split_days(params.num_days, num_days, seed=0)
        fractions = node_binding(params, days)
        rows.append(
            {
                "scenario": name,
                "grid_kw": float(params.station.node_max_kw[0]),
                **{g: 100.0 * v for g, v in grouped(params, fractions).items()},
            }
        )
    return rows


def format_table(rows: list[dict]) -> str:
    """A Markdown table of `table`'s rows.

    Args:
        rows: the rows of `table`.

    Returns:
        The table: one line per row, with the grid limit (kW) and the percentage of steps of
        each of `GROUPS` (one decimal; "–" for a group the scenario's station lacks).
    """
    head = (
        "| scenario | grid connection kW | " + " | ".join(f"{g} % of steps" for g in GROUPS) + " |"
    )
    lines = [head, "|" + "---|" * (len(GROUPS) + 2)]
    for r in rows:
        cells = " | ".join(f"{r[g]:.1f}" if g in r else "–" for g in GROUPS)
        lines.append(f"| `{r['scenario']}` | {r['grid_kw']:.1f} | {cells} |")
    return "\n".join(lines)


def main(argv=None) -> list[dict]:
    """The command line: print the binding table of the given scenarios (the module doc).

    Args:
        argv: the command-line arguments (``--days``, ``--scenarios``); None: ``sys.argv``.

    Returns:
        The rows of `table` that were printed.

    Raises:
        SystemExit: ``--days`` below 1 (argparse's error, before anything runs).
    """
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--days", type=int, default=100, help="held-out days per scenario (default 100)"
    )
    parser.add_argument(
        "--scenarios",
        nargs="+",
        default=None,
        help="default: shopping and every coordination scenario",
    )
    args = parser.parse_args(argv)
    if args.days < 1:
        parser.error(f"--days must be an integer >= 1, got {args.days}")
    rows = table(
        tuple(args.scenarios) if args.scenarios else ("shopping",) + COORDINATION_SCENARIOS,
        args.days,
    )
    print(
        f"always-max, {args.days} held-out days (split_days seed 0), key 0: % of steps in which a node binds"
    )
    print(format_table(rows))
    return rows


if __name__ == "__main__":
    main()
