"""Time SustainGym's EVChargingEnv random-action steps; run with its own venv python (see ../peers.py).

Usage: ``python sustaingym_driver.py STEPS [SITE] [PERIOD]``. Builds the env of SustainGym's
documented example, ``EVChargingEnv(GMMsTraceGenerator('caltech', 'Summer 2021'))``
(bundled GMMs and MOER data, default ``project_action_in_env=True``, 5-minute steps, 288 per
day), runs ``STEPS`` env.step calls with ``action_space.sample()`` actions and resets at the
end of every episode inside the timed loop. Without a MOSEK licence the action projection
falls back to ECOS (SustainGym's own fallback). Prints one line ``RESULT {json}``.
"""

import json
import sys
import time
import warnings
from importlib import metadata

warnings.filterwarnings("ignore")
steps = int(sys.argv[1])
site = sys.argv[2] if len(sys.argv) > 2 else "caltech"
period = sys.argv[3] if len(sys.argv) > 3 else "Summer 2021"

from sustaingym.envs.evcharging import EVChargingEnv, GMMsTraceGenerator  # noqa: E402

t0 = time.perf_counter()
env = EVChargingEnv(GMMsTraceGenerator(site, period, seed=0))
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
try:
    import cvxpy

    solvers = cvxpy.installed_solvers()
except Exception:  # noqa: BLE001
    solvers = []
print(
    "RESULT "
    + json.dumps(
        {
            "peer": "SustainGym",
            "package": "sustaingym",
            "version": metadata.version("sustaingym"),
            "steps": steps,
            "seconds": elapsed,
            "init_s": init_s,
            "resets": resets,
            "scenario": {
                "env": "EVChargingEnv",
                "generator": f"GMMsTraceGenerator({site!r}, {period!r})",
                "stations": int(env.num_stations),
                "project_action_in_env": bool(env.project_action_in_env),
                "step_minutes": 5,
                "max_timestep": int(env.max_timestep),
                "cvxpy_solvers": solvers,
                "acnportal": metadata.version("acnportal"),
            },
        }
    )
)
