"""The mesh loaders' warm-up job (:mod:`service.warmup` runs it): a file repaired."""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

from service.loaders import load_scene
from service.warmup_job import HERE, Job, Kit

#: A mesh file with a concave and a non-planar polygon: loading repairs both by
#: ear-clipping (``service.mesh_repair``), as a user's mesh would be.
_OBJ = """v 0 0 0
v 1 0 0
v 1 1 0
v 0.5 0.3 0
v 0 1 0
v 2 0 0
v 3 0 0.4
v 3 1 0
v 2 1 0.3
f 1 2 3 4 5
f 6 7 8 9
"""


def _mesh_files(kit: Kit) -> None:
    """A mesh file loaded as the service loads one (repair: ear-clipping)."""
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the repair's own warning
        path = Path(tmp) / "warmup.obj"
        path.write_text(_OBJ)
        load_scene(path).flatten()


#: This subsystem's jobs, in order (:data:`service.warmup.JOBS` gathers them).
WARMUP_JOBS: dict[str, Job] = {
    "mesh files: repair": Job(_mesh_files, HERE),
}
