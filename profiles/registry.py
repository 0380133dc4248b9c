"""Named implementations of one kind (filters, log readers, detectors, ...): the table every kind is found through.

Each kind of thing detcal can swap -- a map filter, a vehicle model, a log
reader, a detector, a P_D covariate, a simulator -- has one :class:`Registry`
beside its declared interface. An implementation is one module that adds
itself (``REGISTRY.add(name, obj)`` or the :meth:`Registry.register`
decorator); the built-in ones are modules the registry imports the first time
it is asked (``builtins``), so the table is complete whoever asks first. The
command line's choices, the settings' discriminated unions and the docs' lists
are read from it; a module that needs to know the table changed (a pydantic
union to rebuild) subscribes with :meth:`Registry.on_change`.

Lives in ``profiles``, at the bottom of the import graph, with the errors and
atomic writes every package uses.
"""

from __future__ import annotations

import importlib
import sys
from collections.abc import Callable, Iterator
from typing import Generic, TypeVar

from profiles.errors import UsageError

T = TypeVar("T")
_MISSING = object()


class Registry(Generic[T]):
    """An ordered table ``name -> implementation`` of one kind.

    ``what`` names the kind in messages ("map filter"); ``builtins`` are the
    modules that add the built-in implementations, imported on first use.
    """

    def __init__(self, what: str, builtins: tuple[str, ...] = ()) -> None:
        self.what = what
        self._builtins = builtins
        self._loaded = not builtins
        self._items: dict[str, T] = {}
        self._origin: dict[str, str | None] = {}  # name -> the module that added it
        self._listeners: list[Callable[[], None]] = []

    def _load(self) -> None:
        if not self._loaded:
            self._loaded = True  # (set first: a built-in module may ask the registry while it is imported)
            for module in self._builtins:
                importlib.import_module(module)
            # the built-ins in the order of their modules (one may import another first), then the others as added
            rank = {m: i for i, m in enumerate(self._builtins)}
            order = sorted(self._items, key=lambda n: rank.get(self._origin.get(n), len(rank)))
            self._items = {n: self._items[n] for n in order}

    def add(self, name: str, obj: T, *, replace: bool = False) -> T:
        """Add ``obj`` under ``name``; a name already taken is refused unless ``replace``."""
        if name in self._items and not replace and self._items[name] is not obj:
            raise ValueError(f"{self.what} {name!r} is registered already")
        self._items[name] = obj
        frame = sys._getframe(1)  # the module that adds it (past the decorator form), whatever imported it first
        while frame is not None and frame.f_globals.get("__name__") == __name__:
            frame = frame.f_back
        self._origin[name] = frame.f_globals.get("__name__") if frame is not None else None
        for listener in self._listeners:
            listener()
        return obj

    def register(self, name: str | None = None) -> Callable[[T], T]:
        """Decorator form of :meth:`add`; without ``name`` the object's own ``name`` attribute names it."""

        def deco(obj: T) -> T:
            self.add(name if name is not None else obj.name, obj)  # type: ignore[attr-defined]
            return obj

        return deco

    def remove(self, name: str) -> None:
        """Take ``name`` out of the table (an implementation a test registered)."""
        self._items.pop(name, None)
        self._origin.pop(name, None)
        for listener in self._listeners:
            listener()

    def on_change(self, listener: Callable[[], None]) -> None:
        """Call ``listener()`` whenever an implementation is added or removed."""
        self._listeners.append(listener)

    def get(self, name: str, default=_MISSING) -> T:
        """The implementation ``name``; a UsageError naming the choices when there is none (or ``default``)."""
        self._load()
        if name in self._items:
            return self._items[name]
        if default is not _MISSING:
            return default
        raise UsageError(f"{self.what} {name!r} is not available (expected one of {', '.join(self._items)})")

    def names(self) -> tuple[str, ...]:
        self._load()
        return tuple(self._items)

    def items(self) -> list[tuple[str, T]]:
        self._load()
        return list(self._items.items())

    def values(self) -> list[T]:
        self._load()
        return list(self._items.values())

    def __contains__(self, name: object) -> bool:
        self._load()
        return name in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        return len(self.names())

    def choices(self, last: str = "or") -> str:
        """The names as a sentence: ``rbphd, lmb or glmb``."""
        n = self.names()
        return n[0] if len(n) == 1 else f"{', '.join(n[:-1])} {last} {n[-1]}"


def literal_field(model, name: str, choices: tuple[str, ...], *holders) -> None:
    """Make ``model.name`` one of ``choices`` (a Literal; its default and description kept) and rebuild ``model`` and
    the models that hold it (``holders``, innermost first): how a pydantic field follows a registry."""
    from typing import Literal

    from pydantic import Field
    from pydantic.fields import FieldInfo

    old = model.__pydantic_fields__[name]
    model.__pydantic_fields__[name] = FieldInfo.from_annotated_attribute(
        Literal[choices], Field(default=old.default, description=old.description)  # type: ignore[valid-type]
    )
    for m in (model, *holders):
        m.model_rebuild(force=True)
