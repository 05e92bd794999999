"""Text from files shown on a terminal or in one-line messages: control characters
escaped, long values cut."""

from __future__ import annotations

import unicodedata

MAX_QUOTE_CHARS = 200
"""At most this many characters of a value are quoted in a message."""


def printable(value: object) -> str:
    """Return ``str(value)`` with every control or format character (escape sequences,
    bells, carriage returns, bidirectional overrides) written as ``\\xNN`` / ``\\uNNNN``,
    so text from a file can never drive the terminal."""
    out = []
    for char in str(value):
        if unicodedata.category(char) in ("Cc", "Cf") and char != " ":
            code = ord(char)
            out.append(f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}")
        else:
            out.append(char)
    return "".join(out)


def console_text(value: object) -> str:
    """Return :func:`printable` text with Rich's markup escaped, for a message printed
    through a Rich console: a file named ``[bold]x`` prints as it is named."""
    from rich.markup import escape

    return escape(printable(value))


def quote(value: object, limit: int = MAX_QUOTE_CHARS) -> str:
    """Return ``repr(value)`` cut to about ``limit`` characters for a one-line message."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"
