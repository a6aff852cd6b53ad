"""The render service package: three subsystems in one package, plus shared base modules.

* **Render pipeline** (seed 000), stages in order: :mod:`.scene`, :mod:`.mesh`,
  :mod:`.primitives`, :mod:`.builtin_scenes` (built-in scenes by name), :mod:`.loaders`
  (files) -> :mod:`.projection` (1) -> :mod:`.cull` (2) -> :mod:`.depth_sort` (3) ->
  :mod:`.occlusion` with :mod:`.raster` (4) -> :mod:`.light` (5) -> :mod:`.frame`,
  :mod:`.png` (6); :mod:`.pipeline` wires them; :mod:`.display` is the display model
  (zones, hololines); :mod:`.scene_motion` moves a scene in time; :mod:`.normals_kernel`.
* **Galilean stage** (seed 002): :mod:`.galilean`.
* **ZeroMQ render service**: :mod:`.server` (sockets, handlers, refresh loop),
  :mod:`.broker` and :mod:`.worker` (render processes), :mod:`.protocol` and
  :mod:`.wire` (messages and arrays), :mod:`.frame_stream`, :mod:`.client` (the client
  library), :mod:`.curve_keys` (CurveZMQ keys).
* **Base** (imported by every package; imports nothing above it): :mod:`.errors`,
  :mod:`.signals`, :mod:`.heap`, :mod:`.addresses`, :mod:`.cli_args`.
* **Commands and benchmarks**: ``cli_*.py``, :mod:`.demo`, :mod:`.bench`.

The layers are in README.md ("Layout") and checked by ``tests/test_layers.py``.
"""
