"""What a training run writes: parameters (msgpack), results as JSON, learning-curve plots,
and the claim on its output directory (`claim_run_dir`) that keeps two runs out of one."""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path

import flax.serialization
import jax
import jax.numpy as jnp
import matplotlib
import matplotlib.pyplot as plt
import numpy as np

from baselines.algos import registry
from baselines.config import stored_config
from chargax_marl.core import checks
from chargax_marl.core.scenarios import SCENARIOS

CHECKPOINT = "checkpoint.msgpack"
"""The file name of a run's checkpoint in its output directory."""

CHECKPOINT_FORMAT = 1
"""The layout of `save_checkpoint`'s file; a checkpoint of another layout is refused."""

RUN_FILES = ("results.json", "params.msgpack", "curve.png", CHECKPOINT)
"""The files a training run writes in its output directory: any of them marks a run there."""

LOCK = ".lock"
"""The lock file in a run directory while a run writes it (see `claim_run_dir`)."""


class RunDirError(FileExistsError):
    """An output directory (or path prefix) that holds another run's files, or that another
    live process is writing."""


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
    """Read parameters written by `save_params`.

    Args:
        template: a pytree of the parameters' structure (its leaves' values are replaced).
        path: the msgpack file.

    Returns:
        ``template``'s structure with the file's arrays.
    """
    return flax.serialization.from_bytes(template, Path(path).read_bytes())


def to_jsonable(x):
    """``x`` as JSON values: arrays as lists, non-finite floats as ``None``, and a float that is
    a float32 value as the shortest decimal that reads back to the same float32 (the trainers'
    metrics are float32; their float64 expansions took three times the digits).

    Args:
        x: a value: dicts (keys made strings), lists and tuples are converted element by
            element; any other value that is not a NumPy or JAX array or scalar is kept as it
            is.

    Returns:
        ``x`` as dicts, lists, floats, ints, None and the values kept.
    """
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
    each, atomically (`atomic_write_bytes`).

    Args:
        obj: the object to write (a value `to_jsonable` does not convert is written as its
            ``str``).
        path: the file to write.

    Returns:
        ``path``.
    """
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
        progress: What the run has recorded so far (the metrics of each chunk, the validation
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
    """Carry the last finite value forward along the last axis (updates with no finished episode).

    Args:
        x: an array whose last axis is the points of a curve.

    Returns:
        A float64 copy with each non-finite entry replaced by the last finite one before it
        (NaN before the first).
    """
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
    points before any seed's first finished episode stay NaN (matplotlib leaves them out).

    Args:
        curves: ``(seeds, points)`` learning curves (one curve: ``(points,)``).

    Returns:
        ``(mean, std)``, each ``(points,)``, over the seeds that have a value at the point.
    """
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
    ``eval_points``: optional ``{label: (timesteps, (seeds, n) array)}`` drawn with markers.
    Every line and every set of points has its own line style or marker (`LINE_STYLES`,
    `POINT_STYLES`), so they stay apart in grey-scale print; the legend sits right of the
    axes, outside the data.

    Args:
        path: the image file to write (its folder is created if missing).
        timesteps: ``(points,)`` the env steps of the curves' points.
        curves: ``{label: (seeds, points)}`` the curves, each drawn as its mean with a band
            of ± one std (`seed_mean_std`).
        baselines: ``{label: value}`` drawn as horizontal lines.
        title: the plot's title.
        eval_points: ``{label: (timesteps, (seeds, n))}`` drawn as mean ± std markers; None
            for none.
        ylabel: the y axis's label.

    Returns:
        ``path``.
    """
    matplotlib.use("Agg")

    fig, ax = plt.subplots(figsize=(10, 4.2))
    for label, y in curves.items():
        m, s = seed_mean_std(y)
        (line,) = ax.plot(timesteps, m, label=label, lw=1.5)
        ax.fill_between(timesteps, m - s, m + s, alpha=0.25, color=line.get_color())
    for i, (label, (t, y)) in enumerate((eval_points or {}).items()):
        y = np.atleast_2d(y)
        style = POINT_STYLES[i % len(POINT_STYLES)]
        ax.errorbar(t, y.mean(0), yerr=y.std(0), capsize=3, color=f"C{i + 1}", label=label, **style)
    for i, (label, v) in enumerate(baselines.items()):
        ax.axhline(v, ls=LINE_STYLES[i % len(LINE_STYLES)], lw=1.2, color=f"C{i + 3}", label=label)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0)
    ax.grid(alpha=0.3)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


POINT_STYLES = (
    {"marker": "o", "ms": 5, "ls": "--", "lw": 1.0},
    {"marker": "s", "ms": 7, "ls": "none", "mfc": "white", "mew": 1.5},
    {"marker": "^", "ms": 6, "ls": ":", "lw": 1.0},
    {"marker": "D", "ms": 6, "ls": "none", "mfc": "white", "mew": 1.5},
)
"""The markers of a learning curve's evaluation points, in order: the validation evaluations
(filled circles on a dashed line), the final held-out evaluation (an open square), then
others; shapes and fills that grey-scale print keeps apart."""

LINE_STYLES = (
    "--",
    ":",
    "-.",
    (0, (6, 2, 1, 2, 1, 2)),
    (0, (1, 3)),
    (0, (10, 3)),
    (0, (4, 1, 4, 1, 1, 1)),
    (0, (2, 2)),
)
"""The dash patterns of a learning curve's reference lines, one per line in order."""


