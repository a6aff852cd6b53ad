"""The ZeroMQ render service (``holo-service``; ``docs/service.md``, ``docs/protocol.md``).

* :mod:`.server` - :class:`~service.net.server.Service`: sockets, threads, shutdown;
* :mod:`.state` - configuration, display settings, shared state, counters, reply cache;
* :mod:`.handlers` - the request handlers, a table name -> handler over a state object;
* :mod:`.scheduler` - render scheduling: aim, dispatch, retry, the pipeline of workers;
* :mod:`.refresh` - the refresh thread (:class:`RefreshLoop`) and the viewer's pose;
* :mod:`.broker` and :mod:`.worker` - the LRU broker and the render worker processes;
* :mod:`.protocol` and :mod:`.wire` - messages and arrays on the wire;
* :mod:`.frame_stream` - the PUB frame stream; :mod:`.client` - the client library;
* :mod:`.curve_keys` - CurveZMQ keys.

The command is :mod:`service.commands.holo_service` (a CLI, the top layer).
"""
