"""Pairing left and right frames by time stamp (the two cameras of seed 000 are synchronised; their frames
may still arrive out of step, late, or not at all)."""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class FramePair:
    """A synchronised pair: the left frame's stamp [s] and the two payloads."""

    stamp: float
    left: Any
    right: Any


class StampPairer:
    """Pairs frames whose stamps differ by at most ``tolerance`` [s].

    Frames wait in a short queue per side (``max_pending``) for their partner; a frame whose partner never
    comes (dropped frame) is discarded once a newer pair forms or the queue overflows, and counted in
    ``dropped``. Frames not newer than the last pair are discarded too.

    A frame pairs at once with the nearest waiting frame of the other side within ``tolerance`` (message_filters'
    slop): no frame waits for a possibly better partner, so a pair costs no latency and the last frames of a
    recording pair too (message_filters' ApproximateTime holds a set until a later message shows it is the best).
    That is unambiguous while ``tolerance`` is below half the frame period.
    """

    SIDES = ("left", "right")

    def __init__(self, tolerance: float, max_pending: int = 8):
        if not tolerance >= 0 or max_pending < 1:
            raise ValueError("tolerance must be >= 0 and max_pending >= 1")
        self.tolerance = tolerance
        self._pending = {side: deque() for side in self.SIDES}
        self._max_pending = max_pending
        self._last_pair = float("-inf")
        self.dropped = 0

    def push(self, side: str, stamp: float, payload: Any) -> FramePair | None:
        """Offer a frame of ``side``; returns the pair it completes, if any."""
        if side not in self.SIDES:
            raise ValueError(f"side must be 'left' or 'right', got {side!r}")
        if stamp <= self._last_pair:
            self.dropped += 1
            return None
        other = self._pending["right" if side == "left" else "left"]
        best = min(range(len(other)), key=lambda k: abs(other[k][0] - stamp), default=None)
        if best is None or abs(other[best][0] - stamp) > self.tolerance:
            own = self._pending[side]
            own.append((stamp, payload))
            if len(own) > self._max_pending:
                own.popleft()
                self.dropped += 1
            return None
        partner_stamp, partner = other[best]
        del other[best]
        pair_stamp = stamp if side == "left" else partner_stamp
        self._last_pair = max(stamp, partner_stamp)
        for queue in self._pending.values():  # older frames can no longer pair: they were dropped
            while queue and queue[0][0] <= self._last_pair:
                queue.popleft()
                self.dropped += 1
        return FramePair(pair_stamp, payload if side == "left" else partner, partner if side == "left" else payload)
