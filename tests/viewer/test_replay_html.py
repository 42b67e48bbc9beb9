"""``hybridmarl replay --html``: the self-contained viewer page, driven in a real headless
Chromium (Debian's ``chromium``, via Playwright without its own browser download).

The page's numbers are checked against the engine's own record of the same battle
(``hybridmarl.engine.trace.record_trace``) and against a Traffic Junction episode replayed in
Python. A missing browser is a failure, not a skip: CI installs ``chromium`` (``.ci/run``).
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path

import jax
import numpy as np
import pytest

from hybridmarl.cli.main import main

LAUNCH_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
TURN = 21  # a mid-battle engine turn of m5v5 seed 0: some units dead, some wounded


def _chromium() -> str:
    path = (
        os.environ.get("HYBRIDMARL_CHROMIUM")
        or shutil.which("chromium")
        or shutil.which("chromium-browser")
    )
    if path is None:
        pytest.fail(
            "no chromium executable: install Debian's chromium (apt-get install chromium) or set HYBRIDMARL_CHROMIUM"
        )
    return path


@pytest.fixture(scope="module")
def browser_page(tmp_path_factory):
    """One headless Chromium page for the module (a fresh, empty profile)."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail("playwright is not installed (pip install -r requirements.lock)")
    profile = tmp_path_factory.mktemp("chromium-profile")
    with sync_playwright() as p:
        context = p.chromium.launch_persistent_context(
            str(profile),
            executable_path=_chromium(),
            args=LAUNCH_FLAGS,
            headless=True,
            viewport={"width": 1400, "height": 820},
        )
        page = context.new_page()
        errors: list[str] = []
        page.on("pageerror", lambda e: errors.append(str(e)))
        page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
        page.on(
            "request",
            lambda r: (
                errors.append(f"network request {r.url}")
                if not r.url.startswith(("file:", "data:"))
                else None
            ),
        )
        yield page, errors
        context.close()


def _embedded(path: Path) -> dict:
    m = re.search(
        r'<script type="application/json" id="replay-data">(.*?)</script>',
        path.read_text(encoding="utf-8"),
        re.S,
    )
    assert m, "no embedded replay data"
    return json.loads(m.group(1))


def _rows(page) -> dict[int, dict[str, str]]:
    """The side panel: data attributes of every unit row, by unit id."""
    rows = page.eval_on_selector_all(
        "tr.unit-row", "rs => rs.map(r => Object.assign({}, r.dataset))"
    )
    return {int(r["unitId"]): r for r in rows}


