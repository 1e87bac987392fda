"""``with thing:`` closes ``thing``: the one context-manager idiom of studyctl's closeable handles (databases,
stores, opened studies, result files)."""

from __future__ import annotations

from typing import Self


class Closeable:
    """A handle with a ``close()``; ``with`` closes it on the way out, also on an error."""

    def close(self) -> None:
        raise NotImplementedError

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
