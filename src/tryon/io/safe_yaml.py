"""YAML input with limits: a small document must not expand into a huge one (alias bombs),
nest without end or hold recursive structures. Raises `InputFileError` / `LimitError`."""

from __future__ import annotations

from typing import Any

import yaml

from tryon.errors import InputFileError, LimitError
from tryon.limits import LIMITS, check_limit


class _CountingLoader(yaml.SafeLoader):
    """SafeLoader that refuses more than `max_yaml_aliases` alias references."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self.aliases = 0

    def compose_node(self, parent: Any, index: Any) -> Any:
        if self.check_event(yaml.AliasEvent):
            self.aliases += 1
            if self.aliases > LIMITS.max_yaml_aliases:
                raise LimitError(f"YAML document uses more than max_yaml_aliases = {LIMITS.max_yaml_aliases} alias "
                                 "references (*name); write the values out instead")
        return super().compose_node(parent, index)


def _expanded_size(node: yaml.Node, source: str) -> int:
    """Nodes of the document with aliases expanded; refuses cycles and oversized documents."""
    sizes: dict[int, int] = {}
    active: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(node, False)]
    while stack:
        current, done = stack.pop()
        key = id(current)
        children = _children(current)
        if done:
            active.discard(key)
            sizes[key] = 1 + sum(sizes[id(c)] for c in children)
            if sizes[key] > LIMITS.max_yaml_nodes:
                raise LimitError(f"{source}: the YAML document expands to more than max_yaml_nodes = "
                                 f"{LIMITS.max_yaml_nodes:,} values (aliases repeat their anchors)")
            continue
        if key in sizes:
            continue
        if key in active:
            raise InputFileError(f"{source}: the YAML document refers to itself (a recursive alias)")
        active.add(key)
        stack.append((current, True))
        stack.extend((c, False) for c in children if id(c) not in sizes)
    return sizes[id(node)]


def _children(node: yaml.Node) -> list[yaml.Node]:
    if isinstance(node, yaml.SequenceNode):
        return list(node.value)
    if isinstance(node, yaml.MappingNode):
        return [n for pair in node.value for n in pair]
    return []


def load_yaml(text: str, source: str = "YAML") -> Any:
    """The single document in `text` (None when empty), within the YAML limits."""
    check_limit(f"{source}: YAML text (bytes)", len(text.encode("utf-8", "replace")), LIMITS.max_yaml_bytes,
                "max_yaml_bytes", overridable=False)
    loader = None
    try:
        loader = _CountingLoader(text)
        node = loader.get_single_node()
        if node is None:
            return None
        _expanded_size(node, source)
        return loader.construct_document(node)
    except yaml.YAMLError as exc:
        raise InputFileError(f"{source}: malformed YAML ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    except RecursionError:
        raise InputFileError(f"{source}: the YAML document is nested too deeply") from None
    except (ValueError, TypeError, OverflowError) as exc:  # e.g. integers with too many digits
        raise InputFileError(f"{source}: malformed YAML ({exc})") from None
    finally:
        if loader is not None:
            loader.dispose()
