"""One-line notices about a profile being loaded (an earlier schema migrated, a legal but suspicious value counted).

Library code cannot print: it tells the listeners registered here, and the
command line prints each notice as a warning (and records it in the run folder).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

_LISTENERS: list[Callable[[str], None]] = []


def on_notice(listener: Callable[[str], None]) -> Callable[[], None]:
    """Call ``listener(line)`` for every notice; returns a function that removes it."""
    _LISTENERS.append(listener)
    return lambda: _LISTENERS.remove(listener) if listener in _LISTENERS else None


def notice(line: str) -> None:
    """Tell the listeners ``line`` (one line, naming the file)."""
    for listener in list(_LISTENERS):
        listener(line)


@contextlib.contextmanager
def collected() -> Iterator[list[str]]:
    """The notices told while the block runs, in a list (for a caller that reports them its own way)."""
    lines: list[str] = []
    off = on_notice(lines.append)
    try:
        yield lines
    finally:
        off()
