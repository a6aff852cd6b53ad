"""The Galilean stage (seed 002): galpixmaps propagated at the refresh rate between renders.

Modules: :mod:`.fixed_point` (bit budget, arithmetic), :mod:`.galpixmap` (SoA maps),
:mod:`.motion_field` (apparent motion from the renderer), :mod:`.propagate` (the
one-pass scatter), :mod:`.poisson` (test and expansion), :mod:`.local_update`
(Flinders Street buffers, use-by dates, priorities), :mod:`.head_motion` (viewer
motion), and :mod:`.stage` (the object the service drives).  The paper's thought experiments
are in :mod:`service.bench.galilean_experiments`.  See ``docs/galilean.md``.
"""

from service.galilean.fixed_point import BitBudget, FixedPoint, bit_budget
from service.galilean.galpixmap import GalileanError, Galpixmap
from service.galilean.stage import GalileanSettings, GalileanStage, Refresh

__all__ = [
    "BitBudget", "FixedPoint", "bit_budget", "Galpixmap", "GalileanError",
    "GalileanSettings", "GalileanStage", "Refresh",
]
