"""Peers: the depth a user could get from another engine, timed beside ours.

Engines a user might pick instead of this renderer, driven through the optional
extra ``.[peers]`` (``pip install -e '.[peers]'``):

- **llvmpipe**: OpenGL's software rasteriser (Mesa) through moderngl's headless EGL
  context.  The mesh is uploaded once; a frame is one draw per zone into its own
  viewport of one tall framebuffer, then one read back of the depth.  The vertex
  shader applies each zone's shear (``X = x - z tan(theta_k)``, ``Y = y``, the
  off-axis parallel projection of the README's display model); the fragment shader
  writes the interpolated depth ``-z`` to a float colour target (exact for a parallel
  projection), while a depth buffer decides which surface wins.  On Debian it needs
  the packages ``libegl1``, ``libegl-mesa0``, ``libgbm1`` and ``libgl1-mesa-dri``.
- **llvmpipe-cull**: the same with back-face culling on (``GL_CULL_FACE``), as a GL
  application drawing closed meshes would run it.
- **open3d**: Open3D's ``RaycastingScene`` (package ``open3d-cpu``): Embree 4 behind
  one call that casts every ray of every zone on all cores.  The rays are prebuilt
  as one tensor; the BVH is built at :meth:`Open3dPeer.load` and reported apart
  (``build_ms``), since a static scene keeps it for many frames.
- **embree**: an Embree ray cast (embreex), kept for reference: it is the weakest way to
  call Embree (one ray per ``rtcIntersect1``).  The scene's BVH is built once; a frame
  casts one ray per pixel centre and zone, all parallel to that zone's direction
  ``(-tan(theta_k), 0, -1)`` (an orthographic, sheared ray bundle), and reads the hit
  distance as depth.  The rays depend only on the display, so they are made once.

A peer that cannot start (the extra not installed, no EGL display) raises
:class:`PeerUnavailable` with the reason; :func:`start_peers` collects the reasons
and goes on with the peers that did start.

``OMP_NUM_THREADS`` / ``NUMBA_NUM_THREADS`` limit our kernels' threads; llvmpipe's
are ``LP_NUM_THREADS``, which :func:`start_peers` sets to numba's thread count unless
it is set already, so both sides use the same cores; Open3D casts on that many
threads too.  embreex casts single rays from one thread.
"""

from __future__ import annotations

import functools
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from service.base.errors import HoloError
from service.bench.galilean_bench import complexity_scene
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene, SceneArrays

PEER_NAMES = ("open3d", "llvmpipe", "llvmpipe-cull", "embree")
#: Depths (world units) closer than this agree; a pixel is 2/cols wide (0.00625 at 320).
TOLERANCE = 1e-3
#: Extra scenes for the peers: the Galilean complexity scene at about 1k to 1M triangles.
BIG_SCENES = {"spheres-1k": 1000, "spheres-8k": 8000, "spheres-100k": 100000, "spheres-1m": 1000000}
#: Frames a static scene keeps a peer's BVH for: its build is amortised over them.
AMORTISE_FRAMES = 60
#: Our occlusion methods timed beside the peers (the z-buffer is ``ours_ms``; the others
#: are ``<method>_ms``), each up to this many triangles.
OUR_METHODS = {"zbuffer": 10**9, "runlength": 10**9, "bsp": 10**5, "raycast": 10**5}

_VERTEX_SHADER = """
#version 330
in vec3 pos;
uniform float shear;
uniform vec2 half_size;
uniform vec2 depth_range;
out float depth;
void main() {
    depth = -pos.z;
    float nz = 2.0 * (depth - depth_range.x) / (depth_range.y - depth_range.x) - 1.0;
    gl_Position = vec4((pos.x - pos.z * shear) / half_size.x, pos.y / half_size.y, nz, 1.0);
}
"""
_FRAGMENT_SHADER = """
#version 330
in float depth;
out float value;
void main() { value = depth; }
"""


