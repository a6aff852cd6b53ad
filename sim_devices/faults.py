"""Fault injection between a simulated device's frames and its endpoint (seeded).

A :class:`FaultInjector` turns each encoded frame into a list of actions
(:class:`Write`, :class:`Pause`, :class:`Disconnect`), drawing from one seeded
``random.Random`` so that a run is exactly reproducible, and keeps a
:class:`FaultLedger`: what was done to which frame, and which frames went out
byte-for-byte intact.  Tests compare a decoder's output with the ledger
("every intact frame recovered, none invented").

Fault classes (per-frame probabilities 0..1 unless noted):

============  ===================================================================
corrupt       one byte of the frame xor-ed with a non-zero value
drop          1-3 bytes removed from the frame
truncate      the frame cut to 2..len-1 bytes (its tail never sent)
burst         after the frame, ``burst_len`` (min, max) random bytes
wrong_baud    the frame replaced by what a receiver at the wrong rate would see
              (``baud_ratio``, default 12 = 115200 sent, 9600 read)
split         (flag) every write split into pieces of 1..``max_split`` bytes
pause         after the frame, ``pause_s`` of silence
disconnect    after the frame, the link drops for ``reconnect_s`` seconds
============  ===================================================================

Only one of corrupt / drop / truncate / wrong_baud is applied to a frame (drawn in
that order); burst, pause and disconnect come after it independently.
"""

from __future__ import annotations

import math
import random
from collections import Counter
from dataclasses import dataclass, field, fields

from service.base.errors import SettingsError

DAMAGE = ("corrupt", "drop", "truncate", "wrong_baud")
AFTER = ("burst", "pause", "disconnect")


@dataclass(frozen=True)
class Write:
    """Write these bytes."""

    data: bytes


@dataclass(frozen=True)
class Pause:
    """Send nothing for ``seconds``."""

    seconds: float


@dataclass(frozen=True)
class Disconnect:
    """Drop the link, come back after ``seconds``."""

    seconds: float


Action = Write | Pause | Disconnect


@dataclass(frozen=True)
class FaultSpec:
    """Which faults, how often, and the seed (see module docstring)."""

    corrupt: float = 0.0
    drop: float = 0.0
    truncate: float = 0.0
    wrong_baud: float = 0.0
    burst: float = 0.0
    pause: float = 0.0
    disconnect: float = 0.0
    split: bool = False
    burst_len: tuple[int, int] = (4, 40)
    max_split: int = 16
    pause_s: float = 0.05
    reconnect_s: float = 0.2
    baud_ratio: float = 12.0
    seed: int = 0

    def __post_init__(self) -> None:
        for name in DAMAGE + AFTER:
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise SettingsError(f"fault probability {name} must be in 0..1")
        if sum(getattr(self, n) for n in DAMAGE) > 1.0:
            raise SettingsError("corrupt + drop + truncate + wrong_baud must be <= 1")
        if self.max_split < 1 or not 0 < self.burst_len[0] <= self.burst_len[1]:
            raise SettingsError("max_split >= 1 and 0 < burst_len min <= max needed")
        for name in ("pause_s", "reconnect_s"):  # inf: a run that never resumes
            if not 0.0 <= getattr(self, name) < math.inf:
                raise SettingsError(f"fault {name} must be a finite number of seconds >= 0")
        if not 0.0 < self.baud_ratio < math.inf:  # 0: a reader that samples one bit
            raise SettingsError("fault baud_ratio must be a finite number > 0")

    @classmethod
    def parse(cls, text: str) -> FaultSpec:
        """From ``"corrupt=0.02,burst=0.01,split,seed=3"`` (empty: no faults)."""
        kinds = {f.name: f.type for f in fields(cls)}
        opts: dict[str, object] = {}
        for item in filter(None, (s.strip() for s in text.split(","))):
            key, sep, value = item.partition("=")
            if key not in kinds:
                raise SettingsError(f"unknown fault {key!r}; known: {', '.join(kinds)}")
            if key in opts:  # the later one would silently win
                raise SettingsError(f"fault {key} given twice in {text!r}")
            opts[key] = _convert(key, value if sep else "1")
        return cls(**opts)

    @property
    def any(self) -> bool:
        """True when some fault is switched on."""
        return self.split or any(getattr(self, n) for n in DAMAGE + AFTER)


def _convert(key: str, value: str) -> object:
    try:
        if key == "burst_len":
            lo, _, hi = value.partition("-")
            return (int(lo), int(hi or lo))
        if key in ("seed", "max_split"):
            return int(value)
        if key == "split":
            return value not in ("0", "false", "no")
        return float(value)
    except ValueError:
        what = "a count or a LO-HI range" if key == "burst_len" else "a number"
        raise SettingsError(f"fault {key}={value!r} is not {what}") from None


