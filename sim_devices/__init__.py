"""Simulated devices that speak the real protocols, for tests and the demo.

:mod:`.tracker` (Hatire or native head tracker), :mod:`.dialbox` (SGI dial and button
box), :mod:`.motion` (head motions), :mod:`.faults` (seeded fault injection),
:mod:`.endpoints` (loop://, pty and TCP links and the device runner); the command is
:mod:`.cli` (``holo-sim``).
"""
