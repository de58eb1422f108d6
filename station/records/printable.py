"""Text from people (job ids, VINs) as the records keep and show it.

A job id reaches a terminal (``station history``), a CSV export and an HTML report. A control
character in it forges or hides output there: a newline starts a line of its own in a listing,
ESC drives the terminal, a bidirectional override reorders what a reader sees. So such
characters are refused where a job id comes in (``station measure --job``; the PLC accepts
printable ASCII only), and text already stored is shown with them escaped (``visible``).
"""

from __future__ import annotations

import unicodedata

# Unicode categories a printed line must not carry: controls (C0, DEL, C1), format characters
# (bidirectional overrides, zero-width joiners), lone surrogates (bytes that were not UTF-8 in
# argv), and the line and paragraph separators.
UNPRINTABLE_CATEGORIES = frozenset({"Cc", "Cf", "Cs", "Zl", "Zp"})


def unprintable(text: str) -> list[str]:
    """The characters of ``text`` a printed line must not carry, each once, in order."""
    return list(dict.fromkeys(ch for ch in text if unicodedata.category(ch) in UNPRINTABLE_CATEGORIES))


def escaped(ch: str) -> str:
    """One character as Python writes it in a string literal: ``\\n``, ``\\x1b``, ``\\u202e``."""
    return ch.encode("unicode_escape").decode("ascii")


def visible(text: str) -> str:
    """``text`` with every unprintable character written as its escape (``JOB\\n1`` for a
    newline), everything else as it is."""
    return "".join(escaped(ch) if unicodedata.category(ch) in UNPRINTABLE_CATEGORIES else ch for ch in text)
