"""High scores in a JSON file, written atomically and never lost.

File layout (UTF-8 JSON)::

    {"version": 1, "scores": [{"name": "bot", "score": 1234, "seconds": 98.7,
                               "difficulty": "normal", "when": "2026-11-22T03:14:07Z"}, ...]}

Best first, at most :data:`KEEP` entries.  Saving writes a temporary file in the
same folder, flushes and fsyncs it, then ``os.replace`` puts it in place, so a
crash leaves either the old table or the new one, never half of one.  A file that
cannot be read as this layout is not overwritten: it is copied to
``<name>.corrupt-<n>`` first and :class:`HighScoreFileError` names the copy;
:meth:`HighScores.load` with ``recover=True`` then starts an empty table.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from service.base.errors import HoloError

KEEP = 10
VERSION = 1



class HighScoreFileError(HoloError, ValueError):
    """The high-score file is unreadable; ``backup`` is where a copy was kept."""

    def __init__(self, path: Path, reason: str, backup: Path | None) -> None:
        self.path, self.reason, self.backup = path, reason, backup
        kept = f"; a copy was kept at {backup}" if backup else ""
        super().__init__(f"high-score file {path} is unreadable ({reason}){kept}")


@dataclass
class HighScores:
    """A high-score table bound to a file.

    Attributes
    ----------
    path : Path
    scores : list of dict
        Best first.
    recovered_from : HighScoreFileError or None
        Set when :meth:`load` replaced a corrupt file's table with an empty one.
    """

    path: Path
    scores: list[dict] = field(default_factory=list)
    recovered_from: HighScoreFileError | None = None

    @classmethod
    def load(cls, path: str | Path, recover: bool = False) -> HighScores:
        """Read the table (a missing file is an empty table).

        Parameters
        ----------
        path : str or Path
        recover : bool
            On a corrupt file, back it up and return an empty table instead of
            raising.

        Raises
        ------
        HighScoreFileError
            For a corrupt file (after it was backed up), unless ``recover``.
        """
        p = Path(path)
        try:
            return cls(p, _parse(p))
        except FileNotFoundError:
            return cls(p, [])
        except (ValueError, OSError) as exc:
            err = HighScoreFileError(p, str(exc), _backup(p))
            if not recover:
                raise err from exc
            return cls(p, [], err)

    def qualifies(self, score: int) -> bool:
        """True when ``score`` would enter the table."""
        return len(self.scores) < KEEP or score > self.scores[-1]["score"]

    def add(self, name: str, score: int, seconds: float, difficulty: str) -> int | None:
        """Add a score and save; returns its rank (1 = best) or None if it did not enter."""
        when = time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())
        entry = {
            "name": str(name)[:32],
            "score": int(score),
            "seconds": round(float(seconds), 2),
            "difficulty": difficulty,
            "when": when,
        }
        ranked = sorted([*self.scores, entry], key=lambda e: -e["score"])
        if entry not in ranked[:KEEP]:
            return None
        self.scores = ranked[:KEEP]
        self.save()
        return self.scores.index(entry) + 1

    def save(self) -> None:
        """Write the table atomically (temp file in the same folder, fsync, ``os.replace``)."""
        self.path.parent.mkdir(parents=True, exist_ok=True)
        data = json.dumps({"version": VERSION, "scores": self.scores}, indent=1).encode()
        fd, tmp = tempfile.mkstemp(prefix=f".{self.path.name}.", dir=self.path.parent)
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, self.path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise


def _parse(path: Path) -> list[dict]:
    """The scores of a file, validated; ValueError says what is wrong."""
    doc = json.loads(path.read_bytes().decode("utf-8"))
    if not isinstance(doc, dict) or doc.get("version") != VERSION:
        raise ValueError(f"not a version {VERSION} high-score table")
    scores = doc.get("scores")
    if not isinstance(scores, list) or not all(_valid(e) for e in scores):
        raise ValueError("scores must be a list of {name, score, ...} entries")
    return sorted(scores, key=lambda e: -e["score"])[:KEEP]


def _valid(entry: object) -> bool:
    return (
        isinstance(entry, dict)
        and isinstance(entry.get("name"), str)
        and isinstance(entry.get("score"), int)
    )


def _backup(path: Path) -> Path | None:
    """Copy a bad file to the first free ``<name>.corrupt-<n>``; None if it cannot."""
    for n in range(1, 1000):
        target = path.with_name(f"{path.name}.corrupt-{n}")
        if not target.exists():
            try:
                shutil.copy2(path, target)
            except OSError:
                return None
            return target
    return None
