"""The render service package: three subsystems in one package, plus shared base modules.

* **Render pipeline** (seed 000): :mod:`.render` (its stages in order, one module
  each; :mod:`.render.pipeline` wires them), fed by :mod:`.primitives`,
  :mod:`.builtin_scenes` (built-in scenes by name) and :mod:`.loaders` (files), with
  :mod:`.png` for pictures; :mod:`.display` is the display model (zones, hololines);
  :mod:`.frame_settings` everything a frame is made with; :mod:`.scene_motion` moves a
  scene in time; :mod:`.normals_kernel`.
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
