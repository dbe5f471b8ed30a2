"""Untrusted text on its way to a person: made inert and bounded.

Names and values from files, bags and devices (a tf frame in a bag, an OpenIGTLink device
name, a cell of a CSV) reach error messages and printed listings. Printed raw, an escape
sequence in such a name could move the cursor, rewrite earlier lines or set the terminal's
title, and a multi-megabyte value would flood the screen. These helpers turn every character
that a terminal could act on into a visible escape and cut the text to a length.
"""

from __future__ import annotations

import reprlib
import unicodedata

from spacecal.core.errors import InvalidInputError

#: Unicode categories escaped for the terminal: controls (C0, DEL, C1 - including the 8-bit
#: CSI), format characters (bidirectional overrides, zero-width joiners), surrogates, private
#: use, unassigned code points, the line and paragraph separators, and every space but the
#: ASCII one (a no-break space in a name is shown as ``\xa0``, not hidden).
_ESCAPED_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Co", "Cn", "Zl", "Zp", "Zs"})
_NAMED_ESCAPES = {"\n": "\\n", "\r": "\\r", "\t": "\\t"}
#: Default number of characters kept of one piece of untrusted text.
DEFAULT_LIMIT = 200
#: What replaces the cut end of a text.
ELLIPSIS = "..."


#: Longest name of a robot, tracker or tool (and of anything else a person names) accepted.
MAX_NAME_CHARS = 200


#: What the categories of characters without a Unicode name are, for messages.
_CATEGORY_NAMES = {
    "Cc": "a control character",
    "Cs": "a surrogate",
    "Co": "a private-use character",
    "Cn": "an unassigned code point",
}


def _hidden(character: str) -> bool:
    """True for a character :func:`sanitize_for_terminal` escapes (every space but the ASCII one,
    controls, format characters...): one that would not print as itself."""
    return character != " " and unicodedata.category(character) in _ESCAPED_CATEGORIES


def _refused_character(text: str, spaces: bool) -> str | None:
    return next((c for c in text if _hidden(c) or (c == " " and not spaces)), None)


def check_name(name: object, what: str, max_chars: int = MAX_NAME_CHARS) -> str:
    """``name`` if a person reads it as it is, else one line naming ``what``.

    The one rule for names that people give and read (a robot, a tracker, a tool in the
    station's record): 1 to ``max_chars`` characters, none of which
    :func:`sanitize_for_terminal` would escape (so no newline, no C0 or C1 control, no DEL, no
    bidirectional override, isolate or mark, no zero-width or other invisible character, no
    space but the ASCII one), not starting or ending with a space. Letters of any script are
    names. Such a name prints as itself in a terminal and on a page, and two names that look
    the same are the same string.

    Parameters
    ----------
    name : object
        The name (anything but a ``str`` is refused).
    what : str
        Named in the error, e.g. ``"robot name"``.
    max_chars : int
        Longest name accepted.

    Raises
    ------
    InvalidInputError
        One line: what is wrong, the name shown escaped and cut.
    """
    return _checked(name, what, max_chars, spaces=True)


def check_printable_token(value: object, what: str, max_chars: int) -> str:
    """``value`` if it is 1 to ``max_chars`` characters that print as themselves, spaces
    excluded: :func:`check_name`'s rule for a device URL or a model name, where a space or a
    line break would smuggle a second value into one."""
    return _checked(value, what, max_chars, spaces=False)


def _checked(value: object, what: str, max_chars: int, spaces: bool) -> str:
    if not isinstance(value, str):
        raise InvalidInputError(f"{what}: expected text, got {type(value).__name__}")
    if not value.strip():
        raise InvalidInputError(f"{what} is empty")
    if len(value) > max_chars:
        raise InvalidInputError(f"{what} {quoted(value)} is longer than {max_chars} characters")
    bad = _refused_character(value, spaces)
    if bad is not None:
        label = unicodedata.name(bad, "").lower() or _CATEGORY_NAMES.get(unicodedata.category(bad), "")
        kind = "a space" if bad == " " else f"U+{ord(bad):04X} ({label})"
        allowed = "printable characters and spaces" if spaces else "printable characters, no spaces"
        raise InvalidInputError(f"{what} {quoted(value)} holds {kind}; it takes {allowed}")
    if value != value.strip(" "):
        raise InvalidInputError(f"{what} {quoted(value)} must not start or end with a space")
    return value


