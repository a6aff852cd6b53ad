"""Everything a frame is made with, as one value (:class:`FrameSettings`).

The display, the render options (the pipeline's own
:class:`~service.render.pipeline.RenderSettings`: method, cull, light, painter
fallback, level of detail), the Galilean stage's order and refresh rate, the
encodings a frame carries, the autostereogram's and the quality choice: their
defaults live here and in the types it holds, nowhere else.  The service's state
(:class:`service.engine.state.Settings`, which adds a generation count) and the game's
backends hold one; :mod:`service.net.settings_wire` carries it on the wire.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from service.display import DisplaySettings
from service.render.pipeline import RenderSettings


@dataclass(frozen=True)
class FrameSettings:
    """What every frame of a display is made with.

    Attributes
    ----------
    display : DisplaySettings
        Zones, viewing angle, pixels per zone, width.
    render : RenderSettings
        The render options (occlusion method, cull, light, painter fallback, LOD).
    galpixel_order : int
        Order of the Galilean stage's galpixels, 0 to 3.
    refresh_hz : float
        Refreshes a second.
    encodings : tuple of str
        The arrays a frame carries (``colour``, ``depth``, ``debris``, ``autostereogram``).
    sird_method : str
        The autostereogram's method (``tiw``, ``row``, ``interpolated``).
    sird_eye_sep : float
        The autostereogram's eye separation in pixels; 0: its default for the width.
    quality : str
        ``fixed`` (as set) or ``auto`` (each render's method and light evaluation
        chosen within ``max_error``; :mod:`service.quality`).
    max_error : str
        The ``auto`` budget: ``"0.5%"`` of pixels wrong, or ``"40dB"``.
    """

    display: DisplaySettings = field(default_factory=DisplaySettings)
    render: RenderSettings = field(default_factory=RenderSettings)
    galpixel_order: int = 2
    refresh_hz: float = 60.0
    encodings: tuple[str, ...] = ("colour", "depth")
    sird_method: str = "tiw"
    sird_eye_sep: float = 0.0
    quality: str = "fixed"
    max_error: str = "0.5%"
