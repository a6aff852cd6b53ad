"""Autostereograms (seed 001, and Thimbleby, Inglis and Witten 1994): SIRDs from depth.

Modules: :mod:`.geometry` (depth to ``z``, the separation ``s(z)``, the settings),
:mod:`.patterns` (seeded random dots, image tiles), one kernel module per method:
:mod:`.row` (the seed's software algorithm), :mod:`.interpolated` (the seed's hardware
variant on the CPU), :mod:`.tiw` (symmetric constraints with hidden-surface removal),
:mod:`.stage` (the stage function and its reusable buffers) and :mod:`.decode` (a
separation decoder, its accuracy, streak counts).  See ``docs/autostereogram.md``.
"""

from service.autostereogram.geometry import (
    SirdSettings,
    default_eye_sep,
    depth_to_z,
    finite_range,
    separation_map,
)
from service.autostereogram.patterns import make_pattern, random_dots
from service.autostereogram.stage import (
    METHODS,
    SirdStats,
    SirdWorkspace,
    broken_constraints,
    stereogram,
)

__all__ = [
    "SirdSettings", "default_eye_sep", "depth_to_z", "finite_range", "separation_map",
    "make_pattern", "random_dots", "METHODS", "SirdStats", "SirdWorkspace",
    "broken_constraints", "stereogram",
]
