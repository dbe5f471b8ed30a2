"""Numbers a parser already made (YAML, JSON) checked before they become floats
(:func:`spacecal.core.strict_numbers.number_value`), and shown short in messages."""

import pytest

from spacecal.core.errors import InvalidInputError
from spacecal.core.strict_numbers import number_shown, number_value
from spacecal.io.ros_common import number_field


@pytest.mark.parametrize("value", [0, -3, 1.5, 1e-300, 99.0, -100])
def test_plain_numbers_pass(value):
    assert number_value(value, 100.0) == float(value)


@pytest.mark.parametrize(
    ("value", "reason"),
    [
        (True, "not a number"),
        ("1", "not a number"),
        (None, "not a number"),
        (float("nan"), "not finite"),
        (float("inf"), "not finite"),
        (10**31, "an integer beyond 100"),
        (10**400, "an integer beyond 100"),
        (1e308, "beyond 100"),
        (-100.5, "beyond 100"),
    ],
    ids=["bool", "str", "None", "nan", "inf", "10**31", "10**400", "1e308", "-100.5"],
)
def test_what_is_not_a_plain_finite_number_says_why(value, reason):
    with pytest.raises(ValueError, match=reason):
        number_value(value, 100.0)


def test_an_integer_beyond_a_float_is_refused_without_a_bound():
    with pytest.raises(ValueError, match="too large for a floating-point number"):
        number_value(10**400)
    assert number_value(10**300) == 1e300


@pytest.mark.parametrize(
    ("value", "shown"),
    [
        (10**400 - 1, "an integer of 400 digits"),
        (10**400, "an integer of 401 digits"),
        (-(10**5000), "an integer of 5001 digits"),
        (10**39, "1" + "0" * 39),
        (1e308, "1e+308"),
    ],
    ids=["400 digits", "401 digits", "5001 digits", "40 digits", "1e308"],
)
def test_numbers_are_shown_short(value, shown):
    assert number_shown(value) == shown


def test_number_field_names_where_the_field_and_the_bound():
    with pytest.raises(
        InvalidInputError,
        match=r"f\.yaml: t: field 'x' is an integer of 400 digits, "
        r"expected a finite number of magnitude at most 100$",
    ):
        number_field({"x": 10**400 - 1}, "x", "f.yaml: t", 100.0)
    with pytest.raises(InvalidInputError, match=r"field 'x' is 'abc', expected a finite number$"):
        number_field({"x": "abc"}, "x", "f.yaml: t")
