"""What a training run writes: parameters (msgpack), results as JSON, learning-curve plots."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import flax.serialization
import jax
import jax.numpy as jnp
import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines.algos import registry


def save_params(params, path: str | Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(flax.serialization.to_bytes(jax.device_get(params)))
    return path


def load_params(template, path: str | Path):
    return flax.serialization.from_bytes(template, Path(path).read_bytes())


def to_jsonable(x):
    """``x`` as JSON values: arrays as lists, non-finite floats as ``None``, and a float that is
    a float32 value as the shortest decimal that reads back to the same float32 (the trainers'
    metrics are float32; their float64 expansions took three times the digits)."""
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, (np.ndarray, jnp.ndarray)):
        return to_jsonable(np.asarray(x).tolist())
    if isinstance(x, (np.floating, float)):
        if not np.isfinite(x):
            return None
        single = np.float32(x)
        return float(str(single)) if float(single) == float(x) else float(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    return x


def _dumps(x, indent: int = 0) -> str:
    """JSON with nested objects indented and lists of numbers or strings on one line."""
    pad, inner = " " * indent, " " * (indent + 2)
    if isinstance(x, dict) and x:
        items = ",\n".join(f"{inner}{json.dumps(k)}: {_dumps(v, indent + 2)}" for k, v in x.items())
        return "{\n" + items + "\n" + pad + "}"
    if isinstance(x, list) and any(isinstance(v, (dict, list)) for v in x):
        return "[\n" + ",\n".join(inner + _dumps(v, indent + 2) for v in x) + "\n" + pad + "]"
    return json.dumps(x, default=str)


def write_json(obj: dict, path: str | Path) -> Path:
    """Write ``obj`` (see :func:`to_jsonable`) as indented JSON whose number lists take one line each."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(_dumps(to_jsonable(obj)) + "\n")
    return path


def smooth_nan(x: np.ndarray) -> np.ndarray:
    """Carry the last finite value forward along the last axis (updates with no finished episode)."""
    x = np.array(x, dtype=np.float64)
    for idx in np.ndindex(x.shape[:-1]):
        row = x[idx]
        last = np.nan
        for t in range(row.shape[0]):
            if np.isfinite(row[t]):
                last = row[t]
            else:
                row[t] = last
    return x


def seed_mean_std(curves) -> tuple[np.ndarray, np.ndarray]:
    """Mean and std over seeds of learning curves ``(seeds, points)`` after :func:`smooth_nan`;
    points before any seed's first finished episode stay NaN (matplotlib leaves them out)."""
    y = smooth_nan(np.atleast_2d(np.asarray(curves, dtype=float)))
    with warnings.catch_warnings():  # all-NaN columns: NaN without "Mean of empty slice"
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanmean(y, 0), np.nanstd(y, 0)


def plot_learning_curve(
    path,
    timesteps,
    curves: dict[str, np.ndarray],
    baselines: dict[str, float],
    title: str,
    eval_points=None,
    ylabel="daily profit (EUR)",
):
    """Mean ± std over seeds of each curve ``(seeds, points)``; baselines as horizontal lines;
    ``eval_points``: optional ``{label: (timesteps, (seeds, n) array)}`` drawn with markers."""
    matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for label, y in curves.items():
        m, s = seed_mean_std(y)
        (line,) = ax.plot(timesteps, m, label=label)
        ax.fill_between(timesteps, m - s, m + s, alpha=0.25, color=line.get_color())
    for label, (t, y) in (eval_points or {}).items():
        y = np.atleast_2d(y)
        ax.errorbar(t, y.mean(0), yerr=y.std(0), marker="o", ms=4, capsize=3, label=label)
    styles = ["--", ":", "-."]
    for i, (label, v) in enumerate(baselines.items()):
        ax.axhline(v, ls=styles[i % 3], color=f"C{i + 3}", label=label)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


LINES = (
    ("battery_rule", "always-max + battery rule"),
    ("battery_programme", "always-max + battery programme"),
    ("plan_programme", "plan + battery programme"),
    ("price_threshold", "price-threshold"),
    ("mpc", "MPC, 4 h horizon"),
    ("lp_bound", "LP hindsight bound"),
)
"""The reference policies drawn as horizontal lines on a learning curve (after always-max)."""


def plot_curve(
    path, algo: str, timesteps, episode_profit, baselines: dict, evals: list, title: str
):
    """A run's learning curve: the sampled training-episode profit over seeds, the held-out
    greedy evaluations, and every reference of ``baselines`` present (:data:`LINES`) as a line."""
    am = baselines["always_max"]["metrics"]["daily_profit_eur"]["mean"]
    lines = {f"always-max (held-out) {am:.0f}": am}
    for key, label in LINES:
        if key in baselines:
            v = baselines[key]["metrics"]["daily_profit_eur"]["mean"]
            lines[f"{label} (held-out) {v:.0f}"] = v
    plot_learning_curve(
        path,
        timesteps,
        {f"{algo} training episodes (sampled)": np.asarray(episode_profit)},
        lines,
        title,
        eval_points={
            f"{algo} held-out (greedy)": (
                [e["timesteps"] for e in evals],
                np.asarray([e["per_seed_profit"] for e in evals]).T,
            )
        }
        if evals
        else None,
    )


def load_run(run_dir: str | Path):
    """``(results, train, params)`` of a ``baselines.train`` output directory: its
    ``results.json``, the rebuilt ``train`` of its algorithm and config, and the trained
    parameters of every seed (leading axis = seed) from ``params.msgpack``."""
    run_dir = Path(run_dir)
    results = json.loads((run_dir / "results.json").read_text())
    train = registry.make_train(results["algo"], results["config"])
    template = jax.vmap(train.policy.init)(
        jax.random.split(jax.random.PRNGKey(0), int(results["seeds"]))
    )
    return results, train, load_params(template, run_dir / "params.msgpack")
