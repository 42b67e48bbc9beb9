"""The ``hybridmarl`` dispatch table and its error handling: the generated help, unknown
commands, and the one mapping of errors to exit codes (UserError -> 2, TrainingDiverged -> 3, a
missing optional package -> 2 naming the extra)."""

from __future__ import annotations

import pytest

from hybridmarl.cli import main as cli_main
from hybridmarl.cli.extras import missing_extra_error
from hybridmarl.cli.main import COMMANDS, Command, main, usage
from hybridmarl.errors import EXIT_BAD_INPUT, EXIT_DIVERGED, TrainingDiverged, UserError


def _raise_user_error(args: list[str]) -> int:
    raise UserError(f"bad thing in {args}")


def _raise_diverged(args: list[str]) -> int:
    raise TrainingDiverged("critic loss is nan at episode 12")


def _raise_missing_extra(args: list[str]) -> int:
    import imageio_not_installed_here  # type: ignore[import-not-found]  # noqa: F401

    return 0


def _missing_video(args: list[str]) -> int:
    raise ModuleNotFoundError("No module named 'imageio'", name="imageio")


def _returns_none(args: list[str]) -> None:
    return None


def _fake(monkeypatch: pytest.MonkeyPatch, fn_name: str) -> None:
    monkeypatch.setitem(COMMANDS, "fake", Command("a fake command", f"{__name__}:{fn_name}"))


def test_help_lists_every_command(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert out.strip() == usage()
    for name, cmd in COMMANDS.items():
        assert f"  {name}" in out and cmd.help in out, name
    assert set(COMMANDS) == {
        "quickstart",
        "battle",
        "trace",
        "replay",
        "train",
        "eval",
        "demos",
        "reproduce",
    }
    assert main(["-h"]) == 0
    assert main([]) == EXIT_BAD_INPUT  # no command: the help, and a failing exit code
    assert "usage: hybridmarl" in capsys.readouterr().out


def test_every_handler_resolves():
    for name, cmd in COMMANDS.items():
        assert callable(cmd.handler()), name


def test_unknown_and_removed_commands(capsys):
    for argv in (["fly"], ["bench", "engine"]):
        assert main(argv) == EXIT_BAD_INPUT
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("hybridmarl: error: unknown command"), err


def test_user_error_is_one_line_exit_2(monkeypatch, capsys):
    _fake(monkeypatch, "_raise_user_error")
    assert main(["fake", "--x"]) == EXIT_BAD_INPUT
    cap = capsys.readouterr()
    assert cap.err.splitlines() == ["hybridmarl: error: bad thing in ['--x']"] and cap.out == ""


def test_training_diverged_exit_3(monkeypatch, capsys):
    _fake(monkeypatch, "_raise_diverged")
    assert main(["fake"]) == EXIT_DIVERGED
    assert capsys.readouterr().err.splitlines() == [
        "hybridmarl: training stopped: critic loss is nan at episode 12"
    ]


def test_missing_extra_names_it(monkeypatch, capsys):
    _fake(monkeypatch, "_missing_video")
    assert main(["fake"]) == EXIT_BAD_INPUT
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and "hybridmarl[video]" in err[0], err
    # Another missing module is a bug, not bad input: it is not turned into a UserError.
    _fake(monkeypatch, "_raise_missing_extra")
    with pytest.raises(ModuleNotFoundError):
        main(["fake"])
    assert missing_extra_error(ModuleNotFoundError("x", name="matplotlib.pyplot")) is not None


def test_none_is_exit_0(monkeypatch):
    _fake(monkeypatch, "_returns_none")
    assert main(["fake"]) == 0


def test_train_defaults_and_results(monkeypatch):
    """train: the default preset is quick; --env traffic_junction --preset quick builds; a
    learner's result means exit 0, TrainingDiverged exit 3."""
    from hybridmarl import algos

    mod = algos.algo_module("hybrid")
    seen = []

    def fake_train(cfg):
        seen.append(cfg)
        return object()

    monkeypatch.setattr(mod, "train", fake_train)
    assert main(["train", "--run-dir", "runs/x", "--no-progress"]) == 0
    want = mod.PRESETS[getattr(algos, "DEFAULT_PRESET", "quick")]("combat")
    assert seen[-1] == want.replace(run_dir="runs/x", progress=False)
    assert (
        main(["train", "--env", "traffic_junction", "--preset", "quick", "--run-dir", "runs/tj"])
        == 0
    )
    assert seen[-1] == mod.PRESETS["quick"]("traffic_junction").replace(run_dir="runs/tj")
    monkeypatch.setattr(mod, "train", lambda cfg: _raise_diverged([]))
    assert main(["train", "--preset", "toy"]) == EXIT_DIVERGED


def test_module_entry_point():
    assert cli_main.main is main


def test_paragraph_helptext_joins_wrapped_docstring_lines() -> None:
    from hybridmarl.cli.helptext import paragraph_helptext

    doc = "First line of a field,\n    continued (3\n    seeds).\n\n    Second paragraph\n    - an item, with\n    --flag text"
    assert paragraph_helptext(doc) == (
        "First line of a field, continued (3 seeds).\n\nSecond paragraph\n- an item, with --flag text"
    )


def test_command_help_is_not_broken_at_source_line_ends(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # ReproduceConfig.budget's docstring wraps after "3" in the source; the help must not.
    monkeypatch.setenv("COLUMNS", "200")
    with pytest.raises(SystemExit) as exit_info:
        main(["reproduce", "--help"])
    assert exit_info.value.code == 0
    out = capsys.readouterr().out
    assert "cpu (quick presets, 3 seeds, 1,000 battles per row" in out
    # Each optional field of reproduce states its default in its docstring; tyro's own
    # "(default: None)" would contradict it.
    assert "Comma-separated combat scenarios (default: m5v5,m30v30,m18v20,m24v30)." in out
    assert "(default: None)" not in out
