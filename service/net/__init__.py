"""The ZeroMQ render service around the engine (``holo-service``; ``docs/service.md``).

The render and refresh threads are :mod:`service.engine`'s; this package is their
transport: sockets, the protocol (``docs/protocol.md``), worker processes.

* :mod:`.server` - :class:`~service.net.server.Service`: sockets, threads, shutdown;
* :mod:`.state` - configuration, the service's state (the engine's and its sockets), reply cache;
* :mod:`.handlers` - the request handlers, a table name -> handler over a state object;
* :mod:`.scheduler` - the engine's render thread with the workers: dispatch, retry, pipeline;
* :mod:`.refresh` - the engine's refresh thread with the devices and the frame stream;
* :mod:`.broker` and :mod:`.worker` - the LRU broker and the render worker processes;
* :mod:`.protocol` and :mod:`.wire` - messages and arrays on the wire;
* :mod:`.frame_stream` - the PUB frame stream; :mod:`.client` - the client library;
* :mod:`.curve_keys` - CurveZMQ keys.

The command is :mod:`service.commands.holo_service` (a CLI, the top layer).
"""
