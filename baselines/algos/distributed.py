"""Multi-process (multi-host) training with ``jax.distributed``.

Every process runs the same program (SPMD). `initialize` must run before anything
asks JAX for its devices; afterwards ``jax.devices()`` lists the devices of all processes,
`baselines.algos.env_mesh` spans them and the env batch is split across processes.

Two things differ from one process, and `baselines.train` handles both here:

* inputs of a jitted program over the global mesh must be global arrays: the seed keys are
  made one, replicated on every device (`replicate`);
* an output that spans devices of other processes cannot be read with ``np.asarray``: the
  trained parameters (replicated) are read from this process's copy (`to_host`)
  before the held-out evaluation, which every process then runs on its own devices.

Only process 0 writes outputs and prints the evaluation (`is_main`). On CPU the processes exchange
data through gloo (``jax_cpu_collectives_implementation``); ``tests/test_distributed.py``
runs the training CLI as two processes on one machine this way.
"""

from __future__ import annotations

import argparse

import jax
import numpy as np
from jax.experimental import multihost_utils
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The command-line flags of a multi-process run (``--distributed``, ``--coordinator``,
    ``--num-processes``, ``--process-id``).

    Args:
        parser: the parser to add them to, as one argument group.
    """
    d = parser.add_argument_group(
        "multi-process (multi-host) training, see baselines/algos/distributed.py"
    )
    d.add_argument(
        "--distributed",
        action="store_true",
        help="call jax.distributed.initialize() first (implied by --coordinator); without "
        "--coordinator JAX detects the cluster (SLURM, Open MPI, ...). Every process runs "
        "the same command; only process 0 writes --out",
    )
    d.add_argument(
        "--coordinator", default=None, help="HOST:PORT of process 0's coordinator service"
    )
    d.add_argument("--num-processes", type=int, default=None)
    d.add_argument("--process-id", type=int, default=None)


def initialize_from_argv(argv=None) -> bool:
    """Initialise when the command line (default ``sys.argv[1:]``) asks for it
    (`add_arguments`); ignores every other flag. Returns whether it did.

    A command-line entry point calls this *before* importing the trainers: importing them
    (gymnax) already runs JAX computations, after which ``jax.distributed.initialize`` refuses.

    Args:
        argv: the command line's arguments; None: ``sys.argv[1:]``.

    Returns:
        True when it called `initialize`; False when neither ``--distributed`` nor
        ``--coordinator`` is given, or ``jax.distributed`` is already initialised.
    """
    parser = argparse.ArgumentParser(add_help=False)
    add_arguments(parser)
    a, _ = parser.parse_known_args(argv)
    if not (a.distributed or a.coordinator) or jax.distributed.is_initialized():
        return False
    initialize(a.coordinator, a.num_processes, a.process_id)
    return True


def initialize(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
) -> None:
    """``jax.distributed.initialize`` with CPU collectives switched on (gloo) so that CPU-only
    processes can run cross-process programs. With no arguments JAX detects the cluster
    (SLURM, Open MPI, Kubernetes, Cloud TPU, ...). Must run before any JAX computation,
    which includes importing `baselines.algos` (gymnax builds arrays at import).

    Args:
        coordinator_address: ``HOST:PORT`` of process 0's coordinator service; None: detected.
        num_processes: the number of processes; None: detected.
        process_id: this process's index; None: detected.
    """
    if jax.config.jax_cpu_collectives_implementation in (None, "", "none"):
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(
        coordinator_address=coordinator_address, num_processes=num_processes, process_id=process_id
    )


def is_main() -> bool:
    """Whether this is process 0, the one that writes outputs.

    Returns:
        True on process 0 (and on a single-process run).
    """
    return jax.process_index() == 0


def replicate(x, mesh=None):
    """A process-local array (the same on every process, e.g. PRNG keys) as a global array
    replicated on every device of ``mesh`` (default: all devices). Unchanged on one process.

    Args:
        x: an array, or an array of typed PRNG keys, equal on every process.
        mesh: the mesh to replicate over; None: a one-axis mesh of ``jax.devices()``.

    Returns:
        ``x`` itself on one process; else a global array (typed keys stay typed keys) with a
        fully replicated sharding over ``mesh``.
    """
    if jax.process_count() == 1:
        return x

    mesh = Mesh(np.asarray(jax.devices()), ("all",)) if mesh is None else mesh
    typed = jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)
    local = np.asarray(jax.random.key_data(x) if typed else x)
    out = jax.make_array_from_process_local_data(
        NamedSharding(mesh, PartitionSpec()), local, local.shape
    )
    return jax.random.wrap_key_data(out) if typed else out


def to_host(tree):
    """Every array leaf as a NumPy array on this process: a replicated leaf from this process's
    own copy, a leaf split across processes gathered from all of them (a collective: every
    process must call it).

    Args:
        tree: a pytree of arrays (any leaf that is not a `jax.Array` is passed to
            ``np.asarray``).

    Returns:
        The same pytree with NumPy leaves.
    """

    def leaf(x):
        if not isinstance(x, jax.Array) or x.is_fully_addressable:
            return np.asarray(x)
        if x.is_fully_replicated:
            return np.asarray(x.addressable_data(0))
        return np.asarray(multihost_utils.process_allgather(x, tiled=True))

    return jax.tree.map(leaf, tree)
