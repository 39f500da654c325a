"""Stable-Baselines3 PPO on the multi-agent station through SuperSuit, with worker processes.

``python examples/supersuit_sb3.py --timesteps 2048 --num-cpus 2`` turns the PettingZoo
``ParallelEnv`` into a vector env whose entries are the agents (parameter sharing: one
policy for every port and the battery, PettingZoo's own SB3 tutorial), concatenates
``--num-envs`` stations over ``--num-cpus`` worker processes, trains PPO for
``--timesteps`` agent-steps and prints the mean reward per agent-step of the last rollout.

Worker processes must be *spawned*: JAX is multithreaded, and a worker forked after JAX
started would deadlock (chargax_marl raises ``ForkedProcessError`` there instead). So the
script sets the ``spawn`` start method and keeps its work under ``if __name__ == "__main__"``.
Needs the ``clients`` extra (``pip install -e ".[clients]"``: stable-baselines3, supersuit,
torch); run by ``make examples``.
"""

from __future__ import annotations

import argparse
import multiprocessing


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--timesteps", type=int, default=2048, help="agent-steps of PPO training")
    parser.add_argument(
        "--num-envs", type=int, default=2, help="stations (each contributes one entry per agent)"
    )
    parser.add_argument(
        "--num-cpus", type=int, default=2, help="worker processes (0: all in this process)"
    )
    parser.add_argument(
        "--step-minutes",
        type=float,
        default=60.0,
        help="minutes per step (5 = the paper's 288 steps)",
    )
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    multiprocessing.set_start_method("spawn", force=True)  # never fork a process that runs JAX
    import supersuit as ss
    from stable_baselines3 import PPO
    from stable_baselines3.common.utils import set_random_seed

    from chargax_marl.marl import parallel_env

    env = parallel_env(step_minutes=args.step_minutes)
    vec = ss.pettingzoo_env_to_vec_env_v1(env)
    vec = ss.concat_vec_envs_v1(
        vec, args.num_envs, num_cpus=args.num_cpus, base_class="stable_baselines3"
    )
    try:
        set_random_seed(args.seed)  # torch and numpy; SuperSuit's process vector env has no seed()
        n_steps = max(8, args.timesteps // vec.num_envs // 2)
        model = PPO(
            "MlpPolicy",
            vec,
            n_steps=n_steps,
            batch_size=n_steps * vec.num_envs // 2,
            n_epochs=2,
            verbose=0,
            device="cpu",
        )
        model.learn(total_timesteps=args.timesteps)
        rewards = model.rollout_buffer.rewards
    finally:
        vec.close()  # stops the worker processes, also on an error
    out = {
        "agent_steps": int(model.num_timesteps),
        "mean_reward": float(rewards.mean()),
        "num_workers": args.num_cpus,
        "vector_entries": int(vec.num_envs),
    }
    print(
        f"PPO on {out['vector_entries']} agent entries ({args.num_envs} stations, {args.num_cpus} worker processes): "
        f"{out['agent_steps']} agent-steps, mean reward per agent-step in the last rollout {out['mean_reward']:.4f}"
    )
    return out


if __name__ == "__main__":
    main()