class PeerUnavailable(HoloError):
    """A peer engine could not be started; the message says why."""


def peer_scene(name: str) -> Scene:
    """A built-in scene, or one of :data:`BIG_SCENES` (the Galilean complexity scene)."""
    if name in BIG_SCENES:

        return complexity_scene(BIG_SCENES[name], DisplaySettings())
    return builtin_scene(name)


def _depth_range(vertices: np.ndarray) -> tuple[float, float]:
    """Depth (-z) interval holding every vertex, padded so nothing touches a clip plane."""
    lo, hi = float(-vertices[:, 2].max()), float(-vertices[:, 2].min())
    pad = 0.01 * (hi - lo) + 0.01
    return lo - pad, hi + pad


class LlvmpipePeer:
    """Mesa's llvmpipe through a headless moderngl (EGL) context."""

    name = "llvmpipe"
    #: Back-face culling (``GL_CULL_FACE``) off; :class:`LlvmpipeCullPeer` turns it on.
    cull = False

    def __init__(self) -> None:
        try:
            import moderngl
        except ImportError as exc:
            raise PeerUnavailable(
                f"moderngl not installed ({exc}); pip install -e '.[peers]'") from None
        try:
            self.ctx = moderngl.create_context(standalone=True, backend="egl")
        except Exception as exc:  # noqa: BLE001 - any driver failure means "cannot start"
            raise PeerUnavailable(
                f"no headless EGL context ({str(exc).splitlines()[0]}); on Debian install "
                "libegl1 libegl-mesa0 libgbm1 libgl1-mesa-dri"
            ) from None
        self.renderer = self.ctx.info.get("GL_RENDERER", "?")
        self.prog = self.ctx.program(vertex_shader=_VERTEX_SHADER,
                                     fragment_shader=_FRAGMENT_SHADER)
        self._flags = moderngl.DEPTH_TEST | (moderngl.CULL_FACE if self.cull else 0)
        self._objects: list = []
        self.build_ms = 0.0

    def load(self, arrays: SceneArrays, display: DisplaySettings) -> None:
        """Upload a scene's triangles and make a framebuffer of ``zones`` stacked images."""
        self._release()
        t0 = time.perf_counter()
        ctx, z, w, h = self.ctx, display.zones, display.cols, display.rows
        vbo = ctx.buffer(np.ascontiguousarray(arrays.vertices, np.float32).tobytes())
        ibo = ctx.buffer(np.ascontiguousarray(arrays.triangles, np.int32).tobytes())
        self.vao = ctx.vertex_array(self.prog, [(vbo, "3f", "pos")], index_buffer=ibo,
                                    index_element_size=4)
        colour = ctx.texture((w, h * z), 1, dtype="f4")
        depth = ctx.depth_renderbuffer((w, h * z))
        self.fbo = ctx.framebuffer([colour], depth)
        self._objects = [vbo, ibo, self.vao, colour, depth, self.fbo]
        self.prog["half_size"].value = (display.width / 2, display.height / 2)
        self.prog["depth_range"].value = _depth_range(arrays.vertices)
        self.shears = [float(s) for s in display.shears()]
        self.shape = (z, h, w)
        self.build_ms = (time.perf_counter() - t0) * 1e3

    def depth(self) -> np.ndarray:
        """Draw every zone and read the depth back: (Z, R, C) float32, +inf where empty."""
        z, h, w = self.shape
        self.fbo.use()
        self.fbo.viewport = (0, 0, w, h * z)
        self.fbo.clear(red=np.inf, depth=1.0)
        self.ctx.enable_only(self._flags)
        for k, shear in enumerate(self.shears):
            self.fbo.viewport = (0, k * h, w, h)
            self.prog["shear"].value = shear
            self.vao.render()
        raw = self.fbo.read(viewport=(0, 0, w, h * z), components=1, dtype="f4")
        # OpenGL's row 0 is the bottom; ours is the top
        return np.frombuffer(raw, np.float32).reshape(z, h, w)[:, ::-1]

    def _release(self) -> None:
        for obj in reversed(self._objects):
            obj.release()
        self._objects = []

    def close(self) -> None:
        """Free the GL objects and the context."""
        self._release()
        self.ctx.release()


