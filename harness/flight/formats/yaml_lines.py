"""YAML through PyYAML (any valid YAML: block or flow style, comments, anchors), with line numbers kept.

The loaded mappings and lists remember the line of every key and item, so a reader that validates the
loaded data can still name the file line of a bad value (`file:line: field position needs 3 numbers`).
Scalars are resolved by PyYAML's safe loader (ints, floats, booleans, strings; no arbitrary objects).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from yaml.nodes import MappingNode, Node, ScalarNode, SequenceNode

from harness.errors import InputError


class YamlSyntaxError(InputError):
    """Not valid YAML; `line` is 1-based (None when PyYAML gives no position)."""

    def __init__(self, message: str, line: int | None) -> None:
        super().__init__(message)
        self.line = line


class LineMap(dict):  # type: ignore[type-arg]
    """A YAML mapping: `line` of the mapping itself, `key_lines[key]` of each entry."""

    line: int = 0
    key_lines: dict[Any, int]

    def line_of(self, key: Any) -> int:
        return self.key_lines.get(key, self.line)


class LineList(list):  # type: ignore[type-arg]
    """A YAML sequence: `line` of the sequence itself, `item_lines[k]` of each item."""

    line: int = 0
    item_lines: list[int]

    def line_of(self, index: int) -> int:
        return self.item_lines[index] if 0 <= index < len(self.item_lines) else self.line


def _convert(node: Node, loader: yaml.SafeLoader) -> Any:
    if isinstance(node, MappingNode):
        loader.flatten_mapping(node)     # merge keys (<<: *base)
        out = LineMap()
        out.line = node.start_mark.line + 1
        out.key_lines = {}
        for key_node, value_node in node.value:
            key = _convert(key_node, loader)
            try:
                hash(key)
            except TypeError:
                raise YamlSyntaxError("a mapping key must be a scalar", key_node.start_mark.line + 1) from None
            if key in out:     # PyYAML would keep the last one silently; YAML says keys are unique
                raise YamlSyntaxError(f"duplicate key {key!r}", key_node.start_mark.line + 1)
            out[key] = _convert(value_node, loader)
            out.key_lines[key] = key_node.start_mark.line + 1
        return out
    if isinstance(node, SequenceNode):
        seq = LineList(_convert(item, loader) for item in node.value)
        seq.line = node.start_mark.line + 1
        seq.item_lines = [item.start_mark.line + 1 for item in node.value]
        return seq
    if isinstance(node, ScalarNode):
        return loader.construct_object(node, deep=True)
    raise YamlSyntaxError(f"unsupported YAML node {type(node).__name__}", node.start_mark.line + 1)


def load_yaml_lines(path: Path) -> Any:
    """The document of `path` as LineMap / LineList / scalars. Raises YamlSyntaxError (with the line) for
    invalid YAML, more than one document or bytes that are not UTF-8 text; OSError propagates."""
    try:
        text = Path(path).read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:          # a binary file: the reader's error (exit 2), not a crash
        raise YamlSyntaxError(f"not a UTF-8 text file ({exc.reason} at byte {exc.start})", None) from None
    loader = yaml.SafeLoader(text)
    try:
        node = loader.get_single_node()
        return None if node is None else _convert(node, loader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        what = " ".join(x for x in (exc.context, exc.problem) if x)
        raise YamlSyntaxError(f"not valid YAML: {what or exc}", mark.line + 1 if mark else None) from None
    except yaml.YAMLError as exc:
        raise YamlSyntaxError(f"not valid YAML: {exc}", None) from None
    except RecursionError:      # an alias inside its own anchor (`a: &x [*x]`), or absurdly deep nesting
        raise YamlSyntaxError("not a plain YAML document: a recursive alias or nesting too deep", None) from None
    finally:
        loader.dispose()