def curve_title(algo: str, config: dict, seeds: int, draws: int = 1) -> str:
    """A learning curve's title: the algorithm, what it trained on and the seeds.

    Args:
        algo: the algorithm's name (``"ippo"``).
        config: the run's resolved config (``TASK``, ``SCENARIO``, ``TRAFFIC``).
        seeds: the seeds trained.
        draws: the car draws per held-out day (named when more than one).

    Returns:
        ``"IPPO on <task id>: N seeds"``, or without a task ``"IPPO on <scenario>, <traffic>
        traffic: N seeds"`` (the scenario's own traffic where ``TRAFFIC`` is unset; a number
        of cars per day as ``"<n> cars per day"``), with
        ``", held-out days x D car draws"`` when ``draws`` > 1.
    """
    if config.get("TASK"):
        trained_on = str(config["TASK"])
    else:
        scenario = config["SCENARIO"]
        traffic = config.get("TRAFFIC")
        if traffic is None:
            traffic = SCENARIOS.get(scenario, {}).get("traffic", "default")
        if isinstance(traffic, str):
            trained_on = f"{scenario}, {traffic} traffic"
        else:
            trained_on = f"{scenario}, {traffic:g} cars per day"
    seeds_text = f"{seeds} seed" + ("s" if seeds != 1 else "")
    return f"{algo.upper()} on {trained_on}: {seeds_text}" + (
        f", held-out days x {draws} car draws" if draws > 1 else ""
    )


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
    path,
    algo: str,
    timesteps,
    episode_profit,
    baselines: dict,
    evals: list,
    title: str,
    validation: dict | None = None,
):
    """A run's learning curve: the sampled training-episode profit over seeds, the greedy
    evaluations during training (on the validation days), the final held-out evaluation, and
    the references as lines.

    Args:
        path: the PNG to write.
        algo: the algorithm's name, for the labels.
        timesteps: the env steps of the training curve's points.
        episode_profit: ``(seeds, points)`` sampled training-episode profits.
        baselines: the held-out references by name (a run's evaluation table); every one of
            `LINES` present, and always-max, is drawn as a line; an entry ``algo`` (the
            trained policy's held-out evaluation) is drawn as a point at the last step.
        evals: a run's ``eval_curve``, the validation evaluations, drawn as points.
        title: the plot's title.
        validation: the validation days' references (a run's ``validation["references"]``):
            always-max on them is drawn as a line too.
    """
    am = baselines["always_max"]["metrics"]["daily_profit_eur"]["mean"]
    lines = {f"always-max (held-out) {am:.0f}": am}
    for key, label in LINES:
        if key in baselines:
            v = baselines[key]["metrics"]["daily_profit_eur"]["mean"]
            lines[f"{label} (held-out) {v:.0f}"] = v
    if validation and "always_max" in validation:
        v = validation["always_max"]["metrics"]["daily_profit_eur"]["mean"]
        lines[f"always-max (validation) {v:.0f}"] = v
    points = {}
    if evals:
        points[f"{algo} validation (greedy)"] = (
            [e["timesteps"] for e in evals],
            np.asarray([e["per_seed_profit"] for e in evals]).T,
        )
    final = baselines.get(algo)
    if isinstance(final, dict) and "per_seed_profit" in final and len(timesteps):
        points[f"{algo} held-out (greedy, final)"] = (
            [np.asarray(timesteps)[-1]],
            np.asarray([final["per_seed_profit"]]).T,
        )
    plot_learning_curve(
        path,
        timesteps,
        {f"{algo} training episodes (sampled)": np.asarray(episode_profit)},
        lines,
        title,
        eval_points=points or None,
    )


