"""Camera -> model extrinsic from a few static frames, by point-to-centerline registration (ICP with Kabsch steps).

(R, t) minimizes sum_kj dist(R q_kj + t, model centerline_k)^2 over frames k and measured samples q_kj (camera
frame): each iteration solves the least-squares problem to the current closest points c_kj in closed form (Kabsch:
t = mean(c) - R mean(q)); the cost never increases (a local minimum). The start is given or, for ordered samples,
from equal-arc-length correspondences. Collinear samples (a straight needle in one pose) leave the rotation about
its axis free: rejected.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from needle_common.transforms import RigidTransform

from needle_sim_ros.comparison.centerline_distance import chord_arc_length, closest_points_on_polyline
from needle_sim_ros.comparison.shape_error import CenterlineSamples, ComparisonError

# Measured samples whose second principal extent is below this fraction of the first count as collinear.
_COLLINEAR_RATIO = 1e-6


@dataclass(frozen=True)
class ExtrinsicCalibration:
    """Estimated camera -> model motion, RMS point-to-centerline residual [m], iterations used, convergence."""

    model_from_camera: RigidTransform
    rmse: float
    iterations: int
    converged: bool


def kabsch(source: np.ndarray, target: np.ndarray) -> RigidTransform:
    """Least-squares rigid motion with ``target ~ R source + t`` for corresponding points (n, 3), n >= 3."""
    source_mean, target_mean = source.mean(axis=0), target.mean(axis=0)
    rotation, _ = Rotation.align_vectors(target - target_mean, source - source_mean)
    return RigidTransform(rotation.as_matrix(), target_mean - rotation.apply(source_mean))


def _arc_length_guess(frames: Sequence[tuple[CenterlineSamples, CenterlineSamples]]) -> RigidTransform:
    """Kabsch on samples paired by equal arc length from the base (without measured arc lengths, the first
    measured sample is taken as the base)."""
    sources, targets = [], []
    for model, measured in frames:
        if not measured.ordered:
            raise ComparisonError("unordered measured samples need an initial extrinsic guess")
        model_arc = chord_arc_length(model.points) if model.arc_length is None else model.arc_length
        measured_arc = chord_arc_length(measured.points) if measured.arc_length is None else measured.arc_length
        at = np.clip(measured_arc, model_arc[0], model_arc[-1])
        targets.append(np.column_stack([np.interp(at, model_arc, model.points[:, i]) for i in range(3)]))
        sources.append(measured.points)
    return kabsch(np.concatenate(sources), np.concatenate(targets))


def calibrate_extrinsic(frames: Sequence[tuple[CenterlineSamples, CenterlineSamples]],
                        initial: RigidTransform | None = None, max_iterations: int = 100,
                        step_tolerance: float = 1e-10) -> ExtrinsicCalibration:
    """Estimate the camera -> model extrinsic from (model centerline, measured centerline) pairs of static frames,
    iterating until no measured sample moves by more than ``step_tolerance`` [m], or ``max_iterations``."""
    if not frames:
        raise ComparisonError("calibration needs at least one frame")
    measured_all = np.concatenate([measured.points for _, measured in frames])
    centred = measured_all - measured_all.mean(axis=0)
    extent = np.linalg.svd(centred, compute_uv=False)
    if len(measured_all) < 3 or extent[1] <= _COLLINEAR_RATIO * extent[0]:
        raise ComparisonError("measured samples are collinear: the rotation about the needle axis is unobservable; "
                              "use a bent needle or several base poses")
    motion = _arc_length_guess(frames) if initial is None else initial

    def closest(motion: RigidTransform) -> tuple[np.ndarray, np.ndarray]:
        found = [closest_points_on_polyline(motion.apply(measured.points), model.points) for model, measured in frames]
        return np.concatenate([c.point for c in found]), np.concatenate([c.distance for c in found])

    converged, iterations = False, 0
    for iterations in range(1, max_iterations + 1):
        targets, _ = closest(motion)
        updated = kabsch(measured_all, targets)
        step = np.max(np.linalg.norm(updated.apply(measured_all) - motion.apply(measured_all), axis=1))
        motion = updated
        if step < step_tolerance:
            converged = True
            break
    _, distance = closest(motion)
    return ExtrinsicCalibration(motion, float(np.sqrt(np.mean(distance**2))), iterations, converged)
