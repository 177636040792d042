"""Synthetic sample experiments (seed 000 Sec. III and a tissue insertion): protocols and ground truth (ROS-free),
bag writing (:mod:`.make_bags`, ``needle_make_bags``: rclpy messages).
"""
