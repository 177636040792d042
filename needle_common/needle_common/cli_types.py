"""What the command-line tools share: argparse types (numbers with their bound, so that NaN, inf and out-of-range
values end the command as argparse errors, one line naming the option, exit status 2, before any work) and the exit
status of a run (:func:`command_status`)."""
from __future__ import annotations

import argparse
import math
import sys
from typing import Callable


def number(text: str) -> float:
    """A finite float."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: '{text}'") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text}")
    return value


def positive(text: str) -> float:
    value = number(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def non_negative(text: str) -> float:
    value = number(text)
    if not value >= 0.0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: '{text}'") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {text}")
    return value


def command_status(prog: str, run: Callable[[argparse.Namespace], int], arguments: argparse.Namespace,
                   bad_input: tuple[type[Exception], ...], failure: tuple[type[Exception], ...] = ()) -> int:
    """``run(arguments)``'s exit status, without a traceback for the exceptions named: ``bad_input`` prints
    ``prog: error: <message>`` and gives 2, ``failure`` (the input was fine, the work failed) ``prog: <message>``
    and 1, each message on one line of stderr. Other exceptions (bugs) propagate with their traceback."""
    try:
        return run(arguments)
    except bad_input as error:
        print(f"{prog}: error: {one_line(error)}", file=sys.stderr)
        return 2
    except failure as error:
        print(f"{prog}: {one_line(error)}", file=sys.stderr)
        return 1


def one_line(error: BaseException) -> str:
    """The message of ``error`` on one line (a YAML parser's, e.g., spans several), or its type if it has none."""
    return " ".join(str(error).split()) or type(error).__name__
