"""Load YAML into plain Python data while keeping the file position of every key and value.

PyYAML's composer gives nodes with start marks; we build the data ourselves from those nodes so each
key path (``("conditions", 2, "params")``) maps to where its key and its value start. Duplicate keys,
which PyYAML silently lets the last one win, are reported as problems instead.

Protocol files and analysis plans both load through :func:`load_marked`; plans are stricter (no merge
keys, keys read as text) and word the problems themselves, using :attr:`Problem.kind`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from studyctl.errors import UsageError
from studyctl.inputs import read_text
from studyctl.problems import KeyPath, Mark, Problem, show

try:  # the C composer is much faster and gives the same marks
    _Loader: type = yaml.CSafeLoader
except AttributeError:  # pragma: no cover - libyaml missing
    _Loader = yaml.SafeLoader

_MERGE_TAG = "tag:yaml.org,2002:merge"

# Bounds checked before anything is built, so a hostile file fails in milliseconds with one problem instead
# of expanding aliases into gigabytes ("billion laughs") or recursing past the stack. Real protocols and plans
# are a few KB with a handful of anchors; these are generous.
MAX_BYTES = 2_000_000
MAX_DEPTH = 64
MAX_ALIASES = 1_000
MAX_VALUES = 20_000  # values after alias expansion (a real protocol or plan has a few hundred)
TOO_BIG = "too_big"

# Problem kinds (Problem.kind) of the problems found while loading.
SYNTAX = "syntax"
DUPLICATE_KEY = "duplicate_key"
MERGE_KEY = "merge_key"
BAD_KEY = "bad_key"
BAD_VALUE = "bad_value"


@dataclass
class MarkedData:
    """Data loaded from YAML, with the position of every key (``keys``) and value (``values``)."""

    data: Any
    keys: dict[KeyPath, Mark] = field(default_factory=dict)
    values: dict[KeyPath, Mark] = field(default_factory=dict)
    problems: list[Problem] = field(default_factory=list)
    source: str = ""

    def where(self, path: KeyPath) -> str:
        """``file:line:col`` of :meth:`key_mark` (the file is the name given to :func:`load_marked`)."""
        mark = self.key_mark(path)
        return f"{self.source}:{mark.line}:{mark.column}"

    def key_mark(self, path: KeyPath) -> Mark:
        """Where the key of ``path`` is written (for a list item: where the item starts)."""
        return self._best(path, self.keys, self.values)

    def value_mark(self, path: KeyPath) -> Mark:
        """Where the value of ``path`` starts; falls back to the nearest enclosing path."""
        return self._best(path, self.values, self.keys)

    @staticmethod
    def _best(path: KeyPath, first: dict[KeyPath, Mark], second: dict[KeyPath, Mark]) -> Mark:
        path = tuple(path)
        while True:
            if path in first:
                return first[path]
            if path in second:
                return second[path]
            if not path:
                return Mark(1, 1)
            path = path[:-1]


def _mark(node: yaml.Node) -> Mark:
    return Mark(node.start_mark.line + 1, node.start_mark.column + 1)


class _TooBig(Exception):
    def __init__(self, node: yaml.Node) -> None:
        self.node = node


class _Builder:
    def __init__(self, filename: str, merge_keys: bool, text_keys: bool) -> None:
        self.filename = filename
        self.merge_keys = merge_keys
        self.text_keys = text_keys
        self.out = MarkedData(data=None, source=filename)
        self._constructor = yaml.constructor.SafeConstructor()
        self._built = 0

    def build(self, node: yaml.Node, path: KeyPath) -> Any:
        self._built += 1
        if self._built > MAX_VALUES:
            raise _TooBig(node)
        self.out.values.setdefault(path, _mark(node))
        if isinstance(node, yaml.MappingNode):
            return self._mapping(node, path)
        if isinstance(node, yaml.SequenceNode):
            result = []
            for index, item in enumerate(node.value):
                self.out.keys.setdefault((*path, index), _mark(item))
                result.append(self.build(item, (*path, index)))
            return result
        try:
            return self._constructor.construct_object(node, deep=True)
        except yaml.YAMLError as exc:
            self._problem(
                node, path, "value cannot be read", show(node.value), f"a valid YAML scalar ({exc})", BAD_VALUE
            )
            return None

    def _mapping(self, node: yaml.MappingNode, path: KeyPath) -> dict[Any, Any]:
        result: dict[Any, Any] = {}
        explicit: set[Any] = set()
        merged: list[yaml.MappingNode] = []
        for key_node, value_node in node.value:
            if key_node.tag == _MERGE_TAG and not self.merge_keys:
                self._problem(key_node, path, "merge keys are not allowed here", "'<<'", "plain keys", MERGE_KEY)
                continue
            if key_node.tag == _MERGE_TAG:
                sources = value_node.value if isinstance(value_node, yaml.SequenceNode) else [value_node]
                for source in sources:
                    if isinstance(source, yaml.MappingNode):
                        merged.append(source)
                    else:
                        self._problem(
                            source, path, "merge key '<<' needs a mapping", show(source.value), "a mapping", MERGE_KEY
                        )
                continue
            if not isinstance(key_node, yaml.ScalarNode):
                self._problem(key_node, path, "key must be a plain value", "a mapping or list", "a string", BAD_KEY)
                continue
            key = self._constructor.construct_object(key_node, deep=True)
            if self.text_keys:
                if key is None or not isinstance(key, str | int | float | bool):
                    self._problem(key_node, path, "key must be a plain value", show(key), "a string", BAD_KEY)
                    continue
                key = str(key)
            if key in explicit:
                first = self.out.keys[(*path, key)]
                self._problem(
                    key_node,
                    (*path, key),
                    f"duplicate key (first written at line {first.line})",
                    show(key),
                    "each key once per mapping",
                    DUPLICATE_KEY,
                )
                continue
            explicit.add(key)
            self.out.keys[(*path, key)] = _mark(key_node)
            result[key] = self.build(value_node, (*path, key))
        for source in merged:  # explicit keys win over merged ones, earlier merges over later ones
            for key_node, value_node in source.value:
                if not isinstance(key_node, yaml.ScalarNode):
                    continue
                key = self._constructor.construct_object(key_node, deep=True)
                if key in result:
                    continue
                self.out.keys[(*path, key)] = _mark(key_node)
                result[key] = self.build(value_node, (*path, key))
        return result

    def _problem(self, node: yaml.Node, path: KeyPath, what: str, found: str, allowed: str, kind: str) -> None:
        self.out.problems.append(Problem(self.filename, _mark(node), tuple(path), what, found, allowed, kind=kind))


def _text_at(text: str, mark: yaml.Mark | None) -> str:
    """What stands at a syntax error's position: the rest of that line (shortened), or end of file."""
    if mark is None:
        return "invalid text"
    lines = text.splitlines()
    if mark.line >= len(lines):
        return "the end of the file"
    rest = lines[mark.line][mark.column:].strip()
    if not rest:
        return "the end of the line"
    return repr(rest if len(rest) <= 30 else rest[:27] + "...")