class LlvmpipeCullPeer(LlvmpipePeer):
    """llvmpipe with back-face culling on.

    A triangle whose projection winds clockwise (its normal ``(b - a) x (c - a)``
    turned away from the zone) is not drawn.
    """

    name = "llvmpipe-cull"
    cull = True


class Open3dPeer:
    """Open3D's ``RaycastingScene``: Embree 4, every zone's rays in one threaded call."""

    name = "open3d"

    def __init__(self) -> None:
        try:
            import open3d
        except ImportError as exc:
            raise PeerUnavailable(
                f"open3d not installed ({exc}); pip install -e '.[peers]'") from None
        self._o3d = open3d
        self.renderer = f"Open3D {open3d.__version__} RaycastingScene (Embree 4)"
        self.threads = _thread_count()
        self.build_ms = 0.0

    def load(self, arrays: SceneArrays, display: DisplaySettings) -> None:
        """Build the BVH (timed as ``build_ms``) and one tensor of every zone's rays."""
        o3d = self._o3d
        t0 = time.perf_counter()
        self.scene = o3d.t.geometry.RaycastingScene(nthreads=self.threads)
        self.empty = arrays.triangles.shape[0] == 0
        if not self.empty:
            self.scene.add_triangles(
                o3d.core.Tensor(np.ascontiguousarray(arrays.vertices, np.float32)),
                o3d.core.Tensor(np.ascontiguousarray(arrays.triangles, np.uint32)))
            # the BVH is committed on the first query: cast one ray so build_ms holds it
            self.scene.cast_rays(o3d.core.Tensor(np.array([[0, 0, 0, 0, 0, -1]], np.float32)))
        self.build_ms = (time.perf_counter() - t0) * 1e3
        self.front = float(arrays.vertices[:, 2].max()) + 1.0 if not self.empty else 1.0
        rays = sheared_rays(display, self.front)
        self.rays = o3d.core.Tensor(np.concatenate(
            [np.concatenate(pair, axis=1) for pair in rays]))
        self.shape = (display.zones, display.rows, display.cols)

    def depth(self) -> np.ndarray:
        """Cast every zone's rays: (Z, R, C) float32, +inf where nothing is hit."""
        if self.empty:
            return np.full(self.shape, np.inf, np.float32)
        t = self.scene.cast_rays(self.rays, nthreads=self.threads)["t_hit"].numpy()
        return (t - np.float32(self.front)).reshape(self.shape)

    def close(self) -> None:
        """Drop the scene."""
        self.scene = None


