"""The scoreboard: the README shows what the files give."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from chargax_marl.benchmark import scoreboard
from chargax_marl.benchmark.references import (
    BOUND,
    RULES,
    load_references,
    reference_path,
    save_references,
)
from chargax_marl.benchmark.tasks import get_task
from chargax_marl.trace import params_fingerprint

ROOT = Path(__file__).resolve().parents[2]
SCORES = ROOT / "results" / "scores"


def test_the_readme_shows_the_current_version_s_scoreboard():
    table = scoreboard.render(SCORES, SCORES / "score_time.json")
    assert scoreboard.embedded((ROOT / "README.md").read_text()) == table
    assert f"-v{scoreboard.CURRENT_VERSION}` |" in table.splitlines()[0]
    assert f"-v{scoreboard.CURRENT_VERSION - 1}`" not in table
    assert "| LP bound (occupancy) | 1.00 ± " in table
    assert "always-max | 0.00 ± 0.00 (+0.0)" in table


@pytest.mark.parametrize("version", [1, 2])
def test_the_docs_show_the_older_versions_scoreboards(version):
    table = scoreboard.render(SCORES, SCORES / "score_time.json", version=version)
    assert scoreboard.embedded((ROOT / "docs" / "benchmark.md").read_text(), version) == table
    assert f"-v{version}` |" in table.splitlines()[0]
    bound = {1: "occupancy", 2: "port-pooled"}[version]
    assert f"| LP bound ({bound}) | 1.00 ± " in table


def test_a_version_without_tasks_is_refused():
    with pytest.raises(ValueError, match="field 'version' must be one of"):
        scoreboard.render(version=99)


def test_a_stale_score_file_is_refused(tmp_path):
    stored = json.loads((SCORES / "ippo_Chargax-shopping-v1.json").read_text())
    stored["params_fingerprint"] = "0" * 16
    (tmp_path / "stale.json").write_text(json.dumps(stored))
    with pytest.raises(ValueError, match="re-score the run"):
        scoreboard.read_scores(tmp_path)


def test_embed_replaces_only_the_block():
    text = f"a\n{scoreboard.START}\nold\n{scoreboard.END}\nb\n"
    assert scoreboard.embed(text, "new") == f"a\n{scoreboard.START}\nnew\n{scoreboard.END}\nb\n"
    with pytest.raises(ValueError, match="no <!-- scoreboard:start -->"):
        scoreboard.embedded("no block")
    # an end marker before the start is no block (it raised IndexError)
    backwards = f"a\n{scoreboard.END}\nold\n{scoreboard.START}\nb\n"
    with pytest.raises(ValueError, match="an end after the start"):
        scoreboard.embed(backwards, "new")


def _edf_file(tmp_path, **fields):
    """A score file of EDF's stored profits on the 10 % grid task, with ``fields`` set (a
    value of None: that field left out)."""
    task_id = "Chargax-shopping-grid10-high-v1"
    profit = np.asarray(load_references(task_id)["policies"]["edf"]["daily_profit"])
    data = {
        "name": "EDF as a file",
        "task": task_id,
        "score": 0.0,
        "seeds": 1,
        "daily_profit": profit[None].tolist(),
        "params_fingerprint": params_fingerprint(get_task(task_id).make_params()),
    }
    data.update(fields)
    data = {k: v for k, v in data.items() if v is not None}
    (tmp_path / "edf.json").write_text(json.dumps(data))
    return task_id


def test_a_score_file_without_seeds_is_shown_by_its_name(tmp_path):
    """A policy with no seeds (a hand-written rule): its row is its name; its cells are those
    of its profits on the references (it raised KeyError: 'seeds')."""
    task_id = _edf_file(tmp_path, seeds=None)
    version = get_task(task_id).version
    table = scoreboard.render(tmp_path, version=version)
    row = next(line for line in table.splitlines() if line.startswith("| EDF as a file |"))
    edf = next(line for line in table.splitlines() if line.startswith("| EDF |"))
    columns = [t for t, task in scoreboard.TASKS.items() if task.version == version]
    column = columns.index(task_id) + 2
    assert row.split("|")[column] == edf.split("|")[column]
    assert "| `shopping-grid10-high-v1` | EDF as a file |" in scoreboard.learner_gaps(tmp_path)


def test_a_score_file_without_profits_is_refused_by_name(tmp_path):
    _edf_file(tmp_path, daily_profit=None)
    with pytest.raises(ValueError, match=r"edf.json: .* lacks \['daily_profit'\]"):
        scoreboard.read_scores(tmp_path)


def test_a_cell_says_how_many_days_it_rests_on_when_days_were_left_out(tmp_path):
    result = {"score": 0.5, "score_stderr": 0.1, "over_always_max_eur": {"mean": 3.0}}
    assert scoreboard._cell({**result, "days_scored": 100}, 100) == "0.50 ± 0.10 (+3.0)"
    assert (
        scoreboard._cell({**result, "days_scored": 98}, 99) == "0.50 ± 0.10 (+3.0; 98 of 99 days)"
    )
    # the shipped LP bound has every day of every task
    for task_id in scoreboard.TASKS:
        assert scoreboard._scored_days(task_id) == 100
    # a day whose bound solve failed has no headroom: every score of the task rests on 99
    task_id = "Chargax-shopping-grid10-high-v1"
    refs = json.loads(reference_path(task_id).read_text())
    refs["policies"][BOUND]["daily_profit"][44][7] = None
    save_references(refs, tmp_path)
    assert scoreboard._scored_days(task_id, tmp_path) == 99


def test_the_learner_gaps_pair_the_best_agent_with_both_mpcs_and_the_strongest_rule(tmp_path):
    """A score file made of EDF's profits on the 10 % grid task: its gaps are EDF's paired
    differences with the two MPCs and the strongest rule; the committed table is the
    generated one."""
    task_id = "Chargax-shopping-grid10-high-v1"
    refs = load_references(task_id)["policies"]
    edf = np.asarray(refs["edf"]["daily_profit"])
    fingerprint = params_fingerprint(get_task(task_id).make_params())
    for name, profit in (("EDF as a run", edf), ("worse", edf - 1.0)):
        data = {"name": name, "task": task_id, "seeds": 1, "daily_profit": profit[None].tolist()}
        data.update(score=float(profit.mean()), params_fingerprint=fingerprint)
        (tmp_path / f"{name}.json").write_text(json.dumps(data))
    table = scoreboard.learner_gaps(tmp_path)
    day = edf.mean(1)

    def pm(other):
        diff = day - np.asarray(refs[other]["daily_profit"]).mean(1)
        return f"{diff.mean():+.1f} ± {diff.std(ddof=1) / np.sqrt(diff.size):.1f}"

    best = max(RULES, key=lambda r: np.nanmean(refs[r]["daily_profit"]) if r in refs else -1e9)
    row = table.splitlines()[2]
    assert row.startswith("| `shopping-grid10-high-v1` | EDF as a run (1 seeds) |")
    assert row.endswith(f"| {pm('mpc')} | {pm('mpc_levels1')} | coupled plan | {pm(best)} |")
    assert best == "coupled_plan" and len(table.splitlines()) == 3
    assert (SCORES / "learner_gaps.md").read_text() == scoreboard.learner_gaps(SCORES) + "\n"
