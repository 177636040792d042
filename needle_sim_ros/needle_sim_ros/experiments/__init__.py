"""Synthetic sample experiments (seed 000 Sec. III and a tissue insertion): protocols, ground truth, bag writing.

:mod:`.protocols` and :mod:`.ground_truth` are ROS-free; the bag writer (:mod:`.make_bags`, console script
``needle_make_bags``) needs rclpy messages.
"""