@dataclass
class FaultLedger:
    """What the injector did.

    Attributes
    ----------
    counts : Counter
        Fault name -> times applied (``split`` counts writes split).
    intact : list of int
        Indices of frames sent byte-for-byte intact.
    damaged : dict
        Frame index -> ``(fault, detail)``: corrupt -> byte position, drop -> bytes
        removed, truncate -> bytes kept, wrong_baud -> bytes sent instead.
    burst_bytes : int
        Garbage bytes sent in bursts.
    frames : int
        Frames seen.
    """

    counts: Counter = field(default_factory=Counter)
    intact: list[int] = field(default_factory=list)
    damaged: dict[int, tuple[str, int]] = field(default_factory=dict)
    burst_bytes: int = 0
    frames: int = 0


def wrong_baud_bytes(data: bytes, ratio: float) -> bytes:
    """What a UART reading at ``1/ratio`` of the sender's rate makes of ``data`` (8N1).

    ``ratio`` is the receiver's bit time in sender bit times (12 = sent at 115200,
    read at 9600).  The receiver waits for a start bit, samples eight data bits at
    their middles and skips the stop bit, as a real UART does.
    """
    bits: list[int] = []
    for b in data:
        bits += [0, *((b >> i) & 1 for i in range(8)), 1]
    n = len(bits)
    out = bytearray()
    i = 0
    while True:
        while i < n and bits[i]:
            i += 1
        if i >= n:
            return bytes(out)
        val = 0
        for k in range(8):
            p = int(i + (1.5 + k) * ratio)
            val |= (bits[p] if p < n else 1) << k
        out.append(val)
        i = max(i + 1, math.ceil(i + 9.5 * ratio))


class FaultInjector:
    """Applies a :class:`FaultSpec` to frames; deterministic for a given seed."""

    def __init__(self, spec: FaultSpec | None = None) -> None:
        self.spec = spec or FaultSpec()
        self.ledger = FaultLedger()
        self._rng = random.Random(self.spec.seed)
        self._damage = {"corrupt": self._corrupt, "drop": self._drop,
                        "truncate": self._truncate, "wrong_baud": self._wrong_baud}

    def apply(self, frame: bytes) -> list[Action]:
        """Actions that send ``frame`` through the faults."""
        spec, rng, led = self.spec, self._rng, self.ledger
        index = led.frames
        led.frames += 1
        data, damage = frame, self._pick_damage(rng.random())
        if damage:
            data, detail = self._damage[damage](frame)
            led.counts[damage] += 1
            led.damaged[index] = (damage, detail)
        else:
            led.intact.append(index)
        actions = self._writes(data)
        if rng.random() < spec.burst:
            led.counts["burst"] += 1
            size = rng.randint(*spec.burst_len)
            led.burst_bytes += size
            actions += self._writes(bytes(rng.randrange(256) for _ in range(size)))
        if rng.random() < spec.pause:
            led.counts["pause"] += 1
            actions.append(Pause(spec.pause_s))
        if rng.random() < spec.disconnect:
            led.counts["disconnect"] += 1
            actions.append(Disconnect(spec.reconnect_s))
        return actions

    def _pick_damage(self, u: float) -> str:
        for name in DAMAGE:
            p = getattr(self.spec, name)
            if u < p:
                return name
            u -= p
        return ""

    def _writes(self, data: bytes) -> list[Action]:
        if not self.spec.split or len(data) <= 1:
            return [Write(data)] if data else []
        self.ledger.counts["split"] += 1
        out: list[Action] = []
        pos = 0
        while pos < len(data):
            size = self._rng.randint(1, self.spec.max_split)
            out.append(Write(data[pos:pos + size]))
            pos += size
        return out

    def _corrupt(self, frame: bytes) -> tuple[bytes, int]:
        raw = bytearray(frame)
        pos = self._rng.randrange(len(raw))
        raw[pos] ^= self._rng.randrange(1, 256)
        return bytes(raw), pos

    def _drop(self, frame: bytes) -> tuple[bytes, int]:
        raw = bytearray(frame)
        count = min(self._rng.randint(1, 3), len(raw) - 1)
        for _ in range(count):
            del raw[self._rng.randrange(len(raw))]
        return bytes(raw), count

    def _truncate(self, frame: bytes) -> tuple[bytes, int]:
        kept = self._rng.randint(min(2, len(frame) - 1), len(frame) - 1)
        return frame[:kept], kept

    def _wrong_baud(self, frame: bytes) -> tuple[bytes, int]:
        data = wrong_baud_bytes(frame, self.spec.baud_ratio)
        return data, len(data)
