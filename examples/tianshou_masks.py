"""Tianshou's multi-agent machinery on the station, reading the action masks from the observations.

``python examples/tianshou_masks.py --episodes 2 --max-cycles 24`` builds the AEC env with
``action_mask_in_obs=True`` (observations ``{"observation": Box, "action_mask": MultiBinary}``,
PettingZoo's classic-env convention that Tianshou, AgileRL and RLlib read), wraps it in
Tianshou's ``PettingZooEnv``, gives every agent Tianshou's masked random policy under
``MultiAgentOffPolicyAlgorithm`` and collects episodes with a ``Collector``. V2G is off, so
every port has its discharging levels masked (the battery keeps them): the script checks from
the replay buffer that no agent ever picked a masked action, and prints the counts.

Replace the random algorithms by DQN ones (as in Tianshou's tic-tac-toe example) to train.
Needs the ``clients`` extra (tianshou, torch); run by ``make examples``.
"""

from __future__ import annotations

import argparse

import numpy as np


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--episodes", type=int, default=2)
    parser.add_argument(
        "--max-cycles", type=int, default=24, help="steps per episode (288 = a whole 5-minute day)"
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    from tianshou.algorithm.multiagent.marl import MultiAgentOffPolicyAlgorithm
    from tianshou.algorithm.random import MARLRandomDiscreteMaskedOffPolicyAlgorithm
    from tianshou.data import Collector, VectorReplayBuffer
    from tianshou.env import DummyVectorEnv
    from tianshou.env.pettingzoo_env import PettingZooEnv

    from chargax_marl.marl import aec_env

    def make():
        return PettingZooEnv(
            aec_env(action_mask_in_obs=True, v2g=False, max_cycles=args.max_cycles)
        )

    env = make()
    algorithms = [MARLRandomDiscreteMaskedOffPolicyAlgorithm(env.action_space) for _ in env.agents]
    algorithm = MultiAgentOffPolicyAlgorithm(algorithms=algorithms, env=env)
    np.random.seed(args.seed)  # the masked random policy draws from numpy's global generator
    envs = DummyVectorEnv([make])
    steps = args.episodes * args.max_cycles * len(env.agents)
    buffer = VectorReplayBuffer(steps + 10, 1)
    collector = Collector(algorithm, envs, buffer)
    collector.reset(reset_buffer=True, gym_reset_kwargs={"seed": args.seed})
    stats = collector.collect(n_episode=args.episodes, reset_before_collect=False)

    data = buffer[np.arange(len(buffer))]
    acts = np.asarray(data.act)
    masks = np.asarray(data.obs.mask, bool)
    chosen_valid = masks[np.arange(len(acts)), acts]
    masked_share = float(1.0 - masks.mean())
    out = {
        "episodes": int(stats.n_collected_episodes),
        "agent_steps": int(len(acts)),
        "masked_actions_chosen": int((~chosen_valid).sum()),
        "masked_share": masked_share,
    }
    print(
        f"{out['episodes']} episodes, {out['agent_steps']} agent-steps; {masked_share:.0%} of the actions "
        f"were masked; masked actions chosen: {out['masked_actions_chosen']}"
    )
    return out


if __name__ == "__main__":
    main()
