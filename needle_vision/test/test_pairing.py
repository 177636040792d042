"""Pairing left and right frames by stamp."""
import numpy as np
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


def _arrivals(rng, frames: int, period: float, jitter: float, latency: dict, drop: float):
    """Frames of both cameras (stamp = k * period + jitter per camera), each camera's frames arriving in order after
    a random latency (the right camera's up to several periods), some never arriving: (arrival, side, stamp, k)."""
    events, present = [], {"left": set(), "right": set()}
    for side in ("left", "right"):
        arrival = 0.0
        for k in range(frames):
            if rng.random() < drop:
                continue
            present[side].add(k)
            stamp = k * period + rng.uniform(-jitter, jitter)
            arrival = max(arrival, stamp + rng.uniform(*latency[side]))  # in order, as one camera delivers them
            events.append((arrival, side, stamp, k))
    return sorted(events), present


@pytest.mark.parametrize("seed", range(5))
def test_jittered_delayed_and_dropped_frames_pair_exactly_by_approximate_time(seed):
    """30 Hz cameras, stamps jittered by +-0.8 ms, the right camera's frames up to 3 periods late, 10 % of each
    camera's frames lost: every frame whose partner came pairs with it, and every other is counted as dropped."""
    rng = np.random.default_rng(seed)
    events, present = _arrivals(rng, 300, 1 / 30, 0.8e-3, {"left": (0.001, 0.005), "right": (0.001, 0.1)}, 0.1)
    pairer = StampPairer(0.002, max_pending=8)
    pairs = [pair for _, side, stamp, k in events if (pair := pairer.push(side, stamp, (side, k))) is not None]
    assert all(pair.left == ("left", k) and pair.right == ("right", k) for pair in pairs
               for k in [pair.left[1]])
    both = present["left"] & present["right"]
    assert [pair.left[1] for pair in pairs] == sorted(both)
    singles = len(present["left"] ^ present["right"])
    assert singles - 2 <= pairer.dropped <= singles  # the frames still waiting after the last pair are not counted


def test_frames_pair_only_within_the_slop():
    """Stamps jittered by +-3 ms: a slop of twice that pairs every frame, 2 ms only some, and never wrongly."""
    events, _ = _arrivals(np.random.default_rng(9), 100, 1 / 30, 3e-3, {"left": (0.001, 0.002),
                                                                       "right": (0.001, 0.002)}, 0.0)
    for slop, complete in ((0.0065, True), (0.002, False)):
        pairer = StampPairer(slop)
        pairs = [p for _, side, stamp, k in events if (p := pairer.push(side, stamp, k)) is not None]
        assert all(p.left == p.right for p in pairs)
        assert (len(pairs) == 100) if complete else (0 < len(pairs) < 100)


def test_the_queue_stays_bounded_when_one_camera_stalls():
    """The right camera delivers nothing for five frames: the left queue keeps only the newest three; the right
    frames that come late pair with those, the older ones are counted."""
    pairer = StampPairer(0.001, max_pending=3)
    for k in range(5):
        assert pairer.push("left", k * 0.1, k) is None
    assert pairer.dropped == 2  # left 0 and 1
    results = [pairer.push("right", k * 0.1, k) for k in range(5)]
    assert [(p.left, p.right) for p in results if p is not None] == [(2, 2), (3, 3), (4, 4)]
    assert pairer.dropped == 4  # and right 0 and 1, without a partner once right 2 paired
    for k in range(100):  # a stalled camera never grows the queue
        pairer.push("left", 1.0 + k * 0.1, k)
    assert pairer.dropped == 4 + 97
