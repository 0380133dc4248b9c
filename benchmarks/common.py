"""What the benchmark scripts share: their integer-list and ``--set key=value`` arguments, their per-run CSV, the
self-calibrated Victoria Park profiles."""

from __future__ import annotations

import csv
import io
import os
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[1]
#: the shared real logs: beside the repository (or beside the folder of its worktrees), the first that exists
SHARED_DATA = next((p / "shared/data" for p in (ROOT.parent, ROOT.parent.parent) if (p / "shared/data").is_dir()), ROOT.parent / "shared/data")

#: the self-calibrated Victoria Park profile of each map filter (``detcal selfcal`` from the nominal profile with
#: ``benchmarks/configs/victoria_park.yaml``; RB-PHD's also serves MH-FastSLAM); each rebuilt by ``make rebuild-profiles``
VP_PROFILES = {
    "rbphd": ROOT / "benchmarks/profiles/victoria-park-selfcal@2.0.0.yaml",
    "lmb": ROOT / "benchmarks/profiles/victoria-park-selfcal-lmb@2.0.0.yaml",
    "glmb": ROOT / "benchmarks/profiles/victoria-park-selfcal-glmb@2.0.0.yaml",
}


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


def read_rows(path: Path, fields: list[str] | None = None) -> list[dict]:
    """The complete rows of a CSV written by :func:`append_row` (values read as YAML scalars: ints and floats come back as
    such); [] when the file is absent. A last line a stopped run cut short (no line end) is left out; a file whose
    columns are not ``fields`` (when given) is refused, so runs of another layout are never mixed in."""
    if not path.exists():
        return []
    text = path.read_text()
    if not text.endswith("\n"):
        text = text[: text.rfind("\n") + 1]
    r = csv.DictReader(io.StringIO(text, newline=""))
    if fields is not None and r.fieldnames is not None and r.fieldnames != fields:
        raise SystemExit(f"{path}: its columns {r.fieldnames} are not this benchmark's {fields}; give another --csv")
    return [{k: _scalar(v) for k, v in row.items()} for row in r if None not in row and None not in row.values()]


def _scalar(text: str) -> object:
    """A CSV field back as the int or float it was written from ("nan" included), else the text."""
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def append_row(path: Path, row: dict) -> None:
    """Add one run's row to ``path`` (the header first when the file is new) and flush it to disk, so a stopped
    benchmark keeps every run that ended; the next start reads them back with :func:`read_rows` and skips them."""
    if path.exists():
        data = path.read_bytes()
        if data and not data.endswith(b"\n"):  # a line cut by a stopped run: dropped, as read_rows drops it
            with path.open("r+b") as fh:
                fh.truncate(data.rfind(b"\n") + 1)
    new = not path.exists() or path.stat().st_size == 0
    with path.open("a", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(row))
        if new:
            w.writeheader()
        w.writerow(row)
        fh.flush()
        os.fsync(fh.fileno())
