"""Read a protocol file: YAML with positions, strict schema, cross-reference checks, all errors at once."""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import NoReturn

from pydantic import ValidationError

from studyctl.errors import NotFoundError, ProtocolError
from studyctl.inputs import MAX_TEXT_BYTES
from studyctl.problems import Mark, Problem
from studyctl.protocol.checks import cross_check
from studyctl.protocol.schema import Protocol
from studyctl.protocol.validation import problems_from_validation
from studyctl.resources import find_shipped
from studyctl.yamlmarks import load_marked


def find_problems(text: str, filename: str = "<protocol>") -> tuple[Protocol | None, list[Problem]]:
    """Parse and check protocol ``text``; return the model (None if invalid) and every problem, in file order."""
    marked = load_marked(text, filename)
    if marked.problems and marked.data is None:
        return None, marked.problems
    problems = list(marked.problems)
    if not isinstance(marked.data, dict):
        found = "an empty file" if marked.data is None else f"a {type(marked.data).__name__}"
        problems.append(Problem(filename, Mark(1, 1), (), "a protocol is a mapping of sections", found,
                                "a mapping starting with 'studyctl_protocol: 1'"))
        return None, problems
    model: Protocol | None = None
    # Top-level "x-" keys hold YAML anchors only (as in docker-compose files); they are not protocol data.
    data = {k: v for k, v in marked.data.items() if not (isinstance(k, str) and k.startswith("x-"))}
    try:
        model = Protocol.model_validate(data)
    except ValidationError as exc:
        problems.extend(problems_from_validation(exc, marked, filename))
    problems.extend(cross_check(marked, filename))
    unique: dict[str, Problem] = {}
    for problem in problems:
        unique.setdefault(str(problem), problem)
    ordered = sorted(unique.values(), key=lambda p: p.sort_key)
    return (model if not ordered else None), ordered


def _raise(problems: list[Problem], filename: str) -> NoReturn:
    lines = [str(p) for p in problems]
    if len(lines) == 1:
        message = lines[0]
    else:
        message = f"{filename}: {len(lines)} problems in the protocol:\n" + "\n".join(f"  {line}" for line in lines)
    error = ProtocolError(message, problems=lines)
    error.details = problems  # type: ignore[attr-defined]
    raise error


def load_protocol_text(text: str, filename: str = "<protocol>") -> Protocol:
    """Load a protocol from YAML text; raise :class:`ProtocolError` listing every problem."""
    model, problems = find_problems(text, filename)
    if problems or model is None:
        _raise(problems, filename)
    model._source_text = text
    model._sha256 = hashlib.sha256(text.encode("utf-8")).hexdigest()
    model._path = filename
    return model


def read_protocol_text(path: str | Path) -> tuple[str, str]:
    """The text of a protocol file and the name to use in messages (NotFoundError / ProtocolError)."""
    file = Path(path)
    if not file.is_file():
        raise NotFoundError(f"protocol file {str(path)!r} does not exist; pass an existing .yaml file")
    size = file.stat().st_size
    if size > MAX_TEXT_BYTES:
        raise ProtocolError(f"{path}:1:1: <root>: file too large: {size:,} bytes, allowed at most "
                            f"{MAX_TEXT_BYTES:,} (a protocol is a few KB of YAML)")
    try:
        return file.read_text(encoding="utf-8"), str(path)
    except UnicodeDecodeError as exc:
        raise ProtocolError(f"{path}:1:1: <root>: file is not UTF-8 text: found byte {exc.object[exc.start]:#04x}"
                            f" at offset {exc.start}, allowed UTF-8 encoded YAML") from None


def load_protocol(path: str | Path) -> Protocol:
    """Load and fully check a protocol file.

    Parameters
    ----------
    path
        A protocol YAML file.

    Returns
    -------
    Protocol
        The validated protocol, with ``source_text``, ``sha256`` and ``path`` set.

    Raises
    ------
    ProtocolError
        Listing every problem found (``problems``), each naming file:line:column and the key path.
    NotFoundError
        When the file does not exist.
    """
    text, name = read_protocol_text(path)
    return load_protocol_text(text, name)


def resolve_protocol(name_or_path: str | Path) -> Path:
    """A protocol file path from a path or the name of a shipped protocol (``needle_insertion``)."""
    return find_shipped("protocols", name_or_path)


def check_protocol(path: str | Path) -> list[Problem]:
    """Every problem in a protocol file (empty when it is valid); never raises for file content."""
    text, name = read_protocol_text(path)
    return find_problems(text, name)[1]
