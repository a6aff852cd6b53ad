"""Part 5 of ``holo-bench billboard``: clouds against quadric levels in a crowd of small objects.

Where seed 004 uses billboard clouds: far away, many small objects.  A crowd of
``--crowd`` copies of one mesh (``--crowd-mesh``), each ``--crowd-sizes`` pixels
across (its bounding-box diagonal on screen), spread over the display on a jittered
grid, turned at random, is rendered in every zone (z-buffer, Blinn per polygon) as:

* the full meshes (the reference);
* every quadric level of the mesh's LOD chain (every copy at that level);
* billboard clouds at each ``--crowd-eps`` (percent of the diagonal) and
  ``--crowd-texture`` (texels across the diagonal).

Per render: CPU ms (median of ``--repeats``, all representations interleaved, one
renderer each; ``empty_ms``: the same for a frame without objects), ``colour_pct``:
% of all pixels whose colour differs from the reference's by more than
``service.lod.settings.COLOUR_LEVELS`` in any channel, ``coverage_pct``: % of all
pixels covered by one
render only, and ``differs_pct``: either.  Each cloud is
then matched with the quadric level of the same error: the cheapest level whose
``differs_pct`` is no more than the cloud's (the full mesh if none); ``cloud_vs_mesh``
is the cloud's CPU ms over that level's (above 1: the cloud costs more), and
``above_empty_vs_mesh`` the same above the empty frame's (what the objects cost).
"""

from __future__ import annotations

import time

import numpy as np

from service.bench.lod_bench import LIGHTS, MATERIAL
from service.billboard_render import BillboardObject
from service.display import DisplaySettings
from service.lod.cache import build_chain
from service.lod.settings import COLOUR_LEVELS, LodSettings
from service.render.light import LightSettings
from service.render.mesh import Mesh
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene, SceneObject, Transform, euler_quaternion, quaternion_matrix
from service.simplify.billboard import build_cloud

SETTINGS = RenderSettings(method="zbuffer", light=LightSettings("blinn", "polygon"))


