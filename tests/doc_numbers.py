"""The numbers a document gives, checked without its wording.

A test that recomputes a published number from committed data checks the document by that number,
formatted as the document formats numbers (one decimal, the minus sign U+2212, a small p as
``1.2·10⁻⁷``), not by the sentence around it: :func:`assert_numbers` finds the expected numbers in
order, any words and other numbers between, within a window after a label (a cell's or a contrast's
name) or after the first of them; :func:`table_row` reads a markdown table's row by its first cell.
"""

from __future__ import annotations

import re
from typing import Sequence

MINUS = "\N{MINUS SIGN}"
#: a number as the documents write one: a sign (+, -, U+2212), digits with thousands commas, a
#: fraction, a power of ten in superscripts (``1.2·10⁻⁷``)
NUMBER = re.compile(r"[+\-\u2212]?\d+(?:,\d{3})*(?:\.\d+)?(?:·10[⁻⁰¹²³⁴⁵⁶⁷⁸⁹]+)?")


def normalised(text: str) -> str:
    """``text`` with its emphasis (``**``, backticks) removed and every run of white space one space."""
    return re.sub(r"\s+", " ", text.replace("**", "").replace("`", ""))


def _key(token: str) -> str:
    """A number token compared by value as written: a plus sign optional, a hyphen as U+2212."""
    return token.replace("-", MINUS).lstrip("+")


def n(x: float, plus: bool = False, digits: int = 1) -> str:
    """A number as the documents write it: ``digits`` decimals, the minus sign U+2212, a plus sign if asked."""
    s = f"{x:.{digits}f}".replace("-", MINUS)
    return "+" + s if plus and x >= 0 else s


def numbers(text: str) -> list[str]:
    """The number tokens of ``text``, in order."""
    return [m.group() for m in NUMBER.finditer(text)]


def _in_order(tokens: list[str], expected: list[str]) -> bool:
    it = iter(tokens)
    return all(any(t == e for t in it) for e in expected)


def assert_numbers(text: str, expected: Sequence[str], label: str | None = None, window: int = 400) -> None:
    """AssertionError unless the numbers ``expected`` (each as the document writes it) occur in this
    order, other words and numbers between them, each starting within ``window`` characters after an
    occurrence of ``label`` in the normalised ``text``, or (no label) after the start of an occurrence
    of the first of them."""
    doc = normalised(text)
    want = [_key(e) for e in expected]
    if label is not None:
        anchors, at = [], doc.find(label)
        while at >= 0:
            anchors.append(at + len(label))
            at = doc.find(label, at + 1)
    else:
        anchors = [m.start() for m in NUMBER.finditer(doc) if _key(m.group()) == want[0]]
    for a in anchors:
        tokens = []
        for m in NUMBER.finditer(doc, a):  # every number that starts within the window, whole
            if m.start() >= a + window:
                break
            tokens.append(_key(m.group()))
        if _in_order(tokens, want):
            return
    where = f"after {label!r}" if label is not None else "anywhere"
    raise AssertionError(f"the numbers {list(expected)} are not in order within {window} characters {where} "
                         f"({len(anchors)} places tried)")


def table_row(text: str, first: str) -> list[str]:
    """The cells of the markdown table row of ``text`` whose first cell is ``first`` (emphasis
    removed); AssertionError if there is none."""
    for line in text.splitlines():
        cells = [normalised(c).strip() for c in line.strip().strip("|").split("|")]
        if line.lstrip().startswith("|") and cells and cells[0] == first:
            return cells
    raise AssertionError(f"no table row {first!r}")
