"""The command-line tools' number types: NaN, inf and out-of-range values are argparse errors (exit 2, one line)."""
import argparse

import pytest

from needle_common.cli_types import non_negative, number, positive, positive_int


def test_bounds_and_non_finite_values():
    assert (number("-1.5"), positive("2e-3"), non_negative("0"), positive_int("3")) == (-1.5, 2e-3, 0.0, 3)
    for kind, text in ((number, "nan"), (number, "inf"), (number, "abc"), (positive, "0"), (positive, "-inf"),
                       (non_negative, "-1e-9"), (non_negative, "nan"), (positive_int, "0"), (positive_int, "1.5")):
        with pytest.raises(argparse.ArgumentTypeError):
            kind(text)
