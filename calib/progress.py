"""A progress bar on a terminal, silence in CI and pipes.

The bar is drawn on stderr, the stream it checks, so a command's results on
stdout stay clean when stdout is a pipe or a file.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator
from typing import TypeVar

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

T = TypeVar("T")


def progress(items: Iterable[T], total: int, label: str) -> Iterator[T]:
    """``items`` as they come, with a bar of ``total`` steps named ``label`` on a terminal (none when ``CI`` is set)."""
    if os.environ.get("CI") or not sys.stderr.isatty():
        yield from items
        return
    with Progress(TextColumn(label), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(), console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(label, total=total)
        for it in items:
            yield it
            bar.advance(task)
