"""Game over (thesis 5.2.2): three beeps, "a truly spectacular display", the score.

The sequence is a timetable (:data:`TIMETABLE`) played by :class:`GameOverSequence`:
three beeps a quarter second apart, then the explosion, then the score screen.

The beep is a short sine tone made with numpy and played through
``pygame.sndarray``; with ``SDL_AUDIODRIVER=dummy`` (headless) or no mixer the
:class:`Beeper` is muted and only counts.

The display: the player's mesh shatters into pieces flung outward with velocities,
a downward acceleration and spins (:func:`explosion_scene`), loaded as a scene of its
own; the renders follow the pieces (the service's and the local engine alike).
:func:`burst_records` is the same for whole objects.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pygame

from service.render.mesh import Mesh
from service.render.scene import MotionState, Scene, Transform

#: seconds after game over -> what happens.
TIMETABLE: tuple[tuple[float, str], ...] = (
    (0.0, "beep"),
    (0.25, "beep"),
    (0.5, "beep"),
    (0.8, "explode"),
    (3.3, "score"),
)
#: Seconds the score screen stays before attract mode starts a new game.
SCORE_SECONDS = 4.0
BEEP_HZ = 880.0
BEEP_SECONDS = 0.12


def tone(
    hz: float = BEEP_HZ, seconds: float = BEEP_SECONDS, rate: int = 22050, channels: int = 2
) -> np.ndarray:
    """A sine tone with 5 ms fades, int16, shape (n, channels) (or (n,) for 1 channel)."""
    n = int(rate * seconds)
    t = np.arange(n) / rate
    ramp = np.minimum(1.0, np.minimum(t, seconds - t) / 0.005)
    wave = (0.4 * 32767 * np.sin(2 * np.pi * hz * t) * ramp).astype(np.int16)
    return wave if channels == 1 else np.repeat(wave[:, None], channels, axis=1)


class Beeper:
    """Plays the beep, or only counts it when muted (headless, no audio device).

    Parameters
    ----------
    muted : bool
        Never touch the audio device.
    """

    def __init__(self, muted: bool) -> None:
        self.count = 0
        self._sound = None if muted else _make_sound()

    @property
    def muted(self) -> bool:
        """True when beeps are only counted."""
        return self._sound is None

    def beep(self) -> None:
        """One beep."""
        self.count += 1
        if self._sound is not None:
            self._sound.play()


def _make_sound() -> pygame.mixer.Sound | None:
    """The beep as a mixer sound, or None where there is no usable mixer."""
    try:
        if not pygame.mixer.get_init():
            pygame.mixer.init()
        _, _, channels = pygame.mixer.get_init()
        return pygame.sndarray.make_sound(tone(channels=channels))
    except (pygame.error, ValueError, TypeError):
        return None


class GameOverSequence:
    """Steps through :data:`TIMETABLE` from the moment the game ended.

    Parameters
    ----------
    start : float
        Clock reading (seconds) at game over.
    """

    def __init__(self, start: float) -> None:
        self.start = start
        self._next = 0
        self.phase = "beeps"

    def due(self, now: float) -> list[str]:
        """Timetable entries that have come due since the last call, in order."""
        out = []
        while self._next < len(TIMETABLE) and now - self.start >= TIMETABLE[self._next][0]:
            out.append(TIMETABLE[self._next][1])
            self._next += 1
        if out and out[-1] in ("explode", "score"):
            self.phase = out[-1]
        return out

    def finished(self, now: float) -> bool:
        """True once the score screen has been up for :data:`SCORE_SECONDS`."""
        return now - self.start >= TIMETABLE[-1][0] + SCORE_SECONDS


def burst_records(records: list[dict], seed: int = 0, speed: float = 0.35) -> list[dict]:
    """Object records flung outward from the player's origin (object-level burst).

    Every object gets a velocity away from the player (the player itself a random
    one), a downward acceleration and a fast spin.
    """
    rng = np.random.default_rng(seed)
    centre = np.array(records[0]["position"], float)
    out = []
    for rec in records:
        away = np.array(rec["position"], float) - centre + rng.normal(0, 0.05, 3)
        away /= max(float(np.linalg.norm(away)), 1e-6)
        out.append(
            {
                **rec,
                "velocity": (away * speed).tolist(),
                "acceleration": [0.0, -0.8, 0.0],
                "angular_velocity": rng.normal(0, 6.0, 3).tolist(),
            }
        )
    return out


def shatter(mesh: Mesh, pieces: int = 16, seed: int = 0) -> list[tuple[Mesh, np.ndarray]]:
    """Split a mesh into pieces by the direction of each polygon from the centre.

    Returns
    -------
    list of (Mesh, ndarray)
        Each non-empty piece (the mesh's vertices, a subset of its polygons) and
        its unit outward direction.
    """
    rng = np.random.default_rng(seed)
    dirs = rng.normal(size=(pieces, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    centre = mesh.vertices.mean(axis=0)
    safe = np.where(mesh.polygons >= 0, mesh.polygons, 0)
    mask = (mesh.polygons >= 0)[..., None]
    centroids = (mesh.vertices[safe] * mask).sum(1) / mesh.counts[:, None] - centre
    group = np.argmax(centroids @ dirs.T, axis=1)
    out = []
    for k in range(pieces):
        sel = group == k
        if np.any(sel):
            piece = Mesh(mesh.vertices, mesh.polygons[sel], mesh.counts[sel], f"shard{k}")
            out.append((piece, dirs[k]))
    return out


def explosion_scene(
    scene: Scene,
    records: list[dict],
    seed: int = 0,
    speed: float = 0.5,
    gravity: float = 0.5,
    pieces: int = 16,
) -> Scene:
    """The scene at game over with the player (object 0) shattered and flying apart.

    The attackers keep their places and stop; each piece of the player starts at the
    player's origin with an outward velocity, ``gravity`` downward and a spin.
    """
    rng = np.random.default_rng(seed)
    ship = scene.objects[0]
    origin = Transform(np.array(records[0]["position"], float), scale=ship.transform.scale)
    shards = []
    for mesh, direction in shatter(ship.mesh, pieces, seed):
        motion = MotionState(
            velocity=direction * speed * rng.uniform(0.5, 1.5),
            acceleration=np.array([0.0, -gravity, 0.0]),
            angular_velocity=rng.normal(0.0, 4.0, 3),
        )
        shards.append(replace(ship, mesh=mesh, transform=origin, motion=motion, name=mesh.name))
    by_name = {r["name"]: r for r in records}
    still = [
        replace(
            o,
            transform=Transform(
                np.array(by_name[o.name]["position"]), np.array(by_name[o.name]["orientation"])
            ),
        )
        for o in scene.objects[1:]
        if o.name in by_name
    ]
    return Scene([*shards, *still], scene.lights, scene.ambient)
