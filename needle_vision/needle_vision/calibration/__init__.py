"""Stereo calibration: the rig model (camera_calibration YAMLs, CameraInfo), rectification, the
needle_stereo_calibrate tool."""
