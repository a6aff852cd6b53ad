"""Advance a scene in time by its objects' motion, and look at it from a moving viewer.

Each :class:`~service.render.scene.SceneObject` carries a :class:`~service.render.scene.MotionState`
(world units and radians, per second).  At a time ``dt`` after the scene's state:

* position ``p + v dt + a dt^2 / 2``;
* orientation ``exp(phi / 2) * q`` with the rotation vector
  ``phi = w dt + alpha dt^2 / 2`` (world frame).  This is the exact integral of
  the angular velocity when ``alpha`` is parallel to ``w`` (or zero), the cases
  the Galilean stage's experiments use; otherwise a second-order approximation.

A **viewer** is a :class:`~service.render.scene.Transform` (the head's pose in the world)
with its own ``MotionState``; :func:`view_scene` re-expresses a scene in the
viewer's frame, so the display model of :mod:`service.display` applies unchanged.

:func:`control_points` gives the exact projected vertex positions of every object,
the "true control points" the local-update error estimate compares with what the
Galilean stage displays.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from service.display import DisplaySettings
from service.render.projection import project
from service.render.scene import (
    Light,
    MotionState,
    Scene,
    Transform,
    quaternion_matrix,
    quaternion_multiply,
)


def rotation_vector(motion: MotionState, dt: float) -> np.ndarray:
    """Rotation vector ``w dt + alpha dt^2 / 2`` (radians, world frame), shape (3,)."""
    return motion.angular_velocity * dt + 0.5 * motion.angular_acceleration * dt * dt


def rotation_angle(motion: MotionState, dt: float) -> float:
    """Angle in radians an object turns in ``dt`` seconds (the use-by clock)."""
    return float(np.linalg.norm(rotation_vector(motion, dt)))


def _exp_quaternion(phi: np.ndarray) -> np.ndarray:
    angle = float(np.linalg.norm(phi))
    if angle < 1e-15:
        return np.array([1.0, 0.0, 0.0, 0.0])
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * phi / angle])


def advance_transform(transform: Transform, motion: MotionState, dt: float) -> Transform:
    """The transform ``dt`` seconds later under ``motion``.

    Parameters
    ----------
    transform : Transform
    motion : MotionState
    dt : float
        Seconds (may be negative).

    Returns
    -------
    Transform
    """
    pos = transform.position + motion.velocity * dt + 0.5 * motion.acceleration * dt * dt
    q = quaternion_multiply(_exp_quaternion(rotation_vector(motion, dt)), transform.orientation)
    return Transform(position=pos, orientation=q, scale=transform.scale)


def advance_scene(scene: Scene, dt: float) -> Scene:
    """The scene ``dt`` seconds later (motion states unchanged except velocity).

    Velocities are advanced too (``v + a dt``, ``w + alpha dt``), so advancing by
    ``dt1`` then ``dt2`` equals advancing by ``dt1 + dt2`` for uniform acceleration.
    """
    objs = []
    for o in scene.objects:
        m = o.motion
        m2 = MotionState(m.velocity + m.acceleration * dt, m.acceleration,
                         m.angular_velocity + m.angular_acceleration * dt, m.angular_acceleration)
        objs.append(replace(o, transform=advance_transform(o.transform, m, dt), motion=m2))
    # billboard clouds carry no motion: they stay where they are.  The meshes and
    # materials are the same, in the same order: the placement-free arrays that
    # Scene.flatten caches (polygons, triangulation, materials) carry over, so the
    # moved scene's flatten re-does only the transforms
    return Scene(objects=objs, lights=list(scene.lights), ambient=scene.ambient,
                 billboards=list(scene.billboards), _static=scene._static)


def view_scene(scene: Scene, viewer: Transform) -> Scene:
    """The scene in the viewer's frame: ``R_v^T (p - p_v)``, ``q_v^* q``.

    The viewer at the identity transform sees the scene unchanged.  Lights are
    re-expressed too, so the lighting moves with the world, not with the head.
    """
    rt = quaternion_matrix(viewer.orientation).T
    qc = viewer.orientation * np.array([1.0, -1.0, -1.0, -1.0])

    def seen(o: object) -> object:  # a mesh or billboard-cloud object, moved into view
        t = o.transform
        pos = rt @ (t.position - viewer.position)
        return replace(o, transform=Transform(pos, quaternion_multiply(qc, t.orientation),
                                              t.scale))

    objs = [seen(o) for o in scene.objects]
    boards = [seen(b) for b in scene.billboards]
    lights = view_lights(scene.lights, viewer)
    # the same meshes and materials in the same order: share flatten's cached arrays
    return Scene(objects=objs, lights=lights, ambient=scene.ambient, billboards=boards,
                 _static=scene._static)


def view_lights(lights: list[Light], viewer: Transform) -> list[Light]:
    """The lights in the viewer's frame (:func:`view_scene`'s): they stay with the world."""
    rt = quaternion_matrix(viewer.orientation).T
    out = []
    for li in lights:
        vec = rt @ (li.vector - viewer.position) if li.kind == "point" else rt @ li.vector
        out.append(replace(li, vector=vec))
    return out


def placements(
    scene: Scene, dts: list[float], viewer: Transform | None = None,
    viewer_motion: MotionState | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Every object's placement at several times, as :func:`scene_at` places them.

    The same arithmetic, bit for bit, without building a scene per time: a
    time's objects are advanced together (what each object alone needs, its
    rotation's angle and sine, is found per object, as :func:`advance_transform`
    finds it).

    Parameters
    ----------
    scene : Scene
    dts : list of float, length K
        Seconds after the scene's state.
    viewer, viewer_motion : optional
        As :func:`scene_at`.

    Returns
    -------
    positions : ndarray, shape (K, O, 3)
    orientations : ndarray, shape (K, O, 4)
        Unit quaternions; with :func:`service.render.scene.flatten` they give the scene's
        arrays at each time.
    """
    objs = scene.objects
    pos = np.empty((len(dts), len(objs), 3))
    quat = np.empty((len(dts), len(objs), 4))
    if not objs:
        return pos, quat
    p0 = np.array([o.transform.position for o in objs])
    q0 = np.array([o.transform.orientation for o in objs]).T  # (4, O): rows w, x, y, z
    v, a, w, al = (np.array([getattr(o.motion, f) for o in objs]) for f in
                   ("velocity", "acceleration", "angular_velocity", "angular_acceleration"))
    for i, dt in enumerate(dts):
        pos[i] = p0 + v * dt + 0.5 * a * dt * dt
        turn = np.array([_exp_quaternion(phi) for phi in w * dt + 0.5 * al * dt * dt]).T
        quat[i] = _unit(quaternion_multiply(turn, q0).T)
        if viewer is None:
            continue
        pose = advance_transform(viewer, viewer_motion or MotionState(), dt)
        rt = quaternion_matrix(pose.orientation).T
        pos[i] = [rt @ (p - pose.position) for p in pos[i]]
        conj = pose.orientation * np.array([1.0, -1.0, -1.0, -1.0])
        quat[i] = _unit(quaternion_multiply(conj, quat[i].T).T)
    return pos, quat


