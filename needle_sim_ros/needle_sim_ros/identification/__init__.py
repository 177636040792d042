"""Identification of tissue and needle parameters from recorded data (ROS-free): the seed 003 LuGre EKFs, the
seed 002 three-phase insertion profile fit, the seed 001 k_b least squares. The models they identify live in
:mod:`needle_sim_ros.tissue`; ``needle_batch identify`` fits the simulator's tissue parameters to whole bags."""
from .bending_stiffness import identify_bending_stiffness
from .insertion_profile_fit import ProfileFit, detect_puncture, fit_insertion_profile
from .lugre_ekf import TABLE_I_GROUPS, LuGreEstimate, LuGreEstimator, fisher_information, identify_record

__all__ = ["identify_bending_stiffness", "ProfileFit", "detect_puncture", "fit_insertion_profile", "TABLE_I_GROUPS",
           "LuGreEstimate", "LuGreEstimator", "fisher_information", "identify_record"]
