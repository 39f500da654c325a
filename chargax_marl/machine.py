"""What machine a figure was measured on: CPU model, cores, JAX backend and load.

Used by the benchmarks and the experiment runners, which record it beside every wall time.
"""

from __future__ import annotations

import os
import platform
import subprocess


def machine_info() -> dict:
    """CPU model, core count, jax version, backend and device kind (for result files and READMEs)."""
    import jax

    model = platform.processor() or platform.machine()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        for line in out.splitlines():
            if line.startswith("Model name:"):
                model = line.split(":", 1)[1].strip()
    except (OSError, subprocess.SubprocessError):
        pass
    dev = jax.devices()[0]
    return {"cpu": model, "cores": os.cpu_count(), "jax": jax.__version__, "backend": dev.platform,
            "device": dev.device_kind, "python": platform.python_version()}


def load_info() -> str:
    """The 1/5/15-minute load averages, as ``uptime`` prints them (other jobs skew timings)."""
    try:
        one, five, fifteen = os.getloadavg()
        return f"load {one:.2f} {five:.2f} {fifteen:.2f}"
    except OSError:
        return "load n/a"
