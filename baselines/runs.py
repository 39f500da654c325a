"""What a training run writes: parameters (msgpack), results as JSON, learning-curve plots."""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import flax.serialization
import jax
import jax.numpy as jnp
import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines.algos import registry

CHECKPOINT = "checkpoint.msgpack"
"""The file name of a run's checkpoint in its output directory."""

CHECKPOINT_FORMAT = 1
"""The layout of `save_checkpoint`'s file; a checkpoint of another layout is refused."""


def atomic_write_bytes(data: bytes, path: str | Path) -> Path:
    """Write ``data`` to ``path`` so that ``path`` holds either its old or its new content.

    The bytes go to a temporary file in the same directory, are flushed to disk, and the file
    is renamed over ``path`` (``os.replace``, atomic on POSIX): a process killed while writing
    leaves the previous file whole (and at worst a stray ``.tmp`` file).

    Args:
        data: The file's new content.
        path: The file to write.

    Returns:
        ``path``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def save_params(params, path: str | Path) -> Path:
    """Write ``params`` (any pytree of arrays) as flax msgpack, atomically.

    Args:
        params: The parameters (e.g. every seed's, leading axis = seed).
        path: The file to write.

    Returns:
        ``path``.
    """
    return atomic_write_bytes(flax.serialization.to_bytes(jax.device_get(params)), path)


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
    """Write ``obj`` (see `to_jsonable`) as indented JSON whose number lists take one line
    each, atomically (`atomic_write_bytes`)."""
    return atomic_write_bytes((_dumps(to_jsonable(obj)) + "\n").encode(), path)


def save_checkpoint(path: str | Path, run: dict, next_chunk: int, runner_state, progress) -> Path:
    """Write the whole state of an unfinished training run, atomically.

    Args:
        path: The checkpoint file (`CHECKPOINT` in the run directory).
        run: What restarts the run: the algorithm, the resolved config and the run keys
            (JSON values).
        next_chunk: The index of the chunk to train next.
        runner_state: The trainer's runner state after the chunks before ``next_chunk``
            (parameters, optimiser state, env states, keys, update counter of every seed).
        progress: What the run has recorded so far (the metrics of each chunk, the held-out
            evaluations, the seconds spent), any mix of dicts, lists, arrays and numbers.

    Returns:
        ``path``.
    """
    leaves = [np.asarray(x) for x in jax.tree.leaves(jax.device_get(runner_state))]
    payload = {
        "format": CHECKPOINT_FORMAT,
        "run": json.dumps(run, sort_keys=True),
        "next_chunk": int(next_chunk),
        "runner_state": {str(i): x for i, x in enumerate(leaves)},
        "progress": _to_msgpack(progress),
    }
    return atomic_write_bytes(flax.serialization.msgpack_serialize(payload), path)


def load_checkpoint(path: str | Path, runner_template=None) -> dict:
    """Read a checkpoint of `save_checkpoint`.

    Args:
        path: The checkpoint file.
        runner_template: A pytree with the runner state's structure, shapes and dtypes (e.g.
            ``jax.eval_shape`` of the trainer's init); None leaves ``runner_state`` a list of
            its leaves.

    Returns:
        ``{"run", "next_chunk", "runner_state", "progress"}``.

    Raises:
        ValueError: The file is not a checkpoint of this layout, or its runner state does not
            match ``runner_template`` (another algorithm, config or code version).
    """
    path = Path(path)
    try:
        payload = flax.serialization.msgpack_restore(path.read_bytes())
    except Exception as e:  # msgpack raises several types on truncated or foreign bytes
        raise ValueError(f"{path}: not a readable training checkpoint ({e})") from e
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(
            f"{path}: not a training checkpoint of format {CHECKPOINT_FORMAT} "
            f"(got {payload.get('format') if isinstance(payload, dict) else type(payload)})"
        )
    stored = payload["runner_state"]
    leaves = [np.asarray(stored[str(i)]) for i in range(len(stored))]
    runner_state = leaves
    if runner_template is not None:
        want, treedef = jax.tree.flatten(runner_template)
        got = [(x.shape, x.dtype) for x in leaves]
        if got != [(tuple(w.shape), np.dtype(w.dtype)) for w in want]:
            raise ValueError(
                f"{path}: the stored runner state ({len(leaves)} arrays) does not match this "
                f"trainer's ({len(want)} arrays): another algorithm, config or code version"
            )
        runner_state = jax.tree.unflatten(treedef, [jnp.asarray(x) for x in leaves])
    return {
        "run": json.loads(payload["run"]),
        "next_chunk": int(payload["next_chunk"]),
        "runner_state": runner_state,
        "progress": _from_msgpack(payload["progress"]),
    }


def _to_msgpack(x):
    """``x`` with lists tagged (msgpack stores dicts with string keys, arrays and numbers)."""
    if isinstance(x, dict):
        return {"dict": {str(k): _to_msgpack(v) for k, v in x.items()}}
    if isinstance(x, (list, tuple)):
        return {"list": {str(i): _to_msgpack(v) for i, v in enumerate(x)}}
    if x is None:
        return {"none": 0}
    if isinstance(x, (np.ndarray, jnp.ndarray)):
        return {"array": np.asarray(x)}
    return {"value": x}


def _from_msgpack(x):
    """The inverse of `_to_msgpack`."""
    ((tag, v),) = x.items()
    if tag == "dict":
        return {k: _from_msgpack(u) for k, u in v.items()}
    if tag == "list":
        return [_from_msgpack(v[str(i)]) for i in range(len(v))]
    if tag == "none":
        return None
    return v


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
    """Mean and std over seeds of learning curves ``(seeds, points)`` after `smooth_nan`;
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
    greedy evaluations, and every reference of ``baselines`` present (`LINES`) as a line."""
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
