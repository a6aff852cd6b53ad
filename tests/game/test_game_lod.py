"""``holo-game --lod``: the game's renderer draws each object at its level of detail."""

from __future__ import annotations

import pytest
from testkit import wait_until

from game import cli
from game.backends import LocalRenderer
from game.rules import new_game
from game.scene import object_states


def test_lod_on_reaches_the_local_renderer(setup_from_args, tmp_path):
    game, backend = setup_from_args("--lod-error", "0.75")
    assert isinstance(backend, LocalRenderer)
    assert backend.render_settings.lod is not None
    assert backend.render_settings.lod.error_px == 0.75
    backend.update(object_states(new_game(game)))
    # frame() returns at each refresh (60 Hz), so wait on a deadline, not a count: the
    # first render may compile kernels (after a change) for many seconds
    if not wait_until(lambda: getattr(backend.frame(timeout_s=0.5), "render_id", -1) >= 0,
                      180):
        pytest.fail("the local renderer showed no render")
    levels = backend._renderer.lod.previous  # the render thread chose a level per object
    assert levels is not None and levels.size == len(backend._scene.objects)
    # the attackers' chain is built off the render thread (a child process) and cached
    if not wait_until(lambda: any((tmp_path / "lod").glob("*.json")), 180):
        pytest.fail("the attackers' level-of-detail chain was never cached")
    assert backend._renderer.lod.background


def test_lod_off_by_default_and_bad_budget_refused(setup_from_args, capsys):
    _, backend = setup_from_args()
    assert backend.render_settings.lod is None
    with pytest.raises(SystemExit) as stop:
        cli.build_parser().parse_args(["--lod-error", "0"])
    assert stop.value.code == 2
    assert "--lod-error" in capsys.readouterr().err


def test_budget_ms_reaches_the_local_renderer_and_its_cost_model(setup_from_args):
    game, backend = setup_from_args("--budget-ms", "40")
    lod = backend.render_settings.lod
    assert lod is not None and lod.budget_ms == 40 and lod.error_px == 0.5  # alone: on
    states = object_states(new_game(game))
    # each update is a render, measured for the cost model (its first, cold, left out)
    if not wait_until(lambda: backend.update(states) or backend._renderer.lod.cost.samples,
                      180, step_s=0.05):
        pytest.fail("no render was measured")
    assert backend._renderer.lod.cost.ready


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
