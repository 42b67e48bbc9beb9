"""Shared fixtures. Tests keep scenarios small and reuse compiled functions (module-level caches
in the engine), so the whole suite stays within a few minutes on a 2-core CPU."""

from __future__ import annotations

import os

# Compilation, not execution, dominates this suite (small scenarios, many distinct programs).
# XLA's backend optimisation level 0 cuts the suite's CPU time by about a third (measured on
# test_exact_resume: 98 -> 67 s user). It can change float rounding, so a trained toy policy's
# numbers differ from a run at the default level (m3v3 toy: R -0.156 against -0.117); the tests
# compare runs made at the same level, never against figures from the default one. It must be
# set before jax is imported; a caller's own XLA_FLAGS win.
os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0")

from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from hybridmarl.engine.state import make_rules  # noqa: E402

DATA = Path(__file__).parent / "data"
TRACE_DIR = DATA / "sparcraft_traces"


@pytest.fixture(scope="session")
def rules():
    return make_rules()
