"""A level-of-detail chain built in a child process of its own (no GIL shared with renders).

:class:`service.lod.ChainBuilds` runs ``python -m service.lod_build MESH.npz FOLDER
RECIPE.json PARENT_PID`` for a chain not in the cache: the mesh's arrays come in a numpy file
(``vertices``, ``polygons``, ``counts``; read with ``allow_pickle=False``), the
chain's settings as JSON (``fractions``, ``cloud_eps``, ``texture_res``, ``name``),
and the chain goes into the cache folder (:func:`service.lod.build_chain`, which
takes its lock file), where the parent reads it.  Quadric decimation
(fast-simplification) holds the GIL for 20-40 ms a call on the bunny: in a thread of
the rendering process it stalled renders and the service's refreshes by as much.

The protocol to the parent, on stdout, one line each: ``note: TEXT`` for what went
wrong with the cache (it was rebuilt), then ``levels: N``.  A build that fails says
why in one line on stderr and exits 1.  Nothing here is for users to run.
"""

from __future__ import annotations

import json
import os
import signal
import sys
from pathlib import Path

import numpy as np

from service.lod import BUILD_NICE, LodSettings, build_chain
from service.mesh import Mesh
from service.signals import end_with_parent


def main(argv: list[str] | None = None) -> int:
    """Build one chain into the cache; see the module notes."""
    args = sys.argv[1:] if argv is None else argv
    if len(args) > 3:
        # a service stopped mid-build would otherwise leave its build running
        end_with_parent(int(args[3]), signal.SIGTERM)
    try:
        mesh_file, folder, recipe = Path(args[0]), Path(args[1]), json.loads(args[2])
        os.nice(BUILD_NICE)  # renders come first
        with np.load(mesh_file, allow_pickle=False) as data:
            mesh = Mesh(data["vertices"], data["polygons"], data["counts"],
                        str(recipe.get("name", "mesh")))
        settings = LodSettings(fractions=tuple(recipe["fractions"]),
                               cloud_eps=tuple(recipe["cloud_eps"]),
                               texture_res=int(recipe["texture_res"]))
        notes: list[str] = []
        chain = build_chain(mesh, settings, folder, notes=notes)
    except Exception as exc:  # noqa: BLE001 - one line to the parent, whatever it was
        print(f"{type(exc).__name__}: {exc}"[:300].replace("\n", " "), file=sys.stderr)
        return 1
    for note in notes:
        print("note: " + note.replace("\n", " "))
    print(f"levels: {len(chain.levels)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
