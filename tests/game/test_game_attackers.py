"""``--attackers FILE``: the 2,000-polygon limit per game object (issue 6, thesis 5.1.2)."""

from __future__ import annotations

import json
from pathlib import Path

import pygame

from game.commands import holo_game as cli
from game.scene import MAX_POLYGONS


def write_grid_obj(path: Path, n: int) -> int:
    """An n x n grid of quads, each split into two triangles; returns the polygon count."""
    lines = [f"v {i / n} {j / n} {0.1 * ((i + j) % 2)}" for j in range(n + 1) for i in range(n + 1)]
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i + 1  # OBJ indices start at 1
            b, c, d = a + 1, a + n + 2, a + n + 1
            lines += [f"f {a} {b} {c}", f"f {a} {c} {d}"]
    path.write_text("\n".join(lines) + "\n")
    return 2 * n * n


def _argv(tmp_path: Path, attackers: Path, *extra: str) -> list[str]:
    return [
        "--local",
        "--headless",
        "--size",
        "80x60",
        "--attackers",
        str(attackers),
        "--highscores",
        str(tmp_path / "hs.json"),
        *extra,
    ]


def test_an_attacker_file_over_the_limit_is_refused_naming_the_file(tmp_path, capsys):
    big = tmp_path / "too-many.obj"
    count = write_grid_obj(big, 32)
    assert count > MAX_POLYGONS

    rc = cli.main(_argv(tmp_path, big, "--seconds", "1"))

    assert rc == 2
    err = capsys.readouterr().err
    assert err.startswith("holo-game: ") and str(big) in err
    assert f"{count} polygons" in err and str(MAX_POLYGONS) in err


def test_an_attacker_file_under_the_limit_is_used_for_every_attacker(tmp_path, capsys):
    small = tmp_path / "small.obj"
    count = write_grid_obj(small, 4)
    assert count < MAX_POLYGONS

    parser = cli.build_parser()
    args = parser.parse_args(_argv(tmp_path, small))
    cli.check_args(parser, args)
    _, backend, *_ = cli._setup(args)
    try:
        attackers = [o for o in backend._scene.objects if o.name.startswith("attacker")]
        assert attackers
        assert all(o.mesh.n_polygons == count for o in attackers)
        player = backend._scene.objects[0]
        assert player.name == "player" and player.mesh.n_polygons != count
    finally:
        backend.close()
        pygame.quit()

    # and the game runs with it
    assert cli.main(_argv(tmp_path, small, "--bot", "--seconds", "0.5")) == 0
    stats = json.loads(capsys.readouterr().out.splitlines()[-1])
    assert stats["refreshes"] > 0