class EmbreePeer:
    """Embree's BVH ray cast (embreex), one orthographic sheared ray bundle per zone."""

    name = "embree"

    def __init__(self) -> None:
        try:
            import embreex.mesh_construction as mesh_construction
            import embreex.rtcore_scene as rtcore_scene
        except ImportError as exc:
            raise PeerUnavailable(
                f"embreex not installed ({exc}); pip install -e '.[peers]'") from None
        self._scene_type = rtcore_scene.EmbreeScene
        self._mesh_type = mesh_construction.TriangleMesh
        self.renderer = "Embree 4 (embreex, one rtcIntersect1 per ray)"
        self.build_ms = 0.0

    def load(self, arrays: SceneArrays, display: DisplaySettings) -> None:
        """Build the BVH and the rays of every zone (see :func:`sheared_rays`)."""
        t0 = time.perf_counter()
        self.scene = self._scene_type()
        self.empty = arrays.triangles.shape[0] == 0
        if not self.empty:
            self._mesh_type(self.scene, np.ascontiguousarray(arrays.vertices, np.float32),
                            np.ascontiguousarray(arrays.triangles, np.int32))
            # the BVH is built on the first query: cast one ray so build_ms holds it
            self.scene.run(np.zeros((1, 3), np.float32), np.array([[0, 0, -1]], np.float32))
        self.front = float(arrays.vertices[:, 2].max()) + 1.0 if not self.empty else 1.0
        self.rays = sheared_rays(display, self.front)
        self.shape = (display.zones, display.rows, display.cols)
        self.build_ms = (time.perf_counter() - t0) * 1e3

    def depth(self) -> np.ndarray:
        """Cast every zone's rays: (Z, R, C) float32, +inf where nothing is hit."""
        out = np.full(self.shape, np.inf, np.float32)
        if self.empty:
            return out
        for k, (origins, directions) in enumerate(self.rays):
            tfar = np.asarray(self.scene.run(origins, directions, query="DISTANCE"))
            # a miss leaves tfar at embreex's "infinity", 1e37
            d = np.where(tfar < 1e30, tfar - np.float32(self.front), np.inf)
            out[k] = d.reshape(self.shape[1:])
        return out

    def close(self) -> None:
        """Drop the scene (embreex frees it when collected)."""
        self.scene = None