def _escape(character: str) -> str:
    if character in _NAMED_ESCAPES:
        return _NAMED_ESCAPES[character]
    code = ord(character)
    if code <= 0xFF:
        return f"\\x{code:02x}"
    if code <= 0xFFFF:
        return f"\\u{code:04x}"
    return f"\\U{code:08x}"


def sanitize_for_terminal(text: object, limit: int = DEFAULT_LIMIT) -> str:
    """``text`` with every control, format or otherwise invisible character escaped, at most
    ``limit`` characters long (a cut text ends with ``...``).

    Parameters
    ----------
    text : object
        A string (anything else is converted with ``str``; pass only bounded objects).
    limit : int
        Most characters returned, escapes and the ellipsis included (at least 3).

    Returns
    -------
    str
        Printable text: ``"a\\x1b[2Jb"`` for ``"a<ESC>[2Jb"``, ``"x\\ny"`` for a newline.
        Printable characters (any script) and the space are kept as they are.
    """
    if not isinstance(text, str):
        text = str(text)
    limit = max(int(limit), len(ELLIPSIS))
    pieces: list[str] = []
    length = 0
    for character in text:
        piece = (
            character
            if character == " " or unicodedata.category(character) not in _ESCAPED_CATEGORIES
            else _escape(character)
        )
        pieces.append(piece)
        length += len(piece)
        if length > limit:  # cut: stop reading, make room for the ellipsis
            while length > limit - len(ELLIPSIS):
                length -= len(pieces.pop())
            return "".join(pieces) + ELLIPSIS
    return "".join(pieces)


_REPR = reprlib.Repr()
_REPR.maxlevel = 3
_REPR.maxdict = 4
_REPR.maxlist = _REPR.maxtuple = _REPR.maxset = _REPR.maxfrozenset = _REPR.maxdeque = 4
_REPR.maxstring = _REPR.maxother = DEFAULT_LIMIT
_REPR.maxlong = 40


def quoted(value: object, limit: int = 60) -> str:
    """A bounded, terminal-safe ``repr`` of a value read from a file, for an error message.

    Nested containers are abbreviated (``reprlib``), so the cost does not grow with the size of
    the value (a structure built from YAML aliases would otherwise be expanded in full).
    """
    if isinstance(value, str):
        text = repr(value[:limit]) + (ELLIPSIS if len(value) > limit else "")
    else:
        text = _REPR.repr(value)
    return sanitize_for_terminal(text, limit + 2 + len(ELLIPSIS))


def exception_line(exc: BaseException) -> str:
    """An exception's message on one line (whitespace runs, newlines included, as one space), or
    its type's name when it has none."""
    return " ".join(str(exc).split()) or type(exc).__name__


def one_line_ascii(text: str) -> str:
    """``text`` as one line of printable ASCII: every other character (newlines, controls,
    non-ASCII letters) as a Python-style escape. For comments in generated files, where a line
    break would end the comment and start code, a key or markup."""
    return "".join(c if " " <= c <= "~" else _escape(c) for c in str(text))


def double_quoted_ascii(text: str) -> str:
    r"""``text`` as a double-quoted literal of printable ASCII that Python and YAML (1.1 and 1.2)
    both read back as exactly ``text``: ``\\`` and ``\"`` escaped, every character outside
    printable ASCII as ``\n``, ``\xNN``, ``\uNNNN`` or ``\UNNNNNNNN``, so no content can close
    the literal early or break its line."""
    return '"' + "".join(_quoted_escape(c) for c in text) + '"'


def _quoted_escape(character: str) -> str:
    if character in '"\\':
        return "\\" + character
    return character if " " <= character <= "~" else _escape(character)
