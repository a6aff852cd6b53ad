"""Skipping to a sync marker and counting what is skipped: the framed decoders' scan.

The Hatire and native decoders look for their frames' first bytes (``AA AA``,
``A5 5A``) and throw away what lies before them.  :class:`SyncScan` does that and
keeps the counts every decoder keeps (``stats.bytes_discarded``, ``stats.resyncs``):
a run of skipped bytes, however it was chunked, is one resync, ended by
:meth:`SyncScan.end_run` when the next frame (or the end of input) comes.
"""

from __future__ import annotations

from drivers.events import DecoderStats


class SyncScan:
    """Finds ``sync`` in a buffer, dropping and counting the bytes before it.

    Parameters
    ----------
    sync : bytes
        The marker a frame starts with.
    stats : DecoderStats
        The decoder's counters (``bytes_discarded``, ``resyncs`` are kept here).

    Attributes
    ----------
    run : int
        Bytes dropped since the last frame (the current run).
    """

    def __init__(self, sync: bytes, stats: DecoderStats) -> None:
        self.sync = sync
        self.stats = stats
        self.run = 0

    def drop(self, count: int) -> None:
        """Count ``count`` bytes as thrown away (nothing for ``count <= 0``)."""
        if count > 0:
            self.run += count
            self.stats.bytes_discarded += count

    def end_run(self) -> int:
        """The bytes of the run just ended (one resync), or 0 when none were dropped."""
        run = self.run
        if run:
            self.stats.resyncs += 1
            self.run = 0
        return run

    def next_sync(self, buf: bytearray, pos: int) -> tuple[int, bool]:
        """Skip from ``pos`` to the next sync marker in ``buf``.

        Returns
        -------
        index : int
            Where the marker starts; when there is none, where the bytes kept for
            the next feed start (a last byte that may begin a marker split across
            two feeds is kept, every other byte dropped).
        found : bool
            Whether a marker was found.
        """
        j = buf.find(self.sync, pos)
        if j >= 0:
            self.drop(j - pos)
            return j, True
        n = len(buf)
        keep = 1 if n > pos and buf[-1] == self.sync[0] else 0
        self.drop(n - keep - pos)
        return n - keep, False