def plot_run(results: dict, path) -> Path:
    """Draw a finished run's learning curve (`plot_curve`) from its ``results.json``.

    Args:
        results: a run's results (what ``results.json`` holds, parsed).
        path: the PNG to write.

    Returns:
        ``path`` as a `pathlib.Path`.
    """
    config = stored_config(results["config"])
    curve = results["curve"]
    evaluation = results["evaluation"]
    draws = int(evaluation.get("draws", 1))
    plot_curve(
        path,
        results["algo"],
        curve["timesteps"],
        curve["episode_profit_eur"],
        evaluation["table"],
        results["eval_curve"],
        curve_title(results["algo"], config, results["seeds"], draws),
        validation=(results.get("validation") or {}).get("references"),
    )
    return Path(path)


def load_run(run_dir: str | Path):
    """``(results, train, params)`` of a ``baselines.train`` output directory: its
    ``results.json``, the rebuilt ``train`` of its algorithm and config, and the trained
    parameters of every seed (leading axis = seed) from ``params.msgpack``.

    Args:
        run_dir: the run's output directory.

    Returns:
        ``(results, train, params)``: the parsed ``results.json``, the
        `baselines.algos.trainer.Trainer` of its algorithm and stored config, and the
        parameters of every seed.
    """
    run_dir = Path(run_dir)
    results = json.loads((run_dir / "results.json").read_text())
    train = registry.make_train(results["algo"], stored_config(results["config"]))
    template = jax.vmap(train.policy.init)(
        jax.random.split(jax.random.PRNGKey(0), int(results["seeds"]))
    )
    return results, train, load_params(template, run_dir / "params.msgpack")


def _holder(text: str) -> str:
    """Who a lock file's ``text`` (`_lock`'s JSON) names, for a message."""
    try:
        d = json.loads(text)
        return f"PID {d['pid']} on host {d['host']}"
    except (ValueError, TypeError, KeyError):
        return "a process that has not yet written its PID"


