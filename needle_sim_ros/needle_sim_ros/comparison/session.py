"""The comparison core of ``needle_compare``, ROS-free: what the node and the offline comparison stage both run.

Shapes in an unexpected frame or with unusable samples are rejected (counted by reason), the others paired by stamp
(:class:`ShapePairer`) and compared in the model frame (:func:`compare_centerlines`); a shape's tag (its header)
comes back with the comparison.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from needle_common.transforms import RigidTransform

from needle_sim_ros.comparison.pairing import ShapePairer
from needle_sim_ros.comparison.shape_error import CenterlineSamples, ComparisonError, ErrorSummary, ShapeComparison, \
    compare_centerlines


@dataclass(frozen=True)
class ComparedPair:
    """One comparison: the tags and centerlines of the model and measured shapes, and the errors."""

    model_tag: Any
    measured_tag: Any
    model: CenterlineSamples
    measured: CenterlineSamples
    result: ShapeComparison


class ComparisonSession:
    """``needle_compare``'s parameters in force (:mod:`needle_sim_ros.parameters.compare`) applied to a stream of
    shapes; ``on_reject(what, reason)`` hears of every rejected input (the node logs it)."""

    def __init__(self, values: dict[str, Any], on_reject: Callable[[str, str], None] | None = None) -> None:
        self.model_from_camera = RigidTransform.from_xyz_quaternion([*values["extrinsic.translation"],
                                                                     *values["extrinsic.rotation"]])
        self.max_match_distance = values["max_match_distance"] or math.inf
        self.model_frame, self.measured_frame = values["model_frame"], values["measured_frame"]
        self.pairer = ShapePairer(int(round(values["tolerance"] * 1e9)), model_buffer=values["model_buffer"])
        self.summary = ErrorSummary()
        self.on_reject = on_reject

    def reject(self, what: str, reason: str) -> None:
        self.summary.reject(what)
        if self.on_reject is not None:
            self.on_reject(what, reason)

    def _centerline(self, what: str, frame_id: str, expected_frame: str, minimum: int,
                    **samples) -> CenterlineSamples | None:
        if expected_frame and frame_id != expected_frame:
            self.reject(what, f"frame_id '{frame_id}' is not '{expected_frame}'")
            return None
        try:
            centerline = CenterlineSamples(**samples)
            if len(centerline.points) < minimum:
                raise ComparisonError("needs at least two samples")
        except ComparisonError as error:
            self.reject(what, str(error))
            return None
        return centerline

    def add_model(self, stamp_ns: int, frame_id: str, tag: Any, points: np.ndarray,
                  arc_length: np.ndarray) -> list[ComparedPair]:
        """A model shape (ordered base to tip, at least two samples); returns the comparisons it completes."""
        centerline = self._centerline("model shape", frame_id, self.model_frame, 2, points=points,
                                      arc_length=arc_length)
        return [] if centerline is None else self.compare(self.pairer.add_model(stamp_ns, (tag, centerline)))

    def add_measurement(self, stamp_ns: int, frame_id: str, tag: Any, points: np.ndarray,
                        arc_length: np.ndarray | None = None, what: str = "measured shape") -> list[ComparedPair]:
        """A measured shape: ordered base to tip with its ``arc_length``, or (``arc_length`` None) an unordered
        point cloud; returns the comparisons it completes."""
        samples = {"points": points, "arc_length": arc_length} if arc_length is not None else {
            "points": points, "ordered": False}
        centerline = self._centerline(what, frame_id, self.measured_frame, 0, **samples)
        return [] if centerline is None else self.compare(self.pairer.add_measurement(stamp_ns, (tag, centerline)))

    def compare(self, pairs) -> list[ComparedPair]:
        compared = []
        for pair in pairs:
            (model_tag, model), (measured_tag, measured) = pair.model, pair.measurement
            try:
                result = compare_centerlines(model, measured, self.model_from_camera, self.max_match_distance)
            except ComparisonError as error:
                self.reject("shape pair", str(error))
                continue
            self.summary.add(result)
            compared.append(ComparedPair(model_tag, measured_tag, model, measured, result))
        return compared

    def finish(self) -> dict[str, Any]:
        """The run summary (:meth:`ErrorSummary.as_dict`), unpaired measurements included."""
        self.summary.unpaired_measurements = self.pairer.unpaired
        return self.summary.as_dict()
