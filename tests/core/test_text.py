"""Untrusted text on its way to a terminal: escaped and bounded."""

import time
import unicodedata

import pytest

from spacecal.core.text import double_quoted_ascii, one_line_ascii, quoted, sanitize_for_terminal


@pytest.mark.parametrize(
    "text,shown",
    [
        ("base_link", "base_link"),
        ("a b", "a b"),
        ("caf\u00e9 \u4e2d", "caf\u00e9 \u4e2d"),  # printable letters of any script stay
        ("x\x1b[2Jy", "x\\x1b[2Jy"),  # ESC: clear screen
        ("\x1b]0;owned\x07", "\\x1b]0;owned\\x07"),  # OSC: set the window title
        ("a\nb\rc\td", "a\\nb\\rc\\td"),
        ("\x9b31m", "\\x9b31m"),  # 8-bit CSI
        ("\x00\x7f", "\\x00\\x7f"),
        ("abc\u202egnp.exe", "abc\\u202egnp.exe"),  # right-to-left override
        ("zero\u200bwidth", "zero\\u200bwidth"),
        ("line\u2028sep\u2029", "line\\u2028sep\\u2029"),
        ("\ud800", "\\ud800"),  # a lone surrogate
        ("\U000e0041", "\\U000e0041"),  # a tag character (format)
    ],
)
def test_control_and_invisible_characters_are_escaped(text, shown):
    assert sanitize_for_terminal(text, 100) == shown


def test_every_output_character_is_printable():
    everything = "".join(chr(c) for c in range(0x0, 0x3000)) + "\U0001f600\U000e0001\U0010fffd"
    out = sanitize_for_terminal(everything, 10**6)
    assert all(c == " " or unicodedata.category(c)[0] not in "CZ" for c in out)


@pytest.mark.parametrize("limit", [3, 10, 50])
def test_the_length_is_bounded_and_a_cut_is_marked(limit):
    assert sanitize_for_terminal("a" * limit, limit) == "a" * limit
    cut = sanitize_for_terminal("a" * (limit + 1), limit)
    assert len(cut) <= limit and cut.endswith("...")
    escaped = sanitize_for_terminal("\x1b" * 100, limit)
    assert len(escaped) <= limit and escaped.endswith("...")


def test_a_huge_text_is_cut_without_reading_it_all():
    start = time.perf_counter()
    out = sanitize_for_terminal("\x1b" * 50_000_000, 200)
    assert len(out) <= 200 and time.perf_counter() - start < 1.0


def test_quoted_is_bounded_for_huge_and_nested_values():
    nested: list = []
    for _ in range(50):
        nested = [nested] * 10  # 10**50 leaves if expanded
    start = time.perf_counter()
    for value in (nested, "x" * 10**7, {"k" * 1000: list(range(10**6))}, b"\x1b" * 1000, 10**200):
        text = quoted(value)
        assert len(text) <= 70 and "\x1b" not in text
    assert time.perf_counter() - start < 1.0
    assert quoted("a'b\n") == '"a\'b\\n"'


@pytest.mark.parametrize(
    "text", ["", "plain", 'q"q', "b\\s", "\n\r\t\x00", "\u2028\x85", "\U0001f600", "\udfff"]
)
def test_double_quoted_ascii_is_a_python_literal_of_exactly_the_text(text):
    import ast

    literal = double_quoted_ascii(text)
    assert literal.isascii() and literal.isprintable()
    assert ast.literal_eval(literal) == text


def test_one_line_ascii_cannot_break_a_line():
    out = one_line_ascii("a\nb\r\x85\u2028c\u00e9")
    assert out.isascii() and out.isprintable() and "\n" not in out
