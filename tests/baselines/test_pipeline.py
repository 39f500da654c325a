"""The pipeline's protocol: evaluations during training play only the validation days; the
held-out days are played once, by the finished run."""

from __future__ import annotations

import numpy as np

from baselines import pipeline
from baselines.algos import runner
from baselines.config import build_env_params, load, validation_env
from baselines.eval import heldout, rules
from tests.helpers import TINY_CLI


def test_no_evaluation_during_training_plays_a_held_out_day(monkeypatch):
    # the tiny IPPO run of the other pipeline tests (their compiled programs are shared), in
    # two chunks of one update, 20 held-out and 20 validation days
    config, _ = load("cpu", [*TINY_CLI[2:], f"TOTAL_TIMESTEPS={2 * 4 * 24}", "OPTIMAL=off"])
    _, _, _, held_out = build_env_params(config)
    _, val_days, _ = validation_env(config)
    assert not np.intersect1d(val_days, held_out).size
    phase = ["before training"]
    played = []  # (phase, what, days) of every evaluation of the policy or the rules

    def recording(name, fn, days_at):
        def wrapped(*args, **kwargs):
            played.append((phase[0], name, np.asarray(args[days_at]).tolist()))
            return fn(*args, **kwargs)

        monkeypatch.setattr(module_of[name], name, wrapped)

    module_of = {"evaluate_batched": heldout, "evaluate_rules": rules}
    recording("evaluate_batched", heldout.evaluate_batched, 3)
    recording("evaluate_rules", rules.evaluate_rules, 1)
    run_in_chunks = runner.run_in_chunks

    def training(*args, **kwargs):
        phase[0] = "training"
        try:
            return run_in_chunks(*args, **kwargs)
        finally:
            phase[0] = "after training"

    monkeypatch.setattr(runner, "run_in_chunks", training)
    programs = []  # the compiled evaluation every evaluation of the policy ran
    keyed = heldout.compiled_keyed_evaluation

    def compiled(make_act, params):
        programs.append(keyed(make_act, params))
        return programs[-1]

    monkeypatch.setattr(heldout, "compiled_keyed_evaluation", compiled)
    res = pipeline.run("ippo", config, seeds=2, chunks=2, quiet=True).results
    # the held-out evaluation ran the validation's program: one compile for all three
    assert len(programs) == 3 and len({id(fn) for fn in programs}) == 1
    assert programs[0]._cache_size() == 1

    val, held = val_days.tolist(), held_out.tolist()
    until_trained = [p for p in played if p[0] != "after training"]
    assert [p[1] for p in until_trained if p[0] == "training"] == ["evaluate_batched"] * 2
    assert all(days == val for _, _, days in until_trained), until_trained
    after = [p for p in played if p[0] == "after training"]
    assert sorted(p[1] for p in after) == ["evaluate_batched", "evaluate_rules"]
    assert all(days == held for _, _, days in after), after
    # what the results say the evaluations played
    assert res["validation"]["days"] == val and res["evaluation"]["days"] == held
    assert (
        res["validation"]["draws"] == 1 and "NUM_VALIDATION_DAYS=20" in res["validation"]["source"]
    )
    assert [e["timesteps"] for e in res["eval_curve"]] == [4 * 24, 4 * 24 * 2]
    assert res["evaluation"]["table"]["ippo"]["num_days"] == 20
