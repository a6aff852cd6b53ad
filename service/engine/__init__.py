"""The engine: renders and refreshes on two threads, no sockets (``docs/service.md``).

* :mod:`.engine` - :class:`~service.engine.engine.Engine`: the two threads, started
  and stopped together; the render service and the game's local mode both run one;
* :mod:`.state` - what the threads share: settings, the scene and its versions, the
  refresh clock, finished renders, counters;
* :mod:`.scheduler` - the render thread: renders aimed at rendezvous;
* :mod:`.refresh` - the refresh thread: the Galilean stage at the refresh rate;
* :mod:`.jobs` - one render job, as the engine and the worker processes make it;
* :mod:`.viewer` - the viewer's pose, filtered, and the zone it is in.

:mod:`service.net` is the transport around it: sockets, protocol, worker processes.
"""
