"""The render pipeline: scene -> cull -> sort -> occlusion -> light -> frame.

Each stage is a plain function over arrays (see the stage modules); this module
only wires them together, times them, and applies the painter's-order fallback:
when the run-length method reports that the average-z order decided a pixel the
scene did not (cyclic overlap, interpenetration), the frame is redone with the
z-buffer and the fallback is reported in the stats instead of showing a wrong
picture.
"""

from __future__ import annotations

import functools
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from service.base.errors import SettingsError
from service.billboard_render import draw_billboards
from service.display import DisplaySettings
from service.lod.settings import LodSettings
from service.lod.state import LodState
from service.render.cull import CullSettings, cull_zones
from service.render.depth_sort import depth_order, kept_triangles, tie_source
from service.render.frame import Frame
from service.render.light import LightSettings, mark_shown, shade
from service.render.mesh import Mesh
from service.render.occlusion import Visibility
from service.render.occlusion.bsp import BspCache, bsp
from service.render.occlusion.raycast import raycast
from service.render.occlusion.runlength import runlength
from service.render.occlusion.zbuffer import zbuffer
from service.render.projection import project_tables
from service.render.scene import Scene, SceneArrays, SceneObject

OcclusionFn = Callable[[SceneArrays, np.ndarray, DisplaySettings, np.ndarray], Visibility]


@dataclass(frozen=True)
class RenderSettings:
    """Choices for one render.

    Attributes
    ----------
    method : {"zbuffer", "runlength", "bsp", "raycast"}
        Occlusion method.
    cull : CullSettings
    light : LightSettings
    painter_fallback : {"frame", "pixel", "off"}
        What to do when the run-length method proves the average-z order wrong
        (a point it hid was nearer than what it drew): ``"frame"`` redraws the frame
        with the z-buffer; ``"pixel"`` draws just those points (a z-test where the
        sort failed; same picture as the z-buffer, cheaper); ``"off"`` keeps the
        painter's picture (for study). Every mode reports the count. Default
        ``"pixel"``: its buffers equal the z-buffer's bit for bit (the repair uses the
        z-buffer's strict depth test, so exact ties keep the surface drawn first), and
        a scene whose sort is wrong on a few points (the game scene: ~44 pixels at 5
        zones) keeps the run-length method instead of paying for two methods.
    painter_tolerance : int
        Inconsistent pixels tolerated before the ``"frame"`` fallback (0: any).
    lod : LodSettings or None
        Level of detail per object (:mod:`service.lod`); None or disabled: full meshes.
    """

    method: str = "zbuffer"
    cull: CullSettings = field(default_factory=CullSettings)
    light: LightSettings = field(default_factory=LightSettings)
    painter_fallback: str = "pixel"
    painter_tolerance: int = 0
    lod: LodSettings | None = None

    def __post_init__(self) -> None:
        if self.method not in METHOD_NAMES:
            raise SettingsError(f"method must be one of {METHOD_NAMES}, got {self.method!r}")
        if self.painter_fallback not in FALLBACKS:
            raise SettingsError(
                f"painter_fallback must be one of {FALLBACKS}, got {self.painter_fallback!r}"
            )
        if self.painter_tolerance < 0:
            raise SettingsError("painter_tolerance must be >= 0")


METHOD_NAMES = ("runlength", "zbuffer", "bsp", "raycast")
FALLBACKS = ("frame", "pixel", "off")
#: Methods that take the per-zone cull mask (BSP and ray casting draw every kept polygon).
MASKED_METHODS = frozenset({"zbuffer", "runlength", "runlength-repair"})
#: Display shapes whose triangle map each thread of a Renderer keeps for reuse.
SCRATCH_SHAPES = 4


