"""The render pipeline (seed 000), one module per stage, in order.

:mod:`.scene` and :mod:`.mesh` (the model) -> :mod:`.projection` (1) -> :mod:`.cull` (2)
-> :mod:`.depth_sort` (3) -> :mod:`.occlusion` with :mod:`.raster` (4) -> :mod:`.light`
(5) -> :mod:`.frame` (6); :mod:`.pipeline` wires them (``Renderer``, ``RenderSettings``).
"""
