"""The render service package: three subsystems in one package, plus shared base modules.

* **Render pipeline** (seed 000), stages in order: :mod:`.scene`, :mod:`.mesh`,
  :mod:`.primitives`, :mod:`.builtin_scenes` (built-in scenes by name), :mod:`.loaders`
  (files) -> :mod:`.projection` (1) -> :mod:`.cull` (2) -> :mod:`.depth_sort` (3) ->
  :mod:`.occlusion` with :mod:`.raster` (4) -> :mod:`.light` (5) -> :mod:`.frame`,
  :mod:`.png` (6); :mod:`.pipeline` wires them; :mod:`.display` is the display model
  (zones, hololines); :mod:`.scene_motion` moves a scene in time; :mod:`.normals_kernel`.
* **Galilean stage** (seed 002): :mod:`.galilean`.
* **ZeroMQ render service**: :mod:`.net` (server, state, request handlers, render
  scheduler, refresh loop, broker and workers, protocol and wire, frame stream, client
  library, CurveZMQ keys; its ``__init__`` lists them).
* **Base** (imported by every package; imports nothing above it): :mod:`.errors`,
  :mod:`.signals`, :mod:`.heap`, :mod:`.addresses`, :mod:`.cli_args`.
* **Level of detail**: :mod:`.lod`; **simplification**: :mod:`.simplify`.
* **Commands and benchmarks**: :mod:`.commands` (one module per console script),
  :mod:`.bench`.

The layers are in README.md ("Layout") and checked by ``tests/test_layers.py``.
"""
