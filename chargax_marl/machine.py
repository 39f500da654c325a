"""What machine a figure was measured on: CPU model, cores, JAX backend and load.

Used by the benchmarks and the experiment runners, which record it beside every wall time.
"""

from __future__ import annotations

import os
import platform
import subprocess

import jax


def cpu_description(lscpu: str) -> str:
    """The CPU as ``lscpu`` describes it: the model name, with the family, model and the
    widest vector instructions (``avx512``, ``avx2``) in brackets, and the L2 and L3 caches
    (their sizes summed over their instances, as ``lscpu`` gives them).

    A virtual machine often reports only a generic model name ("AMD EPYC"), which two hosts of
    different generations, and speeds, share; the family and model tell them apart.

    Args:
        lscpu: the output of ``lscpu``.

    Returns:
        For example ``"AMD EPYC (family 25 model 17, avx512; L2 2 MiB, L3 32 MiB)"``; the empty
        string when ``lscpu`` names no model.
    """
    fields = {}
    for line in lscpu.splitlines():
        key, sep, value = line.partition(":")
        if sep and key.strip() not in fields:
            fields[key.strip()] = value.strip()
    name = fields.get("Model name", "")
    if not name:
        return ""

    def labelled(*pairs):  # "label value" of each field present (without lscpu's "(N instances)")
        return [f"{label} {fields[key].split(' (')[0]}" for label, key in pairs if fields.get(key)]

    flags = set(fields.get("Flags", "").split())
    isa = "avx512" if "avx512f" in flags else "avx2" if "avx2" in flags else ""
    family_model = " ".join(labelled(("family", "CPU family"), ("model", "Model")))
    ident = ", ".join(x for x in (family_model, isa) if x)
    caches = ", ".join(labelled(("L2", "L2 cache"), ("L3", "L3 cache")))
    details = "; ".join(x for x in (ident, caches) if x)
    return f"{name} ({details})" if details else name


def machine_info() -> dict:
    """CPU, core count, jax version, backend and device kind (for result files and READMEs).

    Returns:
        ``{"cpu", "cores", "jax", "backend", "device", "python"}``; ``cpu`` is
        `cpu_description` of ``lscpu`` where it runs, else the platform's processor name.
    """
    model = platform.processor() or platform.machine()
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, timeout=10).stdout
        model = cpu_description(out) or model
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
    uncommitted changes, for result files; ``commit`` is ``None`` outside a git checkout.

    Args:
        root: a directory inside the git checkout; None for the one holding this package.

    Returns:
        ``{"commit", "dirty"}``: the ``HEAD`` commit hash and whether tracked files have
        uncommitted changes; both None when ``git`` fails or cannot run.
    """
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
    """The 1/5/15-minute load averages, as ``uptime`` prints them (other jobs skew timings).

    Returns:
        ``"load <1-min> <5-min> <15-min>"`` with two decimals each, or ``"load n/a"`` where the
        system gives no load averages.
    """
    try:
        one, five, fifteen = os.getloadavg()
        return f"load {one:.2f} {five:.2f} {fifteen:.2f}"
    except OSError:
        return "load n/a"
