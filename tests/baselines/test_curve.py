"""A run's learning curve (`baselines.runs.plot_curve`): its title says what was trained, and
its legend stays off the data."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from baselines import runs
from baselines.config import resolve

ROOT = Path(__file__).resolve().parents[2]


def test_the_title_names_the_algorithm_the_task_and_the_seeds():
    config = resolve({"TASK": "Chargax-shopping-v3"})
    assert runs.curve_title("ippo", config, 4) == "IPPO on Chargax-shopping-v3: 4 seeds"
    assert (
        runs.curve_title("mappo", config, 1, draws=8)
        == "MAPPO on Chargax-shopping-v3: 1 seed, held-out days x 8 car draws"
    )


def test_without_a_task_the_title_names_the_scenario_and_its_traffic():
    """``TRAFFIC`` unset is the scenario's own traffic, not None."""
    config = resolve({"SCENARIO": "shopping"})
    assert config["TRAFFIC"] is None
    assert runs.curve_title("ippo", config, 4) == "IPPO on shopping, medium traffic: 4 seeds"
    config = resolve({"SCENARIO": "workplace", "TRAFFIC": "high"})
    assert runs.curve_title("ppo", config, 2) == "PPO on workplace, high traffic: 2 seeds"
    config = resolve({"SCENARIO": "shopping", "TRAFFIC": 150})
    assert runs.curve_title("ppo", config, 2) == "PPO on shopping, 150 cars per day: 2 seeds"


def test_a_committed_run_is_redrawn_with_its_title_and_the_legend_outside(tmp_path, monkeypatch):
    """`plot_run` (``scripts/plot_curve.py``, the docs' image) on `make train`'s committed run:
    its task in the title, and the legend right of the axes, clear of every point."""
    results = json.loads((ROOT / "results/ippo_shopping_v2/results.json").read_text())
    figures = []
    close = runs.plt.close
    monkeypatch.setattr(runs.plt, "close", lambda fig: figures.append(fig))
    path = runs.plot_run(results, tmp_path / "curve.png")
    assert path.stat().st_size > 0
    (fig,) = figures
    (ax,) = fig.axes
    assert ax.get_title() == "IPPO on Chargax-shopping-v2: 4 seeds"
    fig.canvas.draw()
    legend = ax.get_legend().get_window_extent()
    assert legend.x0 >= ax.get_window_extent().x1
    labels = [t.get_text() for t in ax.get_legend().get_texts()]
    assert "ippo validation (greedy)" in labels and "ippo held-out (greedy, final)" in labels
    close(fig)


def test_the_validation_and_held_out_points_differ_in_shape_not_only_colour(tmp_path, monkeypatch):
    figures = []
    close = runs.plt.close
    monkeypatch.setattr(runs.plt, "close", lambda fig: figures.append(fig))
    steps = np.arange(1, 5) * 100
    runs.plot_learning_curve(
        tmp_path / "c.png",
        steps,
        {"training": np.ones((2, 4))},
        {"always-max": 1.0, "bound": 2.0},
        "t",
        eval_points={"validation": (steps, np.ones((2, 4))), "held-out": ([400], np.ones((2, 1)))},
    )
    (fig,) = figures
    (ax,) = fig.axes
    points = [c.lines[0] for c in ax.containers]  # the errorbars' data lines
    assert [c.get_label() for c in ax.containers] == ["validation", "held-out"]
    shapes = {line.get_marker() for line in points}
    assert len(shapes) == 2
    references = [line for line in ax.get_lines() if line.get_label() in ("always-max", "bound")]
    assert len({str(line.get_linestyle()) for line in references}) == 2
    close(fig)
