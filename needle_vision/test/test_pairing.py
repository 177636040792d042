"""Pairing left and right frames by stamp."""
import pytest

from needle_vision.streams.pairing import StampPairer


def test_frames_pair_within_tolerance_in_any_arrival_order():
    pairer = StampPairer(0.002)
    assert pairer.push("left", 1.000, "L1") is None
    pair = pairer.push("right", 1.0015, "R1")
    assert (pair.stamp, pair.left, pair.right) == (1.000, "L1", "R1")
    assert pairer.push("right", 1.010, "R2") is None
    pair = pairer.push("left", 1.0105, "L2")
    assert (pair.stamp, pair.left, pair.right) == (1.0105, "L2", "R2")  # the left frame's stamp
    assert pairer.dropped == 0


def test_unsynchronised_frames_do_not_pair():
    pairer = StampPairer(0.002)
    assert pairer.push("left", 1.000, "L") is None
    assert pairer.push("right", 1.003, "R") is None


def test_dropped_frame_is_discarded_and_counted():
    pairer = StampPairer(0.002)
    pairer.push("left", 1.000, "L1")  # its right partner never arrives
    pairer.push("left", 1.005, "L2")
    pair = pairer.push("right", 1.005, "R2")
    assert pair.left == "L2"
    assert pairer.dropped == 1
    assert pairer.push("right", 1.000, "late R1") is None  # older than the last pair
    assert pairer.dropped == 2


def test_queue_overflow_drops_the_oldest():
    pairer = StampPairer(0.001, max_pending=3)
    for k in range(5):
        pairer.push("left", float(k), k)
    assert pairer.dropped == 2
    assert pairer.push("right", 4.0, "R").left == 4


def test_bad_arguments():
    with pytest.raises(ValueError):
        StampPairer(-1.0)
    with pytest.raises(ValueError, match="side"):
        StampPairer(0.001).push("centre", 0.0, None)
