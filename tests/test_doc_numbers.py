"""tests/doc_numbers.py: a document's numbers found in order after a label, whatever the words."""

from __future__ import annotations

import pytest

from tests.doc_numbers import assert_numbers, n, numbers, table_row

TEXT = """* **W at 2.5 ms finished**: deterministic endpoint mean **198.2 reward
  per s, SD 12.5** (−181.0 to 215.3); P1 +97.7 [60.1, 135.3] (Welch 95%, raw p 1.2·10⁻⁷).

| P6 | −194.6 [−230.0, −159.2] | 0.00016 | ahead |
"""


def test_the_numbers_are_found_in_order_with_any_words_between():
    assert_numbers(TEXT, [n(198.2), n(12.5), n(-181.0), n(215.3)])
    assert_numbers(TEXT, ["97.7", "60.1", "135.3", "1.2·10⁻⁷"], label="P1", window=60)
    assert_numbers(TEXT, ["-194.6", "-230.0"], label="| P6 |")  # a hyphen reads as the minus sign


@pytest.mark.parametrize("expected,label", [
    (["198.2", "215.3", "12.5"], None),  # out of order
    (["198.2", "12.4"], None),  # another number
    (["98.2"], None),  # a part of a number is no number
    (["97.7", "60.1"], "P6"),  # not after the label
    (["198.2", "1.2·10⁻⁷"], "W at"),  # beyond the window
])
def test_numbers_out_of_order_changed_or_elsewhere_fail(expected, label):
    with pytest.raises(AssertionError):
        assert_numbers(TEXT, expected, label=label, window=60)


def test_numbers_and_table_rows():
    assert numbers("−1.5 to +2, 12,870 splits, 2.5·10⁻³") == ["−1.5", "+2", "12,870", "2.5·10⁻³"]
    assert table_row(TEXT, "P6") == ["P6", "−194.6 [−230.0, −159.2]", "0.00016", "ahead"]
    with pytest.raises(AssertionError):
        table_row(TEXT, "P7")
