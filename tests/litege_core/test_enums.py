import pytest

from litege_core.enums import ParsableEnum
from litege_core.errors import ArrayShapeError, InputError


class Colour(ParsableEnum, noun="colour", error=ArrayShapeError):
    RED = "red"
    BLUE = "blue"


class Plain(ParsableEnum):
    ONE = "one"


def test_parse_members_and_strings():
    assert Colour.parse("red") is Colour.RED and Colour.parse(Colour.BLUE) is Colour.BLUE
    assert list(Colour) == [Colour.RED, Colour.BLUE]  # _noun and _error are not members


def test_unknown_values_raise_the_configured_error_listing_choices():
    with pytest.raises(ArrayShapeError, match=r"unknown colour 'green'.*\['red', 'blue'\]"):
        Colour.parse("green")
    with pytest.raises(InputError, match="unknown value 'two'"):
        Plain.parse("two")
