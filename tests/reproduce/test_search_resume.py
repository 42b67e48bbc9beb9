"""A search task killed part-way resumes after the battles it finished and ends with the
numbers of an uninterrupted task (battles are independent: start state i, seed seed + i)."""

from __future__ import annotations

import json

import pytest

from hybridmarl.reproduce import worker
from hybridmarl.training.task import TaskSpec, make_task

PLAYER = "uct:script=attack-closest,playout1=attack-weakest,traversals=4,time_ms=0"
N, SEED = 4, 5


@pytest.fixture(scope="module")
def task():
    return make_task(TaskSpec(env="combat", scenario="m5v5", enemy="attack-weakest"))


@pytest.fixture(scope="module")
def uninterrupted(task, tmp_path_factory):
    d = tmp_path_factory.mktemp("whole")
    return worker.evaluate_search(task, PLAYER, N, SEED, d)


def test_a_killed_search_task_resumes_where_it_stopped(task, uninterrupted, tmp_path, monkeypatch):
    # Save after every battle and die after the second one, as a killed worker would.
    monkeypatch.setattr(worker, "PARTIAL_EVERY_S", 0.0)
    from hybridmarl.training import evaluate

    real = evaluate.play_search_battles

    def killed_after_two(*args, on_battle=None, **kwargs):
        def hook(done, ep, decisions):
            on_battle(done, ep, decisions)
            if done == 2:
                raise KeyboardInterrupt

        return real(*args, on_battle=hook, **kwargs)

    monkeypatch.setattr(evaluate, "play_search_battles", killed_after_two)
    with pytest.raises(KeyboardInterrupt):
        worker.evaluate_search(task, PLAYER, N, SEED, tmp_path)
    saved = json.loads((tmp_path / worker.PARTIAL_FILE).read_text())
    assert len(saved["episodes"]["won"]) == 2 and saved["stats"]["traversals"][1] > 0

    monkeypatch.setattr(evaluate, "play_search_battles", real)
    started = []
    monkeypatch.setattr(
        evaluate,
        "play_search_battles",
        lambda *a, **k: (started.append(k["first"]), real(*a, **k))[1],
    )
    summary, per_episode, (wall_before, _) = worker.evaluate_search(task, PLAYER, N, SEED, tmp_path)
    assert started == [2] and wall_before > 0
    whole_summary, whole_per_episode, _ = uninterrupted
    assert per_episode == whole_per_episode
    for k in ("W", "R", "traversals_per_decision", "nodes_per_decision"):
        assert summary[k] == pytest.approx(whole_summary[k]), k


def test_a_partial_file_of_another_task_is_ignored(task, uninterrupted, tmp_path):
    (tmp_path / worker.PARTIAL_FILE).write_text(
        json.dumps({"player": "other", "n": N, "seed": SEED, "episodes": {"won": [1.0] * 3}})
    )
    _, per_episode, (wall_before, _) = worker.evaluate_search(task, PLAYER, N, SEED, tmp_path)
    assert wall_before == 0.0 and per_episode == uninterrupted[1]
    (tmp_path / worker.PARTIAL_FILE).write_text("{not json")
    assert worker.evaluate_search(task, PLAYER, N, SEED, tmp_path)[1] == uninterrupted[1]
