"""Part 4 of ``holo-bench billboard``: what a cloud costs against the meshes it replaces.

For each mesh (``--cost-meshes``: the ``holo-bench lod`` meshes) and on-screen size
(``--cost-sizes``: the bounding-box diagonal in pixels, the object centred and turned
as in ``holo-bench lod``), CPU milliseconds of a whole ``--zones``-zone frame, above an
empty frame's, for the full mesh, its billboard cloud (the LOD chain's, EPS 1 %), and
the quadric level level of detail picks at that size without clouds (the cheapest
whose predicted error is within ``--lod-error``).  The four renders are interleaved and
each takes the best of ``--repeats`` (the machine is shared: the best is the least
disturbed).  ``lod_picks_cloud`` says whether the chain with the cloud would choose it.
"""

from __future__ import annotations

import time

import numpy as np

from service.bench.lod_bench import LIGHTS, MATERIAL, MESHES
from service.billboard_render import BillboardObject
from service.display import DisplaySettings
from service.lod.cache import build_chain
from service.lod.select import pixels_per_unit, select_levels
from service.lod.settings import LodSettings
from service.render.light import LightSettings
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene, SceneObject, Transform, euler_quaternion, quaternion_matrix

SETTINGS = RenderSettings(method="zbuffer", light=LightSettings("blinn", "polygon"))
#: The cloud level of the chain, EPS as a fraction of the diagonal.
CLOUD_EPS = 0.01


def _scene(level: object, kind: str, place: Transform) -> Scene:
    if kind == "billboard":
        return Scene([], LIGHTS, 1.0, billboards=[BillboardObject(level, MATERIAL, place)])
    return Scene([SceneObject(level, MATERIAL, place)], LIGHTS, 1.0)


def _best_ms(scenes: list[Scene], display: DisplaySettings, repeats: int) -> list[float]:
    """Best CPU ms of each scene's render, the scenes interleaved (one renderer each)."""
    renderers = [Renderer() for _ in scenes]
    for r, s in zip(renderers, scenes, strict=True):
        r.render(s, display, SETTINGS)  # kernels, caches
    best = [np.inf] * len(scenes)
    for _ in range(repeats):
        for k, (r, s) in enumerate(zip(renderers, scenes, strict=True)):
            c0 = time.process_time()
            r.render(s, display, SETTINGS)
            best[k] = min(best[k], (time.process_time() - c0) * 1e3)
    return best


def cost_rows(display: DisplaySettings, meshes: list[str], sizes: list[float],
              error_px: float, repeats: int) -> list[dict]:
    """One row per mesh and size (see the module doc)."""
    ppu = pixels_per_unit(display)
    rows = []
    for name in meshes:
        mesh = MESHES[name]()
        chain = build_chain(mesh, LodSettings(cloud_eps=(CLOUD_EPS,)))
        lo, hi = mesh.vertices.min(0), mesh.vertices.max(0)
        diag = float(np.linalg.norm(hi - lo))
        cloud = chain.kinds.index("billboard")
        meshes_only = [k for k, kind in enumerate(chain.kinds) if kind != "billboard"]
        for px in sizes:
            s = px * display.pixel_size / diag
            q = euler_quaternion(0.4, 0.25, 0.0)
            place = Transform(-(quaternion_matrix(q) @ ((lo + hi) / 2)) * s, q, s)
            err = chain.errors * s
            lv_mesh = meshes_only[int(select_levels(err[meshes_only][None], ppu, error_px)[0][0])]
            lv_any = int(select_levels(err[None], ppu, error_px)[0][0])
            empty, full, cl, lod = _best_ms(
                [Scene([], LIGHTS, 1.0), _scene(chain.levels[0], "full", place),
                 _scene(chain.levels[cloud], "billboard", place),
                 _scene(chain.levels[lv_mesh], "quadric", place)], display, repeats)
            rows.append({
                "mesh": name, "size_px": px, "empty_ms": empty,
                "full_ms": full - empty, "full_triangles": int(chain.triangles[0]),
                "cloud_ms": cl - empty, "cloud_quads": int(chain.triangles[cloud] // 2),
                "cloud_predicted_px": float(err[cloud] * ppu),
                "lod_mesh_ms": lod - empty, "lod_mesh_triangles": int(chain.triangles[lv_mesh]),
                "lod_mesh_predicted_px": float(err[lv_mesh] * ppu),
                "lod_picks_cloud": lv_any == cloud,
            })
    return rows


def chart(ax, rows: list[dict]) -> None:  # noqa: ANN001 (a matplotlib Axes)
    """CPU ms above an empty frame against on-screen size, per mesh: full, cloud, LOD's level."""
    for i, name in enumerate(dict.fromkeys(r["mesh"] for r in rows)):
        rs = [r for r in rows if r["mesh"] == name]
        x = [r["size_px"] for r in rs]
        ax.plot(x, [r["full_ms"] for r in rs], "o-", c=f"C{i}", label=f"{name} full mesh")
        ax.plot(x, [r["cloud_ms"] for r in rs], "*--", c=f"C{i}", label=f"{name} cloud (1 %)")
        ax.plot(x, [r["lod_mesh_ms"] for r in rs], "s:", c=f"C{i}",
                label=f"{name} LOD's quadric level")
    ax.set(xlabel="on-screen size (bounding-box diagonal, px)", ylabel="CPU ms above empty",
           xscale="log", yscale="log", title="Cost per frame: cloud vs meshes")
    ax.legend(fontsize=7)