def test_combat_page_matches_the_engine_trace(tmp_path, capsys, browser_page):
    from hybridmarl.engine.trace import record_trace
    from hybridmarl.engine.units import TYPE_NAMES
    from hybridmarl.envs.combat import Combat

    page, errors = browser_page
    out = tmp_path / "m5v5.html"
    assert (
        main(
            [
                "replay",
                "--scenario",
                "m5v5",
                "--ours",
                "attack-closest",
                "--enemy",
                "attack-weakest",
                "--seed",
                "0",
                "--html",
                str(out),
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out.strip())
    assert summary["html"] == str(out) and summary["done"] and summary["engine_turns"] > TURN
    text = out.read_text(encoding="utf-8")
    assert "<script src" not in text and "http://" not in text.replace(
        "http://www.w3.org/2000/svg", ""
    )

    # The engine's own turn-by-turn record of the same start state (the replay's keys).
    env = Combat("m5v5", enemy="attack-weakest")
    _, k0 = jax.random.split(jax.random.key(0))
    _, state = jax.jit(env.reset)(k0)
    game = jax.device_get(state.game)
    n_units = int((np.asarray(game.uid) < 4096).sum())
    from hybridmarl.engine.state import UnitSpec

    units: list[UnitSpec] = [None] * n_units  # type: ignore[list-item]
    for p in (0, 1):
        for s in range(game.uid.shape[1]):
            uid = int(game.uid[p, s])
            if uid < n_units:
                units[uid] = UnitSpec(
                    TYPE_NAMES[int(game.utype[p, s])], p, int(game.x[p, s]), int(game.y[p, s])
                )
    trace = record_trace(units, state.game, env.rules, "attack-closest", "attack-weakest")
    assert len(trace.turns) == summary["engine_turns"]
    # Every frame of the page's data: HP by unit id after each engine turn.
    data = _embedded(out)["timeline"]
    ids = [u["id"] for u in data["units"]]
    for record, frame in zip(trace.turns, data["frames"][1:], strict=True):
        assert frame["turn"] == record.turn + 1 and frame["time"] == record.next_time
        assert dict(zip(ids, frame["hp"], strict=True)) == record.hp, f"turn {record.turn}"
    record = trace.turns[TURN - 1]  # the turn that ends at the page's frame TURN

    page.goto(out.as_uri())
    assert page.locator("#viewer").get_attribute("data-kind") == "combat"
    frame = page.evaluate(f"window.hybridmarlViewer.frameOfTurn({TURN})")
    # Drive the controls: slider to just before, then step forward, back and forward again.
    page.locator("#frame-slider").fill(str(frame - 2))
    page.locator("#btn-next").click()
    page.locator("#btn-next").click()
    page.locator("#btn-prev").click()
    page.locator("#btn-next").click()
    status = page.locator("#status")
    assert status.get_attribute("data-frame") == str(frame)
    assert status.get_attribute("data-turn") == str(TURN)
    assert status.get_attribute("data-time") == str(record.next_time)

    rows = _rows(page)
    assert sorted(rows) == list(range(n_units))
    alive = [u for u, r in rows.items() if r["alive"] == "1"]
    assert sorted(alive) == sorted(record.units)  # the trace lists the living units
    assert 0 < len(alive) < n_units
    for uid, hp in record.hp.items():
        assert int(rows[uid]["hp"]) == hp, f"unit {uid}"
        assert (
            int(page.locator(f'g.unit[data-unit-id="{uid}"]').get_attribute("data-hp") or -1) == hp
        )
    for uid, (_, _, t_move, t_attack) in record.units.items():
        assert int(rows[uid]["cooldown"]) == max(t_attack - record.next_time, 0)
        assert int(rows[uid]["moveCooldown"]) == max(t_move - record.next_time, 0)
    # One attack line per attack the engine executed this turn (an overkill became a PASS).
    attacks = sorted(
        (int(a.split()[0]), int(a.split("target=")[1].split()[0]))
        for a in record.actions
        if "ATTACK" in a and "overkill" not in a
    )
    lines = page.eval_on_selector_all(
        "line.attack", "ls => ls.map(l => [+l.dataset.from, +l.dataset.to])"
    )
    assert sorted(map(tuple, lines)) == attacks
    assert status.get_attribute("data-alive-ours") == str(
        sum(1 for u in alive if units[u].player == 0)
    )

    shot = tmp_path / "combat.png"
    page.screenshot(path=str(shot))
    from PIL import Image

    pixels = np.asarray(Image.open(shot).convert("RGB")).reshape(-1, 3)
    for colour in ((214, 48, 49), (46, 170, 70)):  # both sides' unit discs are drawn
        assert (np.abs(pixels.astype(int) - colour).sum(axis=1) < 12).sum() > 100, colour
    # Play runs the timeline forward by itself.
    page.locator("#btn-first").click()
    page.locator("#btn-play").click()
    for _ in range(50):  # the page's CSP forbids eval, so poll rather than wait_for_function
        if page.evaluate("window.hybridmarlViewer.current()") >= 3:
            break
        page.wait_for_timeout(100)
    assert page.evaluate("window.hybridmarlViewer.current()") >= 3
    page.locator("#btn-play").click()
    assert page.locator("#btn-play").get_attribute("data-playing") == "0"
    assert errors == []


def test_traffic_junction_page_matches_the_episode(tmp_path, capsys, browser_page):
    from hybridmarl.envs.traffic_junction import TrafficJunction
    from hybridmarl.envs.traffic_junction.demonstrators import DEMONSTRATORS
    from hybridmarl.envs.traffic_junction.env import ROUTE_NAMES, car_cells

    page, errors = browser_page
    out = tmp_path / "tj.html"
    seed, at = 2, 25
    assert (
        main(
            [
                "replay",
                "--env",
                "traffic_junction",
                "--ours",
                "always-gas",
                "--seed",
                str(seed),
                "--html",
                str(out),
            ]
        )
        == 0
    )
    summary = json.loads(capsys.readouterr().out.strip())
    assert summary["steps"] == 40 and summary["collisions"] > 0  # always-gas collides

    # The same episode in Python (the replay's keys), up to step ``at``.
    env = TrafficJunction()
    params = env.default_params.replace(p_arrive=0.2)
    policy = DEMONSTRATORS["always-gas"]
    key = jax.random.key(seed)
    key, k0 = jax.random.split(key)
    _, state = env.reset(k0, params)
    collisions_at = 0
    step, act = jax.jit(env.step), jax.jit(policy)
    for _ in range(at):
        key, k_act, k_env = jax.random.split(key, 3)
        _, state, _, _, info = step(k_env, state, act(k_act, state), params)
        collisions_at = int(info["collisions"])

    page.goto(out.as_uri())
    assert page.locator("#viewer").get_attribute("data-kind") == "traffic_junction"
    page.locator("#frame-slider").fill(str(at))
    assert page.locator("#status").get_attribute("data-t") == str(at)
    rows = _rows(page)
    active = np.asarray(state.active)
    cells = np.asarray(car_cells(state))
    assert [rows[i]["active"] == "1" for i in range(len(active))] == active.tolist()
    cars = page.eval_on_selector_all(
        "g.car",
        "cs => cs.map(c => [+c.dataset.carId, +c.dataset.row, +c.dataset.col, +c.dataset.route])",
    )
    expected = sorted(
        [i, int(cells[i, 0]), int(cells[i, 1]), int(state.route[i])] for i in np.flatnonzero(active)
    )
    assert sorted(cars) == expected
    assert {rows[int(i)]["action"] for i in np.flatnonzero(active)} <= {"gas", ""}
    shown = page.eval_on_selector_all("tr.unit-row", "rs => rs.map(r => r.children[1].textContent)")
    assert [shown[i] for i in np.flatnonzero(active)] == [
        ROUTE_NAMES[int(state.route[i])] for i in np.flatnonzero(active)
    ]
    # Collision markers: a cell per collision site; every colliding car is flagged.
    collided = sum(r["collided"] == "1" for r in rows.values())
    assert collided == collisions_at
    assert (page.locator("rect.collision").count() > 0) == (collisions_at > 0)
    page.screenshot(path=str(tmp_path / "tj.png"))
    assert (tmp_path / "tj.png").stat().st_size > 5000
    assert errors == []


def test_html_page_embeds_policy_probabilities(tmp_path):
    """With an actor, each acting allied unit's top action probabilities and the chosen action
    are recorded at every decision point (here a uniform actor over the legal actions)."""
    import jax.numpy as jnp

    from hybridmarl.envs.combat import Combat
    from hybridmarl.viewer import record_combat_timeline, write_page

    env = Combat("m3v3", enemy="attack-weakest")

    def uniform(state):
        legal = env.get_avail_actions(state).astype(jnp.float32)
        return legal / legal.sum(axis=-1, keepdims=True)

    def alg1(
        key, state
    ):  # a stand-in for Alg. 1: moves agent 0 from its first legal action to its last
        legal = np.asarray(env.get_avail_actions(state))
        start = legal.argmax(axis=1)
        actions = start.copy()
        actions[0] = legal.shape[1] - 1 - legal[0, ::-1].argmax()
        return {
            "actions": actions,
            "start": start,
            "q_start": np.float32(0.25),
            "q_final": np.float32(0.5),
        }

    timeline, last = record_combat_timeline(
        env,
        env.script_policy("attack-closest"),
        seed=1,
        max_steps=2,
        probs_fn=uniform,
        alg1_fn=alg1,
    )
    decisions = [f for f in timeline["frames"] if f["decision"]]
    assert len(decisions) == last["steps"] == 2
    first = decisions[0]["policy"]["agents"]
    assert len(first) == 3  # every unit acts at the opening turn
    for agent in first:
        probs = [p for _, p in agent["probs"]]
        assert probs == sorted(probs, reverse=True) and all(abs(p - probs[0]) < 1e-6 for p in probs)
        assert re.fullmatch(r"noop|move (left|right|down|up)|attack \d+", agent["chosen"])
    summary = decisions[0]["policy"]["alg1"]
    assert summary == {
        "q_start": 0.25,
        "q_final": 0.5,
        "changed": int(first[0]["alg1"] != first[0]["alg1_start"]),
    }
    assert first[0]["alg1"] != first[0]["alg1_start"] and all(
        a["alg1"] == a["alg1_start"] for a in first[1:]
    )
    path = write_page(tmp_path / "p.html", timeline, title="m3v3 \u00e9t\u00e9 </script><b>", fps=4)
    doc = _embedded(Path(path))
    assert doc["timeline"]["frames"][1]["policy"] == decisions[0]["policy"]
    assert (
        doc["meta"]["title"] == "m3v3 \u00e9t\u00e9 </script><b>"
    )  # escaped inside the page, intact in the data
    assert "<title>m3v3 \u00e9t\u00e9 &lt;/script&gt;&lt;b&gt;</title>" in Path(path).read_text(
        encoding="utf-8"
    )


def test_html_option_errors(tmp_path, capsys):
    bad = tmp_path / "r.txt"
    assert main(["replay", "--html", str(bad)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--html" in err and ".html" in err
    assert not bad.exists() and list(tmp_path.iterdir()) == []
    assert (
        main(["replay", "--run-dir", str(tmp_path / "missing"), "--html", str(tmp_path / "r.html")])
        == 2
    )
    assert list(tmp_path.iterdir()) == []
