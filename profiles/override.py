"""The one way to change validated settings: a copy with dotted-path changes, validated like the file they came from.

pydantic's copy with an update skips validation (``particles: 0`` would be
copied in); :func:`updated` rebuilds the model from its data with the changes, so
every bound and cross-field check holds, and a bad key or value is refused with
its path. Used for command-line overrides (``--set``, ``--particles``), the
sweep's varied settings and every derived copy of a config or profile.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeVar

from pydantic import BaseModel, ValidationError

from profiles.errors import UsageError

M = TypeVar("M", bound=BaseModel)


def updated(model: M, changes: Mapping[str, object], *, reset: tuple[str, ...] = ()) -> M:
    """A validated copy of ``model`` with ``changes`` ({dotted path: value}; a group's value replaces the whole
    group, None sets None); a bad key or value raises a UsageError naming its path. ``reset``: discriminator keys
    (e.g. ``filter.kind``) whose change starts their group from its new kind's defaults."""
    data = model.model_dump()
    for key, value in changes.items():
        node = data
        *path, last = key.split(".")
        for i, part in enumerate(path):
            if not isinstance(node.get(part), dict):
                raise UsageError(f"{key}: unknown key ({'.'.join(path[: i + 1])} is not a group of settings)")
            node = node[part]
        if key in reset and node.get(last) != value:
            node.clear()
        node[last] = value
    try:
        return type(model).model_validate(data)
    except ValidationError as exc:
        e = exc.errors()[0]
        msg = "unknown key" if e["type"] == "extra_forbidden" else e["msg"]
        raise UsageError(f"{'.'.join(str(x) for x in e['loc'])}: {msg}") from None
