"""The ``hybridmarl`` command line: a thin layer over the Python API.

:mod:`hybridmarl.cli.main` holds the table of subcommands and maps errors to exit codes (its
``main(argv)`` is the ``hybridmarl`` entry point); :mod:`~hybridmarl.cli.engine` (battle, trace),
:mod:`~hybridmarl.cli.learn` (train, eval, demos), :mod:`~hybridmarl.cli.quickstart` and
:mod:`~hybridmarl.cli.replay` hold the commands. :mod:`~hybridmarl.cli.helptext` turns the config
dataclasses' docstrings into their help text.
"""