def _bounds_problem(text: str, filename: str) -> Problem | None:
    """A problem if the YAML is too large, too deeply nested or uses too many aliases (checked on the event
    stream, which costs time linear in the text and never expands an alias)."""
    if len(text) > MAX_BYTES:
        return Problem(filename, Mark(1, 1), (), "file too large", f"{len(text):,} characters",
                       f"at most {MAX_BYTES:,} characters (protocols and plans are a few KB)", kind=TOO_BIG)
    depth = aliases = 0
    try:
        for ev in yaml.parse(text, Loader=_Loader):
            if isinstance(ev, (yaml.MappingStartEvent, yaml.SequenceStartEvent)):
                depth += 1
                if depth > MAX_DEPTH:
                    return Problem(filename, Mark(ev.start_mark.line + 1, ev.start_mark.column + 1), (),
                                   "nested too deeply", f"more than {MAX_DEPTH} levels",
                                   f"at most {MAX_DEPTH} nested mappings/lists", kind=TOO_BIG)
            elif isinstance(ev, (yaml.MappingEndEvent, yaml.SequenceEndEvent)):
                depth -= 1
            elif isinstance(ev, yaml.AliasEvent):
                aliases += 1
                if aliases > MAX_ALIASES:
                    return Problem(filename, Mark(ev.start_mark.line + 1, ev.start_mark.column + 1), (),
                                   "too many aliases (*name)", f"more than {MAX_ALIASES}",
                                   f"at most {MAX_ALIASES} aliases; write the values out", kind=TOO_BIG)
    except yaml.YAMLError:
        return None  # compose reports the syntax error with its position
    return None


