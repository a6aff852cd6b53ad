"""Simplified representations of meshes (issue 13 part B, seed 004).

=====================  ==========================================================
module                 what
=====================  ==========================================================
:mod:`.quadric`        quadric edge-collapse decimation (fast-simplification)
:mod:`.distance`       sampled surface-to-surface distance (the error in world units)
:mod:`.errors`         :class:`SimplifyError`
=====================  ==========================================================
"""