def _unit(q: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4) over their norms, each as :class:`Transform` normalises one."""
    return q / np.array([np.linalg.norm(x) for x in q])[:, None]


def scene_at(
    scene: Scene, dt: float, viewer: Transform | None = None,
    viewer_motion: MotionState | None = None,
) -> Scene:
    """The scene ``dt`` seconds later as the (moving) viewer then sees it."""
    moved = advance_scene(scene, dt)
    if viewer is None:
        return moved
    pose = advance_transform(viewer, viewer_motion or MotionState(), dt)
    return view_scene(moved, pose)


def control_points(
    scene: Scene, dt: float, display: DisplaySettings,
    viewer: Transform | None = None, viewer_motion: MotionState | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Exact projected vertex positions ``dt`` seconds later.

    Returns
    -------
    proj : ndarray, shape (Z, V, 3)
        Column, row (pixel units, centres at +0.5) and depth of every vertex of
        the flattened scene, per zone.
    vertex_object : ndarray, shape (V,), int64
        Object index of each vertex.
    """
    s = scene_at(scene, dt, viewer, viewer_motion)
    verts = [o.transform.apply(o.mesh.vertices) for o in s.objects]
    owner = [np.full(o.mesh.n_vertices, i, np.int64) for i, o in enumerate(s.objects)]
    if not verts:
        return np.zeros((display.zones, 0, 3)), np.zeros(0, np.int64)
    return project(np.concatenate(verts), display), np.concatenate(owner)


#: Binomial coefficients C(n, k), n, k = 0..3 (Leibniz's rule for the derivatives).
_BINOMIAL = ((1, 0, 0, 0), (1, 1, 0, 0), (1, 2, 1, 0), (1, 3, 3, 1))


