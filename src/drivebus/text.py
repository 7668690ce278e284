"""Words in messages: a drive's name with its article, a count with its noun, a number
with its unit.

One place for the small grammar every message needs, so that a refusal reads "an NT86",
"1 axis" and "12.000mm" wherever it is written.
"""

from __future__ import annotations

import re

__all__ = ["a", "count", "quantity", "ranges"]

_LETTERS = re.compile(r"[A-Za-z]*")
_SAID_WITH_A_VOWEL = frozenset("AEFHILMNORSX")
"""Letters whose names start with a vowel sound (an F, an H, an NT86)."""


def a(name: str) -> str:
    """``name`` after its indefinite article as it is read aloud: a model code spelt out
    letter by letter ("an NT86", "an EPR60", "a BHSS", "a CL86R", "an OD2000") or a word
    ("a Lexium32", "a MOONS-STF", "an Oriental")."""
    head = _LETTERS.match(name)
    letters = head.group(0) if head else ""
    if not letters:
        return f"a {name}"
    if letters.isupper() and len(letters) <= 4:  # an initialism: its letters are read
        return f"{'an' if letters[0] in _SAID_WITH_A_VOWEL else 'a'} {name}"
    return f"{'an' if letters[0].upper() in 'AEIOU' else 'a'} {name}"


def count(n: int, one: str, many: str) -> str:
    """``n`` and the noun in its number: "1 axis", "2 axes"."""
    return f"{n} {one if n == 1 else many}"


def ranges(values: list[int]) -> str:
    """Whole numbers as runs: [1, 2, 3, 5] -> "1-3, 5"."""
    runs: list[list[int]] = []
    for v in values:
        if runs and v == runs[-1][-1] + 1:
            runs[-1].append(v)
        else:
            runs.append([v])
    return ", ".join(f"{r[0]}-{r[-1]}" if len(r) > 1 else str(r[0]) for r in runs)


def quantity(value: float | None, unit: str, digits: int = 3, sep: str = "") -> str:
    """A value in its unit: "12.000mm" (``sep`` between them: "12.000 mm"), "-" unknown."""
    return "-" if value is None else f"{value:.{digits}f}{sep}{unit}"
