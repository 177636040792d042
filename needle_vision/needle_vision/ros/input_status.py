"""Moved to :mod:`needle_common.ros.input_status`; the stereo node still imports it from here."""
from needle_common.ros.input_status import InputStatus

__all__ = ["InputStatus"]
