"""The ROS 2 side: the needle_stereo node and its measurement status (the pieces every node uses: needle_common.ros)."""
