"""Model vs measured needle shape: stamp pairing, extrinsic transform, centerline distance errors, calibration, and
the comparison session that the needle_compare node and the offline comparison stage both run."""
from needle_sim_ros.comparison.centerline_distance import ClosestPoints, chord_arc_length, closest_points_on_polyline
from needle_sim_ros.comparison.extrinsic_calibration import ExtrinsicCalibration, calibrate_extrinsic, kabsch
from needle_sim_ros.comparison.pairing import ShapePairer, StampedPair
from needle_sim_ros.comparison.session import ComparedPair, ComparisonSession
from needle_sim_ros.comparison.shape_error import (CenterlineSamples, ComparisonError, ErrorSummary, ShapeComparison,
                                                   compare_centerlines)

__all__ = ["CenterlineSamples", "ClosestPoints", "ComparedPair", "ComparisonError", "ComparisonSession", "ErrorSummary",
           "ExtrinsicCalibration", "ShapeComparison", "ShapePairer", "StampedPair", "calibrate_extrinsic",
           "chord_arc_length", "closest_points_on_polyline", "compare_centerlines", "kabsch"]
