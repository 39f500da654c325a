"""What machine a figure was measured on: CPU model, cores, JAX backend and load.

Used by the benchmarks and the experiment runners, which record it beside every wall time.
"""

from __future__ import annotations

import os
import platform
import subprocess

import jax


def machine_info() -> dict:
    """CPU model, core count, jax version, backend and device kind (for result files and READMEs)."""
    model = platform.processor() or platform.machine()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    dev = jax.devices()[0]
    return {
        "cpu": model,
        "cores": os.cpu_count(),
        "jax": jax.__version__,
        "backend": dev.platform,
        "device": dev.device_kind,
        "python": platform.python_version(),
    }


def code_version(root=None) -> dict:
    """The git commit of the checkout at ``root`` (default: this package's) and whether it has
    uncommitted changes, for result files; ``commit`` is ``None`` outside a git checkout."""
    root = root or os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    try:

        def git(*args):
            return subprocess.run(
                ["git", "-C", str(root), *args],
                capture_output=True,
                text=True,
                timeout=10,
                check=True,
            ).stdout.strip()

        return {
            "commit": git("rev-parse", "HEAD"),
            "dirty": bool(git("status", "--porcelain", "--untracked-files=no")),
        }
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


def load_info() -> str:
    """The 1/5/15-minute load averages, as ``uptime`` prints them (other jobs skew timings)."""
    try:
        one, five, fifteen = os.getloadavg()
        return f"load {one:.2f} {five:.2f} {fifteen:.2f}"
    except OSError:
        return "load n/a"
