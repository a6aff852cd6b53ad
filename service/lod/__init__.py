"""Level of detail: per object per frame, the cheapest representation within an error budget.

Each mesh gets a *chain* of representations (:class:`LodChain`): the full mesh, then
quadric-decimated levels (:func:`service.simplify.quadric.decimate`), each with its
geometric error in mesh units (a sampled symmetric Hausdorff distance to the full
mesh).  A chain is built once and cached on disk by the mesh's hash
(:func:`cache_dir`; format in ``docs/file-formats.md``: ``<hash>.npz`` arrays plus
``<hash>.json`` header, no pickle).

Each frame :func:`select_levels` picks, for every object, the coarsest level whose
*predicted screen error* stays under ``LodSettings.error_px``:

    predicted px = level error (mesh units) x object scale x pixels per world unit

**Which projection.** Every view zone of this display is an off-axis *parallel*
projection (:mod:`service.display`): a world displacement ``d`` moves a point on
zone ``k``'s pixel grid by ``(d_x - d_z tan(theta_k), d_y) / s``, whatever its
depth.  The longest such move per unit of ``|d|`` is ``sqrt(1 + tan^2 theta_k) / s``,
so the pixels per world unit (:func:`pixels_per_unit`) are that at the widest zone
and **do not shrink with depth**: a far object is not smaller on this display.  The
game and the service draw every object at its world size through these same parallel
projections (the head-tracked mode only chooses which zone to show), so in this
project the level depends on the object's size (mesh error x scale) and on the
pixel size, not on its distance.  :func:`select_levels` takes the pixels per unit
per object, so a perspective viewer (``f / depth``) could pass its own.

**Hysteresis.** An object moves to a coarser level only when that level's
predicted error is under ``(1 - hysteresis) x error_px``, and back to a finer one
only when its level's error goes over ``error_px``; between the two it keeps its
level, so a scale or zoom hovering at a threshold does not flicker.  The chosen
level never predicts more than ``error_px`` unless ``budget_ms`` forced it.

**Time budget.** With ``budget_ms``, when the triangles chosen would cost more than
the budget, objects are stepped to coarser levels, the smallest on screen first and,
among equals, the farthest; such objects are reported ``over_error``.  The cost is
predicted by a *measured* model (:class:`FrameCost`): a line ``fixed + per triangle``
fitted to the renderer's own last frames (their triangles and render milliseconds),
not a constant; the first frame, with nothing measured, is chosen by error alone.

**Building off the render path.**  A chain takes seconds to build (the bunny: 2 s
quiet, 5-9 s on a loaded machine), longer than the service's render timeout, so
no frame builds one.  A renderer (:class:`LodState`, ``background`` by default: a bare
``Renderer()``, the service's, its workers', the game's and the commands')
hands a chain that is not cached to a :class:`service.lod.builds.ChainBuilds` thread
(which builds it in a child process, with a cache folder or without) and draws that
mesh in full meanwhile (exact, slower); the report's ``chains`` says how many are
ready, building or failed.  A build that failed for a reason that may pass (the
child killed, a full disk) is tried again a bounded number of times; one that fails
deterministically is not.  Processes sharing a cache folder build each chain once
(a lock file).  A damaged or torn cache file is reported and rebuilt.  Scene loading
queues a scene's builds (:meth:`LodState.prepare`); a script or test that wants its
first frame to use the chains waits for them first
(:meth:`service.render.pipeline.Renderer.prepare`).
"""
