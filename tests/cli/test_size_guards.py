"""The size guards of ``train``, ``demos collect`` and ``eval --n`` (cli.sizes): above their
threshold they stop before any work with one line (the estimate, the option, --yes) and exit
code 2; ``--yes`` passes them; no preset at its defaults, nor any task of the reproduction
grid, trips them."""

from __future__ import annotations

import functools

import pytest

from hybridmarl.cli import sizes
from hybridmarl.cli.main import main
from hybridmarl.training.task import TaskSpec, make_task


@functools.cache
def _task(env: str, scenario: str | None):
    """The task of ``env``/``scenario`` (the sizes of its state and observation do not depend on
    the setting)."""
    return make_task(
        TaskSpec(env=env) if scenario is None else TaskSpec(env=env, scenario=scenario)
    )


def _one_line_error(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    return lines[0]


def test_train_refuses_a_huge_buffer_before_any_work(tmp_path, capsys):
    run = tmp_path / "run"
    assert (
        main(
            [
                "train",
                "--preset",
                "toy",
                "--scenario",
                "m3v3",
                "--buffer-size",
                "10000000000",
                "--run-dir",
                str(run),
            ]
        )
        == 2
    )
    line = _one_line_error(capsys)
    assert (
        line.startswith("hybridmarl: error: --buffer-size 10000000000:")
        and "GiB" in line
        and "--yes" in line
    ), line
    assert not run.exists()


def test_train_size_guard_passes_with_yes():
    from hybridmarl.algos.hybrid.config import PRESETS

    cfg = PRESETS["toy"]("combat").replace(scenario="m3v3", num_envs=10**7)
    with pytest.raises(sizes.SizeError, match="^--num-envs 10000000: .* pass --yes"):
        sizes.check_train_size(cfg, _task("combat", "m3v3"), yes=False)
    sizes.check_train_size(cfg, _task("combat", "m3v3"), yes=True)


def test_demos_collect_refuses_a_huge_n(tmp_path, capsys):
    out = tmp_path / "d.safetensors"
    assert (
        main(["demos", "collect", "--scenario", "m3v3", "--n", "1000000000", "--out", str(out)])
        == 2
    )
    line = _one_line_error(capsys)
    assert (
        line.startswith("hybridmarl: error: --n 1000000000 observations of m3v3")
        and "CPU time" in line
        and "--yes" in line
    ), line
    assert not out.exists()
    with pytest.raises(sizes.SizeError):
        sizes.check_demos_size(10**9, _task("combat", "m3v3"), yes=False)
    sizes.check_demos_size(10**9, _task("combat", "m3v3"), yes=True)


def test_eval_refuses_a_huge_n(tmp_path, capsys):
    out = tmp_path / "e.json"
    assert (
        main(
            [
                "eval",
                "--script",
                "attack-closest",
                "--scenario",
                "m3v3",
                "--n",
                "1000000000",
                "--out",
                str(out),
            ]
        )
        == 2
    )
    line = _one_line_error(capsys)
    assert (
        line.startswith("hybridmarl: error: --n 1000000000 episodes of m3v3") and "--yes" in line
    ), line
    assert not out.exists()
    with pytest.raises(sizes.SizeError):
        sizes.check_eval_size(10**9, _task("combat", "m3v3"), yes=False)
    sizes.check_eval_size(10**9, _task("combat", "m3v3"), yes=True)


def test_thresholds_sit_where_the_docs_say():
    # m5v5: 6,598 bytes a state and joint observation (528 + 5 x (4 x 301 + 10)).
    state, observation = sizes.task_sizes(_task("combat", "m5v5"))
    assert (state, observation) == (528, 6070)
    assert (
        sizes.CONFIRM_BYTES // sizes.demos_memory(1, state, observation) == 433_966
    )  # demos collect --n
    assert sizes.CONFIRM_BYTES // sizes.eval_memory(1, state, observation) == 433_966  # eval --n


def test_no_preset_and_no_reproduction_task_trips_a_guard():
    from hybridmarl import algos
    from hybridmarl.reproduce import grid as G
    from hybridmarl.reproduce import protocol as P

    scenarios = dict.fromkeys((*P.SCENARIOS, *P.FIG3_SCENARIOS, "m5v5"))
    for algo in algos.ALGOS:
        mod = algos.algo_module(algo)
        for make in mod.PRESETS.values():
            for scenario in scenarios:
                sizes.check_train_size(
                    make("combat").replace(scenario=scenario), _task("combat", scenario), yes=False
                )
            sizes.check_train_size(
                make("traffic_junction"), _task("traffic_junction", None), yes=False
            )
    checked = 0
    for budget in P.BUDGETS:
        for setting in ("sparcraft", "paper"):
            grid = G.expand(P.TABLES, budget, setting)
            for task in grid.tasks.values():
                c = task.config
                env_task = _task(c["env"], c.get("scenario"))
                sizes.check_eval_size(c["n"], env_task, yes=False)
                if task.kind == "train":  # the config the harness trains (reproduce.worker)
                    cfg = (
                        algos.algo_module(c["algo"])
                        .PRESETS[c["preset"]](c["env"])
                        .replace(**c["overrides"])
                    )
                    sizes.check_train_size(cfg, env_task, yes=False)
                    checked += 1
    assert checked > 100
