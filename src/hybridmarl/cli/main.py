"""The ``hybridmarl`` command: one table of subcommands, and the one place that turns errors into
exit codes.

:data:`COMMANDS` maps each subcommand to its one-line help and its handler; the top-level help
is generated from it. A handler takes the remaining arguments, parses them itself (tyro), and
returns an exit code (``None`` means 0). Bad input raises :class:`~hybridmarl.errors.UserError`
(``hybridmarl: error: <message>`` on stderr, exit code 2; no output file is left); a training
run whose losses became NaN/inf raises :class:`~hybridmarl.errors.TrainingDiverged`
(``hybridmarl: training stopped: <message>``, exit code 3). Ctrl-C exits with code 130 (a
training run stops at the end of its chunk and saves a checkpoint first). A missing optional package becomes a
:class:`~hybridmarl.errors.UserError` naming the extra to install
(:func:`hybridmarl.cli.extras.optional_extras`).

Handlers are imported only when their command runs, so ``hybridmarl --help`` does not load JAX.
"""

from __future__ import annotations

import importlib
import os
import sys
from collections.abc import Callable
from dataclasses import dataclass

from hybridmarl.errors import (
    EXIT_BAD_INPUT,
    EXIT_DIVERGED,
    EXIT_INTERRUPTED,
    Interrupted,
    TrainingDiverged,
    UserError,
)

#: A command handler: the arguments after the command name -> exit code (None: 0).
Handler = Callable[[list[str]], "int | None"]


@dataclass(frozen=True)
class Command:
    """One subcommand: its one-line help and where its handler lives (``module:function``,
    imported when the command runs)."""

    help: str
    target: str

    def handler(self) -> Handler:
        module, _, name = self.target.partition(":")
        return getattr(importlib.import_module(module), name)


#: Every subcommand of ``hybridmarl``, in the order the help lists them.
COMMANDS: dict[str, Command] = {
    "quickstart": Command(
        "train the hybrid method on m5v5, compare with its demonstrator, curve + replay",
        "hybridmarl.cli.quickstart:quickstart_command",
    ),
    "battle": Command(
        "play a scripted battle series and print a win-rate table",
        "hybridmarl.cli.engine:battle_command",
    ),
    "trace": Command(
        "print a turn-by-turn trace of one battle",
        "hybridmarl.cli.engine:trace_command",
    ),
    "replay": Command(
        "record a battle or a Traffic Junction episode as a GIF",
        "hybridmarl.cli.replay:replay_command",
    ),
    "train": Command(
        "train a learner (--algo hybrid|bc|dqfd|ogtl, --preset quick|paper|...)",
        "hybridmarl.cli.learn:train_command",
    ),
    "eval": Command(
        "evaluate a trained policy or a script (W, R with 95% CIs)",
        "hybridmarl.cli.learn:eval_command",
    ),
    "demos": Command(
        "record / inspect demonstration datasets (collect, info)",
        "hybridmarl.cli.learn:demos_command",
    ),
    "reproduce": Command(
        "the paper's Table 1, Table 2 and Fig. 3 as a resumable grid of runs (Ray or local)",
        "hybridmarl.cli.reproduce:reproduce_command",
    ),
}


def usage() -> str:
    """The top-level help, generated from :data:`COMMANDS`."""
    width = max(len(name) for name in COMMANDS) + 2
    lines = [f"usage: hybridmarl {{{','.join(COMMANDS)}}} ...", ""]
    lines += [f"  {name:<{width}}{cmd.help}" for name, cmd in COMMANDS.items()]
    lines += ["", "Run 'hybridmarl COMMAND --help' for the options of a command."]
    return "\n".join(lines)


def _configure_host_devices() -> None:
    """Expose the CPU cores to XLA as host devices before JAX is imported, so batched games can
    be split across them (one jitted program uses about one core). Respects a user's XLA_FLAGS."""
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_force_host_platform_device_count" not in flags and "jax" not in sys.modules:
        n = os.cpu_count() or 1
        if n > 1:
            os.environ["XLA_FLAGS"] = (
                flags + f" --xla_force_host_platform_device_count={min(n, 8)}"
            ).strip()


def _one_line(err: BaseException) -> str:
    return " ".join(str(err).split("\n")).strip()


def main(argv: list[str] | None = None) -> int:
    """Run ``hybridmarl`` with ``argv`` (default ``sys.argv[1:]``) and return the exit code."""
    args = sys.argv[1:] if argv is None else list(argv)
    if not args or args[0] in ("-h", "--help"):
        print(usage())
        return 0 if args else EXIT_BAD_INPUT
    name, rest = args[0], args[1:]
    _configure_host_devices()
    from hybridmarl.cli.extras import optional_extras
    from hybridmarl.cli.helptext import use_paragraph_helptext

    use_paragraph_helptext()

    try:
        command = COMMANDS.get(name)
        if command is None:
            raise UserError(f"unknown command {name!r} (commands: {', '.join(COMMANDS)})")
        with optional_extras():
            rc = command.handler()(rest)
    except UserError as e:
        print(f"hybridmarl: error: {_one_line(e)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except TrainingDiverged as e:
        print(f"hybridmarl: training stopped: {_one_line(e)}", file=sys.stderr)
        return EXIT_DIVERGED
    except Interrupted as e:
        print(f"hybridmarl: {_one_line(e)}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except KeyboardInterrupt:
        print("hybridmarl: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    return 0 if rc is None else int(rc)


if __name__ == "__main__":
    sys.exit(main())
