"""One lookup by name for the whole tool: a miss names what exists and the nearest name to what was written."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from studyctl.errors import UnknownKeyError
from studyctl.suggest import named


@dataclass(frozen=True)
class _Condition:
    id: str


CONDITIONS = (_Condition("BL"), _Condition("RT"), _Condition("ESG"))


def test_a_hit_returns_the_item_itself():
    assert named(CONDITIONS, "RT", what="condition", plural="conditions") is CONDITIONS[1]


def test_a_misspelt_name_is_refused_with_the_choices_and_the_nearest_one():
    with pytest.raises(UnknownKeyError) as err:
        named(CONDITIONS, "ESGG", what="condition", plural="conditions", where=" in the protocol")
    assert err.value.args[0] == (
        "no condition 'ESGG' in the protocol; conditions are BL, RT, ESG; did you mean 'ESG'?"
    )


def test_a_name_near_nothing_gets_no_guess_and_an_empty_pool_says_none():
    with pytest.raises(UnknownKeyError, match=r"conditions are BL, RT, ESG$"):
        named(CONDITIONS, "haptic", what="condition", plural="conditions")
    with pytest.raises(UnknownKeyError, match=r"no trait 'x'; traits are none$"):
        named((), "x", what="trait", plural="traits")
