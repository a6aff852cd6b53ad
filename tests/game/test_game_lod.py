"""``holo-game --lod``: the game's renderer draws each object at its level of detail."""

from __future__ import annotations

import pytest
from testkit import wait_until

from game.backends import LocalRenderer
from game.commands import holo_game as cli
from game.rules import new_game
from game.scene import object_states


def test_lod_on_reaches_the_local_renderer(setup_from_args, tmp_path):
    game, backend = setup_from_args("--lod-error", "0.75")
    assert isinstance(backend, LocalRenderer)
    assert backend.settings.render.lod is not None
    assert backend.settings.render.lod.error_px == 0.75
    backend.update(object_states(new_game(game)))
    # frame() returns at each refresh (60 Hz), so wait on a deadline, not a count: the
    # first render may compile kernels (after a change) for many seconds
    if not wait_until(lambda: getattr(backend.frame(timeout_s=0.5), "render_id", -1) >= 0,
                      180):
        pytest.fail("the local renderer showed no render")
    lod = backend.engine.scheduler.local().lod
    levels = lod.previous  # the render thread chose a level per object
    assert levels is not None and levels.size == len(backend._scene.objects)
    # the attackers' chain is built off the render thread (a child process) and cached
    if not wait_until(lambda: any((tmp_path / "lod").glob("*.json")), 180):
        pytest.fail("the attackers' level-of-detail chain was never cached")
    assert lod.background


def test_lod_off_by_default_and_bad_budget_refused(setup_from_args, capsys):
    _, backend = setup_from_args()
    assert backend.settings.render.lod is None
    with pytest.raises(SystemExit) as stop:
        cli.build_parser().parse_args(["--lod-error", "0"])
    assert stop.value.code == 2
    assert "--lod-error" in capsys.readouterr().err


def test_budget_ms_reaches_the_local_renderer_and_its_cost_model(setup_from_args):
    game, backend = setup_from_args("--budget-ms", "40")
    lod = backend.settings.render.lod
    assert lod is not None and lod.budget_ms == 40 and lod.error_px == 0.5  # alone: on
    states = object_states(new_game(game))
    chosen = backend.engine.scheduler.local().lod  # its cost model is made for the display
    # each render is measured for the cost model (its first, cold, left out)
    if not wait_until(lambda: backend.update(states) or chosen.cost.samples, 180, step_s=0.05):
        pytest.fail("no render was measured")
    assert chosen.cost.ready


def test_budget_ms_reaches_the_service(service_factory, setup_from_args, tmp_path,
                                       monkeypatch):
    from testkit import wait_until

    from game.backends import ServiceBackend
    from service.net.client import ServiceClient

    monkeypatch.setenv("HOLO_LOD_CACHE", str(tmp_path / "svc-lod"))
    svc = service_factory("--scene", "game", "--zones", "3", "--size", "32x24",
                          "--workers", "0", "--refresh", "30")
    game, backend = setup_from_args("--service", svc.control, "--budget-ms", "30",
                                    "--lod-error", "0.75", local=False)
    assert isinstance(backend, ServiceBackend)
    # its first connection may time out on a loaded machine; frame() retries it
    assert wait_until(lambda: backend.connected or backend.frame(timeout_s=0.1) is not None,
                      60)
    with ServiceClient(svc.control, timeout_s=30) as c:
        lod = c.render_once()[0]["stats"]["lod"]
    assert lod["budget_ms"] == 30 and lod["error_px"] == 0.75


def _tear_ship_cache(folder):
    """A torn cache file of the ship's chain (arrays without their header): a note."""
    from game.scene import game_scene
    from service.lod.chain import mesh_key
    from service.lod.settings import LodSettings

    key = mesh_key(game_scene(1).objects[0].mesh, LodSettings().recipe)
    folder.mkdir(parents=True, exist_ok=True)
    (folder / f"{key}.npz").write_bytes(b"PK torn")
    return key


