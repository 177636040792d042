"""Pairing of measured shapes with model shapes by header stamp (nearest model stamp within a tolerance).

Model shapes (non-decreasing stamps) are kept in a bounded buffer. A measurement at t is decided once a model stamp
>= t arrived: paired with the nearer model shape around t if within the tolerance, else counted unpaired; until then
it waits (at most ``pending_limit``, the oldest dropped). A model stamp going back (a looped bag) clears both buffers.
"""
from __future__ import annotations

import bisect
from collections import deque
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class StampedPair:
    model: Any
    measurement: Any
    model_stamp_ns: int
    measurement_stamp_ns: int


class ShapePairer:
    """Pairs each measurement with the model shape nearest in stamp, if within ``tolerance_ns``: one-sided and
    streaming (the stereo node's :class:`needle_vision.streams.pairing.StampPairer` pairs two symmetric streams)."""

    def __init__(self, tolerance_ns: int, model_buffer: int = 200, pending_limit: int = 100) -> None:
        if tolerance_ns < 0 or model_buffer < 1 or pending_limit < 1:
            raise ValueError("tolerance_ns must be >= 0, model_buffer and pending_limit >= 1")
        self.tolerance_ns = int(tolerance_ns)
        self._model_stamps: deque[int] = deque(maxlen=model_buffer)
        self._models: deque[Any] = deque(maxlen=model_buffer)
        self._pending: deque[tuple[int, Any]] = deque()
        self._pending_limit = pending_limit
        self.unpaired = 0
        self.restarts = 0

    def add_model(self, stamp_ns: int, model: Any) -> list[StampedPair]:
        """Buffer a model shape; returns the pairs of waiting measurements that it decides."""
        if self._model_stamps and stamp_ns < self._model_stamps[-1]:
            self.restarts += 1
            self.unpaired += len(self._pending)
            self._model_stamps.clear()
            self._models.clear()
            self._pending.clear()
        self._model_stamps.append(stamp_ns)
        self._models.append(model)
        pairs, waiting = [], deque()
        for stamp, measurement in self._pending:
            if stamp <= stamp_ns:
                pairs.extend(self._decide(stamp, measurement))
            else:
                waiting.append((stamp, measurement))
        self._pending = waiting
        return pairs

    def add_measurement(self, stamp_ns: int, measurement: Any) -> list[StampedPair]:
        """Pair a measurement now if decidable, else keep it waiting; returns the pairs made."""
        if self._model_stamps and self._model_stamps[-1] >= stamp_ns:
            return self._decide(stamp_ns, measurement)
        self._pending.append((stamp_ns, measurement))
        if len(self._pending) > self._pending_limit:
            self._pending.popleft()
            self.unpaired += 1
        return []

    def _decide(self, stamp_ns: int, measurement: Any) -> list[StampedPair]:
        stamps = self._model_stamps
        i = bisect.bisect_left(stamps, stamp_ns)
        candidates = [j for j in (i - 1, i) if 0 <= j < len(stamps)]
        best = min(candidates, key=lambda j: abs(stamps[j] - stamp_ns))
        if abs(stamps[best] - stamp_ns) > self.tolerance_ns:
            self.unpaired += 1
            return []
        return [StampedPair(self._models[best], measurement, stamps[best], stamp_ns)]
