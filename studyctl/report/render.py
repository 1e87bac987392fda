"""Render report blocks to HTML and Markdown with Jinja2 templates (``templates/report.{html,md}.j2``).

A block is a tuple whose first element names its kind: ``("h", level, text[, anchor])``, ``("p", text)``,
``("meta", lines)``, ``("alert", text)``, ``("list", items)``, ``("apa", lines)``,
``("findings", [(title, anchor, lines)])``, ``("table", head, rows[, caption])``, ``("figure", id, caption[, alt])``
and ``("toc",)`` (where the table of contents goes, built from the level-2 and level-3 headings).
"""

from __future__ import annotations

import base64
import re
from collections.abc import Mapping, Sequence
from functools import cache
from typing import Any

Block = tuple


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", str(text).lower()).strip("-") or "section"


def _normalise(content: Sequence[Block]) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    """Blocks as dicts for the templates (every heading with a unique anchor), and the TOC entries."""
    used: set[str] = set()
    out, toc = [], []
    for b in content:
        kind = b[0]
        if kind == "h":
            anchor = b[3] if len(b) > 3 and b[3] else _slug(b[2])
            base, i = anchor, 2
            while anchor in used:
                anchor, i = f"{base}-{i}", i + 1
            used.add(anchor)
            item = {"kind": "h", "level": int(b[1]), "text": str(b[2]), "anchor": anchor}
            if item["level"] in (2, 3):
                toc.append(item)
        elif kind == "table":
            item = {"kind": "table", "head": [str(h) for h in b[1]], "rows": [[str(c) for c in r] for r in b[2]],
                    "caption": str(b[3]) if len(b) > 3 and b[3] else ""}
        elif kind == "figure":
            item = {"kind": "figure", "id": b[1], "caption": str(b[2]), "alt": str(b[3] if len(b) > 3 else b[2])}
        elif kind == "findings":
            item = {"kind": "findings", "items": [{"title": t, "anchor": a, "lines": list(ls)} for t, a, ls in b[1]]}
        elif kind in ("meta", "list", "apa"):
            item = {"kind": kind, "items": [str(i) for i in b[1]]}
        elif kind == "toc":
            item = {"kind": "toc"}
        else:
            item = {"kind": kind, "text": str(b[1])}
        out.append(item)
    return out, toc


@cache
def _env():  # noqa: ANN202 - a jinja2 Environment, imported lazily (CLI start-up)
    import jinja2

    env = jinja2.Environment(
        loader=jinja2.PackageLoader("studyctl.report", "templates"),
        autoescape=jinja2.select_autoescape(enabled_extensions=("html.j2",), default_for_string=False),
        trim_blocks=True,
        lstrip_blocks=True,
        keep_trailing_newline=True,
    )
    env.filters["md"] = _md_cell
    env.filters["cell"] = _html_cell
    return env


# In a narrow column a bound such as "< .001" wrapped between its sign and its number, and a df pair "4, 44"
# between its two numbers: each is one value and keeps one line (a no-break space).
_BOUND = re.compile(r"^([<>≤≥]) (?=[.\d−-])")
_DF_PAIR = re.compile(r"^(\d+(?:\.\d+)?), (?=\d+(?:\.\d+)?$)")


def _html_cell(c: Any) -> str:
    return _DF_PAIR.sub("\\1,\u00a0", _BOUND.sub("\\1\u00a0", str(c)))


def _md_cell(c: Any) -> str:
    return str(c).replace("|", "\\|").replace("\n", " ")


def render_html(title: str, content: Sequence[Block], figures: Mapping[str, bytes] | None = None) -> str:
    """Blocks as a self-contained HTML page (figures embedded as PNG data)."""
    blocks, toc = _normalise(content)
    images = {k: base64.b64encode(v).decode("ascii") for k, v in (figures or {}).items()}
    return _env().get_template("report.html.j2").render(title=title, blocks=blocks, toc=toc, images=images)


def render_markdown(content: Sequence[Block]) -> str:
    """Blocks as Markdown (figures linked from ``figures/``)."""
    blocks, toc = _normalise(content)
    text = _env().get_template("report.md.j2").render(blocks=blocks, toc=toc)
    return re.sub(r"\n{3,}", "\n\n", text)


_TEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{",
        "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}", "<": r"\textless{}",
        ">": r"\textgreater{}"}


def tex(text: Any) -> str:
    """Text with LaTeX's special characters escaped."""
    return "".join(_TEX.get(ch, ch) for ch in str(text))


def render_latex(title: str, content: Sequence[Block]) -> str:
    """Every table of the blocks as a booktabs ``table`` environment, captioned by its section heading."""
    blocks, _ = _normalise(content)
    tables, heading, anchor, count = [], "", "table", {}
    for b in blocks:
        if b["kind"] == "h" and b["level"] >= 2:
            heading, anchor = b["text"], b["anchor"]
        elif b["kind"] == "table" and b["rows"]:
            count[heading] = count.get(heading, 0) + 1
            label = anchor + (f"-{count[heading]}" if count[heading] > 1 else "")
            tables.append({
                "caption": tex(heading), "caption_plain": heading.replace("\n", " "), "label": label,
                "head": [tex(h) for h in b["head"]], "rows": [[tex(c) for c in r] for r in b["rows"]],
                "note": tex(b["caption"]),
            })
    return _env().get_template("tables.tex.j2").render(title=title, tables=tables)