def _skew(w: np.ndarray) -> np.ndarray:
    """Cross-product matrices ``[w]x`` of vectors (N, 3), shape (N, 3, 3)."""
    out = np.zeros((w.shape[0], 3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    out[:, 1, 0], out[:, 2, 0], out[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return out


def _turn_rates(w: np.ndarray, alpha: np.ndarray, dt: float) -> np.ndarray:
    """``R^(n) R^T`` (n = 0..3) of rotations turning at ``w + alpha dt``, shape (4, N, 3, 3).

    With ``R' = [omega]x R`` and ``omega' = alpha``: ``I``, ``[omega]``, ``[alpha] +
    [omega]^2``, ``2 [alpha][omega] + [omega][alpha] + [omega]^3``.
    """
    om, al = _skew(w + alpha * dt), _skew(alpha)
    om2 = om @ om
    eye = np.broadcast_to(np.eye(3), om.shape)
    return np.stack([eye, om, al + om2, 2 * al @ om + om @ al + om2 @ om])


def _path_rates(p0: np.ndarray, v: np.ndarray, a: np.ndarray, dt: float) -> np.ndarray:
    """Position and its derivatives 1..3 at ``dt`` under uniform acceleration, (4, N, 3)."""
    return np.stack([p0 + v * dt + 0.5 * a * dt * dt, v + a * dt, a, np.zeros_like(a)])


def motion_derivatives(
    scene: Scene, dt: float, period: float, viewer: Transform | None = None,
    viewer_motion: MotionState | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Time derivatives 1..3 of every object's points as the (moving) viewer sees them.

    A point of object ``o`` at ``X`` (viewer frame, at ``dt``: where
    :func:`scene_at` puts it) has n-th derivative ``K[n-1, o] @ X + e[n-1, o]`` per
    ``period^n``, and a direction carried by the object (a normal) ``K[n-1, o] @ N``.
    Exact for the motion :func:`advance_transform` integrates: uniform linear
    acceleration, and angular velocity ``w + alpha dt`` (the placement's own
    rotation when ``alpha`` is parallel to ``w`` or zero; otherwise the placement is
    a second-order approximation of that motion and these are the motion's derivatives).

    With the object ``R(t) s m + p(t)`` and the viewer ``B = R_v^T``, ``c``:
    ``X^(n) = sum_k C(n, k) B^(k) (R^(n-k) s m + (p - c)^(n-k))`` with ``R^(j) =
    W_j R`` and ``B^(k) = B V_k^T`` (``W``, ``V`` from :func:`_turn_rates`).

    Parameters
    ----------
    scene : Scene
    dt : float
        Seconds after the scene's state.
    period : float
        Seconds per unit of time of the derivatives (a refresh period).
    viewer, viewer_motion : optional
        As :func:`scene_at`.

    Returns
    -------
    K : ndarray, shape (3, O + 1, 3, 3)
    e : ndarray, shape (3, O + 1, 3)
        Row ``O`` is the world's own (a still point: the lights).
    """
    objs = scene.objects
    fields = ("angular_velocity", "angular_acceleration", "velocity", "acceleration")
    still = np.zeros((1, 3))  # the world's own row
    p0, w, al, v, a = (np.concatenate([np.array(x, np.float64).reshape(-1, 3), still]) for x in (
        [o.transform.position for o in objs], *([getattr(o.motion, f) for o in objs]
                                                for f in fields)))
    turn, path = _turn_rates(w, al, dt), _path_rates(p0, v, a, dt)
    if viewer is None:
        back, vturn, vpath = np.eye(3), np.zeros((4, 3, 3)), np.zeros((4, 1, 3))
        vturn[0] = np.eye(3)
    else:
        vm = viewer_motion or MotionState()
        back = quaternion_matrix(advance_transform(viewer, vm, dt).orientation).T
        vturn = _turn_rates(vm.angular_velocity[None], vm.angular_acceleration[None], dt)[:, 0]
        vpath = _path_rates(viewer.position[None], vm.velocity[None], vm.acceleration[None], dt)
    mk = back @ vturn.transpose(0, 2, 1)  # B^(k) = B V_k^T, (4, 3, 3)
    # (p - c)^(j) - W_j (p - c): zero for j = 0
    rel = path - vpath - np.einsum("joab,ob->joa", turn, path[0] - vpath[0])
    rel[0] = 0.0
    scale = (period ** np.arange(1, 4))[:, None, None]
    lead = np.einsum("nkj,kab->njab", _LEIBNIZ, mk)[:, :, None]  # sum_k C(n, k) B^(k), j = n - k
    big_k = (lead @ (turn @ back.T)[None]).sum(axis=1) * scale[..., None]
    e = (lead @ rel[None, ..., None]).sum(axis=1)[..., 0] * scale
    return big_k, e


def _leibniz() -> np.ndarray:
    """``L[n - 1, k, j] = C(n, k)`` where ``j = n - k`` (n = 1..3), else 0: shape (3, 4, 4)."""
    out = np.zeros((3, 4, 4))
    for n in range(1, 4):
        for k in range(n + 1):
            out[n - 1, k, n - k] = _BINOMIAL[n][k]
    return out


#: Leibniz's rule for the n-th derivative of a product as a table (:func:`_leibniz`).
_LEIBNIZ = _leibniz()
