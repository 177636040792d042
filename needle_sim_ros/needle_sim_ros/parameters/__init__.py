"""ROS-free parameter declarations (:class:`needle_vision.parameters.ParamSpec`) of the simulator and comparison
cores, and experiment files read without ROS. The nodes declare them with descriptors (``nodes/parameters.py``);
the offline pipeline validates the same values against them."""
