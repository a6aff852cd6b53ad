"""Where a stereogram's depth comes from: a depth ``.npy`` or the centre view of a scene.

A scene (a ``.hobj``/``.ply``/``.obj``/``.toml`` file or ``builtin:NAME``, what
``holo-render`` takes) is rendered in one view zone straight on (the centre view),
and its depth map is used.  A ``.npy`` must hold a 2-D float depth map as
``holo-render`` writes it; ``size`` resamples it (nearest) when it differs.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from service.base.errors import SettingsError
from service.builtin_scenes import builtin_scene
from service.display import DisplaySettings
from service.loaders import load_scene
from service.npy_file import read_npy_file
from service.render.pipeline import Renderer, RenderSettings
from service.render.scene import Scene


def centre_depth(scene: Scene, cols: int, rows: int) -> np.ndarray:
    """Depth of the straight-on view of a scene, shape (rows, cols) float32."""
    display = DisplaySettings(zones=1, angle_deg=0.0, cols=cols, rows=rows)
    return Renderer().render(scene, display, RenderSettings()).depth[0]


def resample(depth: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """Nearest-neighbour resample of a (H, W) map to (rows, cols)."""
    h, w = depth.shape
    if (h, w) == (rows, cols):
        return depth
    r = np.arange(rows) * h // rows
    c = np.arange(cols) * w // cols
    return np.ascontiguousarray(depth[r][:, c])


def read_depth_npy(path: Path) -> np.ndarray:
    """A 2-D float depth map from ``.npy`` (no pickles), or :class:`SettingsError`."""
    try:
        with open(path, "rb") as fh:
            magic = fh.read(6)
    except OSError as exc:
        raise SettingsError(f"{path}: cannot read the file: {exc.strerror}") from None
    if magic != b"\x93NUMPY":  # else numpy's error talks of pickles
        raise SettingsError(f"{path}: not a .npy file (no NUMPY header)")
    try:
        d = read_npy_file(path)
    except ValueError as exc:
        raise SettingsError(f"{path}: not a depth map .npy ({exc})") from None
    except OSError as exc:
        raise SettingsError(f"{path}: cannot read the file: {exc.strerror}") from None
    if d.ndim != 2 or d.dtype.kind not in "fiu":
        raise SettingsError(f"{path}: want a 2-D numeric depth map, got {d.shape} {d.dtype}")
    if d.size == 0:
        raise SettingsError(f"{path}: depth map is empty ({d.shape[1]}x{d.shape[0]})")
    return d.astype(np.float32)


def load_depth(spec: str, size: tuple[int, int] | None, default_size: tuple[int, int]
               ) -> np.ndarray:
    """The depth map an input names.

    Parameters
    ----------
    spec : str
        A ``.npy`` path, a scene or mesh file, or ``builtin:NAME``.
    size : (cols, rows) or None
        Wanted size; None keeps a ``.npy``'s own and renders scenes at ``default_size``.
    default_size : (cols, rows)

    Returns
    -------
    ndarray, shape (rows, cols), float32
    """
    if spec.lower().endswith(".npy"):
        d = read_depth_npy(Path(spec))
        return d if size is None else resample(d, *size)
    cols, rows = size or default_size
    scene = builtin_scene(spec.split(":", 1)[1]) if spec.startswith("builtin:") else \
        load_scene(Path(spec))
    return centre_depth(scene, cols, rows)
