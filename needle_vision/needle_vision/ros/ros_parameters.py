"""Moved to :mod:`needle_common.ros.ros_parameters`; the stereo node still imports it from here."""
from needle_common.ros.ros_parameters import declare_all

__all__ = ["declare_all"]
