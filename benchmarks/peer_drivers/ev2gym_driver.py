"""Time EV2Gym's random-action steps; run with EV2Gym's own venv python (see ../peers.py).

Usage: ``python ev2gym_driver.py STEPS [CONFIG]``. Runs ``STEPS`` env.step calls with
``action_space.sample()`` actions on ``CONFIG`` (default: the bundled
``example_config_files/PublicPST.yaml``, the scenario of EV2Gym's default state and reward
functions), resetting at the end of every episode (resets are inside the timed loop, as a
training rollout does). Prints one line ``RESULT {json}``.
"""

import json
import os
import sys
import time
from importlib import metadata

steps = int(sys.argv[1])
import ev2gym  # noqa: E402

root = os.path.dirname(os.path.dirname(ev2gym.__file__))
os.chdir(root)  # the bundled configs use paths relative to the package's parent folder
config = (
    sys.argv[2]
    if len(sys.argv) > 2
    else os.path.join("ev2gym", "example_config_files", "PublicPST.yaml")
)

import numpy as np  # noqa: E402
from ev2gym.models.ev2gym_env import EV2Gym  # noqa: E402

np.random.seed(0)
t0 = time.perf_counter()
env = EV2Gym(
    config_file=config, generate_rnd_game=True, save_replay=False, save_plots=False, seed=0
)
env.reset(seed=0)
env.action_space.seed(0)
init_s = time.perf_counter() - t0
resets = 0
start = time.perf_counter()
for _ in range(steps):
    _, _, terminated, truncated, _ = env.step(env.action_space.sample())
    if terminated or truncated:
        env.reset()
        resets += 1
elapsed = time.perf_counter() - start
print(
    "RESULT "
    + json.dumps(
        {
            "peer": "EV2Gym",
            "package": "ev2gym",
            "version": metadata.version("ev2gym"),
            "steps": steps,
            "seconds": elapsed,
            "init_s": init_s,
            "resets": resets,
            "scenario": {
                "config": config,
                "timescale_min": env.timescale,
                "simulation_length": env.simulation_length,
                "charging_stations": env.cs,
                "transformers": env.number_of_transformers,
                "action_dim": int(np.prod(env.action_space.shape)),
            },
        }
    )
)
