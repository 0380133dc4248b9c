"""YAML read the strict way: a key given twice in one mapping is an error, not "the last one wins".

PyYAML's ``safe_load`` keeps the last of two equal keys without a word, so a
profile or config edited by hand (``range_max`` pasted twice, the second an
old value) would be believed. :func:`load` refuses it with the line of the
second key and of the first, through PyYAML's own ``ConstructorError`` (its
``problem_mark`` gives the line), so every caller that already names the line
of a YAML error names this one too.
"""

from __future__ import annotations

import yaml

try:  # the C loader when PyYAML was built with libyaml (same documents, faster)
    _Base = yaml.CSafeLoader
except AttributeError:  # pragma: no cover - depends on how PyYAML was built
    _Base = yaml.SafeLoader


class StrictLoader(_Base):
    """``yaml.SafeLoader`` that refuses a key given twice in one mapping."""


def _mapping(loader: StrictLoader, node: yaml.MappingNode, deep: bool = False) -> dict:
    seen: dict[object, yaml.Node] = {}
    for key_node, _ in node.value:
        if key_node.tag == "tag:yaml.org,2002:merge":
            continue  # keys merged in (<<: *base) may be overridden: that is what a merge is for
        key = loader.construct_object(key_node, deep=True)
        try:
            first = seen.get(key)
        except TypeError:  # an unhashable key: PyYAML's own error below says so
            continue
        if first is not None:
            raise yaml.constructor.ConstructorError(
                "while reading a mapping",
                node.start_mark,
                f"key {key!r} is given twice (first on line {first.start_mark.line + 1})",
                key_node.start_mark,
            )
        seen[key] = key_node
    return loader.construct_mapping(node, deep=deep)


StrictLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _mapping)


def load(text: str) -> object:
    """The document in ``text`` (``yaml.safe_load`` semantics), refusing duplicated keys (a ``yaml.YAMLError``)."""
    return yaml.load(text, Loader=StrictLoader)  # noqa: S506  (a SafeLoader subclass)
