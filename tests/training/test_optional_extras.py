"""Training on a core install: without the 'tensorboard' and 'plots' extras a run keeps its
CSV logs and skips TensorBoard and the curve, with a line saying which extra would add them."""

from __future__ import annotations

import sys

from hybridmarl.training.logger import RunLogger
from hybridmarl.training.plots import training_curve


def test_without_tensorboardx_the_logger_skips_tensorboard(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # makes the import fail
    log = RunLogger(tmp_path, tensorboard=True)
    assert log.tb is None
    log.train.write([{"episodes": 1, "x": 0.5}])
    log.close()
    assert (tmp_path / "train.csv").is_file() and not (tmp_path / "tb").exists()
    assert "hybridmarl[tensorboard]" in capsys.readouterr().out


def test_without_matplotlib_no_curve(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "matplotlib", None)
    assert training_curve([0.1, 0.2, 0.3], tmp_path / "curve.png") is None
    assert not (tmp_path / "curve.png").exists()
    assert "hybridmarl[plots]" in capsys.readouterr().out
