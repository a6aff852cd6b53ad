"""Display model: view zones across a viewing angle, hololines as rows.

The display plane is z = 0, ``width`` world units wide, centred on the origin, with
``cols`` x ``rows`` square pixels; row 0 is the top hololine.  The viewing angle is
split into ``zones`` equal view zones; zone k looks along the direction

    theta_k = angle * ((k + 0.5) / zones - 0.5)        (radians, about the y axis)

so 5 zones across 16 degrees have centres at -6.4, -3.2, 0, 3.2 and 6.4 degrees and
zone 0 is the leftmost viewer position (x < 0).  The display has horizontal parallax
only, like Holo-video: each zone is an *off-axis (sheared) parallel projection*
along its direction, not a rotated camera.  A world point (x, y, z) lands on the
display plane at

    X = x - z * tan(theta_k),   Y = y

and on the pixel grid at ``sx = (X + width/2) / s``, ``sy = (height/2 - Y) / s``
(``s = width / cols``, pixel centres at integer + 0.5).  Its depth is ``-z``: the
distance behind the display plane, smaller is nearer, ``+inf`` where nothing is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from service.base.errors import SettingsError

#: Most pixels of all zones together (zones x cols x rows): 64 zones of 1024x1024, or one
#: of 8192x8192.  Frames of this size take a few GB; 64 zones of 8192x8192 asked
#: holo-render for a 16 GiB buffer first, and a MemoryError was its answer.
MAX_PIXELS = 64 * 1024 * 1024


@dataclass(frozen=True)
class DisplaySettings:
    """The multi-view display.

    Attributes
    ----------
    zones : int
        Number of view zones, 1 to 64 (thesis: 5).
    angle_deg : float
        Total viewing angle in degrees, 0 to 60 (thesis: 16).
    cols, rows : int
        Pixels per hololine and number of hololines.
    width : float
        Width of the display plane in world units (height follows from square pixels).
    """

    zones: int = 5
    angle_deg: float = 16.0
    cols: int = 320
    rows: int = 240
    width: float = 2.0

    def __post_init__(self) -> None:
        if not (isinstance(self.zones, int | np.integer) and 1 <= self.zones <= 64):
            raise SettingsError(f"zones must be an integer from 1 to 64, got {self.zones!r}")
        if not (0.0 <= float(self.angle_deg) <= 60.0):
            raise SettingsError(f"viewing angle must be 0 to 60 degrees, got {self.angle_deg}")
        if not (1 <= self.cols <= 8192 and 1 <= self.rows <= 8192):
            raise SettingsError(
                f"display size must be 1..8192 each way, got {self.cols}x{self.rows}"
            )
        if self.zones * self.cols * self.rows > MAX_PIXELS:
            raise SettingsError(
                f"{self.zones} zones of {self.cols}x{self.rows} are "
                f"{self.zones * self.cols * self.rows:,} pixels (at most {MAX_PIXELS:,})"
            )
        if not (np.isfinite(self.width) and self.width > 0):
            raise SettingsError(f"display width must be > 0, got {self.width}")

    @property
    def pixel_size(self) -> float:
        """World units per pixel (square pixels)."""
        return self.width / self.cols

    @property
    def height(self) -> float:
        """Height of the display plane in world units."""
        return self.rows * self.pixel_size

    def zone_angles(self) -> np.ndarray:
        """Zone centre directions in radians, shape (zones,)."""
        k = np.arange(self.zones)
        return np.radians(self.angle_deg) * ((k + 0.5) / self.zones - 0.5)

    def view_vectors(self) -> np.ndarray:
        """Unit vectors from the display toward each zone's viewer, shape (zones, 3)."""
        th = self.zone_angles()
        return np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=1)

    def shears(self) -> np.ndarray:
        """tan(theta_k) for each zone, shape (zones,)."""
        return np.tan(self.zone_angles())


def parse_size(text: str) -> tuple[int, int]:
    """Parse ``"WxH"`` into (cols, rows); raise :class:`SettingsError` if malformed."""
    try:
        w, h = text.lower().split("x")
        return int(w), int(h)
    except ValueError:
        raise SettingsError(f"size must look like 320x240, got {text!r}") from None
