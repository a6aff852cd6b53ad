"""Writing a benchmark's rows: CSV, and CSV beside JSON (every ``holo-bench`` table).

:func:`zones_label` is how the tables and progress lines name a zone count.

Rows are dicts with the same keys; the CSV's columns are the first row's keys, in
their order.  No rows: no CSV (there is no header to write).
"""

from __future__ import annotations

import csv
import json
from pathlib import Path


def write_csv(rows: list[dict], path: Path) -> None:
    """``rows`` as a CSV file at ``path`` (nothing written when there are none)."""
    if not rows:
        return
    with Path(path).open("w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def write_rows(rows: list[dict], stem: Path) -> None:
    """``stem.json`` (the rows as a JSON list) and ``stem.csv`` next to each other."""
    stem.with_suffix(".json").write_text(json.dumps(rows, indent=1))
    write_csv(rows, stem.with_suffix(".csv"))


def zones_label(count: int | str) -> str:
    """``"1 zone"``, ``"5 zones"`` (a count read back from a CSV may be a string)."""
    return f"{count} zone" if int(count) == 1 else f"{count} zones"
