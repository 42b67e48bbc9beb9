"""Shared fixtures. Tests keep scenarios small and reuse compiled functions (module-level caches
in the engine), so the whole suite stays within a few minutes on a 2-core CPU."""

from __future__ import annotations

from pathlib import Path

import pytest

from hybridmarl.engine.state import make_rules

DATA = Path(__file__).parent / "data"
TRACE_DIR = DATA / "sparcraft_traces"


@pytest.fixture(scope="session")
def rules():
    return make_rules()
