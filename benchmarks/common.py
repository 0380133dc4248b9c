"""What the benchmark scripts share: their integer-list and ``--set key=value`` arguments, their per-run CSV."""

from __future__ import annotations

import csv
from pathlib import Path

import yaml


def ints(text: str) -> list[int]:
    """``0-2,5`` -> [0, 1, 2, 5]; an empty text -> []."""
    out: list[int] = []
    for part in filter(None, text.split(",")):
        a, _, b = part.partition("-")
        out += list(range(int(a), int(b) + 1)) if b else [int(a)]
    return out


def parse_set(item: str) -> tuple[str, object]:
    """``key=value`` (a dotted key reaches into a section) -> (key, the value read as YAML)."""
    key, sep, value = item.partition("=")
    if not sep or not key:
        raise SystemExit(f"--set {item!r}: expected key=value")
    return key, yaml.safe_load(value)


def write_rows(path: Path, rows: list[dict]) -> None:
    """One CSV row per run, the columns of the first run's keys."""
    with path.open("w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
