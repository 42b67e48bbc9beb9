"""BC's train.csv: its agreement with the demonstrator (the column DQfD and OGTL log per chunk)
is written once, on the last row, and equals the clone's accuracy on the demonstrations."""

from __future__ import annotations

import csv
import math

from hybridmarl.cli.main import main


def test_bc_writes_its_agreement_on_the_last_row_m3v3(tmp_path, capsys):
    run = tmp_path / "bc"
    argv = [
        "train",
        "--algo",
        "bc",
        "--preset",
        "toy",
        "--no-progress",
        "--scenario",
        "m3v3",
        "--demonstrator",
        "attack-closest",
        "--enemy",
        "attack-weakest",
        "--run-dir",
        str(run),
    ]
    assert main(argv) == 0
    out = capsys.readouterr().out
    accuracy = float(out.split("accuracy ")[1].split()[0])
    with open(run / "train.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows[-1]["step"] == "20"  # the toy preset's last step
    assert 0.0 <= float(rows[-1]["agreement"]) <= 1.0
    assert (
        abs(float(rows[-1]["agreement"]) - accuracy) < 5e-4
    )  # the printed accuracy has 3 decimals
    assert all(math.isnan(float(r["agreement"])) for r in rows[:-1])
