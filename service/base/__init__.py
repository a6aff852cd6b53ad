"""The base layer: what every package may import and which imports nothing of ours.

:mod:`.errors` (the one exception hierarchy), :mod:`.signals` (the exit rule),
:mod:`.heap` (the allocator knob), :mod:`.addresses` and :mod:`.cli_args` (address
and argparse types).  Drivers, simulated devices, the service and the game build on
these; ``tests/test_layers.py`` checks that they import nothing else of ours.
"""
