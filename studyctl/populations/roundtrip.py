"""Write a changed population back into its own YAML text, keeping the file's comments and layout.

``studyctl calibrate`` writes the fitted population as a new file. Dumped from the model alone
(:meth:`~studyctl.populations.model.TraitPopulation.to_yaml`) it lost every comment of the file it started
from — the header saying what the population is and which numbers are cited, chosen or fitted — and the fit
had to be carried into the shipped file by hand. Here the starting file is read with ruamel.yaml's
round-trip loader, the new content is merged into it key by key (a value that did not change keeps its text:
its folded or quoted style, its number format), keys the new content lacks are dropped, new keys are added,
and the result is dumped with the comments where they were. A comment the loader attached to a key that the new
content drops (the lines right after that key's value) goes with it; a long quoted value that changed is
re-wrapped at ``width``. The merged text reads back to the same
population as the new content (a test checks both this and that the comments survive).
"""

from __future__ import annotations

import io
from collections.abc import Mapping
from typing import Any

__all__ = ["merge_into_text"]


def merge_into_text(source: str, data: Mapping[str, Any], *, width: int = 110) -> str | None:
    """``data`` (a population's plain content) written over the YAML ``source`` it was read from.

    Returns None when ``source`` is not a YAML mapping that the round-trip loader reads (the caller then
    writes ``data`` plainly).
    """
    from ruamel.yaml import YAML
    from ruamel.yaml.comments import CommentedMap
    from ruamel.yaml.error import YAMLError

    yaml = YAML()  # round-trip: comments, key order and scalar styles are kept
    yaml.width = width
    yaml.allow_unicode = True
    yaml.preserve_quotes = True
    yaml.indent(mapping=2, sequence=2, offset=0)
    try:
        doc = yaml.load(source)
    except YAMLError:
        return None
    if not isinstance(doc, CommentedMap):
        return None
    _merge(doc, data)
    out = io.StringIO()
    yaml.dump(doc, out)
    text = out.getvalue()
    # ruamel leaves a space at the end of a wrapped flow list's lines ("a, b, \n"); dropped unless a value held it
    # (a block scalar's trailing space is content)
    tidy = "\n".join(line.rstrip(" ") for line in text.split("\n"))
    return tidy if tidy == text or yaml.load(tidy) == yaml.load(text) else text


def _merge(node: Any, new: Mapping[str, Any]) -> None:
    for key in [k for k in node if k not in new]:
        del node[key]
    for key, value in new.items():
        old = node.get(key) if key in node else None
        if isinstance(value, Mapping) and hasattr(old, "ca") and isinstance(old, Mapping):
            _merge(old, value)
        elif key in node and _same(old, value):
            continue  # unchanged: keep its text as written
        else:
            node[key] = _fresh(value)


def _same(old: Any, new: Any) -> bool:
    if isinstance(old, bool) or isinstance(new, bool):
        return old is new or (isinstance(old, bool) and isinstance(new, bool) and old == new)
    if isinstance(old, int | float) and isinstance(new, int | float):
        return float(old) == float(new)
    if isinstance(old, list) and isinstance(new, list | tuple):
        return len(old) == len(new) and all(_same(a, b) for a, b in zip(old, new, strict=True))
    if isinstance(old, str) and isinstance(new, str):
        return str(old) == new
    return old is None and new is None


def _fresh(value: Any) -> Any:
    """A new value in the style :meth:`TraitPopulation.to_yaml` writes: short scalar lists inline, numbers to 6
    significant digits."""
    from ruamel.yaml.comments import CommentedMap, CommentedSeq

    if isinstance(value, Mapping):
        m = CommentedMap()
        for k, v in value.items():
            m[str(k)] = _fresh(v)
        return m
    if isinstance(value, list | tuple):
        seq = CommentedSeq(_fresh(v) for v in value)
        if len(value) <= 4 and all(isinstance(v, int | float | str) for v in value):
            seq.fa.set_flow_style()
        return seq
    if isinstance(value, float) and not isinstance(value, bool):
        return float(f"{value:.6g}")
    return value
