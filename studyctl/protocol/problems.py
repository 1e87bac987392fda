"""Moved to :mod:`studyctl.problems`; kept importable for code written against this place."""

from studyctl.problems import *  # noqa: F403
from studyctl.problems import KeyPath, Mark, Problem, format_path, one_of, show  # noqa: F401
