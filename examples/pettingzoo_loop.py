"""One day of the station through the PettingZoo ``ParallelEnv`` API, for two policies.

``python examples/pettingzoo_loop.py`` runs a random policy (uniform over each agent's valid
actions, from ``infos[agent]["action_mask"]``) and the always-max baseline (every port at full
power, batteries idle) for one day each on the default station, and prints each day's profit
(the sum of the shared reward). Both days use the same seed, so they are the same calendar
day with the same arriving cars.
"""

from __future__ import annotations

import argparse

from chargax_marl.marl import parallel_env
from chargax_marl.policies import always_max


def run_day(env, policy, seed: int) -> float:
    """Play one day with ``policy(env, obs, infos) -> {agent: action}``; return the sum of rewards."""
    obs, infos = env.reset(seed=seed)
    profit = 0.0
    while env.agents:
        actions = policy(env, obs, infos)
        obs, rewards, terminations, truncations, infos = env.step(actions)
        profit += rewards[
            env.possible_agents[0]
        ]  # the shared station reward, the same for every agent
    return profit


def random_policy(env, obs, infos):
    return {a: int(env.action_space(a).sample(mask=infos[a]["action_mask"])) for a in env.agents}


def always_max_policy(env, obs, infos):
    # The package's rule-based policy works in signed levels; the MARL env maps them to indices.
    levels = always_max(None, None, env.params)
    actions = env.env.levels_to_actions(levels)
    return {a: int(actions[a]) for a in env.agents}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--step-minutes",
        type=float,
        default=5.0,
        help="minutes per step (5 = the paper's 288 steps)",
    )
    args = parser.parse_args(argv)

    env = parallel_env(step_minutes=args.step_minutes)
    for agent in env.possible_agents:
        env.action_space(agent).seed(args.seed + env.possible_agents.index(agent))
    results = {}
    for name, policy in (("random", random_policy), ("always_max", always_max_policy)):
        results[name] = run_day(env, policy, args.seed)
        print(f"{name:<11} day profit: {results[name]:9.2f} EUR")
    env.close()
    return results


if __name__ == "__main__":
    main()