@contextlib.contextmanager
def _lock(path: Path, what: str) -> Iterator[None]:
    """Hold the exclusive lock ``path`` (``fcntl.flock``) for the duration of the block.

    The lock file holds the holder's PID and host as JSON, for the messages. The kernel
    releases a ``flock`` when its process ends, however it ends: a lock file that nobody holds
    was left by a process that ended without removing it (killed, or its machine restarted),
    and is taken over with a message on stderr. The lock file is removed on leaving the block,
    normally or by an exception.

    Args:
        path: The lock file.
        what: What the lock guards, for the messages (e.g. ``run directory outputs/x``).

    Raises:
        RunDirError: A live process holds the lock (the message names its PID and host), or
            ``path`` cannot be opened as a file (a directory is there, say).
    """
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as e:  # a directory or another non-file in the lock's place, no access
            raise RunDirError(
                f"{what}: its lock file {path} cannot be opened ({e.strerror}): a run's lock "
                f"is a plain file; remove what is at {path}, or write to another output"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(os.pread(fd, 4096, 0).decode(errors="replace"))
            os.close(fd)
            raise RunDirError(
                f"{what} is being written by {holder}, which holds its lock {path}: wait for "
                "that run to end, or write to another output"
            ) from None
        try:  # the file a holder removed on release is not the lock any more: open it anew
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
    try:
        previous = os.pread(fd, 4096, 0).decode(errors="replace")
        if previous.strip():
            print(
                f"{path}: taking over the stale lock of {_holder(previous)}: no process "
                "holds it any more (that run ended without releasing it, e.g. killed)",
                file=sys.stderr,
            )
        mine = {"pid": os.getpid(), "host": socket.gethostname()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(mine) + "\n").encode(), 0)
        yield
    finally:
        path.unlink(missing_ok=True)
        os.close(fd)


@contextlib.contextmanager
def _claim(
    lock: Path,
    files: Sequence[Path],
    what: str,
    overwrite: bool,
    refusal: Callable[[list[Path]], str] | None,
) -> Iterator[None]:
    """Hold ``lock`` and make sure no earlier run's ``files`` are there (see `claim_run_dir`).

    Args:
        lock: The lock file.
        files: The files a run writes; any of them present is another run's.
        what: What the lock guards, for the messages.
        overwrite: Delete ``files`` (and their temporaries) instead of refusing.
        refusal: The refusal's message from the files present; None accepts them (resume).

    Raises:
        RunDirError: A live process holds ``lock``, or ``files`` are present and neither
            ``overwrite`` nor resuming accepts them.
    """
    with _lock(lock, what):
        present = [f for f in files if f.exists()]
        if overwrite:
            for f in files:
                f.unlink(missing_ok=True)
                for tmp in f.parent.glob(f"{f.name}.*.tmp"):  # `atomic_write_bytes`'s leftovers
                    tmp.unlink(missing_ok=True)
            if present:
                print(f"{what}: deleted the previous run's {[f.name for f in present]}")
        elif present and refusal is not None:
            raise RunDirError(refusal(present))
        yield


def _stored_run(out: Path) -> dict | None:
    """The settings of the run in ``out``: its checkpoint's (algorithm, config, seeds, seed,
    chunks, references) or else its ``results.json``'s; None where neither reads."""
    try:
        stored = load_checkpoint(out / CHECKPOINT)["run"]
    except ValueError:  # no checkpoint or an unreadable one
        try:
            results = json.loads((out / "results.json").read_text())
        except (OSError, ValueError):
            return None
        stored = {k: results[k] for k in ("algo", "config", "seeds", "seed") if k in results}
    if "config" in stored:
        stored = {**stored, "config": stored_config(stored["config"])}
    return stored


def _differences(stored: dict, run: dict) -> list[str]:
    """``KEY=stored (this run: value)`` for each setting both hold with different values."""
    stored, run = to_jsonable(stored), to_jsonable(run)
    pairs = [(k, stored[k], run[k]) for k in sorted(stored) if k != "config" and k in run]
    theirs, mine = stored.get("config") or {}, run.get("config") or {}
    pairs += [(f"config {k}", theirs[k], mine[k]) for k in sorted(theirs) if k in mine]
    return [f"{k}={a!r} (this run: {b!r})" for k, a, b in pairs if a != b]


