"""The game's scene: the player's ship and the attackers, and their states per update.

Objects are the player (index 0, named ``player``) then the attackers
(``attacker1`` ...), each of at most :data:`MAX_POLYGONS` polygons (thesis 5.1.2).
With ambient-only light (thesis 5.1.1, the default) materials get ``k_a`` near 1 so
the objects stay bright; ``full_light`` keeps the thesis's Blinn-Phong look.

:func:`object_states` turns a :class:`~game.rules.GameState` into the transport-
neutral per-object records the renderer backends take (plain lists of floats).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from game.rules import GameState, attacker_velocities
from service.base.errors import HoloError
from service.loaders import load_mesh
from service.primitives import attacker, player
from service.render.mesh import Mesh
from service.render.scene import (
    Light,
    Material,
    MotionState,
    Scene,
    SceneObject,
    Transform,
    axis_angle_quaternion,
)

MAX_POLYGONS = 2000
#: Attackers' spin axes (cycled) and spin rate in radians per second.
SPIN_AXES = ((1, 1, 0), (0, 1, 1), (1, 0, 1), (1, -1, 0), (0, 1, -1), (1, 1, 1))
SPIN_RATE = 1.5
#: (ambient, diffuse, specular) of the materials per light mode.
LOOKS = {False: (0.95, 0.0, 0.0), True: (0.3, 0.6, 0.5)}
PLAYER_COLOUR = (0.3, 0.85, 1.0)
#: Attackers' colours (cycled), so that overlapping flat-lit attackers stay apart.
ATTACKER_COLOURS = (
    (1.0, 0.4, 0.15),
    (1.0, 0.85, 0.2),
    (0.95, 0.25, 0.55),
    (0.6, 1.0, 0.3),
    (0.75, 0.45, 1.0),
    (1.0, 0.6, 0.6),
)



class SceneError(HoloError, ValueError):
    """A game object breaks the rules (too many polygons)."""


def _check(mesh: Mesh, name: str) -> Mesh:
    if mesh.n_polygons > MAX_POLYGONS:
        raise SceneError(
            f"{name} has {mesh.n_polygons} polygons; the game allows at most {MAX_POLYGONS}"
        )
    return mesh


def attacker_mesh(path: str | Path | None = None) -> Mesh:
    """The built-in spiky attacker, or a mesh file scaled to the same size.

    Raises
    ------
    SceneError
        If the mesh has more than :data:`MAX_POLYGONS` polygons.
    service.base.errors.MeshFileError
        For a bad file.
    """
    if path is None:
        return _check(attacker(6, radius=0.08, spike=0.9), "attacker")

    mesh = _check(load_mesh(path), str(path))
    centre = (mesh.vertices.min(0) + mesh.vertices.max(0)) / 2
    extent = float(np.max(mesh.vertices.max(0) - mesh.vertices.min(0))) or 1.0
    return Mesh((mesh.vertices - centre) * (0.3 / extent), mesh.polygons, mesh.counts, "attacker")


def game_scene(n_attackers: int, full_light: bool = False, attackers: Mesh | None = None) -> Scene:
    """The scene at its start: player at the origin, attackers at the origin too.

    Positions come with the first :func:`apply_states`; only meshes and materials
    are fixed here.
    """
    ka, kd, ks = LOOKS[full_light]
    ship = _check(player(3, size=0.3), "player")
    mine = attackers if attackers is not None else attacker_mesh()
    objects = [SceneObject(ship, Material(PLAYER_COLOUR, ka, kd, ks, 5.0), name="player")]
    hues = [Material(c, ka, kd, ks, 3.0) for c in ATTACKER_COLOURS]
    objects += [
        SceneObject(mine, hues[k % len(hues)], name=f"attacker{k + 1}") for k in range(n_attackers)
    ]
    lights = [Light("directional", np.array([0.4, 0.6, 1.0]), (1.0, 1.0, 1.0), 0.9)]
    return Scene(objects=objects, lights=lights, ambient=1.0)


def _spin(k: int) -> np.ndarray:
    axis = np.array(SPIN_AXES[k % len(SPIN_AXES)], float)
    return SPIN_RATE * axis / np.linalg.norm(axis)


def object_states(state: GameState) -> list[dict]:
    """Per-object records for the renderer, player first.

    Each record: ``name``, ``position``, ``orientation`` (w, x, y, z), ``velocity``,
    ``acceleration``, ``angular_velocity`` as lists of floats.
    """
    zero = [0.0, 0.0, 0.0]
    records = [
        {
            "name": "player",
            "position": state.player.tolist(),
            "orientation": [1.0, 0, 0, 0],
            "velocity": zero,
            "acceleration": zero,
            "angular_velocity": zero,
        }
    ]
    moving = not (state.over or state.paused)
    vel = attacker_velocities(state) if moving else np.zeros_like(state.velocities)
    for k, (pos, v) in enumerate(zip(state.attackers, vel, strict=True)):
        spin = _spin(k)
        angle = float(np.linalg.norm(spin)) * (state.t + k)
        q = axis_angle_quaternion(spin, angle)
        records.append(
            {
                "name": f"attacker{k + 1}",
                "position": pos.tolist(),
                "orientation": q.tolist(),
                "velocity": v.tolist(),
                "acceleration": zero,
                "angular_velocity": (spin if moving else np.zeros(3)).tolist(),
            }
        )
    return records


def apply_states(scene: Scene, records: list[dict]) -> Scene:
    """A copy of ``scene`` with the named objects placed and moving as ``records`` say."""
    by_name = {r["name"]: r for r in records}
    objects = []
    for obj in scene.objects:
        rec = by_name.get(obj.name)
        if rec is not None:
            transform = Transform(
                np.array(rec["position"]), np.array(rec["orientation"]), obj.transform.scale
            )
            motion = MotionState(
                np.array(rec["velocity"]),
                np.array(rec["acceleration"]),
                np.array(rec["angular_velocity"]),
            )
            obj = replace(obj, transform=transform, motion=motion)
        objects.append(obj)
    return Scene(objects=objects, lights=scene.lights, ambient=scene.ambient)
