"""chargax_marl: a JAX simulator of EV charging stations for single- and multi-agent RL.

Importing the package registers the Gymnasium ids ``chargax_marl/Chargax-v0`` and
``chargax_marl/Chargax-<scenario>-v0`` (`chargax_marl.registration`) and the fork
guard of `chargax_marl.lifecycle`.

``__version__`` is the installed distribution's version (its metadata, from
``pyproject.toml``); ``"unknown"`` where the source tree is imported without being installed.
"""

import importlib.metadata as _metadata

from chargax_marl import lifecycle as _lifecycle  # noqa: F401  (registers the at-fork hook)
from chargax_marl.registration import register_envs as _register_envs

_register_envs()

try:
    __version__ = _metadata.version("chargax_marl")
except _metadata.PackageNotFoundError:  # a source tree on sys.path, not installed
    __version__ = "unknown"
