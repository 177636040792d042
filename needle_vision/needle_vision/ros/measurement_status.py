"""What became of the stereo node's image pairs, on ``/diagnostics`` beside its input report.

A status ``<fully qualified node name>: measurement`` (e.g. ``/needle_stereo: measurement``) with cumulative counts
(``pairs_<outcome>``: measured, background, rejected, skipped_no_calibration, skipped_loading_kernels (before the
measurement's kernels are compiled or loaded), skipped_decode_error (an image of an encoding it cannot read or a
compressed image that does not decode); ``frames_unpaired``: frames dropped
without a partner within ``sync_tolerance``,
``rejected_<kind>``: the measurement's rejections by kind since the calibration) and a level from what happened
since the previous report: WARN while pairs are rejected or skipped or frames go unpaired, OK otherwise.
"""
from __future__ import annotations

from collections import Counter

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from needle_common.ros.input_status import OK, WARN

OUTCOMES = ("measured", "background", "rejected", "skipped_no_calibration", "skipped_loading_kernels",
            "skipped_decode_error")


class MeasurementStatus:
    def __init__(self, node_name: str) -> None:
        self.name = f"{node_name}: measurement"
        self.pairs: Counter[str] = Counter({outcome: 0 for outcome in OUTCOMES})
        self._reported: Counter[str] = Counter()

    def count(self, outcome: str) -> None:
        self.pairs[outcome] += 1

    def status(self, unpaired_frames: int, rejections: Counter[str]) -> DiagnosticStatus:
        now = Counter({**{f"pairs {k}": n for k, n in self.pairs.items()}, "frames unpaired": unpaired_frames})
        new = {key.replace("_", " "): count - self._reported[key] for key, count in now.items()
               if key not in ("pairs measured", "pairs background") and count > self._reported[key]}
        self._reported = now
        kinds = ", ".join(f"{kind} {count}" for kind, count in rejections.most_common())
        message = ("since the last report: " + ", ".join(f"{n} {key}" for key, n in new.items())
                   + (f" (rejected so far: {kinds})" if kinds else "")) if new else \
            f"{self.pairs['measured']} pairs measured"
        values = {**{f"pairs_{k}": n for k, n in self.pairs.items()}, "frames_unpaired": unpaired_frames,
                  **{f"rejected_{kind}": n for kind, n in rejections.items()}}
        return DiagnosticStatus(level=bytes([WARN if new else OK]), name=self.name, message=message,
                                hardware_id="needle_sim",
                                values=[KeyValue(key=k, value=str(v)) for k, v in values.items()])