def crowd_places(mesh: Mesh, n: int, size_px: float, display: DisplaySettings,
                 seed: int = 0) -> list[Transform]:
    """``n`` placements of ``mesh``, each ``size_px`` across, on a jittered grid over the display.

    Depths spread over [-0.5, 0.5] (the zones' parallax); orientations at random.
    """
    rng = np.random.default_rng(seed)
    lo, hi = mesh.vertices.min(axis=0), mesh.vertices.max(axis=0)
    s = size_px * display.pixel_size / (float(np.linalg.norm(hi - lo)) or 1.0)
    w, h = display.width, display.height
    gc = max(int(np.ceil(np.sqrt(n * w / h))), 1)
    gr = int(np.ceil(n / gc))
    places = []
    for k in range(n):
        cx = ((k % gc) + 0.5 + rng.uniform(-0.3, 0.3)) / gc
        cy = ((k // gc) + 0.5 + rng.uniform(-0.3, 0.3)) / gr
        q = euler_quaternion(*rng.uniform(-np.pi, np.pi, 3))
        centre = np.array([(cx - 0.5) * w * 0.95, (cy - 0.5) * h * 0.95, rng.uniform(-0.5, 0.5)])
        places.append(Transform(centre - quaternion_matrix(q) @ ((lo + hi) / 2) * s, q, s))
    return places


def _scene(level: object, kind: str, places: list[Transform]) -> Scene:
    """Every placement of ``level``: meshes, or billboard clouds when ``kind`` is ``cloud``."""
    if kind == "cloud":
        return Scene([], LIGHTS, 1.0,
                     billboards=[BillboardObject(level, MATERIAL, p) for p in places])
    return Scene([SceneObject(level, MATERIAL, p) for p in places], LIGHTS, 1.0)


def pixel_errors(ref, frame) -> dict:
    """% of all pixels differing from ``ref`` in colour (any channel), coverage, or either."""
    ca, cb = np.isfinite(ref.depth), np.isfinite(frame.depth)
    cover = ca != cb
    colour = (np.abs(ref.colour.astype(np.int16) - frame.colour).max(axis=-1) > COLOUR_LEVELS)
    return {"colour_pct": 100.0 * float(colour.mean()), "coverage_pct": 100.0 * float(cover.mean()),
            "differs_pct": 100.0 * float((colour | cover).mean())}


def _median_ms(scenes: list[Scene], display: DisplaySettings, repeats: int) -> tuple[list, list]:
    """Each scene's last frame and median CPU ms, the scenes interleaved (one renderer each)."""
    renderers = [Renderer() for _ in scenes]
    frames = [r.render(s, display, SETTINGS) for r, s in zip(renderers, scenes, strict=True)]
    times: list[list[float]] = [[] for _ in scenes]
    for _ in range(repeats):
        for k, (r, s) in enumerate(zip(renderers, scenes, strict=True)):
            c0 = time.process_time()
            frames[k] = r.render(s, display, SETTINGS)
            times[k].append((time.process_time() - c0) * 1e3)
    return frames, [float(np.median(t)) for t in times]


def _candidates(mesh: Mesh, eps_pct: list[float], textures: list[int]) -> list[dict]:
    """The full mesh, its chain's quadric levels and its clouds, as rows to fill."""
    chain = build_chain(mesh, LodSettings(cloud_eps=()))
    out = [{"kind": kind if k else "full", "level": k, "eps_pct": 0.0, "texture_res": 0,
            "triangles": int(chain.triangles[k]), "quads": 0, "_level": lv}
           for k, (lv, kind) in enumerate(zip(chain.levels, chain.kinds, strict=True))]
    diag = float(np.linalg.norm(mesh.vertices.max(axis=0) - mesh.vertices.min(axis=0)))
    for e in eps_pct:
        for res in textures:
            c = build_cloud(mesh.vertices, mesh.triangles, e / 100 * diag, res)
            out.append({"kind": "cloud", "level": -1, "eps_pct": e, "texture_res": res,
                        "triangles": 0, "quads": c.n_billboards, "_level": c})
    return out


def crowd_rows(mesh: Mesh, name: str, display: DisplaySettings, n: int, sizes: list[float],
               eps_pct: list[float], textures: list[int], repeats: int) -> list[dict]:
    """One row per size and representation (see the module doc), matches filled in."""
    cands = _candidates(mesh, eps_pct, textures)
    rows = []
    for px in sizes:
        places = crowd_places(mesh, n, px, display)
        scenes = [_scene(c["_level"], c["kind"], places) for c in cands]
        frames, ms = _median_ms([Scene([], LIGHTS, 1.0)] + scenes, display, repeats)
        here = [{"mesh": name, "objects": n, "size_px": px,
                 **{k: v for k, v in c.items() if not k.startswith("_")}, "cpu_ms": t,
                 "empty_ms": ms[0], **pixel_errors(frames[1], f)}
                for c, f, t in zip(cands, frames[1:], ms[1:], strict=True)]
        rows += match_clouds(here)
    return rows


def match_clouds(rows: list[dict]) -> list[dict]:
    """Give each cloud row the cheapest mesh level whose ``differs_pct`` is within the cloud's."""
    meshes = [r for r in rows if r["kind"] != "cloud"]
    for r in rows:
        if r["kind"] != "cloud":
            r.update(matched_level=r["level"], matched_ms=r["cpu_ms"], cloud_vs_mesh=np.nan,
                     above_empty_vs_mesh=np.nan)
            continue
        ok = [m for m in meshes if m["differs_pct"] <= r["differs_pct"]] or meshes[:1]
        best = min(ok, key=lambda m: m["cpu_ms"])
        r.update(matched_level=best["level"], matched_ms=best["cpu_ms"],
                 cloud_vs_mesh=r["cpu_ms"] / max(best["cpu_ms"], 1e-9),
                 above_empty_vs_mesh=(r["cpu_ms"] - r["empty_ms"])
                 / max(best["cpu_ms"] - best["empty_ms"], 1e-9))
    return rows


def chart(fig, rows: list[dict]) -> None:  # noqa: ANN001 (a matplotlib Figure)
    """One panel per size: CPU ms against % pixels differing; mesh levels a line, clouds stars."""
    sizes = list(dict.fromkeys(r["size_px"] for r in rows))
    axes = fig.subplots(1, len(sizes), squeeze=False)[0]
    for ax, px in zip(axes, sizes, strict=True):
        here = [r for r in rows if r["size_px"] == px]
        m = [r for r in here if r["kind"] != "cloud"]
        ax.plot([r["differs_pct"] for r in m], [r["cpu_ms"] for r in m], "o-", ms=3,
                label="full mesh and quadric levels")
        ax.plot([m[0]["differs_pct"]], [m[0]["cpu_ms"]], "ks", label="full mesh")
        for i, r in enumerate(r for r in here if r["kind"] == "cloud"):
            ax.plot([r["differs_pct"]], [r["cpu_ms"]], "*", ms=11, c=f"C{i + 1}",
                    label=f"cloud EPS {r['eps_pct']:g} %, texture {r['texture_res']} "
                    f"({r['cloud_vs_mesh']:.2f}x its mesh level)")
        ax.set(xlabel="% of all pixels differing (colour > 32 levels or coverage)",
               ylabel="CPU ms per frame", yscale="log",
               title=f"{here[0]['objects']} x {here[0]['mesh']}, {px:g} px across")
        ax.legend(fontsize=7)
