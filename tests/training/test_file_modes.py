"""Files and directories hybridmarl writes get the user's umask, like any other tool's (the
atomic writers start from mkstemp/mkdtemp, which make them private)."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from hybridmarl.io import write_json_atomic
from hybridmarl.training.checkpoint import save_checkpoint


@pytest.fixture
def umask_022():
    old = os.umask(0o022)
    yield
    os.umask(old)


def _mode(path) -> int:
    return stat.S_IMODE(os.stat(path).st_mode)


def test_json_and_checkpoint_modes_follow_umask(tmp_path, umask_022):
    write_json_atomic(tmp_path / "eval.json", {"W": 1.0})
    assert _mode(tmp_path / "eval.json") == 0o644
    save_checkpoint(tmp_path, 8, {"actor.w": np.zeros(3, np.float32)}, {})
    (ckpt,) = [p for p in (tmp_path / "checkpoints").iterdir() if not p.name.startswith(".")]
    assert _mode(ckpt) == 0o755
    assert _mode(ckpt / "arrays.safetensors") == 0o644 and _mode(ckpt / "meta.json") == 0o644


def test_dataset_mode_follows_umask(tmp_path, umask_022):
    from hybridmarl.training.demos import Dataset, save_dataset

    save_dataset(
        Dataset(arrays={"obs": np.zeros((2, 3), np.float32)}, meta={"format": "test"}),
        tmp_path / "d.safetensors",
    )
    assert _mode(tmp_path / "d.safetensors") == 0o644
