"""The benchmark: versioned tasks, shipped references, and scores against them.

- `tasks`: `TASKS`, the registered `Task` s (the
  scenario, the held-out days, the car draws and their keys), and `load_task`, a task of
  one's own read from a TOML or JSON file;
- `references`: always-max (score 0), the LP hindsight bound
  (score 1), the strongest rules and (where computed) the MPC per day and draw, shipped with
  the package;
- `scoring`: `get_normalized_score` of per-day profits and
  `score` of a policy of any kind (`protocol`);
- `picture`: `day_picture`, one held-out day of a policy beside always-max;
- `scoreboard`: the table of every task and policy, from files.
"""

from chargax_marl.benchmark.picture import day_picture
from chargax_marl.benchmark.protocol import KINDS, play
from chargax_marl.benchmark.references import (
    ReferenceMismatchError,
    add_mpc,
    bound_violations,
    compute_mpc,
    compute_references,
    load_references,
    refill_bound,
    save_references,
)
from chargax_marl.benchmark.scoring import compare, get_normalized_score, score
from chargax_marl.benchmark.tasks import TASKS, Task, get_task, load_task

__all__ = [
    "KINDS",
    "TASKS",
    "ReferenceMismatchError",
    "Task",
    "add_mpc",
    "bound_violations",
    "compare",
    "compute_mpc",
    "compute_references",
    "day_picture",
    "get_normalized_score",
    "get_task",
    "load_references",
    "load_task",
    "play",
    "refill_bound",
    "save_references",
    "score",
]
