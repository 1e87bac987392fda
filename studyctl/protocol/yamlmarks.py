"""Moved to :mod:`studyctl.yamlmarks` (YAML with positions is used below the protocol layer too); kept importable
for code written against this place."""

from studyctl.yamlmarks import *  # noqa: F403
from studyctl.yamlmarks import MarkedData, load_marked, load_plain  # noqa: F401
