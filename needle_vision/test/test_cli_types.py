"""The command-line tools' number types: NaN, inf and out-of-range values are argparse errors (exit 2, one line)."""
import argparse

import pytest

from needle_vision.calibration.calibrate import main as calibrate
from needle_vision.cli_types import non_negative, number, positive, positive_int


def test_bounds_and_non_finite_values():
    assert (number("-1.5"), positive("2e-3"), non_negative("0"), positive_int("3")) == (-1.5, 2e-3, 0.0, 3)
    for kind, text in ((number, "nan"), (number, "inf"), (number, "abc"), (positive, "0"), (positive, "-inf"),
                       (non_negative, "-1e-9"), (non_negative, "nan"), (positive_int, "0"), (positive_int, "1.5")):
        with pytest.raises(argparse.ArgumentTypeError):
            kind(text)


@pytest.mark.parametrize("option", [["--square", "inf"], ["--square", "0"], ["--sync-tolerance", "nan"],
                                    ["--workers", "0"]])
def test_a_calibration_command_line_out_of_range_is_refused(tmp_path, capsys, option):
    """Before: --square inf was accepted (a board of infinite squares), NaN tolerances too."""
    arguments = ["--board", "9x6", "--square", "0.01", *option, "--output-dir", str(tmp_path), str(tmp_path)]
    with pytest.raises(SystemExit) as exit_status:
        calibrate(arguments)
    assert exit_status.value.code == 2 and f"argument {option[0]}" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
