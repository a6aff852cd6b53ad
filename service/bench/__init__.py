"""Benchmarks: time against error for every method with alternatives (not tests).

One module per benchmark, run by ``holo-bench NAME`` (:mod:`service.commands.holo_bench`):
render (with :mod:`.peers`, other engines timed beside ours), light, galilean (with
:mod:`.galilean_experiments`), service, filters, decoders, latency.  Each writes CSV
or JSON and matplotlib charts.
"""
