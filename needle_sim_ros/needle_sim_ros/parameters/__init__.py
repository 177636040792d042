"""ROS-free parameter declarations (:class:`needle_common.parameters.ParamSpec`) of the simulator and comparison
cores, and experiment files read without ROS. The nodes declare them with descriptors
(``needle_common.ros.ros_parameters``); the offline pipeline validates the same values against them."""