def load_marked(text: str, filename: str, *, merge_keys: bool = True, text_keys: bool = False) -> MarkedData:
    """Parse YAML ``text`` into data plus the position of every key path.

    Syntax errors do not raise: they come back as problems (with ``data`` None), so a caller can
    report them alongside everything else.

    Parameters
    ----------
    text, filename
        The YAML and the name its problems and :meth:`MarkedData.where` give.
    merge_keys
        Expand ``<<`` merge keys (explicit keys win); when False each one is a ``MERGE_KEY`` problem.
    text_keys
        Turn scalar keys into text (``1:`` is the key ``'1'``); a null or other non-name key is a
        ``BAD_KEY`` problem. When False, keys are kept as YAML typed them.
    """
    bounds = _bounds_problem(text, filename)
    if bounds is not None:
        return MarkedData(data=None, problems=[bounds], source=filename)
    try:
        root = yaml.compose(text, Loader=_Loader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = Mark(mark.line + 1, mark.column + 1) if mark else Mark(1, 1)
        what = f"YAML syntax error: {exc.problem or 'invalid text'}"
        if exc.context:
            what += f" ({exc.context})"
        problem = Problem(filename, where, (), what, _text_at(text, mark), "valid YAML", kind=SYNTAX)
        return MarkedData(data=None, problems=[problem], source=filename)
    except yaml.YAMLError as exc:  # pragma: no cover - reader errors without marks
        problem = Problem(filename, Mark(1, 1), (), "YAML error", str(exc), "valid YAML", kind=SYNTAX)
        return MarkedData(data=None, problems=[problem], source=filename)
    if root is None:
        return MarkedData(data=None, source=filename)
    builder = _Builder(filename, merge_keys, text_keys)
    try:
        builder.out.data = builder.build(root, ())
    except _TooBig as big:
        problem = Problem(filename, _mark(big.node), (), "aliases expand to too many values",
                          f"more than {MAX_VALUES:,} values", "a document that is not an alias bomb; write the "
                          "values out instead of nesting aliases", kind=TOO_BIG)
        return MarkedData(data=None, problems=[problem], source=filename)
    return builder.out


def load_plain(text: str, filename: str) -> Any:
    """Bounded ``yaml.safe_load``: the data of ``text`` (keys as YAML typed them, merge keys expanded), or
    :class:`~studyctl.errors.UsageError` naming ``filename:line`` for a syntax error or a hostile document."""
    marked = load_marked(text, filename)
    fatal = [p for p in marked.problems if p.kind in (SYNTAX, TOO_BIG, MERGE_KEY)]
    if fatal:
        raise UsageError(str(fatal[0]))
    return marked.data


def precheck_yaml_file(path: Any, what: str) -> None:
    """Read an input YAML file as its own loader will (size, UTF-8, alias and nesting limits) and raise that
    loader's one-line error if it is hostile or unreadable. A command calls this before it imports a heavy stack
    (engine, store, pandas), so such a file is refused by a small process (issue 19: within 200 MB); the file's
    own loader still checks its content. No file given, or a missing one: nothing to do here."""
    if path is None or not Path(path).is_file():
        return
    load_plain(read_text(path, what), str(path))
