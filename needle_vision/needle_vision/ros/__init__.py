"""The ROS 2 side: the needle_stereo node, parameter declaration from the specs, TF output."""
