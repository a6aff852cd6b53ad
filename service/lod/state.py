"""What level of detail keeps between frames of one renderer (:class:`LodState`)."""

from __future__ import annotations

import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from service.base.errors import SettingsError
from service.display import DisplaySettings
from service.lod.builds import ChainBuilds
from service.lod.cache import build_chain, cache_dir, read_chain
from service.lod.chain import LodChain, full_only, mesh_key
from service.lod.cost import CostModel, FrameCost, frame_prior
from service.lod.select import (
    colour_angle,
    colour_pixels,
    degrade_to_budget,
    limit_colour,
    pixels_per_unit,
    select_levels,
    share_at,
)
from service.lod.settings import (
    BUDGET_BAND,
    CHAINS_KEPT,
    COLOUR_ANGLES,
    NOTES_KEPT,
    LodSettings,
)
from service.render.mesh import Mesh
from service.render.scene import Scene, SceneObject


@dataclass
class LodState:
    """What level of detail keeps between frames of one renderer.

    Chains by mesh identity (and by mesh hash, for the same mesh arriving as a new
    object, as each service job's scene does), last levels per object (hysteresis),
    the cost model of the frames (:class:`FrameCost`, for ``budget_ms``: the
    calibrated :class:`CostModel`'s line for the frame until frames are measured;
    reset when the display or the method changes), and one scene whose objects are replaced each
    frame, so the flattened scene's static parts stay cached while no level changes.

    No frame builds a chain.  With ``background`` (the default) a chain that is
    neither in memory nor in the cache is built by a :class:`ChainBuilds` thread, in a
    child process, while frames draw that object's full mesh (exact, slower); the
    first frame after it is done uses it.  :meth:`prepare` queues a scene's chains
    when it is loaded, before any frame needs them; a script or test that wants
    every frame's levels decided by its own inputs waits for them first
    (:meth:`service.render.pipeline.Renderer.prepare`).  Without ``background`` (the
    warm-up job, which compiles the simplifier's kernels in its own process)
    :meth:`prepare` builds the chains here, ``progress(mesh name, done, planned)``
    hearing how far it got, and a frame draws a mesh not prepared in full.
    """

    chains: dict = field(default_factory=dict)
    previous: np.ndarray | None = None
    names: tuple = ()
    cost: FrameCost = field(default_factory=FrameCost)
    scene: Scene | None = None
    cache: Path | None | bool = True
    display_key: tuple = ()
    background: bool = True
    progress: Callable[[str, int, int], None] | None = None
    builds: ChainBuilds | None = None
    #: cache problems met by chains built in the frame (the background's: ``builds``)
    notes: deque = field(default_factory=lambda: deque(maxlen=NOTES_KEPT))
    _by_key: OrderedDict = field(default_factory=OrderedDict)
    #: chains :meth:`prepare` built in this process (a frame that sees it change looks again)
    _prepared: int = 0
    _last: tuple | None = None
    #: the calibrated cost model (loaded on the first frame; None if it cannot be read)
    _model: CostModel | None | bool = False

    def chain(self, mesh: Mesh, settings: LodSettings) -> LodChain:
        """The chain of ``mesh``: read or built once per renderer, or its stand-in.

        The stand-in (:func:`full_only`, ``ready`` False) while the chain is built in
        the background (or, without ``background``, when :meth:`prepare` did not build it).
        """
        got = self.chains.get(id(mesh))
        mine = got is not None and got[0] is mesh and got[2] == settings.recipe
        if mine and got[1].ready:
            return got[1]
        key = got[1].key if mine else mesh_key(mesh, settings.recipe)
        chain = self._by_key.get(key)
        if chain is None:
            chain = self._fetch(mesh, settings, key)
            if chain.ready:
                self._keep(key, chain)
        else:
            self._by_key.move_to_end(key)
        if chain.levels[0] is not mesh:  # the same mesh as another object: draw its own
            chain = replace(chain, levels=(mesh, *chain.levels[1:]))
        self.chains[id(mesh)] = (mesh, chain, settings.recipe)
        return chain

    def prepare(self, scene: Scene, settings: LodSettings) -> int:
        """Start (``background``) or do (not) the builds of the chains ``scene`` lacks.

        For scene loading, before any frame needs them.  With ``background`` the
        builds are queued (:meth:`ChainBuilds.submit_scene`) and the first frames
        draw full meshes until they are done (:meth:`wait`); without, they are built
        here, now.  Returns how many were queued or built.
        """
        if self.background:
            if self.builds is None:
                self.builds = ChainBuilds(self.cache)
            return self.builds.submit_scene(scene, settings)
        built, seen = 0, set()
        for obj in scene.objects:
            if id(obj.mesh) in seen:
                continue
            seen.add(id(obj.mesh))
            key = mesh_key(obj.mesh, settings.recipe)
            if key not in self._by_key:
                self._keep(key, self._build_here(obj.mesh, settings))
                built += 1
        self._prepared += built
        return built

    def wait(self, timeout_s: float | None = None) -> bool:
        """Wait for the background builds :meth:`prepare` queued; False if still busy.

        ``timeout_s`` None waits as long as they take.
        """
        return self.builds is None or self.builds.wait_idle(timeout_s)

    def _build_here(self, mesh: Mesh, settings: LodSettings) -> LodChain:
        """Build ``mesh``'s chain in this process (:meth:`prepare` without background)."""
        report = self.progress
        tell = None if report is None else (lambda d, n: report(mesh.name, d, n))
        notes: list[str] = []
        try:
            return build_chain(mesh, settings, self.cache, notes, tell)
        finally:
            self.notes.extend(notes)

    def _keep(self, key: str, chain: LodChain) -> None:
        """Keep a ready chain in memory by its hash (the least recently used go first)."""
        self._by_key[key] = chain
        self._by_key.move_to_end(key)
        while len(self._by_key) > CHAINS_KEPT:
            self._by_key.popitem(last=False)

    def _fetch(self, mesh: Mesh, settings: LodSettings, key: str) -> LodChain:
        """A chain not in memory: from the background builds or the cache, or a stand-in.

        Never built here: with ``background`` it is queued, without it was not
        prepared and the mesh is drawn in full.
        """
        done = self.builds.take(key) if self.builds is not None else None
        if done is not None:
            return done
        folder = cache_dir() if self.cache is True else (Path(self.cache) if self.cache else None)
        cached = read_chain(folder, key, mesh) if folder is not None else None
        if cached is not None:
            return cached
        if not self.background:
            self.notes.append(f"level-of-detail chain of {mesh.name or 'a mesh'} not "
                              "prepared (LodState.prepare); drawn with its full mesh")
            return full_only(mesh, key)
        if self.builds is None:
            self.builds = ChainBuilds(self.cache)
        self.builds.submit(key, mesh, settings)  # no-op once built, failed or queued
        return full_only(mesh, key)

    def _prior(self, display: DisplaySettings, method: str, evaluation: str,
               motion: bool) -> tuple[float, float] | None:
        """The calibrated model's line for these frames; None (and a note) without one."""
        if self._model is False:
            try:
                self._model = CostModel.load()
            except SettingsError as exc:
                self._model = None
                self.notes.append(f"level of detail: no calibrated cost model ({exc}); "
                                  "the time budget waits for measured frames")
        if self._model is None:
            return None
        return frame_prior(self._model, method, evaluation, display, motion)

    def close(self, timeout_s: float = 10.0) -> None:
        """End the background builds: a running build child is stopped (SIGTERM).

        A chain it had not finished is built again by the next renderer that needs it.
        """
        if self.builds is not None:
            self.builds.close(timeout_s)

    def chain_status(self, chains: list) -> dict:
        """``ready``, ``building`` and ``failed`` counts of distinct chains, and ``notes``."""
        failed = self.builds.failed if self.builds is not None else {}
        ready = sum(c.ready for c in chains)
        bad = sum(not c.ready and c.key in failed for c in chains)
        out = {"ready": ready, "building": len(chains) - ready - bad, "failed": bad}
        notes = list(self.notes) + (list(self.builds.notes) if self.builds is not None else [])
        if notes:
            out["notes"] = notes[-NOTES_KEPT:]
        return out

    def observe(self, triangles: int, ms: float) -> None:
        """A frame's triangles and render milliseconds (the LOD step not included)."""
        self.cost.observe(triangles, ms)

    def _tables(self, scene: Scene, settings: LodSettings) -> dict:
        """Per-object chain tables, rebuilt only when the scene's meshes change."""
        generation = (self.builds.generation if self.builds is not None else 0, self._prepared)
        key = (tuple(id(o.mesh) for o in scene.objects), settings.recipe, generation)
        if getattr(self, "_tab_key", None) == key:
            return self._tab
        chains, which, seen = [], [], {}
        for o in scene.objects:
            j = seen.setdefault(id(o.mesh), len(chains))
            if j == len(chains):
                chains.append(self.chain(o.mesh, settings))
            which.append(j)
        # only this scene's meshes: a service job's scene brings new mesh objects each time
        self.chains = {k: v for k, v in self.chains.items() if k in seen}
        width = max((len(c.levels) for c in chains), default=1)
        err = np.full((len(chains), width), np.inf)
        tris = np.zeros((len(chains), width), np.int64)
        for j, c in enumerate(chains):
            err[j, : len(c.levels)] = c.errors
            tris[j] = c.triangles[np.minimum(np.arange(width), len(c.levels) - 1)]
        cloud = np.zeros((len(chains), width), np.bool_)
        turned = np.zeros((len(chains), width, len(COLOUR_ANGLES), 2))
        for j, c in enumerate(chains):
            cloud[j, : len(c.levels)] = [k == "billboard" for k in c.kinds]
            if c.turned is not None:
                turned[j, : len(c.levels)] = c.turned
        w = np.asarray(which, np.int64)
        n_levels = np.array([len(c.levels) for c in chains], np.int64)
        n_meshes = np.array([sum(k != "billboard" for k in c.kinds) for c in chains], np.int64)
        self._tab = {"chains": chains, "which": w, "errors": err[w], "triangles": tris[w],
                     "radius": np.array([c.radius for c in chains])[w],
                     "mesh_errors": np.where(cloud, np.inf, err)[w],
                     "last": (n_levels - 1)[w], "last_mesh": (n_meshes - 1)[w],
                     "ready": np.array([c.ready for c in chains], np.bool_)[w],
                     "turned": turned[w], "area": np.array([c.area for c in chains])[w],
                     "status": self.chain_status(chains)}
        self._tab_key = key
        return self._tab

    def apply(self, scene: Scene, display: DisplaySettings, settings: LodSettings,
              clouds: bool = True, method: str = "zbuffer",
              evaluation: str = "polygon") -> tuple[Scene, dict]:
        """The scene with each object's chosen level, and the frame's LOD report.

        ``clouds``: whether billboard-cloud levels may be chosen (the renderer draws
        ``Scene.billboards``); the Galilean path (:mod:`service.galilean.motion_field`)
        draws meshes only and passes False.  ``method`` and ``evaluation`` (the
        frame's occlusion method and light evaluation) pick the calibrated cost
        model's line the time budget starts from.

        Returns
        -------
        scene : Scene
            Objects carry their chosen level's mesh (the same materials, placement
            and motion); kept between frames so the flattening's cache holds.
        report : dict
            ``levels`` and ``predicted_px`` per object, ``triangles`` (chosen) and
            ``triangles_full``, ``over_error`` (objects degraded past the budget by
            ``budget_ms``), ``billboards`` (objects drawn as their billboard cloud),
            ``select_ms`` (choosing only), ``error_px``, ``chains`` (the scene's
            distinct chains ``ready``, ``building`` and ``failed``, and ``notes``:
            the last cache problems and failed builds, when there are any).
        """
        objs = scene.objects
        old = getattr(self, "_tab", None)
        tab = self._tables(scene, settings)
        self._reset_history(objs, old, tab)
        key = (display.zones, display.rows, display.cols, display.pixel_size, method,
               evaluation, clouds)
        if key != self.display_key:  # another display or method: frames cost otherwise
            self.cost, self.display_key = FrameCost(prior=self._prior(
                display, method, evaluation, not clouds)), key
        t0 = time.perf_counter_ns()
        ppu = pixels_per_unit(display)
        level, predicted = self._select(objs, tab, ppu, settings, clouds,
                                        (evaluation, display, scene.lights))
        select_ms = (time.perf_counter_ns() - t0) / 1e6
        self.previous = level
        out, boards = self._objects(scene, tab, level)
        self._fill_scene(scene, out, boards)
        return self.scene, self._report(scene, tab, level, predicted, boards, settings,
                                        select_ms, ppu)

    def _report(self, scene: Scene, tab: dict, level: np.ndarray, predicted: np.ndarray,
                boards: list, settings: LodSettings, select_ms: float, ppu: float) -> dict:
        """The frame's LOD report (see :meth:`apply`).

        ``level`` and ``predicted`` (shape (n,)) are :meth:`_select`'s per object.
        """
        rows = np.arange(len(scene.objects))
        report = {
            "error_px": settings.error_px,
            "colour_pct": settings.colour_pct,
            "levels": level.tolist(),
            "predicted_px": np.round(predicted, 4).tolist(),
            "triangles": int(tab["triangles"][rows, level].sum()),
            "triangles_full": int(tab["triangles"][:, 0].sum()),
            "over_error": int((predicted > settings.error_px).sum()),
            "billboards": len(boards) - len(getattr(scene, "billboards", [])),
            "select_ms": round(select_ms, 4),
            "pixels_per_unit": round(ppu, 3),
            "chains": tab["status"],
        }
        if settings.budget_ms is not None:
            report.update(budget_ms=settings.budget_ms, cost_model=self.cost.as_dict(),
                          predicted_ms=(round(self.cost.predict(report["triangles"]), 3)
                                        if self.cost.ready else None))
        return report

    def _reset_history(self, objs: list, old: dict | None, tab: dict) -> None:
        """Forget last frame's levels where they no longer say anything.

        All of them when the objects changed (names or count); those of the objects
        whose chain just arrived (``tab`` ready where ``old`` was not), which had no
        level to flicker from.
        """
        names = tuple(o.name for o in objs)
        if self.previous is None or names != self.names or self.previous.size != len(objs):
            self.previous, self.names = np.full(len(objs), -1, np.int64), names
        elif old is not None and tab is not old and old["ready"].size == len(objs):
            self.previous = np.where(tab["ready"] & ~old["ready"], -1, self.previous)

    def _select(self, objs: list, tab: dict, ppu: float, settings: LodSettings,
                clouds: bool, frame: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Each object's level for the error budget, the colour budget, the time budget.

        Finer where colour would change past ``colour_pct`` (``frame``: the light
        evaluation, the display and the scene's lights, :meth:`_colour`), then
        (``budget_ms``) coarser for the time budget.

        Returns
        -------
        level : ndarray, shape (n,), int64
            The chosen level of each of the ``n`` objects.
        predicted : ndarray, shape (n,), float64
            Its predicted screen error in pixels.
        """
        scale = np.fromiter((o.transform.scale for o in objs), np.float64, len(objs))
        errors = tab["errors"] if clouds else tab["mesh_errors"]
        level, predicted = select_levels(errors * scale[:, None], ppu,
                                         settings.error_px, self.previous, settings.hysteresis)
        if settings.colour_pct is not None and frame is not None and len(objs):
            level = self._colour(objs, tab, level, scale * scale, ppu, settings.colour_pct,
                                 frame)
            predicted = errors[np.arange(len(objs)), level] * scale * ppu
        if settings.budget_ms is not None and self.cost.ready and len(objs):
            level = self._budget(objs, tab, level, scale * ppu, settings.budget_ms, clouds)
            predicted = errors[np.arange(len(objs)), level] * scale * ppu
        return level, predicted

    def _colour(self, objs: list, tab: dict, level: np.ndarray, scale2: np.ndarray,
                ppu: float, colour_pct: float, frame: tuple) -> np.ndarray:
        """Levels stepped finer until the predicted colour change is ``colour_pct`` or less.

        ``frame`` is ``(evaluation, display, lights)``; ``scale2`` (n,) the objects'
        squared scales.  Each object's angle comes from its material and the lights
        (:func:`colour_angle`); its pixels from its surface area.  The shares are kept
        while the objects' materials, the lights and the chains stay the same, and the
        answer while the error's levels and the sizes do too (0.39 ms of a 200-object
        selection was spent recomputing them, against 0.09 ms without colour).
        """
        evaluation, display, lights = frame
        light = sum((np.asarray(li.colour, np.float64) * li.intensity for li in lights),
                    np.zeros(3))
        # the materials themselves (frozen, compared by identity first): kept alive here,
        # so a new one never takes an old one's id
        key = (evaluation, tuple(o.material for o in objs), light.tobytes(), ppu)
        memo = getattr(self, "_colour_memo", None)
        if memo is None or memo[0] is not tab or memo[1] != key:
            angle = colour_angle(np.array([o.material.colour for o in objs], np.float64),
                                 np.array([o.material.diffuse for o in objs], np.float64),
                                 light)
            share = share_at(tab["turned"][..., 0 if evaluation == "polygon" else 1], angle)
            memo = (tab, key, colour_pixels(share, tab["area"], ppu), None)
        budget = colour_pct / 100.0 * display.rows * display.cols
        asked = (level.tobytes(), scale2.tobytes(), budget)
        if memo[3] is not None and memo[3][0] == asked:
            return memo[3][1].copy()
        chosen = limit_colour(level, memo[2] * scale2[:, None], tab["triangles"], budget)
        self._colour_memo = (*memo[:3], (asked, chosen))
        return chosen.copy()

    def _fill_scene(self, scene: Scene, out: list, boards: list) -> None:
        """Put this frame's objects, billboards, lights and ambient in the kept scene."""
        if self.scene is None:
            self.scene = Scene([], [], scene.ambient)
        self.scene.objects, self.scene.lights = out, scene.lights
        self.scene.ambient = scene.ambient
        if boards:
            self.scene.billboards = boards
        elif hasattr(self.scene, "billboards"):
            self.scene.billboards = []

    def _objects(self, scene: Scene, tab: dict, level: np.ndarray) -> tuple[list, list]:
        """The objects at their levels, and the billboards (the scene's, then clouds).

        When the scene's objects are the very same ones as last frame and no level
        changed, last frame's list is handed back (objects are immutable), which
        spares building ~200 objects a frame (0.15 ms of a 0.25 ms LOD step).
        """
        objs = scene.objects
        last = self._last
        if (last is not None and last[4] is tab and len(last[0]) == len(objs)
                and np.array_equal(last[1], level)
                and all(a is b for a, b in zip(last[0], objs, strict=True))
                and not getattr(scene, "billboards", None)):
            return last[2], list(last[3])
        out, boards = [], list(getattr(scene, "billboards", []))
        for o, lv, j in zip(objs, level.tolist(), tab["which"].tolist(), strict=True):
            chain = tab["chains"][j]
            if lv == 0:
                out.append(o)
            elif chain.kinds[lv] == "billboard":
                # deferred: clouds load the compiled simplifier (chain._decimated's reason)
                from service.billboard_render import BillboardObject

                boards.append(BillboardObject(chain.levels[lv], o.material, o.transform, o.name))
            else:
                out.append(SceneObject(chain.levels[lv], o.material, o.transform, o.motion,
                                       o.name))
        self._last = (list(objs), level.copy(), out, list(boards), tab)
        return out, boards

    def _budget(self, objs: list, tab: dict, level: np.ndarray, size_px: np.ndarray,
                budget_ms: float, clouds: bool) -> np.ndarray:
        """The error's levels, degraded to the time budget with a dead band.

        Last frame's degrading is held while its predicted cost stays within
        ``[(1 - 2 BUDGET_BAND), 1] x budget``; over the budget the levels are planned
        again for ``(1 - BUDGET_BAND) x budget``; once the error's own levels fit
        ``(1 - 2 BUDGET_BAND) x budget`` they are taken back.  A frame cost (and a
        model) that wobbles by a few % then moves no object between levels.
        """
        rows = np.arange(level.size)
        cost = lambda lv: self.cost.predict(tab["triangles"][rows, lv].sum())  # noqa: E731
        held = np.maximum(level, self.previous)  # last frame's degrading kept
        if cost(held) > budget_ms:
            return self._degrade(objs, tab, level, size_px,
                                 (1 - BUDGET_BAND) * budget_ms, clouds)
        return level if cost(level) <= (1 - 2 * BUDGET_BAND) * budget_ms else held

    def _degrade(self, objs: list, tab: dict, level: np.ndarray, size_px: np.ndarray,
                 budget_ms: float, clouds: bool) -> np.ndarray:
        """Levels stepped coarser until the cost model predicts ``budget_ms`` or less.

        The smallest on screen (chain radius x scale x pixels per unit) go first and,
        among equals, the farthest (largest ``-z``).
        """
        depth = -np.fromiter((o.transform.position[2] for o in objs), np.float64, len(objs))
        order = np.lexsort((-depth, tab["radius"] * size_px))
        priority = np.empty(len(objs))
        priority[order] = np.arange(len(objs))
        return degrade_to_budget(level, tab["triangles"], priority,
                                 self.cost.max_triangles(budget_ms),
                                 tab["last"] if clouds else tab["last_mesh"])
