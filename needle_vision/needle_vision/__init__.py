"""Stereo reconstruction of needle centerlines (ROS-free library) and its ROS 2 node."""