def sheared_rays(display: DisplaySettings, front: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per zone, origins and directions (each (R*C, 3) float32) of its pixel rays.

    The ray of pixel (r, c) in zone k is the line of points that zone projects onto
    the pixel centre: ``(X + z t_k, Y, z)`` with ``t_k = tan(theta_k)``.  It starts at
    ``z = front`` (in front of the scene) and runs along ``(-t_k, 0, -1)``, so the hit
    distance ``t`` is ``front - z`` and the depth ``-z`` is ``t - front``.
    """
    s = display.pixel_size
    x = (np.arange(display.cols) + 0.5) * s - display.width / 2
    y = display.height / 2 - (np.arange(display.rows) + 0.5) * s
    xx, yy = np.meshgrid(x, y)
    rays = []
    for t in display.shears():
        origins = np.stack([xx + front * t, yy, np.full_like(xx, front)], axis=-1)
        directions = np.broadcast_to(np.array([-t, 0.0, -1.0]), origins.shape)
        rays.append((np.ascontiguousarray(origins.reshape(-1, 3), np.float32),
                     np.ascontiguousarray(directions.reshape(-1, 3), np.float32)))
    return rays


PEER_TYPES = {"open3d": Open3dPeer, "llvmpipe": LlvmpipePeer,
              "llvmpipe-cull": LlvmpipeCullPeer, "embree": EmbreePeer}


def _thread_count() -> int:
    """Return numba's thread count: the cores our kernels use, given to the threaded peers too."""
    return int(numba.config.NUMBA_NUM_THREADS)


def start_peers(names=PEER_NAMES) -> tuple[list, dict[str, str]]:
    """Start the named peers; return (the peers that started, {name: why not} for the rest)."""
    os.environ.setdefault("LP_NUM_THREADS", str(_thread_count()))
    started, reasons = [], {}
    for name in names:
        try:
            started.append(PEER_TYPES[name]())
        except PeerUnavailable as exc:
            reasons[name] = str(exc)
    return started, reasons


def depth_agreement(ours: np.ndarray, theirs: np.ndarray, tolerance: float = TOLERANCE) -> float:
    """% of pixels where two depth maps agree: both empty, or both within ``tolerance``.

    Parameters
    ----------
    ours, theirs : ndarray, shape (Z, R, C)
        Depths, +inf where nothing is drawn.
    """
    empty = np.isinf(ours) & np.isinf(theirs)
    with np.errstate(invalid="ignore"):
        close = np.abs(ours.astype(np.float64) - theirs) <= tolerance
    return 100.0 * float(np.mean(empty | close))


@dataclass(frozen=True)
class PeerRun:
    """How one comparison is timed.

    Attributes
    ----------
    repeats : int
        Timed calls of each engine per round.
    rounds : int
        Rounds.  Calls are interleaved one by one (ours, llvmpipe, embree, ours, ...,
        the order rotating each call), so a busy moment of the machine slows every
        engine alike instead of one engine's whole block; each engine's time is the
        median of its ``repeats * rounds`` calls.
    warmup : int
        Untimed calls of each engine first: a peer's first draw compiles its shaders
        (llvmpipe JIT-compiles them at the first draw, not at link time), touches its
        buffers and builds lazy state, and ours loads its kernels.
    reference : bool
        Also ray cast with our ``raycast`` method and give each engine's % of pixels
        whose depth differs from it (slow on big scenes).
    tolerance : float
        Depth agreement tolerance, world units.
    methods : tuple of str
        Our occlusion methods timed in turn with the peers (the z-buffer always;
        the others up to their :data:`OUR_METHODS` size).
    """

    repeats: int = 3
    rounds: int = 3
    warmup: int = 1
    reference: bool = True
    tolerance: float = TOLERANCE
    methods: tuple[str, ...] = ("zbuffer",)


def _ours(arrays: SceneArrays, display: DisplaySettings, method: str = "zbuffer") -> np.ndarray:
    """Our stages 1-4 with an occlusion method (default the z-buffer): the depth (Z, R, C)."""
    vis, _, _ = Renderer().visibility(arrays, display, RenderSettings(method=method))
    return vis.depth


def our_methods(triangles: int, methods: tuple[str, ...]) -> list[str]:
    """Which of ``methods`` besides the z-buffer to time on a scene (:data:`OUR_METHODS`)."""
    return [m for m in methods if m != "zbuffer" and triangles <= OUR_METHODS[m]]


def interleaved_ms(engines: dict, run: PeerRun,
                   clock: Callable[[], float] = time.perf_counter) -> tuple[dict, dict]:
    """Median ms of each engine (name -> callable), after untimed warm-up calls.

    Every engine is first called ``run.warmup`` times untimed; then the timed calls
    go one at a time in turn, the order rotating by one each turn (see
    :class:`PeerRun`).  ``clock`` returns seconds.

    Returns
    -------
    ms : dict of str to float
        Median milliseconds per call.
    depth : dict of str to ndarray
        Each engine's last output.
    """
    names = list(engines)
    depth: dict = {}
    for _ in range(run.warmup):
        for name in names:
            depth[name] = engines[name]()
    times: dict[str, list[float]] = {name: [] for name in names}
    for turn in range(run.repeats * run.rounds):
        shift = turn % len(names)
        for name in names[shift:] + names[:shift]:
            t0 = clock()
            depth[name] = engines[name]()
            times[name].append((clock() - t0) * 1e3)
    return {name: float(np.median(t)) for name, t in times.items()}, depth


def compare(scene_name: str, zones: int, size: tuple[int, int], peers: list,
            run: PeerRun | None = None, angle: float = 16.0) -> list[dict]:
    """Time our z-buffer and every peer on one configuration; check their depth against ours.

    Returns
    -------
    list of dict
        One row per peer: ``scene, zones, size, triangles, peer, peer_ms, ours_ms,
        ratio`` (ours / peer), ``<method>_ms`` for each other method of ours timed
        (``run.methods``), ``build_ms`` (the peer's upload or BVH, not timed per
        frame), ``static_ms`` (``peer_ms`` + ``build_ms`` / :data:`AMORTISE_FRAMES`),
        ``moving_ms`` (``peer_ms`` + ``build_ms``: a scene that moves rebuilds it),
        ``pct_agree`` (depth within the tolerance of ours) and, with
        ``run.reference``, ``pct_differ`` (% pixels unlike our ray cast) and
        ``ours_pct_differ``.
    """
    run = run or PeerRun()
    arrays = peer_scene(scene_name).flatten()
    display = DisplaySettings(zones=zones, angle_deg=angle, cols=size[0], rows=size[1])
    for peer in peers:
        peer.load(arrays, display)
    engines = {"ours": lambda: _ours(arrays, display)}
    mine = our_methods(int(arrays.triangles.shape[0]), run.methods)
    engines |= {f"ours:{m}": functools.partial(_ours, arrays, display, m) for m in mine}
    engines |= {p.name: p.depth for p in peers}
    ms, depth = interleaved_ms(engines, run)
    ref = None
    if run.reference:
        vis, _, _ = Renderer().visibility(arrays, display, RenderSettings(method="raycast"))
        ref = vis.depth
    rows = []
    for peer in peers:
        row = {"scene": scene_name, "zones": zones, "size": f"{size[0]}x{size[1]}",
               "triangles": int(arrays.triangles.shape[0]), "peer": peer.name,
               "peer_ms": round(ms[peer.name], 3), "ours_ms": round(ms["ours"], 3),
               "ratio": round(ms["ours"] / ms[peer.name], 3),
               **{f"{m}_ms": round(ms[f"ours:{m}"], 3) for m in mine},
               "build_ms": round(peer.build_ms, 3),
               # a static scene keeps the BVH/upload AMORTISE_FRAMES frames; a moving one
               # pays it every frame
               "static_ms": round(ms[peer.name] + peer.build_ms / AMORTISE_FRAMES, 3),
               "moving_ms": round(ms[peer.name] + peer.build_ms, 3),
               "pct_agree": round(depth_agreement(depth["ours"], depth[peer.name],
                                                  run.tolerance), 4)}
        if ref is not None:
            row["pct_differ"] = round(100 - depth_agreement(ref, depth[peer.name],
                                                            run.tolerance), 4)
            row["ours_pct_differ"] = round(100 - depth_agreement(ref, depth["ours"],
                                                                 run.tolerance), 4)
        rows.append(row)
    return rows


def fastest_peers(rows: list[dict]) -> list[dict]:
    """Per configuration (scene, zones, size), the peer with the least ``static_ms``.

    Returns
    -------
    list of dict
        ``scene, zones, size, triangles, ours_ms, peer, static_ms, moving_ms`` and
        ``ratio`` (ours / the peer's static ms), in the rows' order.
    """
    best: dict[tuple, dict] = {}
    for r in rows:
        key = (r["scene"], r["zones"], r["size"])
        if key not in best or r["static_ms"] < best[key]["static_ms"]:
            best[key] = r
    return [{k: r[k] for k in ("scene", "zones", "size", "triangles", "ours_ms", "peer",
                               "static_ms", "moving_ms")}
            | {"ratio": round(r["ours_ms"] / r["static_ms"], 3)} for r in best.values()]


def plot_peers(ax, rows: list[dict], scene: str) -> None:
    """Draw each peer as a dashed grey reference line (ms, % differ) on a chart panel.

    Points are labelled with the zone count, as the methods' are; rows without
    ``pct_differ`` (no ray-cast reference) are left out.
    """
    styles = {"open3d": ("0.15", "X"), "llvmpipe": ("0.35", "P"),
              "llvmpipe-cull": ("0.45", "p"), "embree": ("0.6", "*")}
    for name in PEER_NAMES:
        pts = sorted((r for r in rows if r["scene"] == scene and r["peer"] == name
                      and "pct_differ" in r), key=lambda r: r["zones"])
        if not pts:
            continue
        colour, marker = styles[name]
        ax.plot([r["peer_ms"] for r in pts], [r["pct_differ"] for r in pts], ls="--",
                color=colour, marker=marker, label=f"peer: {name}")
        for r in pts:
            ax.annotate(str(r["zones"]), (r["peer_ms"], r["pct_differ"]), fontsize=7,
                        color=colour, textcoords="offset points", xytext=(3, -9))
