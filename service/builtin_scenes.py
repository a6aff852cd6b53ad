"""Built-in scenes by name: the dodge game, test scenes for occlusion, and the demo.

==============  =====================================================================
name            what it shows
==============  =====================================================================
``game``        the dodge game (seed 000, chapter 5): a player ship and 6 spiky
                attackers, about 8,000 polygons, within the default display width
``sphere-torus``  a sphere with a tilted torus around it (in front above, behind below)
``cyclic``      three long thin triangles overlapping in a cycle: no painter's order
                (and average-z order in particular) is right for every pair
``threaded``    a rectangle threaded through a C shape, cutting through one arm
``demo``        several objects and materials, shiny ones, at different depths
==============  =====================================================================

Names are spelled with hyphens; an underscore is taken for a hyphen
(``sphere_torus`` is ``sphere-torus``), see :func:`canonical_scene_name`.

All scenes fit the default display (width 2.0 centred on the origin, height 1.5 at
320x240) with z within about +-0.6.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

import numpy as np

from service.base.errors import SettingsError
from service.primitives import attacker, cube, lathe, outward_mesh, player, sphere, torus
from service.render.mesh import Mesh
from service.render.scene import (
    Light,
    Material,
    MotionState,
    Scene,
    SceneObject,
    Transform,
    axis_angle_quaternion,
    euler_quaternion,
)


def _key_lights(point: bool = False) -> list[Light]:
    """A directional key light from upper front right, a dim fill, optionally a point."""
    lights = [
        Light("directional", np.array([0.4, 0.6, 1.0]), (1.0, 1.0, 1.0), 0.9),
        Light("directional", np.array([-0.6, -0.2, 0.5]), (0.6, 0.7, 1.0), 0.3),
    ]
    if point:
        lights.append(Light("point", np.array([-0.6, 0.7, 1.2]), (1.0, 0.95, 0.85), 0.8))
    return lights


# (position, spin axis, velocity) of the game's six attackers
ATTACKERS = (
    ((-0.72, 0.48, -0.4), (1, 1, 0), (0.05, -0.12, 0.02)),
    ((-0.05, 0.55, 0.15), (0, 1, 1), (-0.02, -0.15, 0.0)),
    ((0.68, 0.42, -0.2), (1, 0, 1), (-0.06, -0.1, 0.03)),
    ((-0.55, -0.05, 0.38), (1, -1, 0), (0.08, -0.05, -0.02)),
    ((0.5, 0.02, 0.4), (0, 1, -1), (-0.07, -0.08, -0.03)),
    ((0.25, 0.25, -0.42), (1, 1, 1), (0.0, -0.11, 0.05)),
)


def game_scene(player_detail: int = 4, attacker_detail: int = 8) -> Scene:
    """The dodge game: the player's ship near the bottom and six attackers above it.

    Parameters
    ----------
    player_detail, attacker_detail : int
        Resolution levels; the defaults give about 8,000 polygons in all.
    """
    ship = SceneObject(
        player(player_detail, size=0.35),
        Material((0.3, 0.85, 1.0), ambient=0.3, diffuse=0.6, specular=0.6, shininess=5.0),
        Transform(position=np.array([0.0, -0.5, 0.1])),
        name="player",
    )
    mesh = attacker(attacker_detail, radius=0.09, spike=0.9)
    hue = Material((1.0, 0.35, 0.15), ambient=0.3, diffuse=0.6, specular=0.4, shininess=3.0)
    objects = [ship]
    for k, (pos, axis, vel) in enumerate(ATTACKERS):
        turn = axis_angle_quaternion(np.array(axis, float), 0.4 * k)
        spin = 1.5 * np.array(axis, float) / np.linalg.norm(axis)
        objects.append(
            SceneObject(
                mesh, hue, Transform(np.array(pos), turn),
                MotionState(velocity=np.array(vel), angular_velocity=spin),
                name=f"attacker{k + 1}",
            )
        )
    return Scene(objects=objects, lights=_key_lights())


def sphere_torus_scene() -> Scene:
    """A sphere with a torus around it, tilted so it passes in front and behind."""
    ball = SceneObject(
        sphere(0.32, 16, 32),
        Material((0.85, 0.25, 0.2), specular=0.7, shininess=5.0),
        name="sphere",
    )
    ring = SceneObject(
        torus(0.55, 0.1, 40, 12),
        Material((0.9, 0.75, 0.25), specular=0.9, shininess=5.0),
        Transform(orientation=axis_angle_quaternion(np.array([1.0, 0, 0]), np.radians(-60))),
        MotionState(angular_velocity=np.array([0.0, 0.6, 0.0])),
        name="torus",
    )
    return Scene(objects=[ball, ring], lights=_key_lights())


def _cyclic_triangle(a: np.ndarray, b: np.ndarray, width: float, z: tuple) -> Mesh:
    """A long thin triangle from apex ``a`` (depth ``z[0]``) to a base across ``b``."""
    d = (b - a) / np.linalg.norm(b - a)
    side = np.array([-d[1], d[0]]) * width / 2
    pts = [np.append(a, z[0]), np.append(b - side, z[1]), np.append(b + side, z[1])]
    return Mesh.from_polygons(np.array(pts), [[0, 1, 2]], "stick")


def cyclic_scene() -> Scene:
    """Three long thin triangles, each lying over the next: a cyclic overlap.

    Triangle i runs from corner i to past corner i+1 of an equilateral triangle,
    rising from z = -0.25 (apex) to z = +0.25 (base), so where triangles i and i+1
    cross, triangle i is in front.  The three average depths are equal, and no order
    of the three is right for every pair.
    """
    ang = np.radians(90 + 120 * np.arange(3))
    corners = 0.42 * np.stack([np.cos(ang), np.sin(ang)], 1)
    colours = ((0.9, 0.2, 0.2), (0.2, 0.85, 0.3), (0.25, 0.4, 0.95))
    objects = []
    for i in range(3):
        a, b = corners[i], corners[(i + 1) % 3]
        start, end = a - 0.35 * (b - a), b + 0.35 * (b - a)
        mesh = _cyclic_triangle(start, end, 0.22, (-0.25, 0.25))
        objects.append(
            SceneObject(mesh, Material(colours[i], specular=0.2), name=f"stick{i + 1}")
        )
    return Scene(objects=objects, lights=_key_lights())


def c_shape(inner: float = 0.3, outer: float = 0.5, depth: float = 0.12, n: int = 24) -> Mesh:
    """A thick C: a rectangular section swept from 40 to 320 degrees about the z axis.

    The opening faces +x; the C lies in the display plane, ``depth`` thick in z.
    Returns a closed mesh with outward winding (side quads plus two end caps).
    """
    ang = np.radians(np.linspace(40, 320, n + 1))
    section = [(outer, depth / 2), (inner, depth / 2), (inner, -depth / 2), (outer, -depth / 2)]
    verts = np.array([[r * np.cos(t), r * np.sin(t), z] for t in ang for r, z in section])
    polys = [
        [4 * i + j, 4 * (i + 1) + j, 4 * (i + 1) + (j + 1) % 4, 4 * i + (j + 1) % 4]
        for i in range(n)
        for j in range(4)
    ]
    polys += [[0, 1, 2, 3], [4 * n + 3, 4 * n + 2, 4 * n + 1, 4 * n]]
    return outward_mesh(verts, polys, "c-shape")


def threaded_scene() -> Scene:
    """A rectangle threaded through a C shape, interpenetrating it.

    The rectangle cuts through the C's left arm and leaves through the opening on the
    right; it is tilted (z from -0.1 to +0.1) so it pokes out of both of the C's faces.
    """
    rect = np.array([[-0.8, -0.12, -0.1], [0.8, -0.12, -0.1], [0.8, 0.12, 0.1], [-0.8, 0.12, 0.1]])
    bar = SceneObject(
        Mesh.from_polygons(rect, [[0, 1, 2, 3]], "rectangle"),
        Material((0.3, 0.6, 0.95), specular=0.3),
        name="rectangle",
    )
    ring = SceneObject(c_shape(), Material((0.95, 0.6, 0.2), specular=0.6), name="c-shape")
    return Scene(objects=[ring, bar], lights=_key_lights())


def _vase() -> Mesh:
    """A lathed vase (a surface of revolution with a flat foot and top)."""
    y = np.linspace(-0.25, 0.25, 13)
    r = 0.09 + 0.07 * np.sin((y + 0.25) / 0.5 * np.pi * 1.3)
    return lathe(np.stack([r, y], 1), 24, "vase")


DEMO_OBJECTS = (
    # (mesh builder, colour, specular, shininess, position, (yaw, pitch, roll) degrees)
    (lambda: sphere(0.26, 18, 36), (0.9, 0.15, 0.15), 0.9, 5.0, (-0.45, -0.05, 0.4), (0, 0, 0)),
    (lambda: cube(0.4), (0.2, 0.45, 0.95), 0.3, 2.0, (-0.1, 0.05, -0.1), (35, 25, 0)),
    (lambda: torus(0.3, 0.09, 36, 12), (0.95, 0.8, 0.3), 1.0, 5.0, (0.45, 0.1, -0.3),
     (20, -30, 0)),
    (lambda: attacker(5, 0.1, 0.9), (0.7, 0.3, 0.9), 0.5, 4.0, (0.55, -0.3, 0.3), (10, 10, 0)),
    (lambda: player(3, 0.4), (0.3, 0.9, 0.8), 0.7, 5.0, (0.15, -0.1, 0.45), (-20, 15, -25)),
    (_vase, (0.85, 0.85, 0.8), 0.8, 5.0, (-0.65, 0.3, -0.45), (0, 10, 0)),
)


def demo_scene() -> Scene:
    """Six objects and materials at depths from -0.55 to +0.55, overlapping on screen.

    The view zones show parallax and changes of occlusion; two directional lights and
    a point light make the shiny ones (sphere, torus, vase, ship) show highlights.
    """
    objects = []
    for build, colour, spec, shine, pos, ypr in DEMO_OBJECTS:
        mesh = build()
        q = euler_quaternion(*np.radians(ypr))
        objects.append(
            SceneObject(
                mesh, Material(colour, 0.2, 0.7, spec, shine), Transform(np.array(pos), q),
                MotionState(angular_velocity=np.array([0.0, 0.5, 0.0])), name=mesh.name,
            )
        )
    return Scene(objects=objects, lights=_key_lights(point=True), ambient=0.8)


SCENES: dict[str, Callable[[], Scene]] = {
    "game": game_scene,
    "sphere-torus": sphere_torus_scene,
    "cyclic": cyclic_scene,
    "threaded": threaded_scene,
    "demo": demo_scene,
}
"""Built-in scene builders by name."""


def canonical_scene_name(name: str) -> str:
    """The spelling ``SCENES`` uses: ``sphere_torus`` and ``Sphere-Torus`` give ``sphere-torus``.

    Raises
    ------
    SettingsError
        For an unknown name (the message lists the known ones).
    """
    key = name.strip().lower().replace("_", "-")
    if key not in SCENES:
        raise SettingsError(f"unknown scene {name!r}; known: {', '.join(SCENES)}")
    return key


def builtin_scene(name: str) -> Scene:
    """A fresh copy of the built-in scene ``name`` (see ``SCENES``; ``_`` for ``-`` too).

    Raises
    ------
    SettingsError
        For an unknown name (the message lists the known ones).
    """
    return SCENES[canonical_scene_name(name)]()


def scene_name(text: str) -> str:
    """An argparse type: a built-in scene, canonical spelling (``sphere_torus`` ok)."""
    try:
        return canonical_scene_name(text)
    except SettingsError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
