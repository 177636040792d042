"""Error of a model centerline against a measured one (the ShapeError message, without ROS): each measured sample,
brought into the model frame by the extrinsic p_j = R q_j + t, is its distance to the model centerline
(:mod:`.centerline_distance`); RMSE and maximum over the matched samples; tip error between the model's last sample
and the measured tip.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from needle_common.transforms import RigidTransform

from needle_sim_ros.comparison.centerline_distance import closest_points_on_polyline


class ComparisonError(ValueError):
    """The shapes cannot be compared (bad samples, or no measured sample matched)."""


@dataclass(frozen=True)
class CenterlineSamples:
    """Needle centerline samples [m] in one frame, as compared (validated input; the model's own sampled centerline with
    tangents is :class:`needle_sim_ros.model.Centerline`). ``ordered`` samples run from the base to the tip
    (NeedleShape); an unordered set (a point cloud) has no defined last sample. ``arc_length`` [m] (optional) must be
    non-decreasing and as long as ``points``."""

    points: np.ndarray
    arc_length: np.ndarray | None = None
    ordered: bool = True

    def __post_init__(self) -> None:
        points = np.asarray(self.points, dtype=float)
        if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
            raise ComparisonError(f"centerline points must be a non-empty (n, 3) array, got shape {points.shape}")
        if not _all_finite(points):
            raise ComparisonError("centerline points must be finite")
        object.__setattr__(self, "points", points)
        if self.arc_length is not None and len(self.arc_length):
            arc = np.asarray(self.arc_length, dtype=float)
            if arc.shape != (len(points),):
                raise ComparisonError(f"arc_length has {arc.size} values for {len(points)} points")
            if not _all_finite(arc) or (arc[1:] < arc[:-1]).any():
                raise ComparisonError("arc_length must be finite and non-decreasing from base to tip")
            object.__setattr__(self, "arc_length", arc)
        else:
            object.__setattr__(self, "arc_length", None)


def _all_finite(values: np.ndarray) -> bool:
    """Whether every value is finite: a finite sum says so at once (a model shape per 10 ms is checked)."""
    return math.isfinite(values.sum()) or bool(np.isfinite(values).all())


@dataclass(frozen=True)
class ShapeComparison:
    """Errors [m] of the matched measured samples and the model arc length [m] of their closest points."""

    rmse: float
    max_error: float
    tip_error: float
    errors: np.ndarray
    arc_length: np.ndarray
    matched: np.ndarray  # bool mask over the measured samples

    @property
    def matched_samples(self) -> int:
        return int(np.count_nonzero(self.matched))


def compare_centerlines(model: CenterlineSamples, measured: CenterlineSamples,
                        model_from_measured: RigidTransform = RigidTransform(),
                        max_match_distance: float = math.inf) -> ShapeComparison:
    """Compare a measured centerline (in its own frame) with the model centerline (in the model frame).

    A sample is matched within ``max_match_distance`` of the model centerline (``inf``: all). The measured tip is an
    ordered centerline's last sample, else the matched sample whose closest model point lies farthest along the model.
    Raises ComparisonError if nothing matched."""
    if len(model.points) < 2:
        raise ComparisonError("model centerline needs at least two samples")
    if not max_match_distance > 0.0:
        raise ComparisonError(f"max_match_distance must be > 0, got {max_match_distance}")
    points = model_from_measured.apply(measured.points)
    closest = closest_points_on_polyline(points, model.points, model.arc_length)
    matched = closest.distance <= max_match_distance
    if not np.any(matched):
        raise ComparisonError(f"no measured sample within max_match_distance = {max_match_distance} m of the model")
    errors = closest.distance[matched]
    if measured.ordered:
        measured_tip = points[-1]
    else:
        candidates = np.flatnonzero(matched)
        measured_tip = points[candidates[np.argmax(closest.arc_length[candidates])]]
    return ShapeComparison(rmse=float(np.sqrt(np.mean(errors**2))), max_error=float(np.max(errors)),
                           tip_error=float(np.linalg.norm(model.points[-1] - measured_tip)), errors=errors,
                           arc_length=closest.arc_length[matched], matched=matched)


@dataclass
class ErrorSummary:
    """Running statistics of a comparison run (printed and written as JSON at shutdown)."""

    count: int = 0
    rmse_sum: float = 0.0
    rmse_max: float = 0.0
    tip_error_sum: float = 0.0
    tip_error_max: float = 0.0
    max_error: float = 0.0
    unpaired_measurements: int = 0
    rejected_inputs: dict[str, int] = field(default_factory=dict)

    def add(self, comparison: ShapeComparison) -> None:
        self.count += 1
        self.rmse_sum += comparison.rmse
        self.rmse_max = max(self.rmse_max, comparison.rmse)
        self.tip_error_sum += comparison.tip_error
        self.tip_error_max = max(self.tip_error_max, comparison.tip_error)
        self.max_error = max(self.max_error, comparison.max_error)

    def reject(self, reason: str) -> None:
        self.rejected_inputs[reason] = self.rejected_inputs.get(reason, 0) + 1

    def as_dict(self) -> dict:
        """JSON-ready summary; means are null when nothing was compared."""
        mean = (lambda total: total / self.count) if self.count else (lambda total: None)
        return {"compared": self.count, "rmse_mean_m": mean(self.rmse_sum),
                "rmse_max_m": self.rmse_max if self.count else None, "tip_error_mean_m": mean(self.tip_error_sum),
                "tip_error_max_m": self.tip_error_max if self.count else None,
                "max_error_m": self.max_error if self.count else None,
                "unpaired_measurements": self.unpaired_measurements, "rejected_inputs": dict(self.rejected_inputs)}
