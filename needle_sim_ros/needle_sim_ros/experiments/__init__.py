"""Synthetic sample experiments (seed 000 Sec. III and a tissue insertion): protocols, ground truth, bag writing.

The ROS-free parts (:mod:`.protocols`, :mod:`.ground_truth`) are imported here; the bag writer
(:mod:`.make_bags`, console script ``needle_make_bags``) needs rclpy messages and is imported on its own.
"""
from needle_sim_ros.experiments.ground_truth import TruthModel, TruthSamples, run_ground_truth, truth_simulation
from needle_sim_ros.experiments.protocols import EXPERIMENTS, Experiment

__all__ = ["EXPERIMENTS", "Experiment", "TruthModel", "TruthSamples", "run_ground_truth", "truth_simulation"]
