"""The command-line tools' number types: NaN, inf and out-of-range values are argparse errors (exit 2, one line);
their exit status: bad input 2, a failed run 1, each with a one-line message and no traceback."""
import argparse

import pytest

from needle_common.cli_types import command_status, non_negative, number, positive, positive_int


def test_bounds_and_non_finite_values():
    assert (number("-1.5"), positive("2e-3"), non_negative("0"), positive_int("3")) == (-1.5, 2e-3, 0.0, 3)
    for kind, text in ((number, "nan"), (number, "inf"), (number, "abc"), (positive, "0"), (positive, "-inf"),
                       (non_negative, "-1e-9"), (non_negative, "nan"), (positive_int, "0"), (positive_int, "1.5")):
        with pytest.raises(argparse.ArgumentTypeError):
            kind(text)


class BadInput(ValueError):
    pass


class Failed(RuntimeError):
    pass


def raising(error: Exception):
    def run(arguments: argparse.Namespace) -> int:
        raise error
    return run


# OpenCV's errors span lines (and end with a newline): such a message, wrapped in a bad-input error
OPENCV = ("OpenCV(4.10.0) /io/opencv/modules/calib3d/src/calibration.cpp:3840: error: (-215:Assertion failed)\n"
          "  cameraMatrix1 in function 'stereoRectify'\n")


@pytest.mark.parametrize("error, status, line", [
    (BadInput("missing.yaml: file not found"), 2, "tool: error: missing.yaml: file not found"),
    (BadInput(OPENCV), 2, "tool: error: OpenCV(4.10.0) /io/opencv/modules/calib3d/src/calibration.cpp:3840: error: "
                          "(-215:Assertion failed) cameraMatrix1 in function 'stereoRectify'"),
    (OSError(28, "No space left on device"), 2, "tool: error: [Errno 28] No space left on device"),
    (Failed("no pair was measured"), 1, "tool: no pair was measured"),
    (Failed(), 1, "tool: Failed"),
])
def test_command_status_one_line_without_traceback(capsys, error, status, line):
    assert command_status("tool", raising(error), argparse.Namespace(), (BadInput, OSError), (Failed,)) == status
    captured = capsys.readouterr()
    assert captured.err == line + "\n" and captured.out == ""


def test_command_status_of_a_run_and_of_a_bug(capsys):
    assert command_status("tool", lambda arguments: arguments.code, argparse.Namespace(code=0), (BadInput,)) == 0
    with pytest.raises(KeyError):  # not named: a bug keeps its traceback
        command_status("tool", raising(KeyError("x")), argparse.Namespace(), (BadInput,), (Failed,))
    assert capsys.readouterr().err == ""
