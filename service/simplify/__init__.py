"""Simplified representations of meshes (issue 13 part B, seed 004).

=====================  ==========================================================
module                 what
=====================  ==========================================================
:mod:`.quadric`        quadric edge-collapse decimation (fast-simplification)
:mod:`.distance`       sampled surface-to-surface distance (the error in world units)
:mod:`.planes`         billboard clouds: greedy Hough-binned plane choice and merge
:mod:`.clip`           cutting faces by a plane's slab (the rim of a collapsed region)
:mod:`.rectangle`      minimal-area bounding rectangle (hull + rotating calipers)
:mod:`.billboard`      billboard clouds: planes, rectangles, texture shoot
:mod:`.cloud_file`     the ``.hbc`` billboard-cloud file (zip of .npy + header.json)
:mod:`.errors`         :class:`SimplifyError`
=====================  ==========================================================
"""
