"""The one usage rule of the developers' diagnostic scripts: ``-h``/``--help`` prints the script's docstring (which
says what it measures and what its positional arguments are) instead of being read as one of those arguments."""

from __future__ import annotations

import sys


def argv_or_usage(doc: str | None) -> list[str]:
    """The script's arguments (``sys.argv[1:]``); with ``-h`` or ``--help`` among them, the docstring is printed
    and the script exits 0."""
    args = sys.argv[1:]
    if "-h" in args or "--help" in args:
        print((doc or "").strip())
        sys.exit(0)
    return args
