"""The ``hybridmarl`` command line: a thin layer over the Python API."""

from hybridmarl.cli.main import main

__all__ = ["main"]
