"""Pseudonymous participant codes and the optional identity key file kept outside the database.

The study database stores only codes. Whoever must be able to re-identify participants (e.g. to
contact them for a second session) keeps an identity key: a small tab-separated file mapping each
code to free text (name, contact), created readable by its owner only, and kept apart from the data
(never exported, never inside the database). Codes are random, not derived from identities.
"""

from __future__ import annotations

import contextlib
import os
import secrets
from collections.abc import Callable
from pathlib import Path

from studyctl.errors import ConfigError, NotFoundError, UsageError

# No 0/O, 1/I/L, 5/S, 2/Z: codes are read aloud and written by hand.
CODE_ALPHABET = "ABCDEFGHJKMNPQRTUVWXY346789"
_HEADER = "# studyctl identity key: code<TAB>identity. Keep this file apart from the study data.\n"


def random_code(prefix: str = "P", length: int = 6, *, token: Callable[[str], str] = secrets.choice) -> str:
    """A random pseudonymous code such as ``P-7K3QXM`` (about 28 bits of entropy for 6 characters).

    Drawn from the operating system's CSPRNG, not from a study seed: codes must not be reproducible
    from anything stored with the data. ``token`` picks one character of the alphabet (tests pass a
    scripted one).
    """
    if not 4 <= length <= 32:
        raise UsageError(f"code length must be 4–32 characters, got {length}")
    body = "".join(token(CODE_ALPHABET) for _ in range(length))
    return f"{prefix}-{body}" if prefix else body


def _escape(value: str) -> str:
    return value.replace("\\", "\\\\").replace("\t", "\\t").replace("\n", "\\n").replace("\r", "\\r")


def _unescape(value: str) -> str:
    out, i = [], 0
    table = {"t": "\t", "n": "\n", "r": "\r", "\\": "\\"}
    while i < len(value):
        ch = value[i]
        if ch == "\\" and i + 1 < len(value) and value[i + 1] in table:
            out.append(table[value[i + 1]])
            i += 2
            continue
        out.append(ch)
        i += 1
    return "".join(out)


class IdentityKey:
    """The identity key file at ``path`` (mode 0600): ``add``, ``lookup``, ``codes``.

    Every ``add`` appends one line and fsyncs, so the key never loses a participant it acknowledged.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def _read(self) -> dict[str, str]:
        if not self.path.exists():
            return {}
        entries: dict[str, str] = {}
        for number, line in enumerate(self.path.read_text(encoding="utf-8").splitlines(), start=1):
            if not line or line.startswith("#"):
                continue
            code, sep, identity = line.partition("\t")
            if not sep:
                raise ConfigError(f"{self.path}:{number}: expected code<TAB>identity, found {line[:40]!r}")
            entries[_unescape(code)] = _unescape(identity)
        return entries

    def add(self, code: str, identity: str) -> None:
        """Record who ``code`` is; refuses a code already in the key."""
        if not code or not identity:
            raise UsageError("identity key entries need a non-empty code and identity")
        if code in self._read():
            raise UsageError(f"code {code!r} is already in the identity key {self.path}")
        new = not self.path.exists()
        fd = os.open(self.path, os.O_CREAT | os.O_WRONLY | os.O_APPEND, 0o600)
        with os.fdopen(fd, "a", encoding="utf-8") as fh:
            if new:
                fh.write(_HEADER)
            fh.write(f"{_escape(code)}\t{_escape(identity)}\n")
            fh.flush()
            os.fsync(fh.fileno())
        with contextlib.suppress(OSError):
            os.chmod(self.path, 0o600)

    def lookup(self, code: str) -> str:
        """The identity recorded for ``code`` (:class:`NotFoundError` if absent)."""
        entries = self._read()
        if code not in entries:
            raise NotFoundError(f"code {code!r} is not in the identity key {self.path}")
        return entries[code]

    def codes(self) -> list[str]:
        return list(self._read())


__all__ = ["CODE_ALPHABET", "IdentityKey", "random_code"]