@contextlib.contextmanager
def claim_run_dir(
    out: str | Path, *, overwrite: bool = False, resume: bool = False, run: dict | None = None
) -> Iterator[Path]:
    """Claim the run directory ``out`` for one training run, for the duration of the block.

    A run directory holds one run. While the block runs, ``out/.lock`` (`LOCK`) holds an
    exclusive ``fcntl.flock`` and the PID and host of this process: a second process that
    claims ``out`` meanwhile is refused with a message naming them. A lock left by a process
    that ended without releasing it (killed) is taken over, with a message on stderr. The
    lock is released and its file removed on leaving the block, normally or by an exception.

    A directory that holds any of a run's files (`RUN_FILES`) is refused unless ``resume``
    (the run there continues from its checkpoint; `baselines.pipeline.run` checks that the
    settings match) or ``overwrite`` (that run's files are deleted first; other files in
    ``out`` are left alone).

    Args:
        out: The run directory; created if missing.
        overwrite: Delete the files of the run already in ``out`` instead of refusing.
        resume: Accept the run already in ``out``: this run continues it.
        run: This run's settings (``algo``, ``config``, ``seeds`` ...), to name the settings
            in which the run already in ``out`` differs; None names only its files.

    Yields:
        ``out`` as a `Path`.

    Raises:
        ValueError: Both ``overwrite`` and ``resume``, or ``out`` is not a usable directory
            (empty, a file, under a file, no write access:
            `chargax_marl.core.checks.output_path`).
        RunDirError: Another live process holds the lock of ``out`` (or its lock is not a
            file), or ``out`` holds a run and neither ``overwrite`` nor ``resume`` is given.
    """
    if overwrite and resume:
        raise ValueError(
            f"{out}: overwrite=True (--overwrite) deletes the run that resume=True (--resume) "
            "continues; give one of them"
        )
    out = checks.output_path("out (OUT)", out, "dir")
    out.mkdir(parents=True, exist_ok=True)

    def refusal(present: list[Path]) -> str:
        stored = _stored_run(out)
        held = f"{out} already holds a run ({', '.join(f.name for f in present)})"
        if stored is not None:
            held += f": {stored.get('algo')}, {stored.get('seeds')} seeds"
            diffs = _differences(stored, run) if run is not None else []
            if diffs:
                held += ", differing from this run in " + "; ".join(diffs)
            elif run is not None:
                held += ", with this run's settings"
        return (
            f"{held}. A run directory holds one run: write to another directory (OUT=...), "
            f"continue that run from its checkpoint (python -m baselines.train --resume {out}; "
            "resume=True), or delete its files and train afresh (--overwrite; overwrite=True)"
        )

    what = f"run directory {out}"
    files = [out / name for name in RUN_FILES]
    with _claim(out / LOCK, files, what, overwrite, None if resume else refusal):
        yield out


@contextlib.contextmanager
def claim_outputs(
    prefix: str | Path, suffixes: Sequence[str], *, overwrite: bool = False
) -> Iterator[str]:
    """Claim the result files ``prefix + suffix`` of one experiment runner, for the block.

    The rule of `claim_run_dir` for a runner's path prefix (e.g. ``outputs/traffic_sweep``
    writes ``outputs/traffic_sweep.json`` and ``.png``): ``prefix.lock`` holds the lock, and
    files of an earlier run are refused unless ``overwrite`` deletes them first.

    Args:
        prefix: The path prefix of the result files; its folder is created if missing.
        suffixes: What the runner appends to ``prefix`` (e.g. ``(".json", ".png")``).
        overwrite: Delete the earlier run's files instead of refusing.

    Yields:
        ``prefix`` as a string.

    Raises:
        ValueError: ``prefix`` is not a usable prefix (empty, a folder alone, under a file, no
            write access: `chargax_marl.core.checks.output_path`).
        RunDirError: Another live process holds ``prefix.lock``, or a file ``prefix + suffix``
            exists and ``overwrite`` is not given.
    """
    prefix = checks.output_path("prefix", prefix, "prefix")
    Path(prefix).parent.mkdir(parents=True, exist_ok=True)

    def refusal(present: list[Path]) -> str:
        return (
            f"{prefix}: the result files {[str(f) for f in present]} of an earlier run exist. "
            "Write to another path (--out or out=...), or delete them and run afresh "
            "(--overwrite; overwrite=True)"
        )

    files = [Path(prefix + suffix) for suffix in suffixes]
    with _claim(Path(prefix + ".lock"), files, f"outputs {prefix}", overwrite, refusal):
        yield prefix
