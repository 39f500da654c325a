"""Optimal-control baselines solved with HiGHS: a hindsight bound, an MPC controller, a MILP.

- `model`: the station's day as an LP (one builder for every solver here).
- `bound`: the hindsight bound over a reference policy's port occupancy.
- `pooled`: the port-pooled bound over every policy (any port, any admission).
- `mpc`: a receding-horizon controller usable as a policy in both views.
- `milp`: the bound over admissions too (binary occupancy), for small problems.
"""

from chargax_marl.optimal.bound import Bound, Occupancy, bound_days, hindsight_bound, occupancy
from chargax_marl.optimal.model import SolverError
from chargax_marl.optimal.pooled import pooled_bound, pooled_bound_days

__all__ = [
    "Bound",
    "Occupancy",
    "SolverError",
    "bound_days",
    "hindsight_bound",
    "occupancy",
    "pooled_bound",
    "pooled_bound_days",
]
