"""needle_sim_ros: ANCF needle model (ROS-free core) and its ROS 2 nodes."""