def test_the_service_lod_notes_reach_the_hud_and_the_log_once(
        service_factory, setup_from_args, tmp_path, monkeypatch, capsys):
    from game.backends import ServiceBackend
    from game.client_loop import GameClient, LoopSettings
    from game.commands.holo_game import Progress
    from game.display import GameWindow

    key = _tear_ship_cache(tmp_path / "lod")  # the folder both processes use
    svc = service_factory("--zones", "3", "--size", "32x24", "--workers", "0",
                          "--refresh", "30")
    game, backend = setup_from_args("--service", svc.control, "--lod-error", "0.5",
                                    local=False)
    assert isinstance(backend, ServiceBackend)
    client = GameClient(backend, GameWindow((320, 200)), LoopSettings(game))
    progress = Progress(None, 0.0)

    def noted() -> bool:
        client.tick()
        progress(client)
        return bool(client.lod_notes)

    if not wait_until(noted, 180, step_s=0.05):
        pytest.fail("no level-of-detail note reached the game")
    note = client.lod_notes[0][1]
    assert key in note and "rebuilding" in note
    now = client.clock()
    lines = [ln for ln in client.hud(now).lines if ln.startswith("level of detail: ")]
    assert len(lines) == 1 and len(lines[0]) == 90 and "..." in lines[0]
    assert lines[0].endswith("json is missing); rebuilding it")  # what failed, what is done
    backend._lod_next = 0.0  # ask the service again at once: the same note is not new
    for _ in range(3):
        client.tick()
        progress(client)
        backend._lod_next = 0.0
    assert [n for _, n in client.lod_notes] == [note]  # once, however often reported
    assert client.stats(1.0)["lod_notes"] == [note]
    err = capsys.readouterr().err
    assert err.count(f"holo-game: level of detail: {note}\n") == 1
    assert not [ln for ln in client.hud(now + 11.0).lines if ln.startswith("level of")]


def test_the_local_renderer_hands_each_lod_note_once(setup_from_args, tmp_path):
    key = _tear_ship_cache(tmp_path / "lod")
    game, backend = setup_from_args("--lod-error", "0.5")
    states = object_states(new_game(game))
    notes: list[str] = []

    def noted() -> bool:
        backend.update(states)
        notes.extend(backend.lod_notes())
        return bool(notes)

    if not wait_until(noted, 180, step_s=0.05):
        pytest.fail("the local renderer handed no level-of-detail note")
    for _ in range(5):  # later renders report it again: not handed again
        backend.update(states)
        backend.frame(timeout_s=0.1)
        notes.extend(backend.lod_notes())
    assert len(notes) == 1 and key in notes[0] and "rebuilding" in notes[0]


def test_closing_the_local_renderer_ends_a_chain_build_at_once(setup_from_args, tmp_path):
    """A build still running at close is stopped, not left to finish (seconds, longer
    on a loaded machine) with its thread and child process behind the closed game."""
    import contextlib
    import os
    import threading

    from testkit import held_lock, wait_for

    from game.scene import game_scene
    from service.lod.chain import mesh_key
    from service.lod.settings import LodSettings

    keys = {mesh_key(o.mesh, LodSettings().recipe) for o in game_scene(1).objects}
    with contextlib.ExitStack() as held:
        for key in keys:  # every chain's build waits for its lock: one is running at close
            held.enter_context(held_lock(tmp_path / "lod", key))
        game, backend = setup_from_args("--lod-error", "0.5")
        backend.update(object_states(new_game(game)))
        lod = backend.engine.scheduler.local().lod
        wait_for(lambda: lod.builds is not None and lod.builds.child_pid is not None, 180,
                 "a chain build running")
        pid = lod.builds.child_pid
        backend.close()
        assert not any(t.name == "lod-chains" for t in threading.enumerate())
        assert not os.path.exists(f"/proc/{pid}")  # ended and reaped
