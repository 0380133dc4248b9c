"""Atomic outputs; the implementation lives in :mod:`profiles.atomic` (the bottom of the import graph)."""

from profiles.atomic import atomic_output

__all__ = ["atomic_output"]
