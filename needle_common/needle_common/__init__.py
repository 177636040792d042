"""The base of the needle_sim suite, below ``needle_sim_ros`` and ``needle_vision`` (it imports neither): the one
parameter system, command-line types, output files and package files; ``ros/`` the node pieces every node uses."""
