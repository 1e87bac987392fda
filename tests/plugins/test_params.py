"""Declared plugin parameters: defaults, unknown names, types and ranges give one clear error."""

from __future__ import annotations

import pytest

from studyctl.errors import ModelParameterError
from studyctl.plugins.params import Param, describe, validate_params

SPEC = (
    Param("gain", 1.0, 0.0, 10.0, unit="N", source="paper"),
    Param("count", 3, 1, 5, kind=int),
    Param("mode", "a", choices=("a", "b")),
    Param("on", True, kind=bool),
    Param("levels", (1, 2), kind=tuple),
)


def test_defaults_and_overrides():
    out = validate_params("thing", {"gain": 2, "mode": "b", "levels": [3]}, SPEC)
    assert out == {"gain": 2.0, "count": 3, "mode": "b", "on": True, "levels": (3,)}
    assert isinstance(out["gain"], float)
    assert validate_params("thing", None, SPEC)["gain"] == 1.0


@pytest.mark.parametrize(
    ("params", "message"),
    [
        ({"gian": 1}, "thing: unknown parameter 'gian'; did you mean 'gain'? Known parameters: count, gain, levels"),
        ({"gain": 11}, "thing: parameter 'gain' = 11 is out of range; use a float in [0, 10] N"),
        ({"gain": float("nan")}, "thing: parameter 'gain' = nan must be finite"),
        ({"gain": "high"}, "thing: parameter 'gain' = 'high' must be a float in [0, 10] N"),
        ({"gain": True}, "thing: parameter 'gain' = True must be a float"),
        ({"count": 2.5}, "thing: parameter 'count' = 2.5 must be a whole number"),
        ({"count": 0}, "thing: parameter 'count' = 0 is out of range; use a int in [1, 5]"),
        ({"mode": "c"}, "thing: parameter 'mode' = 'c' is not allowed; use one of 'a', 'b'"),
        ({"on": "yes"}, "thing: parameter 'on' = 'yes' must be true or false"),
        ({"levels": 3}, "thing: parameter 'levels' = 3 must be a list"),
    ],
)
def test_bad_values_name_the_parameter_and_what_is_allowed(params, message):
    with pytest.raises(ModelParameterError) as err:
        validate_params("thing", params, SPEC)
    assert str(err.value).startswith(message)


def test_describe_lists_sources():
    rows = describe(SPEC)
    assert rows[0] == {"name": "gain", "default": 1.0, "allowed": "a float in [0, 10] N", "unit": "N",
                       "source": "paper"}
