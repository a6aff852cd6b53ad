"""Device drivers: serial byte protocols, readers, filters, recording and replay.

:mod:`.protocols` (pure codecs) and :mod:`.events` (what they produce) are the bottom;
:mod:`.reader` (one thread per serial device), :mod:`.tracker_driver` and
:mod:`.dialbox_driver` (host commands), :mod:`.filters` (pose filtering and
prediction), :mod:`.publisher` and :mod:`.subscriber` (events over ZeroMQ),
:mod:`.recording` and :mod:`.replay_clock` (session logs), :mod:`.pty_link` (a pty
pair as a serial port); commands in :mod:`.commands` (``holo-devices``,
``holo-replay``, ``holo-view``).  See ``docs/drivers.md``.
"""