class Renderer:
    """Renders scenes; keeps what can be reused between frames (the BSP tree)."""

    def __init__(self) -> None:
        self._bsp = BspCache()
        self._methods: dict[str, OcclusionFn] = {
            "runlength": runlength,
            "runlength-repair": functools.partial(runlength, repair=True),
            "zbuffer": zbuffer,
            "bsp": functools.partial(bsp, tree=self._bsp),
            "raycast": raycast,
        }
        self._scratch = threading.local()
        self.lod = LodState()

    def prepare(self, scene: Scene, lod: LodSettings | None = None,
                timeout_s: float | None = None) -> bool:
        """Build the level-of-detail chains ``scene``'s meshes lack, before its frames.

        No frame builds a chain: one not built yet is drawn with its full mesh while
        it builds in the background (:class:`~service.lod.state.LodState`).  A script
        or test that wants its first frame's levels to be the chains' calls this
        first; it waits for the builds (``timeout_s`` None: as long as they take).
        ``lod`` is the frames' :class:`LodSettings` (its recipe picks the chain;
        default ``LodSettings()``).  Returns whether every chain is ready.
        """
        self.lod.prepare(scene, lod if lod is not None else LodSettings())
        return self.lod.wait(timeout_s)

    def _triangle_buffer(self, shape: tuple[int, int, int]) -> np.ndarray:
        """Reusable (Z, R, C) int32 triangle map of the calling thread for :meth:`render`.

        The map never leaves :meth:`render` (a frame keeps colour and depth), so one
        buffer per thread and shape (the last :data:`SCRATCH_SHAPES` shapes) serves
        every frame, without the page faults a fresh multi-megabyte array costs.
        """
        pool = getattr(self._scratch, "triangle", None)
        if pool is None:
            pool = self._scratch.triangle = {}
        buf = pool.pop(shape, None)
        if buf is None:
            buf = np.empty(shape, np.int32)
        pool[shape] = buf  # most recently used last
        while len(pool) > SCRATCH_SHAPES:
            del pool[next(iter(pool))]
        return buf

    def render(
        self, scene: Scene, display: DisplaySettings, settings: RenderSettings | None = None
    ) -> Frame:
        """Render every view zone of a scene.

        Returns
        -------
        Frame
            ``colour`` (Z, R, C, 3) uint8, ``depth`` (Z, R, C) float32 and ``stats``
            with polygon counts, per-stage milliseconds and occlusion counters.
        """
        settings = settings or RenderSettings()
        ms: dict[str, float] = {}
        clock = StageClock(ms)
        lod = settings.lod if settings.lod is not None and settings.lod.enabled else None
        if lod is not None:
            with clock("lod"):
                scene, lod_report = self.lod.apply(scene, display, lod, True, settings.method,
                                                   settings.light.evaluation)
        with clock("flatten"):
            arrays = scene.flatten()
        # visibility() keeps its signature (subclasses override it): the buffer goes
        # through this thread's slot, set only while render() is inside it
        self._scratch.active = self._triangle_buffer((display.zones, display.rows, display.cols))
        try:
            vis, counts, proj = self.visibility(arrays, display, settings, clock)
        finally:
            self._scratch.active = None
        boards = None
        if scene.billboards:  # alpha-tested quads into the same depth buffer
            with clock("billboards"):
                boards = draw_billboards(scene.billboards, display, vis, settings.method,
                                         scene.lights, scene.ambient, settings.light)
        with clock("light"):
            colour = shade(arrays, proj, vis, display, scene.lights, scene.ambient, settings.light)
            if boards is not None:
                boards.paint(colour)
        stats = {"polygons": counts, "ms": ms, "occlusion": vis.stats, "method": settings.method}
        if boards is not None:
            stats["billboards"] = boards.stats
        stats["ms"]["total"] = float(sum(ms.values()))
        if lod is not None:
            stats["lod"] = lod_report
            # the budget's cost model: the frame's cost without the LOD step itself
            # (whose first call builds or reads the chains)
            self.lod.observe(arrays.triangles.shape[0], stats["ms"]["total"] - ms["lod"])
        return Frame(colour=colour, depth=vis.depth, stats=stats)

    def visibility(
        self,
        arrays: SceneArrays,
        display: DisplaySettings,
        settings: RenderSettings,
        clock: StageClock | None = None,
    ) -> tuple[Visibility, dict, np.ndarray]:
        """Stages 1-4: project, cull, sort, occlusion (with the painter fallback).

        Called by :meth:`render`, the z-buffer's triangle map is this thread's reused
        buffer; called directly, it is a fresh array the caller may keep.
        """
        clock = clock or StageClock({})
        scratch = getattr(self._scratch, "active", None)
        name = settings.method
        if name == "runlength" and settings.painter_fallback == "pixel":
            name = "runlength-repair"
        by_triangle = name == "zbuffer"  # the one-pass z-buffer reads the mask as (T, Z)
        # the projection by vertex too, where a z-buffer runs (or may: the fallback)
        tables = by_triangle or (name == "runlength" and settings.painter_fallback == "frame")
        with clock("project"):
            proj, xz, yd = project_tables(arrays.vertices, display, tables)
        with clock("cull"):  # both culls from one facing table, in one pass
            keep, counts, draw = cull_zones(arrays.normals, arrays.triangle_polygon,
                                            arrays.polygon_closed, display, settings.cull)
            if not by_triangle:
                draw = np.ascontiguousarray(draw.T)  # (Z, T)
        with clock("sort"):  # ties in depth go to the triangle earlier in the depth order
            if name == "zbuffer":  # which its depth test finds where a tie is: no sort
                order = kept_triangles(arrays.triangle_polygon, keep)
                key = tie_source(arrays.vertices, arrays.polygons, arrays.counts,
                                 arrays.triangle_polygon)
            else:  # the other methods draw (or paint, or break ties) in the order
                order = depth_order(arrays.vertices, arrays.polygons, arrays.counts,
                                    arrays.triangle_polygon, keep)
        extra = {"draw": draw} if name in MASKED_METHODS else {}
        if name == "zbuffer":  # it also finds the polygons shown (Visibility.shown)
            extra = {"draw_t": draw, "tri_out": scratch, "item": arrays.triangle_polygon,
                     "n_items": arrays.n_polygons, "tables": (xz, yd), "key": key}
        with clock("occlusion"):
            vis = self._methods[name](arrays, proj, display, order, **extra)
        bad = vis.stats.get("inconsistent_pixels", 0)
        if settings.painter_fallback == "frame" and bad > settings.painter_tolerance:
            with clock("fallback"):
                mask = {"draw_t": draw} if by_triangle else {"draw": draw}
                redo = zbuffer(arrays, proj, display, order, tri_out=scratch,
                               item=arrays.triangle_polygon, n_items=arrays.n_polygons,
                               tables=(xz, yd), **mask)
            redo.stats = {**vis.stats, "fallback": "zbuffer"}
            vis = redo
        with clock("occlusion"):  # the count of polygons seen is part of the stage's cost
            if vis.shown is None:  # the z-buffer's one-pass kernel finds it as it draws
                vis.shown = mark_shown(vis.triangle, arrays.triangle_polygon, arrays.n_polygons)
            counts["drawn"] = int(vis.shown.any(axis=0).sum())
        return vis, counts, proj


class StageClock:
    """Context-manager factory that adds each stage's milliseconds to a dict."""

    def __init__(self, ms: dict[str, float]) -> None:
        self.ms = ms
        self._name = ""
        self._t0 = 0

    def __call__(self, name: str) -> StageClock:
        """Name the stage the next ``with`` block times."""
        self._name = name
        return self

    def __enter__(self) -> None:
        self._t0 = time.perf_counter_ns()

    def __exit__(self, *exc: object) -> None:
        self.ms[self._name] = (
            self.ms.get(self._name, 0.0) + (time.perf_counter_ns() - self._t0) / 1e6
        )


def warm_up(settings: RenderSettings | None = None) -> None:
    """Compile (or load from numba's cache) the kernels a render will use.

    Renders a one-triangle scene with the same settings, so timings of the next real
    render measure the work and not the compiler.
    """
    tri = Mesh.from_triangles([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.1]], [[0, 1, 2]])
    Renderer().render(Scene([SceneObject(tri)]), DisplaySettings(zones=2, cols=8, rows=8), settings)
