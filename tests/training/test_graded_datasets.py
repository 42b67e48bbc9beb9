"""Graded demonstration datasets (``hybridmarl.training.datasets``): a tiny set generated,
ranked by W and read back by the ordinary dataset loader."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from hybridmarl.errors import UserError
from hybridmarl.training.datasets import GradedSpec, generate_graded, load_manifest, tier_table
from hybridmarl.training.demos import load_dataset, state_at
from hybridmarl.training.task import make_task


def test_tiny_graded_set_round_trips_through_the_loader(tmp_path):
    spec = GradedSpec(
        scenario="m3v3",
        scripts=("nokdps", "attack-closest"),
        noise=0.5,
        num_observations=96,
        eval_battles=16,
        num_envs=8,
        seed=3,
    )
    lines: list[str] = []
    manifest = generate_graded(tmp_path, spec, log=lines.append)
    assert len(lines) == 4
    assert load_manifest(tmp_path) == json.loads(json.dumps(manifest))
    entries = manifest["datasets"]
    assert [e["name"] for e in sorted(entries, key=lambda e: e["name"])] == [
        "attack-closest",
        "attack-closest-eps0.5",
        "nokdps",
        "nokdps-eps0.5",
    ]
    assert [e["rank"] for e in entries] == [1, 2, 3, 4]
    assert [e["W"] for e in entries] == sorted((e["W"] for e in entries), reverse=True)
    assert "| 1 |" in tier_table(manifest)

    task = make_task(load_dataset(tmp_path / entries[0]["file"]).task_spec)
    script_of = {s: jax.jit(jax.vmap(task.demonstrator(s))) for s in ("nokdps", "attack-closest")}
    for e in entries:
        ds = load_dataset(tmp_path / e["file"], expect=task)  # the ordinary loader validates it
        assert ds.size == 96 and ds.meta["demonstrator"] == e["demonstrator"]
        assert ds.meta["graded"]["rank"] == e["rank"] and ds.meta["task"]["scenario"] == "m3v3"
        assert (
            e["eval_battles"] == 16 and (16 * e["W"]).is_integer() and 0.0 <= e["dataset_W"] <= 1.0
        )
        assert e["episodes"] == int(ds.arrays["episode"].max()) + 1
        # The recorded actions are the named script's (clean) or mostly its (noisy).
        states = state_at(ds, np.arange(ds.size), task)
        keys = jax.random.split(jax.random.key(0), ds.size)
        script = np.asarray(script_of[e["script"]](keys, states))
        choice = ds.arrays["active"] & (ds.arrays["legal"].sum(-1) >= 2)
        differ = (script != ds.arrays["actions"])[choice].mean()
        if e["noise"] == 0:
            assert differ == 0.0, e["name"]
        else:
            assert 0.0 < differ < 0.5, e[
                "name"
            ]  # a random legal action can still equal the script's


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        (GradedSpec(scripts=("attack-closest:0.1",)), "without a ':eps' suffix"),
        (GradedSpec(scripts=("no-such-script",)), "no-such-script"),
        (GradedSpec(noise=1.5), "noise must be in [0, 1]"),
        (GradedSpec(scripts=("nokdps", "NOKDPS")), "scripts repeat"),
    ],
)
def test_bad_settings_are_one_line_user_errors(tmp_path, spec, message):
    with pytest.raises(UserError, match=None) as err:
        generate_graded(tmp_path / "out", spec)
    assert message in str(err.value) and "\n" not in str(err.value)
    assert not (tmp_path / "out").exists()


def test_missing_manifest(tmp_path):
    with pytest.raises(UserError, match="no such file"):
        load_manifest(tmp_path)
