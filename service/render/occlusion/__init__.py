"""Stage 4: occlusion (hidden-surface removal) for every view zone, selectable by name.

Every method returns a :class:`Visibility`: for each zone and pixel, the triangle
seen there and its depth.  Shading (:mod:`service.render.light`) turns that into colour, so
methods differ only in which surface each pixel shows, and can be compared pixel
for pixel against the ``raycast`` reference.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Visibility:
    """Per-zone visibility buffer.

    Attributes
    ----------
    triangle : ndarray, shape (Z, R, C), int32
        Index into ``SceneArrays.triangles`` of the surface seen, -1 where empty.
    depth : ndarray, shape (Z, R, C), float32
        Depth (-z) of that surface, +inf where empty.
    stats : dict
        Method-specific counters (e.g. ``{"inconsistent_pixels": 0}``).
    shown : ndarray, shape (Z, P), bool, optional
        Which polygons each zone shows, when the pipeline has already found them
        (:func:`service.render.light.mark_shown`); the light stage then skips that pass.
        None otherwise.
    """

    triangle: np.ndarray
    depth: np.ndarray
    stats: dict = field(default_factory=dict)
    shown: np.ndarray | None = None

    @classmethod
    def empty(cls, zones: int, rows: int, cols: int) -> Visibility:
        """An all-empty buffer."""
        return cls(
            np.full((zones, rows, cols), -1, np.int32),
            np.full((zones, rows, cols), np.inf, np.float32),
        )
