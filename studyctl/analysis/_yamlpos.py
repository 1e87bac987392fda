"""Load YAML while remembering where every value came from, so plan errors can say ``file:line:col``.

PyYAML's composer keeps a start mark on every node; we walk the node tree once, building plain Python
objects and a map from key path (a tuple of keys and list indices) to (line, column), both 1-based.
Duplicate mapping keys are reported instead of silently keeping the last one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from studyctl.errors import ProtocolError
from studyctl.protocol.problems import format_path

Path_ = tuple[str | int, ...]


@dataclass
class Located:
    """A parsed YAML document plus the position of each key path."""

    data: Any
    source: str
    positions: dict[Path_, tuple[int, int]] = field(default_factory=dict)

    def where(self, path: Path_) -> str:
        """``file:line:col`` of the deepest known prefix of ``path`` (the file alone if none is known)."""
        for cut in range(len(path), -1, -1):
            pos = self.positions.get(tuple(path[:cut]))
            if pos is not None:
                return f"{self.source}:{pos[0]}:{pos[1]}"
        return self.source


def _construct(node: yaml.Node, path: Path_, out: Located, problems: list[str]) -> Any:
    out.positions[path] = (node.start_mark.line + 1, node.start_mark.column + 1)
    if isinstance(node, yaml.MappingNode):
        result: dict[Any, Any] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                problems.append(f"{out.source}:{key_node.start_mark.line + 1}: YAML merge keys (<<) are not supported")
                continue
            key = _scalar(key_node) if isinstance(key_node, yaml.ScalarNode) else None
            if not isinstance(key, str | int | float | bool) or key is None:
                problems.append(
                    f"{out.source}:{key_node.start_mark.line + 1}:{key_node.start_mark.column + 1}: "
                    f"mapping keys must be plain names, found {key!r}"
                )
                continue
            key = str(key)
            if key in result:
                problems.append(
                    f"{out.source}:{key_node.start_mark.line + 1}:{key_node.start_mark.column + 1}: "
                    f"{dotted((*path, key))}: duplicate key {key!r} (the first is on line "
                    f"{out.positions[(*path, key)][0]}); remove one of them"
                )
                continue
            result[key] = _construct(value_node, (*path, key), out, problems)
            # Point errors about a key at the key itself, not at its value on the next line.
            out.positions[(*path, key)] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
        return result
    if isinstance(node, yaml.SequenceNode):
        return [_construct(item, (*path, i), out, problems) for i, item in enumerate(node.value)]
    return _scalar(node)


_RESOLVER_LOADER = yaml.SafeLoader("")


def _scalar(node: yaml.ScalarNode) -> Any:
    constructor = yaml.SafeLoader.yaml_constructors.get(node.tag)
    if constructor is None:
        return node.value
    return constructor(_RESOLVER_LOADER, node)


def dotted(path: Path_) -> str:
    """Render a key path as ``tests[2].posthoc.test`` (the protocol's rendering; plans say "(top level)")."""
    return format_path(path) if path else "(top level)"


def load_located(path: Path | str, text: str | None = None) -> Located:
    """Parse one YAML document from ``path`` (or ``text``), keeping positions.

    Raises
    ------
    ProtocolError
        On a syntax error (with line and column), an empty file, or duplicate keys.
    """
    source = str(path)
    if text is None:
        try:
            text = Path(path).read_text(encoding="utf-8")
        except FileNotFoundError:
            raise ProtocolError(f"{source}: no such file") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ProtocolError(f"{source}: cannot read the file ({exc})") from None
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"{source}:{mark.line + 1}:{mark.column + 1}" if mark else source
        raise ProtocolError(f"{where}: YAML syntax error: {exc.problem or exc}") from None
    except yaml.YAMLError as exc:
        raise ProtocolError(f"{source}: YAML syntax error: {exc}") from None
    if node is None:
        raise ProtocolError(f"{source}: the file is empty; an analysis plan is a YAML mapping")
    out = Located(data=None, source=source)
    problems: list[str] = []
    out.data = _construct(node, (), out, problems)
    if problems:
        raise ProtocolError(f"{source}: {len(problems)} problem(s):\n  " + "\n  ".join(problems), problems)
    return out
